"""A client's view of condition events in tests: a collector, the event filter that selects
the fields a test compares plus the ConditionId (OPC UA Part 9), and a ConditionRefresh."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from asyncua import Client, ua

from tanklab_testing.waits import wait_until

REFRESH = ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh)
REFRESH_START = ua.NodeId(ua.ObjectIds.RefreshStartEventType)
REFRESH_END = ua.NodeId(ua.ObjectIds.RefreshEndEventType)


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


async def refresh(client: Client, condition: ua.NodeId, fields: Sequence[str]) -> list[dict[str, Any]]:
    """ConditionRefresh on a fresh Server subscription selecting ``fields`` (and EventType): the
    events of ``condition`` between RefreshStart and RefreshEnd (both received)."""
    events = Events()
    sub = await client.create_subscription(100, events)
    selected = list(dict.fromkeys([*fields, "EventType"]))
    await sub.subscribe_events(
        ua.ObjectIds.Server, ua.ObjectIds.BaseEventType, evfilter=event_filter(selected)
    )
    sub_id = ua.Variant(sub.subscription_id, ua.VariantType.UInt32)
    req = ua.CallMethodRequest(
        ObjectId=ua.NodeId(ua.ObjectIds.ConditionType), MethodId=REFRESH, InputArguments=[sub_id]
    )
    (result,) = await client.uaclient.call([req])
    assert result.StatusCode.is_good(), result.StatusCode

    def types() -> list[Any]:
        return [e.get("EventType") for e in events.items]

    await wait_until(lambda: REFRESH_END in types(), 20, what="RefreshEnd")
    got = types()
    start, end = got.index(REFRESH_START), got.index(REFRESH_END)
    await sub.delete()
    return [e for e in events.items[start + 1 : end] if e.get("NodeId") == condition]
