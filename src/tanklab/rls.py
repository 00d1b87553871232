"""Exponentially weighted recursive least squares with the guards closed-loop use needs.

Model and update (seeds digest 2.3), for a regressor ``x(t)`` of shape (n,) and a scalar target
``y(t)``; ``beta`` has the units of ``y`` per unit of each regressor entry, ``P`` those of
``beta`` squared (it is the parameter covariance up to the noise variance)::

    y(t)    = x(t)' beta + noise
    e(t)    = y(t) - x(t)' beta(t-1)                          a-priori prediction error
    K(t)    = P(t-1) x(t) / (lambda + x(t)' P(t-1) x(t))       gain, shape (n,)
    beta(t) = beta(t-1) + K(t) e(t)
    P(t)    = (P(t-1) - K(t) x(t)' P(t-1)) / lambda

``lambda`` in (0, 1] is the forgetting factor per sample. Define it per unit time with
:meth:`ExpForgettingRls.forgetting_from_memory`: ``lambda = exp(-Ts / Tmem)``, so that the memory
``Tmem`` [s] does not change when the sample time ``Ts`` [s] does.

The bare recursion is not safe in closed loop: at steady state the regressors stop moving (or
become collinear), ``P`` grows like ``lambda**-t`` along every unexcited direction, and in floating
point it overflows and loses definiteness (digest 2.3 measured trace P = 6e6 within 150 s at
Ts = 0.05 s and an overflow to negative values at Ts = 0.01 s). Every update here therefore goes
through these guards, in this order:

1. **Finite input.** A non-finite ``x`` or ``y`` is skipped and counted; the state is untouched.
2. **Dead zone (no excitation, no adaptation).** The default measure is the Euclidean norm of the
   regressor's change since the last *applied* update, ``||x(t) - x_ref||``; with
   ``excitation="norm"`` it is ``||x(t)||``. A sample whose measure is below
   ``excitation_threshold`` is skipped: neither ``beta`` nor ``P`` changes, in particular ``P`` is
   *not* divided by ``lambda``, so idle periods do not inflate the covariance. With the "change"
   measure the first sample after construction or :meth:`~ExpForgettingRls.reset` has no
   reference: it only sets one and is skipped (when the threshold is positive), so a regressor that
   never moves never adapts anything. Measuring change against the last applied update rather than
   the previous sample makes the threshold independent of the sample rate: a slow drift still
   triggers an update once it has moved far enough.
3. **Symmetry.** ``P`` is replaced by ``(P + P') / 2`` after every update.
4. **Definiteness.** The eigenvalues of ``P`` are floored at ``1e-12`` times the largest one
   (condition number at most 1e12), so rounding can never make ``P`` indefinite.
5. **Bound (trace cap).** When ``trace P`` would exceed ``trace_cap``, ``P`` is *scaled* to the cap:
   ``P <- P * trace_cap / trace P``. Scaling (rather than adding a regularising ``delta I``, which
   raises the trace) keeps the eigenvectors and the relative confidence of the directions, keeps
   ``P`` positive definite and costs one multiply; it is the constant-trace idea applied only when
   the cap binds. The default cap is the initial trace ``n * p0``: the estimator never becomes less
   certain than its prior.
6. **Overflow.** An update whose result is not finite (possible only with the cap disabled through
   ``trace_cap=math.inf``) is skipped and counted; the state is untouched.
7. **Projection.** ``beta`` is clipped to ``[lower, upper]`` element-wise (the Euclidean projection
   onto the box; physical bounds such as ``b >= b_min > 0``).

One-sided information (an inequality ``x' beta >= bound`` or ``<= bound``, e.g. a teacher input
clamped at a bound) goes through :meth:`ExpForgettingRls.constrain` instead: a violating estimate
is projected onto the boundary in the metric of ``P^-1`` and ``P`` is left as it is, since an
inequality bounds the parameters without measuring them. The dead zone does not apply to it (a
violated inequality is informative whatever the regressor's change); the finite-input check and
the projection onto ``[lower, upper]`` do.

This module is pure: no clock, no I/O, no logging.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["ExcitationMeasure", "ExpForgettingRls"]

ExcitationMeasure = Literal["change", "norm"]

#: Eigenvalues of P are kept above this fraction of the largest one (condition number <= 1e12).
#: Far above machine epsilon (2.2e-16), which is where rounding starts to cost definiteness.
_EIG_FLOOR_REL = 1e-12


def _real_scalar(value: object, name: str) -> float:
    """Return ``value`` as a float, raising ``TypeError`` for non-real or boolean values."""
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    return float(value)


def _bound_vector(value: ArrayLike | None, n: int, default: float, name: str) -> NDArray[np.float64]:
    """Broadcast a scalar or (n,) bound to shape (n,), rejecting NaN."""
    if value is None:
        return np.full(n, default)
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got shape {arr.shape}")
    if np.isnan(arr).any():
        raise ValueError(f"{name} must not contain NaN")
    return arr.copy()


class ExpForgettingRls:
    """Recursive least squares with exponential forgetting and the guards listed in the module doc.

    Parameters
    ----------
    n_params : int
        Number of parameters ``n`` (length of ``x`` and ``beta``), at least 1.
    forgetting : float
        Forgetting factor ``lambda`` per sample, in (0, 1]; 1 means no forgetting. Use
        :meth:`forgetting_from_memory` to set it from a memory time.
    p0 : float, default 1e3
        Initial covariance ``P(0) = p0 * I``; finite and > 0. Large means a weak prior.
    theta0 : array_like, shape (n,), optional
        Initial estimate ``beta(0)``; zeros by default. Must lie inside ``[lower, upper]``.
    trace_cap : float, optional
        Upper bound on ``trace P``; default ``n * p0`` (the initial trace). Must be >= ``n * p0``.
        ``math.inf`` disables the cap (only to demonstrate the blow-up; never in a controller).
    excitation_threshold : float, default 0.0
        Dead zone on the excitation measure (units of ``x``); samples whose measure is below it
        are skipped. 0 disables the dead zone.
    lower, upper : float or array_like, shape (n,), optional
        Box the estimate is projected onto after every update; default unbounded (-inf, +inf).
    excitation : {"change", "norm"}, default "change"
        Excitation measure: ``||x(t) - x_ref||`` with ``x_ref`` the regressor of the last applied
        update ("change"), or ``||x(t)||`` ("norm").

    Raises
    ------
    TypeError
        If a numeric argument is not a real number or ``n_params`` is not an int.
    ValueError
        If ``forgetting`` is outside (0, 1], ``p0`` is not finite and positive, ``trace_cap`` is
        below ``n * p0``, ``excitation_threshold`` is negative or not finite, the bounds have the
        wrong shape, contain NaN or cross, or ``theta0`` is not finite or lies outside the bounds.
    """

    def __init__(
        self,
        n_params: int,
        *,
        forgetting: float,
        p0: float = 1e3,
        theta0: ArrayLike | None = None,
        trace_cap: float | None = None,
        excitation_threshold: float = 0.0,
        lower: ArrayLike | None = None,
        upper: ArrayLike | None = None,
        excitation: ExcitationMeasure = "change",
    ) -> None:
        if isinstance(n_params, bool) or not isinstance(n_params, (int, np.integer)):
            raise TypeError(f"n_params must be an int, got {type(n_params).__name__}")
        if n_params < 1:
            raise ValueError(f"n_params must be >= 1, got {n_params}")
        self._n = int(n_params)

        lam = _real_scalar(forgetting, "forgetting")
        if not (0.0 < lam <= 1.0):
            raise ValueError(
                f"forgetting must be in (0, 1] (lambda = exp(-Ts / Tmem)), got {lam!r}; "
                "use ExpForgettingRls.forgetting_from_memory(ts_s, memory_s)"
            )
        self._lambda = lam

        self._p0 = self._check_p0(p0)

        if trace_cap is None:
            cap = self._n * self._p0
        else:
            cap = _real_scalar(trace_cap, "trace_cap")
            if math.isnan(cap) or cap <= 0.0:
                raise ValueError(f"trace_cap must be > 0 (math.inf disables it), got {cap!r}")
        self._trace_cap = cap
        self._check_p0_against_cap(self._p0)

        thr = _real_scalar(excitation_threshold, "excitation_threshold")
        if not math.isfinite(thr) or thr < 0.0:
            raise ValueError(f"excitation_threshold must be finite and >= 0, got {thr!r}")
        self._threshold = thr

        if excitation not in ("change", "norm"):
            raise ValueError(f"excitation must be 'change' or 'norm', got {excitation!r}")
        self._measure: ExcitationMeasure = excitation

        self._lower = _bound_vector(lower, self._n, -math.inf, "lower")
        self._upper = _bound_vector(upper, self._n, math.inf, "upper")
        if (self._lower > self._upper).any():
            raise ValueError("lower must be <= upper for every parameter")
        self._bounded = bool(np.isfinite(self._lower).any() or np.isfinite(self._upper).any())

        self._theta0 = self._check_theta(theta0)

        # State, set by reset().
        self._theta = self._theta0.copy()
        self._P = self._p0 * np.eye(self._n)
        self._x_ref: NDArray[np.float64] | None = None
        self._last_error = math.nan
        self._n_updates = 0
        self._n_unexcited = 0
        self._n_nonfinite = 0
        self._n_constrained = 0
        self.reset()

    # ------------------------------------------------------------------ helpers
    def _check_p0(self, p0: object) -> float:
        value = _real_scalar(p0, "p0")
        if not math.isfinite(value) or value <= 0.0:
            raise ValueError(f"p0 must be finite and > 0, got {value!r}")
        return value

    def _check_p0_against_cap(self, p0: float) -> None:
        if self._n * p0 > self._trace_cap:
            raise ValueError(
                f"trace_cap ({self._trace_cap!r}) must be >= n_params * p0 ({self._n * p0!r}): "
                "the initial covariance may not already exceed the cap"
            )

    def _check_theta(self, theta0: ArrayLike | None) -> NDArray[np.float64]:
        if theta0 is None:
            theta = np.clip(np.zeros(self._n), self._lower, self._upper)
        else:
            theta = np.asarray(theta0, dtype=np.float64).copy()
            if theta.shape != (self._n,):
                raise ValueError(f"theta0 must have shape ({self._n},), got shape {theta.shape}")
        if not np.isfinite(theta).all():
            raise ValueError("theta0 must be finite")
        if (theta < self._lower).any() or (theta > self._upper).any():
            raise ValueError("theta0 must lie inside [lower, upper]")
        return theta

    # ------------------------------------------------------------------ API
    @staticmethod
    def forgetting_from_memory(ts_s: float, memory_s: float) -> float:
        """Forgetting factor for a memory time: ``lambda = exp(-ts_s / memory_s)``.

        Parameters
        ----------
        ts_s : float
            Sample time [s], finite and > 0.
        memory_s : float
            Memory (time constant of the exponential weighting) [s], > 0; ``math.inf`` gives 1.

        Returns
        -------
        float
            ``lambda`` in (0, 1]. Example: Ts = 1 s, Tmem = 60 s gives 0.98347.
        """
        ts = _real_scalar(ts_s, "ts_s")
        mem = _real_scalar(memory_s, "memory_s")
        if not math.isfinite(ts) or ts <= 0.0:
            raise ValueError(f"ts_s must be finite and > 0, got {ts!r}")
        if math.isnan(mem) or mem <= 0.0:
            raise ValueError(f"memory_s must be > 0 (math.inf for no forgetting), got {mem!r}")
        return math.exp(-ts / mem)

    def excitation_of(self, x: ArrayLike) -> float:
        """Excitation measure of regressor ``x`` against the current reference (units of ``x``).

        Returns ``math.inf`` when the "change" measure has no reference yet.
        """
        xv = self._as_regressor(x)
        if self._measure == "norm":
            return float(np.linalg.norm(xv))
        if self._x_ref is None:
            return math.inf
        return float(np.linalg.norm(xv - self._x_ref))

    def _as_regressor(self, x: ArrayLike) -> NDArray[np.float64]:
        xv = np.asarray(x, dtype=np.float64)
        if xv.shape != (self._n,):
            raise ValueError(f"x must have shape ({self._n},), got shape {xv.shape}")
        return xv

    def update(self, x: ArrayLike, y: float) -> bool:
        """Apply one RLS step for regressor ``x`` and target ``y``, through every guard.

        Parameters
        ----------
        x : array_like, shape (n,)
            Regressor.
        y : float
            Target (units of ``x' beta``).

        Returns
        -------
        bool
            True if the update was applied; False if it was skipped (non-finite input or result,
            or not excited). A skipped sample leaves ``beta``, ``P`` and the reference untouched
            (except that the first sample sets the "change" reference).

        Raises
        ------
        ValueError
            If ``x`` does not have shape (n,) (a programming error, not a data fault).
        """
        xv = self._as_regressor(x)
        yv = _real_scalar(y, "y")
        if not (np.isfinite(xv).all() and math.isfinite(yv)):
            self._n_nonfinite += 1
            return False

        if self._threshold > 0.0:
            if self._measure == "change" and self._x_ref is None:
                self._x_ref = xv.copy()
                self._n_unexcited += 1
                return False
            if self.excitation_of(xv) < self._threshold:
                self._n_unexcited += 1
                return False

        P = self._P
        lam = self._lambda
        with np.errstate(over="ignore", invalid="ignore"):
            Px = P @ xv
            denom = lam + float(xv @ Px)
            K = Px / denom
            err = yv - float(xv @ self._theta)
            theta_new = self._theta + K * err
            P_new = (P - np.outer(K, Px)) / lam
            P_new = 0.5 * (P_new + P_new.T)
        if not (np.isfinite(theta_new).all() and np.isfinite(P_new).all()):
            self._n_nonfinite += 1
            return False

        w, V = np.linalg.eigh(P_new)
        if w[-1] <= 0.0:  # cannot happen from a PD P with lambda > 0; refuse rather than guess
            self._n_nonfinite += 1
            return False
        floor = _EIG_FLOOR_REL * w[-1]
        if w[0] < floor:
            w = np.maximum(w, floor)
            P_new = (V * w) @ V.T
            P_new = 0.5 * (P_new + P_new.T)
        trace = float(w.sum())
        if trace > self._trace_cap:
            P_new *= self._trace_cap / trace

        if self._bounded:
            theta_new = np.clip(theta_new, self._lower, self._upper)
        self._theta = theta_new
        self._P = P_new
        self._last_error = err
        self._x_ref = xv.copy()
        self._n_updates += 1
        return True

    def constrain(self, x: ArrayLike, bound: float, sense: Literal["ge", "le"]) -> bool:
        """Impose one-sided information ``x' beta >= bound`` (``"ge"``) or ``<= bound`` (``"le"``).

        An inequality says where the parameters may lie, not where they are, so it must not make
        the estimator more certain. When the current estimate satisfies it, nothing changes. When
        it violates it, ``beta`` is projected onto the boundary in the metric of ``P^-1``::

            beta <- beta + P x (bound - x' beta) / (x' P x)

        (the normalised projection algorithm: the smallest change, weighted by the current
        uncertainty, that satisfies the inequality; directions ``P`` is sure about move least),
        then clipped to ``[lower, upper]`` (which may leave the inequality short where a bound
        binds). ``P``, the excitation reference and the update counter are left untouched:
        no covariance shrinks and no forgetting applies.

        Parameters
        ----------
        x : array_like, shape (n,)
            Regressor.
        bound : float
            Right-hand side (units of ``x' beta``).
        sense : {"ge", "le"}
            Direction of the inequality.

        Returns
        -------
        bool
            True if ``beta`` moved; False if the estimate was consistent, the input non-finite
            (counted in ``n_skipped_nonfinite``) or ``x' P x`` is zero (no direction to move in).

        Raises
        ------
        ValueError
            If ``x`` does not have shape (n,) or ``sense`` is not "ge" or "le".
        """
        if sense not in ("ge", "le"):
            raise ValueError(f"sense must be 'ge' or 'le', got {sense!r}")
        xv = self._as_regressor(x)
        b = _real_scalar(bound, "bound")
        if not (np.isfinite(xv).all() and math.isfinite(b)):
            self._n_nonfinite += 1
            return False
        gap = b - float(xv @ self._theta)
        if (sense == "ge" and gap <= 0.0) or (sense == "le" and gap >= 0.0):
            return False
        Px = self._P @ xv
        xPx = float(xv @ Px)
        if not xPx > 0.0:
            return False
        theta_new = self._theta + Px * (gap / xPx)
        if not np.isfinite(theta_new).all():
            self._n_nonfinite += 1
            return False
        if self._bounded:
            theta_new = np.clip(theta_new, self._lower, self._upper)
        moved = not np.array_equal(theta_new, self._theta)
        self._theta = theta_new
        if moved:
            self._n_constrained += 1
        return moved

    def predict(self, x: ArrayLike) -> float:
        """Prediction ``x' beta`` for regressor ``x`` of shape (n,)."""
        return float(self._as_regressor(x) @ self._theta)

    def reset(self, theta0: ArrayLike | None = None, p0: float | None = None) -> None:
        """Return to the constructed state: ``beta = theta0``, ``P = p0 I``, counters zeroed.

        Parameters
        ----------
        theta0 : array_like, shape (n,), optional
            New initial estimate (inside the bounds); default the constructor's ``theta0``.
        p0 : float, optional
            New initial covariance scale (``n * p0 <= trace_cap``); default the constructor's.
        """
        if p0 is not None:
            value = self._check_p0(p0)
            self._check_p0_against_cap(value)
            self._p0 = value
        if theta0 is not None:
            self._theta0 = self._check_theta(theta0)
        self._theta = self._theta0.copy()
        self._P = self._p0 * np.eye(self._n)
        self._x_ref = None
        self._last_error = math.nan
        self._n_updates = 0
        self._n_unexcited = 0
        self._n_nonfinite = 0
        self._n_constrained = 0

    # ------------------------------------------------------------------ read-only state
    @property
    def n_params(self) -> int:
        """Number of parameters ``n``."""
        return self._n

    @property
    def forgetting(self) -> float:
        """Forgetting factor ``lambda`` per sample."""
        return self._lambda

    @property
    def trace_cap(self) -> float:
        """Cap on ``trace P`` (``math.inf`` when disabled)."""
        return self._trace_cap

    @property
    def excitation_threshold(self) -> float:
        """Dead zone on the excitation measure (units of ``x``)."""
        return self._threshold

    @property
    def lower(self) -> NDArray[np.float64]:
        """Lower projection bounds, shape (n,) (a copy)."""
        return self._lower.copy()

    @property
    def upper(self) -> NDArray[np.float64]:
        """Upper projection bounds, shape (n,) (a copy)."""
        return self._upper.copy()

    @property
    def theta(self) -> NDArray[np.float64]:
        """Current estimate ``beta``, shape (n,) (a copy)."""
        return self._theta.copy()

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Current covariance ``P``, shape (n, n), symmetric positive definite (a copy)."""
        return self._P.copy()

    @property
    def trace(self) -> float:
        """``trace P`` (sum of the parameter variances, up to the noise variance)."""
        return float(np.trace(self._P))

    @property
    def last_error(self) -> float:
        """A-priori prediction error ``e`` of the last applied update (NaN before any)."""
        return self._last_error

    @property
    def n_updates(self) -> int:
        """Number of applied updates since construction or the last reset."""
        return self._n_updates

    @property
    def n_skipped(self) -> int:
        """Number of skipped samples (``n_skipped_unexcited + n_skipped_nonfinite``)."""
        return self._n_unexcited + self._n_nonfinite

    @property
    def n_skipped_unexcited(self) -> int:
        """Samples skipped by the dead zone (including the first, reference-setting one)."""
        return self._n_unexcited

    @property
    def n_constrained(self) -> int:
        """Number of :meth:`constrain` calls that moved the estimate (not counted as updates)."""
        return self._n_constrained

    @property
    def n_skipped_nonfinite(self) -> int:
        """Samples skipped for a non-finite input or a non-finite (overflowing) result."""
        return self._n_nonfinite
