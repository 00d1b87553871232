"""The historian's records: one sample of a tag, one event (pure value types).

A **tag** is a node's string identifier in the site namespace (``urn:tanklab``), as the tiers
publish it: ``PLC.LIC1.PV``, ``Plant.LT1.PV``, ``Supervisor.Mode``. The historian's server mirrors
these NodeIds, so a tag names the same thing at a tier's endpoint and at the historian's
(architecture, "History").

Times are UTC **microseconds since 1970-01-01** (``*_us``, int): the resolution of PostgreSQL's
``timestamptz``, exact in SQLite's INTEGER, and finer than any tier's publishing. OPC UA's
DateTime (100 ns ticks since 1601) converts exactly at the service edge:
``ticks = t_us * 10 + EPOCH_OFFSET_TICKS``, with ``EPOCH_OFFSET_TICKS = 116_444_736_000_000_000``.
A sample's time is the **source timestamp** the tier published (the scan's stamp), not the time
the historian received it.

Status codes are the OPC UA StatusCode as published (uint32; ``0`` is Good; the top two bits are
the severity: ``0b10`` Bad, ``0b01`` Uncertain, OPC UA Part 4, 7.39).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "EPOCH_OFFSET_TICKS",
    "STATUS_GOOD",
    "EventRecord",
    "Sample",
    "is_bad",
    "is_good",
    "is_uncertain",
]

EPOCH_OFFSET_TICKS = 116_444_736_000_000_000
"""OPC UA DateTime ticks (100 ns since 1601-01-01 UTC) at 1970-01-01 UTC."""

STATUS_GOOD = 0
_SEVERITY_MASK = 0xC000_0000
_BAD = 0x8000_0000
_UNCERTAIN = 0x4000_0000

Value = float | int | bool | str | None
"""What a tag holds: analog values are floats, enumerations ints, flags bools, text str; ``None``
only with a Bad status (no value, e.g. a gap the historian marks)."""


class Sample(NamedTuple):
    """One recorded value of one tag."""

    t_us: int
    """Source timestamp, UTC microseconds since 1970-01-01."""
    value: Value
    status: int = STATUS_GOOD
    """OPC UA StatusCode as published (uint32)."""


class EventRecord(NamedTuple):
    """One recorded event (a condition's state change or an audit event)."""

    t_us: int
    """The event's Time, UTC microseconds since 1970-01-01."""
    event_id: bytes
    """The event's EventId (unique per event, Part 9)."""
    event_type: str
    """The event type's NodeId as a string, e.g. ``i=9482`` (ExclusiveLevelAlarmType)."""
    source: str
    """The SourceName, e.g. ``PLC.T1.Level``."""
    severity: int
    """1..1000 (Part 5)."""
    message: str
    fields: dict[str, object]
    """Every other selected field by browse path (``ActiveState/Id``, ``ConditionName``...),
    JSON-serialisable values."""


def is_good(status: int) -> bool:
    """Severity Good (top two bits 00)."""
    return status & _SEVERITY_MASK == 0


def is_uncertain(status: int) -> bool:
    """Severity Uncertain (top two bits 01)."""
    return status & _SEVERITY_MASK == _UNCERTAIN


def is_bad(status: int) -> bool:
    """Severity Bad (top bit set)."""
    return status & _BAD != 0
