"""The whole document: header (machine, how to read it), goals, closing notes, then the sections
in order and the other modules' sections (:attr:`Report.extra`)."""

from __future__ import annotations

import math

from benchmarks.common import REFERENCE_SPEED_MS, Summary, fmt
from benchmarks.mpc import OURS
from benchmarks.report.base import Report, find, in_ms, table
from benchmarks.report.cosim_section import cosim_section
from benchmarks.report.goals import goals_section
from benchmarks.report.mpc_section import mpc_section
from benchmarks.report.stack_section import lateness_of, stack_section


def _header(rep: Report) -> list[str]:
    lines = [
        "# Benchmarks",
        "",
        f"Written by `{rep.command}` on {rep.date}"
        + (" (**quick pass**: shorter runs, fewer samples)" if rep.quick else "")
        + f"; the whole run took {fmt(rep.total_wall_s / 60.0, 2)} min of wall time. "
        "Do not edit: rerun `make bench` (about 15 minutes on 2 cores; "
        "`python -m benchmarks.run --quick` for a fast pass that writes `var/benchmarks-quick.md`).",
        "",
        "Every table comes from this one run. Times are wall-clock (`time.perf_counter`) unless the "
        "column says solver-reported; p99 is `numpy.percentile(..., 99)` (linear interpolation), so "
        "with n < 100 it lies between the two largest samples. The machine is shared with other "
        "sessions: the *other load* columns give the average number of cores that work outside this "
        "benchmark kept busy during each measurement (machine busy time from /proc/stat minus the "
        "CPU time of the benchmark's own processes); with 2 cores, anything above ~0.3 slows the "
        "multi-process measurements visibly.",
        "",
        "## Machine",
        "",
    ]
    lines += table(["", ""], [[k, v] for k, v in rep.machine.items()], "ll")
    lines += table(["package", "version"], [[k, v] for k, v in rep.versions.items()], "ll")
    if rep.settings:
        lines += ["Run settings: " + "; ".join(f"{k} {v}" for k, v in rep.settings.items()) + ".", ""]
    start, end = rep.speed_reference_ms
    if math.isfinite(start):
        lines += [
            f"Machine speed reference (`benchmarks.common.speed_reference`, a fixed CPU-bound "
            f"workload shaped like a co-simulation scan; lower is faster): {fmt(start)} ms at the "
            f"start of the run, {fmt(end)} ms at the end. This machine is shared and its speed "
            "drifts, by up to 40 % within a day and by 2x between days (8.6 ms one day, 18.6 ms "
            "another), so every goal on a time is stated at the reference speed, "
            f"{fmt(REFERENCE_SPEED_MS)} ms (`REFERENCE_SPEED_MS` in benchmarks/common.py; "
            "docs/decisions/0036-goals-at-reference-speed.md): a time is scaled by "
            f"{fmt(REFERENCE_SPEED_MS)} ms / the speed reference, a real-time factor by the speed "
            f"reference / {fmt(REFERENCE_SPEED_MS)} ms, with the speed reference measured closest "
            "to it (this run's at its start; section 9 measures its own). The MPC and "
            "co-simulation goals run in one process, like the reference; the lock-step and "
            "operator-command goals span several processes and also wait on OPC UA round trips "
            "and the scheduler, which the reference does not measure, so scaling them is an "
            "approximation: the goals table gives the measured number beside the scaled one, and "
            "the verdict is on the scaled one.",
            "",
        ]
    return lines


def _closing(rep: Report) -> list[str]:
    lines = ["## Closing notes", ""]
    parts = []
    for np_ in (10, 40, 160):
        r = find(rep.mpc_alone, np_)
        if r is not None:
            s = in_ms(r.series[OURS].wall)
            o = in_ms(r.series[OURS].solver)
            parts.append(
                f"Np = {np_}: {fmt(s.median)} / {fmt(s.p99)} ms "
                f"(solver alone {fmt(o.median)} / {fmt(o.p99)} ms)"
            )
    if parts:
        lines.append("- MPC step time, Kortela configuration, median / p99: " + "; ".join(parts) + ".")
    st = rep.stack
    items = []
    for speed, key in ((1, "processes, speed 1"), (20, "processes, speed 20")):
        lat = lateness_of(st, key)
        if lat is not None and not lat.error:
            items.append(f"speed {speed}: {fmt(lat.p50_ms)} / {fmt(lat.p99_ms)} ms ({lat.scans} scans)")
    if items:
        lines.append("- PLC scan lateness p50 / p99 (plant + PLC processes): " + "; ".join(items) + ".")
    if st is not None:
        runs = [r for r in st.lockstep if not r.error]
        if runs:
            sp = Summary.of([r.speed for r in runs])
            lines.append(
                f"- Lock-step speed: {fmt(sp.median)} model seconds per wall second (median of {sp.n}; "
                f"1000 s in {fmt(1000.0 / sp.median)} s)."
            )
    lat20 = lateness_of(st, "tankctl up")
    if lat20 is not None and not lat20.error:
        lines.append(
            f"- Realtime scan lateness at speed 20 (the whole stack, `tankctl up --speed 20`): p50 "
            f"{fmt(lat20.p50_ms)} ms, p99 {fmt(lat20.p99_ms)} ms, {lat20.overruns} overruns in "
            f"{lat20.scans} scans (scan period 50 ms of wall time)."
        )
    lines.append("")
    return lines


def render(rep: Report) -> str:
    lines = _header(rep) + goals_section(rep) + _closing(rep) + mpc_section(rep)
    lines += cosim_section(rep) + stack_section(rep)
    for block in rep.extra:
        lines += [block.rstrip(), ""]
    if rep.errors:
        lines += ["## Errors", "", *[f"- {e}" for e in rep.errors], ""]
    return "\n".join(lines).rstrip() + "\n"
