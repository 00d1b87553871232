"""Settings of the gain adapter (:class:`AdaptationConfig`), every default with its reason.

Units as the attributes state: times in model seconds [s], the error scale ``E`` in the loops'
error unit, fractions of the pump range ``U = u_max - u_min`` or of the gain box width.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from supervisor.adaptation._validate import positive
from tanklab.gains import GainBox, PidGains

__all__ = ["AdaptationConfig", "Estimator", "GainPath", "SaturatedSamples"]

SaturatedSamples = Literal["one_sided", "drop", "equality"]
Estimator = Literal["prior", "rls"]
GainPath = Literal["geometric", "linear"]


@dataclass(frozen=True, eq=False)
class AdaptationConfig:
    """Settings of :class:`PidGainAdapter`; every default is stated with its reason.

    Attributes
    ----------
    memory_s : float, default 60.0
        RLS memory [s]; ``lambda = exp(-Ts / memory_s)`` = 0.9835 at Ts = 1 s (digest 2.3: Tmem of
        30 to 100 s, lambda 0.98 to 0.99 per 1 s sample).
    p0 : float, default 1e3
        Initial covariance of the dimensionless parameters: a weak prior (typical ``theta_hat`` is
        0.01 to 1).
    trace_cap : float or None, default None
        Cap on the covariance trace (dimensionless); None means ``n_params * p0``.
    excitation_threshold : float, default 1e-3
        Dead zone on the change of the dimensionless regressor since the last applied update:
        1e-3 is 0.1 mm of error change at ``error_scale`` = 0.1 m.
    error_scale : float, default 0.1
        ``E`` [error unit] used to make the RLS dimensionless; 0.1 m is the size of a typical level
        move (the benchmark step is 0.05 m). Use 10 for a rig whose errors are in cm.
    push_period_s : float, default 10.0
        Model time between proposals [s] (architecture: gain pushes every 10 s).
    min_time_s : float, default 10.0
        Model time from the first reading before the first proposal [s] (the paper starts
        adapting after 10 s in simulation).
    full_mimo : bool, default False
        False: pump i fits only its own loop's gains (the paper; the PLC's per-loop
        ``SetGains``). True: pump i fits gains on every loop.
    own_loop : tuple of int or None, default None
        Loop index paired with each pump (sign guard, diagonal mode); None means pump i <-> loop i.
    box : GainBox or None, default None
        Admissible gains; None means, per pump row and gain type, ``+-10 x`` the largest fixed gain
        of that type in the row, with the entries a pump does not adapt pinned to their fixed value.
    ki_min : float, sequence of float (n_u,) or None, default None
        Lower bound on each pump's own-loop Ki (> 0, keeps integral action, hence zero offset under
        leaks); None means 0.1 x the fixed own-loop Ki.
    max_change_fraction : float, default 0.25
        No gain may change by more than ``max(max_change_fraction * |applied|, floor)`` per push.
    change_floor : PidGains or None, default None
        The absolute floor of that limit, for gains at or near zero; None means
        ``max_change_fraction * 0.1 *`` the largest fixed gain of the same type in the pump's row
        (so a gain that has shrunk to a tenth of its pump's scale still moves at the fraction of
        that tenth, and a zero cross-gain can leave zero).
    max_spectral_radius : float, default 0.995
        Closed-loop spectral radius must be below this (stability with margin; digest 2.4). With
        the paper's fixed gains on the simulation model the radius is 0.9880.
    horizon_steps : int, default 120
        Steps of the input-bound simulation (2 min at Ts = 1 s: longer than the 27 s and 58 s plant
        modes, so the first swing of the input is seen).
    saturated : {"one_sided", "drop", "equality"}, default "one_sided"
        What a pump's sample teaches when ``u_MPC`` is within ``saturation_band`` of a bound. A
        clamped move only says "at least this much" (at ``u_max``; "at most" at ``u_min``):
        "one_sided" uses it as that inequality (projection, see the module doc); "drop" ignores it
        (no learning at all while the MPC fills a tank at Qmax: the Energies run learned nothing
        for pump 1 in its first 70 s); "equality" fits it as an equality (drags the gains toward
        the clamped move: digest 2.4's collapse).
    saturation_band : float, default 0.005
        Width of that band as a fraction of ``u_max - u_min`` (solver tolerance headroom).
    estimator : {"prior", "rls"}, default "prior"
        "prior": :class:`~supervisor.prior_rls.PriorRls`, least squares with a persistent prior
        at the model-based tuning (:func:`model_based_gains`) and directional forgetting: the
        information matrix is at least the prior's, so its condition number is bounded, and
        where the data say nothing the estimate is the model-based tuning (ADR 0014). "rls":
        the former exponentially forgetting RLS from the fixed gains (``p0``, ``trace_cap``),
        kept for comparison: ill-conditioned in closed loop (docs/adaptation.md 2.9).
    prior_closed_loop_s : float or None, default None
        ``tau_c`` [s] of the model-based tuning (SIMC); None means ``4 Ts``.
    prior_weight : float, default 1.0
        ``w`` in ``L0 = diag(w / sigma^2)``, sigma the larger of the prior's and the fixed gain's
        size per parameter (dimensionless): the prior weighs as much as ``w`` samples that measure
        the parameter at its own scale.
    path : {"geometric", "linear"}, default "geometric"
        How a proposal moves from the applied gains toward the estimate: "geometric" moves
        gains that keep their sign along a straight line in log space (every gain the same
        fraction of its log-distance), the others linearly, with one step fraction per pump;
        "linear" is the straight line in gain space (the former proposer).
    kd_keep_sign : bool, default True
        The estimate's own-loop Kd stays between 0 and the fixed Kd (it may shrink to 0, never
        change sign: the model-based tuning has Kd = 0).
    noise_move_budget : float or None, default 0.0035
        Largest rms pump move per scan, as a fraction of the pump's range, that the estimated
        transmitter noise may cause through the loop gain (``sqrt(2) Kp sigma``): each pump's
        own-loop target is scaled down to ``Kp <= budget U / (sqrt(2) sigma)``, with 20 %
        hysteresis. None: no limit. Sized so that 0.5 mm of noise on the Energies plant moves the
        pumps at most 3x as much as the paper's fixed PID (measured 2.4x).
    box_limit_fraction : float, default 0.01
        A gain closer to a box limit than this fraction of the smaller of the box width and the
        gain's natural scale (the larger of its fixed and model-based values) is reported on the
        limit (``on_box_limit``).
    """

    memory_s: float = 60.0
    p0: float = 1e3
    trace_cap: float | None = None
    excitation_threshold: float = 1e-3
    error_scale: float = 0.1
    push_period_s: float = 10.0
    min_time_s: float = 10.0
    full_mimo: bool = False
    own_loop: tuple[int, ...] | None = None
    box: GainBox | None = None
    ki_min: float | tuple[float, ...] | None = None
    max_change_fraction: float = 0.25
    change_floor: PidGains | None = None
    max_spectral_radius: float = 0.995
    horizon_steps: int = 120
    saturated: SaturatedSamples = "one_sided"
    saturation_band: float = 0.005
    estimator: Estimator = "prior"
    prior_closed_loop_s: float | None = None
    prior_weight: float = 1.0
    path: GainPath = "geometric"
    kd_keep_sign: bool = True
    box_limit_fraction: float = 0.01
    noise_move_budget: float | None = 0.0035

    def __post_init__(self) -> None:
        if not (
            isinstance(self.memory_s, (int, float)) and self.memory_s > 0 and not math.isnan(self.memory_s)
        ):
            raise ValueError(f"memory_s must be > 0 (math.inf: no forgetting), got {self.memory_s!r}")
        positive(self.p0, "p0")
        if self.trace_cap is not None and not (
            isinstance(self.trace_cap, (int, float)) and self.trace_cap > 0
        ):
            raise ValueError(f"trace_cap must be None or > 0, got {self.trace_cap!r}")
        positive(self.excitation_threshold, "excitation_threshold", allow_zero=True)
        positive(self.error_scale, "error_scale")
        positive(self.push_period_s, "push_period_s")
        positive(self.min_time_s, "min_time_s", allow_zero=True)
        positive(self.max_change_fraction, "max_change_fraction")
        rho = positive(self.max_spectral_radius, "max_spectral_radius")
        if rho > 1.0:
            raise ValueError(f"max_spectral_radius must be in (0, 1], got {rho!r}")
        if isinstance(self.horizon_steps, bool) or not isinstance(self.horizon_steps, int):
            raise TypeError("horizon_steps must be an int")
        if self.horizon_steps < 1:
            raise ValueError(f"horizon_steps must be >= 1, got {self.horizon_steps}")
        if self.saturated not in ("one_sided", "drop", "equality"):
            raise ValueError(f"saturated must be 'one_sided', 'drop' or 'equality', got {self.saturated!r}")
        band = positive(self.saturation_band, "saturation_band", allow_zero=True)
        if band >= 0.5:
            raise ValueError(f"saturation_band must be < 0.5 (fraction of the input range), got {band!r}")
        if self.estimator not in ("prior", "rls"):
            raise ValueError(f"estimator must be 'prior' or 'rls', got {self.estimator!r}")
        if self.prior_closed_loop_s is not None:
            positive(self.prior_closed_loop_s, "prior_closed_loop_s")
        positive(self.prior_weight, "prior_weight")
        if self.path not in ("geometric", "linear"):
            raise ValueError(f"path must be 'geometric' or 'linear', got {self.path!r}")
        if not isinstance(self.kd_keep_sign, bool):
            raise TypeError("kd_keep_sign must be a bool")
        if self.noise_move_budget is not None:
            positive(self.noise_move_budget, "noise_move_budget")
        frac = positive(self.box_limit_fraction, "box_limit_fraction", allow_zero=True)
        if frac >= 0.5:
            raise ValueError(f"box_limit_fraction must be < 0.5 (fraction of the box width), got {frac!r}")
