"""The supervisor's OPC UA server: mode, MPC diagnostics, RLS state, disturbance estimate.

``Supervisor.Mode`` is writable (engineer): OFF, ADVISORY, ADAPTIVE_PID, MPC; the switch happens
at the next cycle, bumplessly. ADAPTIVE_PID on a site whose loops are not all PID loops is
refused with BadInvalidState.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from asyncua import ua

from supervisor.cycle import SupervisorCore
from tanklab.config import SiteConfig
from tanklab.enums import SupervisorMode
from tanklab.tags import Tag, supervisor_tags, tags_by_path
from tanklab.ua import Publisher
from tanklab.ua_security import ServerSecurity, TierServer, start_tier_server

log = logging.getLogger(__name__)


class SupervisorServer:
    """Serves a :class:`SupervisorCore` at ``opc.tcp://HOST:PORT/tanklab/supervisor``."""

    def __init__(
        self, site: SiteConfig, core: SupervisorCore, host: str, port: int, security: ServerSecurity
    ) -> None:
        self.site = site
        self.core = core
        self.url = f"opc.tcp://{host}:{port}/tanklab/supervisor"
        self.tags = supervisor_tags(site)
        self.by_path = tags_by_path(self.tags)
        self.security = security
        self.tier: TierServer | None = None
        self.publisher: Publisher | None = None
        self.on_mode: Callable[[], None] | None = None
        """Called after an accepted ``Supervisor.Mode`` write (the runtime saves the mode)."""

    async def start(self) -> None:
        """Initialise, secure, build the address space and start listening."""
        self.tier = await start_tier_server(
            "supervisor",
            url=self.url,
            name="tanklab supervisor",
            security=self.security,
            tags=self.tags,
            on_write=self._on_write,
        )
        self.publisher = self.tier.publisher
        await self.publish(self.core.values())
        log.info("supervisor server listening at %s", self.url)

    async def stop(self) -> None:
        if self.tier is not None:
            await self.tier.server.stop()
        log.info("supervisor server stopped")

    async def publish(self, values: dict[str, Any]) -> None:
        assert self.publisher is not None
        await self.publisher.publish(values)

    def _on_write(self, tag: Tag, value: Any) -> ua.StatusCode | None:
        if tag.path != "Supervisor.Mode":
            return ua.StatusCode(ua.StatusCodes.BadNotWritable)
        try:
            self.core.request_mode(SupervisorMode(int(value)))
        except ValueError as e:
            log.info("mode change refused: %s", e)
            return ua.StatusCode(ua.StatusCodes.BadInvalidState)
        log.info("Supervisor.Mode := %s", SupervisorMode(int(value)).name)
        if self.on_mode is not None:
            self.on_mode()
        return None
