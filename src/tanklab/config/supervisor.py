"""The supervisor's config: the MPC, the RLS-to-PID adaptation and the supervisor's mode."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import ConfigDict, Field

from tanklab.config.base import Model, NonNegFloat, PositiveFloat
from tanklab.config.plc import AlarmOverride
from tanklab.enums import SupervisorMode


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


class SupervisorAlarmsConfig(Model):
    """Alarm management of the supervisor's own conditions (docs/alarms.md section 9): the schema
    of ``plc.alarms`` where it means something for them."""

    max_shelving_time_s: PositiveFloat | None = Field(
        None,
        description="Longest shelving allowed, timed or one-shot, in model time [s]; null = "
        "plc.alarms.max_shelving_time_s (one alarm philosophy per site).",
    )
    overrides: dict[str, AlarmOverride] = Field(
        default_factory=dict,
        description="Per-alarm overrides keyed by alarm name (MpcFailing, AdaptationUnhealthy, PlcLinkLost): "
        "priority, on_delay_s, off_delay_s, enabled.",
    )


CONTROLLER_PATH = r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*$"
"""A controller's dotted path: ``package.module:Class`` (decision 0054)."""


class ControllerSpec(Model):
    """A supervisory controller of one's own (decision 0054, docs/your-controller.md): a class
    implementing :class:`supervisor.controller.SupervisoryController`, loaded by dotted path and
    built from the site and ``params``; the supervisor contains it (a raise, a non-finite or
    out-of-range output, an overrun of ``budget_s`` holds the last safe action)."""

    # ``class`` in the file; ``class_`` in Python (a dump without aliases validates again)
    model_config = ConfigDict(extra="forbid", validate_assignment=True, populate_by_name=True)

    class_: str = Field(
        alias="class",
        pattern=CONTROLLER_PATH,
        description="The controller class as package.module:Class (importable where the supervisor runs).",
    )
    params: dict[str, Any] = Field(
        default_factory=dict, description="The controller's own parameters, passed to it as a mapping."
    )
    budget_s: PositiveFloat | None = Field(
        None,
        description="CPU time one step may take [s]; a longer step is an overrun (its output is "
        "discarded); null = the supervisor's sample time.",
    )
    max_failures: int = Field(
        3,
        ge=1,
        le=1000,
        description="Consecutive failed steps (raise, bad output, overrun) after which the supervisor "
        "stops its heartbeat, so the PLC's watchdog sheds the loops as for a lost supervisor.",
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
    alarms: SupervisorAlarmsConfig = Field(
        default_factory=SupervisorAlarmsConfig,
        description="Alarm management of the supervisor's conditions: per-alarm overrides, shelving.",
    )
    controller: ControllerSpec | None = Field(
        None,
        description="A supervisory controller of one's own run in place of the shipped MPC and "
        "adaptive PID (class, params, budget_s, max_failures); null = the shipped ones.",
    )

    @property
    def mode_enum(self) -> SupervisorMode:
        """The initial mode as the contract's enumeration."""
        return SupervisorMode[self.mode]
