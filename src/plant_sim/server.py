"""The plant's OPC UA server: the contract's plant nodes over a :class:`PlantSimulator`.

Client writes go through :class:`tanklab_io.ua.WriteGuard` (type, finiteness, EURange, enum,
status) and then through the simulator's own setters, one handler per writable tag
(:meth:`PlantServer.write_handlers`), so a refused write never reaches the model and the node
keeps its old value. ``Plant.Sim.Advance(seconds, commands)`` is the
lock-step entry point: it writes the pump commands, integrates and answers the new time and
transmitter readings in one round trip; outside lock-step it answers BadInvalidState.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
from asyncua import ua

from plant_sim.plant import PlantSimulator
from tanklab import paths
from tanklab.config import SiteConfig
from tanklab.enums import SensorFault
from tanklab.handlers import HandlerTable
from tanklab.tags import Tag, plant_tags, tags_by_path
from tanklab_io.ua import MethodHandler, Publisher, WriteHandler
from tanklab_io.ua_security import ServerSecurity, TierServer, start_tier_server

log = logging.getLogger(__name__)


class PlantServer:
    """Serves a :class:`PlantSimulator` at ``opc.tcp://HOST:PORT/tanklab/plant``.

    Parameters
    ----------
    site : the site config (its plant section is simulated).
    sim : the simulator to serve (shared with the runtime that advances it).
    host, port : where to listen.
    security : PKI, users and audit directory (:mod:`tanklab_io.ua_security`).
    lockstep : whether ``Plant.Sim.Advance`` is allowed (the plant then ignores the wall clock).
    """

    def __init__(
        self,
        site: SiteConfig,
        sim: PlantSimulator,
        host: str,
        port: int,
        security: ServerSecurity,
        *,
        lockstep: bool = False,
    ):
        self.site = site
        self.sim = sim
        self.host = host
        self.port = port
        self.lockstep = lockstep
        self.url = f"opc.tcp://{host}:{port}/tanklab/plant"
        self.tags = plant_tags(site)
        self.by_path = tags_by_path(self.tags)
        self.security = security
        self.tier: TierServer | None = None
        self.publisher: Publisher | None = None
        self.advances = 0
        self.settings_changed = False
        """An operator's write (leak, valve, fault, disturbance) since the runtime last
        checkpointed: the runtime stores it at its next tick, not only every few seconds."""

    async def start(self) -> None:
        """Initialise, secure, build the address space and start listening."""
        self.tier = await start_tier_server(
            "plant",
            url=self.url,
            name="tanklab plant simulator",
            security=self.security,
            tags=self.tags,
            writes=self.write_handlers(),
            methods=self.method_handlers(),
        )
        self.publisher = self.tier.publisher
        # The writable nodes were built with the config's initial values; a resumed simulator
        # (checkpoint) has its own: publish what the model holds, so restored means shown.
        await self.publisher.publish(self.writable_values())
        await self.publish()
        log.info("plant server listening at %s", self.url)

    async def stop(self) -> None:
        """Stop listening (idempotent)."""
        if self.tier is not None:
            await self.tier.server.stop()
        log.info("plant server stopped")

    # ---- writes -------------------------------------------------------------------------

    def write_handlers(self) -> HandlerTable[WriteHandler]:
        """The handler of each writable plant variable: the simulator setter it goes to."""
        sim = self.sim
        table: HandlerTable[WriteHandler] = HandlerTable()
        for i, name in enumerate(sim.net.tank_names):
            tank, lt = paths.plant.tank(name), paths.plant.lt(name)
            table.on(tank.leak, self._setting(partial(sim.set_leak, name)))
            table.on(tank.disturbance, self._setting(partial(sim.set_disturbance, name)))
            table.on(lt.fault, self._setting(partial(self._set_fault, lt.name)))
            table.on(lt.fault_value, self._setting(partial(self._set_fault_value, lt.name, i)))
        for name in sim.net.valve_names:
            table.on(paths.plant.valve_opening(name), self._setting(partial(sim.set_valve, name)))
        for name in sim.net.pump_names:
            table.on(paths.plant.pump(name).command, self._command(name))
            table.on(paths.plant.pump(name).delivered, self._setting(partial(sim.set_pump_fraction, name)))
        return table

    def method_handlers(self) -> HandlerTable[MethodHandler]:
        """The handler of each plant method (``Plant.Sim.Advance``)."""
        table: HandlerTable[MethodHandler] = HandlerTable()
        table.on(paths.plant.sim_advance, self._advance)
        return table

    def _set_fault(self, transmitter: str, value: Any) -> None:
        self.sim.set_fault(transmitter, SensorFault(value))

    def _set_fault_value(self, transmitter: str, index: int, value: Any) -> None:
        self.sim.set_fault(transmitter, self.sim.transmitters.fault[index], value)

    def _setting(self, apply: Callable[[Any], None]) -> WriteHandler:
        """An operator's setting: applied by the simulator (which may refuse it), then an event."""

        def handler(tag: Tag, value: Any) -> ua.StatusCode | None:
            try:
                apply(value)
            except (ValueError, KeyError) as e:
                log.info("write to %s refused by the model: %s", tag.path, e)
                return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
            self.settings_changed = True
            log.info("%s := %r", tag.path, value)
            return None

        return handler

    def _command(self, pump: str) -> WriteHandler:
        """A pump command: arrives every scan, so worth a debug line only."""

        def handler(tag: Tag, value: Any) -> ua.StatusCode | None:
            try:
                self.sim.set_command(pump, value)
            except (ValueError, KeyError) as e:
                log.info("write to %s refused by the model: %s", tag.path, e)
                return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
            log.debug("%s := %r", tag.path, value)
            return None

        return handler

    async def _advance(self, seconds: float, commands: list[float]) -> list[ua.Variant] | ua.StatusCode:
        if not self.lockstep:
            return ua.StatusCode(ua.StatusCodes.BadInvalidState)
        if not np.isfinite(seconds) or not 0 < seconds <= 3600:
            return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
        try:
            self.sim.set_commands(np.asarray(commands, dtype=float))
        except ValueError:
            return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
        readings = self.sim.advance(seconds)
        self.advances += 1
        await self.publish()
        return [
            ua.Variant(self.sim.t_s, ua.VariantType.Double),
            ua.Variant([float(r) for r in readings], ua.VariantType.Double, is_array=True),
        ]

    # ---- publishing ---------------------------------------------------------------------

    def writable_values(self) -> dict[str, Any]:
        """Every writable plant value as the simulator holds it, keyed by tag path: leaks,
        disturbances, valve openings, sensor faults and their values, pump commands (as last
        written, before any watchdog safe state)."""
        sim = self.sim
        u = sim.inputs
        values: dict[str, Any] = {}
        for i, name in enumerate(sim.net.tank_names):
            tank, lt = paths.plant.tank(name), paths.plant.lt(name)
            values[tank.leak] = float(u.leak_openings[i])
            values[tank.disturbance] = float(u.disturbances_m3_s[i])
            values[lt.fault] = int(sim.transmitters.fault[i])
            values[lt.fault_value] = float(sim.transmitters.fault_value[i])
        for k, name in enumerate(sim.net.valve_names):
            values[paths.plant.valve_opening(name)] = float(u.valve_openings[k])
        for j, name in enumerate(sim.net.pump_names):
            values[paths.plant.pump(name).command] = float(sim.commands[j])
            values[paths.plant.pump(name).delivered] = float(sim.pump_fractions[j])
        return {p: v for p, v in values.items() if p in self.by_path}

    def snapshot_values(self) -> dict[str, Any]:
        """Every read-only plant value now, keyed by tag path."""
        sim = self.sim
        values: dict[str, Any] = {}
        levels = sim.levels
        lsh, lsl = sim.switches()
        flows = sim.flows()
        for i, name in enumerate(sim.net.tank_names):
            tank = paths.plant.tank(name)
            values[tank.level] = float(levels[i])
            values[tank.lsh] = bool(lsh[i])
            values[tank.lsl] = bool(lsl[i])
            values[paths.plant.lt(name).pv] = float(sim.readings[i])
        for j, name in enumerate(sim.net.pump_names):
            values[paths.plant.pump(name).flow] = float(flows.pumps[j])
        bal = sim.balance()
        balance = paths.plant.balance
        values[balance("In")] = bal.v_in
        values[balance("Out")] = bal.v_out
        values[balance("Leaked")] = bal.v_leaked
        values[balance("Spilled")] = bal.v_spilled
        values[balance("Stored")] = bal.v_stored
        values[balance("Error")] = bal.error
        values[paths.plant.sim_time] = sim.t_s
        values[paths.plant.sim_watchdog] = bool(sim.watchdog_tripped)
        return values

    async def publish(self) -> None:
        """Publish the simulator's state to the address space."""
        assert self.publisher is not None
        await self.publisher.publish(self.snapshot_values())

    async def publish_speed(self, speed: float) -> None:
        """Publish the speed factor (0 in lock-step)."""
        assert self.publisher is not None
        await self.publisher.publish({paths.plant.sim_speed: speed})
