r"""The MPC's QP, rebuilt independently for cvxpy and do-mpc, to time against ``MpcController``.

Every comparator solves the QP that :class:`supervisor.mpc.MpcController` solves (module
docstring of ``supervisor.mpc``), in the same dimensionless variables (fractions of the ranges),
so that a solver tolerance means the same thing to all of them::

    x~ = (x - x_op) / s_x,  u~ = (u - u_op) / s_u,  z~ = (z - Cz x_op) / s_z,  eps~ = eps / s_z

    min  1/2 sum_{k=1..Np} (z~(k) - r~(k))' Qz~ (z~(k) - r~(k))
       + 1/2 sum_{k=0..Np-1} (u~(k) - u~(k-1))' S~ (u~(k) - u~(k-1))
       + sum_{k=1..Np} sum_i (1/2 rho_q~_i eps~_i(k)^2 + rho_l~_i eps~_i(k))
    s.t. x~(k+1) = A~ x~(k) + B~ u~(k) + w~,  x~(0) = x~0,  z~(k) = Cz~ x~(k)
         u~min <= u~(k) <= u~max
         d~min <= u~(k) - u~(k-1) <= d~max   (u~(-1) clipped so the rate window meets the box)
         z~min - eps~(k) <= z~(k) <= z~max + eps~(k),  eps~(k) >= 0

with the scales, the cost scale c and the slack weights taken from the controller's public
properties (``scales``, ``cost_scale``, ``slack_weights``) and the model and weights from its
``model`` and ``config``. The input weight R must be zero (the Kortela configuration's).
Only the QP is compared: the state estimate x(k|k) and the disturbance eta come from the
controller's Kalman filter (``MpcResult.state``, ``MpcResult.disturbance``), so every solver
answers the same question.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from supervisor.mpc import MpcController

FloatArray = NDArray[np.float64]


def _weight_matrix(value: Any, size: int) -> FloatArray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return np.eye(size) * float(arr)
    if arr.ndim == 1:
        return np.diag(np.broadcast_to(arr, (size,)))
    return arr


def _vec(value: Any, size: int) -> FloatArray:
    return np.broadcast_to(np.asarray(value, dtype=float), (size,)).copy()


def _sqrt_psd(W: FloatArray) -> FloatArray:
    """L with L' L = W for a symmetric PSD W."""
    lam, V = np.linalg.eigh(0.5 * (W + W.T))
    return np.diag(np.sqrt(np.clip(lam, 0.0, None))) @ V.T


@dataclass(frozen=True)
class ScaledQp:
    """The scaled QP data of a controller (see the module docstring); arrays in scaled units."""

    N: int
    A: FloatArray
    B: FloatArray
    Cz: FloatArray
    Q: FloatArray
    S: FloatArray
    rho_q: FloatArray
    rho_l: FloatArray
    u_min: FloatArray
    u_max: FloatArray
    d_min: FloatArray
    d_max: FloatArray
    z_min: FloatArray
    z_max: FloatArray
    first_move_rate_limited: bool
    # the maps from absolute SI values to scaled ones
    x_op: FloatArray
    u_op: FloatArray
    z_op: FloatArray
    Bd: FloatArray
    sx: FloatArray
    su: FloatArray
    sz: FloatArray

    @classmethod
    def of(cls, mpc: MpcController) -> ScaledQp:
        """Rebuild the scaled QP from the controller's public model, config and properties."""
        model, cfg = mpc.model, mpc.config
        m, nz = model.n_inputs, model.n_controlled
        if np.any(_weight_matrix(cfg.R, m) != 0.0):
            raise ValueError("the comparators implement R = 0 only")
        sx, su, sz = mpc.scales
        c = mpc.cost_scale
        rho_q, rho_l = mpc.slack_weights
        Dz, Du = np.diag(sz), np.diag(su)
        du_min, du_max = _vec(cfg.du_min, m), _vec(cfg.du_max, m)
        z_op = model.Cz @ model.x_op
        return cls(
            N=mpc.horizon,
            A=np.diag(1.0 / sx) @ model.A @ np.diag(sx),
            B=np.diag(1.0 / sx) @ model.B @ Du,
            Cz=np.diag(1.0 / sz) @ model.Cz @ np.diag(sx),
            Q=Dz @ _weight_matrix(cfg.Qz, nz) @ Dz / c,
            S=Du @ _weight_matrix(cfg.S, m) @ Du / c,
            rho_q=rho_q * sz**2 / c,
            rho_l=rho_l * sz / c,
            u_min=(_vec(cfg.u_min, m) - model.u_op) / su,
            u_max=(_vec(cfg.u_max, m) - model.u_op) / su,
            d_min=du_min / su,
            d_max=du_max / su,
            z_min=(_vec(cfg.z_min, nz) - z_op) / sz,
            z_max=(_vec(cfg.z_max, nz) - z_op) / sz,
            first_move_rate_limited=cfg.first_move_rate_limited,
            x_op=model.x_op.copy(),
            u_op=model.u_op.copy(),
            z_op=z_op,
            Bd=mpc.disturbance_matrix,
            sx=sx,
            su=su,
            sz=sz,
        )

    @property
    def n(self) -> int:
        return int(self.A.shape[0])

    @property
    def m(self) -> int:
        return int(self.B.shape[1])

    @property
    def nz(self) -> int:
        return int(self.Cz.shape[0])

    def inputs(
        self, state: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """Scaled (x~0, w~, r~ (N, nz), u~(-1), u~(-1) clipped for the rate rows) of absolute values."""
        x0 = (state - self.x_op) / self.sx
        w = (self.Bd @ eta) / self.sx
        r_abs = np.broadcast_to(np.asarray(r, dtype=float), (self.N, self.nz))
        rt = (r_abs - self.z_op) / self.sz
        up = (u_prev - self.u_op) / self.su
        up_eff = np.clip(up, self.u_min - self.d_max, self.u_max - self.d_min)
        return x0, w, rt, up, up_eff

    def u_abs(self, u_scaled: FloatArray) -> FloatArray:
        """Absolute input [m^3/s] of a scaled one."""
        return self.u_op + np.asarray(u_scaled, dtype=float).reshape(-1) * self.su


@dataclass
class SolveRecord:
    """One comparator solve: wall time of the call, the solver's own time, status, first move."""

    wall_s: float
    solver_s: float
    status: str
    u0: FloatArray
    cpu_s: float = float("nan")
    """The process's CPU time over the same call [s] (wall minus time spent waiting for a core)."""


class CvxpyMpc:
    """The scaled QP in cvxpy, built once with Parameters (DPP) and re-solved per step.

    ``solver=None`` lets cvxpy choose its default QP solver; ``solver="OSQP"`` passes ``eps_abs``
    = ``eps_rel`` = ``eps`` with polishing, ``max_iter`` and warm start, as the controller uses.
    """

    def __init__(
        self, qp: ScaledQp, *, solver: str | None, eps: float | None = None, max_iter: int = 10000
    ) -> None:
        import cvxpy as cp

        self.qp = qp
        self.solver = solver
        N, n, m, nz = qp.N, qp.n, qp.m, qp.nz
        self.x0 = cp.Parameter(n)
        self.w = cp.Parameter(n)
        self.r = cp.Parameter((N, nz))
        self.up = cp.Parameter(m)
        self.up_eff = cp.Parameter(m)
        X = cp.Variable((N + 1, n))
        self.U = cp.Variable((N, m))
        eps_v = cp.Variable((N, nz))
        Z = X[1:] @ qp.Cz.T
        Lq, Ls = _sqrt_psd(qp.Q), _sqrt_psd(qp.S)
        prev = cp.vstack([cp.reshape(self.up, (1, m), order="C"), self.U[:-1]])
        prev_eff = cp.vstack([cp.reshape(self.up_eff, (1, m), order="C"), self.U[:-1]])
        W = cp.reshape(self.w, (1, n), order="C")
        cost = 0.5 * cp.sum_squares((Z - self.r) @ Lq.T) + 0.5 * cp.sum_squares((self.U - prev) @ Ls.T)
        cost += cp.sum(0.5 * cp.square(eps_v) @ np.diag(qp.rho_q) + eps_v @ np.diag(qp.rho_l))
        cons = [
            X[0] == self.x0,
            X[1:] == X[:-1] @ qp.A.T + self.U @ qp.B.T + np.ones((N, 1)) @ W,
            self.U - np.tile(qp.u_min, (N, 1)) >= 0,
            self.U - np.tile(qp.u_max, (N, 1)) <= 0,
            eps_v >= 0,
        ]
        finite_z_lo, finite_z_hi = np.isfinite(qp.z_min), np.isfinite(qp.z_max)
        if finite_z_lo.all():
            cons.append(Z + eps_v >= np.tile(qp.z_min, (N, 1)))
        if finite_z_hi.all():
            cons.append(Z - eps_v <= np.tile(qp.z_max, (N, 1)))
        if not (finite_z_lo.all() and finite_z_hi.all()):
            raise ValueError("the comparators need finite output bounds on every controlled output")
        if np.all(np.isfinite(qp.d_max)) and np.all(np.isfinite(qp.d_min)):
            moves = self.U - prev_eff
            if not qp.first_move_rate_limited:
                moves = moves[1:]
            cons += [
                moves <= np.tile(qp.d_max, (moves.shape[0], 1)),
                moves >= np.tile(qp.d_min, (moves.shape[0], 1)),
            ]
        self.problem = cp.Problem(cp.Minimize(cost), cons)
        if not self.problem.is_dpp():
            raise ValueError("the cvxpy formulation must be DPP so that it is canonicalised once")
        self.kwargs: dict[str, Any] = {"warm_start": True}
        if solver is not None:
            self.kwargs["solver"] = solver
        if solver == "OSQP":
            if eps is None:
                raise ValueError("OSQP needs eps")
            self.kwargs.update(
                eps_abs=eps,
                eps_rel=eps,
                polishing=True,
                max_iter=max_iter,
                adaptive_rho_interval=50,
                check_termination=5,
            )
        self.solver_name = solver or "?"

    def solve(self, state: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray) -> SolveRecord:
        """Set the parameters and time ``problem.solve()`` [s]."""
        x0, w, rt, up, up_eff = self.qp.inputs(state, eta, r, u_prev)
        self.x0.value, self.w.value, self.r.value = x0, w, rt
        self.up.value, self.up_eff.value = up, up_eff
        t0, c0 = time.perf_counter(), time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "solution may be inaccurate" is reported as a status
            self.problem.solve(**self.kwargs)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        stats = self.problem.solver_stats
        self.solver_name = str(stats.solver_name) if stats is not None else "?"
        solver_s = float(stats.solve_time) if stats is not None and stats.solve_time is not None else np.nan
        U = self.U.value
        u0 = self.qp.u_abs(U[0]) if U is not None else np.full(self.qp.m, np.nan)
        return SolveRecord(wall, solver_s, str(self.problem.status), u0, cpu)


class DoMpc:
    """The scaled QP as a do-mpc MPC (discrete linear model, IPOPT through CasADi).

    do-mpc has no rate constraints of its own, and its nonlinear constraints see (x_k, u_k, tvp_k)
    only; so the model state is augmented with the previous input, ``up(k+1) = u(k)``, and the
    move cost and rate bounds are written on ``u - up``. The output slacks are extra inputs
    (bounded below by 0) with the controller's quadratic + linear penalty, and the output rows
    and tracking cost use z~(k+1) = Cz~ (A~ x~(k) + B~ u~(k) + w~), which is the controller's
    cost and constraints on z(1..Np) exactly. w~ and r~ are time-varying parameters. IPOPT runs
    with do-mpc's defaults (tolerance 1e-8, MUMPS) and do-mpc's own warm start (the previous
    solution and multipliers); output suppressed.
    """

    def __init__(self, qp: ScaledQp, ts_s: float) -> None:
        import casadi
        import do_mpc

        self.qp = qp
        n, m, nz = qp.n, qp.m, qp.nz
        model = do_mpc.model.Model("discrete")
        x = model.set_variable("_x", "x", (n, 1))
        up = model.set_variable("_x", "up", (m, 1))
        u = model.set_variable("_u", "u", (m, 1))
        e = model.set_variable("_u", "eps", (nz, 1))
        w = model.set_variable("_tvp", "w", (n, 1))
        r = model.set_variable("_tvp", "r", (nz, 1))
        A, B, Cz = (casadi.DM(a) for a in (qp.A, qp.B, qp.Cz))
        model.set_rhs("x", A @ x + B @ u + w)
        model.set_rhs("up", u)
        model.setup()
        z_next = Cz @ (A @ x + B @ u + w)
        ez = z_next - r
        du = u - up
        lterm = 0.5 * casadi.mtimes([ez.T, casadi.DM(qp.Q), ez]) + 0.5 * casadi.mtimes(
            [du.T, casadi.DM(qp.S), du]
        )
        lterm += casadi.sum1(0.5 * casadi.DM(qp.rho_q) * e**2 + casadi.DM(qp.rho_l) * e)
        mpc = do_mpc.controller.MPC(model)
        mpc.settings.n_horizon = qp.N
        mpc.settings.t_step = ts_s
        mpc.settings.n_robust = 0
        mpc.settings.store_full_solution = False
        mpc.settings.supress_ipopt_output()
        mpc.set_objective(lterm=lterm, mterm=casadi.DM(0.0))
        mpc.set_rterm(u=0.0, eps=0.0)  # the move cost is in lterm (on u - up, see above)
        mpc.bounds["lower", "_u", "u"] = qp.u_min
        mpc.bounds["upper", "_u", "u"] = qp.u_max
        mpc.bounds["lower", "_u", "eps"] = np.zeros(nz)
        mpc.set_nl_cons("z_hi", z_next - e, ub=qp.z_max)
        mpc.set_nl_cons("z_lo", -z_next - e, ub=-qp.z_min)
        if np.all(np.isfinite(qp.d_max)) and np.all(np.isfinite(qp.d_min)):
            if not qp.first_move_rate_limited:
                raise ValueError("the do-mpc comparator implements first_move_rate_limited=True only")
            mpc.set_nl_cons("rate_hi", du, ub=qp.d_max)
            mpc.set_nl_cons("rate_lo", -du, ub=-qp.d_min)
        self._tvp = mpc.get_tvp_template()
        self._w = np.zeros(n)
        self._r = np.zeros((qp.N, nz))

        def tvp_fun(_t_now: float) -> Any:
            for k in range(qp.N + 1):
                self._tvp["_tvp", k, "w"] = self._w
                self._tvp["_tvp", k, "r"] = self._r[min(k, qp.N - 1)]
            return self._tvp

        mpc.set_tvp_fun(tvp_fun)
        mpc.setup()
        mpc.x0 = np.zeros(n + m)
        mpc.set_initial_guess()
        self.mpc = mpc
        # CasADi 3.8's IPOPT stats carry no total time: time do-mpc's solve() (the nlpsol call
        # that make_step makes) to split make_step into solver and do-mpc bookkeeping.
        self._solve_s = float("nan")
        inner = mpc.solve

        def timed_solve() -> None:
            t0 = time.perf_counter()
            inner()
            self._solve_s = time.perf_counter() - t0

        mpc.solve = timed_solve

    def solve(self, state: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray) -> SolveRecord:
        """Set the time-varying parameters and time ``make_step`` [s] (solver: its NLP solve)."""
        x0, w, rt, _up, up_eff = self.qp.inputs(state, eta, r, u_prev)
        self._w, self._r = w, rt
        xa = np.concatenate([x0, up_eff]).reshape(-1, 1)
        t0, c0 = time.perf_counter(), time.process_time()
        u = self.mpc.make_step(xa)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        status = str(self.mpc.solver_stats.get("return_status", "?"))
        u0 = self.qp.u_abs(np.asarray(u).reshape(-1)[: self.qp.m])
        return SolveRecord(wall, self._solve_s, status, u0, cpu)
