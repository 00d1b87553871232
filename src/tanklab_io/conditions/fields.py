"""What a condition is made of: its children (node layout) and their values for one snapshot.

One table (:data:`CHILDREN`) serves both sides of the projection: the node builder creates one
node per child the condition's kind has, and every event carries the same names as fields
(``AckedState/Id`` is both the child ``<condition id>.AckedState.Id`` and the event field a
client selects with the browse path ``AckedState``, ``Id``). :func:`snapshot_values` maps a
:class:`~tanklab.alarms.model.ConditionSnapshot` to those values: pure, no server involved, so
what a client sees is testable without one.

Layout (Part 9, the mandatory children of each type plus the optional ones tanklab uses)
    ConditionType: EventId, EventType, SourceNode, SourceName, Time, ReceiveTime, Message,
    Severity, ConditionClassId, ConditionClassName, ConditionName, BranchId, Retain,
    EnabledState (+Id), Quality, LastSeverity, Comment (each + SourceTimestamp), ClientUserId,
    methods Enable, Disable, AddComment. AcknowledgeableConditionType: AckedState (+Id),
    method Acknowledge; ConfirmedState (+Id) and method Confirm only for a definition that
    asks for confirmation. AlarmConditionType: ActiveState (+Id), InputNode, SuppressedState
    (+Id), SuppressedOrShelved, MaxTimeShelved, ShelvingState (ShelvedStateMachineType:
    CurrentState (+Id), UnshelveTime, methods OneShotShelve, TimedShelve, Unshelve).
    ExclusiveLevelAlarmType: the configured limits of HighHighLimit, HighLimit, LowLimit,
    LowLowLimit, and LimitState (CurrentState (+Id)). OffNormalAlarmType: NormalState, which
    points at the condition's own ``NormalValue`` variable (False: a trip or fault input is
    normal when false).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime

from asyncua import ua

from tanklab.alarms.model import AlarmDefinition, ConditionKind, ConditionSnapshot, LimitState, ShelvingState

PROPERTY = "property"
VARIABLE = "variable"
OBJECT = "object"
METHOD = "method"

_LIMITS = ("HighHighLimit", "HighLimit", "LowLimit", "LowLowLimit")


@dataclass(frozen=True, slots=True)
class Child:
    """One child node of a condition.

    ``path`` is the browse path below the condition with ``/`` between names (the event field
    name); ``node`` one of property, variable, object, method; ``vtype`` the value's Variant type
    (None for objects and methods); ``data_type`` and ``type_definition`` numeric ids of ns 0;
    ``method`` for a method child, the standard method whose InputArguments it copies.
    """

    path: str
    node: str
    vtype: ua.VariantType | None = None
    data_type: int = 0
    type_definition: int = ua.ObjectIds.PropertyType
    method: int = 0
    applies: Callable[[AlarmDefinition], bool] = lambda d: True

    @property
    def name(self) -> str:
        """The child's own BrowseName (the last element of its path)."""
        return self.path.rsplit("/", 1)[-1]


def _prop(path: str, vtype: ua.VariantType, data_type: int, **kw: object) -> Child:
    return Child(path, PROPERTY, vtype, data_type, ua.ObjectIds.PropertyType, **kw)  # type: ignore[arg-type]


def _two_state(name: str, **kw: object) -> tuple[Child, ...]:
    return (
        Child(
            name,
            VARIABLE,
            ua.VariantType.LocalizedText,
            ua.ObjectIds.LocalizedText,
            ua.ObjectIds.TwoStateVariableType,
            **kw,  # type: ignore[arg-type]
        ),
        _prop(f"{name}/Id", ua.VariantType.Boolean, ua.ObjectIds.Boolean, **kw),
    )


def _condition_variable(name: str, vtype: ua.VariantType, data_type: int) -> tuple[Child, ...]:
    return (
        Child(name, VARIABLE, vtype, data_type, ua.ObjectIds.ConditionVariableType),
        _prop(f"{name}/SourceTimestamp", ua.VariantType.DateTime, ua.ObjectIds.UtcTime),
    )


def _state_machine(name: str, machine_type: int, **kw: object) -> tuple[Child, ...]:
    return (
        Child(name, OBJECT, type_definition=machine_type, **kw),  # type: ignore[arg-type]
        Child(
            f"{name}/CurrentState",
            VARIABLE,
            ua.VariantType.LocalizedText,
            ua.ObjectIds.LocalizedText,
            ua.ObjectIds.FiniteStateVariableType,
            **kw,  # type: ignore[arg-type]
        ),
        _prop(f"{name}/CurrentState/Id", ua.VariantType.NodeId, ua.ObjectIds.NodeId, **kw),
    )


def _method(path: str, standard: int, **kw: object) -> Child:
    return Child(path, METHOD, method=standard, **kw)  # type: ignore[arg-type]


def _confirm(d: AlarmDefinition) -> bool:
    return d.confirm


def _level(d: AlarmDefinition) -> bool:
    return d.kind == ConditionKind.EXCLUSIVE_LEVEL


def _off_normal(d: AlarmDefinition) -> bool:
    return d.kind == ConditionKind.OFF_NORMAL


def _limit(index: int) -> Callable[[AlarmDefinition], bool]:
    def configured(d: AlarmDefinition) -> bool:
        return _level(d) and d.limits_m is not None and d.limits_m[index] is not None

    return configured


_DT, _NID, _LT = ua.VariantType.DateTime, ua.VariantType.NodeId, ua.VariantType.LocalizedText
_O = ua.ObjectIds

CHILDREN: tuple[Child, ...] = (
    _prop("EventId", ua.VariantType.ByteString, _O.ByteString),
    _prop("EventType", _NID, _O.NodeId),
    _prop("SourceNode", _NID, _O.NodeId),
    _prop("SourceName", ua.VariantType.String, _O.String),
    _prop("Time", _DT, _O.UtcTime),
    _prop("ReceiveTime", _DT, _O.UtcTime),
    _prop("Message", _LT, _O.LocalizedText),
    _prop("Severity", ua.VariantType.UInt16, _O.UInt16),
    _prop("ConditionClassId", _NID, _O.NodeId),
    _prop("ConditionClassName", _LT, _O.LocalizedText),
    _prop("ConditionName", ua.VariantType.String, _O.String),
    _prop("BranchId", _NID, _O.NodeId),
    _prop("Retain", ua.VariantType.Boolean, _O.Boolean),
    *_two_state("EnabledState"),
    *_condition_variable("Quality", ua.VariantType.StatusCode, _O.StatusCode),
    *_condition_variable("LastSeverity", ua.VariantType.UInt16, _O.UInt16),
    *_condition_variable("Comment", _LT, _O.LocalizedText),
    _prop("ClientUserId", ua.VariantType.String, _O.String),
    _method("Enable", _O.ConditionType_Enable),
    _method("Disable", _O.ConditionType_Disable),
    _method("AddComment", _O.ConditionType_AddComment),
    *_two_state("AckedState"),
    _method("Acknowledge", _O.AcknowledgeableConditionType_Acknowledge),
    *_two_state("ConfirmedState", applies=_confirm),
    _method("Confirm", _O.AcknowledgeableConditionType_Confirm, applies=_confirm),
    *_two_state("ActiveState"),
    _prop("InputNode", _NID, _O.NodeId),
    *_two_state("SuppressedState"),
    _prop("SuppressedOrShelved", ua.VariantType.Boolean, _O.Boolean),
    _prop("MaxTimeShelved", ua.VariantType.Double, _O.Duration),
    *_state_machine("ShelvingState", _O.ShelvedStateMachineType),
    _prop("ShelvingState/UnshelveTime", ua.VariantType.Double, _O.Duration),
    _method("ShelvingState/OneShotShelve", _O.ShelvedStateMachineType_OneShotShelve),
    _method("ShelvingState/TimedShelve", _O.ShelvedStateMachineType_TimedShelve),
    _method("ShelvingState/Unshelve", _O.ShelvedStateMachineType_Unshelve),
    *(_prop(name, ua.VariantType.Double, _O.Double, applies=_limit(i)) for i, name in enumerate(_LIMITS)),
    *_state_machine("LimitState", _O.ExclusiveLimitStateMachineType, applies=_level),
    _prop("NormalState", _NID, _O.NodeId, applies=_off_normal),
)
"""Every child a condition may have, parents before children."""

NORMAL_VALUE = "NormalValue"
"""An OffNormal condition's own variable holding its input's normal value (what NormalState
points at)."""

_TWO_STATE_TEXT = {
    "EnabledState": ("Enabled", "Disabled"),
    "AckedState": ("Acknowledged", "Unacknowledged"),
    "ConfirmedState": ("Confirmed", "Unconfirmed"),
    "ActiveState": ("Active", "Inactive"),
    "SuppressedState": ("Suppressed", "Unsuppressed"),
}

SHELVING_STATE_IDS = {
    ShelvingState.UNSHELVED: _O.ShelvedStateMachineType_Unshelved,
    ShelvingState.TIMED: _O.ShelvedStateMachineType_TimedShelved,
    ShelvingState.ONE_SHOT: _O.ShelvedStateMachineType_OneShotShelved,
}
LIMIT_STATE_IDS = {
    LimitState.HIGH_HIGH: _O.ExclusiveLimitStateMachineType_HighHigh,
    LimitState.HIGH: _O.ExclusiveLimitStateMachineType_High,
    LimitState.LOW: _O.ExclusiveLimitStateMachineType_Low,
    LimitState.LOW_LOW: _O.ExclusiveLimitStateMachineType_LowLow,
}


def children_of(definition: AlarmDefinition) -> tuple[Child, ...]:
    """The children a condition of ``definition`` has (its kind's, its options')."""
    return tuple(c for c in CHILDREN if c.applies(definition))


def event_type_id(kind: ConditionKind) -> ua.NodeId:
    """The standard type a condition of ``kind`` is an instance of (``i=9482`` ExclusiveLevel...)."""
    return ua.NodeId(getattr(ua.ObjectIds, kind.value))


@dataclass(frozen=True, slots=True)
class ConditionNode:
    """The fixed facts of one condition node: its definition, ids and configuration.

    ``condition_id`` is the condition's NodeId (``paths.condition``); ``source_id`` the
    source's; ``notifiers`` the objects whose notifier delivers its events, the Server object
    first, then the tier root down to the source's object; ``max_time_shelved_s`` the longest
    shelving a client may ask for [s].
    """

    definition: AlarmDefinition
    condition_id: ua.NodeId
    source_id: ua.NodeId
    source_name: str
    input_id: ua.NodeId
    normal_id: ua.NodeId
    notifiers: tuple[ua.NodeId, ...]
    max_time_shelved_s: float

    @property
    def shelving_id(self) -> ua.NodeId:
        """The NodeId of the condition's ShelvingState object (the shelving methods' object)."""
        return child_id(self.condition_id, "ShelvingState")


def child_id(condition_id: ua.NodeId, path: str) -> ua.NodeId:
    """The NodeId of a condition's child ``path`` (``AckedState/Id`` -> ``<id>.AckedState.Id``)."""
    return ua.NodeId(f"{condition_id.Identifier}.{path.replace('/', '.')}", condition_id.NamespaceIndex)


def static_values(node: ConditionNode) -> dict[str, ua.Variant]:
    """The values that never change: names, ids, limits, the maximum shelving time."""
    d = node.definition
    values = {
        "EventType": ua.Variant(event_type_id(d.kind), _NID),
        "SourceNode": ua.Variant(node.source_id, _NID),
        "SourceName": ua.Variant(node.source_name, ua.VariantType.String),
        "ConditionClassId": ua.Variant(ua.NodeId(_O.ProcessConditionClassType), _NID),
        "ConditionClassName": ua.Variant(ua.LocalizedText("Process"), _LT),
        "ConditionName": ua.Variant(d.name, ua.VariantType.String),
        "BranchId": ua.Variant(ua.NodeId(), _NID),
        "InputNode": ua.Variant(node.input_id, _NID),
        "MaxTimeShelved": ua.Variant(node.max_time_shelved_s * 1000.0, ua.VariantType.Double),
        "NormalState": ua.Variant(node.normal_id, _NID),
    }
    if d.limits_m is not None:
        for name, limit in zip(_LIMITS, d.limits_m, strict=True):
            if limit is not None:
                values[name] = ua.Variant(float(limit), ua.VariantType.Double)
    return values


def snapshot_values(
    node: ConditionNode, snapshot: ConditionSnapshot, event_id: bytes, time: datetime, receive_time: datetime
) -> dict[str, ua.Variant]:
    """Every child's value (the static ones included) for ``snapshot``, raised as ``event_id``.

    ``time`` is the change's UTC stamp (from the tier's model time), ``receive_time`` when the
    server raised it. Only the children ``node``'s definition has are included.
    """
    s = snapshot
    values = static_values(node)
    values["EventId"] = ua.Variant(event_id, ua.VariantType.ByteString)
    values["Time"] = ua.Variant(time, _DT)
    values["ReceiveTime"] = ua.Variant(receive_time, _DT)
    values["Message"] = ua.Variant(ua.LocalizedText(s.message), _LT)
    values["Severity"] = ua.Variant(s.severity, ua.VariantType.UInt16)
    values["Retain"] = ua.Variant(s.retain, ua.VariantType.Boolean)
    quality = ua.StatusCode(ua.StatusCodes.Good if s.quality_good else ua.StatusCodes.Bad)
    values["Quality"] = ua.Variant(quality, ua.VariantType.StatusCode)
    values["LastSeverity"] = ua.Variant(s.last_severity, ua.VariantType.UInt16)
    values["Comment"] = ua.Variant(ua.LocalizedText(s.comment), _LT)
    for name in ("Quality", "LastSeverity", "Comment"):
        values[f"{name}/SourceTimestamp"] = ua.Variant(time, _DT)
    values["ClientUserId"] = ua.Variant(s.comment_user, ua.VariantType.String)
    states = {
        "EnabledState": s.enabled,
        "AckedState": s.acked,
        "ConfirmedState": s.confirmed,
        "ActiveState": s.active,
        "SuppressedState": s.suppressed,
    }
    for name, on in states.items():
        true_text, false_text = _TWO_STATE_TEXT[name]
        values[name] = ua.Variant(ua.LocalizedText(true_text if on else false_text), _LT)
        values[f"{name}/Id"] = ua.Variant(on, ua.VariantType.Boolean)
    shelved = s.shelving != ShelvingState.UNSHELVED
    values["SuppressedOrShelved"] = ua.Variant(s.suppressed or shelved, ua.VariantType.Boolean)
    values["ShelvingState/CurrentState"] = ua.Variant(ua.LocalizedText(s.shelving.value), _LT)
    values["ShelvingState/CurrentState/Id"] = ua.Variant(ua.NodeId(SHELVING_STATE_IDS[s.shelving]), _NID)
    unshelve_ms = s.unshelve_time_s * 1000.0 if s.shelving == ShelvingState.TIMED else 0.0
    values["ShelvingState/UnshelveTime"] = ua.Variant(unshelve_ms, ua.VariantType.Double)
    limit = s.limit_state if s.active else None
    values["LimitState/CurrentState"] = ua.Variant(ua.LocalizedText(limit.value if limit else ""), _LT)
    limit_id = ua.NodeId(LIMIT_STATE_IDS[limit]) if limit else ua.NodeId()
    values["LimitState/CurrentState/Id"] = ua.Variant(limit_id, _NID)
    have = {c.path for c in children_of(node.definition) if c.node in (PROPERTY, VARIABLE)}
    return {k: v for k, v in values.items() if k in have}
