"""The PLC program's alarms (plc_emulator.alarms): events from the scan, the trip alarm reset with
the interlock, acknowledge through the manager, the warm restart of their state."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest

from helpers import ROOT
from plc_emulator.program import PlcProgram, ScanInputs
from plc_emulator.publish import status_values
from plc_emulator.server import ModelUtc
from tanklab import paths
from tanklab.alarms import CallStatus, ConditionCall, Method
from tanklab.config import load_site

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
"""HH trips at 0.58 m on T1 and T2; switches H 0.558 m, L 0.031 m; deadband 2 % of 0.62 m."""


def scan(p: PlcProgram, levels: list[float]) -> list[tuple[str, str]]:
    p.scan(ScanInputs(p.next_scan_t_s, np.array(levels), np.ones(3, dtype=bool)))
    return [(e.condition.name, e.reason) for e in p.alarms.events]


def test_a_trip_raises_its_alarms_and_resets_with_the_interlock() -> None:
    p = PlcProgram(SITE, alarm_event_prefix=b"plc")
    assert scan(p, [0.3, 0.3, 0.3]) == []  # the first scan: IoFault's start value goes, no event
    assert status_values(p.status())[paths.plc.io_fault] is False
    # T1 >= 0.58 m: the interlock latches and both alarms raise, in the same scan
    assert scan(p, [0.59, 0.3, 0.3]) == [("T1Level", "active HighHigh"), ("T1Trip", "active")]
    published = status_values(p.status())
    assert published[paths.plc.interlock("T1")] is True and published[paths.plc.alarm("T1", "HH")] is True
    m = p.alarms.manager
    assert scan(p, [0.50, 0.3, 0.3]) == [("T1Level", "returned to normal")]
    assert m.condition("T1Trip").active  # latched with the interlock
    assert p.reset_interlocks() == ["T1"]
    assert scan(p, [0.50, 0.3, 0.3]) == [("T1Trip", "returned to normal")]
    trip = m.condition("T1Trip")
    assert trip.retain and not trip.acked and not trip.confirmed
    status, _ = m.call(ConditionCall("T1Trip", Method.ACKNOWLEDGE, "op", trip.latest_event_id), p.t_s)
    assert status is CallStatus.GOOD
    status, _ = m.call(ConditionCall("T1Trip", Method.CONFIRM, "op", trip.latest_event_id), p.t_s)
    assert status is CallStatus.GOOD and not trip.retain
    assert trip.latest is not None and trip.latest.event_id.startswith(b"plc")


def test_alarm_state_survives_a_warm_restart() -> None:
    a = PlcProgram(SITE)
    scan(a, [0.3, 0.3, 0.3])
    scan(a, [0.56, 0.3, 0.3])  # T1 High
    t1 = a.alarms.manager.condition("T1Level")
    a.alarms.manager.call(ConditionCall("T1Level", Method.ACKNOWLEDGE, "op", t1.latest_event_id, "ok"), a.t_s)
    a.alarms.manager.call(ConditionCall("LIC2PvBad", Method.DISABLE, "eng"), a.t_s)
    b = PlcProgram(SITE)
    assert b.restore_retained(json.loads(json.dumps(a.retained()))) == []
    assert b.retained() == a.retained()
    assert scan(b, [0.56, 0.3, 0.3]) == []  # still High, still acknowledged: nothing new
    c = b.alarms.manager.condition("T1Level")
    assert (c.active, c.acked, c.comment) == (True, True, "ok")
    assert not b.alarms.manager.condition("LIC2PvBad").enabled
    bad = a.retained()
    bad["alarms"] = ["not", "a", "mapping"]
    assert PlcProgram(SITE).restore_retained(bad) == ["alarms: not a mapping"]


def test_model_utc_maps_model_time_to_the_anchored_scan_stamp_over_the_speed() -> None:
    stamp = datetime(2026, 1, 1, tzinfo=UTC)
    to_utc = ModelUtc(speed=20.0)
    to_utc.anchor(100.0, stamp)
    assert to_utc(100.0) == stamp
    assert to_utc(140.0) == stamp + timedelta(seconds=2.0)  # 40 model s at 20x: 2 wall s
    assert to_utc(80.0) == stamp - timedelta(seconds=1.0)
    to_utc.anchor(200.0, stamp + timedelta(seconds=3.0))  # the next scan batch re-anchors
    assert to_utc(200.0) == stamp + timedelta(seconds=3.0)
    with pytest.raises(ValueError, match="speed"):
        ModelUtc(speed=0.0)
