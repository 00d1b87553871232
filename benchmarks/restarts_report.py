"""The restart benchmark's results, how they are judged and how section 10 renders them.

What :mod:`benchmarks.restarts` (the driver: a real ``tankctl up`` stack, its tiers SIGKILLed
round by round) records: one :class:`Restart` per kill and a :class:`RestartsResult` per run;
the nodes it compares (:func:`settings_paths`) and how it scores the RLS estimate's move
(:func:`box_change`). From those: the PLC restart's phases read from its log
(:func:`plc_phases`), issue 21's three targets (:func:`goals`) and the Markdown of section 10
(:func:`markdown`). Everything here is pure: values in, values out (``load_result`` reads a
run's ``result.json`` back).
"""

from __future__ import annotations

import json
import math
import os
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from benchmarks.common import Goal, fmt
from tanklab.tags import Tag

TIERS = ("plc", "plant", "supervisor")
"""The order of one round of kills."""
RESTARTS = 20
"""SIGKILLs per tier in a full run."""
POST_S = 10.0
"""How long the levels are still sampled after a restarted PLC is healthy again [s wall = s model]."""
QUIET_S = 20.0
"""The quiet window before the first kill: the level deviation and the RLS move without a kill [s]."""
DEVIATION_TARGET_M = 0.005
"""Issue 21's target for the largest level deviation during a PLC restart [m]."""


def settings_paths(site_tags: dict[str, dict[str, Tag]]) -> dict[str, list[str]]:
    """Per tier, the nodes compared before and after every restart: every writable variable of
    the plant (pump commands aside: the PLC's), every retentive PLC node (SP, limits, mode,
    manual MV, gains and their source) and the interlock latches, and the supervisor's mode."""
    plant = [
        p
        for p, t in site_tags["plant"].items()
        if t.kind == "variable" and t.writable and not p.endswith(".Command")
    ]
    loops = sorted({p.split(".")[1] for p in site_tags["plc"] if p.startswith("PLC.LIC")})
    items = ("SP", "SPLow", "SPHigh", "Mode", "ManualMV", "Kp", "Ki", "Kd", "GainSource")
    plc = [f"PLC.{lp}.{i}" for lp in loops for i in items]
    plc += [p for p, t in site_tags["plc"].items() if p.startswith("PLC.Interlock.") and t.kind == "variable"]
    return {"plant": plant, "plc": plc, "supervisor": ["Supervisor.Mode"]}


@dataclass
class Restart:
    """One SIGKILL and what followed."""

    tier: str
    index: int
    seconds: float
    """From the SIGKILL to the stack healthy again [s wall]."""
    tier_s: float
    """From the SIGKILL to the tier itself back (the PLC: scanning with its field link) [s wall]."""
    lost: list[str]
    """Settings whose value after the restart differs from before: ``path: before -> after``."""
    owned: list[str]
    """Supervisor-owned values that changed (by design: fallback or a new push)."""
    processes: dict[str, int]
    """tankctl processes per tier port right after the stack was healthy again."""
    deviation_m: float | None = None
    """PLC restarts: largest |level - pre-kill level| of T1 and T2 over the window [m]."""
    deviation_by_tank_m: tuple[float, float] | None = None
    sp_deviation_m: float | None = None
    """PLC restarts: largest |level - setpoint| of T1 and T2 over the window [m]."""
    pumps_stopped: bool = False
    """The plant's watchdog stopped the pumps during the window."""
    theta_change: float | None = None
    """PLC restarts: largest change of LIC2's RLS estimate over the window (fraction of the gain
    box's width)."""
    theta: tuple[list[float], list[float]] | None = None
    """PLC restarts: LIC2's RLS estimate just before the kill and at the window's end."""
    pushes: int = 0
    """Gain sets the supervisor had accepted on LIC2 during the window."""
    refusals: int = 0
    """Candidate gain sets rejected (by a guard or the PLC) on LIC2 during the window."""
    killed_at: float = float("nan")
    """Wall-clock time of the SIGKILL (``time.time()``, to find the restart in the tier's log)."""
    phases_s: tuple[float, float, float] | None = None
    """PLC restarts, from its log: SIGKILL -> "warm restart from" (up's poll, the interpreter's
    start, imports, config), -> "pump commands held" (field link, the read of the plant and the
    write that refreshes its watchdog, decision 0026), -> "PLC server listening" (its OPC UA
    server, before the first scan) [s]."""


@dataclass
class RestartsResult:
    restarts: list[Restart] = field(default_factory=list)
    baseline_m: float = float("nan")
    """Largest level deviation over a quiet window as long as a PLC restart's, before any kill [m]."""
    theta_quiet_change: float | None = None
    """Largest change of LIC2's RLS estimate over the quiet window (a baseline; box fraction)."""
    settle_s: float = float("nan")
    left_after_stop: list[int] = field(default_factory=list)
    pid_files_left: list[str] = field(default_factory=list)
    up_exit: int | None = None
    up_lines: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    base: int = 0
    restarts_per_tier: int = RESTARTS
    tiers: list[str] = field(default_factory=lambda: list(TIERS))
    safe_state: str | None = None
    """Every pump's watchdog safe state in this run (None: the shipped config's, ``off``)."""
    load: tuple[float, float] = (float("nan"), float("nan"))
    """The machine's 1-minute load average at the start and at the end (2 cores here)."""


def box_change(a: Sequence[float] | None, b: Sequence[float] | None, widths: Sequence[float]) -> float | None:
    """max_i |b_i - a_i| / width_i: how far an estimate [Kp, Ki, Kd, ...] moved, as a fraction of
    the gain box's width of each gain (a relative change would explode on a gain near 0)."""
    if not a or not b or len(a) != len(b):
        return None
    w = [widths[i % len(widths)] for i in range(len(a))]
    return max(abs(y - x) / wi for x, y, wi in zip(a, b, w, strict=True))


PHASE_MARKS = ("warm restart from", "warm restart: pump commands held", "PLC server listening")


def _stamp(line: str) -> float | None:
    """The wall time of a tier's log line (``%(asctime)s``: local time, milliseconds) [s epoch]."""
    try:
        return datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
    except ValueError:
        return None


def plc_phases(result: RestartsResult, log_text: str) -> None:
    """Fill each PLC restart's ``phases_s`` from the PLC's log: the first line of each phase
    after its SIGKILL."""
    marks = [(t, line) for line in log_text.splitlines() if (t := _stamp(line)) is not None]
    for r in result.restarts:
        if r.tier != "plc" or not math.isfinite(r.killed_at):
            continue
        at: list[float] = []
        t0 = r.killed_at
        for mark in PHASE_MARKS:
            t = next((t for t, line in marks if t >= t0 and mark in line), None)
            if t is None:
                break
            at.append(t)
            t0 = t
        if len(at) == 3:
            r.phases_s = (at[0] - r.killed_at, at[1] - at[0], at[2] - at[1])


def describe(r: Restart) -> str:
    """One progress line for a restart."""
    line = f"  {r.tier} kill {r.index}: back after {r.tier_s:.1f} s, healthy after {r.seconds:.1f} s"
    line += f", lost {len(r.lost)}" + (f" ({'; '.join(r.lost)})" if r.lost else "")
    if r.deviation_by_tank_m is not None and r.sp_deviation_m is not None:
        t1, t2 = (1e3 * d for d in r.deviation_by_tank_m)
        line += f", level deviation T1 {t1:.2f} T2 {t2:.2f} mm (from SP {1e3 * r.sp_deviation_m:.2f} mm)"
        line += f", theta change {fmt(r.theta_change or 0.0)}, pushes {r.pushes}, refused {r.refusals}"
        line += ", pumps stopped by the watchdog" if r.pumps_stopped else ""
    return line + f"; processes {r.processes}"


def goals(result: RestartsResult) -> list[Goal]:
    """Issue 21's three targets for the restarts."""
    n = {t: sum(r.tier == t for r in result.restarts) for t in TIERS}
    done = ", ".join(f"{t} {k}" for t, k in n.items())
    lost = [r for r in result.restarts if r.lost]
    devs = [r.deviation_m for r in result.restarts if r.deviation_m is not None]
    complete = not result.errors and all(k == result.restarts_per_tier for k in n.values())
    worst = max(devs) if devs else float("nan")
    over = sum(d > DEVIATION_TARGET_M for d in devs)
    stopped = sum(
        r.pumps_stopped
        for r in result.restarts
        if r.deviation_m is not None and r.deviation_m > DEVIATION_TARGET_M
    )
    tiers_lost = sorted({r.tier for r in lost})
    return [
        Goal(
            f"settings lost over {result.restarts_per_tier} SIGKILL restarts per tier (speed 1)",
            "0",
            f"{sum(len(r.lost) for r in result.restarts)} (restarts: {done})",
            (not lost) if complete else None,
            f"lost on {', '.join(tiers_lost)} restarts (section 10)" if lost else "",
        ),
        Goal(
            "largest level deviation during a PLC restart",
            "<= 5 mm",
            f"{fmt(1e3 * worst)} mm ({over} of {len(devs)} over)",
            (worst <= DEVIATION_TARGET_M) if devs else None,
            f"{stopped} of the {over} over had the plant's watchdog stop the pumps (section 10)"
            if over
            else "",
        ),
        Goal(
            "tankctl processes left after the stop; one per tier after every restart",
            "0; 1",
            f"{len(result.left_after_stop)}; "
            + (
                "1 each" if all(set(r.processes.values()) == {1} for r in result.restarts) else "not always 1"
            ),
            not result.left_after_stop and all(set(r.processes.values()) == {1} for r in result.restarts),
        ),
    ]


def _summary(values: Sequence[float]) -> str:
    if not values:
        return "-"
    return f"{fmt(statistics.median(values))} / {fmt(max(values))}"


def markdown(result: RestartsResult) -> str:
    """The section of docs/benchmarks.md."""
    by_tier = {t: [r for r in result.restarts if r.tier == t] for t in result.tiers}
    plc = by_tier.get("plc", [])
    devs = [1e3 * r.deviation_m for r in plc if r.deviation_m is not None]
    if result.safe_state is not None:
        lines = [
            f"### 10b. The PLC alone, every pump's watchdog safe state `{result.safe_state}`",
            "",
            f"The same stack, settings and waits with `plant.pumps[].watchdog_safe_state: "
            f"{result.safe_state}` (decision 0019's remedy for a PLC restart gap longer than the "
            f"plant's command timeout); each round kills only the {', '.join(result.tiers)}.",
        ]
    else:
        lines = [
            "## 10. Restarts under a running stack (`tankctl up`, speed 1)",
            "",
            "`benchmarks.restarts` (`python -m benchmarks.run --only restarts`): `tankctl up --speed 1` "
            "on the three-tank Energies site (a copy of `configs/three_tank_energies_sim.yaml` starting "
            f"at the operating point, `stack.restart: true`, `max_restarts: {result.restarts_per_tier}`; "
            "the plant's watchdog keeps the shipped safe state `off`, 10 s). Settings applied through "
            "OPC UA as the engineer before the first kill: T2 leak 0.1, V32 opening 0.8, T3 disturbance "
            "2e-6 m^3/s, a 5 mm BIAS fault on LT3, setpoints 0.405 / 0.205 m, LIC2 SPHigh 0.5 m, engineer "
            "gains on LIC1, the supervisor in ADAPTIVE_PID adapting LIC2; no scenario file (the benchmark "
            "drives the settings itself). Each round SIGKILLs the PLC, the plant and the supervisor, one "
            "at a time (the pid in `up`'s pid file), waits for `up` to restart it and for the stack to be "
            "healthy (the tier answers, the PLC's IO is healthy, PLC and supervisor linked), then compares "
            "every compared node (the plant's writable nodes, the PLC's retentive nodes and interlock "
            "latches, `Supervisor.Mode`) with its value before the kill.",
        ]
    lines += [
        "",
        "| tier | restarts | settings lost | kill -> tier back, median / max [s] "
        "| kill -> stack healthy, median / max [s] | processes per tier after each restart "
        "| supervisor-owned changes |",
        "|---|---|---|---|---|---|---|",
    ]
    for tier, rs in by_tier.items():
        procs = sorted({tuple(sorted(r.processes.items())) for r in rs})
        proc_text = "; ".join(", ".join(f"{t} {n}" for t, n in p) for p in procs) or "-"
        lines.append(
            f"| {tier} | {len(rs)} | {sum(len(r.lost) for r in rs)} | {_summary([r.tier_s for r in rs])} "
            f"| {_summary([r.seconds for r in rs])} "
            f"| {proc_text} | {sum(len(r.owned) for r in rs)} |"
        )
    lost = [f"{r.tier} kill {r.index}: {x}" for r in result.restarts for x in r.lost]
    kinds: dict[str, int] = {}
    for r in result.restarts:
        for x in r.lost:
            key = f"{r.tier}: {x.split(':')[0]}"
            kinds[key] = kinds.get(key, 0) + 1
    stopped = sum(r.pumps_stopped for r in plc)
    lines += [
        "",
        f"PLC restarts: largest deviation of T1 or T2 from its level just before the kill, from the kill "
        f"until {POST_S:g} s after the PLC is healthy again, median / max **{_summary(devs)} mm** "
        f"(target <= {1e3 * DEVIATION_TARGET_M:g} mm; {sum(d > 1e3 * DEVIATION_TARGET_M for d in devs)} of "
        f"{len(devs)} over); the plant's watchdog stopped the pumps in {stopped} of {len(plc)}. A quiet "
        f"20 s window before the first kill: {1e3 * result.baseline_m:.2f} mm. Once the PLC has been "
        "away for the plant's command timeout (10 s) the watchdog puts the pumps in their safe state; "
        "with `off`, T1 then falls by its outflow alone, about 2 mm/s here (Q1 about 3.0e-5 m^3/s over "
        "0.0154 m^2), so a gap 3 s longer than the timeout already costs about 5 mm.",
        "",
        f"Settings lost: **{len(lost)}** in {len(result.restarts)} restarts"
        + (": " + ", ".join(f"{k} ({n}x)" for k, n in sorted(kinds.items())) if kinds else "")
        + ".",
        f"After the final SIGTERM of `up` (exit {result.up_exit}): **{len(result.left_after_stop)}** "
        f"tankctl processes left on the stack's ports, pid files left: "
        f"{', '.join(result.pid_files_left) or 'none'}.",
        "",
    ]
    phases = [r.phases_s for r in plc if r.phases_s is not None]
    if phases:
        start, link, serve = ([p[i] for p in phases] for i in range(3))
        held = [a + b for a, b in zip(start, link, strict=True)]
        gap = [sum(p) for p in phases]
        lines += [
            "Where a PLC restart's gap goes (its log; median / max, s): from the SIGKILL to "
            f"\"warm restart from\" (`up`'s 1 s poll, the interpreter's start, imports, config) "
            f"{_summary(start)}; the field link, the read of the plant and the write-back that "
            f'refreshes its watchdog ("pump commands held", decision 0026) {_summary(link)}; its OPC '
            f'UA server until "listening", before the first scan, {_summary(serve)}; total '
            f"{_summary(gap)}. The pumps were held {_summary(held)} after the SIGKILL "
            f"({sum(h > 10.0 for h in held)} of {len(held)} later than the plant's 10 s command timeout).",
            "",
        ]
    thetas = [r.theta_change for r in plc if r.theta_change is not None]
    if thetas:
        off = [r.theta_change for r in plc if r.theta_change is not None and r.pumps_stopped]
        on = [r.theta_change for r in plc if r.theta_change is not None and not r.pumps_stopped]
        quiet = float("nan") if result.theta_quiet_change is None else result.theta_quiet_change
        lines += [
            "RLS across a PLC restart (the supervisor stays up, ADAPTIVE_PID on LIC2): largest change "
            "of a gain in `Supervisor.RLS.LIC2.Theta` over the restart window, as a fraction of LIC2's "
            f"gain-box width, median / max {_summary(thetas)}: {_summary(off)} over the {len(off)} "
            f"restarts whose gap let the watchdog stop the pumps, {_summary(on)} over the {len(on)} "
            f"others; {fmt(quiet)} over the quiet {QUIET_S:g} s "
            f"window before the first kill. Gain sets accepted on LIC2 during the windows "
            f"{sum(r.pushes for r in plc)}, refused {sum(r.refusals for r in plc)} (a restarted PLC "
            "refuses the supervisor's SetGains until it trusts the supervisor again, "
            "`watchdog.good_scans_to_accept`). The scan counter continues across a warm restart, so "
            "the adapter (`PidGainAdapter.observe`) forms a sample whose window spans the restart "
            "when the new PLC's first scan follows the last one the supervisor read, or repeats it "
            "(a SIGKILL lost the last retentive write: the repeat is ignored as a duplicate and the "
            "next scan is consecutive); it drops the window as a gap only when two or more writes "
            "were lost. The published nodes cannot separate that one sample from the recovery's "
            "ordinary samples that follow it.",
            "",
        ]
    if any("Supervisor.Mode" in x for r in result.restarts for x in r.lost):
        lines += [
            "`Supervisor.Mode` is not retentive: a restarted supervisor starts in its config's mode "
            "(here ADVISORY), so the engineer's ADAPTIVE_PID is lost at every supervisor restart; "
            "the benchmark writes it again after counting it. LIC2's gains then fall back (the "
            "PLC's supervisor watchdog) and are the supervisor's again after its next push: those "
            "are the supervisor-owned changes, not settings.",
            "",
        ]
    if result.errors:
        lines += [f"Errors: {'; '.join(result.errors)}", ""]
    lines.append(
        f"Wall time {result.wall_s / 60:.1f} min (settling {result.settle_s:.0f} s); the machine's 1-minute "
        f"load average {result.load[0]:.1f} at the start, {result.load[1]:.1f} at the end ({os.cpu_count()} "
        "cores; other sessions' work included)."
    )
    lines.append("")
    return "\n".join(lines)


def load_result(path: Path) -> RestartsResult:
    """A run's ``result.json`` back as a :class:`RestartsResult` (to render it again)."""
    data = json.loads(path.read_text(encoding="utf-8"))
    restarts = [Restart(**r) for r in data.pop("restarts")]
    for r in restarts:
        r.deviation_by_tank_m = tuple(r.deviation_by_tank_m) if r.deviation_by_tank_m else None  # type: ignore[assignment]
        r.phases_s = tuple(r.phases_s) if r.phases_s else None  # type: ignore[assignment]
    data["load"] = tuple(data["load"])
    return RestartsResult(restarts=restarts, **data)
