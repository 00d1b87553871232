"""MPC-based PID gain adaptation with admissibility guards (seeds digest 2.1, 2.3, 2.4).

The PLC runs, every scan ``k`` of period ``Ts`` [s], the velocity-form MIMO PID (digest 2.1) with
``e_j = r_j - y_j`` (setpoint minus measured level, [m])::

    u_i(k) = u_i(k-1) + sum_j [ Kp_ij De_j(k) + Ki_ij Ts e_j(k) + (Kd_ij / Ts) D2e_j(k) ]
    De_j(k)  = e_j(k) - e_j(k-1),   D2e_j(k) = e_j(k) - 2 e_j(k-1) + e_j(k-2)

with ``u(k-1)`` the clamped, applied output. The supervisor's MPC runs in the shadow from the
measured state and proposes ``u_MPC(k)``. For each pump ``i`` an :class:`~tanklab.rls.ExpForgettingRls`
fits that pump's gains so that the PID increment reproduces the MPC's move from where the actuator
really is::

    y_i(k)   = u_i,MPC(k) - u_i,applied(k-1)                                  [pump unit]
    psi_i(k) = [ De_j, Ts e_j, D2e_j / Ts  for each loop j the pump uses ]
    theta_i  = [ Kp_ij, Ki_ij, Kd_ij       for each loop j the pump uses ]
    y_i(k)   = psi_i(k)' theta_i

Two corrections to the paper (digest 2.4): the third regressor slot is ``D2e / Ts`` (the paper's
``De / Ts`` makes the Kp and Kd columns proportional), and the target is the MPC input minus the
*applied* input (the paper's ``u_MPC(k) - u_MPC(k-1)`` is right only when the MPC drives).
Diagonal mode (default, the paper's and the PLC's ``SetGains(Kp, Ki, Kd)`` per loop) uses only the
pump's own loop; full MIMO uses every loop (``3 * n_loops`` parameters per pump).

The RLS runs on dimensionless parameters so one set of defaults fits every unit system: with
``E`` the error scale (config, units of ``e``) and ``U_i = u_max,i - u_min,i``::

    theta_hat = [Kp, Ki Ts, Kd / Ts] * E / U_i      x_hat = [De, e, D2e] / E      y_hat = y / U_i

so that ``x_hat' theta_hat = y_hat`` exactly.

The estimator (``estimator="prior"``, the default; ADR 0014, docs/adaptation.md 2.10) is
:class:`~supervisor.prior_rls.PriorRls`: least squares with a persistent prior at the model-based
tuning and directional forgetting::

    theta_i = argmin  sum_s w(s) (y_hat(s) - x_hat(s)' theta)^2 + (theta - theta_p)' L0 (theta - theta_p)
    L0      = diag(prior_weight / sigma^2),  sigma = max(|theta_p|, |theta_fixed|, floors)

so its information matrix is never below ``L0`` (bounded condition number) and where the data say
nothing the estimate is the prior. The prior ``theta_p`` is the SIMC PI of each own tank's
first-order model (:func:`model_based_gains`)::

    Kp = tau / (K (tau_c + Ts / 2)),   Ki = Kp / min(tau, 4 (tau_c + Ts / 2)),   Kd = 0

``estimator="rls"`` keeps the former :class:`~tanklab.rls.ExpForgettingRls` from the fixed gains.

When ``u_MPC,i`` sits at a bound of its input range (within ``saturation_band``), the sample is
an inequality, not an equality: the clamped MPC wants *at least* ``u_MPC,i`` (at ``u_min``: at
most), so the PID's move must satisfy ``psi_i' theta_i >= y_i`` (``<= y_i`` at ``u_min``). With
``saturated="one_sided"`` (default) an estimate that already satisfies it learns nothing, and one
that violates it is projected onto the boundary ``psi_i' theta_i = y_i`` in the metric of the RLS
covariance, ``P`` itself left unchanged (:meth:`tanklab.rls.ExpForgettingRls.constrain`): an
inequality bounds the parameters without measuring them. Dropping these samples (``"drop"``, the
former default) starves the fit while the MPC fills a tank at Qmax; fitting them as equalities
(``"equality"``) drags the gains toward the clamped move (digest 2.4's collapse).

With the prior estimator a violated inequality is absorbed as an equality sample instead (it is
weighed against the prior; a projection would override it).

Transmitter noise is estimated per loop from the model's differenced one-step prediction errors
(:meth:`PidGainAdapter.noise_std`); it limits each pump's loop gain to
``Kp <= noise_move_budget U / (sqrt(2) sigma)`` (the whole own-loop target is scaled) and raises
the dead zone to ``17 sigma / E``.

A candidate gain set (all pumps) is proposed every push period: each ready pump moves from its
applied gains toward its estimate along one path (``path="geometric"``: the straight line in log
space for gains that keep their sign, ``g = a (target / a)^alpha``; ``"linear"``: in gain space),
as far as the rate limit lets every one of its gains go. It is returned for pushing only when it
passes every admissibility guard (:class:`RejectReason`), which replace the paper's vacuous "u
inside the input set" condition: finite; inside the gain box; signs (own loop ``Kp >= 0``, ``Ki >=
Ki_min > 0``); rate limit per push; closed-loop spectral radius of the ZOH model with the
candidate PID below ``max_spectral_radius``; and the unclamped input of the linear closed loop,
simulated from the current state, inside ``[u_min, u_max]`` (excursions beyond a bound the MPC is
pinned at in that scan are the teacher's own saturation and are not counted). The closed-loop
matrix is derived in :func:`closed_loop_matrix`.

This module is pure: model time ``t_s`` [s] and the PLC scan counter are arguments; no clock, no
I/O, no logging.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from supervisor.prior_rls import PriorRls
from tanklab.gains import GainBox, PidGains  # the kernel's gain types, re-exported (decision 0030)
from tanklab.rls import ExpForgettingRls

__all__ = [
    "AdaptationConfig",
    "AdapterDiagnostics",
    "Decision",
    "GainBox",
    "LoopModel",
    "PidGainAdapter",
    "PidGains",
    "PumpDiagnostics",
    "RejectReason",
    "SampleStatus",
    "SaturatedSamples",
    "closed_loop_matrix",
    "closed_loop_spectral_radius",
    "input_bound_violation",
    "simulate_pid_inputs",
]

FloatArray = NDArray[np.float64]
SaturatedSamples = Literal["one_sided", "drop", "equality"]
Estimator = Literal["prior", "rls"]
GainPath = Literal["geometric", "linear"]

#: Relative tolerance on the rate limit and on the input-bound comparison (rounding only).
_REL_TOL = 1e-9
#: The noise estimate's memory, in units of ``memory_s`` (a slow property of the transmitters).
_NOISE_MEMORY_FACTOR = 10.0
#: Dead zone per estimated noise standard deviation, in units of ``sigma / error_scale``.
_NOISE_DEAD_ZONE = 17.0
#: Relative band of the noise limit's hysteresis (engage, release, move).
_NOISE_HYSTERESIS = 0.2


class RejectReason(StrEnum):
    """Why a candidate gain set was rejected, in the order the guards are reported."""

    NON_FINITE = "non_finite"
    OUTSIDE_BOX = "outside_box"
    SIGN = "sign"
    RATE_LIMIT = "rate_limit"
    UNSTABLE = "unstable"
    INPUT_BOUNDS = "input_bounds"


class SampleStatus(StrEnum):
    """What :meth:`PidGainAdapter.observe` did with one scan's readings."""

    FORMED = "formed"  # a regression sample was formed and offered to every pump's RLS
    WARMUP = "warmup"  # first readings after start: history not yet three scans long
    GAP = "gap"  # the window spans a gap in the scan counter: dropped, counted
    INVALID = "invalid"  # non-finite SP, PV or MV: dropped, counted, history restarts
    DUPLICATE = "duplicate"  # same scan number as the previous reading: ignored


def _matrix(value: ArrayLike, name: str, shape: tuple[int, ...] | None = None) -> FloatArray:
    arr = np.array(value, dtype=np.float64, ndmin=1)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


def _finite(arr: FloatArray, name: str) -> FloatArray:
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


def _positive(value: float, name: str, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0.0 or (v == 0.0 and not allow_zero):
        rule = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {rule}, got {v!r}")
    return v


# --------------------------------------------------------------------------- value types
# PidGains and GainBox are tanklab.gains' (imported above); the model is the adaptation's own.
_GAIN_NAMES = ("Kp", "Ki", "Kd")  # as the rejection messages name them


@dataclass(frozen=True, eq=False)
class LoopModel:
    """Discrete (ZOH) linear model of the plant around an equilibrium, with the loops' outputs.

    ``x(k+1) - x_op = A (x(k) - x_op) + B (u(k) - u_op)``, loop outputs ``y = C x``.

    Attributes
    ----------
    A : ndarray, shape (n_x, n_x)
        State matrix (levels [m]).
    B : ndarray, shape (n_x, n_u)
        Input matrix [m per pump unit].
    C : ndarray, shape (n_loops, n_x)
        Loop output matrix: row j selects the PV of loop j.
    ts_s : float
        Sample time [s], the PLC scan the PID runs at.
    u_min, u_max : ndarray, shape (n_u,)
        Actuator bounds [pump unit], finite, ``u_min < u_max``.
    x_op : ndarray, shape (n_x,)
        Equilibrium state; zeros by default (an empty array means the default).
    u_op : ndarray, shape (n_u,)
        Equilibrium input; zeros by default (an empty array means the default).
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    ts_s: float
    u_min: FloatArray
    u_max: FloatArray
    x_op: FloatArray = field(default_factory=lambda: np.zeros(0))
    u_op: FloatArray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        A = _finite(_matrix(self.A, "A"), "A")
        if A.ndim != 2 or A.shape[0] != A.shape[1]:
            raise ValueError(f"A must be square (n_x, n_x), got shape {A.shape}")
        n = A.shape[0]
        B = _finite(_matrix(self.B, "B"), "B")
        if B.ndim != 2 or B.shape[0] != n:
            raise ValueError(f"B must have shape ({n}, n_u), got {B.shape}")
        m = B.shape[1]
        C = _finite(_matrix(self.C, "C"), "C")
        if C.ndim != 2 or C.shape[1] != n:
            raise ValueError(f"C must have shape (n_loops, {n}), got {C.shape}")
        ts = _positive(self.ts_s, "ts_s")
        u_min = _finite(_matrix(self.u_min, "u_min", (m,)), "u_min")
        u_max = _finite(_matrix(self.u_max, "u_max", (m,)), "u_max")
        if not (u_min < u_max).all():
            raise ValueError("u_min must be < u_max for every pump")
        x_op = np.zeros(n) if np.size(self.x_op) == 0 else _finite(_matrix(self.x_op, "x_op", (n,)), "x_op")
        u_op = np.zeros(m) if np.size(self.u_op) == 0 else _finite(_matrix(self.u_op, "u_op", (m,)), "u_op")
        for name, arr in (
            ("A", A),
            ("B", B),
            ("C", C),
            ("u_min", u_min),
            ("u_max", u_max),
            ("x_op", x_op),
            ("u_op", u_op),
        ):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "ts_s", ts)

    @property
    def n_x(self) -> int:
        """Number of states."""
        return int(self.A.shape[0])

    @property
    def n_u(self) -> int:
        """Number of pumps."""
        return int(self.B.shape[1])

    @property
    def n_loops(self) -> int:
        """Number of loops (PID errors)."""
        return int(self.C.shape[0])


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
        _positive(self.p0, "p0")
        if self.trace_cap is not None and not (
            isinstance(self.trace_cap, (int, float)) and self.trace_cap > 0
        ):
            raise ValueError(f"trace_cap must be None or > 0, got {self.trace_cap!r}")
        _positive(self.excitation_threshold, "excitation_threshold", allow_zero=True)
        _positive(self.error_scale, "error_scale")
        _positive(self.push_period_s, "push_period_s")
        _positive(self.min_time_s, "min_time_s", allow_zero=True)
        _positive(self.max_change_fraction, "max_change_fraction")
        rho = _positive(self.max_spectral_radius, "max_spectral_radius")
        if rho > 1.0:
            raise ValueError(f"max_spectral_radius must be in (0, 1], got {rho!r}")
        if isinstance(self.horizon_steps, bool) or not isinstance(self.horizon_steps, int):
            raise TypeError("horizon_steps must be an int")
        if self.horizon_steps < 1:
            raise ValueError(f"horizon_steps must be >= 1, got {self.horizon_steps}")
        if self.saturated not in ("one_sided", "drop", "equality"):
            raise ValueError(f"saturated must be 'one_sided', 'drop' or 'equality', got {self.saturated!r}")
        band = _positive(self.saturation_band, "saturation_band", allow_zero=True)
        if band >= 0.5:
            raise ValueError(f"saturation_band must be < 0.5 (fraction of the input range), got {band!r}")
        if self.estimator not in ("prior", "rls"):
            raise ValueError(f"estimator must be 'prior' or 'rls', got {self.estimator!r}")
        if self.prior_closed_loop_s is not None:
            _positive(self.prior_closed_loop_s, "prior_closed_loop_s")
        _positive(self.prior_weight, "prior_weight")
        if self.path not in ("geometric", "linear"):
            raise ValueError(f"path must be 'geometric' or 'linear', got {self.path!r}")
        if not isinstance(self.kd_keep_sign, bool):
            raise TypeError("kd_keep_sign must be a bool")
        if self.noise_move_budget is not None:
            _positive(self.noise_move_budget, "noise_move_budget")
        frac = _positive(self.box_limit_fraction, "box_limit_fraction", allow_zero=True)
        if frac >= 0.5:
            raise ValueError(f"box_limit_fraction must be < 0.5 (fraction of the box width), got {frac!r}")


@dataclass(frozen=True, eq=False)
class Decision:
    """Outcome of the admissibility guards for one candidate gain set.

    Attributes
    ----------
    t_s : float
        Model time of the proposal [s].
    candidate : PidGains
        The gain set judged.
    accepted : bool
        True when every guard passed (then it is the set to push).
    reasons : tuple of RejectReason
        Every failing guard, in :class:`RejectReason` order; empty when accepted.
    detail : str
        Human-readable detail of the first failure ("" when accepted).
    spectral_radius : float
        Closed-loop spectral radius with the candidate (NaN when not computed).
    input_violation : float
        Peak excursion of the simulated input beyond its bounds, as a fraction of the input
        range (0 inside; NaN when not computed).
    changed : bool
        True when the candidate differs from the gains applied at the time.
    """

    t_s: float
    candidate: PidGains
    accepted: bool
    reasons: tuple[RejectReason, ...]
    detail: str
    spectral_radius: float
    input_violation: float
    changed: bool

    @property
    def reason(self) -> RejectReason | None:
        """First failing guard, or None when accepted."""
        return self.reasons[0] if self.reasons else None


@dataclass(frozen=True)
class PumpDiagnostics:
    """Per-pump adaptation state.

    Attributes
    ----------
    theta : ndarray, shape (3 * loops used,)
        Current RLS estimate in physical units ``[Kp_ij, Ki_ij, Kd_ij, ...]``.
    covariance_trace : float
        Trace of the RLS covariance of the dimensionless parameters.
    samples_used : int
        Applied RLS updates.
    skipped_unexcited : int
        Samples skipped by the RLS dead zone.
    skipped_nonfinite : int
        Samples skipped for a non-finite target or result.
    dropped_saturated : int
        Samples with ``u_MPC`` at a bound that taught nothing: dropped (``saturated="drop"``) or
        already consistent with the estimate (``"one_sided"``).
    one_sided_updates : int
        Samples with ``u_MPC`` at a bound whose inequality the estimate violated and that moved it
        onto the boundary (``saturated="one_sided"``; not counted in ``samples_used``).
    ready : bool
        Enough informative samples (applied updates plus one-sided corrections, at least the
        number of parameters) to propose gains.
    excitation : float
        Smallest eigenvalue of the remembered data's information matrix ``R`` (dimensionless,
        >= 0): how well the weakest parameter direction is measured. For ``estimator="rls"``:
        ``1 / lambda_max(P)`` minus nothing (the RLS has no separate prior), i.e. the smallest
        eigenvalue of ``P^-1``.
    condition_number : float
        Condition number of the information matrix (``L0 + R``; ``P`` for "rls"), >= 1.
    box_distance : ndarray, shape (3 * loops used,)
        Per estimated gain ``[Kp, Ki, Kd, ...]``: distance of the estimate to the nearest limit of
        the gain box, as a fraction of the box width (0 on a limit, 0.5 in the middle; NaN for a
        pinned gain of zero width).
    on_box_limit : bool
        The estimate or the applied gains of this pump sit on a box limit
        (:meth:`PidGainAdapter.on_box_limit`): the box, not the data, decides such a gain.
    prior : ndarray, shape (3 * loops used,)
        The model-based tuning the estimate is regularised toward (physical units).
    """

    theta: FloatArray
    covariance_trace: float
    samples_used: int
    skipped_unexcited: int
    skipped_nonfinite: int
    dropped_saturated: int
    one_sided_updates: int
    ready: bool
    excitation: float = math.nan
    condition_number: float = math.nan
    box_distance: FloatArray = field(default_factory=lambda: np.zeros(0))
    on_box_limit: bool = False
    prior: FloatArray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class AdapterDiagnostics:
    """Adapter-wide counters and per-pump state.

    Attributes
    ----------
    pumps : tuple of PumpDiagnostics
        One per pump.
    samples_formed : int
        Regression samples formed (three contiguous scans).
    dropped_gap : int
        Readings whose window spans a gap in the scan counter.
    dropped_invalid : int
        Readings with a non-finite SP, PV or MV.
    duplicates : int
        Readings repeating the previous scan number (ignored).
    accepted_pushes : int
        Candidates that passed every guard.
    rejected_pushes : int
        Candidates rejected.
    rejected_by_reason : mapping of str to int
        Rejections per :class:`RejectReason` value (every failing guard counted).
    last_reject_reason : RejectReason or None
        First failing guard of the last rejected candidate.
    applied : PidGains
        Gains the adapter believes the PLC applies.
    """

    pumps: tuple[PumpDiagnostics, ...]
    samples_formed: int
    dropped_gap: int
    dropped_invalid: int
    duplicates: int
    accepted_pushes: int
    rejected_pushes: int
    rejected_by_reason: Mapping[str, int]
    last_reject_reason: RejectReason | None
    applied: PidGains


# --------------------------------------------------------------------------- pure functions
def _check_loop_arrays(
    A: ArrayLike, B: ArrayLike, C: ArrayLike, Kp: ArrayLike, Ki: ArrayLike, Kd: ArrayLike, ts_s: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float]:
    Am = _finite(_matrix(A, "A"), "A")
    if Am.ndim != 2 or Am.shape[0] != Am.shape[1]:
        raise ValueError(f"A must be square (n_x, n_x), got shape {Am.shape}")
    n = Am.shape[0]
    Bm = _finite(_matrix(B, "B"), "B")
    if Bm.ndim != 2 or Bm.shape[0] != n:
        raise ValueError(f"B must have shape ({n}, n_u), got {Bm.shape}")
    Cm = _finite(_matrix(C, "C"), "C")
    if Cm.ndim != 2 or Cm.shape[1] != n:
        raise ValueError(f"C must have shape (n_loops, {n}), got {Cm.shape}")
    shape = (Bm.shape[1], Cm.shape[0])
    Kpm = _finite(_matrix(Kp, "Kp", shape), "Kp")
    Kim = _finite(_matrix(Ki, "Ki", shape), "Ki")
    Kdm = _finite(_matrix(Kd, "Kd", shape), "Kd")
    return Am, Bm, Cm, Kpm, Kim, Kdm, _positive(ts_s, "ts_s")


def closed_loop_matrix(
    A: ArrayLike, B: ArrayLike, C: ArrayLike, Kp: ArrayLike, Ki: ArrayLike, Kd: ArrayLike, ts_s: float
) -> FloatArray:
    """Closed-loop matrix of a ZOH linear plant with the velocity-form MIMO PID, ``r = 0``.

    State ``z(k) = [x(k), u(k-1), e(k-1), e(k-2)]`` of size ``n_x + n_u + 2 n_loops``, with
    ``e(k) = -C x(k)``. Writing the PID as

        u(k) = u(k-1) + G0 e(k) - G1 e(k-1) + G2 e(k-2)
        G0 = Kp + Ki Ts + Kd / Ts,   G1 = Kp + 2 Kd / Ts,   G2 = Kd / Ts      (n_u, n_loops)

    and ``x(k+1) = A x(k) + B u(k)`` gives ``z(k+1) = M z(k)`` with::

            [ A - B G0 C   B     -B G1   B G2 ]     x(k+1)
        M = [   -G0 C      I      -G1     G2  ]     u(k)
            [    -C        0       0      0   ]     e(k)
            [     0        0       I      0   ]     e(k-1)

    Parameters
    ----------
    A : array_like, shape (n_x, n_x)
    B : array_like, shape (n_x, n_u)
    C : array_like, shape (n_loops, n_x)
    Kp, Ki, Kd : array_like, shape (n_u, n_loops)
        Gains [pump unit / e], [pump unit / (e s)], [pump unit s / e].
    ts_s : float
        Sample time [s], > 0.

    Returns
    -------
    ndarray, shape (n_x + n_u + 2 n_loops, n_x + n_u + 2 n_loops)

    Raises
    ------
    ValueError
        On a shape mismatch, a non-finite entry or ``ts_s <= 0``.
    """
    Am, Bm, Cm, Kpm, Kim, Kdm, ts = _check_loop_arrays(A, B, C, Kp, Ki, Kd, ts_s)
    n, m, nl = Am.shape[0], Bm.shape[1], Cm.shape[0]
    G0 = Kpm + Kim * ts + Kdm / ts
    G1 = Kpm + 2.0 * Kdm / ts
    G2 = Kdm / ts
    zero = np.zeros
    return np.block(
        [
            [Am - Bm @ G0 @ Cm, Bm, -Bm @ G1, Bm @ G2],
            [-G0 @ Cm, np.eye(m), -G1, G2],
            [-Cm, zero((nl, m)), zero((nl, nl)), zero((nl, nl))],
            [zero((nl, n)), zero((nl, m)), np.eye(nl), zero((nl, nl))],
        ]
    )


def closed_loop_spectral_radius(
    A: ArrayLike, B: ArrayLike, C: ArrayLike, Kp: ArrayLike, Ki: ArrayLike, Kd: ArrayLike, ts_s: float
) -> float:
    """Spectral radius ``max |eig(M)|`` of :func:`closed_loop_matrix` (stable iff < 1).

    A velocity-form PID without integral action on some direction leaves an eigenvalue at
    exactly 1 (the held input is a free constant), so ``Ki`` of full rank is needed for < 1.
    Parameters, shapes and errors as in :func:`closed_loop_matrix`.
    """
    M = closed_loop_matrix(A, B, C, Kp, Ki, Kd, ts_s)
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def model_based_gains(
    model: LoopModel, own_loop: tuple[int, ...] | None, tau_c_s: float | ArrayLike
) -> PidGains:
    """SIMC PI tuning of each pump's own loop from the diagonal of the linear model (Kd = 0).

    For pump ``i`` on loop ``j`` whose PV is state ``t`` (the largest entry of ``C[j]``, scale
    ``c = C[j, t]``), the own-tank model ``x_t(k+1) = a x_t(k) + b u_i(k)`` with ``a = A[t, t]``
    and ``b = c B[t, i]`` (error unit per pump unit) is, in continuous time, a first-order lag
    ``K / (tau s + 1)`` with ``tau = -Ts / ln a`` [s] and ``K = b / (1 - a)``, plus the sample-and-
    hold delay ``theta = Ts / 2``. Skogestad's SIMC rules (2003) then give::

        Kp = tau / (K (tau_c + theta)),   Ti = min(tau, 4 (tau_c + theta)),   Ki = Kp / Ti,  Kd = 0

    and for an integrating tank (``a >= 1``, slope ``k' = b / Ts``): ``Kp = 1 / (k' (tau_c +
    theta))``, ``Ti = 4 (tau_c + theta)``. Cross gains are 0. A pump whose own tank the model does
    not move (``b <= 0``) gets zero gains: the caller's bounds decide.

    Parameters
    ----------
    model : LoopModel
    own_loop : tuple of int or None
        Loop of each pump (None: pump i <-> loop i).
    tau_c_s : float
        Desired closed-loop time constant [s], > 0.

    Returns
    -------
    PidGains
        Shape (n_u, n_loops), [pump unit / error unit], [.. / (error unit s)], [.. s / error unit].
    """
    m, nl = model.n_u, model.n_loops
    tau_cs = np.broadcast_to(np.asarray(tau_c_s, dtype=np.float64), (m,))
    if not (np.isfinite(tau_cs).all() and (tau_cs > 0).all()):
        raise ValueError("tau_c_s must be finite and > 0 (a scalar or one per pump)")
    own = tuple(range(m)) if own_loop is None else tuple(own_loop)
    if len(own) != m or any(not 0 <= j < nl for j in own):
        raise ValueError(f"own_loop must give one loop index in [0, {nl}) per pump ({m})")
    ts = model.ts_s
    theta = ts / 2.0
    kp = np.zeros((m, nl))
    ki = np.zeros((m, nl))
    for i, j in enumerate(own):
        tau_c = float(tau_cs[i])
        t = int(np.argmax(np.abs(model.C[j])))
        a = float(model.A[t, t])
        b = float(model.C[j, t] * model.B[t, i])
        if not b > 0.0:
            continue
        if 0.0 < a < 1.0:
            tau = -ts / math.log(a)
            gain = b / (1.0 - a)
            kp[i, j] = tau / (gain * (tau_c + theta))
            ti = min(tau, 4.0 * (tau_c + theta))
        else:
            kp[i, j] = 1.0 / ((b / ts) * (tau_c + theta))
            ti = 4.0 * (tau_c + theta)
        ki[i, j] = kp[i, j] / ti
    return PidGains(kp, ki, np.zeros((m, nl)))


def simulate_pid_inputs(
    model: LoopModel,
    gains: PidGains,
    *,
    x0: ArrayLike,
    u0: ArrayLike,
    e0: ArrayLike,
    e_prev: ArrayLike,
    r: ArrayLike,
    n_steps: int,
) -> FloatArray:
    """Unclamped PID inputs of the linear closed loop over ``n_steps`` scans.

    From scan ``k`` (state ``x(k) = x0``, applied input ``u(k) = u0``, errors ``e(k) = e0``,
    ``e(k-1) = e_prev``, setpoints ``r`` held), for ``s = 1..n_steps``::

        x(k+s) - x_op = A (x(k+s-1) - x_op) + B (u(k+s-1) - u_op)
        e(k+s)        = r - C x(k+s)
        u(k+s)        = u(k+s-1) + Kp De + Ki Ts e + (Kd / Ts) D2e      (not clamped)

    Parameters
    ----------
    model : LoopModel
    gains : PidGains
        Finite, shape (n_u, n_loops).
    x0 : array_like, shape (n_x,)
        Absolute state [m]. ``u0`` shape (n_u,) absolute input; ``e0``, ``e_prev``, ``r`` shape
        (n_loops,) [m].
    n_steps : int
        Horizon, >= 1.

    Returns
    -------
    ndarray, shape (n_steps, n_u)
        Absolute inputs ``u(k+1) .. u(k+n_steps)``.
    """
    if not gains.is_finite():
        raise ValueError("gains must be finite")
    if gains.shape != (model.n_u, model.n_loops):
        raise ValueError(f"gains must have shape {(model.n_u, model.n_loops)}, got {gains.shape}")
    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    nl = model.n_loops
    x = _finite(_matrix(x0, "x0", (model.n_x,)), "x0") - model.x_op
    u = _finite(_matrix(u0, "u0", (model.n_u,)), "u0") - model.u_op
    e1 = _finite(_matrix(e0, "e0", (nl,)), "e0").copy()
    e2 = _finite(_matrix(e_prev, "e_prev", (nl,)), "e_prev").copy()
    r_dev = _finite(_matrix(r, "r", (nl,)), "r") - model.C @ model.x_op
    ts = model.ts_s
    G0 = gains.kp + gains.ki * ts + gains.kd / ts
    G1 = gains.kp + 2.0 * gains.kd / ts
    G2 = gains.kd / ts
    out = np.empty((n_steps, model.n_u))
    for s in range(n_steps):
        x = model.A @ x + model.B @ u
        e = r_dev - model.C @ x
        u = u + G0 @ e - G1 @ e1 + G2 @ e2
        e2, e1 = e1, e
        out[s] = u
    return out + model.u_op


def input_bound_violation(
    u: ArrayLike,
    u_min: ArrayLike,
    u_max: ArrayLike,
    *,
    allow_above: ArrayLike | None = None,
    allow_below: ArrayLike | None = None,
) -> float:
    """Peak excursion of ``u`` (shape (n_steps, n_u)) beyond ``[u_min, u_max]``, per input range.

    ``max_{s,i} max(u_si - u_max_i, u_min_i - u_si, 0) / (u_max_i - u_min_i)``; 0 when inside.
    ``allow_above`` / ``allow_below`` (bool, shape (n_u,)) exempt input i's excursions above
    ``u_max_i`` / below ``u_min_i`` (the side where the teaching MPC is itself pinned).
    """
    ua = np.asarray(u, dtype=np.float64)
    lo = np.asarray(u_min, dtype=np.float64)
    hi = np.asarray(u_max, dtype=np.float64)
    above = ua - hi
    below = lo - ua
    if allow_above is not None:
        above = np.where(np.asarray(allow_above, dtype=bool), 0.0, above)
    if allow_below is not None:
        below = np.where(np.asarray(allow_below, dtype=bool), 0.0, below)
    excess = np.maximum(np.maximum(above, below), 0.0) / (hi - lo)
    return float(excess.max()) if excess.size else 0.0


# --------------------------------------------------------------------------- the adapter
@dataclass
class _Reading:
    scan: int
    e: FloatArray  # (n_loops,)
    sp: FloatArray  # (n_loops,)
    mv: FloatArray  # (n_u,)
    x: FloatArray  # (n_x,)


@dataclass
class _HorizonState:
    x: FloatArray
    u: FloatArray
    e: FloatArray
    e_prev: FloatArray
    r: FloatArray
    mpc_at_max: NDArray[np.bool_]  # the MPC's input of that scan sat at u_max (per pump)
    mpc_at_min: NDArray[np.bool_]


@dataclass
class _Counters:
    formed: int = 0
    gap: int = 0
    invalid: int = 0
    duplicates: int = 0
    accepted: int = 0
    rejected: int = 0
    by_reason: dict[str, int] = field(default_factory=dict)
    last_reject: RejectReason | None = None


class PidGainAdapter:
    """MPC-taught PID gains for every pump, with admissibility guards (see the module doc).

    Call :meth:`observe` once per PLC scan with the readings of that scan (SP, PV, MV and the scan
    counter read together, and the MPC's input computed from the same state), and
    :meth:`propose` with the model time; a returned, accepted :class:`Decision` carries the gain
    set to push (the adapter then takes it as applied; call :meth:`set_applied` if the PLC
    refused it or holds other gains).

    Parameters
    ----------
    model : LoopModel
        ZOH linear model with the loops' output matrix and input bounds.
    fixed : PidGains
        The PLC's fixed gains, shape (n_u, n_loops): initial estimate and applied gains. Must pass
        the box and sign guards.
    config : AdaptationConfig, optional
        Defaults as documented there.

    Raises
    ------
    ValueError
        On inconsistent shapes, fixed gains outside the box or violating the sign guard, a box
        that excludes the sign guard's region, or an invalid ``own_loop``.
    """

    def __init__(self, model: LoopModel, fixed: PidGains, config: AdaptationConfig | None = None) -> None:
        if not isinstance(model, LoopModel):
            raise TypeError("model must be a LoopModel")
        if not isinstance(fixed, PidGains):
            raise TypeError("fixed must be PidGains")
        cfg = AdaptationConfig() if config is None else config
        self._model = model
        self._cfg = cfg
        m, nl = model.n_u, model.n_loops
        if fixed.shape != (m, nl):
            raise ValueError(f"fixed gains must have shape (n_u, n_loops) = {(m, nl)}, got {fixed.shape}")
        if not fixed.is_finite():
            raise ValueError("fixed gains must be finite")

        if cfg.own_loop is None:
            if m > nl:
                raise ValueError("own_loop must be given when there are more pumps than loops")
            own = tuple(range(m))
        else:
            own = tuple(int(j) for j in cfg.own_loop)
            if len(own) != m or any(not 0 <= j < nl for j in own):
                raise ValueError(f"own_loop must give one loop index in [0, {nl}) per pump ({m})")
        self._own = own
        # Loops each pump's RLS uses.
        self._loops: tuple[tuple[int, ...], ...] = tuple(
            tuple(range(nl)) if cfg.full_mimo else (own[i],) for i in range(m)
        )
        self._own_mask = np.zeros((m, nl), dtype=bool)
        self._own_mask[np.arange(m), own] = True
        self._adapt_mask = np.zeros((m, nl), dtype=bool)
        for i, loops in enumerate(self._loops):
            self._adapt_mask[i, list(loops)] = True

        g_fixed = fixed.stacked()  # (3, m, nl)
        row_scale = np.abs(g_fixed).max(axis=2, keepdims=True)  # (3, m, 1)

        # ki_min per pump
        if cfg.ki_min is None:
            ki_min = 0.1 * fixed.ki[np.arange(m), own]
        else:
            ki_min = np.broadcast_to(np.asarray(cfg.ki_min, dtype=np.float64), (m,)).copy()
        if not (np.isfinite(ki_min).all() and (ki_min > 0).all()):
            raise ValueError("ki_min must be finite and > 0 for every pump (the own-loop Ki must be > 0)")
        self._ki_min = ki_min

        # Gain box
        if cfg.box is None:
            bound = 10.0 * np.broadcast_to(row_scale, g_fixed.shape)
            lo = np.where(self._adapt_mask, -bound, g_fixed)
            hi = np.where(self._adapt_mask, bound, g_fixed)
            box = GainBox(PidGains.from_stacked(lo), PidGains.from_stacked(hi))
        else:
            box = cfg.box
            if box.lower.shape != (m, nl):
                raise ValueError(f"box must have shape {(m, nl)}, got {box.lower.shape}")
        self._box = box
        if not box.contains(fixed):
            raise ValueError("fixed gains must lie inside the gain box")
        sign_ok, detail = self._sign_ok(fixed)
        if not sign_ok:
            raise ValueError(f"fixed gains violate the sign guard: {detail}")

        # Projection bounds in physical units = box intersected with the sign region.
        lo_phys = box.lower.stacked().copy()
        lo_phys[0][self._own_mask] = np.maximum(lo_phys[0][self._own_mask], 0.0)
        own_ki_lo = lo_phys[1][np.arange(m), own]
        lo_phys[1][np.arange(m), own] = np.maximum(own_ki_lo, ki_min)
        hi_phys = box.upper.stacked().copy()
        if cfg.kd_keep_sign:
            # Kd between 0 and its fixed value (ADR 0014): it may shrink to 0, never flip sign.
            kd_f = g_fixed[2]
            keep = self._own_mask
            lo_phys[2][keep] = np.maximum(lo_phys[2][keep], np.minimum(kd_f[keep], 0.0))
            hi_phys[2][keep] = np.minimum(hi_phys[2][keep], np.maximum(kd_f[keep], 0.0))
        if (lo_phys > hi_phys).any():
            raise ValueError("the gain box leaves no room for the sign guard (Kp >= 0, Ki >= ki_min)")
        self._lo_phys, self._hi_phys = lo_phys, hi_phys

        # The model-based tuning: the prior of the estimator (and the nodes' reference).
        tau_c = cfg.prior_closed_loop_s if cfg.prior_closed_loop_s is not None else 4.0 * model.ts_s
        prior_g = model_based_gains(model, own, tau_c).stacked()
        prior_g = np.where(self._own_mask, prior_g, g_fixed)  # cross gains: the fixed ones
        prior_g = np.clip(prior_g, lo_phys, hi_phys)
        self._prior = PidGains.from_stacked(prior_g)

        # Rate-limit floor
        frac = cfg.max_change_fraction
        if cfg.change_floor is None:
            floor = frac * 0.1 * np.broadcast_to(row_scale, g_fixed.shape)
            if cfg.estimator == "prior":
                # A gain's natural scale is the larger of its fixed and its model-based value: a
                # push may move it by max_change_fraction of that scale, or of its applied value.
                natural = np.maximum(np.abs(prior_g), np.abs(g_fixed)) * self._adapt_mask
                floor = np.maximum(floor, frac * natural)
        else:
            if cfg.change_floor.shape != (m, nl):
                raise ValueError(f"change_floor must have shape {(m, nl)}")
            floor = cfg.change_floor.stacked()
            if not (np.isfinite(floor).all() and (floor >= 0).all()):
                raise ValueError("change_floor must be finite and >= 0")
        self._floor = np.array(floor, dtype=np.float64)

        # One estimator per pump on dimensionless parameters.
        ts = model.ts_s
        lam = ExpForgettingRls.forgetting_from_memory(ts, cfg.memory_s)
        E = cfg.error_scale
        self._scale: list[FloatArray] = []
        self._rls: list[ExpForgettingRls | PriorRls] = []
        for i in range(m):
            U = float(model.u_max[i] - model.u_min[i])
            per_loop = np.array([E / U, ts * E / U, E / (ts * U)])
            s = np.tile(per_loop, len(self._loops[i]))
            self._scale.append(s)
            lower = self._pack(lo_phys, i) * s
            upper = self._pack(hi_phys, i) * s
            if cfg.estimator == "prior":
                theta_p = self._pack(prior_g, i) * s
                # Prior scale per parameter: the larger of the prior's and the fixed gain's size,
                # floored at a tenth of the row's scale of that gain type and at a tenth of the
                # pump's largest (the dimensionless parameters are comparable): a zero Kd with a
                # zero fixed Kd still has a scale.
                sigma = np.maximum.reduce(
                    [
                        np.abs(theta_p),
                        np.abs(self._pack(g_fixed, i) * s),
                        self._pack(0.1 * np.broadcast_to(row_scale, g_fixed.shape), i) * s,
                    ]
                )
                sigma = np.maximum(sigma, max(0.1 * float(sigma.max()), 1e-12))
                self._rls.append(
                    PriorRls(
                        theta_p,
                        cfg.prior_weight / sigma**2,
                        forgetting=lam,
                        excitation_threshold=cfg.excitation_threshold,
                        lower=lower,
                        upper=upper,
                    )
                )
            else:
                self._rls.append(
                    ExpForgettingRls(
                        s.size,
                        forgetting=lam,
                        p0=cfg.p0,
                        theta0=self._pack(g_fixed, i) * s,
                        trace_cap=cfg.trace_cap,
                        excitation_threshold=cfg.excitation_threshold,
                        lower=lower,
                        upper=upper,
                    )
                )

        self._fixed = fixed
        self._applied = fixed
        self._natural = np.maximum(np.abs(prior_g), np.abs(g_fixed))
        self._noise_lambda = ExpForgettingRls.forgetting_from_memory(ts, _NOISE_MEMORY_FACTOR * cfg.memory_s)
        self._kp_noise: list[float | None] = [None] * m
        self._noise_acc = np.zeros(nl)  # sum of lambda^age d^2 / 6
        self._noise_weight = 0.0  # sum of lambda^age (the same weights: no start-up bias)
        self._noise_n = 0
        self._eps_prev: FloatArray | None = None
        self._history: list[_Reading] = []
        self._after_gap = False
        self._last_scan: int | None = None
        self._horizon: _HorizonState | None = None
        self._t_start: float | None = None
        self._t_last_proposal: float | None = None
        self._counters = _Counters()
        self._saturated = [0] * m
        self._one_sided = [0] * m
        self._last_decision: Decision | None = None

    # ------------------------------------------------------------------ packing
    def _pack(self, g: FloatArray, i: int) -> FloatArray:
        """Pump i's parameters ``[Kp_ij, Ki_ij, Kd_ij for j in its loops]`` from (3, m, nl)."""
        return np.concatenate([g[:, i, j] for j in self._loops[i]])

    def _unpack_into(self, g: FloatArray, i: int, theta: FloatArray) -> None:
        for k, j in enumerate(self._loops[i]):
            g[:, i, j] = theta[3 * k : 3 * k + 3]

    # ------------------------------------------------------------------ properties
    @property
    def model(self) -> LoopModel:
        """The linear model the guards use."""
        return self._model

    @property
    def config(self) -> AdaptationConfig:
        """The settings."""
        return self._cfg

    @property
    def applied(self) -> PidGains:
        """Gains the adapter believes the PLC applies (rate-limit reference)."""
        return self._applied

    @property
    def fixed(self) -> PidGains:
        """The PLC's fixed gains."""
        return self._fixed

    @property
    def box(self) -> GainBox:
        """The gain box in force (the configured one or the default)."""
        return self._box

    @property
    def change_floor(self) -> PidGains:
        """The rate limit's absolute floor in force per gain (configured, or the default)."""
        return PidGains.from_stacked(self._floor)

    @property
    def ki_min(self) -> FloatArray:
        """Own-loop Ki lower bound per pump, shape (n_u,)."""
        return self._ki_min.copy()

    @property
    def last_decision(self) -> Decision | None:
        """The last decision taken by :meth:`propose` or :meth:`submit`."""
        return self._last_decision

    def _ready(self, i: int) -> bool:
        """Pump i's estimate has absorbed as many informative samples as it has parameters.

        Informative: an applied RLS update, or a one-sided correction that moved the estimate.
        """
        rls = self._rls[i]
        if isinstance(rls, PriorRls):
            return True  # its estimate starts at the model-based tuning, usable from the start
        return rls.n_updates + rls.n_constrained >= rls.n_params

    def estimate(self) -> PidGains:
        """Current RLS estimates as gains (entries a pump does not fit: the applied values)."""
        g = self._applied.stacked().copy()
        for i, rls in enumerate(self._rls):
            self._unpack_into(g, i, rls.theta / self._scale[i])
        return PidGains.from_stacked(g)

    def _box_distance(self, g: FloatArray, i: int) -> FloatArray:
        """Fraction of the box width from each of pump i's gains (packed) to the nearest limit."""
        lo = self._pack(self._box.lower.stacked(), i)
        hi = self._pack(self._box.upper.stacked(), i)
        width = hi - lo
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.minimum(g - lo, hi - g) / width
        return np.where(width > 0.0, np.clip(d, 0.0, 0.5), math.nan)

    def _health(self, i: int) -> tuple[float, float]:
        """Pump i's (excitation, condition number) of its information matrix."""
        rls = self._rls[i]
        if isinstance(rls, PriorRls):
            return rls.excitation, rls.condition_number
        w = np.linalg.eigvalsh(rls.covariance)
        return float(1.0 / w[-1]), float(w[-1] / w[0])

    def on_box_limit(self, i: int) -> bool:
        """Pump i's estimate or applied gains sit on a limit of the gain box.

        A gain is on a limit when it is within ``box_limit_fraction`` of the smaller of the box
        width and the gain's natural scale (the larger of its fixed and model-based values) from
        it: a Ki of 6.5e-6 in a box [0, 1e-3] is 0.65 % of the width from 0, yet three times its
        tolerance (0.01 x 1.9e-4) away, and not decided by the box.
        """
        lo = self._pack(self._box.lower.stacked(), i)
        hi = self._pack(self._box.upper.stacked(), i)
        natural = self._pack(self._natural, i)
        tol = self._cfg.box_limit_fraction * np.minimum(hi - lo, natural)
        adapted = (hi - lo) > 0.0
        for g in (self._rls[i].theta / self._scale[i], self._pack(self._applied.stacked(), i)):
            near = (np.abs(g - lo) <= tol) | (np.abs(hi - g) <= tol)
            if (near & adapted).any():
                return True
        return False

    @property
    def prior(self) -> PidGains:
        """The model-based tuning (:func:`model_based_gains`, clipped into the box and sign region)."""
        return self._prior

    def diagnostics(self) -> AdapterDiagnostics:
        """Counters and per-pump estimator state (for the ``Supervisor.RLS.*`` nodes)."""
        pumps = []
        for i, rls in enumerate(self._rls):
            theta = rls.theta / self._scale[i]
            excitation, cond = self._health(i)
            pumps.append(
                PumpDiagnostics(
                    theta=theta,
                    covariance_trace=rls.trace,
                    samples_used=rls.n_updates,
                    skipped_unexcited=rls.n_skipped_unexcited,
                    skipped_nonfinite=rls.n_skipped_nonfinite,
                    dropped_saturated=self._saturated[i],
                    one_sided_updates=self._one_sided[i],
                    ready=self._ready(i),
                    excitation=excitation,
                    condition_number=cond,
                    box_distance=self._box_distance(theta, i),
                    on_box_limit=self.on_box_limit(i),
                    prior=self._pack(self._prior.stacked(), i),
                )
            )
        c = self._counters
        return AdapterDiagnostics(
            pumps=tuple(pumps),
            samples_formed=c.formed,
            dropped_gap=c.gap,
            dropped_invalid=c.invalid,
            duplicates=c.duplicates,
            accepted_pushes=c.accepted,
            rejected_pushes=c.rejected,
            rejected_by_reason=dict(c.by_reason),
            last_reject_reason=c.last_reject,
            applied=self._applied,
        )

    # ------------------------------------------------------------------ data
    def observe(
        self,
        *,
        scan: int,
        t_s: float,
        sp: ArrayLike,
        pv: ArrayLike,
        mv: ArrayLike,
        u_mpc: ArrayLike,
        x: ArrayLike | None = None,
    ) -> SampleStatus:
        """Take one PLC scan's readings and, when three contiguous scans exist, learn from them.

        Parameters
        ----------
        scan : int
            PLC scan counter of the scan SP, PV and MV were read from (one Read).
        t_s : float
            Model time [s].
        sp, pv : array_like, shape (n_loops,)
            Setpoints and PVs exactly as the PLC's PID used them; ``e = sp - pv``.
        mv : array_like, shape (n_u,)
            Applied (clamped) pump outputs of that scan.
        u_mpc : array_like, shape (n_u,)
            MPC input for this scan, computed from the same measured state. A non-finite entry
            (MPC failure) skips that pump's update (counted by its RLS).
        x : array_like, shape (n_x,), optional
            Full measured state (every level) for the input-bound simulation; by default the
            unmeasured states are set to their operating values:
            ``x = x_op + pinv(C) (pv - C x_op)``.

        Returns
        -------
        SampleStatus
        """
        if isinstance(scan, bool) or not isinstance(scan, (int, np.integer)):
            raise TypeError(f"scan must be an int, got {type(scan).__name__}")
        scan = int(scan)
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError("t_s must be finite")
        model = self._model
        nl, m = model.n_loops, model.n_u
        sp_v = _matrix(sp, "sp", (nl,))
        pv_v = _matrix(pv, "pv", (nl,))
        mv_v = _matrix(mv, "mv", (m,))
        um_v = _matrix(u_mpc, "u_mpc", (m,))
        if self._t_start is None:
            self._t_start = t

        if self._last_scan is not None and scan == self._last_scan:
            self._counters.duplicates += 1
            return SampleStatus.DUPLICATE
        self._last_scan = scan

        if x is None:
            x_v = model.x_op + np.linalg.pinv(model.C) @ (pv_v - model.C @ model.x_op)
        else:
            x_v = _matrix(x, "x", (model.n_x,))
        if not (np.isfinite(sp_v).all() and np.isfinite(pv_v).all() and np.isfinite(mv_v).all()):
            self._history.clear()
            self._after_gap = True
            self._eps_prev = None
            self._counters.invalid += 1
            return SampleStatus.INVALID

        reading = _Reading(scan=scan, e=sp_v - pv_v, sp=sp_v, mv=mv_v, x=x_v)
        if self._history and scan != self._history[-1].scan + 1:
            self._history.clear()
            self._after_gap = True
            self._eps_prev = None
        self._history.append(reading)
        if len(self._history) > 3:
            del self._history[0]
        if len(self._history) < 3:
            # The window [k-2, k] is incomplete: at the very start that is warm-up; after a gap in
            # the scan counter (or an invalid reading) the window spans it and the sample is dropped.
            if self._after_gap:
                self._counters.gap += 1
                return SampleStatus.GAP
            return SampleStatus.WARMUP
        self._after_gap = False

        r0, r1, r2 = self._history[-1], self._history[-2], self._history[-3]
        self._counters.formed += 1
        self._track_noise(r0, r1)
        band = self._cfg.saturation_band * (model.u_max - model.u_min)
        if np.isfinite(x_v).all():
            with np.errstate(invalid="ignore"):
                mpc_at_max = np.isfinite(um_v) & (um_v >= model.u_max - band)
                mpc_at_min = np.isfinite(um_v) & (um_v <= model.u_min + band)
            self._horizon = _HorizonState(
                x=x_v, u=r0.mv, e=r0.e, e_prev=r1.e, r=r0.sp, mpc_at_max=mpc_at_max, mpc_at_min=mpc_at_min
            )
        ts = model.ts_s
        de = r0.e - r1.e
        d2e = r0.e - 2.0 * r1.e + r2.e
        for i, rls in enumerate(self._rls):
            loops = list(self._loops[i])
            psi = np.column_stack([de[loops], ts * r0.e[loops], d2e[loops] / ts]).ravel()
            y = float(um_v[i] - r1.mv[i])
            U = float(model.u_max[i] - model.u_min[i])
            x_hat = psi / (U * self._scale[i])
            at_max = math.isfinite(um_v[i]) and um_v[i] >= model.u_max[i] - band[i]
            at_min = math.isfinite(um_v[i]) and um_v[i] <= model.u_min[i] + band[i]
            mode = self._cfg.saturated
            if (at_max or at_min) and mode != "equality":
                if mode == "drop":
                    self._saturated[i] += 1
                    continue
                # One-sided (module doc): the MPC pinned at u_max wants at least u_MPC, so the
                # PID's move from the applied input must be at least y (at most y at u_min). A
                # consistent estimate learns nothing; a violating one is projected onto psi' theta
                # = y in the metric of P^-1, with P untouched (an inequality is not a measurement).
                if rls.constrain(x_hat, y / U, "ge" if at_max else "le"):
                    self._one_sided[i] += 1
                else:
                    self._saturated[i] += 1
                continue
            rls.update(x_hat, y / U)
        return SampleStatus.FORMED

    def _track_noise(self, r0: _Reading, r1: _Reading) -> None:
        """Update the transmitter-noise estimate from the model's one-step prediction errors.

        ``eps(k) = C x(k) - C [x_op + A (x(k-1) - x_op) + B (u(k-1) - u_op)]`` per loop; model
        errors are smooth, so their difference ``d(k) = eps(k) - eps(k-1)`` is mostly noise:
        for white transmitter noise of standard deviation sigma on every level, ``var d`` is about
        ``6 sigma^2`` (own tank; the couplings add less than 1 %). ``sigma^2`` is the exponentially
        weighted mean of ``d^2 / 6`` over ``10 memory_s`` with the start-up bias removed; a sample
        beyond 5 sigma of the current estimate (a step, a leak opening) is clipped there.
        """
        model = self._model
        if not (np.isfinite(r0.x).all() and np.isfinite(r1.x).all()):
            self._eps_prev = None
            return
        pred = model.x_op + model.A @ (r1.x - model.x_op) + model.B @ (r1.mv - model.u_op)
        eps = model.C @ (r0.x - pred)
        prev, self._eps_prev = self._eps_prev, eps
        if prev is None:
            return
        d2 = (eps - prev) ** 2 / 6.0
        lam = self._noise_lambda
        if self._noise_n >= 10:
            d2 = np.minimum(d2, 25.0 * self.noise_std() ** 2)
        self._noise_acc = lam * self._noise_acc + d2
        self._noise_weight = lam * self._noise_weight + 1.0
        self._noise_n += 1

    def noise_std(self) -> FloatArray:
        """Estimated transmitter noise per loop [error unit], shape (n_loops,); 0 before data."""
        if self._noise_n == 0:
            return np.zeros(self._model.n_loops)
        return np.sqrt(self._noise_acc / self._noise_weight)

    def _update_noise_limit(self) -> None:
        """From the noise estimate: each pump's loop-gain limit (with hysteresis) and dead zone.

        Transmitter noise of standard deviation ``sigma`` moves a PI's output by about
        ``sqrt(2) Kp sigma`` rms per scan, so ``Kp <= kp_noise = budget U / (sqrt(2) sigma)`` keeps
        the noise-driven moves within ``noise_move_budget`` of the range ``U``; :meth:`propose`
        scales a pump's whole own-loop target (Kp, Ki, Kd) down to it (the loop gain, not the
        PID's shape). The limit engages below ``Kp_model / 1.2``, releases above ``Kp_model x 1.2``
        and moves only when it changes by more than 20 %, so that the scatter of the estimate (a
        few %) does not make the gains wander. The dead zone becomes at least ``17 sigma / E``.
        """
        budget = self._cfg.noise_move_budget
        if self._noise_n < 10:
            return
        model = self._model
        sigma = self.noise_std()
        base = self._prior.stacked()
        band = 1.0 + _NOISE_HYSTERESIS
        for i, j in enumerate(self._own):
            U = float(model.u_max[i] - model.u_min[i])
            kp = float(base[0, i, j])
            if budget is None or sigma[j] <= 0.0 or kp <= 0.0:
                continue
            kp_noise = budget * U / (math.sqrt(2.0) * float(sigma[j]))
            held = self._kp_noise[i]
            if held is None:
                if kp_noise < kp / band:
                    held = kp_noise
            elif kp_noise > kp * band:
                held = None
            elif abs(math.log(kp_noise / held)) > math.log(band):
                held = kp_noise
            self._kp_noise[i] = held
        for i, rls in enumerate(self._rls):
            if isinstance(rls, PriorRls):
                # Dead zone sized to the noise (docs/adaptation.md 2.7: about 17 sigma / E, the
                # regressor's noise-driven change being about 5.3 sigma / E rms): noise alone does
                # not adapt (measured: 0.5 mm pulled Ki1 below its fixed value without this).
                sigma_i = float(sigma[list(self._loops[i])].max())
                rls.set_excitation_threshold(
                    max(self._cfg.excitation_threshold, _NOISE_DEAD_ZONE * sigma_i / self._cfg.error_scale)
                )

    @property
    def noise_gain_limit(self) -> FloatArray:
        """Each pump's own-loop Kp limit from the noise [pump unit / error unit] (inf: none)."""
        return np.array([math.inf if v is None else v for v in self._kp_noise])

    # ------------------------------------------------------------------ guards
    def _sign_ok(self, gains: PidGains) -> tuple[bool, str]:
        m = self._model.n_u
        idx = (np.arange(m), np.asarray(self._own))
        kp_own = gains.kp[idx]
        ki_own = gains.ki[idx]
        for i in range(m):
            if not kp_own[i] >= 0.0:
                return False, f"Kp[{i},{self._own[i]}] = {kp_own[i]:.6g} < 0"
            if not ki_own[i] >= self._ki_min[i]:
                return False, f"Ki[{i},{self._own[i]}] = {ki_own[i]:.6g} < Ki_min = {self._ki_min[i]:.6g}"
        return True, ""

    def _step_limit(self, applied: FloatArray) -> FloatArray:
        return np.maximum(self._cfg.max_change_fraction * np.abs(applied), self._floor)

    def evaluate(self, candidate: PidGains, t_s: float = math.nan) -> Decision:
        """Judge ``candidate`` against every guard, without side effects.

        Guards (all evaluated; ``reasons`` lists every failure in this order):

        * ``non_finite``: every gain finite (if not, nothing else is evaluated);
        * ``outside_box``: ``box.lower <= g <= box.upper`` element-wise;
        * ``sign``: own-loop ``Kp_i >= 0`` and ``Ki_i >= Ki_min,i > 0``;
        * ``rate_limit``: ``|g - g_applied| <= max(max_change_fraction |g_applied|, floor)``;
        * ``unstable``: ``rho(M(candidate)) < max_spectral_radius`` (:func:`closed_loop_matrix`);
        * ``input_bounds``: :func:`simulate_pid_inputs` from the current state (last formed
          sample: measured state, applied MV, the PID's last two errors, setpoints held) over
          ``horizon_steps``; the peak excursion beyond ``[u_min, u_max]`` (fraction of range)
          must be 0, or, when the applied gains' own simulation already leaves the bounds (a large
          setpoint error that saturates any sensible gains), no larger than theirs. Excursions of
          pump i above ``u_max`` (below ``u_min``) are not counted when the MPC's input of that
          sample sat at ``u_max`` (``u_min``): the teacher saturates there itself. Skipped
          (``input_violation`` NaN) before the first formed sample.

        Parameters
        ----------
        candidate : PidGains
            Shape (n_u, n_loops).
        t_s : float, optional
            Model time recorded in the decision [s].
        """
        model = self._model
        if candidate.shape != (model.n_u, model.n_loops):
            raise ValueError(f"candidate must have shape {(model.n_u, model.n_loops)}, got {candidate.shape}")
        changed = not candidate.allclose(self._applied, rtol=0.0)
        if not candidate.is_finite():
            return Decision(
                t_s,
                candidate,
                False,
                (RejectReason.NON_FINITE,),
                "a gain is not finite",
                math.nan,
                math.nan,
                changed,
            )
        reasons: list[RejectReason] = []
        details: list[str] = []
        g = candidate.stacked()
        lo, hi = self._box.lower.stacked(), self._box.upper.stacked()
        outside = (g < lo) | (g > hi)
        if outside.any():
            t, i, j = (int(v) for v in np.argwhere(outside)[0])
            reasons.append(RejectReason.OUTSIDE_BOX)
            details.append(
                f"{_GAIN_NAMES[t]}[{i},{j}] = {g[t, i, j]:.6g} outside [{lo[t, i, j]:.6g}, {hi[t, i, j]:.6g}]"
            )
        sign_ok, sign_detail = self._sign_ok(candidate)
        if not sign_ok:
            reasons.append(RejectReason.SIGN)
            details.append(sign_detail)
        a = self._applied.stacked()
        limit = self._step_limit(a)
        too_fast = np.abs(g - a) > limit * (1.0 + _REL_TOL)
        if too_fast.any():
            t, i, j = (int(v) for v in np.argwhere(too_fast)[0])
            reasons.append(RejectReason.RATE_LIMIT)
            step = g[t, i, j] - a[t, i, j]
            details.append(f"{_GAIN_NAMES[t]}[{i},{j}] changes by {step:.6g}, limit {limit[t, i, j]:.6g}")
        rho = closed_loop_spectral_radius(
            model.A, model.B, model.C, candidate.kp, candidate.ki, candidate.kd, model.ts_s
        )
        if not rho < self._cfg.max_spectral_radius:
            reasons.append(RejectReason.UNSTABLE)
            details.append(f"spectral radius {rho:.6f} >= {self._cfg.max_spectral_radius}")
        violation = math.nan
        hs = self._horizon
        if hs is not None:
            kwargs = {"x0": hs.x, "u0": hs.u, "e0": hs.e, "e_prev": hs.e_prev, "r": hs.r}
            n = self._cfg.horizon_steps
            allow = {"allow_above": hs.mpc_at_max, "allow_below": hs.mpc_at_min}
            violation = input_bound_violation(
                simulate_pid_inputs(model, candidate, n_steps=n, **kwargs), model.u_min, model.u_max, **allow
            )
            if violation > 0.0:
                reference = input_bound_violation(
                    simulate_pid_inputs(model, self._applied, n_steps=n, **kwargs),
                    model.u_min,
                    model.u_max,
                    **allow,
                )
                if violation > reference * (1.0 + _REL_TOL):
                    reasons.append(RejectReason.INPUT_BOUNDS)
                    details.append(
                        f"simulated input leaves its bounds by {violation:.4g} of its range "
                        f"(applied gains: {reference:.4g})"
                    )
        return Decision(
            t_s,
            candidate,
            not reasons,
            tuple(reasons),
            details[0] if details else "",
            rho,
            violation,
            changed,
        )

    def submit(self, candidate: PidGains, t_s: float = math.nan) -> Decision:
        """Judge ``candidate`` (:meth:`evaluate`), count the outcome, and take it as applied if accepted.

        A rejected candidate leaves the applied gains untouched.
        """
        decision = self.evaluate(candidate, t_s)
        c = self._counters
        if decision.accepted:
            c.accepted += 1
            self._applied = decision.candidate
        else:
            c.rejected += 1
            for reason in decision.reasons:
                c.by_reason[reason.value] = c.by_reason.get(reason.value, 0) + 1
            c.last_reject = decision.reason
        self._last_decision = decision
        return decision

    def set_applied(self, gains: PidGains) -> None:
        """Record the gains the PLC really applies (after a refused push, or read back)."""
        if gains.shape != (self._model.n_u, self._model.n_loops):
            raise ValueError(f"gains must have shape {(self._model.n_u, self._model.n_loops)}")
        if not gains.is_finite():
            raise ValueError("gains must be finite")
        self._applied = gains

    def propose(self, t_s: float) -> Decision | None:
        """Propose, judge and count a candidate gain set when one is due.

        A candidate is due when ``t_s`` is at least ``min_time_s`` after the first reading, at least
        one pump's RLS has applied as many updates as it has parameters, and ``push_period_s`` has
        passed since the previous proposal. Each ready pump moves from its applied gains along the
        straight line toward its RLS estimate, ``g = g_applied + alpha (g_estimate - g_applied)``
        with the largest ``alpha <= 1`` that keeps every one of its gains inside the rate limit;
        other pumps keep their applied gains.

        Parameters
        ----------
        t_s : float
            Model time [s].

        Returns
        -------
        Decision or None
            None when no candidate is due; otherwise the decision (accepted: push
            ``decision.candidate``).
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError("t_s must be finite")
        if self._t_start is None or t - self._t_start < self._cfg.min_time_s - 1e-9:
            return None
        ready = [self._ready(i) for i in range(len(self._rls))]
        if not any(ready):
            return None
        period = self._cfg.push_period_s
        if self._t_last_proposal is not None and t - self._t_last_proposal < period - 1e-9 * max(1.0, period):
            return None
        self._update_noise_limit()
        a = self._applied.stacked()
        target = a.copy()
        for i, rls in enumerate(self._rls):
            if ready[i]:
                self._unpack_into(target, i, rls.theta / self._scale[i])
        # The noise limit scales a pump's whole own-loop PID (the loop gain, not its shape): the
        # MPC teaches its own reaction to the noise (measured: Kp1 2.2e-3 learned under 0.5 mm).
        for i, j in enumerate(self._own):
            held = self._kp_noise[i]
            if ready[i] and held is not None and target[0, i, j] > held:
                target[:, i, j] *= held / target[0, i, j]
        limit = self._step_limit(a)
        # Move toward the estimate, as far as the rate limit lets every gain of the pump go, along
        # one path per pump (direction-preserving). Clipping each gain on its own bends the path,
        # and a bent path between two admissible sets can cross unstable ones (measured: the
        # Energies run froze at the stability margin that way, see docs/adaptation.md).
        candidate = a.copy()
        for i in range(self._model.n_u):
            candidate[:, i, :] = self._path_step(a[:, i, :], target[:, i, :], limit[:, i, :])
        self._t_last_proposal = t
        return self.submit(PidGains.from_stacked(candidate), t)

    def _path_step(self, a: FloatArray, target: FloatArray, limit: FloatArray) -> FloatArray:
        """One pump's step from ``a`` toward ``target`` (shape (3, n_loops)) under ``limit``.

        ``linear``: ``g = a + alpha (target - a)``. ``geometric``: gains whose applied value and
        target are non-zero and of one sign move as ``g = a (target / a)^alpha`` (a straight line
        in log space: every such gain covers the same fraction of its log-distance), the others
        linearly; ``alpha <= 1`` is the largest step that keeps every gain inside its limit
        ``|g - a| <= limit``: ``alpha |ln(target / a)| <= ln(1 + limit / |a|)`` upward,
        ``<= -ln(1 - limit / |a|)`` downward, ``alpha |target - a| <= limit`` on the linear part.
        """
        delta = target - a
        moving = delta != 0.0
        if not moving.any():
            return a.copy()
        geometric = np.zeros(a.shape, dtype=bool)
        if self._cfg.path == "geometric":
            geometric = moving & (a * target > 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_d = np.where(geometric, np.log(np.where(geometric, target / a, 1.0)), 0.0)
            rel = np.where(geometric, limit / np.abs(a), 0.0)
            up = np.log1p(rel)
            down = -np.log1p(-np.minimum(rel, 1.0 - 1e-12))
            room = np.where(log_d > 0.0, up, down)
            alphas = np.where(geometric, room / np.abs(log_d), limit / np.abs(delta))
        alpha = min(1.0, float(alphas[moving].min()))
        if alpha >= 1.0:
            return target.copy()
        with np.errstate(over="ignore", invalid="ignore"):
            g_geo = a * np.exp(alpha * log_d)
        return np.where(geometric, g_geo, a + alpha * delta)
