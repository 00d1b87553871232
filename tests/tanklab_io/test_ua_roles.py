"""Pure checks of the role and method-call rules of :mod:`tanklab_io.ua` (no server needed)."""

from __future__ import annotations

from typing import Any

from asyncua import ua

from tanklab.enums import LoopMode
from tanklab.tags import Argument, DataType, Role, Tag
from tanklab_io.audit import AuditLog, read_audit
from tanklab_io.ua import CURRENT_USER, TankUser, _method_adapter, authorize, who

MODE = Tag(
    path="PLC.LIC1.Mode",
    tier="plc",
    kind="variable",
    description="mode",
    data_type=DataType.INT32,
    writers=frozenset({Role.OPERATOR, Role.ENGINEER, Role.SUPERVISOR}),
    restricted=((Role.SUPERVISOR, frozenset({int(LoopMode.AUTO), int(LoopMode.REMOTE)})),),
    enum=LoopMode,
)
GAINS = Tag(
    path="PLC.LIC1.SetGains",
    tier="plc",
    kind="method",
    description="gains",
    writers=frozenset({Role.ENGINEER, Role.SUPERVISOR}),
    inputs=(
        Argument("Kp", DataType.DOUBLE, ""),
        Argument("Ki", DataType.DOUBLE, ""),
        Argument("Kd", DataType.DOUBLE, ""),
    ),
)


def test_authorize_follows_writers_and_restrictions() -> None:
    op, sup = TankUser.of("ann", Role.OPERATOR), TankUser.of("supervisor", Role.SUPERVISOR)
    obs = TankUser.of("olga", Role.OBSERVER)
    auto, manual, remote = int(LoopMode.AUTO), int(LoopMode.MANUAL), int(LoopMode.REMOTE)
    assert authorize(MODE, op, auto, manual) is None
    assert authorize(MODE, sup, auto, remote) is None
    assert authorize(MODE, sup, remote, auto) is None
    denied = ua.StatusCodes.BadUserAccessDenied
    assert authorize(MODE, sup, auto, manual).value == denied  # type: ignore[union-attr]
    assert authorize(MODE, sup, manual, remote).value == denied  # type: ignore[union-attr]
    assert authorize(MODE, sup, auto, "REMOTE").value == denied  # type: ignore[union-attr]
    assert authorize(MODE, obs, auto, auto).value == denied  # type: ignore[union-attr]
    assert authorize(MODE, None, auto, auto).value == denied  # type: ignore[union-attr]
    # asyncua's own users (no tanklab role, e.g. its Admin) are nobody here.
    from asyncua.crypto.permission_rules import User, UserRole

    assert authorize(MODE, User(role=UserRole.Admin, name="admin"), auto, auto).value == denied  # type: ignore[union-attr]
    assert who(op) == ("ann", "Operator") and who(None) == ("", "none")


async def test_a_failing_handler_answers_bad_internal_error_and_is_audited(tmp_path: Any) -> None:
    """Regression: asyncua answers a raising handler with BadUnexpectedError; ours is precise."""

    async def broken(kp: float, ki: float, kd: float) -> ua.StatusCode:
        raise RuntimeError("bug")

    audit = AuditLog(tmp_path, "plc")
    call = _method_adapter(GAINS, broken, audit)
    args = [ua.Variant(v, ua.VariantType.Double) for v in (1.0, 2.0, 3.0)]
    token = CURRENT_USER.set(TankUser.of("eve", Role.ENGINEER))
    try:
        result = await call(ua.NodeId("PLC.LIC1", 2), *args)
        assert result.value == ua.StatusCodes.BadInternalError
        short = await call(ua.NodeId("PLC.LIC1", 2), *args[:2])
        assert short.value == ua.StatusCodes.BadArgumentsMissing
        wrong = await call(ua.NodeId("PLC.LIC1", 2), ua.Variant(1, ua.VariantType.Int32), *args[1:])
        assert wrong.value == ua.StatusCodes.BadTypeMismatch
    finally:
        CURRENT_USER.reset(token)
    token = CURRENT_USER.set(TankUser.of("ann", Role.OPERATOR))
    try:
        denied = await call(ua.NodeId("PLC.LIC1", 2), *args)
        assert denied.value == ua.StatusCodes.BadUserAccessDenied
    finally:
        CURRENT_USER.reset(token)
    records = read_audit(audit.path)
    assert [(r["user"], r["status"]) for r in records] == [
        ("eve", "BadInternalError"),
        ("eve", "BadArgumentsMissing"),
        ("eve", "BadTypeMismatch"),
        ("ann", "BadUserAccessDenied"),
    ]
    assert records[0]["new"] == [1.0, 2.0, 3.0] and records[0]["node"] == "PLC.LIC1.SetGains"
