"""How fast a tank network's modes can be: the bound the RK4 integrator picks its sub-steps from.

The level dynamics linearise to ``J = -A^-1 L`` with ``L`` the weighted Laplacian of the orifice
graph (weight ``s c g`` per valve, ``g`` the slope of the orifice law at the current head [m^-0.5];
leaks and drain valves on the diagonal, their head the tank's level). ``g`` is largest in the
laminar band, ``1 / sqrt(H_LAMINAR_M)`` (the turbulent slope ``1 / (2 sqrt|dh|)`` is at most half
of it); with every head at least ``min_head_m`` (>= ``H_LAMINAR_M``) it is at most
``1 / (2 sqrt(min_head_m))``. ``A^-1 L`` has the eigenvalues of the symmetric ``A^-1/2 L A^-1/2``,
which only grow with the weights. So the eigenvalues of ``J`` at those states and any valve and
leak openings lie in ``[-lambda_max, 0]`` [1/s] with ``lambda_max`` the largest eigenvalue of
``A^-1/2 L A^-1/2`` with every valve and leak fully open at that slope. A lagged pump adds the
rate ``1 / lag_s``.

Not covered: an outflow disturbance fading out over the last ``H_LAMINAR_M`` of an emptying tank
(the integrator projects levels onto [0, Hmax], so it cannot overshoot below empty).
"""

from __future__ import annotations

import math

import numpy as np

from plant_sim.models import DRAIN, H_LAMINAR_M, TankNetwork


def rate_bound_1_s(net: TankNetwork, min_head_m: float | None) -> float:
    """Upper bound on the modulus of every eigenvalue of the plant's Jacobian [1/s] at every state
    whose heads across open orifices are all at least ``min_head_m`` [m] (None: any state).

    Raises
    ------
    ValueError
        If ``min_head_m`` is below ``H_LAMINAR_M``.
    """
    if min_head_m is not None and not min_head_m >= H_LAMINAR_M:
        raise ValueError(f"min_head_m must be >= H_LAMINAR_M = {H_LAMINAR_M} m, got {min_head_m}")
    memo = net._rate_memo
    if min_head_m in memo:
        return memo[min_head_m]
    n = net.n_tanks
    # the orifice law's steepest slope at those heads
    g = 1.0 / math.sqrt(H_LAMINAR_M) if min_head_m is None else 0.5 / math.sqrt(min_head_m)
    L = np.diag(net.leak_conductance * g)
    for up, down, c in zip(net.valve_up, net.valve_down, net.valve_conductance, strict=True):
        w = float(c) * g
        L[up, up] += w
        if down != DRAIN:
            L[down, down] += w
            L[up, down] -= w
            L[down, up] -= w
    d = 1.0 / np.sqrt(net.area_m2)
    sym = d[:, None] * L * d[None, :]
    rate = float(np.max(np.linalg.eigvalsh(0.5 * (sym + sym.T)))) if n else 0.0
    lags = net.pump_lag_s[net.pump_lag_s > 0]
    if lags.size:
        rate = max(rate, float(np.max(1.0 / lags)))
    memo[min_head_m] = rate
    return rate


def fastest_rate_1_s(net: TankNetwork) -> float:
    """Upper bound on the modulus of every eigenvalue of the plant's Jacobian, anywhere [1/s]:
    :func:`rate_bound_1_s` with no bound on the heads (the laminar band included)."""
    return rate_bound_1_s(net, None)
