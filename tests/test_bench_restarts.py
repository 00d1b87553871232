"""The restart benchmark's pure parts and its /proc process count (benchmarks.restarts_report, .procs).

The measurement itself runs real stacks for half an hour (``python -m benchmarks.run --only
restarts``); here: which nodes it compares, how it scores an estimate's move, how it judges the
issue's targets, and that ``tankctl_pids`` finds exactly the processes named by their port.
"""

from __future__ import annotations

import subprocess
import sys

from benchmarks.restarts_report import (
    Restart,
    RestartsResult,
    box_change,
    goals,
    markdown,
    plc_phases,
    settings_paths,
)

from helpers import ROOT, free_port, stop_process, wait_until
from tanklab.config import load_site
from tanklab.tags import plant_tags, plc_tags, supervisor_tags, tags_by_path
from tanklab_testing.procs import tankctl_pids

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
TAGS = {
    "plant": tags_by_path(plant_tags(SITE)),
    "plc": tags_by_path(plc_tags(SITE)),
    "supervisor": tags_by_path(supervisor_tags(SITE)),
}
ONE_EACH = {"plant": 1, "plc": 1, "supervisor": 1}


def test_the_compared_nodes_are_every_operator_setting_and_the_retentive_state() -> None:
    paths = settings_paths(TAGS)
    plant = set(paths["plant"])
    # every node an operator writes on the plant; the pump commands are the PLC's
    assert {"Plant.T2.Leak", "Plant.V32.Opening", "Plant.T3.Disturbance", "Plant.LT3.Fault"} <= plant
    assert "Plant.LT3.FaultValue" in plant and not any(p.endswith(".Command") for p in plant)
    writable = {p for p, t in TAGS["plant"].items() if t.kind == "variable" and t.writable}
    assert writable - plant == {"Plant.P1.Command", "Plant.P2.Command"}
    plc = set(paths["plc"])
    for loop in ("LIC1", "LIC2"):
        assert {f"PLC.{loop}.{i}" for i in ("SP", "SPHigh", "Mode", "Kp", "GainSource")} <= plc
    assert any(p.startswith("PLC.Interlock.") for p in plc)
    assert paths["supervisor"] == ["Supervisor.Mode"]


def test_an_estimate_moves_as_a_fraction_of_the_gain_box() -> None:
    widths = [1.0e-2, 1.0e-3, 2.0e-2]
    assert box_change([1e-3, 1e-4, 0.0], [1e-3, 1e-4, 0.0], widths) == 0.0
    # Kd from 0 to 2e-3: a tenth of its box (a relative change would be infinite)
    assert abs((box_change([1e-3, 1e-4, 0.0], [1e-3, 1e-4, 2e-3], widths) or 0) - 0.1) < 1e-12
    assert box_change(None, [1.0], widths) is None and box_change([1.0], [1.0, 2.0], widths) is None


def _restart(tier: str, lost: list[str] | None = None, deviation_m: float | None = None) -> Restart:
    r = Restart(tier, 1, 9.0, 8.0, lost or [], [], dict(ONE_EACH))
    if deviation_m is not None:
        r.deviation_m, r.deviation_by_tank_m, r.pumps_stopped = deviation_m, (deviation_m, 0.0), True
    return r


def test_the_targets_are_judged_on_every_restart() -> None:
    clean = RestartsResult(restarts_per_tier=1)
    clean.restarts = [_restart("plc", deviation_m=0.001), _restart("plant"), _restart("supervisor")]
    assert [g.met for g in goals(clean)] == [True, True, True]
    bad = RestartsResult(restarts_per_tier=1, left_after_stop=[12345])
    bad.restarts = [
        _restart("plc", deviation_m=0.009),
        _restart("plant"),
        _restart("supervisor", ["Supervisor.Mode: 2 -> 1"]),
    ]
    assert [g.met for g in goals(bad)] == [False, False, False]
    text = markdown(bad)
    assert "Settings lost: **1**" in text and "supervisor: Supervisor.Mode (1x)" in text
    assert "**1** tankctl processes left" in text
    # a run that did not complete every restart cannot claim "0 lost"
    short = RestartsResult(restarts_per_tier=2)
    short.restarts = clean.restarts
    assert goals(short)[0].met is None


async def test_tankctl_pids_counts_the_processes_named_by_their_port() -> None:
    port = free_port()
    # A real process whose arguments read like a tier's (`... tankctl ... --port N`).
    argv = [sys.executable, "-c", "import signal; signal.pause()", "tankctl", "plc", "--port", str(port)]
    proc = subprocess.Popen(argv, text=True)
    try:
        await wait_until(lambda: tankctl_pids([port]).get(port) == [proc.pid], 10, what="the process seen")
        assert tankctl_pids([port + 1]) == {}
        assert tankctl_pids([port], flags=("--base-port",)) == {}
    finally:
        stop_process(proc)
    assert tankctl_pids([port]) == {}


def test_a_plc_restart_gap_is_split_into_phases_from_its_log() -> None:
    from datetime import datetime

    killed = datetime(2026, 12, 1, 23, 44, 28, 500000).timestamp()
    log = "\n".join(
        [
            "2026-12-01 23:44:20,000 INFO plc_emulator.runtime: warm restart from x at scan 1, t = 0.0 s",
            "2026-12-01 23:44:33,100 INFO plc_emulator.runtime: warm restart from x at scan 157, t = 156.0 s",
            "2026-12-01 23:44:33,350 plc_emulator.runtime: warm restart: resumed from the plant",
            "2026-12-01 23:44:33,400 plc_emulator.runtime: warm restart: pump commands held (plant ...)",
            "2026-12-01 23:44:37,300 INFO plc_emulator.server: PLC server listening at opc.tcp://h:1/tanklab/plc",
        ]
    )
    result = RestartsResult(restarts=[Restart("plc", 1, 9.0, 8.8, [], [], dict(ONE_EACH), killed_at=killed)])
    plc_phases(result, log)
    phases = result.restarts[0].phases_s
    assert phases is not None
    assert [round(p, 3) for p in phases] == [4.6, 0.3, 3.9]
    assert "PLC restart's gap" in markdown(result)
