"""The supervisor's cycle loop: paced by the PLC's scan counter, with its own staleness watchdog.

The supervisor polls the PLC (one Read) several times per scan period of wall time and hands
every new scan's snapshot to :class:`supervisor.port.SupervisorDriver`, the same per-scan logic the
co-simulation runs: it acknowledges every scan with a new heartbeat, tracks the applied MVs, and
every ``supervisor.sample_time_s`` runs a cycle (:class:`supervisor.cycle.SupervisorCore`); the
driver's request goes to the PLC through :class:`supervisor.link.PlcLink`. Polling, not
subscriptions: an asyncua subscription can go silent after a server freeze followed by a crash,
while a Read either answers or fails.

Staleness watchdog: when ``PLC.Status.Scan`` has not advanced for ``plc_stale_s`` of model time
(at least 1 s of wall time), the PLC counts as lost even if it still answers: the supervisor
stops writing, drops the link, reconnects, and reads the applied gains back from the next
snapshot before it pushes anything (the adapter resynchronises from it).

Retentive memory (``retain_file``): the requested mode (an engineer's ``Supervisor.Mode`` write, or
the shed to ADVISORY) is written atomically on every change and requested again on start, so a
restarted supervisor goes back to what it was doing at its first cycle, through the same bumpless
switch as a write (decision 0026). The supervisor's conditions are retentive too, as the PLC's
(``AlarmManager.to_retain``, written when a feed or a client's call changed one): acked, confirmed,
enabled, shelving with its model-time end, comments, active; restored before the server starts,
which announces each restored retained condition once (``AlarmManager.restart_events``). The
estimate, the RLS state and the MPC's plan are not retentive: they are rebuilt from the PLC's
snapshots.

Alarms (:class:`supervisor.alarms.SupervisorAlarms`): each cycle's status is fed at the
snapshot's model time, and the PLC link's state whenever it changes (down: no snapshot or the
scan counter stale; up: a new scan arrived), at the model time of the last snapshot seen; the
events go out through :meth:`SupervisorServer.publish_alarms` before the next await.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

from supervisor.alarms import SupervisorAlarms
from supervisor.controller import SupervisoryController
from supervisor.cycle import SupervisorCore
from supervisor.host import build_host
from supervisor.link import PlcLink
from supervisor.port import SupervisorDriver
from supervisor.server import SupervisorServer
from tanklab import paths
from tanklab.clock import Clock, MonotonicClock, sleep_or_stop
from tanklab.config import SiteConfig
from tanklab.enums import SupervisorMode
from tanklab.errors import LinkError
from tanklab_io.persist import read_json, write_json_atomic
from tanklab_io.ua_security import ClientIdentity, ServerSecurity, client_setup

log = logging.getLogger(__name__)

WALL_FLOOR_S = 1.0

RETAIN_VERSION = 1


class RetainedMode:
    """The supervisor's retentive memory: its requested mode and (with ``alarms``) its
    conditions, in a JSON file.

    ``{"version": 1, "site": NAME, "mode": "MPC"}``, with ``alarms`` also ``"t_s"`` (the model
    time of the last feed [s]) and ``"alarms"`` (``AlarmManager.to_retain()``, the PLC's
    serialisation: per condition Enabled, Active, Acked, Confirmed, Comment and its user,
    shelving and its end in model time). The file is written when the mode or a condition's
    retained state changed (not when only the model time moved on). A missing, unreadable or
    other site's file is not restored (logged), and is overwritten at the first change; a file
    without ``alarms`` (written before they were kept) restores the mode only.
    """

    def __init__(self, path: Path, site: SiteConfig, alarms: SupervisorAlarms | None = None) -> None:
        self.path = path
        self.site = site.name
        self.alarms = alarms
        self.saved: SupervisorMode | None = None
        self._saved_alarms: dict[str, object] | None = None

    def restore(self, core: SupervisorCore) -> SupervisorMode | None:
        """Request the saved mode on ``core`` and restore the saved conditions into ``alarms``
        (each condition's entry checked whole, as the PLC's); the mode restored, or None (the
        config's)."""
        if not self.path.exists():
            log.info("supervisor mode from the config: no retentive memory at %s yet", self.path)
            return None
        try:
            data = read_json(self.path)
            if data.get("version") != RETAIN_VERSION or data.get("site") != self.site:
                raise ValueError(f"written for site {data.get('site')!r}, version {data.get('version')!r}")
        except (OSError, ValueError, TypeError, KeyError, AttributeError) as e:
            log.warning("supervisor mode from the config: retentive memory %s not restored: %s", self.path, e)
            return None
        self._restore_alarms(data)
        try:
            mode = SupervisorMode[str(data["mode"])]
            core.request_mode(mode)
        except (ValueError, TypeError, KeyError, AttributeError) as e:
            log.warning("supervisor mode from the config: retentive memory %s not restored: %s", self.path, e)
            return None
        self.saved = mode
        log.info("warm restart from %s: supervisor mode %s", self.path, mode.name)
        return mode

    def _restore_alarms(self, data: dict[str, object]) -> None:
        if self.alarms is None or "alarms" not in data:  # absent in files of earlier versions
            return
        entry, t_s = data["alarms"], data.get("t_s", 0.0)
        if not isinstance(entry, dict):
            log.warning("supervisor alarms not restored from %s: not a mapping", self.path)
            return
        if isinstance(t_s, int | float) and not isinstance(t_s, bool) and math.isfinite(t_s) and t_s >= 0:
            self.alarms.t_s = float(t_s)
        skipped = self.alarms.manager.from_retain(entry)
        self._saved_alarms = self.alarms.manager.to_retain()
        log.info(
            "warm restart from %s: supervisor alarms at t = %.1f s%s",
            self.path,
            self.alarms.t_s,
            f" (not restored: {'; '.join(skipped)})" if skipped else "",
        )

    def save_if_changed(self, core: SupervisorCore) -> None:
        """Write the requested mode and the conditions when either differs from what was last
        written."""
        mode = core.requested
        conditions = self.alarms.manager.to_retain() if self.alarms is not None else None
        if mode is self.saved and conditions == self._saved_alarms:
            return
        data: dict[str, object] = {"version": RETAIN_VERSION, "site": self.site, "mode": mode.name}
        if self.alarms is not None:
            data["t_s"] = self.alarms.t_s
            data["alarms"] = conditions
        try:
            write_json_atomic(self.path, data)
        except OSError as e:
            log.warning("supervisor mode %s not saved to %s: %s", mode.name, self.path, e)
            return
        self.saved = mode
        self._saved_alarms = conditions


async def run_supervisor(
    site: SiteConfig,
    *,
    host: str,
    port: int,
    plc_url: str,
    security: ServerSecurity,
    stop: asyncio.Event,
    speed: float = 1.0,
    lockstep: bool = False,
    clock: Clock | None = None,
    ready: asyncio.Event | None = None,
    trace: Path | None = None,
    retain_file: Path | None = None,
    controller: str | SupervisoryController | None = None,
    cpu_clock: Callable[[], float] = time.thread_time,
) -> SupervisorCore:
    """Supervise the PLC until ``stop`` is set; return the core for inspection.

    ``trace``: a CSV file that gets one line per sample whose MPC step ran (see
    :func:`trace_row`): how a lock-step run is compared with the co-simulation.
    ``retain_file``: the retentive mode (see the module docstring); none by default.
    ``controller``: the supervisory controller, or its dotted path (``--controller``; default: the site's
    ``supervisor.controller``, else the shipped one), run through the same
    :func:`supervisor.host.build_host` and :class:`SupervisorDriver` as the co-simulation's;
    ``cpu_clock`` measures its steps against the budget.

    Raises
    ------
    tanklab.errors.ControllerError
        the controller cannot be loaded or built (before anything is served).
    """
    if site.supervisor is None or site.plc is None:
        raise ValueError(f"site {site.name!r} has no supervisor section")
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    clock = clock or MonotonicClock()
    path = controller if isinstance(controller, str) else None
    instance = None if isinstance(controller, str) else controller
    core, ctl = build_host(site, path, controller=instance, cpu_clock=cpu_clock)
    alarms = SupervisorAlarms(
        site,
        adaptation=core.adapter is not None,
        event_prefix=os.urandom(8),  # EventIds unique across restarts of the process
    )
    retained = RetainedMode(retain_file, site, alarms) if retain_file is not None else None
    if retained is not None:
        retained.restore(core)
        retained.save_if_changed(core)  # the file holds the mode in force from the start
    driver = SupervisorDriver(core, ctl)
    server = SupervisorServer(
        site,
        core,
        host,
        port,
        security,
        alarms=alarms,
        speed=speed,
        diagnostics=ctl.controller.diagnostics,
        controller=ctl.report(),
    )

    def save() -> None:
        if retained is not None:
            retained.save_if_changed(core)

    server.on_mode = save
    server.on_alarms = save
    ts_wall = site.plc.scan_period_s / speed
    link = PlcLink(
        site,
        plc_url,
        setup=client_setup(ClientIdentity(security.home, "supervisor")),
        timeout_s=min(2.0, max(0.2, 2 * ts_wall)),
    )
    poll_s = 0.001 if lockstep else max(0.005, ts_wall / 5)
    stale_wall_s = max(site.supervisor.plc_stale_s / speed, WALL_FLOOR_S)
    await server.start()
    if ready is not None:
        ready.set()
    trace_file = trace.open("w", encoding="utf-8") if trace is not None else None
    last_progress = clock.now()
    connected = False
    link_published: dict[str, object] = {}
    link_up = False  # as the alarms were last fed (PlcLinkLost stays normal until a first loss)
    t_model = 0.0  # model time of the last snapshot [s]

    async def link_alarm(up: bool) -> None:
        nonlocal link_up
        if up != link_up:
            link_up = up
            if events := alarms.feed(None, up, t_model):
                save()
                await server.publish_alarms(events)

    try:
        while not stop.is_set():
            snap = await link.snapshot()
            now = clock.now()
            if (link_status := link.link.status(paths.supervisor.plc_link)) != link_published:
                await server.publish(link_status)
                link_published = link_status
            if snap is None:
                if connected:
                    log.warning("PLC lost; will read the applied gains back after reconnecting")
                    core.push_refused()
                connected = False
                await link_alarm(False)
                await server.publish({paths.supervisor.plc_connected: False})
                await sleep_or_stop(clock, now + poll_s * 10, stop)
                continue
            if not connected:
                connected = True
                last_progress = now
                core.push_refused()  # resynchronise the adapter with what the PLC applies
                await server.publish({paths.supervisor.plc_connected: True})
            if snap.scan == driver.last_scan:
                if now - last_progress > stale_wall_s:
                    log.warning("PLC scan counter stale for %.1f s: dropping the link", now - last_progress)
                    await link.close()
                    driver.lost()
                    await link_alarm(False)
                    continue
                await sleep_or_stop(clock, now + poll_s, stop)
                continue
            last_progress = now
            t_model = snap.t_s
            await link_alarm(True)
            sheds = core.sheds
            request = driver.on_snapshot(snap)
            if request is None:
                continue
            if core.sheds > sheds:
                log.warning("MPC shed to ADVISORY: %s (re-engage with `tankctl mode mpc`)", core.shed_reason)
            if retained is not None:
                retained.save_if_changed(core)
            try:
                # The heartbeat goes with the actions (last): the PLC may scan on while this
                # tier publishes its own diagnostics.
                driver.refused(await link.apply(request))
            except LinkError as e:
                log.warning("%s", e)
            if request.actions is not None and request.actions.status is not None:
                if events := alarms.feed(request.actions.status, link_up, t_model):
                    save()
                    await server.publish_alarms(events)
                await server.expire_alarm_rate()
                await server.publish_status(request.actions.status, ctl.report())
                if trace_file is not None and core.result_scan == snap.scan:
                    trace_file.write(",".join(repr(x) for x in trace_row(snap.scan, snap.t_s, core)) + "\n")
    finally:
        if trace_file is not None:
            trace_file.close()
        await link.close()
        await server.stop()
    return core


def trace_row(scan: int, t_s: float, core: SupervisorCore) -> list[float]:
    """One supervisor trace line: the sample's PLC scan and model time [s], the supervisor mode,
    then the MPC's planned inputs [m^3/s] (step-major, pumps inner, as ``PlannedMV``)."""
    assert core.result is not None
    return [
        float(scan),
        float(t_s),
        float(int(core.mode)),
        *(float(x) for x in core.result.planned_u.ravel()),
    ]
