"""The pure parts of the conditions' projection (no server): the node layout per definition, a
snapshot's values, and the role and argument checks of a method call."""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime

import pytest
from asyncua import ua

from tanklab.alarms.model import (
    AlarmDefinition,
    CallStatus,
    ConditionCall,
    ConditionKind,
    LimitState,
    Method,
    Priority,
    ShelvingState,
)
from tanklab.tags import Role
from tanklab_io.conditions import (
    ALLOWED,
    check_call,
    children_of,
    initial_snapshot,
    snapshot_values,
    status_code,
)
from tanklab_io.conditions.fields import ConditionNode, child_id
from tanklab_io.ua import TankUser

LEVEL = AlarmDefinition(
    name="T1Level",
    kind=ConditionKind.EXCLUSIVE_LEVEL,
    source="src",
    message="T1 level",
    priority=Priority.HIGH,
    limits_m=(1.9, 1.7, None, 0.1),
)
TRIP = AlarmDefinition(
    name="T1Trip",
    kind=ConditionKind.OFF_NORMAL,
    source="src",
    message="trip",
    priority=Priority.URGENT,
    confirm=True,
)
T0 = datetime(2026, 1, 1, tzinfo=UTC)


def _node(d: AlarmDefinition) -> ConditionNode:
    cid = ua.NodeId(f"C.{d.name}", 2)
    return ConditionNode(
        d, cid, ua.NodeId("src", 2), "src", ua.NodeId(), ua.NodeId(), (ua.NodeId(2253),), 600.0
    )


def test_the_layout_follows_the_definition() -> None:
    level = {c.path for c in children_of(LEVEL)}
    trip = {c.path for c in children_of(TRIP)}
    assert {"HighHighLimit", "HighLimit", "LowLowLimit", "LimitState/CurrentState/Id"} <= level
    assert "LowLimit" not in level  # not configured
    assert "ConfirmedState/Id" not in level and "Confirm" not in level  # no confirmation asked
    assert {"ConfirmedState/Id", "Confirm", "NormalState"} <= trip
    assert not {"LimitState", "HighLimit"} & trip
    assert {"ShelvingState/TimedShelve", "Acknowledge", "Enable", "AckedState/Id"} <= level & trip
    assert child_id(ua.NodeId("C.T1Level", 2), "AckedState/Id") == ua.NodeId("C.T1Level.AckedState.Id", 2)


def test_a_snapshot_maps_to_part_9_values() -> None:
    s = replace(
        initial_snapshot(LEVEL),
        active=True,
        acked=False,
        retain=True,
        severity=900,
        quality_good=False,
        shelving=ShelvingState.TIMED,
        unshelve_time_s=12.5,
        limit_state=LimitState.HIGH_HIGH,
    )
    v = {k: x.Value for k, x in snapshot_values(_node(LEVEL), s, b"id-1", T0, T0).items()}
    assert v["EventId"] == b"id-1" and v["Time"] == T0 and v["Severity"] == 900
    assert v["ActiveState"].Text == "Active" and v["ActiveState/Id"] is True
    assert v["AckedState"].Text == "Unacknowledged" and v["AckedState/Id"] is False
    assert v["Quality"].value == ua.StatusCodes.Bad
    assert v["ShelvingState/CurrentState"].Text == "TimedShelved"
    assert v["ShelvingState/CurrentState/Id"] == ua.NodeId(ua.ObjectIds.ShelvedStateMachineType_TimedShelved)
    assert v["ShelvingState/UnshelveTime"] == 12_500.0  # ms
    assert v["SuppressedOrShelved"] is True
    assert v["LimitState/CurrentState/Id"] == ua.NodeId(ua.ObjectIds.ExclusiveLimitStateMachineType_HighHigh)
    assert v["MaxTimeShelved"] == 600_000.0 and v["HighHighLimit"] == 1.9 and "LowLimit" not in v
    assert "ConfirmedState/Id" not in v  # the level alarm has none
    assert v["BranchId"] == ua.NodeId()
    inactive = snapshot_values(_node(LEVEL), replace(s, active=False), b"id-2", T0, T0)
    assert inactive["LimitState/CurrentState/Id"].Value == ua.NodeId()  # no limit while inactive
    trip = snapshot_values(_node(TRIP), initial_snapshot(TRIP), b"", T0, T0)
    assert trip["ConfirmedState"].Value.Text == "Confirmed" and "LimitState/CurrentState" not in trip


def _args(*values: tuple[object, ua.VariantType]) -> list[ua.Variant]:
    return [ua.Variant(v, t) for v, t in values]


ACK_ARGS = _args((b"e", ua.VariantType.ByteString), (ua.LocalizedText("hi"), ua.VariantType.LocalizedText))


@pytest.mark.parametrize("method", list(Method))
def test_roles(method: Method) -> None:
    args = {
        Method.ACKNOWLEDGE: ACK_ARGS,
        Method.CONFIRM: ACK_ARGS,
        Method.ADD_COMMENT: ACK_ARGS,
        Method.TIMED_SHELVE: _args((60_000.0, ua.VariantType.Double)),
    }.get(method, [])
    for role in Role:
        got = check_call("T1Level", method, TankUser.of("u", role), args)
        if role in ALLOWED[method]:
            assert isinstance(got, ConditionCall), (method, role)
        else:
            assert isinstance(got, ua.StatusCode) and got.name == "BadUserAccessDenied", (method, role)
    assert ALLOWED[method] == (
        {Role.ENGINEER} if method in (Method.ENABLE, Method.DISABLE) else {Role.OPERATOR, Role.ENGINEER}
    )
    none = check_call("T1Level", method, None, args)
    assert isinstance(none, ua.StatusCode) and none.name == "BadUserAccessDenied"


def test_arguments() -> None:
    op = TankUser.of("ann", Role.OPERATOR)
    assert check_call("T1Level", Method.ACKNOWLEDGE, op, ACK_ARGS) == ConditionCall(
        "T1Level", Method.ACKNOWLEDGE, "ann", b"e", "hi"
    )
    timed = check_call("T1Level", Method.TIMED_SHELVE, op, _args((90_000.0, ua.VariantType.Double)))
    assert timed == ConditionCall("T1Level", Method.TIMED_SHELVE, "ann", shelving_time_s=90.0)

    def refused(method: Method, args: list[ua.Variant]) -> str:
        got = check_call("T1Level", method, op, args)
        assert isinstance(got, ua.StatusCode)
        return got.name

    assert refused(Method.ACKNOWLEDGE, ACK_ARGS[:1]) == "BadArgumentsMissing"
    assert refused(Method.ACKNOWLEDGE, [*ACK_ARGS, ACK_ARGS[0]]) == "BadTooManyArguments"
    assert refused(Method.ACKNOWLEDGE, [ACK_ARGS[1], ACK_ARGS[0]]) == "BadTypeMismatch"
    as_array = ua.Variant([b"e"], ua.VariantType.ByteString, is_array=True)
    assert refused(Method.ACKNOWLEDGE, [as_array, ACK_ARGS[1]]) == "BadTypeMismatch"
    assert refused(Method.TIMED_SHELVE, _args((-1.0, ua.VariantType.Double))) == "BadTypeMismatch"
    assert refused(Method.TIMED_SHELVE, _args((float("inf"), ua.VariantType.Double))) == "BadTypeMismatch"
    assert refused(Method.TIMED_SHELVE, []) == "BadArgumentsMissing"
    assert refused(Method.UNSHELVE, ACK_ARGS[:1]) == "BadTooManyArguments"


def test_every_call_status_names_a_status_code() -> None:
    for status in CallStatus:
        assert status_code(status).name == status.value
