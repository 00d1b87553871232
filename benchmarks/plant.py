"""Plant step cost: what one co-simulation scan costs the plant alone.

The PID co-simulation of the benchmark scenario (:mod:`benchmarks.cosim`: the default site, 1 s
scans, LIC1's setpoint +0.05 m at 10 s, 1000 s) is run once to record the pump commands of every
scan; then a fresh :class:`plant_sim.plant.PlantSimulator` replays them, ``set_commands`` and
``advance(Ts)`` per scan, exactly what the co-simulation asks of the plant. Each replay is timed
with ``time.perf_counter`` around the whole loop (so the clock's own cost is not in the per-scan
figure), repeated, and reported as the per-scan time of each replay: median and min over the
repeats. Also the final levels of the replay, so two versions of the plant can be checked to
integrate the same trajectory (their difference is printed by whoever compares them).

Run: ``python -m benchmarks.plant [--repeats N]``.
"""

from __future__ import annotations

import argparse
import gc
import time
from dataclasses import dataclass

import numpy as np

from benchmarks.common import ENERGIES, SCENARIO_DURATION_S, Summary, load
from benchmarks.cosim import scenario_hook
from plant_sim.plant import PlantSimulator
from tankctl.cosim import CoSimulation


@dataclass(frozen=True)
class PlantStepCost:
    """Per-scan plant cost of the replays [s] and the replay's final levels [m]."""

    per_scan_s: Summary
    scans: int
    final_levels_m: tuple[float, ...]


def recorded_commands() -> tuple[list[np.ndarray], float]:
    """The pump commands of every scan of the PID benchmark scenario, and the scan period [s]."""
    sim = CoSimulation(load(ENERGIES))
    trace = sim.run(SCENARIO_DURATION_S, before_scan=scenario_hook)
    return [np.array(c, dtype=float) for c in trace.commands], sim.ts_s


def replay(commands: list[np.ndarray], ts_s: float) -> tuple[float, PlantSimulator]:
    """Wall time [s] of one replay of ``commands`` on a fresh plant, and the plant after it."""
    plant = PlantSimulator(load(ENERGIES).plant)
    plant.command_timeout_s = float("inf")  # as in the co-simulation
    gc.collect()
    t0 = time.perf_counter()
    for cmd in commands:
        plant.set_commands(cmd)
        plant.advance(ts_s)
    return time.perf_counter() - t0, plant


def plant_step_cost(repeats: int = 9) -> PlantStepCost:
    """Replay the benchmark scenario's commands ``repeats`` times (one warm-up replay first)."""
    commands, ts_s = recorded_commands()
    replay(commands, ts_s)  # warm-up: caches, plans
    walls = []
    plant = None
    for _ in range(repeats):
        wall, plant = replay(commands, ts_s)
        walls.append(wall / len(commands))
    assert plant is not None
    return PlantStepCost(Summary.of(walls), len(commands), tuple(plant.levels.tolist()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9, help="timed replays (default 9)")
    args = parser.parse_args()
    cost = plant_step_cost(args.repeats)
    s = cost.per_scan_s.scaled(1e6)
    print(
        f"plant per scan ({cost.scans} scans, {s.n} replays): median {s.median:.2f} us, "
        f"min {s.minimum:.2f} us, max {s.maximum:.2f} us"
    )
    print("final levels [m]: " + ", ".join(repr(v) for v in cost.final_levels_m))


if __name__ == "__main__":
    main()
