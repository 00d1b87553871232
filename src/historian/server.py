"""The historian's OPC UA server: its status nodes, secured like every tier, and HistoryRead of
the tiers' nodes.

``opc.tcp://HOST:PORT/tanklab/historian`` (port base + 3, 4843 by default), built through
:func:`tanklab_io.ua_security.start_tier_server` like the other tiers: the same security policies,
users and roles, audit log and audit events. Its own nodes are ``Historian.Identity.*`` and
``Historian.Status.*`` (:func:`tanklab.tags.historian_tags`, all read-only). History of the
recorded tiers' nodes is served by :meth:`HistorianServer.install_history` (the HistoryRead
service of :mod:`historian.history_read`, the tiers' NodeIds mapped onto store tags).
"""

from __future__ import annotations

import logging
from typing import Any

from asyncua import ua

from historian.history_read import install_history_read
from historian.store import HistoryStore
from tanklab.config import SiteConfig
from tanklab.handlers import HandlerTable
from tanklab.tags import historian_tags
from tanklab_io.ua import Publisher, WriteHandler
from tanklab_io.ua_client import TANKLAB_INDEX
from tanklab_io.ua_security import ServerSecurity, TierServer, start_tier_server

log = logging.getLogger(__name__)


class HistorianServer:
    """Serves the historian's status at ``opc.tcp://HOST:PORT/tanklab/historian``."""

    def __init__(self, site: SiteConfig, host: str, port: int, security: ServerSecurity) -> None:
        self.site = site
        self.url = f"opc.tcp://{host}:{port}/tanklab/historian"
        self.tags = historian_tags(site)
        self.security = security
        self.tier: TierServer | None = None
        self.publisher: Publisher | None = None

    async def start(self) -> None:
        """Initialise, secure, build the address space and start listening."""
        self.tier = await start_tier_server(
            "historian",
            url=self.url,
            name="tanklab historian",
            security=self.security,
            tags=self.tags,
            writes=HandlerTable[WriteHandler](),
        )
        self.publisher = self.tier.publisher
        log.info("historian server listening at %s", self.url)

    def install_history(self, store_for_reads: HistoryStore, recorded: frozenset[str]) -> None:
        """Serve HistoryRead of the recorded tiers' nodes from ``store_for_reads``
        (:func:`historian.history_read.install_history_read`).

        ``recorded`` are the tags history is served for: the tiers' NodeIds, ``ns=<urn:tanklab>;
        s=<tag>``, mirrored (architecture, "History"); any other NodeId maps to no tag.
        """
        assert self.tier is not None
        idx = TANKLAB_INDEX

        def tag_for_nodeid(nodeid: ua.NodeId) -> str | None:
            ident = nodeid.Identifier
            if nodeid.NamespaceIndex == idx and isinstance(ident, str) and ident in recorded:
                return ident
            return None

        install_history_read(self.tier.server, store_for_reads, tag_for_nodeid)

    async def publish(self, values: dict[str, Any]) -> None:
        assert self.publisher is not None
        await self.publisher.publish(values)

    async def stop(self) -> None:
        if self.tier is not None:
            await self.tier.server.stop()
        log.info("historian server stopped")
