"""A condition method call's checks, before the alarm core sees it: role, argument count and types.

Pure (no server): :func:`check_call` turns the Variants a client sent into a
:class:`~tanklab.alarms.model.ConditionCall`, or the StatusCode that refuses it, in this order:

1. the role (:data:`ALLOWED`): Operator and Engineer acknowledge, confirm, comment and shelve;
   only Engineer enables and disables; anyone else (Observer, the tiers' own identities, a
   session without a tanklab role) gets BadUserAccessDenied;
2. the count: fewer than the method's inputs -> BadArgumentsMissing, more ->
   BadTooManyArguments;
3. each argument's built-in type (:data:`INPUTS`, Part 9's signatures: EventId ByteString,
   Comment LocalizedText, ShelvingTime Duration = Double in ms) -> BadTypeMismatch, and a
   ShelvingTime that is not a finite number >= 0 -> BadTypeMismatch too (no Duration is NaN).

None of these answers BadUnexpectedError (what asyncua answers for a handler that raises).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from asyncua import ua
from asyncua.crypto.permission_rules import User

from tanklab.alarms.model import CallStatus, ConditionCall, Method
from tanklab.tags import Role
from tanklab_io.ua import TankUser

_ACK_ROLES = frozenset({Role.OPERATOR, Role.ENGINEER})

ALLOWED: dict[Method, frozenset[Role]] = {
    Method.ACKNOWLEDGE: _ACK_ROLES,
    Method.CONFIRM: _ACK_ROLES,
    Method.ADD_COMMENT: _ACK_ROLES,
    Method.ONE_SHOT_SHELVE: _ACK_ROLES,
    Method.TIMED_SHELVE: _ACK_ROLES,
    Method.UNSHELVE: _ACK_ROLES,
    Method.ENABLE: frozenset({Role.ENGINEER}),
    Method.DISABLE: frozenset({Role.ENGINEER}),
}
"""The roles that may call each method."""

_COMMENTED = (("EventId", ua.VariantType.ByteString), ("Comment", ua.VariantType.LocalizedText))

INPUTS: dict[Method, tuple[tuple[str, ua.VariantType], ...]] = {
    Method.ACKNOWLEDGE: _COMMENTED,
    Method.CONFIRM: _COMMENTED,
    Method.ADD_COMMENT: _COMMENTED,
    Method.ENABLE: (),
    Method.DISABLE: (),
    Method.ONE_SHOT_SHELVE: (),
    Method.TIMED_SHELVE: (("ShelvingTime", ua.VariantType.Double),),
    Method.UNSHELVE: (),
}
"""Each method's input arguments (name, built-in type), in order."""


def status_code(status: CallStatus) -> ua.StatusCode:
    """The StatusCode named by a :class:`CallStatus` (``BadEventIdUnknown`` -> 0x809A0000)."""
    return ua.StatusCode(getattr(ua.StatusCodes, status.value))


def _bad(name: str) -> ua.StatusCode:
    return ua.StatusCode(getattr(ua.StatusCodes, name))


def role_of(user: User | None) -> Role | None:
    """The tanklab role a session acts in (None: asyncua's own users, no session)."""
    return user.tank_role if isinstance(user, TankUser) else None


def check_call(
    condition: str, method: Method, user: User | None, args: Sequence[ua.Variant]
) -> ConditionCall | ua.StatusCode:
    """The call to hand to the alarm core, or the status refusing it (see the module doc)."""
    role = role_of(user)
    if role is None or role not in ALLOWED[method]:
        return _bad("BadUserAccessDenied")
    inputs = INPUTS[method]
    if len(args) < len(inputs):
        return _bad("BadArgumentsMissing")
    if len(args) > len(inputs):
        return _bad("BadTooManyArguments")
    values = []
    for (_, want), arg in zip(inputs, args, strict=True):
        if not isinstance(arg, ua.Variant) or arg.VariantType != want or isinstance(arg.Value, list):
            return _bad("BadTypeMismatch")
        values.append(arg.Value)
    name = (user.name if user is not None else None) or ""
    if method == Method.TIMED_SHELVE:
        ms = values[0]
        if not isinstance(ms, float) or not math.isfinite(ms) or ms < 0:
            return _bad("BadTypeMismatch")
        return ConditionCall(condition, method, name, shelving_time_s=ms / 1000.0)
    if inputs:
        event_id = values[0] if isinstance(values[0], bytes) else b""
        text = values[1].Text if isinstance(values[1], ua.LocalizedText) else None
        return ConditionCall(condition, method, name, event_id=event_id, comment=text or "")
    return ConditionCall(condition, method, name)


def shown(args: Sequence[ua.Variant]) -> list[object]:
    """A call's arguments as the audit log shows them (EventIds in hex, comments as text)."""
    out: list[object] = []
    for a in args:
        v = a.Value if isinstance(a, ua.Variant) else a
        if isinstance(v, bytes):
            out.append(v.hex())
        elif isinstance(v, ua.LocalizedText):
            out.append(v.Text or "")
        else:
            out.append(v if isinstance(v, str | int | float | bool) or v is None else repr(v))
    return out
