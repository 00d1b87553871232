"""The plant's OPC UA server: the contract's plant nodes over a :class:`PlantSimulator`.

Client writes go through :class:`tanklab.ua.WriteGuard` (type, finiteness, EURange, enum,
status) and then through the simulator's own setters, so a refused write never reaches the
model and the node keeps its old value. ``Plant.Sim.Advance(seconds, commands)`` is the
lock-step entry point: it writes the pump commands, integrates and answers the new time and
transmitter readings in one round trip; outside lock-step it answers BadInvalidState.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from asyncua import ua

from plant_sim.plant import PlantSimulator
from tanklab.config import SiteConfig
from tanklab.enums import SensorFault
from tanklab.tags import Tag, plant_tags, tags_by_path
from tanklab.ua import Publisher
from tanklab.ua_security import ServerSecurity, TierServer, start_tier_server

log = logging.getLogger(__name__)


class PlantServer:
    """Serves a :class:`PlantSimulator` at ``opc.tcp://HOST:PORT/tanklab/plant``.

    Parameters
    ----------
    site : the site config (its plant section is simulated).
    sim : the simulator to serve (shared with the runtime that advances it).
    host, port : where to listen.
    security : PKI, users and audit directory (:mod:`tanklab.ua_security`).
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
            on_write=self._on_write,
            methods={"Plant.Sim.Advance": self._advance},
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

    def _on_write(self, tag: Tag, value: Any) -> ua.StatusCode | None:
        """Apply a validated write to the simulator; refuse what the simulator refuses."""
        parts = tag.path.split(".")
        obj, item = parts[1], parts[2]
        try:
            if item == "Command":
                self.sim.set_command(obj, value)
            elif item == "Leak":
                self.sim.set_leak(obj, value)
            elif item == "Opening":
                self.sim.set_valve(obj, value)
            elif item == "Disturbance":
                self.sim.set_disturbance(obj, value)
            elif item == "Fault":
                self.sim.set_fault(obj, SensorFault(value))
            elif item == "FaultValue":
                self.sim.set_fault(obj, self.sim.transmitters.fault[int(obj[2:]) - 1], value)
            else:
                return ua.StatusCode(ua.StatusCodes.BadNotWritable)
        except (ValueError, KeyError) as e:
            log.info("write to %s refused by the model: %s", tag.path, e)
            return ua.StatusCode(ua.StatusCodes.BadOutOfRange)
        if item != "Command":
            self.settings_changed = True
        # Pump commands arrive every scan: worth a debug line; an operator's write is an event.
        log.log(logging.DEBUG if item == "Command" else logging.INFO, "%s := %r", tag.path, value)
        return None

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
            values[f"Plant.{name}.Leak"] = float(u.leak_openings[i])
            values[f"Plant.{name}.Disturbance"] = float(u.disturbances_m3_s[i])
            values[f"Plant.LT{name[1:]}.Fault"] = int(sim.transmitters.fault[i])
            values[f"Plant.LT{name[1:]}.FaultValue"] = float(sim.transmitters.fault_value[i])
        for k, name in enumerate(sim.net.valve_names):
            values[f"Plant.{name}.Opening"] = float(u.valve_openings[k])
        for j, name in enumerate(sim.net.pump_names):
            values[f"Plant.{name}.Command"] = float(sim.commands[j])
        return {p: v for p, v in values.items() if p in self.by_path}

    def snapshot_values(self) -> dict[str, Any]:
        """Every read-only plant value now, keyed by tag path."""
        sim = self.sim
        values: dict[str, Any] = {}
        levels = sim.levels
        lsh, lsl = sim.switches()
        flows = sim.flows()
        for i, name in enumerate(sim.net.tank_names):
            values[f"Plant.{name}.Level"] = float(levels[i])
            values[f"Plant.{name}.LSH"] = bool(lsh[i])
            values[f"Plant.{name}.LSL"] = bool(lsl[i])
            values[f"Plant.LT{name[1:]}.PV"] = float(sim.readings[i])
        for j, name in enumerate(sim.net.pump_names):
            values[f"Plant.{name}.Flow"] = float(flows.pumps[j])
        bal = sim.balance()
        values["Plant.Balance.In"] = bal.v_in
        values["Plant.Balance.Out"] = bal.v_out
        values["Plant.Balance.Leaked"] = bal.v_leaked
        values["Plant.Balance.Spilled"] = bal.v_spilled
        values["Plant.Balance.Stored"] = bal.v_stored
        values["Plant.Balance.Error"] = bal.error
        values["Plant.Sim.Time"] = sim.t_s
        values["Plant.Sim.Watchdog"] = bool(sim.watchdog_tripped)
        return values

    async def publish(self) -> None:
        """Publish the simulator's state to the address space."""
        assert self.publisher is not None
        await self.publisher.publish(self.snapshot_values())

    async def publish_speed(self, speed: float) -> None:
        """Publish the speed factor (0 in lock-step)."""
        assert self.publisher is not None
        await self.publisher.publish({"Plant.Sim.Speed": speed})
