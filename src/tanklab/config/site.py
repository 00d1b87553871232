"""A whole site: the three tiers' sections, the endpoints, how `tankctl up` runs them, cross-checks."""

from __future__ import annotations

from typing import Self

from pydantic import Field, model_validator

from tanklab.alarms import names as alarm_names
from tanklab.config.base import Model, numeric_key
from tanklab.config.historian import HistorianConfig
from tanklab.config.plant import PlantConfig
from tanklab.config.plc import InterlockSpec, PlcConfig
from tanklab.config.supervisor import SupervisorConfig


class Endpoint(Model):
    """Where a tier serves OPC UA: ``opc.tcp://host:port/tanklab/<tier>``."""

    host: str = Field("127.0.0.1", description="Host name or address to bind / reach.")
    port: int = Field(ge=1, le=65535, description="TCP port.")

    def url(self, tier: str) -> str:
        """Endpoint URL of ``tier`` (plant, plc or supervisor)."""
        return f"opc.tcp://{self.host}:{self.port}/tanklab/{tier}"


class Endpoints(Model):
    """Endpoints of the three tiers (overridden by TANKLAB_* variables and flags)."""

    plant: Endpoint = Field(default_factory=lambda: Endpoint(port=4840), description="Plant simulator.")
    plc: Endpoint = Field(default_factory=lambda: Endpoint(port=4841), description="Soft PLC.")
    supervisor: Endpoint = Field(default_factory=lambda: Endpoint(port=4842), description="Supervisor.")
    historian: Endpoint = Field(default_factory=lambda: Endpoint(port=4843), description="Historian.")


class StackConfig(Model):
    """How `tankctl up` runs the three tiers."""

    restart: bool = Field(False, description="Restart a tier that dies (instead of stopping the stack).")
    max_restarts: int = Field(3, ge=0, description="Restarts allowed per tier before `up` gives up.")


class SiteConfig(Model):
    """A whole site: one YAML file."""

    name: str = Field(description="Site name shown by the tools.")
    description: str = Field("", description="What this site reproduces and from which paper.")
    plant: PlantConfig = Field(description="The physical plant.")
    plc: PlcConfig | None = Field(None, description="The PLC program.")
    supervisor: SupervisorConfig | None = Field(None, description="The supervisor.")
    historian: HistorianConfig = Field(default_factory=HistorianConfig, description="The historian tier.")
    endpoints: Endpoints = Field(default_factory=Endpoints, description="OPC UA endpoints.")
    stack: StackConfig = Field(default_factory=StackConfig, description="How `tankctl up` runs the tiers.")

    @model_validator(mode="after")
    def _cross_refs(self) -> Self:
        tanks = {t.name for t in self.plant.tanks}
        pumps = {p.name for p in self.plant.pumps}
        if self.plc is not None:
            loops = {lp.name for lp in self.plc.loops}
            if len(loops) != len(self.plc.loops):
                raise ValueError("plc.loops: loop names must be unique")
            for lp in self.plc.loops:
                if "T" + lp.pv[2:] not in tanks:
                    raise ValueError(f"plc.loops {lp.name}: pv {lp.pv} has no tank T{lp.pv[2:]}")
                if lp.actuator not in pumps:
                    raise ValueError(f"plc.loops {lp.name}: unknown actuator {lp.actuator}")
                for other in lp.cross_gains:
                    if other not in loops:
                        raise ValueError(f"plc.loops {lp.name}: cross_gains names unknown loop {other}")
                tank = self.plant.tank("T" + lp.pv[2:])
                if lp.sp_max_m > tank.height_max_m:
                    raise ValueError(f"plc.loops {lp.name}: sp_max_m exceeds the tank's height_max_m")
            if len({lp.actuator for lp in self.plc.loops}) != len(self.plc.loops):
                raise ValueError("plc.loops: two loops drive the same pump")
            for il in self.plc.interlocks:
                if il.tank not in tanks:
                    raise ValueError(f"plc.interlocks: unknown tank {il.tank}")
                self._check_interlock(il)
            self._check_alarms()
        if self.supervisor is not None:
            if self.plc is None:
                raise ValueError("supervisor needs a plc section")
            mpc = self.supervisor.mpc
            for t in mpc.controlled + (mpc.filter_outputs or []):
                if t not in tanks:
                    raise ValueError(f"supervisor.mpc: unknown tank {t}")
            if len(mpc.qz) != len(mpc.controlled):
                raise ValueError("supervisor.mpc.qz needs one weight per controlled level")
            if len(mpc.s) != len(self.plant.pumps):
                raise ValueError("supervisor.mpc.s needs one weight per pump")
            if mpc.r is not None and len(mpc.r) != len(self.plant.pumps):
                raise ValueError("supervisor.mpc.r needs one weight per pump")
            ts = self.supervisor.sample_time_s
            if ts is not None:
                ratio = ts / self.plc.scan_period_s
                if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-9 * ratio:
                    raise ValueError(
                        f"supervisor.sample_time_s {ts:g} s must be a whole multiple of plc.scan_period_s "
                        f"{self.plc.scan_period_s:g} s"
                    )
                if self.supervisor.mode == "ADAPTIVE_PID" and round(ratio) != 1:
                    raise ValueError(
                        "supervisor.mode ADAPTIVE_PID needs supervisor.sample_time_s equal to "
                        "plc.scan_period_s (the adapter pairs every scan's PID move with the MPC's)"
                    )
            self._check_supervisor_alarms()
        return self

    def _check_interlock(self, il: InterlockSpec) -> None:
        """A high-high trip must be able to do its job, one scan late at worst.

        The PLC sees a level once per scan, so between the last reading below HH and the trip
        the tank's pumps may run a whole scan at full flow: ``HH + Q_max Ts / A`` must stay below
        the tank's top. (A setpoint above HH is allowed: reaching it trips its own loop, which is
        what the interlock is for; the shipped Energies and Kortela sites let it go to 0.6 m.)
        """
        assert self.plc is not None
        tank = self.plant.tank(il.tank)
        inflow = sum(p.max_flow_m3_s for p in self.plant.pumps if p.feeds == il.tank)
        rise_m = inflow * self.plc.scan_period_s / tank.area_m2
        if il.high_high_m + rise_m >= tank.height_max_m:
            raise ValueError(
                f"plc.interlocks {il.tank}: high_high_m {il.high_high_m:g} m plus one scan at full pump flow "
                f"({rise_m:.3g} m) reaches height_max_m {tank.height_max_m:g} m: the trip could not stop "
                "an overflow (lower the trip, the pump's max_flow_m3_s or the scan period)"
            )

    def _check_alarms(self) -> None:
        """Each override names an alarm of this site and sets only what that alarm has."""
        assert self.plc is not None
        plc = self.plc
        levels = {alarm_names.level(t.name): t for t in self.plant.tanks}
        pv_bad = {alarm_names.pv_bad(lp.name) for lp in plc.loops}
        known = [*levels, *sorted(pv_bad, key=numeric_key), alarm_names.IO_FAULT, alarm_names.SUPERVISOR_LOST]
        known += sorted({alarm_names.trip(il.tank) for il in plc.interlocks}, key=numeric_key)
        for name, o in plc.alarms.overrides.items():
            where = f"plc.alarms.overrides.{name}"
            if name not in known:
                raise ValueError(f"{where}: unknown alarm (this site's: {', '.join(known)})")
            tank = levels.get(name)
            if tank is None:
                level_only = ("limit_priorities", "deadband_m", "low_low_m")
                set_here = [f for f in level_only if getattr(o, f) not in (None, {})]
                if set_here:
                    raise ValueError(f"{where}: {', '.join(set_here)} apply to level alarms only")
                if o.suppress_when_manual and name not in pv_bad:
                    raise ValueError(f"{where}: suppress_when_manual applies to level and PvBad alarms only")
                continue
            low_m, high_m = tank.switch_levels().low_m, tank.switch_levels().high_m
            if o.low_low_m is not None and o.low_low_m >= low_m:
                raise ValueError(
                    f"{where}: low_low_m {o.low_low_m:g} m must be below the low switch {low_m:g} m"
                )
            if o.deadband_m is not None and o.deadband_m >= high_m - low_m:
                raise ValueError(
                    f"{where}: deadband_m {o.deadband_m:g} m must be below the band between the "
                    f"switches ({high_m - low_m:g} m)"
                )
            if o.suppress_when_manual and not any(lp.pv == "LT" + tank.name[1:] for lp in plc.loops):
                raise ValueError(f"{where}: suppress_when_manual needs a loop on {tank.name}'s transmitter")

    def _check_supervisor_alarms(self) -> None:
        """Each supervisor override names one of the supervisor's alarms and sets only what a
        discrete alarm without a loop has (priority, delays, enabled)."""
        assert self.supervisor is not None
        known = [alarm_names.MPC_FAILING]
        if self.supervisor_adapts_gains:
            known.append(alarm_names.ADAPTATION_UNHEALTHY)
        known.append(alarm_names.PLC_LINK_LOST)
        for name, o in self.supervisor.alarms.overrides.items():
            where = f"supervisor.alarms.overrides.{name}"
            if name not in known:
                also = (
                    " (AdaptationUnhealthy needs a gain adapter: every loop a PID loop)"
                    if name == alarm_names.ADAPTATION_UNHEALTHY
                    else ""
                )
                raise ValueError(f"{where}: unknown alarm (the supervisor's: {', '.join(known)}){also}")
            level_only = ("limit_priorities", "deadband_m", "low_low_m")
            set_here = [f for f in level_only if getattr(o, f) not in (None, {})]
            if set_here:
                raise ValueError(f"{where}: {', '.join(set_here)} apply to the PLC's level alarms only")
            if o.suppress_when_manual:
                raise ValueError(
                    f"{where}: suppress_when_manual applies to the PLC's level and PvBad alarms only"
                )

    # Convenience views used by tags and runtimes --------------------------------------------

    @property
    def tank_names(self) -> list[str]:
        """Tank tags in order, e.g. ["T1", "T2", "T3"]."""
        return [t.name for t in self.plant.tanks]

    @property
    def pump_names(self) -> list[str]:
        """Pump tags in order."""
        return [p.name for p in self.plant.pumps]

    @property
    def valve_names(self) -> list[str]:
        """Valve tags in order."""
        return [v.name for v in self.plant.valves]

    @property
    def loop_names(self) -> list[str]:
        """Loop tags in order (empty without a PLC program)."""
        return [lp.name for lp in self.plc.loops] if self.plc else []

    @property
    def supervisor_adapts_gains(self) -> bool:
        """Whether the supervisor has a gain adapter: every PLC loop a PID loop with fixed gains
        (``SupervisorCore.adapter``; the supervisor's AdaptationUnhealthy alarm exists only then)."""
        return self.plc is not None and all(
            lp.block == "pid" and lp.gains is not None for lp in self.plc.loops
        )

    @property
    def supervisor_sample_scans(self) -> int:
        """PLC scans per supervisor sample (``supervisor.sample_time_s / plc.scan_period_s``, >= 1)."""
        if self.supervisor is None or self.plc is None:
            raise ValueError(f"site {self.name!r} has no supervisor section")
        ts = self.supervisor.sample_time_s
        return 1 if ts is None else max(1, round(ts / self.plc.scan_period_s))

    @property
    def supervisor_sample_time_s(self) -> float:
        """The supervisor's (and MPC's) sample time [s]: a whole number of PLC scans."""
        assert self.plc is not None
        return self.supervisor_sample_scans * self.plc.scan_period_s
