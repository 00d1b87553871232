"""Hand-made benchmark results for the tests of the benchmark document (no measurement runs).

:func:`sample_report` fills every section of a :class:`benchmarks.report.Report` the way a full
run does (numbers shaped like docs/benchmarks.md's 2026-12-02 run: speed reference 18.6 ms at the
start, co-simulation PID 15,867x, lock-step 6.61 s, operator commands 1.09 / 1.26 s at a section
speed reference of 21.6 ms); its variants take the branches a full run does not (comparators not
run, a failed lock-step run, no speed reference, met goals). :func:`sample_restarts` does the same
for the restart benchmark. Every sample list is fixed: the same call renders the same document.
"""

from __future__ import annotations

import math
from collections import Counter

from benchmarks.accuracy import GuardResult
from benchmarks.cli import CliResults, CommandTimes, ImportEntry, ImportProfile
from benchmarks.cosim import CosimResult, HotSpot
from benchmarks.mpc import (
    CVXPY_DEFAULT,
    CVXPY_OSQP,
    CVXPY_OSQP_TIGHT,
    DOMPC,
    OURS,
    OURS_ALT,
    HorizonResult,
    Series,
)
from benchmarks.report import Report
from benchmarks.stack import Action, Lateness, LockstepRun, RoundTrip, StackResults

VARIANTS = ("full", "quick", "slow-comparators", "failures", "fast-machine", "empty")


def _samples(median: float, n: int, spread: float = 0.3, tail: float = 3.0) -> list[float]:
    """``n`` values around ``median``: a fixed deterministic pattern with a tail."""
    out = [median * (1.0 + spread * math.sin(1.7 * k + 0.3)) for k in range(n)]
    out[n // 3] = median * tail
    return out


def _series(wall_ms: float, solver_ms: float, n: int, *, ours: bool = False) -> Series:
    s = Series(
        wall_s=_samples(1e-3 * wall_ms, n),
        solver_s=_samples(1e-3 * solver_ms, n, 0.2, 6.0),
        iterations=[1 + (k * 7) % 13 for k in range(n)],
        status=Counter({"SOLVED": n}),
        du0=[0.0 if ours else 1e-4 * (1 + k % 5) for k in range(n)],
        cpu_s=_samples(0.8e-3 * wall_ms, n),
    )
    if ours:
        s.path = Counter({"daqp": n - 3, "osqp": 2, "held": 1})
    return s


def _horizon(np_: int, n: int, side: bool, variant: str) -> HorizonResult:
    scale = np_ / 40.0
    series = {OURS: _series(0.254 * scale**1.2, 0.0301 * scale**1.5, n, ours=True)}
    if side:
        series[OURS_ALT] = _series(0.4 * scale, 0.1 * scale, n)
        series[CVXPY_OSQP] = _series(3.56 * scale, 0.399 * scale, n)
        series[CVXPY_OSQP_TIGHT] = _series(4.1 * scale, 0.9 * scale, n)
        series[CVXPY_DEFAULT] = _series(5.2 * scale, 1.1 * scale, n)
        series[CVXPY_DEFAULT].detail = "CLARABEL"
        series[DOMPC] = _series(25.0 * scale, 13.2 * scale, n)
        if variant == "slow-comparators":
            series[DOMPC] = Series(error="ModuleNotFoundError: No module named 'do_mpc'")
            series[CVXPY_OSQP_TIGHT].error = "stopped after 3 failures"
    return HorizonResult(
        horizon=np_,
        formulation="condensed, daqp",
        alt_formulation="condensed, OSQP",
        qp_size=(4 * np_, 10 * np_),
        alt_qp_size=(4 * np_, 10 * np_),
        steps=n,
        run_wall_s=12.0 * scale,
        series=series,
        input_range=1.2e-4,
        other_cores=0.02 * np_ / 10,
    )


def _spots(base: str, total_s: float) -> list[HotSpot]:
    return [
        HotSpot(
            f"src/{base}.py:{10 * k} f{k}",
            1000 * (k + 1),
            total_s * 0.06 / (k + 1),
            total_s / (k + 1),
            0.06 / (k + 1),
        )
        for k in range(7)
    ]


def _cosim(variant: str) -> list[CosimResult]:
    per_pid = 1000.0 / 15867.0 if variant != "fast-machine" else 1000.0 / 24500.0
    parts = {"plant": 0.41, "PLC program": 0.33, "trace": 0.12, "supervisor": 0.0}
    return [
        CosimResult(
            "PID (PLC only)",
            None,
            1000.0,
            1001,
            _samples(per_pid, 5, 0.05, 1.2),
            _spots("plant_sim/sensors", 0.2),
            0.2,
            0.04,
            parts,
        ),
        CosimResult(
            "supervisor ADVISORY (the default config)",
            "ADVISORY",
            1000.0,
            1001,
            _samples(0.896, 5, 0.05, 1.2),
            _spots("supervisor/rls", 2.0),
            2.0,
            0.05,
            parts,
        ),
        CosimResult(
            "MPC (supervisor in MPC mode)",
            "MPC",
            1000.0,
            1001,
            _samples(1000.0 / 2815.0, 5, 0.05, 1.2),
            _spots("supervisor/mpc", 0.8),
            0.8,
            0.06,
            parts,
        ),
    ]


def _stack(variant: str) -> StackResults:
    st = StackResults(
        round_trips=[
            RoundTrip("1 node", 1, _samples(3e-4, 50)),
            RoundTrip("a loop's 4 nodes", 4, _samples(4e-4, 50)),
        ],
        actions=[
            Action(1.0, 1.0, _samples(5e-4, 20), _samples(0.5, 20), _samples(0.52, 20), missed=0),
            Action(20.0, 0.05, _samples(5e-4, 20), _samples(0.03, 20), _samples(0.031, 20), missed=1),
        ],
        lateness=[
            Lateness("plant + PLC processes, speed 1", 1.0, 60.0, 61, 0, 1.50, 4.99, other_cores=0.1),
            Lateness("plant + PLC processes, speed 20", 20.0, 30.0, 601, 0, 0.940, 2.21, other_cores=0.2),
            Lateness("tankctl up --speed 20 (whole stack)", 20.0, 30.0, 431, 0, 0.870, 4.99, stray=[4242]),
        ],
    )
    walls = (6.61, 5.80, 8.83, 6.2, 7.0) if variant != "fast-machine" else (3.1, 2.9, 3.3, 3.0, 3.2)
    st.lockstep = [
        LockstepRun(1000.0, w, 2.5, (9.0, 11.0), 0.45, 0, [], "", 0.04 + 0.04 * k)
        for k, w in enumerate(walls)
    ]
    if variant == "failures":
        st.lockstep[1] = LockstepRun(error="timed out after 180 s")
        st.lateness[0].error = "no lateness line"
        st.errors.append("lock-step run 2: timed out")
    return st


def _cli(variant: str) -> CliResults:
    res = CliResults(30, load_average="0.95 / 0.98", speed_reference_ms=21.6)
    if variant == "fast-machine":
        res.speed_reference_ms = 9.0
    setpoint = CommandTimes("tankctl setpoint LIC1 0.4", ["tankctl", "setpoint", "LIC1", "0.4"])
    setpoint.samples_s, setpoint.cpu_s, setpoint.other_cores = (
        _samples(1.09, 30, 0.05),
        _samples(1.04, 30, 0.05),
        0.0038,
    )
    status = CommandTimes("tankctl status", ["tankctl", "status"])
    status.samples_s, status.cpu_s, status.other_cores = (
        _samples(1.26, 30, 0.05),
        _samples(1.17, 30, 0.05),
        0.0012,
    )
    if variant == "failures":
        status.samples_s, status.cpu_s = [], []
        status.failures = ["exit 1: no answer"]
    res.commands = [setpoint, status]
    entries = [ImportEntry("tankctl.cli", 2000, 571000, 0)] + [
        ImportEntry(f"mod{k}", 1000 * k, 290000 // (k + 1), 1) for k in range(14)
    ]
    res.imports = [
        ImportProfile("tankctl.cli", entries, []),
        ImportProfile(
            "tankctl.simulate", [ImportEntry("tankctl.simulate", 10, 1148000, 0)], ["scipy.signal"]
        ),
    ]
    return res


def sample_cli(variant: str = "full") -> CliResults:
    """Section 9's results (operator commands at a section speed reference of 21.6 ms)."""
    return _cli(variant)


def sample_report(variant: str = "full") -> Report:
    """A :class:`Report` with every section filled; ``variant`` is one of :data:`VARIANTS`."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}")
    quick = variant == "quick"
    rep = Report(
        date="2026-12-02 04:25 UTC",
        command="python -m benchmarks.run --quick" if quick else "make bench",
        quick=quick,
        machine={"CPU": "AMD EPYC", "cores (os.cpu_count)": "2"},
        versions={"numpy": "2.4.6", "cvxpy": "1.9.3"},
        total_wall_s=34.0 * 60.0,
        settings={"MPC horizons": "10, 40, 160", "lock-step runs": "5"},
        speed_reference_ms=(18.6, 19.0),
    )
    if variant == "empty":
        rep.speed_reference_ms = (math.nan, math.nan)
        return rep
    if variant == "fast-machine":
        rep.speed_reference_ms = (9.0, 9.4)
    if variant == "failures":
        rep.speed_reference_ms = (math.nan, math.nan)
    n = 100 if quick else 400
    rep.mpc_alone = [_horizon(np_, n, False, variant) for np_ in (10, 40, 160)]
    rep.mpc_side = [_horizon(np_, n, True, variant) for np_ in ((10, 40) if quick else (10, 40, 160))]
    rep.mpc_profile = _spots("supervisor/mpc/controller", 0.5)
    rep.accuracy = [
        GuardResult("h1 +5 cm", "condensed", 400, (0.5012, 0.2011), (0.5010, 0.2012), {"SOLVED": 400}),
        GuardResult(
            "h1 +5 cm, rate 1e-6",
            "sparse",
            400,
            (0.6013, 0.1010),
            (0.6010, 0.1009),
            {"SOLVED": 399, "HELD": 1},
        ),
    ]
    rep.cosim = _cosim(variant)
    rep.stack = _stack(variant)
    from benchmarks import cli

    res = _cli(variant)
    rep.extra.append(cli.markdown(res))
    rep.extra_goals += cli.goals(res)
    rep.extra.append("## 7. Robustness\n\nSome text.\n")
    if variant == "failures":
        rep.errors.append("section security failed: RuntimeError: boom")
    return rep


def sample_restarts(safe_state: str | None = None) -> object:
    """A :class:`benchmarks.restarts.RestartsResult` of two rounds (or, with ``safe_state``, the
    PLC-alone run): deviations, phases, RLS moves, one lost setting per supervisor restart."""
    try:
        import benchmarks.restarts_report as rs
    except ImportError:  # the code before the split (the rendering check of that change)
        import benchmarks.restarts as rs  # type: ignore[no-redef]

    one_each = {"plant": 1, "plc": 1, "supervisor": 1}
    tiers = ["plc"] if safe_state is not None else ["plc", "plant", "supervisor"]
    out = rs.RestartsResult(restarts_per_tier=2, tiers=tiers, safe_state=safe_state, base=20100)
    for k in (1, 2):
        plc = rs.Restart("plc", k, 9.0 + k, 8.0 + k, [], [], dict(one_each), killed_at=1.0e9 + 100 * k)
        plc.deviation_m, plc.deviation_by_tank_m, plc.sp_deviation_m = 0.004 * k, (0.004 * k, 0.001), 0.005
        plc.pumps_stopped = k == 2
        plc.theta_change, plc.theta = 0.01 * k, ([1e-3, 1e-5, 0.0], [1.1e-3, 1e-5, 0.0])
        plc.pushes, plc.refusals = k, 1
        plc.phases_s = (4.6 + k, 0.3, 3.9)
        out.restarts.append(plc)
        if safe_state is None:
            out.restarts.append(rs.Restart("plant", k, 5.0, 4.0, [], [], dict(one_each)))
            sup = rs.Restart(
                "supervisor",
                k,
                7.0,
                6.0,
                ["Supervisor.Mode: 2 -> 1"],
                ["PLC.LIC2.Kp: 1 -> 2"],
                dict(one_each),
            )
            out.restarts.append(sup)
    out.baseline_m, out.theta_quiet_change, out.settle_s = 0.0007, 0.002, 95.0
    out.up_exit, out.wall_s, out.load = 0, 1800.0, (0.8, 1.1)
    return out
