"""The PLC's scan loop: deadlines on an injected clock, the field link, the server.

Realtime: scans start on deadlines ``next = previous + Ts / speed`` (wall seconds) on the clock;
a scan whose work runs past the next deadline is an overrun (counted, published, and the
missed deadlines are skipped rather than run in a burst). Model time advances by the nominal
``Ts`` per scan, whatever the speed: the blocks always compute with the model-time Ts.

Lock-step: no deadlines. Each scan ends with ``Plant.Sim.Advance(Ts, commands)`` (the plant
integrates one scan period and returns the next readings) and then waits, at most 2 s of wall
time, for the supervisor to acknowledge the scan by changing ``Heartbeat``; a missing ack counts
as a missed heartbeat, and once the watchdog has declared the supervisor lost the PLC stops
waiting for it. The scan's values are published before the Advance call, so the supervisor reads
and acknowledges them while the plant integrates (decision 0013).

Retentive memory (``plc.retain_file``, or the ``retain_file`` argument: ``tankctl plc
--retain-file``): SP, SP limits, mode, manual MV, applied gains with their source, latched
trips, each loop's MV, the scan counter and the model time, written atomically and durably
(:func:`tanklab_io.persist.write_atomic`: temp file, fsync, rename) after every scan that changed
them, after every applied operator write or accepted call and at stop, by a writer thread
(:class:`RetainedStore`: the scan never waits for the disk; the latest state wins). When the
file exists at start the PLC warm-restarts (``cold=True``, ``tankctl plc --cold``, starts from
the config instead and says so): each value is checked as if written now, the scan counter and
model time continue, and before the first scan the PLC reads the plant's pump commands and
level readings and resumes from them bumplessly (:meth:`PlcProgram.resume_from_plant`): the
outputs start where the pumps are, not at the config's initial command. Decision 0019.

Model-time timeouts have a wall-clock floor of 1 s: at speed X the heartbeat timeout is at
least X model seconds, so scheduling noise never trips the watchdog.
"""

from __future__ import annotations

import asyncio
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from plc_emulator.link import FieldLink, FieldReadings
from plc_emulator.program import PlcProgram, ScanInputs
from plc_emulator.server import PlcServer
from plc_emulator.status import PlcStatus
from tanklab import paths
from tanklab.clock import Clock, Deadlines, MonotonicClock, sleep_or_stop
from tanklab.config import SiteConfig
from tanklab_io.persist import read_json, write_json_atomic
from tanklab_io.ua_security import ClientIdentity, ServerSecurity, client_setup

log = logging.getLogger(__name__)

WALL_FLOOR_S = 1.0
"""Smallest wall time any model-time timeout may correspond to [s]."""
LOCKSTEP_ACK_S = 2.0
"""Longest wall wait for the supervisor's acknowledgement of a lock-step scan [s]."""
LOCKSTEP_STARTUP_S = 30.0
"""Longest wall wait for the supervisor's first heartbeat before the first lock-step scan [s]."""


@dataclass
class PlcRunStats:
    """What a run measured: scans, overruns, start lateness of each scan [wall s]."""

    scans: int = 0
    overruns: int = 0
    lateness_s: list[float] = field(default_factory=list)
    io_failures: int = 0


class RetainedStore:
    """The retentive memory file, written off the scan.

    :meth:`offer` takes a snapshot (``PlcProgram.retained()``) and returns at once; a writer
    thread stores it atomically and durably (:func:`tanklab_io.persist.write_json_atomic`: temp
    file, fsync, rename), one write at a time. A snapshot offered while a write is in flight
    waits for it, and a newer one replaces it (the latest state wins: under load the file skips
    intermediate scans, never the last one). So the scan never waits for the disk (an fsync is
    about 1 ms, a third of a lock-step scan). :meth:`close` waits for the last snapshot to be
    stored. A failed write is logged; the next snapshot tries again.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.stored: dict[str, object] | None = None
        self.writes = 0
        self._pending: dict[str, object] | None = None
        self._task: asyncio.Task[None] | None = None

    def offer(self, data: dict[str, object]) -> None:
        """Store ``data`` soon unless it equals what is stored or waiting (call in the loop)."""
        if data == self._pending or (self._pending is None and data == self.stored):
            return
        self._pending = data
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._drain())

    async def _drain(self) -> None:
        while self._pending is not None:
            data, self._pending = self._pending, None
            try:
                await asyncio.to_thread(write_json_atomic, self.path, data)
            except OSError as e:  # the scan goes on; the next change tries again
                log.warning("cannot store the retentive memory %s: %s", self.path, e)
            else:
                self.stored = data
                self.writes += 1

    async def close(self) -> None:
        """Wait until every offered snapshot has been written (or has failed)."""
        while self._task is not None and not self._task.done():
            await asyncio.shield(self._task)


def _warm_restore(program: PlcProgram, retain: Path | None, cold: bool) -> bool:
    """Restore the retentive memory into ``program``; whether the PLC warm-restarts."""
    if retain is None:
        log.info("cold start from the config (no retentive memory configured)")
        return False
    if cold:
        log.info("cold start from the config (--cold): the retentive memory %s is not read", retain)
        return False
    if not retain.exists():
        log.info("cold start from the config: no retentive memory at %s yet", retain)
        return False
    try:
        skipped = program.restore_retained(read_json(retain))
    except (OSError, ValueError, TypeError, AttributeError) as e:
        log.warning("cold start: retentive memory %s unreadable: %s", retain, e)
        return False
    log.info(
        "warm restart from %s at scan %d, t = %.1f s%s",
        retain,
        program.scan_count,
        program.t_s,
        f" (not restored: {'; '.join(skipped)})" if skipped else "",
    )
    return True


async def _wait_event(event: asyncio.Event, timeout_s: float) -> bool:
    try:
        async with asyncio.timeout(timeout_s):
            await event.wait()
    except TimeoutError:
        return False
    return True


def _trace_row(
    program: PlcProgram, status: PlcStatus, readings: FieldReadings, commands: NDArray[np.float64]
) -> list[float]:
    """One trace line: scan, model time, levels read, commands written, each loop's SP, mode and
    gain source (as left by the scan)."""
    row = [float(program.scan_count), float(status.t_s), *readings.levels_m, *commands]
    return row + [float(x) for lp in program.loops for x in (lp.sp_m, int(lp.mode), int(lp.source))]


async def warm_resume(program: PlcProgram, field_link: FieldLink, *, hold_outputs: bool) -> None:
    """Bumpless warm restart: continue from where the pumps and the levels are now.

    ``hold_outputs`` (real time): write the plant's own pump commands straight back, before the
    server starts and before the first scan. The flows do not change; the write refreshes the
    plant's command watchdog (``plant.watchdog.command_timeout_s``), which the PLC's restart
    gap (interpreter, imports, server start-up: 8 to 22 s measured on a loaded two-core
    machine, docs/benchmarks.md section 10) would otherwise outlast, stopping the pumps under a
    shipped safe state ``off``. A watchdog that already tripped is reset to those commands,
    which is what the first scan would apply anyway. In lock-step the plant does not advance
    without the PLC, so there is nothing to hold.
    """
    state = await field_link.read_state()
    if state is None:
        log.warning("warm restart: the plant cannot be read; the loops resume from their retained MVs")
        return
    commands, now = state
    program.resume_from_plant(commands, now.levels_m, now.good)
    log.info(
        "warm restart: resumed from the plant's commands %s and levels %s",
        [float(c) for c in commands],
        [float(x) for x in now.levels_m],
    )
    if hold_outputs and bool(np.isfinite(commands).all()) and await field_link.write_commands(commands):
        log.info("warm restart: pump commands held (plant watchdog refreshed) before the server starts")


async def run_plc(
    site: SiteConfig,
    *,
    host: str,
    port: int,
    plant_url: str,
    security: ServerSecurity,
    stop: asyncio.Event,
    speed: float = 1.0,
    lockstep: bool = False,
    clock: Clock | None = None,
    ready: asyncio.Event | None = None,
    stats: PlcRunStats | None = None,
    trace: Path | None = None,
    retain_file: Path | None = None,
    cold: bool = False,
) -> PlcRunStats:
    """Scan the PLC program against the plant until ``stop`` is set.

    ``trace``: a CSV file that gets one line per scan (scan, model time, every level read, every
    command written, every loop's SP and mode): a small historian, and how two lock-step runs
    are compared. ``retain_file``: the retentive memory (default: ``plc.retain_file``); warm
    restart when it exists, unless ``cold`` (start from the config; the file is then rewritten
    from the first scan on).
    """
    if site.plc is None:
        raise ValueError(f"site {site.name!r} has no plc section")
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    clock = clock or MonotonicClock()
    stats = stats or PlcRunStats()
    ts = site.plc.scan_period_s
    timeout = site.plc.watchdog.timeout_s
    program = PlcProgram(
        site,
        watchdog_timeout_s=timeout if lockstep else max(timeout, WALL_FLOOR_S * speed),
        alarm_event_prefix=os.urandom(8),  # EventIds unique across restarts of the process
    )
    server = PlcServer(site, program, host, port, security, speed=1.0 if lockstep else speed)
    ack = asyncio.Event()
    seen = asyncio.Event()  # the supervisor has written a heartbeat at least once

    def on_heartbeat() -> None:
        ack.set()
        seen.set()

    server.on_heartbeat = on_heartbeat
    field_link = FieldLink(
        site,
        plant_url,
        setup=client_setup(ClientIdentity(security.home, "plc")),
        timeout_s=min(2.0, max(0.2, ts / speed)),
    )
    retain = retain_file or (Path(site.plc.retain_file) if site.plc.retain_file else None)
    warm = _warm_restore(program, retain, cold)
    store = RetainedStore(retain) if retain is not None else None

    def save_retained() -> None:
        if store is not None:
            store.offer(program.retained())

    server.on_change = save_retained
    # Connect to the plant before the first deadline: the secure handshake (a few hundred ms of
    # RSA and session set-up) is start-up, not scan work, and must not count as an overrun.
    # On a warm restart this comes before the OPC UA server starts (seconds on a loaded
    # machine), so the pumps are held as they are as early as possible.
    await field_link.ensure()
    if warm:
        await warm_resume(program, field_link, hold_outputs=not lockstep)
    await server.start()
    await server.publish(
        {
            paths.plc.scan_period: ts,
            paths.plc.supervisor_timeout: program.watchdog.timeout_s,
            paths.plc.external_timeout: program.external_watchdog.timeout_s,
        }
    )
    if warm:
        await server.publish_status(program.status())
    if ready is not None:
        ready.set()
    period = ts / speed
    deadlines = Deadlines(period_s=period, next_deadline=clock.now())
    t_model = program.next_scan_t_s if warm else 0.0
    pending: FieldReadings | None = None  # lock-step: readings returned by the last Advance
    # A deterministic lock-step run has the supervisor in step from the first scan: wait
    # (bounded) for its first heartbeat before scanning.
    if lockstep and site.supervisor is not None and not await _wait_event(seen, LOCKSTEP_STARTUP_S):
        log.warning("no supervisor heartbeat within %.0f s: scanning without it", LOCKSTEP_STARTUP_S)
    # Line-buffered: every scan's row is in the file once written (a killed PLC loses no row,
    # and the file can be read while the PLC runs).
    trace_file = trace.open("w", encoding="utf-8", buffering=1) if trace is not None else None
    if trace_file is not None:
        cols = (
            ["scan", "t_s"] + [f"LT{t[1:]}" for t in site.tank_names] + [f"{p}_cmd" for p in site.pump_names]
        )
        cols += [f"{lp}_{item}" for lp in site.loop_names for item in ("SP", "Mode", "GainSource")]
        trace_file.write(",".join(cols) + "\n")
    try:
        while not stop.is_set():
            if not lockstep:
                await sleep_or_stop(clock, deadlines.next_deadline, stop)
                if stop.is_set():
                    break
            started = clock.now()
            deadlines.started(started)
            readings = pending if pending is not None else await field_link.read_inputs()
            pending = None
            healthy = readings is not None
            if readings is None:
                stats.io_failures += 1
                n = program.n_tanks
                readings = FieldReadings(np.full(n, np.nan), np.zeros(n, dtype=bool))
            ack.clear()
            out = program.scan(ScanInputs(t_model, readings.levels_m, readings.good, healthy))
            if program.alarms.events:  # before any await: the core's order reaches the nodes
                await server.publish_alarms(program.alarms.events)
            await server.expire_alarm_rate()
            status = out.status
            assert status is not None  # scan() publishes by default
            # The scan's row is taken now: a supervisor write may land during the field I/O below.
            row = _trace_row(program, status, readings, out.commands) if trace_file is not None else None
            # Publish the scan's values before the field I/O: in lock-step the supervisor reads
            # and acts on them while the plant integrates (its acknowledgement may then arrive
            # before Advance returns), instead of after; nothing below changes them.
            await server.publish_status(
                status,
                {paths.plc.overruns: deadlines.overruns, **field_link.link.status(paths.plc.plant_link)},
            )
            if lockstep:
                result = await field_link.advance(ts, out.commands)
                if result is not None:
                    t_model, pending = result
                else:
                    t_model += ts
            else:
                if healthy:
                    await field_link.write_commands(out.commands)
                t_model += ts
            await server.publish({paths.plc.last_scan_duration: clock.now() - started})
            stats.scans += 1
            save_retained()
            if trace_file is not None and row is not None:
                trace_file.write(",".join(repr(float(x)) for x in row) + "\n")
            if lockstep:
                w = program.watchdog
                lost = w.ever_alive and not w.alive
                if seen.is_set() and not lost and not ack.is_set():
                    # Wait for the supervisor's acknowledgement of this scan; a missing one is a
                    # missed heartbeat, so a dead supervisor stops slowing the scan once the
                    # watchdog has declared it lost.
                    await _wait_event(ack, LOCKSTEP_ACK_S)
                deadlines.next_deadline = clock.now()
            else:
                deadlines.finished(clock.now())
            stats.overruns = deadlines.overruns
    finally:
        if trace_file is not None:
            trace_file.close()
        stats.lateness_s = list(deadlines.lateness_s)
        if store is not None:  # the last state is on disk before the PLC says it stopped
            save_retained()
            await store.close()
            log.info(
                "retentive memory stored in %s (scan %d, t = %.1f s)", retain, program.scan_count, program.t_s
            )
        await field_link.close()
        await server.stop()
        if stats.lateness_s:
            p50, p99 = np.percentile(stats.lateness_s, [50, 99])
            log.info(
                "PLC stopped after %d scans: %d overruns, lateness p50 %.2f ms p99 %.2f ms",
                stats.scans,
                stats.overruns,
                1e3 * p50,
                1e3 * p99,
            )
    return stats
