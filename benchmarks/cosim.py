"""Co-simulation speed (model seconds per wall second) and where the time goes.

:class:`tankctl.cosim.CoSimulation` on the default site (Energies simulation set) runs the
benchmark scenario (1000 s, LIC1's setpoint +0.05 m at 10 s) with the PLC alone (PID loops,
``supervisor_mode=None``), with the supervisor in the default config's ADVISORY mode, and in MPC
mode; each run is timed with
``time.perf_counter`` around ``run`` (construction excluded), repeated, and the median taken.
One more run of each is profiled with cProfile (its times are inflated by the profiler; the
shares are what matter) and the functions with the largest own time are reported.
"""

from __future__ import annotations

import cProfile
import gc
import math
import pstats
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from benchmarks.common import ENERGIES, ROOT, SCENARIO_DURATION_S, SCENARIO_STEP_AT_S, SCENARIO_STEP_M, load
from benchmarks.procs import CpuMeter
from plant_sim.integrate import rk4_substep_s
from plant_sim.models import TankNetwork
from tankctl.cosim import CoSimulation

Mode = Literal["ADVISORY", "MPC"] | None


@dataclass(frozen=True)
class HotSpot:
    """One line of a profile: a function and its own (exclusive) and cumulative time."""

    function: str
    calls: int
    own_s: float
    cumulative_s: float
    share: float
    """Own time / total profiled time."""


@dataclass
class CosimResult:
    label: str
    mode: Mode
    model_s: float
    scans: int
    wall_s: list[float]
    profile: list[HotSpot]
    profiled_total_s: float
    other_cores: float
    """Cores other work on the machine kept busy during the timed runs (:class:`CpuMeter`)."""
    parts: dict[str, float]
    """Cumulative share of the profiled time of the scan's parts (:data:`PARTS`)."""

    @property
    def rtf(self) -> list[float]:
        return [self.model_s / w for w in self.wall_s]


def scenario_hook(sim: CoSimulation) -> None:
    """The benchmark scenario's one event: LIC1's setpoint +0.05 m at 10 s of model time."""
    if sim.t_s >= SCENARIO_STEP_AT_S and not getattr(sim, "_bench_stepped", False):
        sim.plc.set_sp("LIC1", sim.plc.loop("LIC1").sp_m + SCENARIO_STEP_M)
        sim._bench_stepped = True  # type: ignore[attr-defined]


def _where(filename: str, line: int, func: str) -> str:
    if filename.startswith(("~", "<")):
        return func  # built-ins: "<built-in method ...>"
    parts = Path(filename).parts
    if "site-packages" in parts:
        shown = "/".join(parts[parts.index("site-packages") + 1 :])
    else:
        try:
            shown = str(Path(filename).resolve().relative_to(ROOT))
        except ValueError:
            shown = filename
    return f"{shown}:{line} {func}"


def hotspots(prof: cProfile.Profile, top: int = 8) -> tuple[list[HotSpot], float]:
    """The ``top`` functions of a finished profile by own time, and the total profiled time [s]."""
    stats = pstats.Stats(prof)
    total = float(stats.total_tt)  # type: ignore[attr-defined]
    rows = []
    for (filename, line, func), (_cc, nc, tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        rows.append(HotSpot(_where(filename, line, func), int(nc), float(tt), float(ct), float(tt) / total))
    rows.sort(key=lambda h: h.own_s, reverse=True)
    return rows[:top], total


PARTS = {
    "plant integration (`plant_sim.integrate.step_rk4`)": ("integrate.py", "step_rk4"),
    "PLC blocks (`plc_emulator.loop.LoopShell.scan`: shells and laws)": ("loop.py", "scan"),
    "PLC scan (`PlcProgram.scan`, PID blocks included)": ("program.py", "scan"),
    "transmitters (`TransmitterBank.read`)": ("sensors.py", "read"),
    "trace (`CoSimulation._record`)": ("cosim.py", "_record"),
    "supervisor (`SupervisorCore.cycle`)": ("cycle.py", "cycle"),
}
"""Parts of a scan whose cumulative profiled share the report gives: (file name, function)."""


def part_shares(prof: cProfile.Profile) -> dict[str, float]:
    """Cumulative share of the profiled total of each of :data:`PARTS` (0 if never called)."""
    stats = pstats.Stats(prof)
    total = float(stats.total_tt)  # type: ignore[attr-defined]
    out = {}
    for label, (file, func) in PARTS.items():
        cum = sum(
            float(ct)
            for (filename, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.stats.items()  # type: ignore[attr-defined]
            if name == func and Path(filename).name == file
        )
        out[label] = cum / total if total > 0 else 0.0
    return out


def profile_top(run: Callable[[], object], top: int = 8) -> tuple[list[HotSpot], float, dict[str, float]]:
    """Run ``run`` under cProfile; the ``top`` functions by own time, the total [s], the parts."""
    prof = cProfile.Profile()
    prof.enable()
    try:
        run()
    finally:
        prof.disable()
    spots, total = hotspots(prof, top)
    return spots, total, part_shares(prof)


def plant_substeps() -> tuple[int, float]:
    """How the benchmark's plant integrates one scan: (RK4 steps, their length [s]) away from the
    orifice law's non-smooth points (:func:`plant_sim.integrate.step_rk4`'s automatic sub-step)."""
    site = load(ENERGIES)
    assert site.plc is not None
    ts = site.plc.scan_period_s
    steps = max(1, math.ceil(ts / rk4_substep_s(TankNetwork.from_config(site.plant)) - 1e-9))
    return steps, ts / steps


def run_one(mode: Mode, duration_s: float) -> tuple[float, int]:
    """Wall time [s] of one run of the scenario and the number of scans."""
    sim = CoSimulation(load(ENERGIES), supervisor_mode=mode)
    gc.collect()
    t0 = time.perf_counter()
    trace = sim.run(duration_s, scenario_hook)
    return time.perf_counter() - t0, len(trace.t_s)


def run(
    repeats: int, log: Callable[[str], None], duration_s: float = SCENARIO_DURATION_S
) -> list[CosimResult]:
    """PID only and MPC, ``repeats`` timed runs each plus one profiled run."""
    out = []
    modes: Sequence[tuple[str, Mode]] = (
        ("PID (PLC only)", None),
        ("supervisor ADVISORY (the default config)", "ADVISORY"),
        ("MPC (supervisor in MPC mode)", "MPC"),
    )
    for label, mode in modes:
        walls = []
        scans = 0
        meter = CpuMeter()
        meter.start([])
        for _ in range(repeats):
            wall, scans = run_one(mode, duration_s)
            walls.append(wall)
        meter.stop([])
        sim = CoSimulation(load(ENERGIES), supervisor_mode=mode)

        def profiled(sim: CoSimulation = sim) -> object:
            return sim.run(duration_s, scenario_hook)

        spots, total, parts = profile_top(profiled)
        res = CosimResult(label, mode, duration_s, scans, walls, spots, total, meter.other_cores, parts)
        log(f"  {label}: wall {sorted(walls)[len(walls) // 2]:.3f} s for {duration_s:g} s of model time")
        out.append(res)
    return out
