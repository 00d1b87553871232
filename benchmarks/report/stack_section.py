"""Sections 3-6 of the document, measured through real processes: OPC UA round trip,
setpoint-to-action latency, PLC scan lateness and lock-step speed."""

from __future__ import annotations

import math
from collections.abc import Sequence

from benchmarks.common import Summary, fmt
from benchmarks.report.base import Report, cores_cell, in_ms, table
from benchmarks.stack import Lateness, StackResults


def _summary_cells(samples_s: Sequence[float]) -> list[str]:
    s = in_ms(Summary.of(samples_s))
    return [str(s.n), fmt(s.median), fmt(s.p99), fmt(s.maximum)]


def stack_section(rep: Report) -> list[str]:
    st = rep.stack
    if st is None:
        return []
    lines = [
        "## 3. OPC UA round trip",
        "",
        "One client (`tanklab_io.ua_client.Link`, the tiers' own client) against a real PLC process scanning "
        "at speed 1 (with its plant process), loopback, back-to-back Reads after 20 warm-up Reads.",
        "",
    ]
    rows = [[rt.label, str(rt.nodes), *_summary_cells(rt.samples_s)] for rt in st.round_trips]
    lines += table(["Read", "nodes", "n", "median [ms]", "p99 [ms]", "max [ms]"], rows)
    lines += [
        "## 4. Setpoint-to-action latency",
        "",
        "Plant and PLC processes (realtime). A client writes `PLC.LIC1.SP` alternately to 0.6 m and "
        "0 m after a random wait of up to one scan period, so the write lands at a random phase of "
        "the scan; two other clients poll `PLC.LIC1.MV` and the plant's `Plant.P1.Command` back to "
        "back until each has moved by a quarter of the pump's range the expected way (the PID swings "
        "across its range in one scan; noise moves it by ~1e-3 of that). Latency = reply showing "
        "the change - write sent; it is dominated by the wait for the next scan (uniform over one "
        "scan period), so the median is about half a period. Resolution: one Read (~0.3 ms).",
        "",
    ]
    rows = []
    for a in st.actions:
        w = in_ms(Summary.of(a.write_s))
        mv = in_ms(Summary.of(a.mv_s))
        cmd = in_ms(Summary.of(a.command_s))
        rows.append(
            [
                f"{a.speed:g}",
                fmt(1e3 * a.scan_period_wall_s),
                str(cmd.n),
                f"{fmt(w.median)} / {fmt(w.p99)}",
                f"{fmt(mv.median)} / {fmt(mv.p99)}",
                f"{fmt(cmd.median)} / {fmt(cmd.p99)}",
                f"{fmt(cmd.minimum)} / {fmt(cmd.maximum)}",
                str(a.missed),
            ]
        )
    lines += table(
        [
            "speed",
            "scan period [ms wall]",
            "n",
            "SP Write round trip median / p99 [ms]",
            "SP -> PLC.LIC1.MV median / p99 [ms]",
            "SP -> Plant.P1.Command median / p99 [ms]",
            "SP -> command min / max [ms]",
            "missed",
        ],
        rows,
    )
    lines += [
        "## 5. PLC scan lateness",
        "",
        "Start lateness of each scan (start time - its deadline on the monotonic clock, `run_plc`), "
        "from the line the PLC logs on SIGTERM (`lateness p50 ... p99 ...`, 0.01 ms resolution). "
        "Plant + PLC processes with no client, then the whole stack under `tankctl up --speed 20` "
        "(supervisor in the config's ADVISORY mode, polling the PLC; its start-up is included).",
        "",
    ]
    rows = [
        [
            lat.label,
            fmt(lat.wall_s),
            str(lat.scans),
            str(lat.overruns),
            fmt(lat.p50_ms) if not math.isnan(lat.p50_ms) else "n/a",
            fmt(lat.p99_ms) if not math.isnan(lat.p99_ms) else "n/a",
            cores_cell(lat.other_cores),
            lat.error or ("stray processes killed: " + str(lat.stray) if lat.stray else ""),
        ]
        for lat in st.lateness
    ]
    lines += table(
        ["run", "wall [s]", "scans", "overruns", "p50 [ms]", "p99 [ms]", "other load [cores]", "note"],
        rows,
        "lrrrrrrl",
    )
    lines += [
        "## 6. Lock-step speed",
        "",
        "`tankctl up --config configs/three_tank_energies_sim.yaml --clock lockstep --no-board "
        "--base-port N` (N with three free ports in 20000-30000, a fresh log directory so no plant "
        "checkpoint is resumed). A client connects to the plant and the PLC while the stack starts "
        "(the run begins at the supervisor's first heartbeat), writes LIC1's setpoint +0.05 m when "
        "`Plant.Sim.Time` reaches 10 s (polling it back to back until then, every 50 ms after: "
        "light load on the plant); speed = model "
        "seconds / wall seconds between the first advance and 1000 s later. SIGTERM stops the "
        "stack; every child was checked gone.",
        "",
    ]
    rows = []
    for i, run in enumerate(st.lockstep, 1):
        if run.error:
            rows.append([str(i), "-", "-", "-", "-", "-", "-", "-", f"failed: {run.error}"])
            continue
        rows.append(
            [
                str(i),
                fmt(run.model_s),
                fmt(run.wall_s),
                fmt(run.speed),
                fmt(1000.0 / run.speed),
                f"{fmt(run.step_model_s[0])} / {fmt(run.step_model_s[1])}",
                fmt(run.startup_s),
                cores_cell(run.other_cores),
                f"exit {run.exit_code}; SP after {fmt(run.sp_after)} m"
                + (f"; stray killed {run.stray}" if run.stray else "; no stray process"),
            ]
        )
    lines += table(
        [
            "run",
            "model [s]",
            "wall [s]",
            "model s per wall s",
            "wall for 1000 s [s]",
            "model t before / after the SP write [s]",
            "launch to first advance [s]",
            "other load [cores]",
            "note",
        ],
        rows,
        "rrrrrrrrl",
    )
    if st.errors:
        lines += ["Failures in this section:", "", *[f"- {e}" for e in st.errors], ""]
    return lines


def lateness_of(st: StackResults | None, pred: str) -> Lateness | None:
    if st is None:
        return None
    return next((lat for lat in st.lateness if pred in lat.label), None)
