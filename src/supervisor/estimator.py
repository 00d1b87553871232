"""Augmented steady-state Kalman filter for offset-free MPC (pure core).

The plant model, in deviations around an operating point (levels [m], flows [m^3/s]), is augmented
with integrating disturbances eta (the offset-free design of Muske & Badgwell / Pannocchia &
Rawlings, seeds digest 2.5)::

    x(k+1)   = A x(k) + B u(k) + Bd eta(k) + w_x(k)        x: (n,)    [m]
    eta(k+1) = eta(k)                    + w_eta(k)        eta: (n_eta,) [units of Bd's columns]
    y(k)     = C x(k)                    + v(k)            y: (ny,)   [m]     (C_eta = 0)

or, with xi = [x; eta], ``xi(k+1) = Aa xi(k) + Ba u(k) + w``, ``y = Ca xi + v`` where::

    Aa = [[A, Bd], [0, I]],   Ba = [[B], [0]],   Ca = [C, 0].

With ``Bd = B`` (the default) eta is an input disturbance in input units [m^3/s]: a leak of q m^3/s
from a pumped tank reads as eta = -q on that pump. A column ``e_i`` of Bd adds eta_i metres per
sample to state i (e.g. ``Bd = [B, e3]`` for a leak on the unpumped tank T3).

Noise: w = [w_x; w_eta] ~ N(0, Qw), Qw = diag(sigma_x^2, sigma_eta^2); v ~ N(0, Rv), Rv = diag(sigma_y^2).
Defaults (digest 2.5): sigma_x = 1e-4 m, sigma_eta = 1e-6 (m^3/s for Bd = B), sigma_y = 1e-3 m, per sample.

The steady-state a-priori covariance P solves the filter DARE (``scipy.linalg.solve_discrete_are``)::

    P  = Aa P Aa' - Aa P Ca' (Ca P Ca' + Rv)^-1 Ca P Aa' + Qw
    Kf = P Ca' (Ca P Ca' + Rv)^-1                          (filter gain, (n + n_eta, ny))

and the filter runs in predictor/corrector form::

    corrector:  xi(k|k)   = xi(k|k-1) + Kf (y(k) - Ca xi(k|k-1))
    predictor:  xi(k+1|k) = Aa xi(k|k) + Ba u(k)

with u(k) the input actually applied over the sample that follows y(k). ``update`` does a predictor
and a corrector as one product: [xi(k|k-1); xi(k|k); innovation] = M [xi(k-1|k-1); u(k-1); y(k)]
with M = [[Aa, Ba, 0], [(I - Kf Ca) Aa, (I - Kf Ca) Ba, Kf], [-Ca Aa, -Ca Ba, I]]. The a-priori estimation
error evolves as e(k+1|k) = Aa (I - Kf Ca) e(k|k-1); the constructor checks that this is stable.

Offset-free estimation needs the augmented pair (Aa, Ca) detectable. At the disturbance integrators
(eigenvalue 1) this is the rank condition

    rank [[I - A, -Bd], [C, 0]] = n + n_eta,

checked at construction with a ``ValueError``; it implies n_eta <= ny. Zero offset in closed loop
also needs n_eta = ny (as many disturbances as outputs fed to the filter).

Everything here is in deviation variables; the MPC (``supervisor.mpc``) converts absolute values.
The module is pure: no clock, no I/O, no logging.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

__all__ = ["AugmentedKalmanFilter", "StateEstimate", "augmented_model", "check_disturbance_observability"]

FloatArray = NDArray[np.float64]

# Relative singular-value threshold for the rank tests (columns are normalised first, so the test
# does not depend on the units of x, u and eta).
_RANK_RTOL = 1e-9
# Spectral radius the a-priori error dynamics must stay below.
_STABLE_RADIUS = 1.0 - 1e-12


@dataclass(frozen=True)
class StateEstimate:
    """One corrected estimate of the augmented state (deviation variables).

    Attributes
    ----------
    x : ndarray, shape (n,)
        State estimate x(k|k), deviation from the operating point [m].
    disturbance : ndarray, shape (n_eta,)
        Disturbance estimate eta(k|k) [units of the columns of Bd; m^3/s for Bd = B].
    innovation : ndarray, shape (ny,)
        y(k) - C x(k|k-1) [m], the measurement minus its prediction.
    """

    x: FloatArray
    disturbance: FloatArray
    innovation: FloatArray


def _matrix(value: ArrayLike, name: str, shape: tuple[int | None, int | None]) -> FloatArray:
    """Convert to a finite 2-D float array and check its shape (None: any size)."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name} must be a real 2-D array, got {type(value).__name__}") from e
    if arr.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got shape {arr.shape}")
    for axis, want in enumerate(shape):
        if want is not None and arr.shape[axis] != want:
            raise ValueError(f"{name} must have shape {shape} (None: any), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _std_vector(value: ArrayLike, size: int, name: str) -> FloatArray:
    """A positive finite standard deviation, scalar (broadcast) or of length ``size``."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name} must be a real scalar or 1-D array") from e
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    if arr.shape != (size,):
        raise ValueError(f"{name} must be a scalar or have shape ({size},), got {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
        raise ValueError(f"{name} must be finite and > 0")
    return arr


def _vector(value: ArrayLike, size: int, name: str, *, copy: bool = True) -> FloatArray:
    """A finite 1-D float vector of length ``size`` (``copy=False``: a float vector of the right
    shape comes back as it is, for values that are only read)."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (size,):
        if not np.isfinite(value).all():  # the per-sample fast path: the value check
            raise ValueError(f"{name} must be finite")
        return value.copy() if copy else value
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name} must be a real 1-D array") from e
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _rank_normalised(M: FloatArray) -> int:
    """Numerical rank of ``M`` after normalising its columns (rank is invariant to that)."""
    norms = np.linalg.norm(M, axis=0)
    norms[norms == 0.0] = 1.0
    s = np.linalg.svd(M / norms, compute_uv=False)
    if s.size == 0 or s[0] == 0.0:
        return 0
    return int(np.sum(s > _RANK_RTOL * s[0]))


def check_disturbance_observability(A: ArrayLike, C: ArrayLike, Bd: ArrayLike) -> None:
    """Raise ``ValueError`` unless the integrating-disturbance model is detectable.

    Checks rank [[I - A, -Bd], [C, 0]] = n + n_eta (the disturbances are distinguishable from the
    states at steady state) and, by the PBH test, that every other eigenvalue of A on or outside the
    unit circle is observable from C.

    Parameters
    ----------
    A : array_like, shape (n, n)
        Discrete state matrix.
    C : array_like, shape (ny, n)
        Measurement matrix of the outputs fed to the filter.
    Bd : array_like, shape (n, n_eta)
        Disturbance input matrix.
    """
    A_ = _matrix(A, "A", (None, None))
    n = A_.shape[0]
    if A_.shape != (n, n):
        raise ValueError(f"A must be square, got shape {A_.shape}")
    C_ = _matrix(C, "C", (None, n))
    Bd_ = _matrix(Bd, "Bd", (n, None))
    ny, n_eta = C_.shape[0], Bd_.shape[1]
    M = np.block([[np.eye(n) - A_, -Bd_], [C_, np.zeros((ny, n_eta))]])
    rank = _rank_normalised(M)
    if rank != n + n_eta:
        raise ValueError(
            "disturbance model not observable: rank [[I - A, -Bd], [C, 0]] must equal n + n_eta = "
            f"{n + n_eta}, got {rank} (n = {n}, n_eta = {n_eta}, ny = {ny}; n_eta may not exceed the "
            "number of measured outputs fed to the filter, and Bd's columns must act differently on y)"
        )
    for lam in np.linalg.eigvals(A_):
        if abs(lam) >= 1.0 - 1e-9:
            pbh = np.vstack([lam * np.eye(n) - A_, C_.astype(complex)])
            s = np.linalg.svd(pbh, compute_uv=False)
            if s[-1] <= _RANK_RTOL * max(s[0], 1.0):
                raise ValueError(f"(A, C) is not detectable: the mode at eigenvalue {lam:.6g} is unobserved")


def augmented_model(
    A: FloatArray, B: FloatArray, C: FloatArray, Bd: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return (Aa, Ba, Ca) of the integrating-disturbance augmented model.

    Shapes: Aa (n + n_eta, n + n_eta), Ba (n + n_eta, m), Ca (ny, n + n_eta).
    """
    n, m = B.shape
    n_eta = Bd.shape[1]
    ny = C.shape[0]
    Aa = np.block([[A, Bd], [np.zeros((n_eta, n)), np.eye(n_eta)]])
    Ba = np.vstack([B, np.zeros((n_eta, m))])
    Ca = np.hstack([C, np.zeros((ny, n_eta))])
    return Aa, Ba, Ca


class AugmentedKalmanFilter:
    """Steady-state Kalman filter on the integrating-disturbance augmented model.

    Parameters
    ----------
    A : array_like, shape (n, n)
        Discrete state matrix (deviation model).
    B : array_like, shape (n, m)
        Discrete input matrix [m per (m^3/s) for the tank models].
    C : array_like, shape (ny, n)
        Rows of the measurement matrix fed to the filter.
    Bd : array_like, shape (n, n_eta), optional
        Disturbance input matrix; default ``B`` (input disturbances, eta in input units).
    state_noise_std : float or array_like, shape (n,)
        Standard deviation of the state noise per sample [m]. Default 1e-4.
    disturbance_noise_std : float or array_like, shape (n_eta,)
        Standard deviation of the disturbance random walk per sample [eta units]. Default 1e-6.
    measurement_noise_std : float or array_like, shape (ny,)
        Standard deviation of the measurement noise [m]. Default 1e-3.

    Raises
    ------
    ValueError
        Bad shapes, non-finite entries, non-positive noise, an unobservable disturbance model, or a
        DARE without a stabilising solution.

    Notes
    -----
    The filter starts from the prior xi(0|-1) = 0 (the operating point, no disturbance); change it
    with :meth:`reset`. Call :meth:`update` once per sample with the new measurement and the input
    applied since the previous call.
    """

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        C: ArrayLike,
        Bd: ArrayLike | None = None,
        *,
        state_noise_std: ArrayLike = 1e-4,
        disturbance_noise_std: ArrayLike = 1e-6,
        measurement_noise_std: ArrayLike = 1e-3,
    ) -> None:
        A_ = _matrix(A, "A", (None, None))
        n = A_.shape[0]
        if A_.shape != (n, n):
            raise ValueError(f"A must be square, got shape {A_.shape}")
        B_ = _matrix(B, "B", (n, None))
        C_ = _matrix(C, "C", (None, n))
        if C_.shape[0] == 0:
            raise ValueError("C must have at least one row (a measured output)")
        Bd_ = B_.copy() if Bd is None else _matrix(Bd, "Bd", (n, None))
        if Bd_.shape[1] == 0:
            raise ValueError("Bd must have at least one column")
        self._n = n
        self._m = B_.shape[1]
        self._ny = C_.shape[0]
        self._n_eta = Bd_.shape[1]
        self._sx = _std_vector(state_noise_std, n, "state_noise_std")
        self._sd = _std_vector(disturbance_noise_std, self._n_eta, "disturbance_noise_std")
        self._sy = _std_vector(measurement_noise_std, self._ny, "measurement_noise_std")
        self._C = C_
        self._Bd_follows_B = Bd is None
        self._install(A_, B_, Bd_)
        self._prior: FloatArray = np.zeros(n + self._n_eta)
        self._posterior: FloatArray | None = None

    # -- model ----------------------------------------------------------------------------------
    def _install(self, A: FloatArray, B: FloatArray, Bd: FloatArray) -> None:
        """Check observability, solve the DARE and store the model and gain."""
        check_disturbance_observability(A, self._C, Bd)
        Aa, Ba, Ca = augmented_model(A, B, self._C, Bd)
        Qw = np.diag(np.concatenate([self._sx, self._sd]) ** 2)
        Rv = np.diag(self._sy**2)
        try:
            P = scipy.linalg.solve_discrete_are(Aa.T, Ca.T, Qw, Rv)
        except (np.linalg.LinAlgError, ValueError) as e:
            raise ValueError(f"filter DARE has no stabilising solution: {e}") from e
        P = 0.5 * (P + P.T)
        K = np.linalg.solve(Ca @ P @ Ca.T + Rv, Ca @ P).T
        err = Aa @ (np.eye(Aa.shape[0]) - K @ Ca)
        radius = float(np.max(np.abs(np.linalg.eigvals(err))))
        if not radius < _STABLE_RADIUS:
            raise ValueError(f"estimation error dynamics not stable: spectral radius {radius:.12g} >= 1")
        self._A, self._B, self._Bd = A, B, Bd
        self._Aa, self._Ba, self._Ca = Aa, Ba, Ca
        self._P = P
        self._K = K
        self._radius = radius
        # one sample as one product: [prior; posterior; innovation] of [last posterior; u; y]
        na, ny = Aa.shape[0], self._ny
        IKC = np.eye(na) - K @ Ca
        self._sample_map = np.block(
            [
                [Aa, Ba, np.zeros((na, ny))],
                [IKC @ Aa, IKC @ Ba, K],
                [-Ca @ Aa, -Ca @ Ba, np.eye(ny)],
            ]
        )

    def set_model(self, A: ArrayLike, B: ArrayLike, Bd: ArrayLike | None = None) -> None:
        """Replace A and B (same shapes) and recompute the gain, keeping the current estimate.

        Parameters
        ----------
        A : array_like, shape (n, n)
        B : array_like, shape (n, m)
        Bd : array_like, shape (n, n_eta), optional
            New disturbance matrix; default: the new B if the filter was built with Bd = B,
            otherwise the current Bd.
        """
        A_ = _matrix(A, "A", (self._n, self._n))
        B_ = _matrix(B, "B", (self._n, self._m))
        if Bd is None:
            Bd_ = B_.copy() if self._Bd_follows_B else self._Bd
        else:
            Bd_ = _matrix(Bd, "Bd", (self._n, self._n_eta))
            self._Bd_follows_B = False
        self._install(A_, B_, Bd_)

    # -- properties ------------------------------------------------------------------------------
    @property
    def n_states(self) -> int:
        """Number of plant states n."""
        return self._n

    @property
    def n_inputs(self) -> int:
        """Number of inputs m."""
        return self._m

    @property
    def n_outputs(self) -> int:
        """Number of measured outputs ny fed to the filter."""
        return self._ny

    @property
    def n_disturbances(self) -> int:
        """Number of integrating disturbances n_eta."""
        return self._n_eta

    @property
    def gain(self) -> FloatArray:
        """Filter gain Kf, shape (n + n_eta, ny) (copy)."""
        return self._K.copy()

    @property
    def covariance(self) -> FloatArray:
        """Steady-state a-priori covariance P from the DARE, shape (n + n_eta, n + n_eta) (copy)."""
        return self._P.copy()

    @property
    def error_spectral_radius(self) -> float:
        """Spectral radius of Aa (I - Kf Ca), the a-priori error dynamics (< 1)."""
        return self._radius

    @property
    def augmented(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(Aa, Ba, Ca) of the augmented model (copies)."""
        return self._Aa.copy(), self._Ba.copy(), self._Ca.copy()

    @property
    def Bd(self) -> FloatArray:
        """Disturbance input matrix, shape (n, n_eta) (copy)."""
        return self._Bd.copy()

    @property
    def estimate(self) -> StateEstimate | None:
        """The last corrected estimate, or None before the first :meth:`update`."""
        if self._posterior is None:
            return None
        return self._make_estimate(self._posterior, np.zeros(self._ny))

    # -- verbs -----------------------------------------------------------------------------------
    def reset(self, x: ArrayLike | None = None, disturbance: ArrayLike | None = None) -> None:
        """Set the prior xi(k|k-1) for the next :meth:`update` and forget the last correction.

        Parameters
        ----------
        x : array_like, shape (n,), optional
            Prior state (deviation) [m]; default zeros.
        disturbance : array_like, shape (n_eta,), optional
            Prior disturbance; default zeros.
        """
        x_ = np.zeros(self._n) if x is None else _vector(x, self._n, "x")
        if disturbance is None:
            d_ = np.zeros(self._n_eta)
        else:
            d_ = _vector(disturbance, self._n_eta, "disturbance")
        self._prior = np.concatenate([x_, d_])
        self._posterior = None

    def shift_state(self, dx: ArrayLike) -> None:
        """Add ``dx`` (n,) to the state part of the current estimate (used when the operating point moves)."""
        dx_ = np.concatenate([_vector(dx, self._n, "dx"), np.zeros(self._n_eta)])
        self._prior = self._prior + dx_  # new arrays: estimates already handed out are views
        if self._posterior is not None:
            self._posterior = self._posterior + dx_

    def correct(self, y: ArrayLike) -> StateEstimate:
        """Corrector step: fold the measurement y(k) (ny,) [m, deviation] into the prior.

        Replaces the posterior; a second ``correct`` without :meth:`predict` corrects the same prior.
        """
        y_ = _vector(y, self._ny, "y")
        innov = y_ - self._Ca @ self._prior
        self._posterior = self._prior + self._K @ innov
        return self._make_estimate(self._posterior, innov)

    def correct_prior(self, prior: FloatArray, y: FloatArray) -> FloatArray:
        """Corrector from a given prior: xi(k|k) = prior + Kf (y - Ca prior); return xi(k|k).

        For a caller that predicts the prior itself (on a finer grid than the filter's sample) and
        has checked both vectors: ``prior`` (n + n_eta,) and ``y`` (ny,) finite float arrays,
        deviation variables. The prior and the posterior replace the filter's own.
        """
        post = prior + self._K @ (y - self._Ca @ prior)
        self._prior, self._posterior = prior, post
        return post

    def set_corrected(self, prior: FloatArray, posterior: FloatArray) -> None:
        """Take a prior xi(k|k-1) and its posterior xi(k|k) = prior + Kf (y - Ca prior) that the
        caller computed with this filter's gain (as :meth:`correct_prior` does, folded into a
        product of its own); (n + n_eta,) each, finite, deviation variables, not changed later."""
        self._prior, self._posterior = prior, posterior

    def predict(self, u: ArrayLike) -> None:
        """Predictor step: propagate the last posterior with the applied input u(k) (m,) [deviation].

        Raises ``ValueError`` if there is no posterior yet (call :meth:`correct` first).
        """
        u_ = _vector(u, self._m, "u")
        if self._posterior is None:
            raise ValueError("predict needs a corrected estimate: call correct(y) first")
        self._prior = self._Aa @ self._posterior + self._Ba @ u_
        self._posterior = None

    def update(self, y: ArrayLike, u_prev: ArrayLike, *, check_finite: bool = True) -> StateEstimate:
        """One sample: predict with the input applied since the last update, then correct with y.

        Parameters
        ----------
        y : array_like, shape (ny,)
            Measurement y(k), deviation from C x_op [m].
        u_prev : array_like, shape (m,)
            Input u(k-1) applied since the previous update (deviation) [m^3/s]; ignored on the
            first update after construction or :meth:`reset` (the prior is used as is).
        check_finite : bool
            Check that y and u_prev are finite (a ValueError, the filter unchanged, if not).
            False skips the check, as scipy's ``check_finite``, for a caller that has just made
            that check itself; a non-finite value then spoils the estimate.

        Returns
        -------
        StateEstimate
            x(k|k), eta(k|k) and the innovation.
        """
        if check_finite or type(y) is not np.ndarray or type(u_prev) is not np.ndarray:
            y_ = _vector(y, self._ny, "y", copy=False)
            u_ = _vector(u_prev, self._m, "u_prev", copy=False)
        else:
            y_, u_ = y, u_prev
            if y_.shape != (self._ny,) or u_.shape != (self._m,):
                raise ValueError(f"y must have shape ({self._ny},) and u_prev ({self._m},)")
        if self._posterior is None:  # the first sample: correct the prior as it is
            innov = y_ - self._Ca @ self._prior
            self._posterior = self._prior + self._K @ innov
            return self._make_estimate(self._posterior, innov)
        # predict and correct in one product (``_sample_map``); the estimate is read-only views
        na = self._prior.size
        out = self._sample_map @ np.concatenate((self._posterior, u_, y_))
        out.setflags(write=False)
        self._prior = out[:na]
        self._posterior = out[na : 2 * na]
        return self._make_estimate(self._posterior, out[2 * na :])

    def _make_estimate(self, xi: FloatArray, innov: FloatArray) -> StateEstimate:
        """Read-only views of xi and innov (the filter replaces, never mutates, its vectors)."""
        x, d, iv = xi[: self._n], xi[self._n :], innov[:]
        for a in (x, d, iv):
            a.setflags(write=False)
        return StateEstimate(x=x, disturbance=d, innovation=iv)
