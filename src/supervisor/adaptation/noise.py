"""Transmitter-noise estimate per loop, and the loop-gain limit it sets (pure, model time only).

The model's one-step prediction error of each loop output [error unit]::

    eps(k) = C x(k) - C [x_op + A (x(k-1) - x_op) + B (u(k-1) - u_op)]

is smooth where the model is wrong, so its difference ``d(k) = eps(k) - eps(k-1)`` is mostly
noise: for white transmitter noise of standard deviation ``sigma`` on every level, ``var d`` is
about ``6 sigma^2`` (own tank; the couplings add less than 1 %). ``sigma^2`` is the exponentially
weighted mean of ``d^2 / 6`` over ``10 memory_s`` [s] with the start-up bias removed; a sample
beyond 5 sigma of the current estimate (a step, a leak opening) is clipped there.

Noise of standard deviation ``sigma`` moves a PI's output by about ``sqrt(2) Kp sigma`` rms per
scan, so ``Kp <= kp_noise = budget U / (sqrt(2) sigma)`` keeps the noise-driven moves within
``noise_move_budget`` of the pump range ``U`` [pump unit]; :func:`hold_gain_limit` adds the 20 %
hysteresis, and the RLS dead zone becomes at least ``NOISE_DEAD_ZONE sigma / E``.
"""

from __future__ import annotations

import math

import numpy as np

from supervisor.adaptation._validate import FloatArray
from supervisor.adaptation.model import LoopModel
from tanklab.rls import ExpForgettingRls

__all__ = ["NOISE_DEAD_ZONE", "NoiseEstimate", "hold_gain_limit"]

#: The noise estimate's memory, in units of ``memory_s`` (a slow property of the transmitters).
_NOISE_MEMORY_FACTOR = 10.0
#: Dead zone per estimated noise standard deviation, in units of ``sigma / error_scale``.
NOISE_DEAD_ZONE = 17.0
#: Relative band of the noise limit's hysteresis (engage, release, move).
_NOISE_HYSTERESIS = 0.2
#: Samples before the estimate is used (clipping, limits).
_MIN_SAMPLES = 10


class NoiseEstimate:
    """Exponentially weighted transmitter-noise estimate per loop (see the module doc).

    Parameters
    ----------
    model : LoopModel
        The model whose one-step prediction errors are the data.
    memory_s : float
        The adapter's RLS memory [s]; the estimate remembers ``10 memory_s``.
    """

    def __init__(self, model: LoopModel, memory_s: float) -> None:
        self._model = model
        self._lambda = ExpForgettingRls.forgetting_from_memory(model.ts_s, _NOISE_MEMORY_FACTOR * memory_s)
        self._acc = np.zeros(model.n_loops)  # sum of lambda^age d^2 / 6
        self._weight = 0.0  # sum of lambda^age (the same weights: no start-up bias)
        self._n = 0
        self._eps_prev: FloatArray | None = None

    @property
    def ready(self) -> bool:
        """Enough samples for the estimate to limit gains and clip outliers."""
        return self._n >= _MIN_SAMPLES

    def restart(self) -> None:
        """Forget the previous prediction error (after a gap or an invalid reading)."""
        self._eps_prev = None

    def track(self, x: FloatArray, x_prev: FloatArray, mv_prev: FloatArray) -> None:
        """Add the sample of scan ``k``: state ``x(k)``, state ``x(k-1)`` and applied ``u(k-1)``."""
        model = self._model
        if not (np.isfinite(x).all() and np.isfinite(x_prev).all()):
            self._eps_prev = None
            return
        pred = model.x_op + model.A @ (x_prev - model.x_op) + model.B @ (mv_prev - model.u_op)
        eps = model.C @ (x - pred)
        prev, self._eps_prev = self._eps_prev, eps
        if prev is None:
            return
        d2 = (eps - prev) ** 2 / 6.0
        lam = self._lambda
        if self._n >= _MIN_SAMPLES:
            d2 = np.minimum(d2, 25.0 * self.std() ** 2)
        self._acc = lam * self._acc + d2
        self._weight = lam * self._weight + 1.0
        self._n += 1

    def std(self) -> FloatArray:
        """Estimated transmitter noise per loop [error unit], shape (n_loops,); 0 before data."""
        if self._n == 0:
            return np.zeros(self._model.n_loops)
        return np.sqrt(self._acc / self._weight)


def hold_gain_limit(held: float | None, kp_noise: float, kp: float) -> float | None:
    """The own-loop Kp limit in force after a new noise limit ``kp_noise`` [pump unit / e].

    The limit engages below ``kp / 1.2`` (``kp`` the model-based Kp), releases above ``kp x 1.2``
    and moves only when it changes by more than 20 %, so that the scatter of the estimate (a few
    %) does not make the gains wander. ``held`` is the limit in force (None: none).
    """
    band = 1.0 + _NOISE_HYSTERESIS
    if held is None:
        if kp_noise < kp / band:
            held = kp_noise
    elif kp_noise > kp * band:
        held = None
    elif abs(math.log(kp_noise / held)) > math.log(band):
        held = kp_noise
    return held
