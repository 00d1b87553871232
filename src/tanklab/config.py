"""Site configuration: the plant, the PLC program, the supervisor and the endpoints.

One YAML file describes one site. Every model has ``extra="forbid"`` (a misspelt key is an
error, not a silently ignored default), every field is documented where it is declared, and
units are in the field names (``_m``, ``_m2``, ``_m3_s``, ``_s``) or descriptions.

Plant physics in the file is physical: tanks with a cross-section, orifices with a discharge
coefficient and an area, so that every flow is Torricelli's

    q = mu * a * opening * sign(h_up - h_down) * sqrt(2 g |h_up - h_down|)     [m^3/s]

Pump commands are in the pump's own unit: a flow [m^3/s], a speed [rpm] or a fraction [1],
mapped to flow by an affine law with a dead zone, ``Q = max(0, slope * cmd + offset)``.

:func:`load_site` reads and validates a file; every failure is a :class:`ConfigError` whose
message is one line naming the file, the field and the rule.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, Self

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from tanklab.enums import LoopMode, SupervisorMode
from tanklab.errors import ConfigError

GRAVITY_M_S2 = 9.81
"""Standard gravity used by every Torricelli flow [m/s^2] (the papers' value)."""

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]

TANK_NAME = r"^T[1-9]$"
PUMP_NAME = r"^P[1-9]$"
LOOP_NAME = r"^LIC[1-9]$"
VALVE_NAME = r"^V[0-9][0-9]$"


class Model(BaseModel):
    """Base of every config model: unknown keys are errors, values are checked on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False)


# --------------------------------------------------------------------------------------------
# Plant
# --------------------------------------------------------------------------------------------


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

    name: str = Field(pattern=TANK_NAME, description="Tag name, T1..T9.")
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

    Its name is ``V{m}{n}``: from tank m to tank n, n = 0 for the drain (V13, V32, V20).
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


class PumpSpec(Model):
    """A pump feeding one tank, commanded in its own unit.

    Flow law: ``Q = clip(slope * clip(cmd, command_min, command_max) + offset, 0, max_flow)``,
    so a speed-commanded pump has a dead zone below ``-offset / slope``. With a lag, the actual
    flow follows that target through ``tau dQ/dt = Q_target - Q``.
    """

    name: str = Field(pattern=PUMP_NAME, description="Tag name, P1..P9.")
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
        if len({v.name for v in self.valves}) != len(self.valves):
            raise ValueError("valve names must be unique")
        if len(self.operating_point.levels_m) != len(self.tanks):
            raise ValueError("operating_point.levels_m needs one level per tank")
        flows = self.operating_point.flows_m3_s
        if flows is not None and len(flows) != len(self.pumps):
            raise ValueError("operating_point.flows_m3_s needs one flow per pump")
        return self

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


# --------------------------------------------------------------------------------------------
# PLC program
# --------------------------------------------------------------------------------------------


class PidGainsSpec(Model):
    """Gains of a velocity-form PID: u(k) = u(k-1) + Kp De + Ki Ts e + Kd/Ts D2e (e = SP - PV).

    Units: MV unit per m of error (Kp), per m s (Ki), MV unit s per m (Kd), with e in the loop's
    ``error_unit``.
    """

    kp: Finite = Field(description="Proportional gain Kp.")
    ki: Finite = Field(description="Integral gain Ki [per s].")
    kd: Finite = Field(0.0, description="Derivative gain Kd [s].")


class GainBox(Model):
    """Admissible gains: SetGains outside this box is rejected with BadOutOfRange."""

    kp: tuple[Finite, Finite] = Field(description="[min, max] of Kp.")
    ki: tuple[Finite, Finite] = Field(description="[min, max] of Ki.")
    kd: tuple[Finite, Finite] = Field(description="[min, max] of Kd.")

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        for name in ("kp", "ki", "kd"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name}: min must not exceed max")
        return self

    def contains(self, kp: float, ki: float, kd: float) -> bool:
        """Whether (kp, ki, kd) lies inside the box (bounds included)."""
        return all(lo <= v <= hi for v, (lo, hi) in ((kp, self.kp), (ki, self.ki), (kd, self.kd)))


class NlpiSpec(Model):
    """Feedback-linearized 2-DOF PI (digest 2.2) for a tank dh/dt = b u - a' sqrt(h)."""

    b: PositiveFloat = Field(description="Input gain b [m/s per MV unit].")
    a_prime: NonNegFloat = Field(description="Outflow coefficient a' [m^0.5/s].")
    zeta: PositiveFloat = Field(0.7071, description="Closed-loop damping ratio [1].")
    wn_rad_s: PositiveFloat = Field(description="Closed-loop natural frequency wn [rad/s].")
    adaptive: bool = Field(False, description="Estimate a' and b online with RLS (digest 2.3).")
    memory_s: PositiveFloat = Field(60.0, description="RLS memory Tmem: lambda = exp(-Ts/Tmem) [s].")


class MracSpec(Model):
    """Model-reference adaptive control of one loop (digest 2.6)."""

    law: Literal["mit", "adaptive_pi"] = Field(description="MIT-rule controller or adaptive PI.")
    delta: PositiveFloat = Field(0.7, description="Reference-model damping [1].")
    wn_rad_s: PositiveFloat = Field(description="Reference-model natural frequency [rad/s].")
    gamma: PositiveFloat = Field(description="Adaptation gain (normalised MIT rule).")
    alpha: PositiveFloat = Field(1e-6, description="Normalisation constant of the MIT rule.")
    theta_initial: tuple[Finite, Finite] = Field(
        (1.0, 0.0), description="Initial (theta1, theta2) or (kp, ki)."
    )
    theta_min: tuple[Finite, Finite] = Field((-1e3, -1e3), description="Projection lower bounds.")
    theta_max: tuple[Finite, Finite] = Field((1e3, 1e3), description="Projection upper bounds.")


class LoopSpec(Model):
    """One control loop of the PLC program: which block reads which transmitter, drives which pump."""

    name: str = Field(pattern=LOOP_NAME, description="Tag name LIC1..; loop j drives pump j by default.")
    pv: str = Field(pattern=r"^LT[1-9]$", description="Level transmitter read as PV.")
    actuator: str = Field(pattern=PUMP_NAME, description="Pump the loop commands.")
    block: Literal["pid", "nlpi", "mrac"] = Field("pid", description="Control block.")
    setpoint_m: NonNegFloat = Field(description="Initial setpoint [m].")
    sp_min_m: NonNegFloat = Field(0.0, description="Lowest setpoint an operator may write [m].")
    sp_max_m: PositiveFloat = Field(description="Highest setpoint an operator may write [m].")
    sp_ramp_m_s: PositiveFloat | None = Field(None, description="Setpoint ramp rate [m/s]; null = steps.")
    mode: Literal["MANUAL", "AUTO", "REMOTE"] = Field("AUTO", description="Mode at start.")
    manual_mv: Finite | None = Field(
        None, description="Manual MV at start (pump unit); default: initial command."
    )
    mv_min: Finite | None = Field(None, description="Lowest MV (pump unit); default: the pump's command_min.")
    mv_max: Finite | None = Field(
        None, description="Highest MV (pump unit); default: the pump's command_max."
    )
    du_max: PositiveFloat | None = Field(
        None, description="Largest MV change per scan (pump unit); null = none."
    )
    error_unit: Literal["m", "cm"] = Field(
        "m", description="Unit of the error the gains multiply (the rig's gains assume cm, digest 2.1)."
    )
    gains: PidGainsSpec | None = Field(None, description="Fixed PID gains (block pid).")
    cross_gains: dict[str, PidGainsSpec] = Field(
        default_factory=dict,
        description="Off-diagonal PID gains on other loops' errors, keyed by loop name (MIMO).",
    )
    derivative_filter_s: NonNegFloat = Field(
        0.0,
        description="Time constant Tf of the first-order D filter [s] (Tf = Td / N, Td = Kd / Kp); 0 = none.",
    )
    setpoint_weight_p: Fraction = Field(
        1.0,
        description="Setpoint weight b of the P term (block pid): P acts on b SP - PV; 1 = on the error, "
        "0 = no proportional kick on a setpoint step.",
    )
    setpoint_weight_d: Fraction = Field(
        0.0,
        description="Setpoint weight c of the D term (block pid): D acts on c SP - PV; 0 = derivative on "
        "the measurement (no derivative kick on a setpoint step), 1 = on the error (the digest's form).",
    )
    gain_box: GainBox | None = Field(None, description="Admissible SetGains range (block pid).")
    nlpi: NlpiSpec | None = Field(None, description="Parameters of block nlpi.")
    mrac: MracSpec | None = Field(None, description="Parameters of block mrac.")
    pv_bad_scans: int = Field(3, ge=1, description="Consecutive bad PV scans before the substitute output.")
    substitute: Literal["hold", "value"] = Field("hold", description="Output while the PV is bad.")
    substitute_mv: Finite = Field(0.0, description="MV used when substitute is 'value' (pump unit).")

    @model_validator(mode="after")
    def _block_params(self) -> Self:
        if self.block == "pid" and self.gains is None:
            raise ValueError("block pid needs gains")
        if self.block == "nlpi" and self.nlpi is None:
            raise ValueError("block nlpi needs an nlpi section")
        if self.block == "mrac" and self.mrac is None:
            raise ValueError("block mrac needs an mrac section")
        if not self.sp_min_m <= self.setpoint_m <= self.sp_max_m:
            raise ValueError("setpoint_m must lie in [sp_min_m, sp_max_m]")
        if self.gains is not None and self.gain_box is not None:
            g = self.gains
            if not self.gain_box.contains(g.kp, g.ki, g.kd):
                raise ValueError("the fixed gains must lie inside gain_box")
        return self

    @property
    def mode_enum(self) -> LoopMode:
        """The initial mode as the contract's enumeration."""
        return LoopMode[self.mode]


class InterlockSpec(Model):
    """High-high level trip: at or above ``high_high_m`` the tank's pumps stop, latched."""

    tank: str = Field(pattern=TANK_NAME, description="Tank watched.")
    high_high_m: PositiveFloat = Field(description="Trip level [m].")
    reset_below_m: PositiveFloat = Field(description="The trip may be reset only below this level [m].")

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if self.reset_below_m >= self.high_high_m:
            raise ValueError("reset_below_m must be below high_high_m")
        return self


class PlcWatchdog(Model):
    """Watchdog on the supervisor's heartbeat."""

    timeout_s: PositiveFloat = Field(3.0, description="Model seconds without a heartbeat change.")
    fallback: Literal["fixed", "last_accepted"] = Field(
        "fixed", description="Gains used after a supervisor loss."
    )
    good_scans_to_accept: int = Field(
        3, ge=1, description="Good heartbeat scans before gains are accepted again."
    )


class PlcConfig(Model):
    """The soft PLC program: loops, interlocks, watchdog, scan period."""

    scan_period_s: PositiveFloat = Field(1.0, description="Scan period Ts in model time [s].")
    loops: list[LoopSpec] = Field(min_length=1, description="Control loops.")
    interlocks: list[InterlockSpec] = Field(default_factory=list, description="High-high trips.")
    watchdog: PlcWatchdog = Field(default_factory=PlcWatchdog, description="Supervisor watchdog.")
    pv_frozen_scans: int = Field(
        0, ge=0, description="Identical PV readings in a row that mark a PV frozen (bad); 0 = off."
    )
    retain_file: str | None = Field(
        None,
        description="Retentive memory file (SP, mode, gains, latched trips) for warm restarts; null = cold.",
    )


# --------------------------------------------------------------------------------------------
# Supervisor
# --------------------------------------------------------------------------------------------


class MpcSpec(Model):
    """Offset-free constrained MPC (digest 2.5); weights in SI units."""

    horizon: int = Field(40, ge=1, le=1000, description="Prediction and control horizon Np [samples].")
    controlled: list[str] = Field(description="Tanks whose levels are controlled (z), e.g. [T1, T2].")
    qz: list[NonNegFloat] = Field(description="Output weights, one per controlled level [1/m^2].")
    s: list[NonNegFloat] = Field(description="Move weights, one per pump [1/(m^3/s)^2].")
    r: list[NonNegFloat] | None = Field(None, description="Input weights per pump; null = none.")
    du_max_m3_s: PositiveFloat | None = Field(
        None, description="Largest move per sample [m^3/s]; null = none."
    )
    first_move_rate_limited: bool = Field(
        True, description="Rate-limit the first move too (false: the paper-literal form, digest 2.5)."
    )
    z_min_m: NonNegFloat = Field(0.0, description="Soft lower bound of controlled levels [m].")
    z_max_m: PositiveFloat | None = Field(None, description="Soft upper bound [m]; default: Hmax.")
    slack_weight: PositiveFloat = Field(1e4, description="Penalty on the output-bound slack (scaled).")
    formulation: Literal["auto", "sparse", "condensed"] = Field("auto", description="QP formulation.")
    filter_outputs: list[str] | None = Field(
        None, description="Tanks whose levels feed the estimator; default: the controlled ones."
    )
    state_noise_m: PositiveFloat = Field(1e-4, description="Kalman state noise std [m].")
    disturbance_noise_m3_s: PositiveFloat = Field(1e-6, description="Kalman disturbance noise std [m^3/s].")
    measurement_noise_m: PositiveFloat = Field(1e-3, description="Kalman measurement noise std [m].")
    relinearize: bool = Field(False, description="Re-linearize at the current estimate each cycle.")


class AdaptationSpec(Model):
    """MPC-based PID adaptation (digest 2.4); see docs/adaptation.md for every guard."""

    push_period_s: PositiveFloat = Field(10.0, description="Model seconds between gain pushes.")
    start_after_s: NonNegFloat = Field(10.0, description="No push before this much model time [s].")
    memory_s: PositiveFloat = Field(60.0, description="RLS memory Tmem; lambda = exp(-Ts/Tmem) [s].")
    trace_cap: PositiveFloat | None = Field(
        None, description="Cap on the trace of the (dimensionless) RLS covariance; null = n_params * p0."
    )
    excitation_threshold: NonNegFloat = Field(
        1e-3, description="RLS dead zone: smallest change of the dimensionless regressor that adapts."
    )
    error_scale_m: PositiveFloat = Field(
        0.1, description="Typical error size [m] that makes the RLS dimensionless (scaled to cm loops)."
    )
    max_change_fraction: PositiveFloat = Field(0.25, description="Largest relative gain change per push.")
    spectral_radius_max: PositiveFloat = Field(
        0.995, lt=1.0, description="Closed-loop spectral radius limit of the linear model with the PID."
    )
    ki_min: PositiveFloat | None = Field(
        None, description="Smallest admissible own-loop Ki; null = 0.1 x the fixed Ki."
    )
    estimator: Literal["prior", "rls"] = Field(
        "prior",
        description=(
            "prior: least squares with a persistent prior at the model-based (SIMC) tuning and "
            "directional forgetting (well-conditioned, ADR 0014); rls: the former exponentially "
            "forgetting RLS from the fixed gains."
        ),
    )
    prior_closed_loop_s: PositiveFloat | None = Field(
        None, description="Closed-loop time constant tau_c of the model-based tuning [s]; null = 4 PLC scans."
    )
    prior_weight: PositiveFloat = Field(
        1.0, description="Weight w of the prior: L0 = w / sigma^2 per parameter (dimensionless)."
    )
    path: Literal["geometric", "linear"] = Field(
        "geometric", description="Path of a push toward the estimate: log-space or gain-space straight line."
    )
    kd_keep_sign: bool = Field(
        True, description="Own-loop Kd stays between 0 and the fixed Kd (never flips)."
    )
    saturated: Literal["one_sided", "drop", "equality"] = Field(
        "one_sided",
        description="What a sample with the MPC at an input bound teaches (docs/adaptation.md 2.2).",
    )
    noise_move_budget: PositiveFloat | None = Field(
        0.0035,
        description=(
            "Largest rms pump move per scan that estimated transmitter noise may cause through the "
            "model-based tuning, as a fraction of the pump range; null = no noise limit."
        ),
    )
    box_limit_fraction: float = Field(
        0.01,
        ge=0.0,
        lt=0.5,
        description=(
            "A gain closer to a box limit than this fraction of the smaller of the box width and "
            "the gain's natural scale (the larger of its fixed and model-based values) is on it."
        ),
    )


class SupervisorConfig(Model):
    """The SCADA level: MPC, adaptation and their cadence."""

    mode: Literal["OFF", "ADVISORY", "ADAPTIVE_PID", "MPC"] = Field("ADVISORY", description="Mode at start.")
    sample_time_s: PositiveFloat | None = Field(
        None,
        description=(
            "Supervisor (and MPC) sample time [s], a whole multiple of the PLC scan period; the MPC "
            "discretises its model at it; default: the PLC scan period."
        ),
    )
    mpc: MpcSpec = Field(description="The MPC.")
    adaptation: AdaptationSpec = Field(default_factory=AdaptationSpec, description="Gain adaptation.")
    plc_stale_s: PositiveFloat = Field(
        5.0, description="Model seconds without a new PLC scan count before the PLC counts as lost."
    )

    @property
    def mode_enum(self) -> SupervisorMode:
        """The initial mode as the contract's enumeration."""
        return SupervisorMode[self.mode]


# --------------------------------------------------------------------------------------------
# Endpoints and site
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------

ENV_ENDPOINT_VARS = {
    "plant": "TANKLAB_PLANT_URL",
    "plc": "TANKLAB_PLC_URL",
    "supervisor": "TANKLAB_SUPERVISOR_URL",
}

_URL = re.compile(r"^opc\.tcp://(?P<host>[^:/]+):(?P<port>\d+)(/.*)?$")


def parse_endpoint_url(url: str) -> Endpoint:
    """Parse ``opc.tcp://host:port[/path]`` into an :class:`Endpoint`.

    Raises
    ------
    ValueError
        If the URL is not of that form or the port is out of range.
    """
    m = _URL.match(url.strip())
    if not m:
        raise ValueError(f"not an opc.tcp://HOST:PORT URL: {url!r}")
    return Endpoint(host=m["host"], port=int(m["port"]))


def format_validation_error(path: str | Path, err: ValidationError) -> str:
    """One line: ``FILE: FIELD: RULE`` for the first error (and a count of the others)."""
    first = err.errors()[0]
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in first["loc"]).replace(".[", "[")
    more = len(err.errors()) - 1
    suffix = f" (and {more} more error{'s' if more > 1 else ''})" if more else ""
    msg = first["msg"].replace("Value error, ", "")
    return f"{path}: {loc or '(top level)'}: {msg}{suffix}"


def read_yaml(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{path}: cannot read: {e.strerror or e}") from e
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(parse)"
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ConfigError(f"{path}: {where}: invalid YAML: {problem}") from e


def site_from_mapping(data: Any, source: str | Path = "<memory>") -> SiteConfig:
    """Validate a mapping (already parsed YAML) as a :class:`SiteConfig`.

    Raises
    ------
    ConfigError
        One line naming ``source``, the field and the rule.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: (top level): expected a mapping of sections, got {type(data).__name__}")
    try:
        return SiteConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(source, e)) from e


def load_site(path: str | Path, *, env: Mapping[str, str] | None = None) -> SiteConfig:
    """Read and validate a site YAML file, then apply endpoint overrides from ``env``.

    Parameters
    ----------
    path
        The YAML file.
    env
        Environment to read ``TANKLAB_PLANT_URL``, ``TANKLAB_PLC_URL`` and
        ``TANKLAB_SUPERVISOR_URL`` from; ``None`` means no overrides (pure). The CLI passes
        ``os.environ``.
    """
    p = Path(path)
    site = site_from_mapping(read_yaml(p), p)
    if env:
        apply_env_overrides(site, env, source=str(p))
    return site


def apply_env_overrides(site: SiteConfig, env: Mapping[str, str], source: str = "<env>") -> None:
    """Replace endpoints by the ``TANKLAB_*_URL`` variables present in ``env`` (in place)."""
    for tier, var in ENV_ENDPOINT_VARS.items():
        url = env.get(var)
        if url:
            try:
                setattr(site.endpoints, tier, parse_endpoint_url(url))
            except ValueError as e:
                raise ConfigError(f"{source}: {var}: {e}") from e


def default_config_path() -> Path:
    """The default site config (``TANKLAB_CONFIG`` or configs/three_tank_energies_sim.yaml)."""
    env = os.environ.get("TANKLAB_CONFIG")
    if env:
        return Path(env)
    return Path("configs/three_tank_energies_sim.yaml")


def site_schema() -> dict[str, Any]:
    """JSON schema of the site file (what `tankctl config schema` prints)."""
    return SiteConfig.model_json_schema()
