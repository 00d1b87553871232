"""Randomized robustness: n random scenarios per suite in the co-simulation, counted (issue #7).

:func:`random_scenarios` draws scenarios with :func:`tankctl.randomized.generate` (seeds
``seed .. seed + n - 1``), runs each with :func:`tankctl.randomized.run_scenario` and counts
overflows and broken oracles; it reports the worst margin to a tank top, the largest balance
errors, trips, refusals and the wall time (``time.perf_counter``; the runs themselves read no
clock). The suites (``tests/robustness`` runs the first seeds of each):

- ``energies``: the default site, every request kind, inflows ``"passable"`` (the issue's item:
  zero overflows expected);
- ``energies_eurange``: the same with inflows up to the Disturbance EURange; each overflow is
  checked against :func:`tankctl.randomized.first_unpassable` (``unexplained`` must stay 0);
- ``two_tank``: the interacting two-tank site (no supervisor), ``"passable"``;
- ``single_tank``: the NL-PI single tank, every kind, ``"passable"`` (it spilled in 25 of 100
  with the 0.5 m^3/s pump first assumed, which one HH scan could not stop; with 0.2 m^3/s and
  HH 0.25 m it must not); ``single_tank_sp_leak``: setpoints, leaks and interlock resets only.

Usage: ``python -m benchmarks.robustness [n] [seed]`` prints the result as JSON.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from typing import Any

from benchmarks.common import ENERGIES, ROOT
from tankctl.randomized import ScenarioSpace, first_unpassable, generate, run_scenario
from tanklab.config import load_site

TWO_TANK = ROOT / "configs" / "two_tank_interacting.yaml"
SINGLE = ROOT / "configs" / "single_tank_short_sim.yaml"
# The single tank's time constant is about a second (a' = 0.5, b = 2): 100 to 200 s is long.
_SINGLE_S = (100.0, 200.0)
_SINGLE_EVERY_S = 8.0


@dataclass(frozen=True)
class Suite:
    name: str
    config: str
    space: ScenarioSpace
    explain_overflows: bool = False
    """Check each overflow against an unpassable inflow (suites with EURange inflows)."""


SUITES = (
    Suite("energies", str(ENERGIES), ScenarioSpace(inflows="passable")),
    Suite("energies_eurange", str(ENERGIES), ScenarioSpace(inflows="eurange"), explain_overflows=True),
    Suite("two_tank", str(TWO_TANK), ScenarioSpace(inflows="passable")),
    Suite("single_tank", str(SINGLE), ScenarioSpace(_SINGLE_S, _SINGLE_EVERY_S, inflows="passable")),
    Suite(
        "single_tank_sp_leak",
        str(SINGLE),
        ScenarioSpace(_SINGLE_S, _SINGLE_EVERY_S, weights={"setpoint": 3.0, "leak": 2.0, "reset": 1.0}),
    ),
)


def run_suite(suite: Suite, n: int, seed: int) -> dict[str, Any]:
    """Run one suite's ``n`` scenarios; counts, worst cases (with their seeds) and timing."""
    site = load_site(suite.config)
    worst = (float("inf"), -1, "")
    bal = (0.0, -1)
    inflow = (0.0, -1)
    overflows: list[int] = []
    unexplained: list[int] = []
    broken: dict[int, list[str]] = {}
    trips = refused = model_s = 0.0
    wall_s = 0.0
    for s in range(seed, seed + n):
        scenario = generate(site, s, suite.space)
        started = time.perf_counter()
        result = run_scenario(scenario)
        wall_s += time.perf_counter() - started
        model_s += scenario.duration_s
        trips += result.trips
        refused += len(result.refused)
        margins = result.margins_m
        k = min(range(len(margins)), key=margins.__getitem__)
        if margins[k] < worst[0]:
            worst = (margins[k], s, site.tank_names[k])
        if abs(result.balance_error_m3) > abs(bal[0]):
            bal = (result.balance_error_m3, s)
        if abs(result.inflow_error_m3) > abs(inflow[0]):
            inflow = (result.inflow_error_m3, s)
        if result.spilled_m3 > 0:
            overflows.append(s)
            if suite.explain_overflows and first_unpassable(scenario, result.first_spill_s) is None:
                unexplained.append(s)
        others = [v for v in result.violations() if not v.startswith("overflow")]
        if others:
            broken[s] = others
    return {
        "site": site.name,
        "inflows": suite.space.inflows,
        "kinds": sorted(k for k, w in suite.space.weights.items() if w > 0),
        "scenarios": n,
        "seeds": [seed, seed + n - 1],
        "overflows": len(overflows),
        "overflow_seeds": overflows,
        "unexplained_overflows": unexplained if suite.explain_overflows else None,
        "other_violations": broken,
        "worst_margin_m": worst[0],
        "worst_margin_seed": worst[1],
        "worst_margin_tank": worst[2],
        "max_abs_balance_error_m3": abs(bal[0]),
        "max_abs_balance_error_seed": bal[1],
        "max_abs_inflow_error_m3": abs(inflow[0]),
        "interlock_trips": int(trips),
        "refused_requests": int(refused),
        "model_s": model_s,
        "wall_s": wall_s,
    }


def random_scenarios(n: int = 100, seed: int = 0) -> dict[str, Any]:
    """Run every suite with ``n`` scenarios (seeds ``seed .. seed + n - 1``).

    Returns
    -------
    ``{"n", "seed", "suites": {name: counts}, "overflows": total in the suites expected to
    have none (every suite but energies_eurange), "unexplained_overflows": EURange
    overflows without an unpassable inflow before them, "worst_margin_m": over those same
    suites, "wall_s"}``; per suite see :func:`run_suite`.
    """
    started = time.perf_counter()
    suites = {suite.name: run_suite(suite, n, seed) for suite in SUITES}
    clean = [suites[name] for name in ("energies", "two_tank", "single_tank", "single_tank_sp_leak")]
    return {
        "n": n,
        "seed": seed,
        "suites": suites,
        "overflows": sum(s["overflows"] for s in clean),
        "unexplained_overflows": len(suites["energies_eurange"]["unexplained_overflows"] or []),
        "worst_margin_m": min(s["worst_margin_m"] for s in clean),
        "wall_s": time.perf_counter() - started,
    }


def markdown(result: dict[str, Any]) -> str:
    """The section of docs/benchmarks.md: one row per suite."""
    lines = [
        "## 7. Randomized robustness scenarios (co-simulation)",
        "",
        f"`benchmarks.robustness.random_scenarios(n={result['n']}, seed={result['seed']})`: per suite, "
        f"{result['n']} seeded scenarios of random setpoints, leaks, gains (through the PLC's "
        "`stage_gains`), loop and supervisor modes, interlock resets and disturbances, every request "
        "inside its node's range, checked every scan (no spill, levels in [0, top], HH stops the "
        "pumps, the water balance closes). `tests/robustness/test_random_scenarios.py` runs the "
        "first seeds of each suite.",
        "",
        "| suite | inflows | scenarios | overflows | worst margin to a tank top [mm] (seed) | HH trips "
        "| other violations | max balance error [m^3] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, s in result["suites"].items():
        lines.append(
            f"| {name} | {s['inflows']} | {s['scenarios']} | {s['overflows']} | "
            f"{s['worst_margin_m'] * 1e3:.1f} ({s['worst_margin_seed']}) | {s['interlock_trips']} | "
            f"{len(s['other_violations'])} | {s['max_abs_balance_error_m3']:.1e} |"
        )
    lines += [
        "",
        f"Overflows in the suites expected clean: **{result['overflows']}**; EURange overflows without "
        f"an inflow the plant cannot pass before them: **{result['unexplained_overflows']}** "
        f"(wall {result['wall_s']:.0f} s).",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:3]]
    print(json.dumps(random_scenarios(*args), indent=2))
