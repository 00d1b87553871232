"""The plant's config: tanks, transmitters, switches, valves, pumps, operating point, watchdog.

Flows are Torricelli's (see :mod:`tanklab.config`); pump commands map to flow by
``Q = max(0, slope * cmd + offset)`` [m^3/s].
"""

from __future__ import annotations

import math
from typing import Literal, Self

from pydantic import Field, model_validator

from tanklab.config.base import (
    GRAVITY_M_S2,
    PUMP_NAME,
    TANK_NAME,
    VALVE_NAME,
    Finite,
    Fraction,
    Model,
    NonNegFloat,
    PositiveFloat,
)


class TransmitterSpec(Model):
    """Level transmitter ``LT{i}`` of a tank: what the PLC reads instead of the true level."""

    noise_std_m: NonNegFloat = Field(0.0, description="Standard deviation of Gaussian noise [m].")
    quantization_m: NonNegFloat = Field(
        0.0, description="Resolution of the reading [m]; 0 means no quantization."
    )
    range_min_m: Finite = Field(0.0, description="Lower end of the transmitter range (4 mA) [m].")
    range_max_m: Finite | None = Field(
        None, description="Upper end of the transmitter range (20 mA) [m]; default: the tank's height."
    )


class SwitchSpec(Model):
    """High and low level switches ``LSH`` and ``LSL`` of a tank."""

    high_m: NonNegFloat = Field(description="LSH trips when the level is at or above this [m].")
    low_m: NonNegFloat = Field(description="LSL trips when the level is at or below this [m].")

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if self.low_m >= self.high_m:
            raise ValueError("low_m must be below high_m")
        return self


class TankSpec(Model):
    """A cylindrical tank with a leak valve to the drain."""

    name: str = Field(pattern=TANK_NAME, description="Tag name, T1..T99.")
    area_m2: PositiveFloat = Field(description="Cross-section At [m^2].")
    height_max_m: PositiveFloat = Field(description="Overflow height Hmax [m]; above it water spills.")
    initial_level_m: NonNegFloat = Field(0.0, description="Level at start [m].")
    leak_mu: NonNegFloat = Field(
        0.0, description="Discharge coefficient of the leak valve when fully open [1]."
    )
    leak_area_m2: NonNegFloat = Field(0.0, description="Orifice area of the leak valve [m^2].")
    initial_leak_opening: Fraction = Field(0.0, description="Leak valve opening at start, 0..1.")
    transmitter: TransmitterSpec = Field(default_factory=TransmitterSpec, description="Level transmitter.")
    switches: SwitchSpec | None = Field(
        None, description="Level switches; default: LSH at 0.9 Hmax, LSL at 0.05 Hmax."
    )

    @model_validator(mode="after")
    def _initial_below_max(self) -> Self:
        if self.initial_level_m > self.height_max_m:
            raise ValueError("initial_level_m must not exceed height_max_m")
        return self

    @property
    def leak_conductance(self) -> float:
        """mu_L * a_L * sqrt(2 g) [m^2.5/s]: leak flow at full opening per sqrt(m) of level."""
        return self.leak_mu * self.leak_area_m2 * math.sqrt(2 * GRAVITY_M_S2)

    def switch_levels(self) -> SwitchSpec:
        """The configured switches, or the defaults (LSH 0.9 Hmax, LSL 0.05 Hmax)."""
        if self.switches is not None:
            return self.switches
        return SwitchSpec(high_m=0.9 * self.height_max_m, low_m=0.05 * self.height_max_m)

    def transmitter_range(self) -> tuple[float, float]:
        """Transmitter range [m] (defaults to 0..Hmax)."""
        t = self.transmitter
        return (t.range_min_m, t.range_max_m if t.range_max_m is not None else self.height_max_m)


class ValveSpec(Model):
    """An orifice with a valve: between two tanks, or from a tank to the drain ("0").

    Its name is ``V{m}{n}``: from tank m to tank n, n = 0 for the drain (V13, V32, V20, V1210).
    Tank numbers go to 99, so a name alone can be ambiguous (V123: T1 -> T23 or T12 -> T3); the
    plant refuses two valves that get the same name (decision 0045).
    Flow is signed: positive from ``upstream`` to ``downstream``; it reverses with the level order.
    """

    name: str = Field(pattern=VALVE_NAME, description="Tag name V{m}{n}; n = 0 is the drain.")
    upstream: str = Field(pattern=TANK_NAME, description="Tank m.")
    downstream: str | None = Field(
        None, pattern=TANK_NAME, description="Tank n, or null for an outlet to the drain."
    )
    mu: PositiveFloat = Field(description="Discharge (outflow) coefficient mu [1].")
    area_m2: PositiveFloat = Field(description="Pipe or orifice section Ap [m^2].")
    initial_opening: Fraction = Field(1.0, description="Opening at start, 0 (clogged) .. 1 (free).")

    @model_validator(mode="after")
    def _name_matches(self) -> Self:
        m = self.upstream[1:]
        n = self.downstream[1:] if self.downstream else "0"
        if self.name != f"V{m}{n}":
            raise ValueError(
                f"name must be V{m}{n} for a valve from {self.upstream} to {self.downstream or 'drain'}"
            )
        return self

    @property
    def conductance(self) -> float:
        """mu * Ap * sqrt(2 g) [m^2.5/s] at full opening."""
        return self.mu * self.area_m2 * math.sqrt(2 * GRAVITY_M_S2)


def _ends(v: ValveSpec) -> str:
    """``T1 -> T23`` or ``T2 -> drain``: a valve's ends, for error messages."""
    return f"{v.upstream} -> {v.downstream or 'drain'}"


class PumpSpec(Model):
    """A pump feeding one tank, commanded in its own unit.

    Flow law: ``Q = clip(slope * clip(cmd, command_min, command_max) + offset, 0, max_flow)``,
    so a speed-commanded pump has a dead zone below ``-offset / slope``. With a lag, the actual
    flow follows that target through ``tau dQ/dt = Q_target - Q``.
    """

    name: str = Field(pattern=PUMP_NAME, description="Tag name, P1..P99.")
    feeds: str = Field(pattern=TANK_NAME, description="Tank the pump delivers into.")
    command_kind: Literal["flow", "speed", "fraction"] = Field(
        "flow", description="Unit of the command: flow [m^3/s], speed [rpm] or fraction [1]."
    )
    command_min: Finite = Field(0.0, description="Lowest accepted command, in the command unit.")
    command_max: Finite = Field(description="Highest accepted command, in the command unit.")
    slope: PositiveFloat = Field(1.0, description="Flow per command unit [m^3/s per unit].")
    offset_m3_s: Finite = Field(0.0, description="Flow at command 0 [m^3/s]; negative gives a dead zone.")
    max_flow_m3_s: PositiveFloat = Field(description="Largest flow the pump delivers (saturation) [m^3/s].")
    lag_s: NonNegFloat = Field(0.0, description="First-order time constant of the flow [s]; 0 = none.")
    initial_command: Finite = Field(0.0, description="Command at start, in the command unit.")
    operating_command: Finite | None = Field(
        None, description="Command at the configured operating point (informational) [command unit]."
    )
    watchdog_safe_state: Literal["off", "hold"] | None = Field(
        None,
        description="What this pump does when the plant's command watchdog times out: off (its lowest"
        " command) or hold (its last command), until the next command; null = plant.watchdog.safe_state.",
    )

    @model_validator(mode="after")
    def _range(self) -> Self:
        if self.command_min >= self.command_max:
            raise ValueError("command_min must be below command_max")
        if self.command_kind == "flow" and (self.slope != 1.0 or self.offset_m3_s != 0.0):
            raise ValueError("a flow-commanded pump has slope 1 and offset 0")
        if not self.command_min <= self.initial_command <= self.command_max:
            raise ValueError("initial_command must lie in [command_min, command_max]")
        return self

    @property
    def unit(self) -> str:
        """Engineering unit of the command."""
        return {"flow": "m^3/s", "speed": "rpm", "fraction": "1"}[self.command_kind]

    def flow_of(self, command: float) -> float:
        """Steady flow [m^3/s] for a command in the pump's unit (saturated, dead zone applied)."""
        cmd = min(max(command, self.command_min), self.command_max)
        return min(max(self.slope * cmd + self.offset_m3_s, 0.0), self.max_flow_m3_s)

    def command_of(self, flow_m3_s: float) -> float:
        """Command that produces ``flow_m3_s`` (inverse of :meth:`flow_of` inside its range)."""
        flow = min(max(flow_m3_s, 0.0), self.max_flow_m3_s)
        cmd = (flow - self.offset_m3_s) / self.slope if flow > 0 else self.command_min
        return min(max(cmd, self.command_min), self.command_max)


class OperatingPoint(Model):
    """Where linear models are taken: levels and the pump flows that hold them."""

    levels_m: list[NonNegFloat] = Field(description="Level of each tank, in the order of `tanks` [m].")
    flows_m3_s: list[NonNegFloat] | None = Field(
        None,
        description="Pump flows [m^3/s], in the order of `pumps`; null = computed as the equilibrium"
        " flows of the controlled levels.",
    )
    note: str = Field("", description="Where the numbers come from (printed, computed, corrected).")


class PlantWatchdog(Model):
    """The plant's own watchdog on pump commands."""

    command_timeout_s: PositiveFloat = Field(
        10.0, description="Model seconds without a pump command before the pumps go to their safe state."
    )
    safe_state: Literal["off", "hold"] = Field(
        "off",
        description="What a pump does on timeout (off: its lowest command; hold: its last command),"
        " unless the pump sets its own watchdog_safe_state.",
    )


class PlantConfig(Model):
    """The physical plant: tanks, valves, pumps, and where it is linearized."""

    kind: Literal["three_tank", "single_tank", "two_tank"] = Field(description="Which benchmark plant.")
    description: str = Field("", description="Free text: paper, parameter set, calibration notes.")
    tanks: list[TankSpec] = Field(min_length=1, description="Tanks, numbered T1.. .")
    valves: list[ValveSpec] = Field(default_factory=list, description="Connecting and outlet valves.")
    pumps: list[PumpSpec] = Field(min_length=1, description="Pumps, numbered P1.. .")
    operating_point: OperatingPoint = Field(description="Operating point for linearization.")
    noise_seed: int = Field(0, description="Seed of the transmitters' noise generator.")
    watchdog: PlantWatchdog = Field(default_factory=PlantWatchdog, description="Pump-command watchdog.")
    state_file: str | None = Field(
        None, description="Checkpoint file for levels, valves, leaks and volumes; null = no persistence."
    )

    @model_validator(mode="after")
    def _topology(self) -> Self:
        names = [t.name for t in self.tanks]
        if len(set(names)) != len(names):
            raise ValueError("tank names must be unique")
        for p in self.pumps:
            if p.feeds not in names:
                raise ValueError(f"pump {p.name} feeds unknown tank {p.feeds}")
        for v in self.valves:
            for end in (v.upstream, v.downstream):
                if end is not None and end not in names:
                    raise ValueError(f"valve {v.name} connects unknown tank {end}")
        if len({p.name for p in self.pumps}) != len(self.pumps):
            raise ValueError("pump names must be unique")
        self._valve_names_unique()
        if len(self.operating_point.levels_m) != len(self.tanks):
            raise ValueError("operating_point.levels_m needs one level per tank")
        flows = self.operating_point.flows_m3_s
        if flows is not None and len(flows) != len(self.pumps):
            raise ValueError("operating_point.flows_m3_s needs one flow per pump")
        return self

    def _valve_names_unique(self) -> None:
        """Refuse two valves with one name. With tank numbers up to 99, ``V{m}{n}`` is ambiguous
        (T1 -> T23 and T12 -> T3 are both V123; decision 0045), so the error names both valves and
        their ends: the fix is to renumber a tank."""
        seen: dict[str, int] = {}
        for i, v in enumerate(self.valves):
            j = seen.setdefault(v.name, i)
            if j != i:
                w = self.valves[j]
                if (w.upstream, w.downstream) == (v.upstream, v.downstream):
                    raise ValueError(f"valves[{i}]: {v.name} ({_ends(v)}) is listed twice (also valves[{j}])")
                raise ValueError(
                    f"valves[{i}].name: {v.name} ({_ends(v)}) is also valves[{j}].name ({_ends(w)}):"
                    " valve names V{m}{n} must be unique (renumber a tank so they differ)"
                )

    @property
    def disturbance_limit_m3_s(self) -> float:
        """Largest magnitude of a disturbance flow [m^3/s]: the largest pump's flow.

        A disturbance is an extra inflow or outflow an operator injects; bounding it by what a
        pump of the plant delivers keeps it meaningful on every plant size (the single
        simulation tank of the NL-PI paper needs 5e-3 m^3/s, the three-tank rigs 1e-4).
        """
        return max(p.max_flow_m3_s for p in self.pumps)

    def tank(self, name: str) -> TankSpec:
        """The tank called ``name``."""
        for t in self.tanks:
            if t.name == name:
                return t
        raise KeyError(name)

    def pump(self, name: str) -> PumpSpec:
        """The pump called ``name``."""
        for p in self.pumps:
            if p.name == name:
                return p
        raise KeyError(name)

    def pump_safe_state(self, name: str) -> Literal["off", "hold"]:
        """The watchdog safe state of pump ``name``: its own, else the plant watchdog's."""
        own = self.pump(name).watchdog_safe_state
        return own if own is not None else self.watchdog.safe_state
