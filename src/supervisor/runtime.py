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
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

from supervisor.cycle import SupervisorCore
from supervisor.link import PlcLink
from supervisor.port import SupervisorDriver
from supervisor.server import SupervisorServer
from tanklab.clock import Clock, MonotonicClock, sleep_or_stop
from tanklab.config import SiteConfig
from tanklab.errors import LinkError
from tanklab.ua_security import ClientIdentity, ServerSecurity, client_setup

log = logging.getLogger(__name__)

WALL_FLOOR_S = 1.0


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
) -> SupervisorCore:
    """Supervise the PLC until ``stop`` is set; return the core for inspection.

    ``trace``: a CSV file that gets one line per sample whose MPC step ran (see
    :func:`trace_row`): how a lock-step run is compared with the co-simulation.
    """
    if site.supervisor is None or site.plc is None:
        raise ValueError(f"site {site.name!r} has no supervisor section")
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    clock = clock or MonotonicClock()
    core = SupervisorCore(site)
    driver = SupervisorDriver(core)
    server = SupervisorServer(site, core, host, port, security)
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
    try:
        while not stop.is_set():
            snap = await link.snapshot()
            now = clock.now()
            if (link_status := link.link.status("Supervisor.PlcLink")) != link_published:
                await server.publish(link_status)
                link_published = link_status
            if snap is None:
                if connected:
                    log.warning("PLC lost; will read the applied gains back after reconnecting")
                    core.push_refused()
                connected = False
                await server.publish({"Supervisor.PlcConnected": False})
                await sleep_or_stop(clock, now + poll_s * 10, stop)
                continue
            if not connected:
                connected = True
                last_progress = now
                core.push_refused()  # resynchronise the adapter with what the PLC applies
                await server.publish({"Supervisor.PlcConnected": True})
            if snap.scan == driver.last_scan:
                if now - last_progress > stale_wall_s:
                    log.warning("PLC scan counter stale for %.1f s: dropping the link", now - last_progress)
                    await link.close()
                    driver.lost()
                    continue
                await sleep_or_stop(clock, now + poll_s, stop)
                continue
            last_progress = now
            sheds = core.sheds
            request = driver.on_snapshot(snap)
            if request is None:
                continue
            if core.sheds > sheds:
                log.warning("MPC shed to ADVISORY: %s (re-engage with `tankctl mode mpc`)", core.shed_reason)
            try:
                # The heartbeat goes with the actions (last): the PLC may scan on while this
                # tier publishes its own diagnostics.
                driver.refused(await link.apply(request))
            except LinkError as e:
                log.warning("%s", e)
            if request.actions is not None:
                await server.publish(request.actions.values)
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
