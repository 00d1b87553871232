"""Regularised least squares with a persistent prior and directional forgetting.

The estimator behind the supervisor's gain adaptation (docs/adaptation.md section 2.1,
docs/decisions/0014-well-conditioned-adaptation.md). For a regressor ``x(t)`` of shape (n,) and a
scalar target ``y(t)`` (both dimensionless here), the estimate at time ``t`` minimises::

    J(theta) = sum_s w_t(s) (y(s) - x(s)' theta)^2  +  (theta - theta_p)' L0 (theta - theta_p)

with ``theta_p`` the prior (the model-based tuning) and ``L0 = diag(l0)`` its information. The
prior term is never forgotten; only the data are. In information form, with ``R`` the data's
information matrix and ``r`` its information vector::

    forget:   R <- R - (1 - lambda) R x x' R / (x' R x)          (only along R x: directional)
              r <- r - (1 - lambda) R x (x' r) / (x' R x)
    absorb:   R <- R + x x',    r <- r + x y
    estimate: theta = clip( (L0 + R)^-1 (L0 theta_p + r), lower, upper )

Directional forgetting (Kulhavy 1987; Bittanti, Bolzern and Campi 1990) discounts old data only in
the direction the new sample measures, so information about directions the loop does not excite
is kept instead of decaying: ``R`` cannot wind down in quiet phases and its excited part stays
bounded (by about ``x x' / (1 - lambda)`` for a regressor repeated for ever). With the prior the
information matrix ``H = L0 + R`` is at least ``L0``, so::

    cond(H) <= (lambda_max(R) + max l0) / min l0            (bounded for every data sequence)

and where the data say nothing the estimate is the prior, not a drift. The forgetting step needs
``x' R x > 0``; when ``R`` has no information along ``x`` yet, nothing is forgotten.

The quadratic identity behind the ``r`` update: with ``R theta_d = r`` for the data's minimiser
``theta_d`` (any one, if ``R`` is singular), the forgotten quadratic is
``(theta - theta_d)' R_new (theta - theta_d)``, whose linear term is ``R_new theta_d``
``= r - (1 - lambda) R x (x' R theta_d) / (x' R x)`` and ``x' R theta_d = x' r``.

Guards, in the order they act (the same contract as :class:`tanklab.rls.ExpForgettingRls`):

1. **Finite input.** A non-finite ``x`` or ``y`` is skipped and counted; the state is untouched.
2. **Dead zone.** A sample whose regressor moved less than ``excitation_threshold`` (Euclidean
   norm) since the last applied update is skipped; nothing is forgotten either. The first sample
   only sets the reference.
3. **Symmetry** of ``R`` after every step, and its eigenvalues floored at 0 (rounding).
4. **Projection** of the estimate onto ``[lower, upper]``.

One-sided information ``x' theta >= bound`` (``"ge"``) or ``<= bound`` (``"le"``), e.g. a
teacher input clamped at a bound, goes through :meth:`PriorRls.constrain`: a satisfied inequality
teaches nothing; a violated one is active and is absorbed as the equality sample ``(x, bound)``
(the active-set treatment of an inequality in least squares). Because the prior stays in the cost,
an active inequality cannot drag the estimate further than the data and the prior together allow
(with the bare RLS, a projection onto every violated boundary drove pump 1's Kp to 0 and its Ki to
the box maximum on the Energies fill, docs/adaptation.md 2.9).

Health, for the supervisor's nodes: ``excitation`` is the smallest eigenvalue of ``R`` (how well
the weakest direction is measured by the remembered data), ``energy`` its trace (the regressor's
energy over the memory), ``condition_number`` that of ``H``, ``trace`` the trace of ``H^-1`` (the
covariance up to the noise variance).

This module is pure: no clock, no I/O, no logging.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PriorRls"]

FloatArray = NDArray[np.float64]


def _vector(value: ArrayLike, n: int, name: str) -> FloatArray:
    arr = np.array(value, dtype=np.float64, ndmin=1)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    return arr


class PriorRls:
    """Least squares with a persistent prior and directional forgetting (see the module doc).

    Parameters
    ----------
    prior : array_like, shape (n,)
        ``theta_p``, the estimate where the data say nothing; finite.
    prior_information : array_like, shape (n,)
        Diagonal of ``L0``, each > 0 and finite (units of ``x`` squared).
    forgetting : float
        ``lambda`` in (0, 1] per applied sample.
    excitation_threshold : float
        Dead zone on ``||x - x_ref||`` (>= 0; 0 disables it).
    lower, upper : array_like, shape (n,), optional
        Projection bounds (default unbounded); ``prior`` is clipped into them.
    """

    def __init__(
        self,
        prior: ArrayLike,
        prior_information: ArrayLike,
        *,
        forgetting: float,
        excitation_threshold: float = 0.0,
        lower: ArrayLike | None = None,
        upper: ArrayLike | None = None,
    ) -> None:
        p = np.array(prior, dtype=np.float64, ndmin=1)
        if p.ndim != 1 or p.size == 0 or not np.isfinite(p).all():
            raise ValueError("prior must be a finite vector of shape (n,), n >= 1")
        n = p.size
        l0 = _vector(prior_information, n, "prior_information")
        if not (np.isfinite(l0).all() and (l0 > 0).all()):
            raise ValueError("prior_information must be finite and > 0 for every parameter")
        lam = float(forgetting)
        if not 0.0 < lam <= 1.0:
            raise ValueError(f"forgetting must be in (0, 1], got {forgetting!r}")
        thr = float(excitation_threshold)
        if not (math.isfinite(thr) and thr >= 0.0):
            raise ValueError(f"excitation_threshold must be finite and >= 0, got {excitation_threshold!r}")
        lo = np.full(n, -np.inf) if lower is None else _vector(lower, n, "lower")
        hi = np.full(n, np.inf) if upper is None else _vector(upper, n, "upper")
        if np.isnan(lo).any() or np.isnan(hi).any() or (lo > hi).any():
            raise ValueError("lower and upper must not be NaN and lower <= upper")
        self._n = n
        self._l0 = l0
        self._lam = lam
        self._thr = thr
        self._lo = lo
        self._hi = hi
        self._prior = np.clip(p, lo, hi)
        self._R = np.zeros((n, n))
        self._r = np.zeros(n)
        self._x_ref: FloatArray | None = None
        self._theta = self._prior.copy()
        self._n_updates = 0
        self._n_unexcited = 0
        self._n_nonfinite = 0
        self._n_constrained = 0
        self._last_error = math.nan

    # ------------------------------------------------------------------ state
    def _solve(self) -> None:
        H = np.diag(self._l0) + self._R
        theta = np.linalg.solve(H, self._l0 * self._prior + self._r)
        self._theta = np.clip(theta, self._lo, self._hi)

    def _information(self) -> FloatArray:
        return np.diag(self._l0) + self._R

    def _regressor(self, x: ArrayLike) -> FloatArray:
        xv = np.array(x, dtype=np.float64, ndmin=1)
        if xv.shape != (self._n,):
            raise ValueError(f"x must have shape ({self._n},), got {xv.shape}")
        return xv

    def _absorb(self, xv: FloatArray, yv: float) -> bool:
        """Forget along ``R x``, add the sample, re-solve; False (state untouched) if not finite."""
        R, r = self._R, self._r
        Rx = R @ xv
        v = float(xv @ Rx)
        if self._lam < 1.0 and v > 1e-12 * max(float(np.trace(R)), 1e-300):
            k = (1.0 - self._lam) / v
            R = R - k * np.outer(Rx, Rx)
            r = r - k * Rx * float(xv @ r)
        R = R + np.outer(xv, xv)
        r = r + xv * yv
        R = 0.5 * (R + R.T)
        w, V = np.linalg.eigh(R)
        if (w < 0.0).any():
            R = (V * np.maximum(w, 0.0)) @ V.T
        if not (np.isfinite(R).all() and np.isfinite(r).all()):
            self._n_nonfinite += 1
            return False
        self._last_error = yv - float(xv @ self._theta)
        self._R, self._r = R, r
        self._solve()
        return True

    def update(self, x: ArrayLike, y: float) -> bool:
        """Absorb one sample ``y = x' theta + noise``; return True when it was applied.

        Skipped (and counted) when ``x`` or ``y`` is not finite, or inside the dead zone.
        """
        xv = self._regressor(x)
        yv = float(y)
        if not (np.isfinite(xv).all() and math.isfinite(yv)):
            self._n_nonfinite += 1
            return False
        if self._thr > 0.0:
            if self._x_ref is None:
                self._x_ref = xv.copy()
                self._n_unexcited += 1
                return False
            if float(np.linalg.norm(xv - self._x_ref)) < self._thr:
                self._n_unexcited += 1
                return False
        if not self._absorb(xv, yv):
            return False
        self._x_ref = xv.copy()
        self._n_updates += 1
        return True

    def constrain(self, x: ArrayLike, bound: float, sense: Literal["ge", "le"]) -> bool:
        """Impose ``x' theta >= bound`` (``"ge"``) or ``<= bound`` (``"le"``).

        A satisfied inequality teaches nothing. A violated one is active: it is absorbed as the
        equality sample ``(x, bound)``, weighed against the prior and the other data (the dead zone
        does not apply: a violation is informative whatever the regressor's change). Returns True
        when it was absorbed (counted in ``n_constrained``, not in ``n_updates``).
        """
        if sense not in ("ge", "le"):
            raise ValueError(f"sense must be 'ge' or 'le', got {sense!r}")
        xv = self._regressor(x)
        b = float(bound)
        if not (np.isfinite(xv).all() and math.isfinite(b)):
            self._n_nonfinite += 1
            return False
        pred = float(xv @ self._theta)
        if (sense == "ge" and pred >= b) or (sense == "le" and pred <= b):
            return False
        if not self._absorb(xv, b):
            return False
        self._n_constrained += 1
        return True

    def set_bounds(self, lower: ArrayLike, upper: ArrayLike) -> None:
        """Replace the projection bounds (the prior is re-clipped into them) and re-solve."""
        lo = _vector(lower, self._n, "lower")
        hi = _vector(upper, self._n, "upper")
        if np.isnan(lo).any() or np.isnan(hi).any() or (lo > hi).any():
            raise ValueError("lower and upper must not be NaN and lower <= upper")
        self._lo, self._hi = lo, hi
        self._prior = np.clip(self._prior, lo, hi)
        self._solve()

    def set_excitation_threshold(self, threshold: float) -> None:
        """Replace the dead zone (>= 0, finite); the reference regressor is kept."""
        thr = float(threshold)
        if not (math.isfinite(thr) and thr >= 0.0):
            raise ValueError(f"excitation_threshold must be finite and >= 0, got {threshold!r}")
        self._thr = thr

    @property
    def excitation_threshold(self) -> float:
        """The dead zone in force."""
        return self._thr

    def set_prior(self, prior: ArrayLike) -> None:
        """Replace ``theta_p`` (clipped into the bounds) and re-solve; the data are kept."""
        p = _vector(prior, self._n, "prior")
        if not np.isfinite(p).all():
            raise ValueError("prior must be finite")
        self._prior = np.clip(p, self._lo, self._hi)
        self._solve()

    # ------------------------------------------------------------------ read-outs
    @property
    def n_params(self) -> int:
        """Number of parameters."""
        return self._n

    @property
    def theta(self) -> FloatArray:
        """Current estimate (a copy), shape (n,)."""
        return self._theta.copy()

    @property
    def prior(self) -> FloatArray:
        """The prior ``theta_p`` (clipped into the bounds), shape (n,)."""
        return self._prior.copy()

    @property
    def data_information(self) -> FloatArray:
        """``R``, the remembered data's information matrix (a copy), shape (n, n)."""
        return self._R.copy()

    @property
    def information(self) -> FloatArray:
        """``H = L0 + R`` (a copy), shape (n, n)."""
        return self._information()

    @property
    def excitation(self) -> float:
        """Smallest eigenvalue of ``R`` (>= 0): how well the weakest direction is measured."""
        return float(max(np.linalg.eigvalsh(self._R)[0], 0.0))

    @property
    def energy(self) -> float:
        """``trace R``: the regressor's energy over the memory."""
        return float(np.trace(self._R))

    @property
    def condition_number(self) -> float:
        """Condition number of ``H`` (>= 1, bounded by the prior)."""
        w = np.linalg.eigvalsh(self._information())
        return float(w[-1] / w[0])

    @property
    def trace(self) -> float:
        """Trace of ``H^-1`` (the covariance up to the noise variance)."""
        return float(np.trace(np.linalg.inv(self._information())))

    @property
    def last_error(self) -> float:
        """A-priori prediction error of the last applied update (NaN before the first)."""
        return self._last_error

    @property
    def n_updates(self) -> int:
        """Applied updates."""
        return self._n_updates

    @property
    def n_skipped_unexcited(self) -> int:
        """Samples skipped by the dead zone."""
        return self._n_unexcited

    @property
    def n_skipped_nonfinite(self) -> int:
        """Samples (or constraints) skipped for a non-finite input or result."""
        return self._n_nonfinite

    @property
    def n_constrained(self) -> int:
        """One-sided constraints that moved the estimate."""
        return self._n_constrained
