"""OfType in event filters matches subtypes, as Part 4 7.7.3 says (asyncua: the exact type only).

asyncua 2.1's ``WhereClauseEvaluator`` evaluates ``OfType(T)`` as ``event.EventType == T``, so
a client filtering on AlarmConditionType never sees an ExclusiveLevelAlarmType event. (asyncua's
own client hides this by sending ``InList`` of every subtype instead of OfType; UaExpert,
node-opcua and open62541 send OfType.) The fix, per server and without a fork:
:func:`match_event_subtypes` wraps the server's subscription service so that every event
monitored item it creates (or modifies) gets a :class:`SubtypeWhereClause`, asyncua's evaluator
with only OfType replaced. asyncua also keeps the old evaluator when ModifyMonitoredItems
changes the filter; the wrapper builds one from the new where clause, so that is fixed too.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from asyncua import Server, ua
from asyncua.server.address_space import AddressSpace
from asyncua.server.monitored_item_service import WhereClauseEvaluator

_HAS_SUBTYPE = ua.NodeId(ua.ObjectIds.HasSubtype)


def supertypes(aspace: AddressSpace, typeid: ua.NodeId) -> frozenset[ua.NodeId]:
    """``typeid`` and every type it is a subtype of (following HasSubtype inverse)."""
    seen = {typeid}
    todo = [typeid]
    while todo:
        current = todo.pop()
        if current not in aspace:
            continue
        for ref in aspace[current].references:
            if ref.ReferenceTypeId == _HAS_SUBTYPE and not ref.IsForward and ref.NodeId not in seen:
                seen.add(ref.NodeId)
                todo.append(ref.NodeId)
    return frozenset(seen)


class SubtypeWhereClause(WhereClauseEvaluator):
    """asyncua's where-clause evaluator with OfType true for the type and its subtypes."""

    def __init__(self, logger: Any, aspace: AddressSpace, whereclause: ua.ContentFilter) -> None:
        super().__init__(logger, aspace, whereclause)
        self._supertypes: dict[ua.NodeId, frozenset[ua.NodeId]] = {}

    def _eval_el(self, index: int, event: Any) -> Any:
        el = self.elements[index]
        if el.FilterOperator != ua.FilterOperator.OfType:
            return super()._eval_el(index, event)
        wanted = self._eval_op(el.FilterOperands[0], event)
        etype = event.EventType
        if etype not in self._supertypes:
            self._supertypes[etype] = supertypes(self._aspace, etype)
        return wanted in self._supertypes[etype]


def _upgrade(service: Any, subscription_id: int, monitored_item_id: int) -> None:
    sub = service.subscriptions.get(subscription_id)
    if sub is None:
        return
    items = sub.monitored_item_srv
    mdata = items._monitored_items.get(monitored_item_id)
    if mdata is None or mdata.where_clause_evaluator is None or mdata.filter is None:
        return
    if isinstance(mdata.filter, ua.EventFilter):
        mdata.where_clause_evaluator = SubtypeWhereClause(
            items.logger, items.aspace, mdata.filter.WhereClause
        )


def match_event_subtypes(server: Server) -> None:
    """Make ``server``'s event filters match OfType by subtype (idempotent)."""
    service = server.iserver.subscription_service
    if getattr(service, "_tanklab_subtypes", False):
        return
    create: Callable[..., Any] = service.create_monitored_items
    modify: Callable[..., Any] = service.modify_monitored_items

    async def create_monitored_items(
        params: ua.CreateMonitoredItemsParameters,
    ) -> list[ua.MonitoredItemCreateResult]:
        results: list[ua.MonitoredItemCreateResult] = await create(params)
        for result in results:
            if result.StatusCode.is_good():
                _upgrade(service, params.SubscriptionId, result.MonitoredItemId)
        return results

    def modify_monitored_items(
        params: ua.ModifyMonitoredItemsParameters,
    ) -> list[ua.MonitoredItemModifyResult]:
        results: list[ua.MonitoredItemModifyResult] = modify(params)
        for item in params.ItemsToModify:
            _upgrade(service, params.SubscriptionId, item.MonitoredItemId)
        return results

    service.create_monitored_items = create_monitored_items
    service.modify_monitored_items = modify_monitored_items
    service._tanklab_subtypes = True
