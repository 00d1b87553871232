"""One connected tier for an operator command: connect (bounded, the site identity checked),
Read, Write, Call, Browse; every failure one :mod:`tankctl.ops.errors` exception."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

from asyncua import Client, Node, ua

from tankctl.ops.display import plain, show
from tankctl.ops.errors import (
    LOGIN_REFUSALS,
    CallRefusedError,
    LoginRefusedError,
    RefusedError,
    UnreachableError,
    describe_failure,
)
from tanklab.errors import LinkError, SecurityError, TanklabError
from tanklab.tags import NAMESPACE_URI, Tag, Tier
from tanklab_io.ua_client import NAMESPACE_ARRAY, TANKLAB_INDEX, ConnectError, Link
from tanklab_io.ua_client_security import cli_identity, client_setup

if TYPE_CHECKING:
    from tankctl.ops.stack import Stack

_T = TypeVar("_T")


@dataclass
class BrowsedNode:
    """A node as the server's Browse and Read services showed it."""

    name: str
    path: str
    node_class: str
    description: str = ""
    children: list[BrowsedNode] = field(default_factory=list)
    value: Any = None
    status: str | None = None
    data_type: str | None = None
    unit: str | None = None
    eu_range: tuple[float, float] | None = None
    enum_strings: list[str] | None = None
    writable: bool | None = None
    inputs: list[str] | None = None
    outputs: list[str] | None = None

    def walk(self, depth: int = 0) -> Iterator[tuple[int, BrowsedNode]]:
        """This node and its descendants, depth first, with their depth."""
        yield depth, self
        for child in self.children:
            yield from child.walk(depth + 1)

    @property
    def enum_name(self) -> str | None:
        """The EnumStrings entry of an enumerated value."""
        if self.enum_strings is None or not isinstance(self.value, int) or isinstance(self.value, bool):
            return None
        return self.enum_strings[self.value] if 0 <= self.value < len(self.enum_strings) else None

    def as_json(self) -> dict[str, Any]:
        """Nested plain structure (see docs/cli.md, ``browse --json``)."""
        out: dict[str, Any] = {"name": self.name, "path": self.path, "class": self.node_class}
        if self.description:
            out["description"] = self.description
        if self.node_class == "Variable":
            out.update(
                value=plain(self.value),
                data_type=self.data_type,
                unit=self.unit,
                eu_range=list(self.eu_range) if self.eu_range else None,
                writable=self.writable,
            )
            if self.enum_strings is not None:
                out["enum"] = self.enum_name
                out["enum_strings"] = self.enum_strings
            if self.status:
                out["status"] = self.status
        if self.node_class == "Method":
            out.update(inputs=self.inputs or [], outputs=self.outputs or [])
        if self.children:
            out["children"] = [c.as_json() for c in self.children]
        return out


class TierClient:
    """An operator command's client of one tier: a :class:`tanklab_io.ua_client.Link` (the one OPC UA
    client wrapper: connection, bounded Read, Write and Call, quiet disconnect) that connects
    once, checks the tier's site identity, browses, and turns every failure into one exception.

    Every request is bounded by ``timeout_s``; any failure to connect or to get an answer
    raises :class:`UnreachableError` naming the tier and its URL. A Bad status on a write raises
    :class:`RefusedError`. Node ids come from the namespace index of ``urn:tanklab``, looked up.
    """

    def __init__(self, tier: Tier, url: str, stack: Stack) -> None:
        self.tier = tier
        self.url = url
        self.stack = stack
        self.timeout_s = stack.timeout_s
        self.identity = stack.identity or cli_identity()
        # The link's own tags are none: the site (and so the tags) may be known only once this
        # tier answered; writes pass the stack's tags.
        self.link = Link(
            url,
            {},
            name=f"tankctl {tier}",
            setup=client_setup(self.identity),
            timeout_s=self.timeout_s,
            client_name="tankctl",
            namespace_index=TANKLAB_INDEX,  # checked by the first Read (connect)
        )
        self._wanted: list[str] = []
        self._first: dict[str, Any] = {}

    @property
    def tags(self) -> dict[str, Tag]:
        """The contract's tags of this tier for the stack's site, by path."""
        return self.stack.tags(self.tier)

    @property
    def idx(self) -> int:
        """The namespace index of ``urn:tanklab`` on the tier (0 before connecting)."""
        return self.link.idx or 0

    @property
    def client(self) -> Client:
        if self.link.client is None:
            raise UnreachableError(self.tier, self.url, "not connected")
        return self.link.client

    def will_read(self, paths: Sequence[str]) -> TierClient:
        """Read ``paths`` together with the site identity when this client connects: one Read
        instead of two. The values are the tier's only once its identity is accepted, and the
        next :meth:`read` of exactly those paths gets them (once; later reads ask the tier)."""
        self._wanted = list(paths)
        return self

    async def connect(self) -> TierClient:
        """Connect, look the namespace index up and check the tier's site identity with
        :meth:`Stack.accept` (each within the timeout); a no-op when connected. The identity
        and the paths of :meth:`will_read` are read in one Read."""
        if self.link.healthy:
            return self
        try:
            await self.link.connect()
        except ConnectError as e:
            raise self._connect_failure(e.stage, e.cause) from None
        paths, reads = self.stack.first_read(self.tier, self._wanted)
        try:
            values = await self._first_read(reads)
            self.stack.accept(self.tier, self.url, {item: values[p] for item, p in paths.items()})
        except TanklabError:
            await self.close()
            raise
        self._first = {p: values[p] for p in self._wanted}
        return self

    async def _first_read(self, paths: Sequence[str]) -> dict[str, Any]:
        """``paths`` read with the server's NamespaceArray in one Read, under the index of
        ``urn:tanklab`` the link assumed (:data:`TANKLAB_INDEX`): the namespace lookup costs no
        round trip of its own. A server that has the namespace elsewhere is read again under
        its index; one that does not have it is unreachable, as when the lookup came first."""
        nodes = [self.client.get_node(NAMESPACE_ARRAY), *(self.node(p) for p in paths)]
        dvs = await self._linked(self.link.read_nodes(nodes))
        uris = dvs[0].Value.Value if dvs[0].Value is not None else None
        uris = uris if isinstance(uris, list) else []
        if NAMESPACE_URI not in uris:
            await self.close()
            raise UnreachableError(self.tier, self.url, f"no {NAMESPACE_URI} namespace")
        if uris.index(NAMESPACE_URI) != self.link.idx:
            self.link.idx = uris.index(NAMESPACE_URI)
            self.link.nodes = {}
            return await self._read(paths)
        return _values(paths, dvs[1:])

    def _connect_failure(self, stage: str, cause: BaseException) -> Exception:
        """What a failed connection attempt tells the operator: the security error as is, a
        refused login, or why the tier is unreachable."""
        if isinstance(cause, SecurityError):
            return cause
        if stage == "namespace":
            # asyncua answers a missing namespace URI with list.index's ValueError.
            missing = f"no {NAMESPACE_URI} namespace" if isinstance(cause, ValueError) else None
            return UnreachableError(self.tier, self.url, missing or describe_failure(cause, self.timeout_s))
        if isinstance(cause, ua.UaStatusCodeError):
            status = ua.StatusCode(cause.code).name
            if status in LOGIN_REFUSALS:
                creds = self.identity.credentials
                user = creds.username if creds is not None else None
                return LoginRefusedError(user, self.tier, self.url, status)
            return UnreachableError(self.tier, self.url, status)
        return UnreachableError(self.tier, self.url, describe_failure(cause, self.timeout_s))

    async def close(self) -> None:
        """Disconnect (idempotent, never raises)."""
        self._first = {}
        await self.link.close()

    async def __aenter__(self) -> TierClient:
        return await self.connect()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def _bounded(self, aw: Awaitable[_T]) -> _T:
        """Await a request within the timeout; lost links and timeouts become UnreachableError."""
        try:
            return await asyncio.wait_for(aw, self.timeout_s)
        except Exception as e:
            await self.close()
            raise UnreachableError(self.tier, self.url, describe_failure(e, self.timeout_s)) from None

    async def _linked(self, aw: Awaitable[_T]) -> _T:
        """Await a request of the link (bounded by it); its LinkError becomes UnreachableError
        (the link has dropped the connection already)."""
        try:
            return await aw
        except LinkError as e:
            cause = e.__cause__
            reason = "not connected" if cause is None else describe_failure(cause, self.timeout_s)
            raise UnreachableError(self.tier, self.url, reason) from None

    def node(self, path: str) -> Node:
        """The node of a tag path (string NodeId in the tanklab namespace)."""
        try:
            return self.link.node(path)
        except LinkError:
            raise UnreachableError(self.tier, self.url, "not connected") from None

    async def read(self, paths: Sequence[str]) -> dict[str, Any]:
        """Values of ``paths`` in one Read; a node answering a Bad status reads as None. The
        paths of :meth:`will_read`, read at connect, are not read again the first time."""
        if self._first and list(paths) == list(self._first):
            first, self._first = self._first, {}
            return first
        return await self._read(paths)

    async def _read(self, paths: Sequence[str]) -> dict[str, Any]:
        if not paths:
            return {}
        return _values(paths, await self._linked(self.link.read(paths)))

    async def write(self, path: str, value: Any) -> None:
        """Write one value with the tag's exact type; a Bad status raises :class:`RefusedError`."""
        tag = self.tags[path]
        (status,) = await self._linked(self.link.write({path: value}, self.tags))
        if not status.is_good():
            raise RefusedError(path, show(tag, value), status.name)

    async def call(self, path: str, *args: float, hints: Mapping[str, str] | None = None) -> None:
        """Call the method ``path`` with Double arguments; a Bad status raises
        :class:`CallRefusedError` (with ``hints[status]`` as its reason, when given)."""
        variants = [ua.Variant(float(a), ua.VariantType.Double) for a in args]
        await self.call_variants(path, variants, ", ".join(f"{a:g}" for a in args), hints=hints)

    async def call_variants(
        self, path: str, variants: Sequence[ua.Variant], shown: str, *, hints: Mapping[str, str] | None = None
    ) -> None:
        """Call the method ``path`` (its object the path's parent) with typed ``variants``; a
        Bad status raises :class:`CallRefusedError` showing the arguments as ``shown``."""
        try:
            await self._linked(self.link.call(path, *variants))
        except ua.UaStatusCodeError as e:
            status = str(ua.StatusCode(e.code).name)
            raise CallRefusedError(path, shown, status, (hints or {}).get(status, "")) from None

    async def eu_range(self, path: str) -> tuple[float, float] | None:
        """The EURange property of a node as the server has it (None if it has none)."""
        params = ua.BrowseParameters()
        params.NodesToBrowse = [_browse_description(self.node(path).nodeid, ua.ObjectIds.HasProperty)]
        (refs,) = await self._browse_all(params)
        for ref in refs:
            if ref.BrowseName.Name == "EURange":
                rng = (await self.read_ids([(ref.NodeId, ua.AttributeIds.Value)]))[0]
                if rng is not None:
                    return (float(rng.Low), float(rng.High))
        return None

    async def read_ids(self, items: Sequence[tuple[ua.NodeId, ua.AttributeIds]]) -> list[Any]:
        """Attribute values of arbitrary nodes, in Reads of at most 500 items; Bad -> None."""
        out: list[Any] = []
        for start in range(0, len(items), 500):
            params = ua.ReadParameters()
            for nid, attr in items[start : start + 500]:
                rv = ua.ReadValueId()
                rv.NodeId = nid
                rv.AttributeId = attr
                params.NodesToRead.append(rv)
            dvs = await self._bounded(self.client.uaclient.read(params))
            for dv in dvs:
                bad = dv.StatusCode is not None and dv.StatusCode.is_bad()
                out.append(None if bad or dv.Value is None else dv.Value.Value)
        return out

    async def _browse_all(self, params: ua.BrowseParameters) -> list[list[ua.ReferenceDescription]]:
        """Browse, following continuation points to the end."""
        results = await self._bounded(self.client.uaclient.browse(params))
        out: list[list[ua.ReferenceDescription]] = []
        for result in results:
            refs = list(result.References or [])
            cp = result.ContinuationPoint
            while cp:
                nxt = ua.BrowseNextParameters()
                nxt.ReleaseContinuationPoints = False
                nxt.ContinuationPoints = [cp]
                (more,) = await self._bounded(self.client.uaclient.browse_next(nxt))
                refs += list(more.References or [])
                cp = more.ContinuationPoint
            out.append(refs)
        return out

    async def browse_tree(self, max_depth: int = 12) -> list[BrowsedNode]:
        """The tanklab nodes under the Objects folder, browsed level by level (one Browse per
        depth) and then read (Value, DataType, UserAccessLevel, Description and the properties
        EngineeringUnits, EURange, EnumStrings, Input/OutputArguments) in one Read."""
        roots: list[BrowsedNode] = []
        frontier: list[tuple[ua.NodeId, BrowsedNode | None]] = [(ua.NodeId(ua.ObjectIds.ObjectsFolder), None)]
        seen: set[ua.NodeId] = set()
        found: list[tuple[ua.NodeId, BrowsedNode]] = []
        props: list[tuple[BrowsedNode, str, ua.NodeId]] = []
        for _ in range(max_depth):
            if not frontier:
                break
            params = ua.BrowseParameters()
            params.NodesToBrowse = [
                _browse_description(nid, ua.ObjectIds.HierarchicalReferences) for nid, _ in frontier
            ]
            results = await self._browse_all(params)
            nxt: list[tuple[ua.NodeId, BrowsedNode | None]] = []
            for (_, parent), refs in zip(frontier, results, strict=True):
                for ref in refs:
                    nid = ref.NodeId
                    if nid.NamespaceIndex != self.idx or nid in seen:
                        continue
                    seen.add(nid)
                    if parent is not None and ref.ReferenceTypeId == ua.NodeId(ua.ObjectIds.HasProperty):
                        props.append((parent, ref.BrowseName.Name, nid))
                        continue
                    ident = nid.Identifier if isinstance(nid.Identifier, str) else nid.to_string()
                    node = BrowsedNode(ref.BrowseName.Name, ident, ua.NodeClass(ref.NodeClass).name)
                    (roots if parent is None else parent.children).append(node)
                    found.append((nid, node))
                    nxt.append((nid, node))
            frontier = nxt
        attrs = (
            ua.AttributeIds.Value,
            ua.AttributeIds.DataType,
            ua.AttributeIds.UserAccessLevel,
            ua.AttributeIds.Description,
        )
        items: list[tuple[ua.NodeId, ua.AttributeIds]] = []
        for nid, node in found:
            for attr in attrs if node.node_class == "Variable" else (ua.AttributeIds.Description,):
                items.append((nid, attr))
        items += [(nid, ua.AttributeIds.Value) for _, _, nid in props]
        values = iter(await self.read_ids(items))
        for _, node in found:
            if node.node_class == "Variable":
                node.value = next(values)
                dtype = next(values)
                access = next(values)
                node.writable = (
                    bool(access & ua.AccessLevel.CurrentWrite.mask) if access is not None else None
                )
                if node.value is None:
                    node.status = "Bad"
                node.data_type = _type_name(dtype, node.value)
            desc = next(values)
            node.description = desc.Text if isinstance(desc, ua.LocalizedText) and desc.Text else ""
        for parent, name, _ in props:
            value = next(values)
            if name == "EngineeringUnits" and value is not None:
                parent.unit = value.DisplayName.Text
            elif name == "EURange" and value is not None:
                parent.eu_range = (float(value.Low), float(value.High))
            elif name == "EnumStrings" and value is not None:
                parent.enum_strings = [v.Text if isinstance(v, ua.LocalizedText) else str(v) for v in value]
            elif name in ("InputArguments", "OutputArguments") and value is not None:
                args = [a.Name for a in value]
                if name == "InputArguments":
                    parent.inputs = args
                else:
                    parent.outputs = args
        return roots


def _values(paths: Sequence[str], dvs: Sequence[ua.DataValue]) -> dict[str, Any]:
    """Read results by path; a node answering a Bad status reads as None."""
    out: dict[str, Any] = {}
    for path, dv in zip(paths, dvs, strict=True):
        bad = dv.StatusCode is not None and dv.StatusCode.is_bad()
        out[path] = None if bad or dv.Value is None else dv.Value.Value
    return out


def _browse_description(nid: ua.NodeId, reference_type: int) -> ua.BrowseDescription:
    d = ua.BrowseDescription()
    d.NodeId = nid
    d.BrowseDirection = ua.BrowseDirection.Forward
    d.ReferenceTypeId = ua.NodeId(reference_type)
    d.IncludeSubtypes = True
    d.NodeClassMask = 0
    d.ResultMask = ua.BrowseResultMask.All
    return d


def _type_name(dtype: Any, value: Any) -> str | None:
    if not isinstance(dtype, ua.NodeId):
        return None
    name = ua.ObjectIdNames.get(dtype.Identifier) if dtype.NamespaceIndex == 0 else None
    name = name or dtype.to_string()
    return f"{name}[]" if isinstance(value, list) else name
