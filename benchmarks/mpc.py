"""MPC step time on the Kortela configuration, side by side with cvxpy and do-mpc.

For each horizon Np the supervisor's MPC (``build_mpc`` of the Kortela site with
``supervisor.mpc.horizon = Np``) runs in closed loop on the nonlinear plant through
:class:`tankctl.cosim.CoSimulation` in MPC mode, on the benchmark scenario (LIC1's setpoint
+0.05 m at 10 s). Each sample the supervisor calls ``MpcController.correct(y, prior)`` (the
filter's corrector) and then ``MpcController.plan(x0, r, u_prev, eta)`` (the QP from the state the
committed move leads to, supervisor.timing); the benchmark, in this order and within the same
sample:

1. times the MPC step (``time.perf_counter`` around ``correct`` plus around ``plan``: filter,
   QP update, the solver, projection, prediction; the objective is evaluated only when read)
   and keeps the solver's own time (``MpcResult.solve_time_s``) and iteration count;
2. gives the same (x0, r, u_prev, eta) to a second ``MpcController``, the same QP form on the
   other backend (daqp <-> OSQP with its tolerance ladder): it solves the same QP;
3. gives the QP that step solved (start state ``MpcResult.state``, disturbance
   ``MpcResult.disturbance``, r, u_prev) to the comparators of :mod:`benchmarks.comparators`:
   cvxpy + OSQP at eps 1e-4 with polish (the controller's first tolerance rung), cvxpy + OSQP
   at eps 1e-6 with polish (its last rung), cvxpy with its default solver and settings, and
   do-mpc (IPOPT). Each comparator's first move is compared with the controller's.

So every ratio is measured on the same sequence of QPs, in one process, interleaved sample by
sample. Each call is timed twice, wall (``perf_counter``) and the process's CPU time
(``process_time``); the ratio goals are judged on CPU time, the wall ratios are shown beside them
(decision 0059: on a shared machine a 3 ms comparator call is preempted far more often than a
0.2 ms step, so the wall ratio measures the machine's other work as much as the solvers).
Interleaving costs the controller some cache warmth, so its own numbers (the goals) come
from a first closed loop with no comparator (``run_horizon(..., comparators=[])``); the
co-simulation is deterministic, so both loops see the same QPs. :func:`profile_steps` profiles
the ``correct`` and ``plan`` calls of a third loop.
"""

from __future__ import annotations

import cProfile
import gc
import time
import traceback
import warnings
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike

from benchmarks.common import KORTELA, SCENARIO_STEP_AT_S, SCENARIO_STEP_M, Summary, load, with_horizon
from benchmarks.comparators import CvxpyMpc, DoMpc, ScaledQp, SolveRecord
from benchmarks.cosim import HotSpot, hotspots
from benchmarks.procs import CpuMeter
from supervisor.mpc import MpcController, MpcResult
from tankctl.cosim import CoSimulation

OURS = "ours"
OURS_ALT = "ours_alt"
CVXPY_OSQP = "cvxpy_osqp"
CVXPY_OSQP_TIGHT = "cvxpy_osqp_tight"
CVXPY_DEFAULT = "cvxpy_default"
DOMPC = "dompc"

LABELS = {
    OURS: "tanklab MpcController",
    OURS_ALT: "tanklab MpcController, other backend (daqp <-> OSQP)",
    CVXPY_OSQP: "cvxpy + OSQP, eps 1e-4 + polish",
    CVXPY_OSQP_TIGHT: "cvxpy + OSQP, eps 1e-6 + polish",
    CVXPY_DEFAULT: "cvxpy, default solver and settings",
    DOMPC: "do-mpc (IPOPT)",
}


class _Solver(Protocol):
    def solve(self, state: Any, eta: Any, r: Any, u_prev: Any) -> SolveRecord: ...


@dataclass
class Series:
    """The per-step record of one solver on one horizon."""

    wall_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)
    """The process's CPU time over the same calls: what a call costs on a machine whose other
    work preempts it (wall - CPU is time spent waiting for a core; decision 0059)."""
    solver_s: list[float] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    status: Counter[str] = field(default_factory=Counter)
    path: Counter[str] = field(default_factory=Counter)
    """How the controller's steps were solved (``MpcResult.solved_by``): ``daqp``, ``osqp`` or
    ``held``."""
    du0: list[float] = field(default_factory=list)
    """|u0 - u0 of the controller| / input range, largest over the inputs."""
    detail: str = ""
    error: str = ""

    @property
    def wall(self) -> Summary:
        return Summary.of(self.wall_s)

    @property
    def solver(self) -> Summary:
        return Summary.of(self.solver_s)

    @property
    def cpu(self) -> Summary:
        return Summary.of(self.cpu_s)


@dataclass
class HorizonResult:
    """Everything measured at one horizon."""

    horizon: int
    formulation: str
    alt_formulation: str
    qp_size: tuple[int, int]
    alt_qp_size: tuple[int, int]
    steps: int
    run_wall_s: float
    series: dict[str, Series]
    input_range: float
    other_cores: float
    """Cores other work on the machine kept busy during the closed loop (:class:`CpuMeter`)."""


def solve_path(res: MpcResult) -> str:
    """``daqp``, ``osqp`` or ``held``: how :class:`MpcController` found this step's plan
    (``MpcResult.solved_by``)."""
    return res.solved_by


def _setpoint_step(sim: CoSimulation) -> None:
    if sim.t_s >= SCENARIO_STEP_AT_S and not getattr(sim, "_bench_stepped", False):
        sim.plc.set_sp("LIC1", sim.plc.loop("LIC1").sp_m + SCENARIO_STEP_M)
        sim._bench_stepped = True  # type: ignore[attr-defined]


def _build(name: str, make: Callable[[], Any], series: dict[str, Series]) -> Any | None:
    """Build a comparator, or record the error that stopped it."""
    s = series.setdefault(name, Series())
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # do-mpc's optional-feature warnings at import
            obj = make()
    except Exception as e:
        s.error = f"{type(e).__name__}: {e}".strip()
        s.detail = traceback.format_exc(limit=3)
        return None
    return obj


def run_horizon(horizon: int, duration_s: float, comparators: Sequence[str]) -> HorizonResult:
    """Closed loop at one horizon with the comparators named (subset of the module's keys)."""
    site = with_horizon(load(KORTELA), horizon)
    sim = CoSimulation(site, supervisor_mode="MPC")
    assert sim.supervisor is not None
    mpc = sim.supervisor.mpc
    alt_solver: Literal["daqp", "osqp"] = "osqp" if mpc.solver == "daqp" else "daqp"
    alt_form = "condensed" if alt_solver == "daqp" else mpc.formulation  # daqp is dense
    alt_config = replace(mpc.config, formulation=alt_form, solver=alt_solver)
    series: dict[str, Series] = {OURS: Series()}
    alt = _build(OURS_ALT, lambda: MpcController(mpc.model, alt_config), series)
    qp = ScaledQp.of(mpc)
    u_range = float(np.max(qp.su))
    others: dict[str, _Solver] = {}
    makers: dict[str, Callable[[], Any]] = {
        CVXPY_OSQP: lambda: CvxpyMpc(qp, solver="OSQP", eps=1e-4),
        CVXPY_OSQP_TIGHT: lambda: CvxpyMpc(qp, solver="OSQP", eps=1e-6),
        CVXPY_DEFAULT: lambda: CvxpyMpc(qp, solver=None),
        DOMPC: lambda: DoMpc(qp, mpc.model.ts_s),
    }
    for name in comparators:
        obj = _build(name, makers[name], series)
        if obj is not None:
            others[name] = obj
    original, original_correct = mpc.plan, mpc.correct
    correct_wall = [0.0]

    def du0(u: np.ndarray, ref: np.ndarray) -> float:
        return float(np.max(np.abs(np.asarray(u) - ref)) / u_range)

    correct_cpu = [0.0]

    def timed_correct(y: ArrayLike, x: ArrayLike, d: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        t0, c0 = time.perf_counter(), time.process_time()
        out = original_correct(y, x, d)
        correct_wall[0] = time.perf_counter() - t0
        correct_cpu[0] = time.process_time() - c0
        return out

    def timed_step(x: ArrayLike, r: ArrayLike, u_prev: ArrayLike, disturbance: ArrayLike) -> MpcResult:
        t0, c0 = time.perf_counter(), time.process_time()
        res = original(x, r, u_prev, disturbance)
        wall = time.perf_counter() - t0 + correct_wall[0]
        cpu = time.process_time() - c0 + correct_cpu[0]
        correct_wall[0] = correct_cpu[0] = 0.0
        s = series[OURS]
        s.wall_s.append(wall)
        s.cpu_s.append(cpu)
        s.solver_s.append(res.solve_time_s)
        s.iterations.append(res.iterations)
        s.status[res.status.name] += 1
        s.path[solve_path(res)] += 1
        if alt is not None:
            t0, c0 = time.perf_counter(), time.process_time()
            res2 = alt.plan(x, r, u_prev, disturbance)
            sa = series[OURS_ALT]
            sa.wall_s.append(time.perf_counter() - t0)
            sa.cpu_s.append(time.process_time() - c0)
            sa.solver_s.append(res2.solve_time_s)
            sa.iterations.append(res2.iterations)
            sa.status[res2.status.name] += 1
            sa.du0.append(du0(res2.u, res.u))
        r_arr = np.asarray(r, dtype=float)
        u_arr = np.asarray(u_prev, dtype=float)
        for name, solver in list(others.items()):
            sc = series[name]
            try:
                rec = solver.solve(res.state, res.disturbance, r_arr, u_arr)
            except Exception as e:  # a comparator that breaks mid-run is reported, not fatal
                sc.error = f"{type(e).__name__} at step {len(sc.wall_s)}: {e}"
                del others[name]
                continue
            sc.wall_s.append(rec.wall_s)
            sc.cpu_s.append(rec.cpu_s)
            sc.solver_s.append(rec.solver_s)
            sc.status[rec.status] += 1
            sc.du0.append(du0(rec.u0, res.u))
        return res

    mpc.plan = timed_step  # type: ignore[method-assign]
    mpc.correct = timed_correct  # type: ignore[method-assign]
    gc.collect()
    meter = CpuMeter()
    meter.start([])
    t0 = time.perf_counter()
    try:
        sim.run(duration_s, _setpoint_step)
    finally:
        mpc.plan = original  # type: ignore[method-assign]
        mpc.correct = original_correct  # type: ignore[method-assign]
    run_wall = time.perf_counter() - t0
    meter.stop([])
    for name in (CVXPY_OSQP, CVXPY_OSQP_TIGHT, CVXPY_DEFAULT):
        if name in others:
            series[name].detail = f"solver used: {getattr(others[name], 'solver_name', '?')}"
    return HorizonResult(
        horizon=horizon,
        formulation=f"{mpc.formulation}, {mpc.solver}",
        alt_formulation=f"{alt_form}, {alt_solver}",
        qp_size=mpc.qp_size,
        alt_qp_size=alt.qp_size if alt is not None else (0, 0),
        steps=len(series[OURS].wall_s),
        run_wall_s=run_wall,
        series=series,
        input_range=u_range,
        other_cores=meter.other_cores,
    )


def profile_steps(horizon: int, duration_s: float, top: int = 8) -> list[HotSpot]:
    """cProfile of every ``MpcController.correct`` and ``plan`` call of the closed loop (nothing
    else profiled)."""
    site = with_horizon(load(KORTELA), horizon)
    sim = CoSimulation(site, supervisor_mode="MPC")
    assert sim.supervisor is not None
    mpc = sim.supervisor.mpc
    original, original_correct = mpc.plan, mpc.correct
    prof = cProfile.Profile()

    def profiled(x: ArrayLike, r: ArrayLike, u_prev: ArrayLike, disturbance: ArrayLike) -> MpcResult:
        prof.enable()
        try:
            return original(x, r, u_prev, disturbance)
        finally:
            prof.disable()

    def profiled_correct(y: ArrayLike, x: ArrayLike, d: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        prof.enable()
        try:
            return original_correct(y, x, d)
        finally:
            prof.disable()

    mpc.plan = profiled  # type: ignore[method-assign]
    mpc.correct = profiled_correct  # type: ignore[method-assign]
    sim.run(duration_s, _setpoint_step)
    return hotspots(prof, top)[0]


def run(
    horizons: Sequence[int], duration_s: float, comparators: Sequence[str], log: Callable[[str], None]
) -> list[HorizonResult]:
    """Every horizon in turn."""
    out = []
    for horizon in horizons:
        res = run_horizon(horizon, duration_s, comparators)
        ours = res.series[OURS].wall.scaled(1e3)
        log(
            f"  Np = {horizon:3d} ({res.formulation}): step median {ours.median:.3f} ms, "
            f"p99 {ours.p99:.3f} ms, {res.steps} steps, {res.run_wall_s:.1f} s"
        )
        out.append(res)
    return out
