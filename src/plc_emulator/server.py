"""The PLC's OPC UA server: the contract's PLC nodes over a :class:`PlcProgram`.

Writes to ``SP``, ``Mode``, ``ManualMV``, ``RemoteMV`` and ``Supervisor.Heartbeat`` pass the
contract's checks (:class:`tanklab.ua.WriteGuard`: type, finiteness, EURange, enum) and then
the program's own (a refused write answers a Bad status and the old value stays).
``LIC{j}.SetGains(Kp, Ki, Kd)`` validates all three and stages them for the next scan
boundary: BadOutOfRange (not finite or outside the gain box), BadTypeMismatch (wrong argument
types, checked by the adapter), BadInvalidState (a block without PID gains, or a supervisor that
is not trusted yet). ``Interlock.Reset()`` resets the latched trips whose level is low enough.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from typing import Any

from asyncua import ua

from plc_emulator.program import GainStatus, PlcProgram
from plc_emulator.writes import HEARTBEAT_PATH, apply_write
from tanklab.config import SiteConfig
from tanklab.tags import Tag, plc_tags, tags_by_path
from tanklab.ua import MethodHandler, Publisher
from tanklab.ua_security import ServerSecurity, TierServer, start_tier_server

log = logging.getLogger(__name__)

_STATUS = {
    GainStatus.STAGED: ua.StatusCodes.Good,
    GainStatus.OUT_OF_RANGE: ua.StatusCodes.BadOutOfRange,
    GainStatus.INVALID_STATE: ua.StatusCodes.BadInvalidState,
}


class PlcServer:
    """Serves a :class:`PlcProgram` at ``opc.tcp://HOST:PORT/tanklab/plc``."""

    def __init__(
        self, site: SiteConfig, program: PlcProgram, host: str, port: int, security: ServerSecurity
    ) -> None:
        self.site = site
        self.program = program
        self.url = f"opc.tcp://{host}:{port}/tanklab/plc"
        self.tags = plc_tags(site)
        self.by_path = tags_by_path(self.tags)
        self.security = security
        self.tier: TierServer | None = None
        self.publisher: Publisher | None = None
        self.on_heartbeat: Callable[[], None] | None = None

    async def start(self) -> None:
        """Initialise, secure, build the address space and start listening."""
        methods: dict[str, MethodHandler] = {"PLC.Interlock.Reset": self._reset}
        for lp in self.program.loops:
            methods[f"PLC.{lp.spec.name}.SetGains"] = self._set_gains_for(lp.spec.name)
        self.tier = await start_tier_server(
            "plc",
            url=self.url,
            name="tanklab soft PLC",
            security=self.security,
            tags=self.tags,
            on_write=self._on_write,
            methods=methods,
        )
        self.publisher = self.tier.publisher
        static: dict[str, Any] = {f"PLC.{lp.spec.name}.Block": lp.spec.block for lp in self.program.loops}
        await self.publish({**static, **self.program.values()})
        log.info("PLC server listening at %s", self.url)

    async def stop(self) -> None:
        if self.tier is not None:
            await self.tier.server.stop()
        log.info("PLC server stopped")

    async def publish(self, values: dict[str, Any]) -> None:
        """Publish the scan's values (and the runtime's status values)."""
        assert self.publisher is not None
        await self.publisher.publish(values)

    # ---- writes and calls ---------------------------------------------------------------

    def _on_write(self, tag: Tag, value: Any) -> ua.StatusCode | None:
        try:
            applied = apply_write(self.program, tag.path, value)
        except (ValueError, KeyError) as e:
            log.info("write to %s refused: %s", tag.path, e)
            return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
        if not applied:
            return ua.StatusCode(ua.StatusCodes.BadNotWritable)
        if tag.path == HEARTBEAT_PATH:
            if self.on_heartbeat is not None:
                self.on_heartbeat()
            return None
        log.info("%s := %r", tag.path, value)
        return None

    def _set_gains_for(self, loop: str) -> Callable[..., Awaitable[list[ua.Variant] | ua.StatusCode]]:
        async def set_gains(kp: float, ki: float, kd: float) -> list[ua.Variant] | ua.StatusCode:
            status = self.program.stage_gains(loop, kp, ki, kd)
            log.info("PLC.%s.SetGains(%g, %g, %g): %s", loop, kp, ki, kd, status.value)
            return ua.StatusCode(_STATUS[status])

        return set_gains

    async def _reset(self) -> list[ua.Variant] | ua.StatusCode:
        reset = self.program.reset_interlocks()
        log.info("PLC.Interlock.Reset: reset %s", ", ".join(reset) or "nothing")
        return ua.StatusCode(ua.StatusCodes.Good)
