"""The PLC's OPC UA server: the contract's PLC nodes over a :class:`PlcProgram`.

Writes to ``SP``, ``SPLow``, ``SPHigh``, ``Mode``, ``ManualMV``, ``RemoteMV`` and
``Supervisor.Heartbeat`` pass the contract's checks (:class:`tanklab_io.ua.WriteGuard`: type,
finiteness, EURange, enum) and then the program's own, through the tag's own handler
(:meth:`PlcServer.write_handlers` over :func:`plc_emulator.writes.program_writes`; a refused
write answers a Bad status and the old value stays).
``LIC{j}.SetGains(Kp, Ki, Kd)`` validates all three and stages them for the next scan
boundary: BadOutOfRange (not finite or outside the gain box), BadTypeMismatch (wrong argument
types, checked by the adapter), BadInvalidState (a block without PID gains; for the supervisor's
identity also a supervisor that is not trusted yet, or a loop an engineer holds). Who called
decides the label: the supervisor's identity stages SUPERVISOR gains, an engineer's session
ENGINEER gains (the session's user comes from :data:`tanklab_io.ua.CURRENT_USER`, set for the
request being served). ``LIC{j}.ResetGains()`` stages the configured gains (source FIXED,
releasing an engineer's hold; BadInvalidState while a mode change is pending or for a block
without PID gains); ``LIC{j}.ReleaseGains()`` hands an ENGINEER loop back (source FIXED, gains
kept). Role checks and the audit record of every call are the method adapter's
(:mod:`tanklab_io.ua`). ``Interlock.Reset()`` resets the latched trips whose level is low enough.

The PLC's alarms are OPC UA conditions (:class:`tanklab_io.conditions.UaConditions`, installed
at :meth:`PlcServer.start` from the program's alarm manager; docs/alarms.md section 7): the
runtime publishes each scan's alarm events with :meth:`PlcServer.publish_alarms` (after each batch
the alarm summary ``PLC.AlarmSummary.*`` follows, and each scan :meth:`PlcServer.expire_alarm_rate`
republishes it when an activation leaves the rate window), and a client's
Acknowledge, Confirm, AddComment, Enable, Disable or shelving call is answered by
``manager.call(call, program.t_s)``. Scans and calls are serialised by the one asyncio loop the
scan and the server share: ``program.scan`` and ``manager.call`` are synchronous, so a call runs
wholly before or after a scan, at the model time of the last scan; the events reach the nodes in
the core's order (the projection publishes one batch at a time, and the runtime asks for the
scan's batch before its first await after the scan).

**Who drives a loop in REMOTE** (decision 0055): each loop's ``RemoteSource`` (engineer,
retentive) names its owner, SUPERVISOR or EXTERNAL. A write of ``RemoteMV`` or ``Mode`` by the
supervisor's identity on an EXTERNAL loop, or by an External identity on a SUPERVISOR loop, is
refused with BadUserAccessDenied before the program sees it (the old value stays; the write
guard has already checked the role against the contract's writers). ``RemoteSource`` changes only
while the loop is not in REMOTE (BadInvalidState). ``External.Heartbeat`` feeds the external
watchdog; unlike the supervisor's it acknowledges no lock-step scan.

The program reports its state as a value (:class:`plc_emulator.status.PlcStatus`);
:func:`plc_emulator.publish.status_values` maps it to the contract's paths, and
:meth:`PlcServer.publish_status` publishes it.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

from asyncua import ua

from plc_emulator.program import GainStatus, PlcProgram
from plc_emulator.publish import status_values
from plc_emulator.status import PlcStatus
from plc_emulator.writes import ProgramWrite, program_writes
from tanklab import paths
from tanklab.alarms import CallStatus, ConditionCall, ConditionEvent
from tanklab.config import SiteConfig
from tanklab.enums import GainSource, LoopMode, RemoteSource
from tanklab.handlers import HandlerTable
from tanklab.tags import HEARTBEAT_PATH, Role, Tag, plc_tags, tags_by_path
from tanklab_io.conditions import ModelUtc, UaConditions
from tanklab_io.conditions.summary import SummaryPublisher
from tanklab_io.ua import CURRENT_USER, MethodHandler, Publisher, TankUser, WriteHandler
from tanklab_io.ua_security import ServerSecurity, TierServer, start_tier_server

log = logging.getLogger(__name__)

_STATUS = {
    GainStatus.STAGED: ua.StatusCodes.Good,
    GainStatus.OUT_OF_RANGE: ua.StatusCodes.BadOutOfRange,
    GainStatus.INVALID_STATE: ua.StatusCodes.BadInvalidState,
}


_REMOTE_ROLES = {Role.SUPERVISOR: RemoteSource.SUPERVISOR, Role.EXTERNAL: RemoteSource.EXTERNAL}
"""The certificate roles that drive loops in REMOTE, and the RemoteSource each one owns."""


class PlcServer:
    """Serves a :class:`PlcProgram` at ``opc.tcp://HOST:PORT/tanklab/plc``.

    ``speed``: model seconds per wall second (how alarm events' model time maps to UTC).
    """

    def __init__(
        self,
        site: SiteConfig,
        program: PlcProgram,
        host: str,
        port: int,
        security: ServerSecurity,
        *,
        speed: float = 1.0,
    ) -> None:
        self.site = site
        self.program = program
        self.url = f"opc.tcp://{host}:{port}/tanklab/plc"
        self.tags = plc_tags(site)
        self.by_path = tags_by_path(self.tags)
        self.security = security
        self.tier: TierServer | None = None
        self.publisher: Publisher | None = None
        self.conditions: UaConditions | None = None
        self.summary: SummaryPublisher | None = None
        """``PLC.AlarmSummary.*``: republished after each batch of condition events and when an
        activation leaves the rate window (:meth:`expire_alarm_rate`)."""
        self.to_utc = ModelUtc(speed)
        self.on_heartbeat: Callable[[], None] | None = None
        self.on_change: Callable[[], None] | None = None
        """Called after every applied write and accepted call but the heartbeat (the runtime
        stores the retentive memory then, not only at the end of the next scan)."""

    async def start(self) -> None:
        """Initialise, secure, build the address space and start listening."""
        self.tier = await start_tier_server(
            "plc",
            url=self.url,
            name="tanklab soft PLC",
            security=self.security,
            tags=self.tags,
            writes=self.write_handlers(),
            methods=self.method_handlers(),
        )
        self.publisher = self.tier.publisher
        await self._install_conditions()
        static: dict[str, Any] = {
            paths.plc.loop(lp.spec.name).block: lp.spec.block for lp in self.program.loops
        }
        await self.publish_status(self.program.status(), static)
        log.info("PLC server listening at %s", self.url)

    async def _install_conditions(self) -> None:
        """The alarm manager's conditions on the server; after a warm restart each restored
        retained condition is announced once (:meth:`AlarmManager.restart_events`), so its
        nodes show the restored state and a client can acknowledge it."""
        assert self.tier is not None
        manager = self.program.alarms.manager
        self.to_utc.anchor(self.program.t_s)
        self.conditions = await UaConditions.install_manager(
            self.tier.server,
            "plc",
            manager,
            handler=self._alarm_call,
            to_utc=self.to_utc,
            audit=self.tier.audit,
        )
        self.summary = SummaryPublisher("plc", manager, self.publish, lambda: self.program.t_s)
        self.conditions.after_publish = self.summary.publish
        await self.summary.publish()
        await self.conditions.publish(manager.restart_events(self.program.t_s))

    def _alarm_call(self, call: ConditionCall) -> tuple[CallStatus, Sequence[ConditionEvent]]:
        """A client's condition call, answered by the core at the last scan's model time (the
        retentive memory is stored when the call changed a condition)."""
        status, events = self.program.alarms.manager.call(call, self.program.t_s)
        if events:
            self._changed()
        return status, events

    async def publish_alarms(self, events: Sequence[ConditionEvent]) -> None:
        """Raise a scan's alarm events (call only with some: the usual scan has none) and
        anchor their model time to now."""
        assert self.conditions is not None
        self.to_utc.anchor(self.program.t_s)
        await self.conditions.publish(events)

    async def expire_alarm_rate(self) -> None:
        """Once per scan: republish the alarm summary if an activation left the 600 s rate
        window by the last scan's model time (a comparison otherwise)."""
        assert self.summary is not None
        await self.summary.expire()

    async def stop(self) -> None:
        if self.tier is not None:
            await self.tier.server.stop()
        log.info("PLC server stopped")

    async def publish(self, values: dict[str, Any]) -> None:
        """Publish values keyed by tag path (the runtime's own: scan duration, link status)."""
        assert self.publisher is not None
        await self.publisher.publish(values)

    async def publish_status(self, status: PlcStatus, extra: Mapping[str, Any] | None = None) -> None:
        """Publish the program's state (:func:`status_values`) and ``extra`` values keyed by tag
        path (the runtime's, for the same scan), in one pass."""
        values = status_values(status)
        if extra:
            values.update(extra)
        await self.publish(values)

    # ---- writes and calls ---------------------------------------------------------------

    def write_handlers(self) -> HandlerTable[WriteHandler]:
        """The handler of each writable PLC variable: the program's (:func:`program_writes`),
        its refusal answered BadOutOfRange."""
        table: HandlerTable[WriteHandler] = HandlerTable()
        owned = {}
        for lp in self.program.loops:
            loop = paths.plc.loop(lp.spec.name)
            owned[loop.remote_mv] = owned[loop.mode] = lp.spec.name
        sources = {paths.plc.loop(lp.spec.name).remote_source: lp.spec.name for lp in self.program.loops}
        for path, apply in program_writes(self.program).items():
            if path == HEARTBEAT_PATH:
                handler = self._heartbeat(apply)
            elif path == paths.plc.external_heartbeat:
                handler = self._external_heartbeat(apply)
            elif path in owned:
                handler = self._owned(owned[path], self._request(apply))
            elif path in sources:
                handler = self._remote_source(sources[path], self._request(apply))
            else:
                handler = self._request(apply)
            table.on(path, handler)
        return table

    def _owned(self, loop: str, inner: WriteHandler) -> WriteHandler:
        """``RemoteMV`` or ``Mode`` of ``loop``: the supervisor's identity only on a SUPERVISOR
        loop, an External identity only on an EXTERNAL one (BadUserAccessDenied otherwise)."""

        def handler(tag: Tag, value: Any) -> ua.StatusCode | None:
            user = CURRENT_USER.get()
            role = user.tank_role if isinstance(user, TankUser) else None
            wanted = _REMOTE_ROLES.get(role) if role is not None else None
            if wanted is not None and self.program.loop(loop).remote_source is not wanted:
                log.info(
                    "write to %s by %s refused: the loop's RemoteSource is not %s",
                    tag.path,
                    role,
                    wanted.name,
                )
                return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
            return inner(tag, value)

        return handler

    def _remote_source(self, loop: str, inner: WriteHandler) -> WriteHandler:
        """``RemoteSource`` of ``loop``: BadInvalidState while the loop is in REMOTE."""

        def handler(tag: Tag, value: Any) -> ua.StatusCode | None:
            lp = self.program.loop(loop)
            if lp.mode is LoopMode.REMOTE and int(value) != int(lp.remote_source):
                log.info("write to %s refused: %s is in REMOTE", tag.path, loop)
                return ua.StatusCode(ua.StatusCodes.BadInvalidState)
            return inner(tag, value)

        return handler

    def _external_heartbeat(self, apply: ProgramWrite) -> WriteHandler:
        def handler(tag: Tag, value: Any) -> ua.StatusCode | None:
            return self._applied(tag, apply, value)

        return handler

    def method_handlers(self) -> HandlerTable[MethodHandler]:
        """The handler of each PLC method: each loop's gain calls and the interlock reset."""
        table: HandlerTable[MethodHandler] = HandlerTable()
        table.on(paths.plc.interlock_reset, self._reset)
        for lp in self.program.loops:
            loop = paths.plc.loop(lp.spec.name)
            table.on(loop.set_gains, self._set_gains_for(lp.spec.name))
            table.on(loop.reset_gains, self._reset_gains_for(lp.spec.name))
            table.on(loop.release_gains, self._release_gains_for(lp.spec.name))
        return table

    @staticmethod
    def _applied(tag: Tag, apply: ProgramWrite, value: Any) -> ua.StatusCode | None:
        try:
            apply(value)
        except (ValueError, KeyError) as e:
            log.info("write to %s refused: %s", tag.path, e)
            return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
        return None

    def _heartbeat(self, apply: ProgramWrite) -> WriteHandler:
        def handler(tag: Tag, value: Any) -> ua.StatusCode | None:
            refused = self._applied(tag, apply, value)
            if refused is None and self.on_heartbeat is not None:
                self.on_heartbeat()
            return refused

        return handler

    def _request(self, apply: ProgramWrite) -> WriteHandler:
        """An operator's or the supervisor's write: logged, and the retentive memory stored."""

        def handler(tag: Tag, value: Any) -> ua.StatusCode | None:
            refused = self._applied(tag, apply, value)
            if refused is None:
                log.info("%s := %r", tag.path, value)
                self._changed()
            return refused

        return handler

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    def _set_gains_for(self, loop: str) -> Callable[..., Awaitable[list[ua.Variant] | ua.StatusCode]]:
        path = paths.plc.loop(loop).set_gains

        async def set_gains(kp: float, ki: float, kd: float) -> list[ua.Variant] | ua.StatusCode:
            user = CURRENT_USER.get()
            role = user.tank_role if isinstance(user, TankUser) else None
            if role is None:  # the adapter's role check refuses these first
                return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
            source = GainSource.SUPERVISOR if role is Role.SUPERVISOR else GainSource.ENGINEER
            status = self.program.stage_gains(loop, kp, ki, kd, source)
            log.info("%s(%g, %g, %g) as %s: %s", path, kp, ki, kd, source.name, status.value)
            self._changed()
            return ua.StatusCode(_STATUS[status])

        return set_gains

    def _reset_gains_for(self, loop: str) -> Callable[..., Awaitable[list[ua.Variant] | ua.StatusCode]]:
        path = paths.plc.loop(loop).reset_gains

        async def reset_gains() -> list[ua.Variant] | ua.StatusCode:
            status = self.program.reset_gains(loop)
            log.info("%s: %s", path, status.value)
            self._changed()
            return ua.StatusCode(_STATUS[status])

        return reset_gains

    def _release_gains_for(self, loop: str) -> Callable[..., Awaitable[list[ua.Variant] | ua.StatusCode]]:
        path = paths.plc.loop(loop).release_gains

        async def release_gains() -> list[ua.Variant] | ua.StatusCode:
            status = self.program.release_gains(loop)
            log.info("%s: %s", path, status.value)
            self._changed()
            return ua.StatusCode(_STATUS[status])

        return release_gains

    async def _reset(self) -> list[ua.Variant] | ua.StatusCode:
        reset = self.program.reset_interlocks()
        log.info("%s: reset %s", paths.plc.interlock_reset, ", ".join(reset) or "nothing")
        self._changed()
        return ua.StatusCode(ua.StatusCodes.Good)
