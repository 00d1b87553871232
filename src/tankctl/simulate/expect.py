"""A scenario's expectations checked against its co-simulation run (``tankctl scenario check``).

Pure: a :class:`~tankctl.simulate.results.ScenarioResult` in, one :class:`Outcome` per
(expectation, variant) out. An expectation applies to its own variant, or to every variant that
ran when it names none. The value ``v`` of its metric in the variant's run passes when

    min <= v <= max        (bounds inclusive; either may be absent, not both)

A metric the run does not define fails, saying why, whatever the bound: ``settling_time_s`` is
None when a step of the loop did not settle within its window or the loop had no step,
``overshoot_pct`` is None when it had no step. A gate must not pass a bound it could not check.

``interlock_trips`` is the number of times the high-high interlock of the tank that the loop's
pump feeds latched during the run: the rising edges of its per-scan latch state, the state
before the first scan being untripped (a co-simulation starts from a cold PLC).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from tankctl.simulate.results import ScenarioResult, VariantResult
from tanklab.scenario import Expectation

__all__ = ["Outcome", "check_expectations", "interlock_trips", "metric_value"]


@dataclass(frozen=True)
class Outcome:
    """One expectation checked on one variant's run."""

    expectation: Expectation
    variant: str
    value: float | None
    """The metric's value in the run (None: the run does not define it)."""
    passed: bool
    reason: str
    """Why it failed ("" when it passed)."""

    def line(self) -> str:
        """One line: ``pass`` or ``FAIL``, the variant, loop, metric, value and bound."""
        e = self.expectation
        what = f"{self.variant} {e.loop} {e.metric}"
        bound = _bound_text(e)
        note = f" ({e.note})" if e.note else ""
        if self.passed:
            return f"pass  {what} = {self.value:.4g}, {bound}"
        return f"FAIL  {what}: {self.reason}, {bound}{note}"


def _bound_text(e: Expectation) -> str:
    if e.min is not None and e.max is not None:
        return f"expected {e.min:g} .. {e.max:g}"
    if e.max is not None:
        return f"expected <= {e.max:g}"
    return f"expected >= {e.min:g}"


def interlock_trips(latched: ArrayLike) -> int:
    """Rising edges of a per-scan latch state (N,) (nonzero: tripped); untripped before scan 0."""
    a = np.asarray(latched, dtype=float) != 0.0
    if a.size == 0:
        return 0
    return int(a[0]) + int(np.count_nonzero(a[1:] & ~a[:-1]))


def metric_value(result: VariantResult, loop: str, metric: str) -> float | None:
    """The value of ``metric`` for ``loop`` in a variant's run (None: not defined for the run).

    Raises
    ------
    KeyError
        The run has no such loop or metric.
    """
    if metric == "interlock_trips":
        site = result.site
        assert site.plc is not None
        actuator = next(lp.actuator for lp in site.plc.loops if lp.name == loop)
        tank = next(p.feeds for p in site.plant.pumps if p.name == actuator)
        if tank not in result.interlock_tanks:
            return 0.0  # no interlock on that tank: it cannot trip
        return float(interlock_trips(result.trips[:, result.interlock_tanks.index(tank)]))
    value = result.loops[loop].as_dict()[metric]
    return None if value is None else float(value)


def _check(e: Expectation, variant: str, value: float | None) -> Outcome:
    if value is None:
        why = "not settled within its window, or no step" if e.metric == "settling_time_s" else "no step"
        return Outcome(e, variant, None, False, f"not defined for this run ({why})")
    if e.max is not None and value > e.max:
        return Outcome(e, variant, value, False, f"{value:.4g} is above {e.max:g}")
    if e.min is not None and value < e.min:
        return Outcome(e, variant, value, False, f"{value:.4g} is below {e.min:g}")
    return Outcome(e, variant, value, True, "")


def check_expectations(
    result: ScenarioResult, expectations: Sequence[Expectation] | None = None
) -> list[Outcome]:
    """Check ``expectations`` (default: the scenario's ``expect:``) on every variant that ran.

    An expectation of a variant that did not run (``--variant`` chose others) gives no outcome.
    """
    out: list[Outcome] = []
    for e in result.scenario.expect if expectations is None else expectations:
        for name, run in result.variants.items():
            if e.variant is None or e.variant == name:
                out.append(_check(e, name, metric_value(run, e.loop, e.metric)))
    return out
