"""Building the condition nodes and their notifier chain in the address space.

asyncua can instantiate a type (``add_object(objecttype=...)``), but it browses the type tree
node by node: a median 50 ms CPU per ExclusiveLevelAlarmType condition with the mandatory
children only, 124 ms with the optional ones, against 8.1 ms for one AddNodes call of the
children tanklab uses (:data:`~tanklab_io.conditions.fields.CHILDREN`), the three alternated in
one process, 12 conditions each (decision 0037). So each condition is added that way.

Notifier chain (Part 9 5.3, Part 3 7.16-7.19)
    Server -HasNotifier-> tier root -HasNotifier-> ... -HasNotifier-> the source's object, each
    with EventNotifier SubscribeToEvents; the source -HasCondition-> the condition; the
    condition is a component (HasComponent) of the source. A source that is a variable (an
    interlock's trip boolean) cannot be a notifier nor have object components: its nearest
    object ancestor is, and holds the condition; the HasCondition and a HasEventSource still
    start at the variable. asyncua delivers an event only to monitored items on the node the
    event names as its emitting node (it does not walk HasNotifier), so the projection raises
    each event once per node of the chain (:attr:`ConditionNode.notifiers`).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

from asyncua import Server, ua

from tanklab.alarms.model import AlarmDefinition, ConditionKind
from tanklab_io.conditions.fields import (
    METHOD,
    NORMAL_VALUE,
    OBJECT,
    PROPERTY,
    ConditionNode,
    child_id,
    children_of,
    event_type_id,
)

_SUBSCRIBE = ua.EventNotifier.SubscribeToEvents


def _exists(server: Server, nodeid: ua.NodeId) -> bool:
    return nodeid in server.iserver.aspace


def _node_class(server: Server, nodeid: ua.NodeId) -> ua.NodeClass:
    dv = server.iserver.aspace.read_attribute_value(nodeid, ua.AttributeIds.NodeClass)
    return ua.NodeClass(dv.Value.Value)


def notifier_path(server: Server, idx: int, source: str, root: str) -> tuple[str, list[str]]:
    """(the object that notifies for ``source``, the object paths from ``root`` down to it).

    Raises ValueError for a source that is not in the address space or not under ``root``.
    """
    if not _exists(server, ua.NodeId(source, idx)):
        raise ValueError(f"condition source {source} is not a node of this server")
    if source != root and not source.startswith(root + "."):
        raise ValueError(f"condition source {source} is not under the tier's root {root}")
    holder = source
    while _node_class(server, ua.NodeId(holder, idx)) != ua.NodeClass.Object:
        holder = holder.rsplit(".", 1)[0]
    chain = [root]
    parts = holder[len(root) :].split(".")[1:]
    for part in parts:
        chain.append(f"{chain[-1]}.{part}")
    return holder, chain


async def _reference(
    server: Server, source: ua.NodeId, ref: int, target: ua.NodeId, target_class: ua.NodeClass
) -> None:
    item = ua.AddReferencesItem(
        SourceNodeId=source,
        ReferenceTypeId=ua.NodeId(ref),
        IsForward=True,
        TargetNodeId=target,
        TargetNodeClass=target_class,
    )
    (await server.iserver.isession.add_references([item]))[0].check()


class NotifierChains:
    """Makes objects notifiers and links them by HasNotifier, each link once."""

    def __init__(self, server: Server) -> None:
        self.server = server
        self._linked: set[tuple[ua.NodeId, ua.NodeId]] = set()
        self._notifiers: set[ua.NodeId] = set()

    async def notifier(self, nodeid: ua.NodeId) -> None:
        """Set ``nodeid``'s EventNotifier to SubscribeToEvents (once)."""
        if nodeid in self._notifiers:
            return
        await self.server.get_node(nodeid).set_event_notifier([_SUBSCRIBE])
        self._notifiers.add(nodeid)

    async def link(self, parent: ua.NodeId, child: ua.NodeId) -> None:
        """``parent`` -HasNotifier-> ``child``, both notifiers (once)."""
        await self.notifier(parent)
        await self.notifier(child)
        if (parent, child) in self._linked:
            return
        await _reference(self.server, parent, ua.ObjectIds.HasNotifier, child, ua.NodeClass.Object)
        self._linked.add((parent, child))


def _attributes(
    child_vtype: ua.VariantType, data_type: int, value: ua.Variant | None
) -> ua.VariableAttributes:
    attrs = ua.VariableAttributes()
    attrs.Value = value if value is not None else ua.Variant(None, child_vtype)
    attrs.DataType = ua.NodeId(data_type)
    attrs.ValueRank = -1
    attrs.ArrayDimensions = []
    attrs.AccessLevel = ua.AccessLevel.CurrentRead.mask
    attrs.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
    attrs.Historizing = False
    return attrs


def _item(
    nodeid: ua.NodeId,
    name: str,
    parent: ua.NodeId,
    ref: int,
    node_class: ua.NodeClass,
    type_definition: int,
    attrs: ua.NodeAttributes,
    ns: int,
) -> ua.AddNodesItem:
    item = ua.AddNodesItem()
    item.RequestedNewNodeId = nodeid
    # Part 9's children are standard names (namespace 0); the condition itself is the tier's.
    item.BrowseName = ua.QualifiedName(name, ns)
    item.ParentNodeId = parent
    item.ReferenceTypeId = ua.NodeId(ref)
    item.NodeClass = node_class
    item.TypeDefinition = ua.NodeId(type_definition) if type_definition else ua.NodeId()
    attrs.DisplayName = ua.LocalizedText(name)
    item.NodeAttributes = attrs
    return item


async def add_condition(
    server: Server,
    node: ConditionNode,
    holder: ua.NodeId,
    initial: dict[str, ua.Variant],
    input_arguments: dict[int, ua.Variant],
) -> list[ua.NodeId]:
    """Add ``node``'s condition object and all its children under ``holder``; returns the
    method nodes' ids. ``initial`` holds each child's first value (by path),
    ``input_arguments`` each standard method's InputArguments value."""
    d = node.definition
    cid = node.condition_id
    obj = ua.ObjectAttributes()
    obj.EventNotifier = 0
    obj.Description = ua.LocalizedText(d.message)
    items = [
        _item(
            cid,
            d.name,
            holder,
            ua.ObjectIds.HasComponent,
            ua.NodeClass.Object,
            event_type_id(d.kind).Identifier,
            obj,
            cid.NamespaceIndex,
        )
    ]
    methods: list[ua.NodeId] = []
    for c in children_of(d):
        nid = child_id(cid, c.path)
        parent = cid if "/" not in c.path else child_id(cid, c.path.rsplit("/", 1)[0])
        if c.node == OBJECT:
            items.append(
                _item(
                    nid,
                    c.name,
                    parent,
                    ua.ObjectIds.HasComponent,
                    ua.NodeClass.Object,
                    c.type_definition,
                    ua.ObjectAttributes(),
                    0,
                )
            )
        elif c.node == METHOD:
            attrs = ua.MethodAttributes()
            attrs.Executable = True
            attrs.UserExecutable = True
            items.append(
                _item(nid, c.name, parent, ua.ObjectIds.HasComponent, ua.NodeClass.Method, 0, attrs, 0)
            )
            if c.method in input_arguments:
                args = _attributes(
                    ua.VariantType.ExtensionObject, ua.ObjectIds.Argument, input_arguments[c.method]
                )
                args.ValueRank = 1
                args.ArrayDimensions = [0]
                items.append(
                    _item(
                        child_id(nid, "InputArguments"),
                        "InputArguments",
                        nid,
                        ua.ObjectIds.HasProperty,
                        ua.NodeClass.Variable,
                        ua.ObjectIds.PropertyType,
                        args,
                        0,
                    )
                )
            methods.append(nid)
        else:
            assert c.vtype is not None
            ref = ua.ObjectIds.HasProperty if c.node == PROPERTY else ua.ObjectIds.HasComponent
            attrs_v = _attributes(c.vtype, c.data_type, initial.get(c.path))
            items.append(
                _item(nid, c.name, parent, ref, ua.NodeClass.Variable, c.type_definition, attrs_v, 0)
            )
    if d.kind == ConditionKind.OFF_NORMAL:
        normal = _attributes(
            ua.VariantType.Boolean, ua.ObjectIds.Boolean, ua.Variant(False, ua.VariantType.Boolean)
        )
        items.append(
            _item(
                node.normal_id,
                NORMAL_VALUE,
                cid,
                ua.ObjectIds.HasComponent,
                ua.NodeClass.Variable,
                ua.ObjectIds.BaseDataVariableType,
                normal,
                cid.NamespaceIndex,
            )
        )
    results = await server.iserver.isession.add_nodes(items)
    for item, result in zip(items, results, strict=True):
        if not result.StatusCode.is_good():
            raise ValueError(
                f"condition {d.name}: node {item.RequestedNewNodeId} not added: {result.StatusCode.name}"
            )
    return methods


async def standard_input_arguments(server: Server, methods: Sequence[int]) -> dict[int, ua.Variant]:
    """The InputArguments property value of each standard method that has one."""
    out: dict[int, ua.Variant] = {}
    for mid in methods:
        for prop in await server.get_node(ua.NodeId(mid)).get_properties():
            if (await prop.read_browse_name()).Name == "InputArguments":
                dv = await prop.read_data_value()
                if dv.Value is not None:
                    out[mid] = dv.Value
    return out


async def link_source(server: Server, chains: NotifierChains, node: ConditionNode, holder: ua.NodeId) -> None:
    """The chain from the Server object to the holder, and the source's HasCondition (and, for a
    variable source, HasEventSource) references."""
    for parent, child in itertools.pairwise(node.notifiers):
        await chains.link(parent, child)
    await chains.notifier(holder)
    await _reference(
        server, node.source_id, ua.ObjectIds.HasCondition, node.condition_id, ua.NodeClass.Object
    )
    if node.source_id != holder:
        await _reference(server, holder, ua.ObjectIds.HasEventSource, node.source_id, ua.NodeClass.Variable)


def definitions_by_name(definitions: Sequence[AlarmDefinition]) -> dict[str, AlarmDefinition]:
    """The definitions by name; ValueError on a repeated name."""
    out: dict[str, AlarmDefinition] = {}
    for d in definitions:
        if d.name in out:
            raise ValueError(f"alarm {d.name} defined twice")
        out[d.name] = d
    return out
