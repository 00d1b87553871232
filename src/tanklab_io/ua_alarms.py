"""Alarm conditions as a client reads them: the state fields of a Part 9 condition, their
NodeIds, and one row per condition from one Read (issue 15).

The PLC's and the supervisor's alarms are OPC UA Part 9 conditions (docs/alarms.md):
``PLC.Conditions.<name>`` and ``Supervisor.Conditions.<name>`` (:func:`tanklab.paths.condition`),
their state variables its children (``<id>.AckedState.Id``), their methods too
(``<id>.Acknowledge``, ``<id>.ShelvingState.TimedShelve``). Pure: values keyed by NodeId string
in, rows out. Shared by the operator commands (:mod:`tankctl.ops.alarms`) and the HMI
(:mod:`hmi.hub`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from typing import Any

from asyncua import ua

from tanklab import paths
from tanklab.alarms.model import AlarmDefinition, ConditionKind, Priority, ShelvingState
from tanklab.tags import Tier

__all__ = [
    "LIMIT_FIELD",
    "STATE_FIELDS",
    "AlarmRow",
    "child",
    "condition_row",
    "condition_rows",
    "fields_of",
    "priority_name",
    "read_paths",
    "text_of",
]

STATE_FIELDS: tuple[str, ...] = (
    "EventId",
    "Severity",
    "Message",
    "Time",
    "Retain",
    "EnabledState/Id",
    "ActiveState/Id",
    "AckedState/Id",
    "ShelvingState/CurrentState",
)
"""The browse paths below a condition that ``tankctl alarms`` reads (Part 9 names)."""
LIMIT_FIELD = "LimitState/CurrentState"
"""Read only for an exclusive level alarm (the other kinds have no LimitState)."""


def child(name: str, field: str, tier: Tier = "plc") -> str:
    """The NodeId string of a condition's child (``PLC.Conditions.T1Level.AckedState.Id``,
    ``Supervisor.Conditions.PlcLinkLost.AckedState.Id``)."""
    return f"{paths.condition(tier, name)}.{field.replace('/', '.')}"


def fields_of(definition: AlarmDefinition) -> tuple[str, ...]:
    """The state fields read for one condition."""
    if definition.kind == ConditionKind.EXCLUSIVE_LEVEL:
        return (*STATE_FIELDS, LIMIT_FIELD)
    return STATE_FIELDS


def read_paths(definitions: Sequence[AlarmDefinition], tier: Tier = "plc") -> list[str]:
    """Every state variable of every condition of ``tier``: the nodes of its one Read."""
    return [child(d.name, f, tier) for d in definitions for f in fields_of(d)]


@dataclass(frozen=True)
class AlarmRow:
    """One condition's state as ``tankctl alarms`` shows it (``--json``: these keys)."""

    tier: str
    """The tier whose condition it is: ``plc`` or ``supervisor``."""
    name: str
    priority: str
    """The ISA-18.2 priority of the current Severity (LOW/MEDIUM/HIGH/URGENT), else ``""``."""
    severity: int | None
    active: bool | None
    acked: bool | None
    shelved: str | None
    """ShelvingState: Unshelved, OneShotShelved or TimedShelved (None if unread)."""
    enabled: bool | None
    retain: bool | None
    limit: str | None
    """The active limit of a level alarm (HighHigh, High, Low, LowLow), else None."""
    since: str | None
    """The condition's Time (its last state change), ISO 8601 UTC."""
    message: str

    @property
    def standing(self) -> bool:
        """Retained: active or unacknowledged (Part 9 Retain; the states when Retain is unread)."""
        if self.retain is not None:
            return self.retain
        return bool(self.active) or self.acked is False

    @property
    def state(self) -> str:
        """``ACTIVE``/``RTN``, ``UNACK``/``ACK``, then ``SHELVED`` and ``DISABLED`` when so."""
        words = ["ACTIVE" if self.active else "RTN", "ACK" if self.acked or self.acked is None else "UNACK"]
        if self.shelved not in (None, ShelvingState.UNSHELVED.value):
            words.append("SHELVED")
        if self.enabled is False:
            words.append("DISABLED")
        return " ".join(words)

    def as_json(self) -> dict[str, Any]:
        return {**asdict(self), "state": self.state, "standing": self.standing}


def text_of(value: Any) -> str | None:
    """A LocalizedText's text, any other value as a string (None stays None)."""
    if value is None:
        return None
    if isinstance(value, ua.LocalizedText):
        return value.Text
    return str(value)


def _iso(value: Any) -> str | None:
    if not isinstance(value, datetime):
        return None
    when = value if value.tzinfo is not None else value.replace(tzinfo=UTC)
    return when.astimezone(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def priority_name(severity: Any) -> str:
    """The priority whose Severity this is (docs/alarms.md's table), else ``""``."""
    try:
        return Priority(int(severity)).name
    except (TypeError, ValueError):
        return ""


def condition_row(definition: AlarmDefinition, values: Mapping[str, Any], tier: Tier = "plc") -> AlarmRow:
    """One row from the Read's values (keyed by :func:`child` NodeId strings; None = Bad)."""

    def v(field: str) -> Any:
        return values.get(child(definition.name, field, tier))

    severity = v("Severity")
    is_level = definition.kind == ConditionKind.EXCLUSIVE_LEVEL
    return AlarmRow(
        tier=tier,
        name=definition.name,
        priority=priority_name(severity),
        severity=int(severity) if severity is not None else None,
        active=v("ActiveState/Id"),
        acked=v("AckedState/Id"),
        shelved=text_of(v("ShelvingState/CurrentState")),
        enabled=v("EnabledState/Id"),
        retain=v("Retain"),
        limit=(text_of(v(LIMIT_FIELD)) or None) if is_level else None,
        since=_iso(v("Time")),
        message=text_of(v("Message")) or "",
    )


def condition_rows(
    definitions: Sequence[AlarmDefinition],
    values: Mapping[str, Any],
    *,
    every: bool = False,
    tier: Tier = "plc",
) -> list[AlarmRow]:
    """The rows ``tankctl alarms`` shows of one tier: the standing ones, or ``every`` condition."""
    rows = [condition_row(d, values, tier) for d in definitions]
    return rows if every else [r for r in rows if r.standing]
