"""The OPC UA projection of a tier's alarm conditions: nodes, events, methods, ConditionRefresh.

The alarm core (``tanklab.alarms``, pure, on model time) decides; this shell shows and asks:

* :meth:`UaConditions.install` adds one condition per :class:`AlarmDefinition` (nodes:
  :mod:`~tanklab_io.conditions.nodes`), binds the condition methods on every instance and on
  the standard type method nodes, and replaces asyncua's ConditionRefresh and
  ConditionRefresh2;
* :meth:`UaConditions.publish` writes each :class:`ConditionEvent`'s snapshot into the
  condition's nodes and raises the event (EventId = ``event.event_id``) on every notifier of
  the condition's chain;
* a method call is checked (:mod:`~tanklab_io.conditions.calls`), handed to the core's
  ``handler`` as a :class:`ConditionCall`, the events it returns are published, its
  :class:`CallStatus` answered as the StatusCode of that name, and the call audited.

Type methods (Part 9 5.5.4, what UaExpert does): a client may call the method node of the type,
e.g. ``i=9111`` AcknowledgeableConditionType.Acknowledge, with the condition as ObjectId
(asyncua does not check that a method belongs to the object it is called on). The shelving
methods take the condition's ShelvingState object (or the condition itself) as ObjectId.
An ObjectId that is no condition of this server answers BadNodeIdUnknown. One projection per
server: the type methods' callbacks are the server's.
"""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Awaitable, Callable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any, ClassVar

from asyncua import Server, ua
from asyncua.common.event_objects import RefreshEndEvent, RefreshStartEvent
from asyncua.common.events import Event

from tanklab import paths
from tanklab.alarms.manager import AlarmManager
from tanklab.alarms.model import (
    AlarmDefinition,
    CallStatus,
    ConditionCall,
    ConditionEvent,
    ConditionKind,
    ConditionSnapshot,
    Method,
    ShelvingState,
)
from tanklab.tags import NAMESPACE_URI
from tanklab_io.audit import AuditLog
from tanklab_io.conditions.calls import check_call, shown, status_code
from tanklab_io.conditions.fields import (
    NORMAL_VALUE,
    ConditionNode,
    child_id,
    children_of,
    snapshot_values,
)
from tanklab_io.conditions.nodes import (
    NotifierChains,
    add_condition,
    definitions_by_name,
    link_source,
    notifier_path,
    standard_input_arguments,
)
from tanklab_io.conditions.oftype import match_event_subtypes
from tanklab_io.ua import CURRENT_SESSION, CURRENT_USER, who

log = logging.getLogger(__name__)

Handler = Callable[[ConditionCall], tuple[CallStatus, Sequence[ConditionEvent]]]
"""The alarm core's answer to a call: its status and the events the call caused."""
Retained = Callable[[], Sequence[ConditionSnapshot | ConditionEvent]]
"""The conditions of interest now (Retain true), for ConditionRefresh: snapshots (re-sent with
the EventId this projection last published for them) or the core's latest events (re-sent with
their own EventId and time)."""
ToUtc = Callable[[float], datetime]
"""The tier's model time [s] -> its UTC stamp."""

_O = ua.ObjectIds
_SERVER = ua.NodeId(_O.Server)
_NULL = ua.Variant()
"""The field of a clause the condition has no child for (shared: never changed)."""

TYPE_METHODS: dict[int, Method] = {
    _O.ConditionType_Enable: Method.ENABLE,
    _O.ConditionType_Disable: Method.DISABLE,
    _O.ConditionType_AddComment: Method.ADD_COMMENT,
    _O.AcknowledgeableConditionType_Acknowledge: Method.ACKNOWLEDGE,
    _O.AcknowledgeableConditionType_Confirm: Method.CONFIRM,
    _O.AlarmConditionType_ShelvingState_OneShotShelve: Method.ONE_SHOT_SHELVE,
    _O.AlarmConditionType_ShelvingState_TimedShelve: Method.TIMED_SHELVE,
    _O.AlarmConditionType_ShelvingState_Unshelve: Method.UNSHELVE,
    _O.ShelvedStateMachineType_OneShotShelve: Method.ONE_SHOT_SHELVE,
    _O.ShelvedStateMachineType_TimedShelve: Method.TIMED_SHELVE,
    _O.ShelvedStateMachineType_Unshelve: Method.UNSHELVE,
}
"""The standard method nodes a client may call with a condition as ObjectId."""

INSTANCE_METHODS: dict[str, Method] = {
    "Enable": Method.ENABLE,
    "Disable": Method.DISABLE,
    "AddComment": Method.ADD_COMMENT,
    "Acknowledge": Method.ACKNOWLEDGE,
    "Confirm": Method.CONFIRM,
    "ShelvingState/OneShotShelve": Method.ONE_SHOT_SHELVE,
    "ShelvingState/TimedShelve": Method.TIMED_SHELVE,
    "ShelvingState/Unshelve": Method.UNSHELVE,
}
"""A condition's own method children (path below the condition) and what they are."""

DEFAULT_MAX_TIME_SHELVED_S = 8 * 3600.0
"""The longest shelving when the tier configures none: one shift [s]."""


def initial_snapshot(definition: AlarmDefinition) -> ConditionSnapshot:
    """A condition's state before the core says anything: enabled, inactive, acknowledged,
    confirmed, not retained, Severity its priority's."""
    severity = int(definition.priority)
    return ConditionSnapshot(
        name=definition.name,
        enabled=True,
        active=False,
        acked=True,
        confirmed=True,
        retain=False,
        severity=severity,
        last_severity=severity,
        message=definition.message,
        comment="",
        comment_user="",
        quality_good=True,
        time_s=0.0,
        shelving=ShelvingState.UNSHELVED,
        unshelve_time_s=0.0,
        suppressed=False,
    )


class ConditionEventFields(Event):
    """A condition's event as a subscription reads it: every value by its field name, and the
    ConditionId (selected with AttributeId NodeId and an empty browse path).

    asyncua's :meth:`Event.to_event_fields` deep-copies every selected value for every
    monitored item and turns each select clause into a name again; with the ~100 clauses of a
    full AlarmConditionType filter that was most of :meth:`UaConditions.publish`'s time. Here
    the Variants are built once per event and never changed after (nothing mutates them, so
    the items can share them), and each clause list's names are worked out once.
    """

    _NAMES: ClassVar[dict[int, tuple[list[ua.SimpleAttributeOperand], list[str]]]] = {}

    def __init__(self, node: ConditionNode, values: Mapping[str, ua.Variant]) -> None:
        self._variants = dict(values)
        self._variants["NodeId"] = ua.Variant(node.condition_id, ua.VariantType.NodeId)
        super().__init__(_SERVER)
        for name, value in self._variants.items():
            self.add_property(name, value.Value, value.VariantType)

    @classmethod
    def _names(cls, clauses: list[ua.SimpleAttributeOperand]) -> list[str]:
        cached = cls._NAMES.get(id(clauses))
        if cached is not None and cached[0] is clauses and len(cached[1]) == len(clauses):
            return cached[1]
        names = [
            Event.browse_path_to_attribute_name(c.BrowsePath)
            if c.BrowsePath
            else ua.AttributeIds(c.AttributeId).name
            for c in clauses
        ]
        if len(cls._NAMES) > 10_000:  # monitored items come and go: keep the cache bounded
            cls._NAMES.clear()
        cls._NAMES[id(clauses)] = (clauses, names)
        return names

    def to_event_fields(self, select_clauses: list[ua.SimpleAttributeOperand]) -> list[ua.Variant]:
        """The selected fields, in order (a field the condition does not have is null)."""
        get = self._variants.get
        return [get(name, _NULL) for name in self._names(select_clauses)]


def event_object(node: ConditionNode, values: Mapping[str, ua.Variant]) -> Event:
    """The event of ``node`` carrying ``values`` (:class:`ConditionEventFields`)."""
    return ConditionEventFields(node, values)


def _system_event(kind: type[Event], now: datetime) -> Event:
    event = kind()
    event.EventId = os.urandom(16)
    event.SourceNode = _SERVER
    event.SourceName = "Server"
    event.Time = now
    event.ReceiveTime = now
    event.Message = ua.LocalizedText(kind.__name__)
    event.Severity = 1
    return event


class UaConditions:
    """A tier's alarm conditions on its asyncua server (make with :meth:`install`)."""

    def __init__(
        self,
        server: Server,
        nodes: Mapping[str, ConditionNode],
        handler: Handler,
        retained: Retained,
        to_utc: ToUtc,
        audit: AuditLog | None,
    ) -> None:
        self.server = server
        self.nodes = dict(nodes)
        self._handler = handler
        self._retained = retained
        self._to_utc = to_utc
        self._audit = audit
        self._by_object: dict[ua.NodeId, str] = {}
        for name, node in self.nodes.items():
            self._by_object[node.condition_id] = name
            self._by_object[node.shelving_id] = name
        self._latest: dict[str, ConditionEvent] = {}
        self._publishing = asyncio.Lock()
        self.published = 0
        self.after_publish: Callable[[], Awaitable[None]] | None = None
        """Awaited after each batch of events is in the nodes and raised, still in the batch's
        turn (the tier republishes its alarm summary: :class:`~tanklab_io.conditions.summary.
        SummaryPublisher`); an exception it raises is logged, never the caller's."""

    @classmethod
    async def install_manager(
        cls,
        server: Server,
        tier: paths.Tier,
        manager: AlarmManager,
        *,
        handler: Handler,
        to_utc: ToUtc,
        audit: AuditLog | None,
    ) -> UaConditions:
        """A tier's alarm manager on ``server``: its definitions, its retained conditions for
        ConditionRefresh, and its maximum shelving time as every condition's MaxTimeShelved (the
        same limit the core refuses a longer TimedShelve with). ``handler`` answers the calls
        (the tier passes them to ``manager.call`` at its model time)."""
        return await cls.install(
            server,
            tier,
            manager.definitions,
            handler=handler,
            retained=manager.retained,
            to_utc=to_utc,
            audit=audit,
            max_time_shelved_s=manager.max_shelving_time_s,
        )

    @classmethod
    async def install(
        cls,
        server: Server,
        tier: paths.Tier,
        definitions: Sequence[AlarmDefinition],
        *,
        handler: Handler,
        retained: Retained,
        to_utc: ToUtc,
        audit: AuditLog | None = None,
        max_time_shelved_s: float | Mapping[str, float] = DEFAULT_MAX_TIME_SHELVED_S,
    ) -> UaConditions:
        """Add ``definitions``' conditions to ``server`` (initialised; started or not) and bind
        their methods and ConditionRefresh.

        ``max_time_shelved_s`` is every condition's MaxTimeShelved [s], or one per name (the
        seam's definition has none; names missing from the mapping get the default).
        Raises ValueError for a repeated name or a source that is not a node under the tier's
        root.
        """
        match_event_subtypes(server)
        idx = await server.register_namespace(NAMESPACE_URI)
        root = paths.tier_root(tier)
        by_name = definitions_by_name(definitions)
        standard = sorted({c.method for d in definitions for c in children_of(d) if c.method})
        input_arguments = await standard_input_arguments(server, standard)
        chains = NotifierChains(server)
        nodes: dict[str, ConditionNode] = {}
        methods: list[tuple[ua.NodeId, str, Method, ua.NodeId]] = []
        now = datetime.now(UTC)
        for name, d in by_name.items():
            holder, chain = notifier_path(server, idx, d.source, root)
            cid = ua.NodeId(paths.condition(tier, name), idx)
            source_id = ua.NodeId(d.source, idx)
            browse = server.iserver.aspace.read_attribute_value(source_id, ua.AttributeIds.BrowseName)
            limit = max_time_shelved_s if isinstance(max_time_shelved_s, float | int) else None
            if limit is None:
                assert isinstance(max_time_shelved_s, Mapping)
                limit = max_time_shelved_s.get(name, DEFAULT_MAX_TIME_SHELVED_S)
            node = ConditionNode(
                definition=d,
                condition_id=cid,
                source_id=source_id,
                source_name=browse.Value.Value.Name,
                input_id=ua.NodeId(d.input_path, idx) if d.input_path else ua.NodeId(),
                normal_id=child_id(cid, NORMAL_VALUE) if d.kind == ConditionKind.OFF_NORMAL else ua.NodeId(),
                notifiers=(_SERVER, *(ua.NodeId(p, idx) for p in chain)),
                max_time_shelved_s=float(limit),
            )
            initial = snapshot_values(node, initial_snapshot(d), b"", to_utc(0.0), now)
            holder_id = ua.NodeId(holder, idx)
            for mid in await add_condition(server, node, holder_id, initial, input_arguments):
                path = str(mid.Identifier)[len(str(cid.Identifier)) + 1 :].replace(".", "/")
                owner = node.shelving_id if path.startswith("ShelvingState/") else cid
                methods.append((mid, name, INSTANCE_METHODS[path], owner))
            await link_source(server, chains, node, holder_id)
            nodes[name] = node
        self = cls(server, nodes, handler, retained, to_utc, audit)
        session = server.iserver.isession
        for mid, name, method, owner in methods:
            session.add_method_callback(mid, self._instance_method(name, method, owner))
        for type_mid, method in TYPE_METHODS.items():
            session.add_method_callback(ua.NodeId(type_mid), self._type_method(method))
        session.add_method_callback(ua.NodeId(_O.ConditionType_ConditionRefresh), self._refresh_method(False))
        session.add_method_callback(ua.NodeId(_O.ConditionType_ConditionRefresh2), self._refresh_method(True))
        return self

    # ---- events -------------------------------------------------------------------------

    async def publish(self, events: Sequence[ConditionEvent]) -> None:
        """Store each event's snapshot in its condition's nodes and raise it on the condition's
        notifier chain (an event of a condition this projection does not have is logged and
        skipped).

        Publications run one after the other, in the order they were asked for (a FIFO lock):
        a tier that calls this right after its core made the events, with no await in between,
        gets its events into the nodes in the core's order, even if a client's call comes in
        while an earlier publication waits on the network."""
        if not events:
            return
        async with self._publishing:
            await self._publish(events)
            if self.after_publish is not None:
                try:
                    await self.after_publish()
                except Exception:  # the events are out: a summary failure must not hide that
                    log.exception("after-publish hook failed")

    async def _publish(self, events: Sequence[ConditionEvent]) -> None:
        for ev in events:
            node = self.nodes.get(ev.condition.name)
            if node is None:
                log.error(
                    "event %s of unknown condition %s not published", ev.event_id.hex(), ev.condition.name
                )
                continue
            receive = datetime.now(UTC)
            values = snapshot_values(node, ev.condition, ev.event_id, self._to_utc(ev.t_s), receive)
            for path, value in values.items():
                dv = ua.DataValue(value, SourceTimestamp=receive, ServerTimestamp=receive)
                await self.server.write_attribute_value(child_id(node.condition_id, path), dv)
            self._latest[ev.condition.name] = ev
            self.published += 1
            subscriptions = list(self.server.iserver.subscription_service.subscriptions.values())
            if not subscriptions:
                continue  # nobody could receive it: the nodes hold the state
            event = event_object(node, values)
            for sub in subscriptions:
                for notifier in node.notifiers:
                    event.emitting_node = notifier
                    await sub.monitored_item_srv.trigger_event(event)

    def latest(self, name: str) -> ConditionEvent | None:
        """The last event published for condition ``name`` (its EventId is the one to ack)."""
        return self._latest.get(name)

    # ---- methods ------------------------------------------------------------------------

    def _instance_method(self, name: str, method: Method, owner: ua.NodeId) -> Callable[..., Any]:
        async def call(parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode:
            if parent != owner and parent != self.nodes[name].condition_id:
                return await self._refuse(method, parent, args, "BadMethodInvalid")
            return await self.call(name, method, args)

        return call

    def _type_method(self, method: Method) -> Callable[..., Any]:
        async def call(parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode:
            name = self._by_object.get(parent)
            if name is None:
                return await self._refuse(method, parent, args, CallStatus.UNKNOWN_CONDITION.value)
            return await self.call(name, method, args)

        return call

    async def _refuse(
        self, method: Method, parent: ua.NodeId, args: Sequence[ua.Variant], status: str
    ) -> ua.StatusCode:
        self._record(f"{parent.to_string()}.{method.value}", args, status)
        return ua.StatusCode(getattr(ua.StatusCodes, status))

    async def call(self, name: str, method: Method, args: Sequence[ua.Variant]) -> ua.StatusCode:
        """Check, hand to the core, publish what it returns, audit, answer (the session's user
        is :data:`~tanklab_io.ua.CURRENT_USER`)."""
        checked = check_call(name, method, CURRENT_USER.get(), args)
        if isinstance(checked, ua.StatusCode):
            status = checked
        else:
            try:
                outcome, events = self._handler(checked)
            except Exception:
                log.exception("alarm handler failed on %s.%s", name, method.value)
                status = ua.StatusCode(ua.StatusCodes.BadInternalError)
            else:
                status = status_code(outcome)
                try:
                    await self.publish(events)
                except Exception:  # the core's state changed: say so, keep its answer
                    log.exception("events of %s.%s not published", name, method.value)
        self._record(f"{self.nodes[name].condition_id.Identifier}.{method.value}", args, status.name)
        return status

    def _record(self, node: str, args: Sequence[ua.Variant], status: str) -> None:
        if self._audit is None:
            return
        user, role = who(CURRENT_USER.get())
        self._audit.record("call", user=user, role=role, node=node, new=shown(args), status=status)

    # ---- ConditionRefresh ---------------------------------------------------------------

    def _refresh_method(self, with_item: bool) -> Callable[..., Any]:
        method = "ConditionRefresh2" if with_item else "ConditionRefresh"

        async def call(parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode:
            status = await self._refresh(args, with_item)
            self._record(f"{parent.to_string()}.{method}", args, status.name)
            return status

        return call

    async def _refresh(self, args: Sequence[ua.Variant], with_item: bool) -> ua.StatusCode:
        want = 2 if with_item else 1
        if len(args) != want:
            name = "BadArgumentsMissing" if len(args) < want else "BadTooManyArguments"
            return ua.StatusCode(getattr(ua.StatusCodes, name))
        if any(not isinstance(a, ua.Variant) or a.VariantType != ua.VariantType.UInt32 for a in args):
            return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
        sub = self.server.iserver.subscription_service.subscriptions.get(args[0].Value)
        session = CURRENT_SESSION.get()
        if sub is None or (session is not None and sub.session_id != session):
            # Part 9 5.5.7: the subscription must be the calling session's.
            return ua.StatusCode(ua.StatusCodes.BadSubscriptionIdInvalid)
        items = sub.monitored_item_srv
        targets = {mid: nid for nid, mids in items._monitored_events.items() for mid in mids}
        if with_item:
            mid = args[1].Value
            if mid not in targets:
                return ua.StatusCode(ua.StatusCodes.BadMonitoredItemIdInvalid)
            targets = {mid: targets[mid]}
        now = datetime.now(UTC)

        async def send(mid: int, event: Event, filtered: bool) -> None:
            mdata = items._monitored_items.get(mid)
            if mdata is None:
                return
            evaluator = mdata.where_clause_evaluator
            if filtered and evaluator is not None and not evaluator.eval(event):
                return
            fields = ua.EventFieldList()
            fields.ClientHandle = mdata.client_handle
            fields.EventFields = event.to_event_fields(mdata.filter.SelectClauses)
            await sub.enqueue_event(mid, fields, mdata.queue_size)

        start = _system_event(RefreshStartEvent, now)
        for mid in targets:
            # Part 9 4.5: the refresh brackets go to every event item of the subscription,
            # whatever its where clause, or the client cannot tell when the refresh ends.
            await send(mid, start, filtered=False)
        for item in self._retained():
            latest: ConditionEvent | None
            if isinstance(item, ConditionEvent):
                snapshot, latest = item.condition, item
            else:
                snapshot, latest = item, self._latest.get(item.name)
            node = self.nodes.get(snapshot.name)
            if node is None:
                continue
            event_id = latest.event_id if latest is not None else b""
            t_s = latest.t_s if latest is not None else snapshot.time_s
            event = event_object(node, snapshot_values(node, snapshot, event_id, self._to_utc(t_s), now))
            for mid, monitored in targets.items():
                if monitored in node.notifiers:
                    event.emitting_node = monitored
                    await send(mid, event, filtered=True)
        end = _system_event(RefreshEndEvent, datetime.now(UTC))
        for mid in targets:
            await send(mid, end, filtered=False)
        return ua.StatusCode(ua.StatusCodes.Good)
