"""The series that the historian's read tests serve and check by hand: TAG, N values one
second apart from T0, ``level(k)``, every 100th one (k % 100 == 50) BadNoCommunication
(tests/historian/conftest.py's ``history_url``)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from tanklab.history.model import EventRecord

S = 1_000_000  # [us]
T0 = 1_764_633_600_000_000  # 2025-12-02 00:00 UTC [us]
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
TAG = "PLC.LIC1.PV"
N = 2_500  # 2.5 pages of node-opcua's 1,000 values


def iso(t_us: int) -> str:
    """As JavaScript's Date.toISOString writes it (milliseconds, Z)."""
    return (EPOCH + timedelta(microseconds=t_us)).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def level(k: int) -> float:
    """The recorded series: a ramp, 0.1 m + 1 mm per second [m]."""
    return 0.1 + 0.001 * k


BAD_CODE = 0x8031_0000
"""BadNoCommunication, the status of every k with k % 100 == 50."""


def is_bad(k: int) -> bool:
    return k % 100 == 50


EVENTS = (
    EventRecord(T0 + 10 * S, b"\x01" * 16, "i=9482", "PLC.T1.Level", 700, "T1 level high", {}),
    EventRecord(T0 + 20 * S, b"\x02" * 16, "i=2052", "PLC", 100, "setpoint LIC1 written", {}),
    EventRecord(T0 + 30 * S, b"\x03" * 16, "i=9482", "PLC.T1.Level", 300, "T1 level normal", {}),
)
"""Three recorded events: an ExclusiveLevelAlarm raised and cleared, an audit event between."""
