"""asyncua adapter of the address-space contract: build nodes, guard writes, resolve on clients.

This is the one module of the shared kernel that touches asyncua; every tier's ``server.py``
and ``link.py`` go through it, so the contract in :mod:`tanklab.tags` is realised the same way
everywhere.

Server side
    :func:`build_nodes` creates the objects along the dotted paths and one node per tag:
    AnalogItemType variables (EURange, EngineeringUnits), MultiStateDiscreteType Int32 variables
    (EnumStrings), plain variables, and methods with named arguments. :class:`WriteGuard`
    replaces the server's attribute service so that every client write to a tanklab node is
    validated before it is stored: wrong type -> BadTypeMismatch; NaN, infinity, outside
    EURange, unknown enum value -> BadOutOfRange; a non-Good status in the written DataValue ->
    BadWriteNotSupported; a read-only node -> BadNotWritable; a role not among the tag's
    writers (or a restricted role moving the value outside its allowed set) ->
    BadUserAccessDenied; the tier's own check may refuse with any status. A refused write leaves
    the old value. The tier's check is the handler it attached to that tag
    (:class:`tanklab.handlers.HandlerTable`, one per writable tag). Writes of a batch are
    judged one by one (each item gets its own status; accepted items are stored even if others
    are refused: a batch is not atomic). A
    client-supplied SourceTimestamp is ignored: the server stamps its own time. Method calls get
    the same role check and precise status codes. Every write and call, accepted or refused, is
    recorded in the tier's :class:`~tanklab_io.audit.AuditLog`.

Who is asking
    The session's user is a :class:`TankUser` (made by
    :class:`tanklab_io.ua_security.TankUserManager`); the request being served sets
    :data:`CURRENT_USER` (a context variable of the request's task) so that method handlers,
    which asyncua calls without the session, know it too.

Client side
    :func:`resolve` looks the namespace index of ``urn:tanklab`` up and returns the nodes of the
    given paths; :func:`read_values` reads many values in one Read. :class:`Link` is the tiers'
    client of the tier below: bounded requests, reconnection with capped exponential backoff and
    jitter (:func:`backoff_delay`, a pure function of the attempt number and a random source),
    one log line per failed attempt (a warning in the tiers), and its attempts and last error for
    status nodes.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import logging
import math
import random
from collections.abc import Awaitable, Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from asyncua import Client, Node, Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.address_space import AttributeService

from tanklab.clock import Clock, MonotonicClock
from tanklab.errors import LinkError
from tanklab.tags import NAMESPACE_URI, DataType, Role, Tag, link_status_paths
from tanklab_io.audit import AuditLog

log = logging.getLogger(__name__)

_VARIANT = {
    DataType.DOUBLE: ua.VariantType.Double,
    DataType.INT32: ua.VariantType.Int32,
    DataType.UINT32: ua.VariantType.UInt32,
    DataType.BOOLEAN: ua.VariantType.Boolean,
    DataType.STRING: ua.VariantType.String,
    DataType.DOUBLE_ARRAY: ua.VariantType.Double,
}
_DATATYPE_ID = {
    DataType.DOUBLE: ua.ObjectIds.Double,
    DataType.INT32: ua.ObjectIds.Int32,
    DataType.UINT32: ua.ObjectIds.UInt32,
    DataType.BOOLEAN: ua.ObjectIds.Boolean,
    DataType.STRING: ua.ObjectIds.String,
    DataType.DOUBLE_ARRAY: ua.ObjectIds.Double,
}

MethodHandler = Callable[..., Awaitable[list[ua.Variant] | ua.StatusCode]]
"""A method implementation: ``async (*python_args) -> outputs or StatusCode``."""

WriteHandler = Callable[[Tag, Any], ua.StatusCode | None]
"""A tier's own check and apply for a validated write of one tag (one handler per writable tag,
:class:`tanklab.handlers.HandlerTable`): None accepts, a StatusCode refuses."""


@dataclass
class TankUser(User):
    """A session's user: asyncua's non-admin user plus the tanklab role it acts in."""

    tank_role: Role | None = None

    @classmethod
    def of(cls, name: str, role: Role) -> TankUser:
        """A user ``name`` acting as ``role`` (never asyncua's Admin)."""
        return cls(role=UserRole.User, name=name, tank_role=role)


CURRENT_USER: contextvars.ContextVar[User | None] = contextvars.ContextVar(
    "tanklab_current_user", default=None
)
"""The user of the request being served (set per request by the secure message processor)."""


def who(user: User | None) -> tuple[str, str]:
    """(user name, role name) of a session user, for refusals and the audit trail."""
    if isinstance(user, TankUser) and user.tank_role is not None:
        return user.name or "", user.tank_role.value
    return (user.name or "") if user is not None else "", "none"


def authorize(tag: Tag, user: User | None, old: Any = None, new: Any = None) -> ua.StatusCode | None:
    """Whether ``user`` may write ``new`` over ``old`` (or call the method): None, or
    BadUserAccessDenied.

    The role must be among the tag's writers; a role listed in ``tag.restricted`` may only
    move an enumerated value between the listed values (both old and new among them).
    """
    role = user.tank_role if isinstance(user, TankUser) else None
    if role is None or role not in tag.writers:
        return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
    allowed = dict(tag.restricted).get(role)
    if allowed is not None:
        try:
            if int(old) not in allowed or int(new) not in allowed:
                return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
        except (TypeError, ValueError):
            return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
    return None


def _python_value(data_type: DataType, value: Any) -> Any:
    """``value`` as the Python type a tag of ``data_type`` stores (arrays as lists of float)."""
    if data_type == DataType.DOUBLE_ARRAY:
        return [float(v) for v in value]
    if data_type == DataType.DOUBLE:
        return float(value)
    if data_type in (DataType.INT32, DataType.UINT32):
        return int(value)
    if data_type == DataType.BOOLEAN:
        return bool(value)
    return str(value)


def variant(tag: Tag, value: Any) -> ua.Variant:
    """The Variant a tag's value is stored as (arrays as Double arrays)."""
    if tag.data_type is None:
        raise ValueError(f"{tag.path} is a method, not a variable")
    return _stored(tag.data_type, _python_value(tag.data_type, value))


def _stored(data_type: DataType, value: Any) -> ua.Variant:
    """The Variant of a value already of its Python type (:func:`_python_value`)."""
    return ua.Variant(value, _VARIANT[data_type], is_array=data_type == DataType.DOUBLE_ARRAY)


def _argument(arg: Any) -> ua.Argument:
    a = ua.Argument()
    a.Name = arg.name
    a.DataType = ua.NodeId(_DATATYPE_ID[arg.data_type])
    a.ValueRank = 1 if arg.data_type == DataType.DOUBLE_ARRAY else -1
    a.ArrayDimensions = []
    unit = f" [{arg.unit}]" if arg.unit else ""
    a.Description = ua.LocalizedText(arg.description + unit)
    return a


async def _ensure_object(server: Server, idx: int, path: str, objects: dict[str, Node]) -> Node:
    if path in objects:
        return objects[path]
    if "." in path:
        parent = await _ensure_object(server, idx, path.rsplit(".", 1)[0], objects)
    else:
        parent = server.nodes.objects
    name = path.rsplit(".", 1)[-1]
    node = await parent.add_object(ua.NodeId(path, idx), ua.QualifiedName(name, idx))
    objects[path] = node
    return node


async def _add_variable(server: Server, idx: int, parent: Node, tag: Tag) -> Node:
    assert tag.data_type is not None
    attrs = ua.VariableAttributes()
    attrs.DisplayName = ua.LocalizedText(tag.name)
    attrs.Description = ua.LocalizedText(tag.description)
    attrs.Value = variant(tag, tag.initial_value())
    attrs.DataType = ua.NodeId(_DATATYPE_ID[tag.data_type])
    is_array = tag.data_type == DataType.DOUBLE_ARRAY
    attrs.ValueRank = 1 if is_array else -1
    attrs.ArrayDimensions = [0] if is_array else []
    level = ua.AccessLevel.CurrentRead.mask
    if tag.writable:
        level |= ua.AccessLevel.CurrentWrite.mask
    attrs.AccessLevel = level
    attrs.UserAccessLevel = level
    attrs.WriteMask = 0
    attrs.UserWriteMask = 0
    attrs.Historizing = False
    if tag.enum is not None:
        typedef = ua.ObjectIds.MultiStateDiscreteType
    elif tag.analog:
        typedef = ua.ObjectIds.AnalogItemType
    else:
        typedef = ua.ObjectIds.BaseDataVariableType
    item = ua.AddNodesItem()
    item.RequestedNewNodeId = ua.NodeId(tag.path, idx)
    item.BrowseName = ua.QualifiedName(tag.name, idx)
    item.NodeClass = ua.NodeClass.Variable
    item.ParentNodeId = parent.nodeid
    item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
    item.TypeDefinition = ua.NodeId(typedef)
    item.NodeAttributes = attrs
    result = (await server.iserver.isession.add_nodes([item]))[0]
    result.StatusCode.check()
    node = server.get_node(result.AddedNodeId)
    if tag.enum is not None:
        names = [ua.LocalizedText(m.name) for m in sorted(tag.enum, key=int)]
        await node.add_property(
            ua.NodeId(f"{tag.path}.EnumStrings", idx),
            ua.QualifiedName("EnumStrings", 0),
            ua.Variant(names, ua.VariantType.LocalizedText, is_array=True),
        )
    if tag.eu_range is not None:
        rng = ua.Range(Low=float(tag.eu_range[0]), High=float(tag.eu_range[1]))
        await node.add_property(ua.NodeId(f"{tag.path}.EURange", idx), ua.QualifiedName("EURange", 0), rng)
    if tag.unit is not None:
        eu = ua.EUInformation(
            NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact",
            UnitId=-1,
            DisplayName=ua.LocalizedText(tag.unit),
            Description=ua.LocalizedText(tag.unit),
        )
        await node.add_property(
            ua.NodeId(f"{tag.path}.EngineeringUnits", idx), ua.QualifiedName("EngineeringUnits", 0), eu
        )
    return node


async def build_nodes(
    server: Server,
    tags: Iterable[Tag],
    methods: Mapping[str, MethodHandler] | None = None,
    audit: AuditLog | None = None,
) -> tuple[int, dict[str, Node]]:
    """Create every tag's node on ``server`` under the namespace ``urn:tanklab``.

    Parameters
    ----------
    server : an initialised asyncua server.
    tags : the tier's tags.
    methods : implementation of each method tag, keyed by path. A method without a handler is
        an error: the contract promises it.
    audit : where calls are recorded (accepted or refused).

    Returns
    -------
    (namespace index, nodes by path).
    """
    methods = methods or {}
    idx = await server.register_namespace(NAMESPACE_URI)
    objects: dict[str, Node] = {}
    nodes: dict[str, Node] = {}
    for tag in tags:
        parent = await _ensure_object(server, idx, tag.parent, objects)
        if tag.kind == "method":
            if tag.path not in methods:
                raise ValueError(f"no handler for method {tag.path}")
            handler = methods[tag.path]
            node = await parent.add_method(
                ua.NodeId(tag.path, idx),
                ua.QualifiedName(tag.name, idx),
                _method_adapter(tag, handler, audit),
                [_argument(a) for a in tag.inputs],
                [_argument(a) for a in tag.outputs],
            )
        else:
            node = await _add_variable(server, idx, parent, tag)
        nodes[tag.path] = node
    return idx, nodes


def _method_adapter(
    tag: Tag, handler: MethodHandler, audit: AuditLog | None
) -> Callable[..., Awaitable[Any]]:
    """Check the caller's role, argument count and types, unwrap Variants, return precise
    status codes, and record the call."""

    async def call(parent: ua.NodeId, *args: ua.Variant) -> Any:
        user = CURRENT_USER.get()
        result = await _checked_call(user, args)
        if audit is not None:
            name, role = who(user)
            status = result if isinstance(result, ua.StatusCode) else ua.StatusCode(ua.StatusCodes.Good)
            shown = [a.Value if isinstance(a, ua.Variant) else repr(a) for a in args]
            audit.record("call", user=name, role=role, node=tag.path, new=shown, status=status.name)
        return result

    async def _checked_call(user: User | None, args: tuple[ua.Variant, ...]) -> Any:
        denied = authorize(tag, user)
        if denied is not None:
            return denied
        if len(args) != len(tag.inputs):
            return ua.StatusCode(
                ua.StatusCodes.BadArgumentsMissing
                if len(args) < len(tag.inputs)
                else ua.StatusCodes.BadTooManyArguments
            )
        values: list[Any] = []
        for arg, v in zip(tag.inputs, args, strict=True):
            want = _VARIANT[arg.data_type]
            if not isinstance(v, ua.Variant) or v.VariantType != want:
                return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
            is_list = isinstance(v.Value, list)
            if (arg.data_type == DataType.DOUBLE_ARRAY) != is_list:
                return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
            values.append(v.Value)
        try:
            return await handler(*values)
        except Exception:
            # A handler bug must still answer precisely and leave a trace, not a bare
            # BadUnexpectedError from asyncua.
            log.exception("method %s failed", tag.path)
            return ua.StatusCode(ua.StatusCodes.BadInternalError)

    return call


# --------------------------------------------------------------------------------------------
# Write validation
# --------------------------------------------------------------------------------------------


def check_value(tag: Tag, value: ua.Variant | None) -> ua.StatusCode | None:
    """Contract checks of a written value: type, finiteness, EURange, enum membership.

    Returns ``None`` when the value is acceptable, else the Bad status to answer.
    """
    if tag.data_type is None or value is None:
        return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
    if value.VariantType != _VARIANT[tag.data_type]:
        return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
    is_list = isinstance(value.Value, list)
    if (tag.data_type == DataType.DOUBLE_ARRAY) != is_list:
        return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
    items = value.Value if is_list else [value.Value]
    for v in items:
        if isinstance(v, float) and not math.isfinite(v):
            return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
        if tag.enum is not None and int(v) not in {int(m) for m in tag.enum}:
            return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
        if tag.eu_range is not None and isinstance(v, int | float) and not isinstance(v, bool):
            lo, hi = tag.eu_range
            if not lo <= v <= hi:
                return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
    return None


class WriteGuard(AttributeService):
    """The server's attribute service with the contract's write validation in front.

    Install with :func:`install_write_guard`. Writes to nodes outside the guarded set (the
    standard namespace) go to asyncua's own checks unchanged (a non-admin user may not write
    them).
    """

    def __init__(
        self,
        base: AttributeService,
        tags_by_nodeid: dict[ua.NodeId, Tag],
        writes: Mapping[str, WriteHandler],
        audit: AuditLog | None = None,
    ):
        super().__init__(base._aspace)
        self._tags = tags_by_nodeid
        self._writes = writes
        self._audit = audit
        self.refused = 0
        self.accepted = 0

    async def write(self, params: ua.WriteParameters, user: User | None = None) -> list[ua.StatusCode]:
        results: list[ua.StatusCode] = []
        for wv in params.NodesToWrite:
            tag = self._tags.get(wv.NodeId)
            if tag is None:
                sub = ua.WriteParameters(NodesToWrite=[wv])
                results.extend(await super().write(sub, user or User()))
                continue
            old = self._aspace.read_attribute_value(wv.NodeId, ua.AttributeIds.Value).Value
            old_value = old.Value if old is not None else None
            new_value = wv.Value.Value.Value if wv.Value is not None and wv.Value.Value is not None else None
            status = self._judge(tag, wv, user, old_value)
            if status is None:
                now = datetime.now(UTC)
                stamped = ua.DataValue(Value=wv.Value.Value, SourceTimestamp=now, ServerTimestamp=now)
                status = await self._aspace.write_attribute_value(wv.NodeId, ua.AttributeIds.Value, stamped)
            if status.is_good():
                self.accepted += 1
            else:
                self.refused += 1
                log.info("write to %s refused: %s", tag.path, status.name)
            if self._audit is not None:
                name, role = who(user)
                self._audit.record(
                    "write",
                    user=name,
                    role=role,
                    node=tag.path,
                    old=old_value,
                    new=new_value,
                    status=status.name,
                )
            results.append(status)
        return results

    def _judge(self, tag: Tag, wv: ua.WriteValue, user: User | None, old: Any) -> ua.StatusCode | None:
        if wv.AttributeId != ua.AttributeIds.Value:
            return ua.StatusCode(ua.StatusCodes.BadNotWritable)
        if tag.kind != "variable" or not tag.writable:
            return ua.StatusCode(ua.StatusCodes.BadNotWritable)
        dv = wv.Value
        new = dv.Value.Value if dv is not None and dv.Value is not None else None
        denied = authorize(tag, user, old, new)
        if denied is not None:
            return denied
        if wv.IndexRange:
            return ua.StatusCode(ua.StatusCodes.BadWriteNotSupported)
        if dv is None:
            return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
        if dv.StatusCode is not None and not dv.StatusCode.is_good():
            return ua.StatusCode(ua.StatusCodes.BadWriteNotSupported)
        bad = check_value(tag, dv.Value)
        if bad is not None:
            return bad
        assert dv.Value is not None
        handler = self._writes.get(tag.path)
        if handler is None:  # check_handlers at start makes this unreachable for the contract
            return ua.StatusCode(ua.StatusCodes.BadNotWritable)
        return handler(tag, dv.Value.Value)


def install_write_guard(
    server: Server,
    tags: Iterable[Tag],
    nodes: dict[str, Node],
    writes: Mapping[str, WriteHandler],
    audit: AuditLog | None = None,
) -> WriteGuard:
    """Put a :class:`WriteGuard` in front of ``server``'s attribute service; ``writes`` holds the
    handler of each writable variable, by path."""
    by_id = {nodes[t.path].nodeid: t for t in tags if t.path in nodes and t.kind == "variable"}
    iserver = server.iserver
    guard = WriteGuard(iserver.attribute_service, by_id, writes, audit)
    iserver.attribute_service = guard
    return guard


@dataclass
class Publisher:
    """Writes many tag values from inside the server (no guard, no client round trip)."""

    server: Server
    tags: dict[str, Tag]
    nodes: dict[str, Node]

    async def publish(self, values: dict[str, Any]) -> None:
        """Store each value (converted to its tag's Variant) that differs from the node's current
        value, with the server's timestamp.

        A value equal to what the node holds is not stored again: its timestamps keep telling
        when it last changed (OPC UA's meaning of SourceTimestamp), and a scan that republishes
        some fifty values, most of them constant, costs only the ones that moved. The comparison
        is against the address space, not a copy kept here, so a client's write in between is
        seen. NaN never equals itself, so a NaN is stored every time.
        """
        now: datetime | None = None
        for path, value in values.items():
            tag = self.tags[path]
            if tag.data_type is None:
                raise ValueError(f"{path} is a method, not a variable")
            nodeid = self.nodes[path].nodeid
            new = _python_value(tag.data_type, value)
            old = self.server.read_attribute_value(nodeid).Value
            if old is not None and old.VariantType == _VARIANT[tag.data_type] and old.Value == new:
                continue
            now = now or datetime.now(UTC)
            dv = ua.DataValue(_stored(tag.data_type, new), SourceTimestamp=now, ServerTimestamp=now)
            await self.server.write_attribute_value(nodeid, dv)

    async def read(self, path: str) -> Any:
        """Current value of a tag as stored in the address space."""
        return await self.nodes[path].read_value()


# --------------------------------------------------------------------------------------------
# Client side
# --------------------------------------------------------------------------------------------


async def namespace_index(client: Client) -> int:
    """Index of ``urn:tanklab`` on the server the client is connected to."""
    return int(await client.get_namespace_index(NAMESPACE_URI))


async def resolve(client: Client, paths: Sequence[str]) -> dict[str, Node]:
    """Nodes of the given paths (the namespace index looked up from the URI)."""
    idx = await namespace_index(client)
    return {p: client.get_node(ua.NodeId(p, idx)) for p in paths}


async def read_values(client: Client, nodes: Sequence[Node]) -> list[Any]:
    """Read many values in one Read service call (values of the same instant)."""
    return list(await client.read_values(list(nodes)))


async def write_value(node: Node, tag: Tag, value: Any) -> ua.StatusCode:
    """Write one value of the tag's type; return the server's status (no exception)."""
    dv = ua.DataValue(variant(tag, value))
    params = ua.WriteParameters()
    wv = ua.WriteValue()
    wv.NodeId = node.nodeid
    wv.AttributeId = ua.AttributeIds.Value
    wv.Value = dv
    params.NodesToWrite = [wv]
    result = await node.session.write(params)
    return result[0]


ClientSetup = Callable[[Client], Awaitable[None]]
"""Prepares a new client before it connects (security policy, certificate, identity):
:func:`tanklab_io.ua_security.client_setup`."""

SESSION_TIMEOUT_MS = 30_000
"""Session timeout a link asks for [ms]: a dead client's session is dropped within 30 s."""


def new_client(url: str, timeout_s: float) -> Client:
    """An asyncua client of ``url`` whose requests wait ``timeout_s`` and whose probe is patient.

    asyncua 2.1 probes the server every ``watchdog_intervall`` (1 s by default) and waits at
    most that long for the answer; a probe that overruns marks the client disconnected for
    good (no auto-reconnect). On a loaded two-core machine, or after the client's event loop
    was busy for a second, a healthy server then looked dead (a CI run lost its test client so).
    Here the probe runs every half session timeout and waits as long (asyncua caps its wait at
    half the session timeout): a server that stops answering is still found before its session
    would expire, and a slow answer is not a lost link. Tier links find a lost peer sooner by
    their own requests (each waits ``timeout_s``).
    """
    half_session_s = max(timeout_s, SESSION_TIMEOUT_MS / 1000.0 / 2.0)
    return Client(url, timeout=timeout_s, watchdog_intervall=half_session_s)


BACKOFF_BASE_S = 0.2
"""Retry delay after a link's first failed connection attempt, before jitter [s]."""
BACKOFF_FACTOR = 2.0
"""Growth of the retry delay per further consecutive failure."""
BACKOFF_CAP_S = 5.0
"""Largest retry delay, before jitter [s]: a tier that comes back is found within 5 s."""
BACKOFF_JITTER = 0.5
"""Fraction of the delay that is random ("equal jitter": half fixed, half uniform)."""


def backoff_delay(
    attempt: int,
    rng: random.Random,
    *,
    base_s: float = BACKOFF_BASE_S,
    factor: float = BACKOFF_FACTOR,
    cap_s: float = BACKOFF_CAP_S,
    jitter: float = BACKOFF_JITTER,
) -> float:
    """Wait before the next connection attempt after ``attempt + 1`` consecutive failures [s].

    Capped exponential backoff with equal jitter::

        d_k = min(cap_s, base_s * factor**k)
        delay = d_k * (1 - jitter * u),    u = rng.random() in [0, 1)

    so ``delay`` lies in ``(d_k * (1 - jitter), d_k]``. With the defaults (0.2 s, x2, 5 s, 0.5)
    the first retries come after 0.1-0.2 s, 0.2-0.4 s, 0.4-0.8 s, ..., then 2.5-5 s for ever.
    Equal rather than full jitter (``jitter = 1``): a full-jitter delay can be ~0, and a link
    that retries at once against a tier that is still starting only adds to its load; half of
    the delay random is enough to spread the links of many clients that lost the same server.

    Parameters
    ----------
    attempt : k >= 0, consecutive failures so far minus one.
    rng : the source of ``u`` (a seeded ``random.Random`` in tests).
    base_s, factor, cap_s : d_0 [s] > 0, growth >= 1, cap [s] >= base_s.
    jitter : 0 (none) .. 1 (full jitter).
    """
    if attempt < 0:
        raise ValueError(f"attempt must be >= 0, got {attempt}")
    if not (base_s > 0 and math.isfinite(base_s) and factor >= 1 and math.isfinite(factor)):
        raise ValueError(f"need base_s > 0 and factor >= 1, got {base_s}, {factor}")
    if not (cap_s >= base_s and math.isfinite(cap_s)):
        raise ValueError(f"cap_s must be >= base_s and finite, got {cap_s}")
    if not 0 <= jitter <= 1:
        raise ValueError(f"jitter must be in [0, 1], got {jitter}")
    # factor**k overflows a float near k = 1024: past the cap, the cap it is.
    if factor > 1 and attempt > math.log(cap_s / base_s) / math.log(factor):
        d = cap_s
    else:
        d = min(cap_s, base_s * factor**attempt)
    return d * (1.0 - jitter * rng.random())


def describe_error(e: BaseException) -> str:
    """``Class: message`` of an exception (just the class when the message is empty: a
    TimeoutError says nothing else)."""
    text = str(e).strip()
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


class ConnectError(LinkError):
    """A connection attempt that failed, at ``stage`` (``setup``: the secure channel and identity;
    ``connect``: the session; ``namespace``: looking ``urn:tanklab`` up), because of ``cause``
    (also the exception's ``__cause__``)."""

    def __init__(self, name: str, url: str, stage: str, cause: BaseException) -> None:
        super().__init__(f"{name} link to {url}: {stage} failed: {describe_error(cause)}")
        self.stage = stage
        self.cause = cause


class Link:
    """An OPC UA client link to the tier below that never crashes its owner.

    Each new client is prepared by ``setup`` (the secure channel and the identity). Every
    request is bounded by ``timeout_s``; any failure marks the link unhealthy, drops the
    connection and raises :class:`~tanklab.errors.LinkError` once. :meth:`ensure` reconnects
    when an attempt is due and resolves the nodes again, so the owner calls it every cycle and
    carries on with its last good values while the tier below is away.

    Retries follow :func:`backoff_delay` on the injected ``clock`` (``now()`` only: the link
    never sleeps, an attempt is simply not made before it is due): after the k-th consecutive
    failure the next attempt waits ``backoff_delay(k - 1, rng)``; a lost connection is retried
    at once (the first attempt), a successful connection resets the count. Every failed attempt
    is one log line at ``failure_level`` naming the link, the attempt number, the endpoint, the
    exception's class and message, and the retry delay (a failed request that drops the link
    one line naming the request): the tiers' links (``PlcLink``,
    ``FieldLink``) pass WARNING; the default INFO keeps a command-line client's probes (``tankctl
    up`` waiting for a tier it is starting, its board) out of an unconfigured terminal, where
    Python prints warnings by itself.

    The operator commands' client (:class:`tankctl.ops.client.TierClient`) is this link too: it
    calls :meth:`connect` (one attempt now, raising :class:`ConnectError`) instead of
    :meth:`ensure`, and maps the failures to its one-line messages.

    Diagnostics (:meth:`status`, published by the tiers on ``<prefix>.Attempts`` etc., see
    :func:`tanklab.tags.link_status_paths`): ``attempts`` failed connection attempts since the
    link was last up (consecutive failures; 0 while up), ``connects`` successful connections,
    ``last_error`` why the last attempt or request failed (kept after a recovery),
    ``retry_delay_s`` the wait scheduled after the last failure.
    """

    def __init__(
        self,
        url: str,
        tags: dict[str, Tag],
        *,
        name: str,
        setup: ClientSetup,
        timeout_s: float = 2.0,
        clock: Clock | None = None,
        rng: random.Random | None = None,
        backoff: Callable[[int, random.Random], float] = backoff_delay,
        failure_level: int = logging.INFO,
        client_name: str | None = None,
    ) -> None:
        self.url = url
        self.client_name = client_name
        """The client's application name shown to the server (None: asyncua's default)."""
        self.setup = setup
        self.tags = tags
        self.name = name
        self.timeout_s = timeout_s
        self.clock: Clock = clock or MonotonicClock()
        self.rng = rng or random.Random()
        self.backoff = backoff
        self.failure_level = failure_level
        self.client: Client | None = None
        self.nodes: dict[str, Node] = {}
        self.idx: int | None = None
        self.healthy = False
        self.failures = 0
        """Requests (read, write, call) that failed and dropped the link."""
        self.connects = 0
        self.attempts = 0
        """Connection attempts that failed since the link was last up (0 while up)."""
        self.last_error = ""
        self.retry_delay_s = 0.0
        self._next_attempt = -math.inf

    def status(self, prefix: str) -> dict[str, Any]:
        """The link's diagnostics as tag values under ``prefix`` (e.g. ``PLC.Status.PlantLink``)."""
        paths = link_status_paths(prefix)
        return {
            paths["Attempts"]: self.attempts,
            paths["Connects"]: self.connects,
            paths["LastError"]: self.last_error,
            paths["RetryDelay"]: self.retry_delay_s,
        }

    async def ensure(self) -> bool:
        """Connect if not connected and an attempt is due; return whether the link is up."""
        if self.healthy:
            return True
        if self.clock.now() < self._next_attempt:
            return False
        try:
            await self.connect()
        except ConnectError:
            return False
        return True

    async def connect(self) -> None:
        """One connection attempt now, due or not (a no-op while up); a failure is counted and
        logged as by :meth:`ensure` and raised as :class:`ConnectError` naming its stage."""
        if self.healthy:
            return
        client = new_client(self.url, self.timeout_s)
        client.session_timeout = SESSION_TIMEOUT_MS
        if self.client_name is not None:
            client.name = self.client_name
        stage = "setup"
        try:
            await asyncio.wait_for(self.setup(client), self.timeout_s)
            stage = "connect"
            await asyncio.wait_for(client.connect(), self.timeout_s)
            stage = "namespace"
            self.idx = await asyncio.wait_for(namespace_index(client), self.timeout_s)
        except Exception as e:
            # asyncua unwinds a failed connect itself; what a timeout cut short is the socket.
            # (A full disconnect of a client that never connected logs its own warning.)
            with contextlib.suppress(Exception):
                client.disconnect_socket()
            self._attempt_failed(e)
            raise ConnectError(self.name, self.url, stage, e) from e
        self.client = client
        self.nodes = {p: client.get_node(ua.NodeId(p, self.idx)) for p in self.tags}
        self.healthy = True
        self.connects += 1
        after = f" after {self.attempts} failed attempts" if self.attempts else ""
        self.attempts = 0
        self.retry_delay_s = 0.0
        log.info("%s link: connected to %s%s", self.name, self.url, after)

    def node(self, path: str) -> Node:
        """The node of a tag path (string NodeId in ``urn:tanklab``), made once per connection:
        the link's own tags are made at connect, any other path on first use."""
        node = self.nodes.get(path)
        if node is None:
            if self.client is None or self.idx is None:
                raise LinkError(f"{self.name} link to {self.url} is down")
            node = self.nodes[path] = self.client.get_node(ua.NodeId(path, self.idx))
        return node

    def _attempt_failed(self, e: BaseException) -> None:
        self.attempts += 1
        self.last_error = describe_error(e)
        self.retry_delay_s = self.backoff(self.attempts - 1, self.rng)
        self._next_attempt = self.clock.now() + self.retry_delay_s
        log.log(
            self.failure_level,
            "%s link: connection attempt %d to %s failed: %s; next attempt in %.2f s",
            self.name,
            self.attempts,
            self.url,
            self.last_error,
            self.retry_delay_s,
        )

    async def _fail(self, what: str, e: BaseException) -> LinkError:
        self.failures += 1
        reason = describe_error(e)
        self.last_error = f"{what}: {reason}"
        if self.healthy:
            log.log(
                self.failure_level,
                "%s link: %s on %s failed (%s); reconnecting",
                self.name,
                what,
                self.url,
                reason,
            )
        self.healthy = False
        client, self.client = self.client, None
        if client is not None:
            await quiet_disconnect(client)
        # The first reconnection attempt is due at once: most losses are one timed-out request.
        self._next_attempt = -math.inf
        return LinkError(f"{self.name} link to {self.url}: {what} failed: {reason}")

    async def read(self, paths: Sequence[str]) -> list[ua.DataValue]:
        """Read the values of ``paths`` in one Read; DataValues with their status codes."""
        if not self.healthy or self.client is None:
            raise LinkError(f"{self.name} link to {self.url} is down")
        try:
            # asyncio.timeout, not wait_for: no extra task per request (a few us, every scan).
            async with asyncio.timeout(self.timeout_s):
                return list(await self.client.read_attributes([self.node(p) for p in paths]))
        except Exception as e:
            raise await self._fail("read", e) from e

    async def write(
        self, values: Mapping[str, Any], tags: Mapping[str, Tag] | None = None
    ) -> list[ua.StatusCode]:
        """Write many values in one Write, each with its tag's exact type (``tags``, default the
        link's own); returns each item's status (no exception for Bad)."""
        if not self.healthy or self.client is None:
            raise LinkError(f"{self.name} link to {self.url} is down")
        paths = list(values)
        types = self.tags if tags is None else tags
        dvs = [ua.DataValue(variant(types[p], values[p])) for p in paths]
        try:
            async with asyncio.timeout(self.timeout_s):
                return list(
                    await self.client.uaclient.write_attributes(
                        [self.node(p).nodeid for p in paths], dvs, ua.AttributeIds.Value
                    )
                )
        except Exception as e:
            raise await self._fail("write", e) from e

    async def call(self, method_path: str, *args: ua.Variant) -> list[Any]:
        """Call a method (its object is the path's parent); raises LinkError, or UaStatusCodeError
        when the server answers the call with a Bad status (the link stays up)."""
        if not self.healthy or self.client is None or self.idx is None:
            raise LinkError(f"{self.name} link to {self.url} is down")
        parent = self.client.get_node(ua.NodeId(method_path.rsplit(".", 1)[0], self.idx))
        try:
            async with asyncio.timeout(self.timeout_s):
                result = await parent.call_method(ua.NodeId(method_path, self.idx), *args)
        except ua.UaStatusCodeError:
            raise
        except Exception as e:
            raise await self._fail(f"call {method_path}", e) from e
        return result if isinstance(result, list) else [result]

    async def close(self) -> None:
        """Disconnect (idempotent)."""
        self.healthy = False
        client, self.client = self.client, None
        if client is not None:
            await quiet_disconnect(client)


async def quiet_disconnect(client: Client, timeout_s: float = 1.0) -> None:
    """Disconnect ``client``, waiting at most ``timeout_s`` [s], never raising: the peer may
    already be gone, and a failed goodbye has nothing to tell anyone."""
    with contextlib.suppress(Exception):
        await asyncio.wait_for(client.disconnect(), timeout_s)
