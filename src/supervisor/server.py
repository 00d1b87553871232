"""The supervisor's OPC UA server: mode, MPC diagnostics, RLS state, disturbance estimate.

The core reports its state as a value (:class:`supervisor.cycle.SupervisorStatus`);
:func:`status_values` maps it to the contract's paths (:mod:`tanklab.paths`), the only place
that knows which node shows what.

``Supervisor.Mode`` is writable (engineer): OFF, ADVISORY, ADAPTIVE_PID, MPC; the switch happens
at the next cycle, bumplessly. ADAPTIVE_PID on a site whose loops are not all PID loops is
refused with BadInvalidState.

The supervisor's own alarms (:class:`supervisor.alarms.SupervisorAlarms`: MpcFailing,
AdaptationUnhealthy, PlcLinkLost) are OPC UA conditions under ``Supervisor`` (installed at
:meth:`SupervisorServer.start`, docs/alarms.md section 9): the runtime publishes each cycle's
events with :meth:`SupervisorServer.publish_alarms`; a client's condition call is answered by
``manager.call(call, alarms.t_s)``, the model time of the last feed.

``Supervisor.Controller.*`` shows the supervisory controller (decision 0054): its class, steps,
contained errors and overruns, the last error, and its declared diagnostics
(:func:`controller_values`). Feeds and calls are
serialised by the one asyncio loop (both synchronous). After a warm restart (the runtime's
retentive memory) each restored retained condition is announced once at start.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from asyncua import ua

from supervisor.alarms import SupervisorAlarms
from supervisor.cycle import SupervisorCore, SupervisorStatus
from supervisor.fdi import FaultKind, FdiReport
from supervisor.host import ControllerReport
from tanklab import paths
from tanklab.alarms import CallStatus, ConditionCall, ConditionEvent
from tanklab.config import SiteConfig
from tanklab.enums import MpcStatus, SupervisorMode
from tanklab.handlers import HandlerTable
from tanklab.tags import Diagnostic, Tag, supervisor_tags, tags_by_path
from tanklab_io.conditions import ModelUtc, UaConditions
from tanklab_io.conditions.summary import SummaryPublisher
from tanklab_io.ua import Publisher, WriteHandler
from tanklab_io.ua_security import ServerSecurity, TierServer, start_tier_server

log = logging.getLogger(__name__)


class SupervisorServer:
    """Serves a :class:`SupervisorCore` at ``opc.tcp://HOST:PORT/tanklab/supervisor``.

    ``alarms``: the supervisor's alarms (a fresh :class:`SupervisorAlarms` without EventId prefix
    by default; the runtime passes one with its process's prefix). ``speed``: model seconds per
    wall second (how alarm events' model time maps to UTC).
    """

    def __init__(
        self,
        site: SiteConfig,
        core: SupervisorCore,
        host: str,
        port: int,
        security: ServerSecurity,
        *,
        alarms: SupervisorAlarms | None = None,
        speed: float = 1.0,
        diagnostics: Sequence[Diagnostic] = (),
        controller: ControllerReport | None = None,
    ) -> None:
        self.site = site
        self.controller = controller
        """The supervisory controller's report to publish at start (its class name)."""
        self.core = core
        self.alarms = alarms or SupervisorAlarms(site, adaptation=core.adapter is not None)
        self.conditions: UaConditions | None = None
        self.summary: SummaryPublisher | None = None
        """``Supervisor.AlarmSummary.*``, as the PLC's (after each batch of condition events and
        when an activation leaves the rate window: :meth:`expire_alarm_rate`)."""
        self.to_utc = ModelUtc(speed)
        self.url = f"opc.tcp://{host}:{port}/tanklab/supervisor"
        self.tags = supervisor_tags(site, diagnostics)
        self.by_path = tags_by_path(self.tags)
        self.security = security
        self.tier: TierServer | None = None
        self.publisher: Publisher | None = None
        self.on_mode: Callable[[], None] | None = None
        """Called after an accepted ``Supervisor.Mode`` write (the runtime saves the mode)."""
        self.on_alarms: Callable[[], None] | None = None
        """Called after a client's condition call changed a condition (the runtime saves the
        retentive memory)."""

    async def start(self) -> None:
        """Initialise, secure, build the address space and start listening."""
        self.tier = await start_tier_server(
            "supervisor",
            url=self.url,
            name="tanklab supervisor",
            security=self.security,
            tags=self.tags,
            writes=self.write_handlers(),
        )
        self.publisher = self.tier.publisher
        manager = self.alarms.manager
        self.to_utc.anchor(self.alarms.t_s)
        self.conditions = await UaConditions.install_manager(
            self.tier.server,
            "supervisor",
            manager,
            handler=self._alarm_call,
            to_utc=self.to_utc,
            audit=self.tier.audit,
        )
        self.summary = SummaryPublisher("supervisor", manager, self.publish, lambda: self.alarms.t_s)
        self.conditions.after_publish = self.summary.publish
        await self.summary.publish()
        # After a warm restart each restored retained condition is announced once, as the PLC's.
        await self.conditions.publish(manager.restart_events(self.alarms.t_s))
        await self.publish_status(self.core.status(), self.controller)
        log.info("supervisor server listening at %s", self.url)

    def _alarm_call(self, call: ConditionCall) -> tuple[CallStatus, Sequence[ConditionEvent]]:
        """A client's condition call, answered by the core at the last feed's model time (the
        retentive memory is stored when the call changed a condition)."""
        status, events = self.alarms.manager.call(call, self.alarms.t_s)
        if events and self.on_alarms is not None:
            self.on_alarms()
        return status, events

    async def publish_alarms(self, events: Sequence[ConditionEvent]) -> None:
        """Raise a feed's alarm events (call only with some) and anchor their model time to now."""
        assert self.conditions is not None
        self.to_utc.anchor(self.alarms.t_s)
        await self.conditions.publish(events)

    async def expire_alarm_rate(self) -> None:
        """After each feed: republish the alarm summary if an activation left the 600 s rate
        window by the feed's model time (a comparison otherwise)."""
        assert self.summary is not None
        await self.summary.expire()

    async def stop(self) -> None:
        if self.tier is not None:
            await self.tier.server.stop()
        log.info("supervisor server stopped")

    async def publish(self, values: dict[str, Any]) -> None:
        assert self.publisher is not None
        await self.publisher.publish(values)

    async def publish_status(
        self, status: SupervisorStatus, controller: ControllerReport | None = None
    ) -> None:
        """Publish the core's state (:func:`status_values`) and the controller's report
        (:func:`controller_values`)."""
        values = status_values(status)
        if controller is not None:
            values.update(controller_values(controller))
        await self.publish(values)

    def write_handlers(self) -> HandlerTable[WriteHandler]:
        """The handler of each writable supervisor variable (``Supervisor.Mode``)."""
        table: HandlerTable[WriteHandler] = HandlerTable()
        table.on(paths.supervisor.mode, self._write_mode)
        return table

    def _write_mode(self, tag: Tag, value: Any) -> ua.StatusCode | None:
        try:
            self.core.request_mode(SupervisorMode(int(value)))
        except ValueError as e:
            log.info("mode change refused: %s", e)
            return ua.StatusCode(ua.StatusCodes.BadInvalidState)
        log.info("%s := %s", tag.path, SupervisorMode(int(value)).name)
        if self.on_mode is not None:
            self.on_mode()
        return None


def status_values(status: SupervisorStatus) -> dict[str, Any]:
    """The supervisor's node values of ``status``, keyed by tag path."""
    sup = paths.supervisor
    v: dict[str, Any] = {sup.mode: int(status.mode), sup.cycle: status.cycles}
    res = status.mpc
    if res is not None:
        v[sup.mpc_solve_time] = res.solve_time_s
        v[sup.mpc_iterations] = res.iterations
        v[sup.mpc_status] = int(res.status)
        v[sup.mpc_failures] = res.failures
        v[sup.mpc_planned_mv] = [float(x) for x in res.planned_u.ravel()]
        v[sup.mpc_predicted_pv] = [float(x) for x in res.predicted_z.ravel()]
        v[sup.disturbance] = [float(x) for x in res.disturbance]
    else:
        v[sup.mpc_status] = int(MpcStatus.NOT_RUN)
    if status.fdi is not None:
        v.update(fdi_values(status.fdi))
    for name, a in status.adaptation or ():
        rls = sup.rls(name)
        v[rls.theta] = list(a.theta)
        v[rls.covariance_trace] = a.covariance_trace
        v[rls.accepted] = a.accepted
        v[rls.last_reason] = a.last_reason
        v[rls.excitation] = a.excitation
        v[rls.condition_number] = a.condition_number
        v[rls.box_distance] = list(a.box_distance)
        v[rls.on_box_limit] = a.on_box_limit
        v[rls.prior] = list(a.prior)
        v[rls.noise_std] = a.noise_std_m
        v[rls.rejected] = status.rejected
    return v


def controller_values(report: ControllerReport) -> dict[str, Any]:
    """The ``Supervisor.Controller.*`` node values of ``report``, keyed by tag path."""
    sup = paths.supervisor
    v: dict[str, Any] = {
        sup.controller_class: report.class_name,
        sup.controller_cycles: report.cycles,
        sup.controller_errors: report.errors,
        sup.controller_last_error: report.last_error,
        sup.controller_overruns: report.overruns,
    }
    for name, value in report.diagnostics.items():
        v[sup.controller_diagnostic(name)] = value
    return v


def fdi_values(report: FdiReport) -> dict[str, Any]:
    """The ``Supervisor.FDI.*`` values of a diagnosis report, keyed by tag path."""
    sup = paths.supervisor
    d = report.diagnosis
    v: dict[str, Any] = {
        sup.fdi_state: int(report.state),
        sup.fdi_diagnosis: d.hypothesis.name if d else "",
        sup.fdi_kind: int(d.hypothesis.kind) if d else int(FaultKind.NONE),
        sup.fdi_size: d.size if d else 0.0,
        sup.fdi_size_std: d.size_std if d else 0.0,
        sup.fdi_confidence: report.confidence,
        sup.fdi_best: report.best.name if report.best else "",
        sup.fdi_message: d.message if d else "",
    }
    for h in report.hypotheses:
        hp = sup.fdi_hypothesis(h.hypothesis.name)
        v[hp.statistic] = h.statistic
        v[hp.threshold] = h.threshold
        v[hp.alarm] = h.alarm
        v[hp.size] = h.size
    return v
