"""The PLC's condition methods through real plant and PLC processes, node-opcua included (issue 15).

One plant and one PLC for the module (``Stack.serving``; the tests run in file order, each
leaves every condition normal and acknowledged). LIC1 runs MANUAL at its equilibrium flow so T1
stays at its operating level whatever LT1 reads, and the tests move the *reading*: a BIAS fault
on the plant's transmitter (``Plant.LT1.Fault`` / ``FaultValue``) puts it below the low switch
(T1Level Low) or above the high-high limit (T1Level HighHigh and the T1Trip interlock), and
clearing the fault brings it back, within a scan.

* node-opcua (SignAndEncrypt, an Operator, trusting the site CA) subscribes to the Server
  object with a Part 9 field list, receives the live T1Level activation and acknowledges it
  with ``acknowledgeCondition``; the acknowledged event reaches node-opcua and an asyncua
  subscriber;
* Confirm of the latched, to-be-confirmed trip: Retain stays true after Acknowledge and the
  return to normal until Confirm;
* AddComment, Enable / Disable (Engineer only; a disabled condition refuses the others),
  TimedShelve expiring on model time (the stack runs at ``SPEED``: 60 s of shelving are a few
  seconds of wall time; asserted on ``PLC.Status.ModelTime``), OneShotShelve ending at the
  return to normal, and the refusals: BadConditionAlreadyShelved, BadShelvingTimeOutOfRange,
  BadTypeMismatch, BadArgumentsMissing, BadUserAccessDenied, BadConditionDisabled, ...;
* the type's methods with the ConditionId (or the ShelvingState object) as ObjectId, as
  UaExpert calls them, and the instance's own method nodes;
* every call, its user, role and outcome, in the PLC's audit file (``--audit-dir`` of the
  module's own), compared call for call with what each test called.

Waits are bounded (``wait_until``) on events and node values, never on elapsed time.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml
from asyncua import Client, ua

from helpers import free_base_port, secure, session_home, wait_until
from node_client import NODE, NODE_DIR, node_script, run_node_script
from tanklab import paths
from tanklab.alarms import names
from tanklab.alarms.definitions import plc_alarms
from tanklab.alarms.model import LimitState, ShelvingState
from tanklab.config import load_site
from tanklab.enums import SensorFault
from tanklab.tags import NAMESPACE_URI
from tanklab_io.audit import read_audit
from tanklab_io.pki import trust
from tanklab_testing.condition_events import Events, event_filter
from tanklab_testing.sites import ENERGIES, site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

SITE = load_site(ENERGIES)
SPEED = 20.0
"""Model seconds per wall second of the module's stack."""
SCAN_S = SITE.plc.scan_period_s
T1, TRIP, LIC1 = names.level("T1"), names.trip("T1"), "LIC1"
DEFINITIONS = {d.name: d for d in plc_alarms(SITE)}
_T1_LIMITS = DEFINITIONS[T1].limit_priorities
assert _T1_LIMITS is not None
LOW_SEVERITY, HIGH_HIGH_SEVERITY = int(_T1_LIMITS[2]), int(_T1_LIMITS[0])
"""The Low and HighHigh limits' Severity (limit priorities: HighHigh, High, Low, LowLow)."""
TRIP_SEVERITY = int(DEFINITIONS[TRIP].priority)
LOW_M = SITE.plant.tank("T1").switch_levels().low_m
HIGH_HIGH_M = min(i.high_high_m for i in SITE.plc.interlocks if i.tank == "T1")
LT1 = paths.plant.lt("T1")
SHELVE_S = 60.0
"""The timed shelving of the expiry test [s of model time]."""

FIELDS = (
    "EventId",
    "EventType",
    "SourceName",
    "ConditionName",
    "Severity",
    "Message",
    "Retain",
    "ActiveState/Id",
    "AckedState/Id",
    "ConfirmedState/Id",
    "EnabledState/Id",
    "Comment",
    "ClientUserId",
    "ShelvingState/CurrentState",
    "ShelvingState/UnshelveTime",
    "LimitState/CurrentState",
)

OIDS = ua.ObjectIds
ACK = ua.NodeId(OIDS.AcknowledgeableConditionType_Acknowledge)
CONFIRM = ua.NodeId(OIDS.AcknowledgeableConditionType_Confirm)
ADD_COMMENT = ua.NodeId(OIDS.ConditionType_AddComment)
ENABLE, DISABLE = ua.NodeId(OIDS.ConditionType_Enable), ua.NodeId(OIDS.ConditionType_Disable)
ONE_SHOT = ua.NodeId(OIDS.ShelvedStateMachineType_OneShotShelve)
TIMED = ua.NodeId(OIDS.ShelvedStateMachineType_TimedShelve)
UNSHELVE = ua.NodeId(OIDS.ShelvedStateMachineType_Unshelve)
METHOD_NAMES = {
    ACK: "Acknowledge",
    CONFIRM: "Confirm",
    ADD_COMMENT: "AddComment",
    ENABLE: "Enable",
    DISABLE: "Disable",
    ONE_SHOT: "OneShotShelve",
    TIMED: "TimedShelve",
    UNSHELVE: "Unshelve",
}
"""The type methods called here, by the name the audit log gives them (``<condition>.<name>``)."""
ROLES = {"operator": "Operator", "engineer": "Engineer", "observer": "Observer"}


def _config(path: Path) -> Path:
    """The default site at its operating point with LIC1 in MANUAL at its equilibrium flow (the
    initial pump command): T1's level holds while the tests bias its reading. The plant's pumps
    hold their command on the watchdog's timeout: the plant runs (at ``SPEED``) before the PLC
    serves, and its pumps going off would drain the tanks by then."""
    site_config(path, at_operating_point=True, pumps_hold_on_watchdog=True)
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    (loop,) = [lp for lp in data["plc"]["loops"] if lp["name"] == LIC1]
    loop["mode"] = "MANUAL"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


@dataclass
class Rig:
    """The module's stack and the PLC's audit file."""

    stack: Stack
    audit: Path


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    tmp = tmp_path_factory.mktemp("condition-methods")
    audit_dir = tmp / "audit"
    stack = Stack(
        _config(tmp / "site.yaml"),
        free_base_port(3),
        speed=SPEED,
        state_file=tmp / "plant.json",
        tier_args={"plc": ("--audit-dir", str(audit_dir))},
    )
    with stack.serving(("plant", "plc")):
        yield Rig(stack, audit_dir / "plc.log")


# ---- a session on the PLC that keeps what it called ------------------------------------------


@dataclass
class Plc:
    """A connected client of the PLC as ``user``, the Server-object events it received, and the
    audit records its calls must have made (``made``: user, role, node, status)."""

    client: Client
    user: str
    idx: int
    events: Events
    made: list[tuple[str, str, str, str]]

    def cid(self, name: str) -> ua.NodeId:
        return ua.NodeId(paths.condition("plc", name), self.idx)

    def child(self, name: str, path: str) -> ua.NodeId:
        return ua.NodeId(f"{paths.condition('plc', name)}.{path}", self.idx)

    def node(self, path: str) -> ua.NodeId:
        return ua.NodeId(path, self.idx)

    async def read(self, *nodes: ua.NodeId) -> list[Any]:
        return list(await self.client.read_values([self.client.get_node(n) for n in nodes]))

    async def call(self, name: str | None, obj: ua.NodeId, method: ua.NodeId, *args: ua.Variant) -> str:
        """Call ``method`` on ``obj`` (a raw call: a Bad status is answered, not raised); the
        status name. The audit record it must leave is noted: ``<condition>.<method>``, by the
        method's name (a type method) or the instance method node's last element; with no
        condition (``name`` None: ``obj`` is none) ``<obj's NodeId string>.<method>``."""
        req = ua.CallMethodRequest(ObjectId=obj, MethodId=method, InputArguments=list(args))
        (result,) = await self.client.uaclient.call([req])
        status = str(result.StatusCode.name)
        assert status != "BadUnexpectedError"
        what = METHOD_NAMES.get(method) or str(method.Identifier).rsplit(".", 1)[-1]
        where = obj.to_string() if name is None else paths.condition("plc", name)
        self.made.append((self.user, ROLES[self.user], f"{where}.{what}", status))
        return status

    def latest(self, name: str) -> dict[str, Any]:
        return self.events.of(self.cid(name))[-1]

    async def next_event(
        self, name: str, after: int, accept: Callable[[dict[str, Any]], bool], what: str
    ) -> Any:
        """The first event of ``name`` received after the first ``after`` events that ``accept``
        takes (bounded wait)."""

        def found() -> dict[str, Any] | None:
            return next(
                (e for e in self.events.items[after:] if e.get("NodeId") == self.cid(name) and accept(e)),
                None,
            )

        await wait_until(lambda: found() is not None, 60, what=what)
        return found()


@dataclass
class Session:
    """Opens :class:`Plc` sessions (the ones that subscribe) and checks the audit at the end."""

    rig: Rig
    made: list[tuple[str, str, str, str]] = field(default_factory=list)
    clients: list[Client] = field(default_factory=list)

    async def plc(self, user: str, subscribe: bool = False) -> Plc:
        client = await secure(self.rig.stack.plc_url, user, timeout_s=10.0)
        await client.connect()
        self.clients.append(client)
        idx = await client.get_namespace_index(NAMESPACE_URI)
        events = Events()
        if subscribe:
            sub = await client.create_subscription(100, events)
            await sub.subscribe_events(OIDS.Server, OIDS.BaseEventType, evfilter=event_filter(FIELDS))
        return Plc(client, user, idx, events, self.made)

    async def close(self) -> None:
        for client in self.clients:
            await client.disconnect()


@pytest.fixture
async def session(rig: Rig) -> Any:
    """The test's sessions; at the end, every call made is in the audit log, in order, with its
    user, role and outcome (and nothing else was called)."""
    mark = len(read_audit(rig.audit))
    s = Session(rig)
    try:
        yield s
    finally:
        await s.close()
    calls = [r for r in read_audit(rig.audit)[mark:] if r["action"] == "call"]
    assert [(r["user"], r["role"], r["node"], r["status"]) for r in calls] == s.made


# ---- driving the reading ---------------------------------------------------------------------


async def bias_lt1(rig: Rig, reading_m: float | None) -> None:
    """Make LT1 read about ``reading_m`` (a BIAS fault from its fault-free reading now; None:
    no fault)."""
    async with await secure(rig.stack.plant_url, timeout_s=10.0) as plant:
        idx = await plant.get_namespace_index(NAMESPACE_URI)
        fault = plant.get_node(ua.NodeId(LT1.fault, idx))
        await fault.write_value(ua.Variant(int(SensorFault.NONE), ua.VariantType.Int32))
        if reading_m is None:
            return
        now = await plant.get_node(ua.NodeId(LT1.pv, idx)).read_value()
        await plant.get_node(ua.NodeId(LT1.fault_value, idx)).write_value(
            ua.Variant(reading_m - now, ua.VariantType.Double)
        )
        await fault.write_value(ua.Variant(int(SensorFault.BIAS), ua.VariantType.Int32))


LOW_READING_M = LOW_M / 2
"""What LT1 reads for T1Level Low (half the low switch: inside the range, below the deadband)."""
HIGH_HIGH_READING_M = HIGH_HIGH_M + 0.02
"""What LT1 reads for HighHigh and the trip (above the interlock's limit, below the range's top)."""


def eid(event_id: bytes) -> ua.Variant:
    return ua.Variant(event_id, ua.VariantType.ByteString)


def text(comment: str) -> ua.Variant:
    return ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText)


def ms(x: float) -> ua.Variant:
    return ua.Variant(x, ua.VariantType.Double)


def is_active(e: dict[str, Any]) -> bool:
    return e["ActiveState/Id"] is True


def is_normal(e: dict[str, Any]) -> bool:
    return e["ActiveState/Id"] is False


def shelving_is(want: ShelvingState) -> Callable[[dict[str, Any]], bool]:
    """Accepts an event whose ShelvingState is ``want``."""
    return lambda e: state(e, "ShelvingState/CurrentState") == want.value


def state(e: dict[str, Any], path: str) -> str:
    """A state machine's CurrentState text (``ShelvingState/CurrentState``)."""
    return str(e[path].Text)


async def raise_low(rig: Rig, op: Plc) -> dict[str, Any]:
    """Bias LT1 below the low switch: the T1Level activation event (Low, unacknowledged)."""
    mark = len(op.events.items)
    await bias_lt1(rig, LOW_READING_M)
    ev = await op.next_event(T1, mark, is_active, "the T1Level Low activation")
    assert state(ev, "LimitState/CurrentState") == LimitState.LOW.value
    assert ev["AckedState/Id"] is False and ev["Retain"] is True
    return dict(ev)


async def back_to_normal(rig: Rig, op: Plc, acked: bool = True) -> dict[str, Any]:
    """Clear the fault: T1Level's return to normal (not retained when it was acknowledged)."""
    mark = len(op.events.items)
    await bias_lt1(rig, None)
    ev = await op.next_event(T1, mark, is_normal, "the T1Level return to normal")
    assert ev["Retain"] is (not acked)
    return dict(ev)


# ---- 1. node-opcua through the real PLC -----------------------------------------------------


def _require_node_modules() -> None:
    stamp = NODE_DIR / "node_modules" / ".package-lock.json"
    if not stamp.is_file() or stamp.stat().st_mtime < (NODE_DIR / "package-lock.json").stat().st_mtime:
        pytest.fail(f"{NODE_DIR}/node_modules is missing or older than package-lock.json: run `make tools`")


@pytest.mark.skipif(NODE is None, reason="node is not installed (node-opcua needs node 20+ and `make tools`)")
async def test_node_opcua_receives_the_live_t1_low_and_acknowledges_it(
    rig: Rig, session: Session, tmp_path: Path
) -> None:
    _require_node_modules()
    pki = session_home().pki
    client_pki = tmp_path / "node-opcua-pki"
    for sub, file in (("certs", pki.ca_cert_pem), ("crl", pki.crl_pem)):
        (client_pki / "trusted" / sub).mkdir(parents=True, exist_ok=True)
        shutil.copy(file, client_pki / "trusted" / sub / file.name)
    args = (rig.stack.plc_url, str(client_pki), "operator", T1, "120000")
    password = "operator-test-password"  # helpers.TEST_PASSWORDS
    first = await run_node_script("live_alarm.mjs", *args, password=password)  # makes its certificate
    assert first["ok"] is False and "BadCertificateUntrusted" in first["error"], first
    trust(pki, Path(first["certificate"]))

    op = await session.plc("operator", subscribe=True)
    cid = op.cid(T1)
    async with node_script("live_alarm.mjs", *args, password=password) as node:
        await node.line("READY", 60)
        await bias_lt1(rig, LOW_READING_M)
        result = await node.result(150)
    assert result["ok"] is True and result["rc"] == 0, result
    active, acked = result["active"], result["acked"]
    assert active["ConditionName"] == T1 and active["SourceName"] == LT1.name
    assert active["ConditionId"] == cid.to_string()
    assert active["EventType"].endswith(f"i={OIDS.ExclusiveLevelAlarmType}")
    assert (active["ActiveState.Id"], active["AckedState.Id"], active["Retain"]) == (True, False, True)
    assert active["Severity"] == LOW_SEVERITY == 500  # Low: MEDIUM (docs/alarms.md, section 2)
    assert active["Message"] == "T1 level: Low"
    assert result["ack"] == "Good"
    assert (acked["ActiveState.Id"], acked["AckedState.Id"]) == (True, True)
    assert (acked["Comment"], acked["ClientUserId"]) == ("from node-opcua", "operator")
    assert acked["EventId"] != active["EventId"]
    session.made.append(("operator", "Operator", f"{paths.condition('plc', T1)}.Acknowledge", "Good"))

    # The asyncua subscriber saw the same two events.
    await wait_until(
        lambda: any(e["EventId"].hex() == acked["EventId"] for e in op.events.of(cid)),
        30,
        what="the acknowledged event at asyncua",
    )
    seen = {e["EventId"].hex(): e for e in op.events.of(cid)}
    assert seen[active["EventId"]]["AckedState/Id"] is False
    got = seen[acked["EventId"]]
    assert got["AckedState/Id"] is True and got["Comment"].Text == "from node-opcua"
    audit = [r for r in read_audit(rig.audit) if r["action"] == "call"][-1]
    assert audit["new"] == [active["EventId"], "from node-opcua"]

    await back_to_normal(rig, op)


# ---- 2. through the real PLC (asyncua) -------------------------------------------------------


async def test_a_trip_is_retained_until_confirmed_after_ack_and_return(rig: Rig, session: Session) -> None:
    op = await session.plc("operator", subscribe=True)
    eng = await session.plc("engineer")
    trip, level = op.cid(TRIP), op.cid(T1)
    start = mark = len(op.events.items)
    await bias_lt1(rig, HIGH_HIGH_READING_M)
    tripped = await op.next_event(TRIP, mark, is_active, "the T1Trip activation")
    # The trip stops P1 and latches: the reading goes back at once (the level alarm returns to
    # normal, unacknowledged: retained), the trip stays active.
    await bias_lt1(rig, None)
    assert tripped["Severity"] == TRIP_SEVERITY == 900  # URGENT
    assert (tripped["AckedState/Id"], tripped["ConfirmedState/Id"], tripped["Retain"]) == (False, False, True)
    high_high = await op.next_event(T1, mark, is_active, "the T1Level HighHigh activation")
    assert state(high_high, "LimitState/CurrentState") == LimitState.HIGH_HIGH.value
    assert high_high["Severity"] == HIGH_HIGH_SEVERITY == 900

    # Confirm comes after Acknowledge; a level alarm has no confirmation.
    assert await op.call(TRIP, trip, CONFIRM, eid(tripped["EventId"]), text("")) == "BadMethodInvalid"
    assert await op.call(T1, level, CONFIRM, eid(high_high["EventId"]), text("")) == "BadMethodInvalid"
    mark = len(op.events.items)
    assert await op.call(TRIP, trip, ACK, eid(tripped["EventId"]), text("tripped")) == "Good"
    acked = await op.next_event(TRIP, mark, lambda e: e["AckedState/Id"] is True, "the acked trip")
    assert (acked["ActiveState/Id"], acked["ConfirmedState/Id"], acked["Retain"]) == (True, False, True)

    returned_level = await op.next_event(T1, start, is_normal, "the T1Level return to normal")
    assert returned_level["Retain"] is True  # not acknowledged
    (still,) = await op.read(op.child(TRIP, "ActiveState.Id"))
    assert still is True
    # The interlock's reset (a PLC method, audited like the condition calls) ends the trip.
    mark = len(op.events.items)
    req = ua.CallMethodRequest(
        ObjectId=op.node(paths.plc.interlocks), MethodId=op.node(paths.plc.interlock_reset), InputArguments=[]
    )
    (result,) = await eng.client.uaclient.call([req])
    assert result.StatusCode.is_good()
    session.made.append(("engineer", "Engineer", paths.plc.interlock_reset, "Good"))
    returned = await op.next_event(TRIP, mark, is_normal, "the trip's return to normal")
    assert (returned["AckedState/Id"], returned["ConfirmedState/Id"]) == (True, False)
    assert returned["Retain"] is True  # to be confirmed

    # Confirm: with a superseded EventId unknown, with the latest Good, then Retain false.
    assert await op.call(TRIP, trip, CONFIRM, eid(acked["EventId"]), text("")) == "BadEventIdUnknown"
    mark = len(op.events.items)
    assert await op.call(TRIP, trip, CONFIRM, eid(returned["EventId"]), text("back")) == "Good"
    confirmed = await op.next_event(
        TRIP, mark, lambda e: e["ConfirmedState/Id"] is True, "the confirmed trip"
    )
    assert (confirmed["ActiveState/Id"], confirmed["AckedState/Id"], confirmed["Retain"]) == (
        False,
        True,
        False,
    )
    again = await op.call(TRIP, trip, CONFIRM, eid(confirmed["EventId"]), text(""))
    assert again == "BadConditionBranchAlreadyConfirmed"

    # The level alarm, normal and unacknowledged, goes once acknowledged.
    mark = len(op.events.items)
    assert await op.call(T1, level, ACK, eid(op.latest(T1)["EventId"]), text("")) == "Good"
    gone = await op.next_event(T1, mark, lambda e: e["AckedState/Id"] is True, "the acked level alarm")
    assert gone["Retain"] is False


async def test_comment_and_enable_disable_by_engineer_only(rig: Rig, session: Session) -> None:
    op = await session.plc("operator", subscribe=True)
    eng = await session.plc("engineer")
    level = op.cid(T1)
    active = await raise_low(rig, op)

    # AddComment (the type's method on the ConditionId): Comment and ClientUserId, still unacked.
    mark = len(op.events.items)
    comment = "LT1 reads low, checking the transmitter"
    assert await op.call(T1, level, ADD_COMMENT, eid(active["EventId"]), text(comment)) == "Good"
    commented = await op.next_event(T1, mark, lambda e: e["Comment"].Text == comment, "the comment event")
    assert commented["ClientUserId"] == "operator"
    assert (commented["ActiveState/Id"], commented["AckedState/Id"]) == (True, False)
    (record,) = [r for r in read_audit(rig.audit) if r["node"].endswith(".AddComment")]
    assert record["new"] == [active["EventId"].hex(), comment] and record["status"] == "Good"
    (node_comment, node_user) = await op.read(op.child(T1, "Comment"), op.child(T1, "ClientUserId"))
    assert (node_comment.Text, node_user) == (comment, "operator")

    # Enable / Disable are the Engineer's.
    assert await op.call(T1, level, DISABLE) == "BadUserAccessDenied"
    assert await op.call(T1, level, ENABLE) == "BadUserAccessDenied"
    mark = len(op.events.items)
    assert await eng.call(T1, level, DISABLE) == "Good"
    disabled = await op.next_event(T1, mark, lambda e: e["EnabledState/Id"] is False, "the disabled event")
    assert disabled["Retain"] is False
    assert await eng.call(T1, level, DISABLE) == "BadConditionAlreadyDisabled"

    # A disabled condition refuses the operator's methods (on the condition and its ShelvingState).
    latest = eid(disabled["EventId"])
    shelving = op.child(T1, "ShelvingState")
    assert await op.call(T1, level, ACK, latest, text("")) == "BadConditionDisabled"
    assert await op.call(T1, level, ADD_COMMENT, latest, text("x")) == "BadConditionDisabled"
    assert await op.call(T1, shelving, ONE_SHOT) == "BadConditionDisabled"
    assert await op.call(T1, shelving, TIMED, ms(60_000.0)) == "BadConditionDisabled"
    (enabled_node,) = await op.read(op.child(T1, "EnabledState.Id"))
    assert enabled_node is False

    # Enable: still low, so a new activation to acknowledge.
    mark = len(op.events.items)
    assert await eng.call(T1, level, ENABLE) == "Good"
    enabled = await op.next_event(T1, mark, lambda e: e["EnabledState/Id"] is True, "the enabled event")
    assert (enabled["ActiveState/Id"], enabled["AckedState/Id"], enabled["Retain"]) == (True, False, True)
    assert await eng.call(T1, level, ENABLE) == "BadConditionAlreadyEnabled"
    mark = len(op.events.items)
    assert await op.call(T1, level, ACK, eid(enabled["EventId"]), text("")) == "Good"
    await op.next_event(T1, mark, lambda e: e["AckedState/Id"] is True, "the acked event")
    await back_to_normal(rig, op)


async def test_bad_arguments_and_a_timed_shelve_expiring_on_model_time(rig: Rig, session: Session) -> None:
    op = await session.plc("operator", subscribe=True)
    level, shelving = op.cid(T1), op.child(T1, "ShelvingState")
    active = await raise_low(rig, op)
    mark = len(op.events.items)
    assert await op.call(T1, level, ACK, eid(active["EventId"]), text("")) == "Good"
    await op.next_event(T1, mark, lambda e: e["AckedState/Id"] is True, "the acked event")

    # Wrong argument counts and types: answered before the alarm core sees the call.
    latest = eid(op.latest(T1)["EventId"])
    assert await op.call(T1, level, ACK, latest) == "BadArgumentsMissing"
    assert await op.call(T1, level, ACK) == "BadArgumentsMissing"
    assert await op.call(T1, level, ACK, ua.Variant("not bytes", ua.VariantType.String), text("")) == (
        "BadTypeMismatch"
    )
    assert await op.call(T1, level, ACK, latest, ua.Variant(7, ua.VariantType.Int32)) == "BadTypeMismatch"
    assert await op.call(T1, shelving, TIMED) == "BadArgumentsMissing"
    assert await op.call(T1, shelving, TIMED, ua.Variant(60_000, ua.VariantType.Int32)) == "BadTypeMismatch"
    assert await op.call(T1, shelving, TIMED, ua.Variant("60 s", ua.VariantType.String)) == "BadTypeMismatch"
    # Longer than MaxTimeShelved [ms]: out of range.
    (max_ms,) = await op.read(op.child(T1, "MaxTimeShelved"))
    assert max_ms == SITE.plc.alarms.max_shelving_time_s * 1000.0
    assert await op.call(T1, shelving, TIMED, ms(max_ms + 1000.0)) == "BadShelvingTimeOutOfRange"
    assert await op.call(T1, shelving, TIMED, ms(0.0)) == "BadShelvingTimeOutOfRange"
    # A negative ShelvingTime is no Duration (like NaN and infinity): the projection's type check.
    assert await op.call(T1, shelving, TIMED, ms(-1000.0)) == "BadTypeMismatch"
    assert await op.call(T1, level, ACK, latest, text(""), text("")) == "BadTooManyArguments"
    # An ObjectId that is no condition (the level's loop object).
    assert await op.call(None, op.node("PLC.LIC1"), ACK, latest, text("")) == "BadNodeIdUnknown"

    # TimedShelve for SHELVE_S, the type's method with the ConditionId as ObjectId (UaExpert's way).
    model_time = op.node(paths.plc.model_time)
    shelving_state = op.child(T1, "ShelvingState.CurrentState")
    (t0,) = await op.read(model_time)
    mark = len(op.events.items)
    assert await op.call(T1, level, TIMED, ms(SHELVE_S * 1000.0)) == "Good"
    (t1,) = await op.read(model_time)
    shelved = await op.next_event(T1, mark, shelving_is(ShelvingState.TIMED), "shelved")
    assert shelved["ShelvingState/UnshelveTime"] == pytest.approx(SHELVE_S * 1000.0)
    assert await op.call(T1, shelving, TIMED, ms(SHELVE_S * 1000.0)) == "BadConditionAlreadyShelved"

    # It expires on model time: sampled (model time, state) pairs, each from one Read, until the
    # node shows Unshelved. The shelving ends at the first scan at or after the call's model time
    # (between t0 and t1) plus SHELVE_S; a Read's two values may be one scan apart.
    samples: list[tuple[float, str]] = []

    async def unshelved() -> bool:
        t, current = await op.read(model_time, shelving_state)
        samples.append((t, current.Text))
        return bool(current.Text == ShelvingState.UNSHELVED.value)

    await wait_until(unshelved, 60, what="the timed shelving's expiry")
    shelved_at = [t for t, s in samples if s == ShelvingState.TIMED.value]
    first_unshelved = next(t for t, s in samples if s == ShelvingState.UNSHELVED.value)
    assert shelved_at, "no sample while shelved"
    assert max(shelved_at) <= t1 + SHELVE_S + SCAN_S
    assert first_unshelved >= t0 + SHELVE_S - SCAN_S
    expired = await op.next_event(T1, mark, shelving_is(ShelvingState.UNSHELVED), "expired")
    assert expired["Message"].Text == "T1 level: Low"  # the state's message; still low
    assert expired["ShelvingState/UnshelveTime"] == 0.0
    assert expired["ActiveState/Id"] is True  # still low, now annunciated again

    # The instance's own TimedShelve node on its ShelvingState, then the type's Unshelve.
    own_timed = op.child(T1, "ShelvingState.TimedShelve")
    mark = len(op.events.items)
    assert await op.call(T1, shelving, own_timed, ms(SHELVE_S * 1000.0)) == "Good"
    await op.next_event(T1, mark, shelving_is(ShelvingState.TIMED), "shelved")
    mark = len(op.events.items)
    assert await op.call(T1, shelving, UNSHELVE) == "Good"
    await op.next_event(
        T1,
        mark,
        shelving_is(ShelvingState.UNSHELVED),
        "unshelved",
    )
    assert await op.call(T1, shelving, UNSHELVE) == "BadConditionNotShelved"
    await back_to_normal(rig, op)


async def test_a_one_shot_shelve_ends_at_the_return_to_normal(rig: Rig, session: Session) -> None:
    op = await session.plc("operator", subscribe=True)
    level, shelving = op.cid(T1), op.child(T1, "ShelvingState")
    active = await raise_low(rig, op)
    own_one_shot = op.child(T1, "ShelvingState.OneShotShelve")
    mark = len(op.events.items)
    assert await op.call(T1, shelving, own_one_shot) == "Good"
    shelved = await op.next_event(T1, mark, shelving_is(ShelvingState.ONE_SHOT), "shelved")
    assert shelved["ActiveState/Id"] is True
    assert await op.call(T1, shelving, ONE_SHOT) == "BadConditionAlreadyShelved"
    assert await op.call(T1, level, ONE_SHOT) == "BadConditionAlreadyShelved"  # ConditionId as object
    mark = len(op.events.items)
    assert await op.call(T1, level, ACK, eid(shelved["EventId"]), text("")) == "Good"
    assert active["EventId"] != shelved["EventId"]
    await op.next_event(T1, mark, lambda e: e["AckedState/Id"] is True, "the acked event")

    normal = await back_to_normal(rig, op)
    await wait_until(
        lambda: state(op.latest(T1), "ShelvingState/CurrentState") == ShelvingState.UNSHELVED.value,
        60,
        what="the one-shot shelving's end",
    )
    assert state(normal, "ShelvingState/CurrentState") in (
        ShelvingState.ONE_SHOT.value,
        ShelvingState.UNSHELVED.value,
    )
    (now,) = await op.read(op.child(T1, "ShelvingState.CurrentState"))
    assert now.Text == ShelvingState.UNSHELVED.value
