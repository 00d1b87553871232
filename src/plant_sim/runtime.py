"""The plant's real-time loop: advance the simulator on the wall clock, publish, checkpoint.

Every ``tick_s`` of wall time (0.05 s) (on deadlines: next = previous + tick), the simulator advances by
``tick_s * speed`` seconds of model time and the server publishes the new state. In lock-step
the loop does not advance the model: ``Plant.Sim.Advance`` does, driven by the PLC.

The clock is injected (:class:`tanklab.clock.Clock`), so tests may drive it. A checkpoint of the
model state (levels, volumes, pump commands, valves, leaks, disturbances, sensor faults) is
written atomically and durably (:func:`tanklab_io.persist.write_atomic`) to the state file every
``checkpoint_s`` of wall time, at the tick after an operator's write, and on stop, and read back
at start: water does not vanish when the simulator restarts, and the server publishes the
restored settings on its writable nodes (restored means shown).
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

from plant_sim.plant import PlantSimulator
from plant_sim.server import PlantServer
from tanklab.clock import Clock, Deadlines, MonotonicClock, sleep_or_stop
from tanklab.config import SiteConfig
from tanklab_io.persist import read_json, write_json_atomic
from tanklab_io.ua_security import ServerSecurity

log = logging.getLogger(__name__)

WALL_FLOOR_S = 1.0
"""Model-time timeouts never fire faster than this in wall time (architecture: Speed)."""


def load_checkpoint(sim: PlantSimulator, path: Path) -> bool:
    """Restore ``sim`` from ``path`` if it exists; a broken file is reported and ignored."""
    if not path.exists():
        return False
    try:
        sim.restore(read_json(path))
    except (OSError, ValueError, KeyError, TypeError) as e:
        log.warning("ignoring unreadable plant checkpoint %s: %s", path, e)
        return False
    log.info(
        "resumed plant state from %s at t = %.1f s (leaks %s, valves %s, faults %s)",
        path,
        sim.t_s,
        sim.inputs.leak_openings.tolist(),
        sim.inputs.valve_openings.tolist(),
        [f.name for f in sim.transmitters.fault],
    )
    return True


def save_checkpoint(sim: PlantSimulator, path: Path) -> None:
    """Write the checkpoint atomically and durably (temp file, fsync, rename)."""
    write_json_atomic(path, sim.snapshot())


async def run_plant(
    site: SiteConfig,
    *,
    host: str,
    port: int,
    security: ServerSecurity,
    speed: float = 1.0,
    lockstep: bool = False,
    stop: asyncio.Event,
    clock: Clock | None = None,
    tick_s: float = 0.05,
    checkpoint_s: float = 5.0,
    state_file: Path | None = None,
    ready: asyncio.Event | None = None,
) -> PlantServer:
    """Serve the plant until ``stop`` is set; return the (stopped) server for inspection."""
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    clock = clock or MonotonicClock()
    sim = PlantSimulator(site.plant)
    # A large speed must not turn scheduling noise into a watchdog trip: floor in wall time.
    sim.command_timeout_s = max(site.plant.watchdog.command_timeout_s, WALL_FLOOR_S * speed)
    if state_file is None and site.plant.state_file:
        state_file = Path(site.plant.state_file)
    if state_file is not None:
        load_checkpoint(sim, state_file)
    server = PlantServer(site, sim, host, port, security, lockstep=lockstep)
    await server.start()
    await server.publish_speed(0.0 if lockstep else speed)
    if ready is not None:
        ready.set()
    deadlines = Deadlines(period_s=tick_s, next_deadline=clock.now() + tick_s)
    last_checkpoint = clock.now()
    try:
        while not stop.is_set():
            await sleep_or_stop(clock, deadlines.next_deadline, stop)
            if stop.is_set():
                break
            deadlines.started(clock.now())
            if not lockstep:
                sim.advance(tick_s * speed)
                await server.publish()
            due = server.settings_changed or clock.now() - last_checkpoint >= checkpoint_s
            if state_file is not None and due:
                server.settings_changed = False
                save_checkpoint(sim, state_file)
                last_checkpoint = clock.now()
            deadlines.finished(clock.now())
    finally:
        if state_file is not None:
            save_checkpoint(sim, state_file)
        await server.stop()
    return server
