"""A client's view of condition events in tests: a collector and the event filter that selects
the fields a test compares, plus the ConditionId (OPC UA Part 9)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from asyncua import ua


class Events:
    """Collects the selected fields of every event (in arrival order); the subscription handler."""

    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []

    def event_notification(self, event: Any) -> None:
        self.items.append({k: v.Value for k, v in event.get_event_props_as_fields_dict().items()})

    def of(self, condition: ua.NodeId) -> list[dict[str, Any]]:
        """The events of one condition (by its ConditionId)."""
        return [e for e in self.items if e.get("NodeId") == condition]


def event_filter(fields: Sequence[str]) -> ua.EventFilter:
    """Select ``fields`` (browse paths below BaseEventType, ``"ActiveState/Id"``) and the
    ConditionId (ConditionType's NodeId attribute, reported as ``"NodeId"``)."""
    f = ua.EventFilter()
    for path in fields:
        op = ua.SimpleAttributeOperand()
        op.TypeDefinitionId = ua.NodeId(ua.ObjectIds.BaseEventType)
        op.BrowsePath = [ua.QualifiedName(p, 0) for p in path.split("/")]
        op.AttributeId = ua.AttributeIds.Value
        f.SelectClauses.append(op)
    cid = ua.SimpleAttributeOperand()
    cid.TypeDefinitionId = ua.NodeId(ua.ObjectIds.ConditionType)
    cid.AttributeId = ua.AttributeIds.NodeId
    f.SelectClauses.append(cid)
    return f
