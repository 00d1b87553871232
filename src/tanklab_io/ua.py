"""asyncua adapter of the address-space contract, server side: build nodes, guard writes, publish.

Every tier's ``server.py`` goes through this module (and every client through
:mod:`tanklab_io.ua_client`), so the contract in :mod:`tanklab.tags` is realised the same way
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
    In :mod:`tanklab_io.ua_client` (resolve, read, write, :class:`~tanklab_io.ua_client.Link`).
"""

from __future__ import annotations

import contextvars
import logging
import math
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from asyncua import Node, Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.address_space import AttributeService

from tanklab.tags import NAMESPACE_URI, DataType, Role, Tag
from tanklab_io.audit import AuditLog
from tanklab_io.ua_values import DATATYPE_IDS as _DATATYPE_ID
from tanklab_io.ua_values import VARIANT_TYPES as _VARIANT
from tanklab_io.ua_values import python_value as _python_value
from tanklab_io.ua_values import stored_variant as _stored
from tanklab_io.ua_values import variant

log = logging.getLogger(__name__)

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

CURRENT_SESSION: contextvars.ContextVar[ua.NodeId | None] = contextvars.ContextVar(
    "tanklab_current_session", default=None
)
"""The SessionId of the request being served (set with :data:`CURRENT_USER`; None outside a
client's request), e.g. for ConditionRefresh to refuse another session's subscription."""


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
