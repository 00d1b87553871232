"""An operator command's first Read (decision 0039): the tier's NamespaceArray, its site
identity and the command's own values in one request, under the namespace index every tanklab
tier has (2), checked by that same Read.

The link is a stand-in that records the Reads and answers them from a server's namespace
table and values: what is checked is which nodes each Read asks for and what the client makes
of the answers, the three cases a real server can present (the namespace where assumed,
elsewhere, absent). The real round trips are counted against a real stack in test_ops.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import pytest
from asyncua import ua

from helpers import ROOT
from tankctl.ops import Stack, UnreachableError
from tanklab.config import load_site
from tanklab.identity import SiteIdentity
from tanklab.tags import NAMESPACE_URI, identity_paths
from tanklab_io.ua_client import NAMESPACE_ARRAY, TANKLAB_INDEX

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
SP = "PLC.LIC1.SP"


@dataclass
class _Node:
    nodeid: ua.NodeId


@dataclass
class _Client:
    def get_node(self, nid: ua.NodeId) -> _Node:
        return _Node(nid)


@dataclass
class FakeLink:
    """The part of tanklab_io.ua_client.Link a TierClient uses, over a server whose
    NamespaceArray is ``uris`` and whose tanklab nodes have ``values``."""

    uris: list[str]
    values: dict[str, Any]
    idx: int | None = None
    healthy: bool = False
    client: _Client | None = None
    nodes: dict[str, _Node] = field(default_factory=dict)
    reads: list[list[ua.NodeId]] = field(default_factory=list)

    async def connect(self) -> None:
        self.idx, self.healthy, self.client = TANKLAB_INDEX, True, _Client()

    def node(self, path: str) -> _Node:
        assert self.idx is not None
        return self.nodes.setdefault(path, _Node(ua.NodeId(path, self.idx)))

    def _value(self, nid: ua.NodeId) -> ua.DataValue:
        if nid == NAMESPACE_ARRAY:
            return ua.DataValue(ua.Variant(self.uris))
        real = self.uris.index(NAMESPACE_URI) if NAMESPACE_URI in self.uris else None
        if nid.NamespaceIndex != real or nid.Identifier not in self.values:
            return ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown))
        return ua.DataValue(ua.Variant(self.values[nid.Identifier]))

    async def read_nodes(self, nodes: list[_Node]) -> list[ua.DataValue]:
        self.reads.append([n.nodeid for n in nodes])
        return [self._value(n.nodeid) for n in nodes]

    async def read(self, paths: list[str]) -> list[ua.DataValue]:
        return await self.read_nodes([self.node(p) for p in paths])

    async def close(self) -> None:
        self.healthy, self.client = False, None


def _plc(uris: list[str]) -> tuple[Stack, FakeLink]:
    ident = SiteIdentity.of(SITE)
    paths = identity_paths("plc")
    values = {paths["SiteName"]: ident.name, paths["ConfigDigest"]: ident.digest, SP: 0.4}
    stack = Stack(SITE, {"plc": "opc.tcp://plc:1", "plant": "x", "supervisor": "y"}, source="--config x")
    link = FakeLink(uris, values)
    stack.client("plc").link = link  # type: ignore[assignment]
    return stack, link


OWN = ["http://opcfoundation.org/UA/", "urn:tanklab:plc"]


async def test_namespace_identity_and_values_in_one_read() -> None:
    stack, link = _plc([*OWN, NAMESPACE_URI])
    client = await stack.client("plc").will_read([SP]).connect()
    assert len(link.reads) == 1
    (read,) = link.reads
    assert read[0] == NAMESPACE_ARRAY
    assert {n.Identifier for n in read[1:]} == {*identity_paths("plc").values(), SP} - {"PLC.Identity.Config"}
    assert await client.read([SP]) == {SP: 0.4}
    assert len(link.reads) == 1  # the first values, handed out once
    assert await client.read([SP]) == {SP: 0.4}
    assert len(link.reads) == 2  # then read from the tier


async def test_a_namespace_elsewhere_is_read_again_under_its_index() -> None:
    stack, link = _plc([*OWN, "urn:other", NAMESPACE_URI])
    client = await stack.client("plc").will_read([SP]).connect()
    assert len(link.reads) == 2
    assert {n.NamespaceIndex for n in link.reads[1]} == {3}
    assert client.idx == 3
    assert await client.read([SP]) == {SP: 0.4}


async def test_no_tanklab_namespace_is_unreachable_as_before() -> None:
    stack, link = _plc(OWN)
    with pytest.raises(UnreachableError) as e:
        await stack.client("plc").connect()
    assert str(e.value) == f"cannot reach plc at opc.tcp://plc:1: no {NAMESPACE_URI} namespace"
    assert not link.healthy
