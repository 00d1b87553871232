"""The linear closed loop of a ZOH plant with the PLC's velocity-form MIMO PID (pure functions).

The PID runs every scan ``k`` of period ``Ts`` [s] with ``e_j = r_j - y_j`` [m]::

    u_i(k) = u_i(k-1) + sum_j [ Kp_ij De_j(k) + Ki_ij Ts e_j(k) + (Kd_ij / Ts) D2e_j(k) ]
    De_j(k)  = e_j(k) - e_j(k-1),   D2e_j(k) = e_j(k) - 2 e_j(k-1) + e_j(k-2)

Here: the closed-loop matrix and its spectral radius (the stability guard), the SIMC tuning from
the model's diagonal (the estimator's prior), and the unclamped inputs of the closed loop over a
horizon with their peak excursion beyond the input bounds (the input-bound guard).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from supervisor.adaptation._validate import FloatArray, finite, matrix, positive, state_space
from supervisor.adaptation.model import LoopModel
from tanklab.gains import PidGains

__all__ = [
    "closed_loop_matrix",
    "closed_loop_spectral_radius",
    "input_bound_violation",
    "model_based_gains",
    "simulate_pid_inputs",
]


def _check_loop_arrays(
    A: ArrayLike, B: ArrayLike, C: ArrayLike, Kp: ArrayLike, Ki: ArrayLike, Kd: ArrayLike, ts_s: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float]:
    Am, Bm, Cm = state_space(A, B, C)
    shape = (Bm.shape[1], Cm.shape[0])
    Kpm = finite(matrix(Kp, "Kp", shape), "Kp")
    Kim = finite(matrix(Ki, "Ki", shape), "Ki")
    Kdm = finite(matrix(Kd, "Kd", shape), "Kd")
    return Am, Bm, Cm, Kpm, Kim, Kdm, positive(ts_s, "ts_s")


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
    x = finite(matrix(x0, "x0", (model.n_x,)), "x0") - model.x_op
    u = finite(matrix(u0, "u0", (model.n_u,)), "u0") - model.u_op
    e1 = finite(matrix(e0, "e0", (nl,)), "e0").copy()
    e2 = finite(matrix(e_prev, "e_prev", (nl,)), "e_prev").copy()
    r_dev = finite(matrix(r, "r", (nl,)), "r") - model.C @ model.x_op
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
