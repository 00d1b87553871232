"""The PLC program's config: loops (PID, nonlinear PI, MRAC), gains, gain box, interlocks, watchdog.

Gains are velocity-form: ``u(k) = u(k-1) + Kp De + Ki Ts e + Kd/Ts D2e`` with e = SP - PV.
"""

from __future__ import annotations

from typing import Literal, Self

from pydantic import Field, model_validator

from tanklab.config.base import (
    LOOP_NAME,
    PUMP_NAME,
    TANK_NAME,
    TRANSMITTER_NAME,
    Finite,
    Fraction,
    Model,
    NonNegFloat,
    PositiveFloat,
)
from tanklab.enums import LoopMode


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
    pv: str = Field(pattern=TRANSMITTER_NAME, description="Level transmitter read as PV.")
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


PriorityName = Literal["LOW", "MEDIUM", "HIGH", "URGENT"]
"""ISA-18.2 priorities (Severity 250, 500, 700, 900; docs/alarms.md)."""
LimitName = Literal["HighHigh", "High", "Low", "LowLow"]


class AlarmOverride(Model):
    """Overrides of one alarm's defaults (docs/alarms.md lists the alarms and their defaults).

    The PLC's ``plc.alarms.overrides`` and the supervisor's ``supervisor.alarms.overrides`` share
    this schema; the supervisor's alarms take ``priority``, ``on_delay_s``, ``off_delay_s`` and
    ``enabled`` only (the site config says so, naming the field).
    """

    priority: PriorityName | None = Field(
        None,
        description="Priority of the alarm (of every limit of a level alarm not in limit_priorities); "
        "null = the default.",
    )
    limit_priorities: dict[LimitName, PriorityName] = Field(
        default_factory=dict,
        description="Level alarms: the priority per limit (HighHigh, High, Low, LowLow).",
    )
    deadband_m: NonNegFloat | None = Field(
        None,
        description="Level alarms: return-to-normal deadband [m]; null = 2 % of the transmitter range "
        "(EEMUA 191).",
    )
    on_delay_s: NonNegFloat = Field(
        0.0, description="Model time the condition must hold before the alarm activates [s]."
    )
    off_delay_s: NonNegFloat = Field(
        0.0, description="Model time the condition must be gone before the alarm returns to normal [s]."
    )
    suppress_when_manual: bool = Field(
        False,
        description="Level and PvBad alarms: suppressed while the tank's loop is in MANUAL (out of service).",
    )
    low_low_m: NonNegFloat | None = Field(
        None, description="Level alarms: the LowLow limit [m], below the tank's low switch; null = none."
    )
    enabled: bool = Field(
        True,
        description="false: the condition starts disabled (EnabledState false) at a cold start; an "
        "Engineer enables it with Enable. A warm restart keeps the retained state.",
    )


class AlarmsConfig(Model):
    """Alarm management of the PLC's conditions (OPC UA Part 9, ISA-18.2)."""

    max_shelving_time_s: PositiveFloat = Field(
        8 * 3600.0, description="Longest shelving allowed, timed or one-shot, in model time [s]."
    )
    overrides: dict[str, AlarmOverride] = Field(
        default_factory=dict,
        description="Per-alarm overrides keyed by alarm name (T1Level, LIC1PvBad, IoFault, SupervisorLost, "
        "T1Trip).",
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
    alarms: AlarmsConfig = Field(
        default_factory=AlarmsConfig, description="Alarm management: per-alarm overrides, shelving."
    )
    retain_file: str | None = Field(
        None,
        description="Retentive memory file (SP, mode, gains, latched trips) for warm restarts; null = cold.",
    )
