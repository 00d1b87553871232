"""The alarm conditions' OPC UA projection on a real, secured asyncua server (issue #15).

Clients connect encrypted as the test users (Observer, Operator, Engineer), so roles apply as in
a deployment. What is checked: a client subscribed to the Server object receives a condition's
events with Part 9's fields; Acknowledge through the instance's method and through the type's
method (``i=9111`` with the condition as ObjectId); every refusal code (roles, argument count and
types, the core's answers); ConditionRefresh / ConditionRefresh2 after a reconnect deliver the
retained conditions between RefreshStart and RefreshEnd; an OfType filter on a base type receives
its subtypes' events and not other types'.

The alarm core is :class:`FakeCore`, a small honest implementation of the seam written for these
tests (a stale EventId is EVENT_ID_UNKNOWN, a second Acknowledge ALREADY_ACKED, a disabled
condition DISABLED, shelving past the maximum SHELVING_TIME_OUT_OF_RANGE, ...): the real core
(``tanklab.alarms.manager``) replaces it when both land; these tests then run against it.
"""

from __future__ import annotations

import itertools
import shutil
from collections.abc import AsyncIterator
from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from helpers import ROOT, free_port, secure, server_security, session_home, wait_until
from node_client import NODE, NODE_DIR, run_node_script
from tanklab import paths
from tanklab.alarms.model import (
    AlarmDefinition,
    CallStatus,
    ConditionCall,
    ConditionEvent,
    ConditionKind,
    ConditionSnapshot,
    LimitState,
    Method,
    Priority,
    ShelvingState,
)
from tanklab.config import load_site
from tanklab.tags import NAMESPACE_URI, Tag, plc_tags
from tanklab_io.audit import read_audit
from tanklab_io.conditions import UaConditions, initial_snapshot
from tanklab_io.pki import trust
from tanklab_io.ua import MethodHandler, WriteHandler
from tanklab_io.ua_security import TierServer, start_tier_server
from tanklab_testing.condition_events import event_filter as condition_event_filter

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
EPOCH = datetime(2026, 1, 1, tzinfo=UTC)
MAX_SHELVE_S = 3600.0


def _parent(path: str) -> str:
    return path.rsplit(".", 1)[0]


LEVEL = AlarmDefinition(
    name="T1Level",
    kind=ConditionKind.EXCLUSIVE_LEVEL,
    source=_parent(paths.plc.io("T1").pv),
    message="T1 level",
    priority=Priority.HIGH,
    input_path=paths.plc.io("T1").pv,
    limits_m=(1.9, 1.7, 0.3, None),
    limit_priorities=(Priority.URGENT, Priority.HIGH, Priority.MEDIUM, Priority.LOW),
)
TRIP = AlarmDefinition(
    name="T1HighHighTrip",
    kind=ConditionKind.OFF_NORMAL,
    source=paths.plc.interlock("T1"),  # a variable: its object notifies
    message="T1 high-high interlock tripped",
    priority=Priority.URGENT,
    input_path=paths.plc.interlock("T1"),
    latched=True,
    confirm=True,
)
PV_BAD = AlarmDefinition(
    name="LIC1PvBad",
    kind=ConditionKind.DISCRETE,
    source=_parent(paths.plc.loop("LIC1").pv),
    message="LIC1 PV bad",
    priority=Priority.MEDIUM,
)
DEFINITIONS = (LEVEL, TRIP, PV_BAD)

FIELDS = (
    "EventId",
    "EventType",
    "SourceNode",
    "SourceName",
    "Time",
    "ReceiveTime",
    "Message",
    "Severity",
    "ConditionName",
    "BranchId",
    "Retain",
    "EnabledState/Id",
    "ActiveState",
    "ActiveState/Id",
    "AckedState",
    "AckedState/Id",
    "ConfirmedState/Id",
    "LastSeverity",
    "Comment",
    "ClientUserId",
    "Quality",
    "ShelvingState/CurrentState",
    "ShelvingState/CurrentState/Id",
    "ShelvingState/UnshelveTime",
    "SuppressedState/Id",
    "LimitState/CurrentState",
    "LimitState/CurrentState/Id",
    "HighLimit",
)


# ---- the in-test alarm core -------------------------------------------------------------


class FakeCore:
    """Part 9's rules in a few lines, on model time ``t_s``: enough to drive the projection."""

    def __init__(self) -> None:
        self.defs = {d.name: d for d in DEFINITIONS}
        self.state = {d.name: initial_snapshot(d) for d in DEFINITIONS}
        self.latest: dict[str, bytes] = {}
        self.count = 0
        self.t_s = 100.0
        self.calls: list[ConditionCall] = []
        self.events: dict[str, ConditionEvent] = {}
        self.retain_events = False
        """Whether :meth:`retained` answers the latest events (as the real core does) rather
        than snapshots: the projection takes both."""

    def _emit(self, name: str, reason: str, **changes: Any) -> ConditionEvent:
        d, s = self.defs[name], replace(self.state[name], **changes, time_s=self.t_s)
        retain = s.enabled and (s.active or not s.acked or (d.confirm and not s.confirmed))
        s = replace(s, retain=retain)
        self.state[name] = s
        self.count += 1
        self.latest[name] = event_id = b"fake-%04d" % self.count
        self.events[name] = ConditionEvent(event_id, s, reason, self.t_s)
        return self.events[name]

    def activate(self, name: str, limit: LimitState | None = None) -> ConditionEvent:
        d, s = self.defs[name], self.state[name]
        severity = int(d.priority)
        if limit is not None and d.limit_priorities is not None:
            severity = int(d.limit_priorities[list(LimitState).index(limit)])
        message = f"{d.message} {limit.value}" if limit else d.message
        return self._emit(
            name,
            "active",
            active=True,
            acked=False,
            confirmed=not d.confirm,
            severity=severity,
            last_severity=s.severity,
            message=message,
            limit_state=limit,
        )

    def clear(self, name: str) -> ConditionEvent:
        d = self.defs[name]
        s = self.state[name]
        return self._emit(
            name,
            "inactive",
            active=False,
            severity=int(d.priority),
            last_severity=s.severity,
            limit_state=None,
        )

    def handle(self, call: ConditionCall) -> tuple[CallStatus, list[ConditionEvent]]:
        self.calls.append(call)
        name, m = call.condition, call.method
        s = self.state[name]
        if m in (Method.ENABLE, Method.DISABLE):
            want = m == Method.ENABLE
            if s.enabled == want:
                return (CallStatus.ALREADY_ENABLED if want else CallStatus.ALREADY_DISABLED), []
            return CallStatus.GOOD, [self._emit(name, m.value, enabled=want)]
        if not s.enabled:
            return CallStatus.DISABLED, []
        if m in (Method.ACKNOWLEDGE, Method.CONFIRM, Method.ADD_COMMENT) and call.event_id != self.latest.get(
            name
        ):
            return CallStatus.EVENT_ID_UNKNOWN, []
        commented = {"comment": call.comment, "comment_user": call.user}
        if m == Method.ACKNOWLEDGE:
            if s.acked:
                return CallStatus.ALREADY_ACKED, []
            return CallStatus.GOOD, [
                self._emit(name, f"acknowledged by {call.user}", acked=True, **commented)
            ]
        if m == Method.CONFIRM:
            if not self.defs[name].confirm or not s.acked:
                return CallStatus.NOT_CONFIRMABLE, []
            if s.confirmed:
                return CallStatus.ALREADY_CONFIRMED, []
            return CallStatus.GOOD, [self._emit(name, "confirmed", confirmed=True, **commented)]
        if m == Method.ADD_COMMENT:
            return CallStatus.GOOD, [self._emit(name, "comment", **commented)]
        shelved = s.shelving != ShelvingState.UNSHELVED
        if m == Method.UNSHELVE:
            if not shelved:
                return CallStatus.NOT_SHELVED, []
            return CallStatus.GOOD, [
                self._emit(name, "unshelved", shelving=ShelvingState.UNSHELVED, unshelve_time_s=0.0)
            ]
        if shelved:
            return CallStatus.ALREADY_SHELVED, []
        if m == Method.ONE_SHOT_SHELVE:
            return CallStatus.GOOD, [self._emit(name, "shelved once", shelving=ShelvingState.ONE_SHOT)]
        if not 0 < call.shelving_time_s <= MAX_SHELVE_S:
            return CallStatus.SHELVING_TIME_OUT_OF_RANGE, []
        timed = {"shelving": ShelvingState.TIMED, "unshelve_time_s": call.shelving_time_s}
        return CallStatus.GOOD, [self._emit(name, "shelved", **timed)]

    def retained(self) -> list[ConditionSnapshot | ConditionEvent]:
        if self.retain_events:
            return [self.events[name] for name, s in self.state.items() if s.retain]
        return [s for s in self.state.values() if s.retain]


# ---- the server and clients -------------------------------------------------------------


async def _nothing(*_: Any) -> list[ua.Variant] | ua.StatusCode:
    return ua.StatusCode(ua.StatusCodes.Good)


def _accept(tag: Tag, value: Any) -> ua.StatusCode | None:
    return None


@dataclass
class Rig:
    tier: TierServer
    url: str
    core: FakeCore
    conditions: UaConditions
    idx: int

    def cid(self, name: str) -> ua.NodeId:
        return ua.NodeId(paths.condition("plc", name), self.idx)

    def child(self, name: str, path: str) -> ua.NodeId:
        return ua.NodeId(f"{paths.condition('plc', name)}.{path}", self.idx)

    def node(self, path: str) -> ua.NodeId:
        return ua.NodeId(path, self.idx)


@pytest.fixture
async def rig(tmp_path: Path) -> AsyncIterator[Rig]:
    tags = plc_tags(SITE)
    methods: dict[str, MethodHandler] = {t.path: _nothing for t in tags if t.kind == "method"}
    writes: dict[str, WriteHandler] = {t.path: _accept for t in tags if t.kind == "variable" and t.writable}
    url = f"opc.tcp://127.0.0.1:{free_port()}/tanklab/plc"
    tier = await start_tier_server(
        "plc",
        url=url,
        name="conditions test",
        security=server_security(tmp_path / "audit"),  # its own: the test reads it whole
        tags=tags,
        writes=writes,
        methods=methods,
    )
    try:
        core = FakeCore()
        conditions = await UaConditions.install(
            tier.server,
            "plc",
            DEFINITIONS,
            handler=core.handle,
            retained=core.retained,
            to_utc=lambda t_s: EPOCH + timedelta(seconds=t_s),
            audit=tier.audit,
            max_time_shelved_s=MAX_SHELVE_S,
        )
        idx = await tier.server.get_namespace_index(NAMESPACE_URI)
        yield Rig(tier, url, core, conditions, idx)
    finally:
        await tier.server.stop()


class Events:
    """A subscription handler collecting events as dicts of the selected fields."""

    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []

    def event_notification(self, event: Any) -> None:
        self.items.append(event.get_event_props_as_fields_dict())

    def values(self, field: str) -> list[Any]:
        return [e[field].Value for e in self.items if field in e]

    def of(self, event_id: bytes) -> dict[str, Any]:
        found = [e for e in self.items if e["EventId"].Value == event_id]
        assert found, f"event {event_id!r} not received"
        return {k: v.Value for k, v in found[-1].items()}


def event_filter(of_type: int | None) -> ua.EventFilter:
    """Select :data:`FIELDS` and the ConditionId; where OfType(``of_type``) if given."""
    f = condition_event_filter(FIELDS)
    if of_type is not None:
        el = ua.ContentFilterElement()
        el.FilterOperator = ua.FilterOperator.OfType
        el.FilterOperands = [ua.LiteralOperand(Value=ua.Variant(ua.NodeId(of_type)))]
        f.WhereClause.Elements.append(el)
    return f


async def subscribe(client: Client, node: ua.NodeId, of_type: int | None, events: Events) -> tuple[Any, int]:
    sub = await client.create_subscription(100, events)
    mid = await sub.subscribe_events(node, ua.ObjectIds.BaseEventType, evfilter=event_filter(of_type))
    return sub, mid  # asyncua answers the server's MonitoredItemId


async def call(client: Client, obj: ua.NodeId, method: ua.NodeId, *args: ua.Variant) -> ua.StatusCode:
    """A raw call (no exception on a Bad status)."""
    req = ua.CallMethodRequest(ObjectId=obj, MethodId=method, InputArguments=list(args))
    (result,) = await client.uaclient.call([req])
    return result.StatusCode


def eid(value: bytes) -> ua.Variant:
    return ua.Variant(value, ua.VariantType.ByteString)


def text(value: str) -> ua.Variant:
    return ua.Variant(ua.LocalizedText(value), ua.VariantType.LocalizedText)


ACK_TYPE = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
CONFIRM_TYPE = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm)
REFRESH = ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh)
REFRESH2 = ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh2)
CONDITION_TYPE = ua.NodeId(ua.ObjectIds.ConditionType)


def code(status: ua.StatusCode) -> str:
    return status.name


# ---- the tests --------------------------------------------------------------------------


async def test_the_nodes_follow_part_9(rig: Rig) -> None:
    async with await secure(rig.url, "observer") as client:
        cond = client.get_node(rig.cid("T1Level"))
        assert (await cond.read_type_definition()) == ua.NodeId(ua.ObjectIds.ExclusiveLevelAlarmType)
        source = client.get_node(rig.node(LEVEL.source))
        conditions = await source.get_referenced_nodes(refs=ua.ObjectIds.HasCondition)
        assert rig.cid("T1Level") in [n.nodeid for n in conditions]
        components = await source.get_referenced_nodes(refs=ua.ObjectIds.HasComponent)
        assert rig.cid("T1Level") in [n.nodeid for n in components]
        # Server -> PLC -> PLC.IO -> PLC.IO.LT1 by HasNotifier, each a notifier.
        chain = [
            ua.NodeId(ua.ObjectIds.Server),
            rig.node("PLC"),
            rig.node(_parent(LEVEL.source)),
            rig.node(LEVEL.source),
        ]
        for parent, child in itertools.pairwise(chain):
            below = await client.get_node(parent).get_referenced_nodes(refs=ua.ObjectIds.HasNotifier)
            assert child in [n.nodeid for n in below], (parent, child)
            notifier = await client.get_node(child).read_attribute(ua.AttributeIds.EventNotifier)
            assert notifier.Value.Value & (1 << ua.EventNotifier.SubscribeToEvents)
        assert await client.get_node(rig.child("T1Level", "HighHighLimit")).read_value() == 1.9
        assert await client.get_node(rig.child("T1Level", "LowLimit")).read_value() == 0.3
        with pytest.raises(ua.UaStatusCodeError):  # not configured: not there
            await client.get_node(rig.child("T1Level", "LowLowLimit")).read_value()
        assert (
            await client.get_node(rig.child("T1Level", "MaxTimeShelved")).read_value() == MAX_SHELVE_S * 1000
        )
        assert await client.get_node(rig.child("T1Level", "InputNode")).read_value() == rig.node(
            LEVEL.input_path or ""
        )
        assert await client.get_node(rig.child("T1Level", "SourceName")).read_value() == "LT1"
        with pytest.raises(ua.UaStatusCodeError):  # no confirmation asked: no ConfirmedState
            await client.get_node(rig.child("T1Level", "ConfirmedState.Id")).read_value()
        # The trip's source is a variable: the interlock object holds the condition.
        assert await client.get_node(rig.child("T1HighHighTrip", "ConfirmedState.Id")).read_value() is True
        normal = await client.get_node(rig.child("T1HighHighTrip", "NormalState")).read_value()
        assert await client.get_node(normal).read_value() is False
        trip_sources = await client.get_node(rig.node(TRIP.source)).get_referenced_nodes(
            refs=ua.ObjectIds.HasCondition
        )
        assert [n.nodeid for n in trip_sources] == [rig.cid("T1HighHighTrip")]
        kind = await client.get_node(rig.cid("LIC1PvBad")).read_type_definition()
        assert kind == ua.NodeId(ua.ObjectIds.DiscreteAlarmType)


async def test_a_server_subscriber_receives_the_condition_events_with_their_fields(rig: Rig) -> None:
    events = Events()
    async with await secure(rig.url, "observer") as client:
        await subscribe(client, ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType, events)
        ev = rig.core.activate("T1Level", LimitState.HIGH)
        await rig.conditions.publish([ev])
        await wait_until(lambda: ev.event_id in events.values("EventId"), 5.0, what="the activation event")
        got = events.of(ev.event_id)
        assert got["EventType"] == ua.NodeId(ua.ObjectIds.ExclusiveLevelAlarmType)
        assert got["NodeId"] == rig.cid("T1Level")
        assert got["SourceNode"] == rig.node(LEVEL.source) and got["SourceName"] == "LT1"
        assert got["ConditionName"] == "T1Level" and got["BranchId"] == ua.NodeId()
        assert got["Time"] == EPOCH + timedelta(seconds=100.0)  # model time, via the tier's clock
        assert got["ReceiveTime"] is not None
        assert got["Severity"] == int(Priority.HIGH) and got["LastSeverity"] == int(Priority.HIGH)
        assert got["Message"].Text == "T1 level High"
        assert got["Retain"] is True and got["EnabledState/Id"] is True
        assert got["ActiveState/Id"] is True and got["ActiveState"].Text == "Active"
        assert got["AckedState/Id"] is False and got["AckedState"].Text == "Unacknowledged"
        assert got["ConfirmedState/Id"] is None  # the definition asks for no confirmation
        assert got["LimitState/CurrentState"].Text == "High"
        assert got["LimitState/CurrentState/Id"] == ua.NodeId(
            ua.ObjectIds.ExclusiveLimitStateMachineType_High
        )
        assert got["ShelvingState/CurrentState"].Text == "Unshelved"
        assert got["Quality"].is_good() and got["SuppressedState/Id"] is False
        assert got["HighLimit"] == 1.7
        # The node holds the same state.
        assert await client.get_node(rig.child("T1Level", "ActiveState.Id")).read_value() is True
        assert await client.get_node(rig.child("T1Level", "EventId")).read_value() == ev.event_id

        # A subscriber on the tier object (PLC) gets it too; one on another source does not.
        on_plc, on_loop = Events(), Events()
        await subscribe(client, rig.node("PLC"), None, on_plc)
        await subscribe(client, rig.node(PV_BAD.source), None, on_loop)
        cleared = rig.core.clear("T1Level")
        await rig.conditions.publish([cleared])
        await wait_until(lambda: cleared.event_id in on_plc.values("EventId"), 5.0, what="the event on PLC")
        await wait_until(
            lambda: cleared.event_id in events.values("EventId"), 5.0, what="the event on Server"
        )
        got = events.of(cleared.event_id)
        assert got["ActiveState/Id"] is False and got["Retain"] is True  # still unacknowledged
        assert got["LimitState/CurrentState/Id"] == ua.NodeId()
        assert cleared.event_id not in on_loop.values("EventId")


async def test_acknowledge_through_the_instance_and_the_type_method(rig: Rig) -> None:
    events = Events()
    async with await secure(rig.url, "operator") as client:
        await subscribe(client, ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType, events)
        first = rig.core.activate("T1Level", LimitState.HIGH_HIGH)
        await rig.conditions.publish([first])
        # Through the instance's own method node, with the condition as ObjectId.
        status = await call(
            client, rig.cid("T1Level"), rig.child("T1Level", "Acknowledge"), eid(first.event_id), text("seen")
        )
        assert code(status) == "Good"
        acked = rig.core.latest["T1Level"]
        await wait_until(lambda: acked in events.values("EventId"), 5.0, what="the acknowledged event")
        got = events.of(acked)
        assert (
            got["AckedState/Id"] is True
            and got["Comment"].Text == "seen"
            and got["ClientUserId"] == "operator"
        )
        assert rig.core.calls[-1] == ConditionCall(
            "T1Level", Method.ACKNOWLEDGE, "operator", first.event_id, "seen"
        )

        # Through the type's method (what UaExpert calls): i=9111 with the condition as ObjectId.
        trip = rig.core.activate("T1HighHighTrip")
        await rig.conditions.publish([trip])
        status = await call(client, rig.cid("T1HighHighTrip"), ACK_TYPE, eid(trip.event_id), text("by type"))
        assert code(status) == "Good"
        status = await call(
            client,
            rig.cid("T1HighHighTrip"),
            CONFIRM_TYPE,
            eid(rig.core.latest["T1HighHighTrip"]),
            text("ok"),
        )
        assert code(status) == "Good"
        confirmed = rig.core.latest["T1HighHighTrip"]
        await wait_until(lambda: confirmed in events.values("EventId"), 5.0, what="the confirmed event")
        got = events.of(confirmed)
        assert (
            got["AckedState/Id"] is True and got["ConfirmedState/Id"] is True and got["Retain"] is True
        )  # still active

    audit = [r for r in read_audit(rig.tier.audit.path) if r["action"] == "call"]
    assert [(r["user"], r["role"], r["node"], r["status"]) for r in audit] == [
        ("operator", "Operator", f"{paths.condition('plc', 'T1Level')}.Acknowledge", "Good"),
        ("operator", "Operator", f"{paths.condition('plc', 'T1HighHighTrip')}.Acknowledge", "Good"),
        ("operator", "Operator", f"{paths.condition('plc', 'T1HighHighTrip')}.Confirm", "Good"),
    ]
    assert audit[0]["new"] == [first.event_id.hex(), "seen"]


async def test_every_refusal_has_its_precise_code(rig: Rig) -> None:
    level, shelve = rig.cid("T1Level"), rig.child("T1Level", "ShelvingState")
    one_shot = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_OneShotShelve)
    timed = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_TimedShelve)
    unshelve = ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_Unshelve)
    disable = ua.NodeId(ua.ObjectIds.ConditionType_Disable)
    enable = ua.NodeId(ua.ObjectIds.ConditionType_Enable)
    ev = rig.core.activate("T1Level", LimitState.HIGH)
    await rig.conditions.publish([ev])
    ms = ua.VariantType.Double

    async with await secure(rig.url, "observer") as observer:
        assert (
            code(await call(observer, level, ACK_TYPE, eid(ev.event_id), text(""))) == "BadUserAccessDenied"
        )
        assert code(await call(observer, shelve, one_shot)) == "BadUserAccessDenied"
    async with await secure(rig.url, "operator") as op:
        assert code(await call(op, level, disable)) == "BadUserAccessDenied"  # Engineer only
        # Arguments: checked before the core sees the call.
        calls_before = len(rig.core.calls)
        assert code(await call(op, level, ACK_TYPE, eid(ev.event_id))) == "BadArgumentsMissing"
        assert (
            code(await call(op, level, ACK_TYPE, eid(ev.event_id), text(""), text("")))
            == "BadTooManyArguments"
        )
        assert code(await call(op, level, ACK_TYPE, text("x"), text(""))) == "BadTypeMismatch"
        wrong_comment = ua.Variant("plain string", ua.VariantType.String)
        assert code(await call(op, level, ACK_TYPE, eid(ev.event_id), wrong_comment)) == "BadTypeMismatch"
        assert code(await call(op, shelve, timed, ua.Variant(60, ua.VariantType.Int32))) == "BadTypeMismatch"
        assert code(await call(op, shelve, timed, ua.Variant(float("nan"), ms))) == "BadTypeMismatch"
        assert code(await call(op, shelve, one_shot, ua.Variant(1.0, ms))) == "BadTooManyArguments"
        assert (
            code(await call(op, rig.node("PLC"), ACK_TYPE, eid(ev.event_id), text(""))) == "BadNodeIdUnknown"
        )
        assert len(rig.core.calls) == calls_before
        # The core's answers, mapped to their StatusCodes.
        assert code(await call(op, level, ACK_TYPE, eid(b"stale"), text(""))) == "BadEventIdUnknown"
        assert code(await call(op, level, ACK_TYPE, eid(ev.event_id), text(""))) == "Good"
        latest = eid(rig.core.latest["T1Level"])
        assert code(await call(op, level, ACK_TYPE, latest, text(""))) == "BadConditionBranchAlreadyAcked"
        assert (
            code(await call(op, level, CONFIRM_TYPE, latest, text(""))) == "BadMethodInvalid"
        )  # not confirmable
        too_long = ua.Variant((MAX_SHELVE_S + 1) * 1000.0, ms)
        assert code(await call(op, shelve, timed, too_long)) == "BadShelvingTimeOutOfRange"
        assert code(await call(op, shelve, unshelve)) == "BadConditionNotShelved"
        assert code(await call(op, shelve, timed, ua.Variant(900_000.0, ms))) == "Good"
        assert rig.core.state["T1Level"].unshelve_time_s == 900.0  # ms -> s
        assert code(await call(op, shelve, one_shot)) == "BadConditionAlreadyShelved"
        # The instance's shelving method, on its ShelvingState object.
        assert code(await call(op, shelve, rig.child("T1Level", "ShelvingState.Unshelve"))) == "Good"
        # An instance method called on another condition is not that condition's.
        wrong_owner = await call(
            op, rig.cid("LIC1PvBad"), rig.child("T1Level", "Acknowledge"), latest, text("")
        )
        assert code(wrong_owner) == "BadMethodInvalid"
    async with await secure(rig.url, "engineer") as eng:
        assert code(await call(eng, level, disable)) == "Good"
        assert code(await call(eng, level, disable)) == "BadConditionAlreadyDisabled"
        latest = eid(rig.core.latest["T1Level"])
        assert code(
            await call(eng, level, ua.NodeId(ua.ObjectIds.ConditionType_AddComment), latest, text("x"))
        ) == ("BadConditionDisabled")
        assert code(await call(eng, level, enable)) == "Good"
        assert code(await call(eng, level, enable)) == "BadConditionAlreadyEnabled"
    refused = [r for r in read_audit(rig.tier.audit.path) if r["action"] == "call" and r["status"] != "Good"]
    assert {r["status"] for r in refused} >= {"BadUserAccessDenied", "BadTypeMismatch", "BadEventIdUnknown"}
    assert all(r["status"] != "BadUnexpectedError" for r in read_audit(rig.tier.audit.path))


async def test_refresh_after_reconnect_delivers_the_retained_conditions(rig: Rig) -> None:
    async with await secure(rig.url, "operator") as client:
        level = rig.core.activate("T1Level", LimitState.LOW)
        pv = rig.core.activate("LIC1PvBad")
        await rig.conditions.publish([level, pv])
        cleared = rig.core.clear("LIC1PvBad")
        await rig.conditions.publish([cleared])
        status = await call(client, rig.cid("LIC1PvBad"), ACK_TYPE, eid(cleared.event_id), text(""))
        assert code(status) == "Good"  # inactive and acknowledged: no longer retained
    last_level = rig.core.latest["T1Level"]

    events = Events()
    async with await secure(rig.url, "observer") as client:  # a new session: nothing seen yet
        sub, mid = await subscribe(
            client, ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType, events
        )
        assert (
            code(
                await call(
                    client, CONDITION_TYPE, REFRESH, ua.Variant(sub.subscription_id, ua.VariantType.UInt32)
                )
            )
            == "Good"
        )
        start, end = (
            ua.NodeId(ua.ObjectIds.RefreshStartEventType),
            ua.NodeId(ua.ObjectIds.RefreshEndEventType),
        )
        await wait_until(lambda: end in events.values("EventType"), 5.0, what="RefreshEnd")
        kinds = events.values("EventType")
        assert kinds[0] == start and kinds[-1] == end  # the brackets pass the OfType filter
        between = events.items[1:-1]
        assert [e["ConditionName"].Value for e in between] == ["T1Level"]
        assert between[0]["EventId"].Value == last_level  # its latest EventId: acknowledgeable
        assert between[0]["LimitState/CurrentState"].Value.Text == "Low"

        # ConditionRefresh2: the one monitored item only; unknown ids refused. (The core answers
        # its latest events this time, as tanklab.alarms.manager does.)
        rig.core.retain_events = True
        events.items.clear()
        args = ua.Variant(sub.subscription_id, ua.VariantType.UInt32), ua.Variant(mid, ua.VariantType.UInt32)
        assert code(await call(client, CONDITION_TYPE, REFRESH2, *args)) == "Good"
        await wait_until(
            lambda: end in events.values("EventType"), 5.0, what="RefreshEnd of ConditionRefresh2"
        )
        assert [e["ConditionName"].Value for e in events.items[1:-1]] == ["T1Level"]
        assert events.items[1]["EventId"].Value == last_level
        async with await secure(rig.url, "engineer") as other:  # another session's subscription
            theirs = ua.Variant(sub.subscription_id, ua.VariantType.UInt32)
            assert code(await call(other, CONDITION_TYPE, REFRESH, theirs)) == "BadSubscriptionIdInvalid"
        unknown = ua.Variant(sub.subscription_id + 1000, ua.VariantType.UInt32)
        assert code(await call(client, CONDITION_TYPE, REFRESH, unknown)) == "BadSubscriptionIdInvalid"
        bad_item = ua.Variant(mid + 1000, ua.VariantType.UInt32)
        assert (
            code(await call(client, CONDITION_TYPE, REFRESH2, args[0], bad_item))
            == "BadMonitoredItemIdInvalid"
        )
        assert (
            code(await call(client, CONDITION_TYPE, REFRESH, ua.Variant(1.0, ua.VariantType.Double)))
            == "BadTypeMismatch"
        )
        assert code(await call(client, CONDITION_TYPE, REFRESH)) == "BadArgumentsMissing"


async def test_of_type_on_a_base_type_receives_subtype_events(rig: Rig) -> None:
    on_alarm, on_limit, on_off_normal, modified = Events(), Events(), Events(), Events()
    async with await secure(rig.url, "observer") as client:
        await subscribe(client, ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType, on_alarm)
        await subscribe(client, ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.LimitAlarmType, on_limit)
        await subscribe(
            client, ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.OffNormalAlarmType, on_off_normal
        )
        level, trip = rig.core.activate("T1Level", LimitState.HIGH), rig.core.activate("T1HighHighTrip")
        await rig.conditions.publish([level, trip])
        await wait_until(lambda: len(on_alarm.items) == 2, 5.0, what="both events on AlarmConditionType")
        await wait_until(lambda: len(on_off_normal.items) == 1, 5.0, what="the trip on OffNormalAlarmType")
        await wait_until(lambda: len(on_limit.items) == 1, 5.0, what="the level on LimitAlarmType")
        assert on_alarm.values("EventId") == [level.event_id, trip.event_id]
        assert on_limit.values("EventId") == [level.event_id]
        assert on_off_normal.values("EventId") == [trip.event_id]

        # ModifyMonitoredItems with a new filter: the new OfType applies (asyncua kept the old
        # evaluator), still by subtype.
        sub, mid = await subscribe(
            client, ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType, modified
        )
        handle = next(h for h, item in sub._monitored_items.items() if item.server_handle == mid)
        request = ua.MonitoredItemModifyRequest()
        request.MonitoredItemId = mid
        request.RequestedParameters = ua.MonitoringParameters(
            ClientHandle=handle,
            SamplingInterval=0.0,
            Filter=event_filter(ua.ObjectIds.DiscreteAlarmType),
            QueueSize=0,
        )
        params = ua.ModifyMonitoredItemsParameters(
            SubscriptionId=sub.subscription_id, ItemsToModify=[request]
        )
        (result,) = await client.uaclient.modify_monitored_items(params)
        assert result.StatusCode.is_good()
        level, trip = rig.core.clear("T1Level"), rig.core.clear("T1HighHighTrip")
        await rig.conditions.publish([level, trip])
        await wait_until(lambda: trip.event_id in on_alarm.values("EventId"), 5.0, what="the trip's clear")
        await wait_until(
            lambda: len(modified.items) == 1, 5.0, what="the trip (OffNormal is a Discrete) only"
        )
        assert modified.values("EventId") == [trip.event_id]


async def _node_alarms(url: str, pki_dir: Path, user: str, condition: str) -> dict[str, Any]:
    """Run tests/node/alarms.mjs once: its JSON result line plus ``rc`` (its exit code)."""
    password = f"{user}-test-password"  # helpers.TEST_PASSWORDS
    return await run_node_script("alarms.mjs", url, str(pki_dir), user, condition, password=password)


@pytest.mark.skipif(NODE is None, reason="node is not installed (node-opcua needs node 20+ and `make tools`)")
async def test_a_node_opcua_client_refreshes_and_acknowledges(rig: Rig, tmp_path: Path) -> None:
    """node-opcua (pinned by tests/node/package-lock.json): OfType AlarmConditionType on the
    Server object, ConditionRefresh, then its ``acknowledgeCondition`` with the refreshed
    event's ConditionId and EventId (it finds the condition's own Acknowledge method)."""
    stamp = NODE_DIR / "node_modules" / ".package-lock.json"
    if not stamp.is_file() or stamp.stat().st_mtime < (NODE_DIR / "package-lock.json").stat().st_mtime:
        pytest.fail(f"{NODE_DIR}/node_modules is missing or older than package-lock.json: run `make tools`")
    ev = rig.core.activate("T1Level", LimitState.HIGH)
    await rig.conditions.publish([ev])
    pki = session_home().pki
    client_pki = tmp_path / "node-opcua-pki"
    for sub, file in (("certs", pki.ca_cert_pem), ("crl", pki.crl_pem)):
        (client_pki / "trusted" / sub).mkdir(parents=True, exist_ok=True)
        shutil.copy(file, client_pki / "trusted" / sub / file.name)
    first = await _node_alarms(rig.url, client_pki, "operator", "T1Level")  # makes its certificate
    assert first["ok"] is False and "BadCertificateUntrusted" in first["error"], first
    trust(pki, Path(first["certificate"]))

    result = await _node_alarms(rig.url, client_pki, "operator", "T1Level")
    assert result["ok"] is True and result["rc"] == 0, result
    assert result["refresh"] == ["T1Level"]
    assert result["eventId"] == ev.event_id.hex()
    assert result["conditionId"] == rig.cid("T1Level").to_string()
    assert (result["ack"], result["acked"]) == ("Good", True)
    assert rig.core.calls[-1] == ConditionCall(
        "T1Level", Method.ACKNOWLEDGE, "operator", ev.event_id, "from node-opcua"
    )
