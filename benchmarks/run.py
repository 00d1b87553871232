"""Run every benchmark side by side and write ``docs/benchmarks.md``.

Usage::

    python -m benchmarks.run              # full run (about 10 minutes on 2 cores)
    python -m benchmarks.run --quick      # fast pass, writes var/benchmarks-quick.md
    python -m benchmarks.run --only mpc,cosim --output /tmp/b.md
    python -m benchmarks.run --only cli --output /tmp/cli.md   # operator commands only (~2 min)

Sections: ``mpc`` (MPC step time against cvxpy and do-mpc), ``cosim`` (co-simulation speed and
hot spots), ``stack`` (OPC UA round trip, setpoint-to-action, PLC scan lateness, lock-step speed
through real processes), ``robustness``, ``security``, ``cli`` (operator command wall time
and the CLI's import cost), ``restarts`` (each tier SIGKILLed 20 times under ``tankctl up`` at
speed 1: settings lost, level deviation, restart time, processes left), ``historian-store`` (the
historian's SQLite and PostgreSQL stores: ingest per core, a day read back in pages, bytes per
value; ~2 min), ``historian-read`` (a day of one tag at 1 s read through HistoryRead from a
real asyncua server, raw and as a 60 s Average; ~1 min), ``alarms`` (issue 15's alarm flood:
the most conditions a site raises in one scan, acknowledged by one client, through real plant
and PLC processes at a 1 s scan: overruns, scan durations, events/s), ``sweep``, ``hmi`` (issue
17: value change to DOM update in headless Chromium, p50/p99, browser and HMI server CPU at 1 and
20 clients, a real stack at speed 1; ~4 min), ``plugin`` (the shipped MPC's cycle direct and
through the supervisory-controller interface, interleaved). Progress goes to stderr;
the document is written at the end. ``--only`` writes a document with those sections alone:
give it an ``--output`` to keep docs/benchmarks.md whole.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from benchmarks import (
    accuracy,
    alarms,
    cli,
    cosim,
    fdi,
    fleet,
    histread,
    histstore,
    hmi,
    mpc,
    plugin,
    report,
    restarts,
    restarts_report,
    robustness,
    security,
    stack,
    sweep,
)
from benchmarks.common import ROOT, machine, speed_reference, versions
from benchmarks.report import alarms_section
from tanklab_io.threads import limit_blas_threads

SECTIONS = (
    "mpc",
    "cosim",
    "stack",
    "robustness",
    "security",
    "cli",
    "restarts",
    "historian-store",
    "historian-read",
    "alarms",
    "sweep",
    "hmi",
    "plugin",
    "fdi",
    "fleet",
)


@dataclass(frozen=True)
class Plan:
    """How much of everything to measure."""

    horizons: tuple[int, ...]
    side_horizons: tuple[int, ...]
    mpc_duration_s: float
    cosim_repeats: int
    reads: int
    actions_x1: int
    actions_x20: int
    lateness_x1_s: float
    lateness_x20_s: float
    lockstep_runs: int
    realtime_x20_s: float
    cli_repeats: int
    alarm_rounds: int


FULL = Plan(
    horizons=(10, 20, 40, 80, 160),
    side_horizons=(10, 20, 40, 80, 160),
    mpc_duration_s=1000.0,
    cosim_repeats=5,
    reads=1000,
    actions_x1=40,
    actions_x20=50,
    lateness_x1_s=60.0,
    lateness_x20_s=30.0,
    lockstep_runs=5,
    realtime_x20_s=30.0,
    cli_repeats=30,
    alarm_rounds=alarms.ROUNDS,
)
QUICK = Plan(
    horizons=(10, 40, 160),
    side_horizons=(10, 40),
    mpc_duration_s=1000.0,
    cosim_repeats=2,
    reads=200,
    actions_x1=8,
    actions_x20=10,
    lateness_x1_s=10.0,
    lateness_x20_s=10.0,
    lockstep_runs=1,
    realtime_x20_s=10.0,
    cli_repeats=8,
    alarm_rounds=4,
)


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fast pass: shorter runs, fewer samples")
    parser.add_argument(
        "--output", type=Path, help="document to write (default docs/benchmarks.md, quick: var/)"
    )
    parser.add_argument(
        "--only", default=",".join(SECTIONS), help=f"comma-separated sections among {', '.join(SECTIONS)}"
    )
    args = parser.parse_args(argv)
    only = {s.strip() for s in args.only.split(",") if s.strip()}
    unknown = only - set(SECTIONS)
    if unknown:
        parser.error(f"unknown section(s): {', '.join(sorted(unknown))}")
    plan = QUICK if args.quick else FULL
    output: Path = args.output or (
        ROOT / "var" / "benchmarks-quick.md" if args.quick else ROOT / "docs" / "benchmarks.md"
    )
    # The benchmark's own OPC UA clients retry connections while tiers start: keep asyncua quiet.
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("asyncua").setLevel(logging.CRITICAL)
    logging.getLogger("tanklab_io.ua_client").setLevel(logging.ERROR)
    # as the tiers and `tankctl simulate` do (tanklab_io.threads): the comparators run on it too
    limit_blas_threads()

    started = time.perf_counter()
    speed_start = speed_reference()
    _log(f"machine speed reference: {speed_start:.1f} ms")
    command = "python -m benchmarks.run" + (" --quick" if args.quick else "")
    if only != set(SECTIONS):
        command += f" --only {','.join(s for s in SECTIONS if s in only)}"
    rep = report.Report(
        date=datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        command="make bench" if command == "python -m benchmarks.run" else command,
        quick=args.quick,
        machine=machine(),
        versions=versions(),
        settings={
            "MPC horizons": ", ".join(map(str, plan.horizons))
            + f" (side by side: {', '.join(map(str, plan.side_horizons))})",
            "MPC closed loop": f"{plan.mpc_duration_s:g} s ({plan.mpc_duration_s / 2.5:.0f} samples)",
            "co-simulation repeats": str(plan.cosim_repeats),
            "reads": str(plan.reads),
            "setpoint trials": f"{plan.actions_x1} at speed 1, {plan.actions_x20} at speed 20",
            "lateness windows": f"{plan.lateness_x1_s:g} s at speed 1, {plan.lateness_x20_s:g} s at speed 20",
            "lock-step runs": str(plan.lockstep_runs),
            "operator command runs": str(plan.cli_repeats),
            "alarm flood rounds": str(plan.alarm_rounds),
        },
    )
    comparators = [mpc.CVXPY_OSQP, mpc.CVXPY_OSQP_TIGHT, mpc.CVXPY_DEFAULT, mpc.DOMPC]

    def section(name: str, body: Callable[[], None]) -> None:
        """Run one section; a failure is reported in the document, and the others still run."""
        if name not in only:
            return
        try:
            body()
        except Exception as e:
            rep.errors.append(f"section {name} failed: {type(e).__name__}: {e}")
            _log(f"section {name} FAILED:\n{traceback.format_exc()}")

    def run_mpc() -> None:
        _log("MPC, the controller alone:")
        rep.mpc_alone = mpc.run(plan.horizons, plan.mpc_duration_s, [], _log)
        _log("MPC, side by side with cvxpy and do-mpc:")
        rep.mpc_side = mpc.run(plan.side_horizons, plan.mpc_duration_s, comparators, _log)
        profile_np = report.GOAL_NP if report.GOAL_NP in plan.horizons else plan.horizons[0]
        rep.mpc_profile = mpc.profile_steps(profile_np, plan.mpc_duration_s)
        rep.mpc_profile_np = profile_np
        _log("MPC accuracy guard (closed-loop IAE against CLARABEL):")
        rep.accuracy = accuracy.run(_log)

    def run_cosim() -> None:
        _log("co-simulation:")
        rep.cosim = cosim.run(plan.cosim_repeats, _log)

    def run_stack() -> None:
        _log("processes:")
        rep.stack = asyncio.run(
            stack.run_all(
                ROOT / "var" / "bench",
                reads=plan.reads,
                actions_x1=plan.actions_x1,
                actions_x20=plan.actions_x20,
                lateness_x1_s=plan.lateness_x1_s,
                lateness_x20_s=plan.lateness_x20_s,
                lockstep_runs=plan.lockstep_runs,
                realtime_x20_s=plan.realtime_x20_s,
                log=_log,
            )
        )

    def run_robustness() -> None:
        _log("randomized robustness scenarios:")
        result = robustness.random_scenarios(n=25 if args.quick else 100)
        rep.extra.append(robustness.markdown(result))
        if result["overflows"] or result["unexplained_overflows"]:
            rep.errors.append(
                f"robustness: {result['overflows']} overflows, {result['unexplained_overflows']} unexplained"
            )

    def run_security() -> None:
        _log("security robustness (fuzz, flood, freeze and crash, idle sockets):")
        rep.extra.append(security.markdown(security.run_all(full=not args.quick)))

    def run_cli() -> None:
        _log("operator commands and the CLI's import cost:")
        result = cli.run(ROOT / "var" / "bench", plan.cli_repeats, _log)
        rep.extra.append(cli.markdown(result))
        rep.extra_goals += cli.goals(result)
        rep.errors += [f"cli: {e}" for e in result.errors]

    section("mpc", run_mpc)
    section("cosim", run_cosim)
    section("stack", run_stack)
    section("robustness", run_robustness)

    def run_restarts() -> None:
        _log("restarts (each tier SIGKILLed under tankctl up at speed 1):")
        n = 5 if args.quick else restarts_report.RESTARTS
        result = asyncio.run(restarts.run(ROOT / "var" / "bench-restarts", _log, n))
        rep.extra_goals += restarts_report.goals(result)
        rep.errors += [f"restarts: {e}" for e in result.errors]
        _log("restarts, the PLC alone with every pump's watchdog safe state hold:")
        hold = asyncio.run(
            restarts.run(ROOT / "var" / "bench-restarts-hold", _log, n, tiers=("plc",), safe_state="hold")
        )
        rep.errors += [f"restarts (hold): {e}" for e in hold.errors]
        rep.extra.append(restarts_report.markdown(result).rstrip() + "\n\n" + restarts_report.markdown(hold))

    section("security", run_security)
    section("cli", run_cli)
    section("restarts", run_restarts)

    def run_histstore() -> None:
        _log("historian storage (SQLite and a throw-away PostgreSQL 15):")
        result = histstore.run(_log)
        rep.extra.append(histstore.markdown(result))
        rep.extra_goals += histstore.goals(result)
        rep.errors += [f"historian-store: {e}" for e in result.errors]

    section("historian-store", run_histstore)

    def run_histread() -> None:
        _log("historian reads through HistoryRead (a day of one tag, raw and Average 60 s):")
        result = histread.run(_log)
        rep.extra.append(histread.markdown(result))
        rep.extra_goals += histread.goals(result)
        rep.errors += [f"historian-read: {e}" for e in result.errors]

    section("historian-read", run_histread)

    def run_alarms() -> None:
        _log("alarm flood (conditions raised in one scan, one client acknowledging all, 1 s scan):")
        result = asyncio.run(alarms.run(ROOT / "var" / "bench-alarms", _log, plan.alarm_rounds))
        rep.extra.append(alarms_section.markdown(result))
        rep.extra_goals += alarms_section.goals(result)
        rep.errors += [f"alarms: {e}" for e in result.errors]
        if result.left:
            rep.errors.append(f"alarms: tankctl processes left on the stack's ports: {result.left}")

    section("alarms", run_alarms)

    def run_sweep() -> None:
        _log("scenario sweeps on Dask (1 and 2 local workers; the 1,000-case Energies sweep):")
        result = sweep.run(_log, quick=args.quick)
        rep.extra.append(sweep.markdown(result))
        rep.extra_goals += sweep.goals(result)
        rep.errors += result.errors

    section("sweep", run_sweep)

    def run_hmi() -> None:
        _log(
            "HMI (value change to DOM update in headless Chromium; browser and server CPU, 1 and 20 clients):"
        )
        window_s = hmi.QUICK_WINDOW_S if args.quick else hmi.WINDOW_S
        result = asyncio.run(hmi.run(ROOT / "var" / "bench-hmi", _log, window_s))
        rep.extra.append(hmi.markdown(result))
        rep.extra_goals += hmi.goals(result)
        rep.errors += [f"hmi: {e}" for e in result.errors]
        if result.left:
            rep.errors.append(f"hmi: tankctl processes left on the stack's ports: {result.left}")

    section("hmi", run_hmi)

    def run_plugin() -> None:
        _log("the supervisory-controller interface: the shipped MPC direct and through it, interleaved:")
        result = plugin.run(_log, duration_s=200.0 if args.quick else 600.0, rounds=1 if args.quick else 3)
        rep.extra.append(plugin.markdown(result))
        rep.extra_goals += plugin.goals(result)
        rep.errors += result.errors

    section("plugin", run_plugin)

    def run_fdi() -> None:
        _log("fault detection and isolation (seeded Monte Carlo through the co-simulation):")
        result = fdi.run(_log, quick=args.quick)
        rep.extra.append(fdi.markdown(result))
        rep.extra_goals += fdi.goals(result)

    section("fdi", run_fdi)

    def run_fleet() -> None:
        _log("fleets of live sites (tankctl fleet up at a 1 s scan):")
        ns = (10,) if args.quick else fleet.DEFAULT_NS
        rep.extra.append(fleet.run(ns, 60.0 if args.quick else 600.0, _log))

    section("fleet", run_fleet)
    rep.speed_reference_ms = (speed_start, speed_reference())
    _log(f"machine speed reference at the end: {rep.speed_reference_ms[1]:.1f} ms")
    rep.total_wall_s = time.perf_counter() - started
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(report.render(rep), encoding="utf-8")
    _log(f"wrote {output} ({rep.total_wall_s / 60:.1f} min)")
    for goal in report.goals(rep):
        _log(f"  {goal.verdict:>14s}  {goal.name}: {goal.measured} (target {goal.target})")
    errors = list(rep.errors)
    if rep.stack is not None:
        errors += rep.stack.errors + [f"lock-step run: {r.error}" for r in rep.stack.lockstep if r.error]
    for err in errors:
        _log(f"  error: {err}")
    return 1 if errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
