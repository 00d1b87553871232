r"""The SI cost of a plan and its output-bound violation (pure; fixed per model).

For a plan u(0..Np-1) [m^3/s] with predicted outputs z(1..Np) [m], reference r [m] and the
applied u(-1)::

    J = 1/2 sum_k |Lq (z(k) - r(k))|^2 + 1/2 sum_k |Ls (u(k) - u(k-1))|^2
      + 1/2 sum_k |Lr (u(k) - u_ss)|^2 + sum_k sum_i (1/2 rho_q,i v_i(k)^2 + rho_l,i v_i(k))

with L' L = Qz, S, R (:func:`supervisor.mpc.model.sqrt_psd`), v(k) = max(z(k) - z_max,
z_min - z(k), 0) the output-bound violation [m] and rho_q [1/m^2], rho_l [1/m] the slack
weights in SI units. u_ss is the offset-free target's input (R > 0 only): the least-squares
solution of [[I - A~, -B~], [Cz~, 0]] [x~s; u~s] = [w~; r~(Np)] in scaled deviations, w~ =
Dx^-1 Bd eta (module docstring of :mod:`supervisor.mpc.formulation`).

A :class:`PlanCost` is a snapshot of the terms for one model: the formulation makes a new one
when the model is re-linearised, so a step's result, which evaluates its cost only when asked
(:attr:`supervisor.mpc.model.MpcResult.objective`), keeps the model it was solved on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from supervisor.mpc.model import FloatArray


@dataclass(frozen=True, eq=False)
class PlanCost:
    """The cost terms of one model (module docstring); arrays are not changed after creation.

    Attributes
    ----------
    Lq, Ls, Lr : ndarray
        Square roots of Qz [1/m^2] (nz, nz), S and R [1/(m^3/s)^2] (m, m).
    use_R : bool
        R has a nonzero entry (the u_ss term is present).
    steady_state_target : bool
        u_ss is the offset-free target's input; False: the operating point (u~ss = 0).
    target_pinv : ndarray, shape (n + m, n + nz)
        Pseudo-inverse of the scaled target matrix [[I - A~, -B~], [Cz~, 0]].
    n : int
        Number of states (u~ss is the target solution's tail).
    Bd : ndarray, shape (n, n_eta)
        The disturbance matrix.
    sx : ndarray, shape (n,)
        The state scale [m].
    u_op, su : ndarray, shape (m,)
        Operating-point input and input scale [m^3/s].
    z_op, sz : ndarray, shape (nz,)
        Cz x_op and the output scale [m].
    z_min, z_max : ndarray, shape (nz,)
        Output bounds [m] (+-inf where absent).
    has_z_rows : bool
        Some output bound is finite.
    half_rho_q, rho_l : ndarray, shape (nz,)
        1/2 rho_q [1/m^2] and rho_l [1/m] of the slack cost, SI units.
    """

    Lq: FloatArray
    Ls: FloatArray
    Lr: FloatArray
    use_R: bool
    steady_state_target: bool
    target_pinv: FloatArray
    n: int
    Bd: FloatArray
    sx: FloatArray
    u_op: FloatArray
    su: FloatArray
    z_op: FloatArray
    sz: FloatArray
    z_min: FloatArray
    z_max: FloatArray
    has_z_rows: bool
    half_rho_q: FloatArray
    rho_l: FloatArray

    def scaled_w(self, eta: FloatArray) -> FloatArray:
        """w~ = Dx^-1 Bd eta, the scaled disturbance input (n,)."""
        return (self.Bd @ eta) / self.sx

    def u_target(self, w_t: FloatArray, r_t_last: FloatArray) -> FloatArray:
        """Scaled u~ss (m,) for the R term from w~ and the scaled last reference r~(Np)."""
        if not self.use_R or not self.steady_state_target:
            return np.zeros(self.su.size)
        sol = self.target_pinv @ np.concatenate([w_t, r_t_last])
        return sol[self.n :]

    def evaluate(
        self, plan: FloatArray, z: FloatArray, r: FloatArray, u_prev: FloatArray, eta: FloatArray
    ) -> tuple[float, float]:
        """(J, max violation [m]) of a plan (Np, m) with outputs z (Np, nz); r is (nz,) or (Np, nz)."""
        w = self.residual_roots(plan, z, r, u_prev, eta)
        slack, violation = self.slack(z)
        return 0.5 * float(np.vdot(w, w)) + slack, violation

    def residual_roots(
        self, plan: FloatArray, z: FloatArray, r: FloatArray, u_prev: FloatArray, eta: FloatArray
    ) -> FloatArray:
        """w with 1/2 |w|^2 the plan's tracking, move and input cost (SI): z - r, the moves and
        u - u_ss, each times a square root L of its weight (L' L = Qz, S, R)."""
        du = np.empty_like(plan)
        du[0] = plan[0] - u_prev
        np.subtract(plan[1:], plan[:-1], out=du[1:])
        parts = [((z - r) @ self.Lq.T).reshape(-1), (du @ self.Ls.T).reshape(-1)]
        if self.use_R:
            rt_last = ((r if r.ndim == 1 else r[-1]) - self.z_op) / self.sz
            uss = self.u_op + self.u_target(self.scaled_w(eta), rt_last) * self.su
            parts.append(((plan - uss) @ self.Lr.T).reshape(-1))
        return np.concatenate(parts)

    def slack(self, z: FloatArray) -> tuple[float, float]:
        """The slack cost (SI) of the output-bound violations of z and the largest one [m]."""
        if not self.has_z_rows:
            return 0.0, 0.0
        viol = np.maximum(np.maximum(z - self.z_max, self.z_min - z), 0.0)
        return float(np.vdot(viol, self.half_rho_q * viol + self.rho_l)), float(viol.max())
