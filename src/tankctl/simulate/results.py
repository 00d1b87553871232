"""The results of ``tankctl simulate``: per step, disturbance, variant and scenario, and the JSON document."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tankctl.metrics import (
    LoopMetrics,
)
from tanklab.config import SiteConfig
from tanklab.scenario import (
    Scenario,
)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class StepResult:
    """One setpoint step of one loop, with its minimum-time bound."""

    loop: str
    time_s: float
    from_m: float
    setpoint_m: float
    overshoot_pct: float
    settling_time_s: float | None
    min_time_s: float | None
    min_time_method: str | None

    @property
    def settling_ratio(self) -> float | None:
        """Controller settling time / minimum-time bound (None if either is missing)."""
        if self.settling_time_s is None or self.min_time_s is None or self.min_time_s <= 0:
            return None
        return self.settling_time_s / self.min_time_s

    def as_dict(self) -> dict[str, Any]:
        """JSON entry (keys of the issue: loop, time, setpoint, overshoot_pct, settling_time_s)."""
        return {
            "loop": self.loop,
            "time": self.time_s,
            "setpoint": self.setpoint_m,
            "from": self.from_m,
            "overshoot_pct": self.overshoot_pct,
            "settling_time_s": self.settling_time_s,
            "min_time_s": self.min_time_s,
            "settling_ratio": self.settling_ratio,
            "min_time_method": self.min_time_method,
        }


@dataclass(frozen=True)
class DisturbanceResult:
    """How one loop rode out a plant event (leak, valve, fault, disturbance flow): over the window
    from the event to the next event of any kind (or the end), IAE [m s] and the peak |e| [m]."""

    loop: str
    time_s: float
    event: str
    window_s: float
    iae: float
    peak_error_m: float

    def as_dict(self) -> dict[str, Any]:
        """JSON entry."""
        return {
            "loop": self.loop,
            "time": self.time_s,
            "event": self.event,
            "window_s": self.window_s,
            "iae": self.iae,
            "peak_error_m": self.peak_error_m,
        }


@dataclass
class VariantResult:
    """One variant's run: trajectories (one row per scan) and metrics.

    Arrays: ``t_s`` (N,) [s]; ``levels_m`` (N, tanks) [m]; ``setpoints_m`` (N, loops) [m];
    ``commands`` (N, pumps) [pump unit]; ``flows_m3_s`` (N, pumps); ``gains`` (N, loops, 3) in
    the block's units (``gain_names`` says which; NaN where a block has fewer); ``modes``
    (N, loops) LoopMode values; ``trips`` (N, interlocks) 1.0 where the interlock of
    ``interlock_tanks`` is latched after the scan.
    """

    name: str
    description: str
    supervisor_mode: str
    site: SiteConfig
    ts_s: float
    t_s: FloatArray
    levels_m: FloatArray
    setpoints_m: FloatArray
    commands: FloatArray
    flows_m3_s: FloatArray
    gains: FloatArray
    gain_names: list[tuple[str, str, str]]
    modes: FloatArray
    reference_m: FloatArray
    """(N, loops) reference-model output y_m of MRAC loops [m] (NaN for other blocks)."""
    trips: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    interlock_tanks: list[str] = field(default_factory=list)
    loops: dict[str, LoopMetrics] = field(default_factory=dict)
    steps: list[StepResult] = field(default_factory=list)
    disturbances: list[DisturbanceResult] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """The variant's JSON entry."""
        return {
            "description": self.description,
            "supervisor_mode": self.supervisor_mode,
            "scan_period_s": self.ts_s,
            "loops": {name: m.as_dict() for name, m in self.loops.items()},
            "steps": [s.as_dict() for s in self.steps],
            "disturbances": [d.as_dict() for d in self.disturbances],
        }


@dataclass
class ScenarioResult:
    """Every variant of one scenario."""

    scenario: Scenario
    site_path: Path
    duration_s: float
    variants: dict[str, VariantResult]
    events: list[tuple[float, str]] = field(default_factory=list)
    """(time [s], short label) of every applied event, for plots."""


def _finite_or_none(x: Any) -> Any:
    """JSON has no NaN: non-finite numbers become null (recursively)."""
    if isinstance(x, dict):
        return {k: _finite_or_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite_or_none(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def result_json(result: ScenarioResult) -> dict[str, Any]:
    """The JSON document of ``tankctl simulate --json``."""
    doc = {
        "scenario": result.scenario.name,
        "site": str(result.site_path),
        "duration_s": result.duration_s,
        "variants": {name: v.as_dict() for name, v in result.variants.items()},
    }
    cleaned: dict[str, Any] = _finite_or_none(doc)
    return cleaned


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------
