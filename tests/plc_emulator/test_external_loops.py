"""Loops handed to an external controller (decision 0055): the pure program's side.

``RemoteSource`` EXTERNAL puts a loop under ``PLC.External.Heartbeat``'s watchdog (same timeout
and rule as the supervisor's: 3 s of model time in the Energies config, Ts = 1 s), and out of the
supervisor's: a lost supervisor sheds only its own REMOTE loops, a lost external controller only
its. Hand-computed timelines in the comments; the shed is bumpless like the supervisor's.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from plc_emulator.program import PlcProgram, ScanInputs, ScanOutputs
from plc_emulator.publish import status_values
from plc_emulator.retain import retained
from tanklab.config import site_from_mapping
from tanklab.enums import LoopMode, RemoteSource

ROOT = Path(__file__).resolve().parents[2]
KI1 = 5.32e-6  # LIC1's fixed Ki (digest 2.1) [m^3/s per m s]
SPAN = 1.2e-4  # pump range [0, 1.2e-4] m^3/s

AUTO, REMOTE = LoopMode.AUTO, LoopMode.REMOTE
LEVELS = [0.399, 0.2, 0.3]  # LIC1: e1 = SP - PV = 0.4 - 0.399 = 0.001 m
U1 = 3.502e-5  # LIC1's equilibrium flow [m^3/s]


class Rig:
    """The Energies PLC program scanned at t = k Ts."""

    def __init__(self) -> None:
        data = yaml.safe_load((ROOT / "configs" / "three_tank_energies_sim.yaml").read_text())
        self.plc = PlcProgram(site_from_mapping(data))
        self.k = 0

    def scan(self, levels: Sequence[float]) -> ScanOutputs:
        lv = np.array(levels, dtype=float)
        out = self.plc.scan(ScanInputs(self.k * self.plc.ts_s, lv, np.ones(len(lv), dtype=bool)))
        self.k += 1
        return out


def published(out: ScanOutputs) -> dict[str, Any]:
    assert out.status is not None
    return status_values(out.status)


def mv(out: ScanOutputs, loop: str) -> float:
    value: float = published(out)[f"PLC.{loop}.MV"]
    return value


def _handed() -> Rig:
    """LIC1 handed to the external controller and in REMOTE at U1 (LIC2 the supervisor's, in REMOTE)."""
    rig = Rig()
    rig.plc.set_remote_source("LIC1", RemoteSource.EXTERNAL)
    rig.plc.set_mode("LIC1", REMOTE)
    rig.plc.set_mode("LIC2", REMOTE)
    return rig


def test_external_heartbeat_keeps_its_loop_and_its_loss_sheds_only_that_loop_bumplessly() -> None:
    rig = _handed()
    for k in range(5):  # t = 0 .. 4: both alive (heartbeats change every scan)
        rig.plc.external_heartbeat(k)
        rig.plc.heartbeat(100 + k)
        rig.plc.set_remote_mv("LIC1", U1)
        out = rig.scan(LEVELS)
        assert mv(out, "LIC1") == U1
        assert published(out)["PLC.External.Alive"] is True
    # The external heartbeat stops (last change at t = 4); the supervisor's goes on.
    for _ in range(2):  # t = 5, 6: 4 + 3 s not reached
        rig.plc.heartbeat(200 + rig.k)
        out = rig.scan(LEVELS)
        assert published(out)["PLC.LIC1.Mode"] == REMOTE
    rig.plc.heartbeat(300)
    out = rig.scan(LEVELS)  # t = 7: 7 - 4 >= 3, expired: LIC1 -> AUTO at its setpoint
    values = published(out)
    assert values["PLC.External.Alive"] is False
    assert values["PLC.LIC1.Mode"] == AUTO
    assert values["PLC.LIC2.Mode"] == REMOTE  # the supervisor's loop is not touched
    assert values["PLC.Supervisor.Alive"] is True
    # Bumpless: the AUTO move of the shedding scan is Ki Ts e = 5.32e-6 * 1 * 0.001 only.
    assert mv(out, "LIC1") - U1 == pytest.approx(KI1 * 0.001, rel=1e-6)
    assert abs(mv(out, "LIC1") - U1) <= 0.01 * SPAN


def test_a_lost_supervisor_does_not_shed_a_loop_handed_to_the_external_controller() -> None:
    rig = _handed()
    for k in range(8):  # no supervisor heartbeat at all: its grace period ends at t = 3
        rig.plc.external_heartbeat(k)
        out = rig.scan(LEVELS)
    values = published(out)
    assert values["PLC.Supervisor.Alive"] is False
    assert values["PLC.LIC2.Mode"] == AUTO  # shed at t = 3
    assert values["PLC.LIC1.Mode"] == REMOTE  # the external controller's, alive
    assert values["PLC.LIC1.RemoteSource"] == int(RemoteSource.EXTERNAL)


def test_without_an_external_heartbeat_its_loop_sheds_after_the_grace_period() -> None:
    rig = _handed()
    for _ in range(3):  # t = 0, 1, 2: the grace period counts from the first scan
        rig.plc.heartbeat(rig.k)
        assert published(rig.scan(LEVELS))["PLC.LIC1.Mode"] == REMOTE
    rig.plc.heartbeat(rig.k)
    assert published(rig.scan(LEVELS))["PLC.LIC1.Mode"] == AUTO  # t = 3


def test_remote_source_changes_only_outside_remote_and_is_retained() -> None:
    rig = _handed()
    with pytest.raises(ValueError, match="LIC1 is in REMOTE"):
        rig.plc.set_remote_source("LIC1", RemoteSource.SUPERVISOR)
    assert rig.plc.loop("LIC1").remote_source is RemoteSource.EXTERNAL  # nothing changed
    data = retained(rig.plc)
    assert data["loops"]["LIC1"]["remote_source"] == "EXTERNAL"
    assert data["loops"]["LIC2"]["remote_source"] == "SUPERVISOR"
    warm = Rig()
    assert warm.plc.restore_retained(data) == []
    assert warm.plc.loop("LIC1").remote_source is RemoteSource.EXTERNAL
    assert warm.plc.loop("LIC1").mode is REMOTE
    # A file of an earlier version (no remote_source) restores SUPERVISOR.
    del data["loops"]["LIC1"]["remote_source"]
    old = Rig()
    assert old.plc.restore_retained(data) == []
    assert old.plc.loop("LIC1").remote_source is RemoteSource.SUPERVISOR
    rig.plc.set_mode("LIC1", AUTO)
    rig.plc.set_remote_source("LIC1", RemoteSource.SUPERVISOR)
    assert rig.plc.loop("LIC1").remote_source is RemoteSource.SUPERVISOR
