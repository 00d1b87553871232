r"""The MPC's quadratic program: model, optimal control problem, scaling, condensed and sparse forms.

Model
-----
Discrete linear model in deviations around an operating point (x_op levels [m], u_op pump flows
[m^3/s]) that must be an equilibrium of the model (seeds digest 1.1)::

    dx(k+1) = A dx(k) + B du(k) + Bd eta          dx = x - x_op  (n,) [m]
    y(k)    = C x(k)   (measured, (ny,) [m])      du = u - u_op  (m,) [m^3/s]
    z(k)    = Cz x(k)  (controlled, (nz,) [m])    eta: integrating disturbance, held constant

The public API takes and returns absolute values (levels m, flows m^3/s); deviations are internal.

Optimal control problem (digest 2.5, its slips corrected), solved every sample::

    min  1/2 sum_{k=1..Np} ||z(k) - r(k)||^2_Qz + 1/2 sum_{k=0..Np-1} ||u(k) - u(k-1)||^2_S
       + 1/2 sum_{k=0..Np-1} ||u(k) - u_ss||^2_R
       + sum_{k=1..Np} sum_i ( 1/2 rho_q,i eps_i(k)^2 + rho_l,i eps_i(k) )
    s.t. u_min <= u(k) <= u_max                               k = 0..Np-1
         du_min <= u(k) - u(k-1) <= du_max                    k = 0..Np-1  (k = 1..Np-1 paper-literal)
         z_min - eps(k) <= z(k) <= z_max + eps(k),  eps(k) >= 0   k = 1..Np
         x(0) = x(k|k) estimated, eta = eta(k|k) estimated, held constant over the horizon

u(-1) is the previously APPLIED input. R = 0 by default (the 2.5 form); with R > 0 (the 2.4
variant) u_ss is the steady-state input of the target problem below, so R does not cost offset.
The output bounds are soft: eps are slack variables with an exact (linear) penalty rho_l larger than
the multipliers of the hard problem, plus a quadratic term, so the QP is always feasible and its
solution equals the hard-bounded one whenever that exists (and rho_l exceeds its multipliers).
Input bounds are hard.

Offset-free design
------------------
Integrating input disturbances (Bd = B by default, Ad = I, C_eta = 0) estimated by the steady-state
Kalman filter of ``supervisor.estimator`` from the measured outputs selected by
``MpcConfig.estimator_outputs``. The prediction uses the augmented model with eta held constant and
penalises z - r directly. At a closed-loop steady state with n_eta = number of filtered outputs the
innovation is zero, so the model predicts the plant, and a constant plan with z != r is not optimal
(moving u lowers the tracking cost at first order, the move cost only at second order): the
offset is zero. The observability condition rank [[I - A, -Bd], [C, 0]] = n + n_eta is checked at
construction. For R > 0, u_ss comes from the offset-free target problem (least-squares solution of
[[I - A, -B], [Cz, 0]] [x_s; u_s] = [Bd eta; r(Np)] in scaled deviations).

Scaling
-------
Every solver is given the problem in dimensionless variables, fractions of their ranges: with
unscaled flows of 1e-4 m^3/s next to levels of 0.4 m, OSQP's absolute tolerances exceed the whole
input range and its iterations stall, and daqp's primal and dual tolerances would mean different
things per variable (docs/mpc.md)::

    x~ = (x - x_op) / s_x,  u~ = (u - u_op) / s_u,  z~ = (z - Cz x_op) / s_z,  eps~ = eps / s_z
    s_u = u_max - u_min;  s_z = z_max - z_min where finite, else max_j |Cz_ij| s_x,j;
    s_x = MpcConfig.x_scale (default: the largest finite output range, e.g. Hmax, for every state)

    A~ = Dx^-1 A Dx,  B~ = Dx^-1 B Du,  Cz~ = Dz^-1 Cz Dx,  w~ = Dx^-1 Bd eta
    Qz~ = Dz Qz Dz / c,  S~ = Du S Du / c,  R~ = Du R Du / c,
    rho_q~ = rho_q s_z^2 / c,  rho_l~ = rho_l s_z / c,
    c = largest diagonal entry of Dz Qz Dz, Du S Du, Du R Du

so the scaled cost is the SI cost divided by c: the same minimiser, and the solver's absolute
tolerances refer to fractions of the ranges. Weights are given in SI units (Qz [1/m^2], S and R
[1/(m^3/s)^2], rho_q [1/m^2], rho_l [1/m]); the default slack weights are rho_l~ = max(10, Np / 2)
and rho_q~ = 1 in scaled units: about ten times the largest output-bound multiplier measured on
the three-tank model (1.0, 1.5 and 6.9 at Np = 10, 40, 160), and no larger, because OSQP scales
the cost by max |q| and a huge rho_l~ stalls ADMM. The scaled QP, with the stacked input
U~ = [u~(0); ...; u~(Np-1)]::

    min 1/2 v' P v + q' v   s.t.  l <= Aqp v <= u

Condensed (v = [U~; eps~]): Z~ = Phi x~0 + Psi w~ + Gamma U~ with Phi = (I (x) Cz~) [A~; ...; A~^Np],
Psi = (I (x) Cz~) [I; I + A~; ...; sum_{i<Np} A~^i], Gamma lower block-triangular with blocks
Cz~ A~^(k-1-j) B~. P = blkdiag(Gamma' Qbar Gamma + D' Sbar D + Rbar, diag(rho_q~)),
q = [Gamma' Qbar (f - R~) - E1 S~ u~(-1) - Rbar U~ss; rho_l~] with f = Phi x~0 + Psi w~, D the
block bidiagonal difference matrix (I on the diagonal, -I below) and E1 the first block column.
Rows: U~ in [u~min, u~max]; D U~ in [du~min, du~max] shifted by u~(-1) in the first row;
Gamma U~ + eps~ >= z~min - f; Gamma U~ - eps~ <= z~max - f; eps~ >= 0.

Sparse (v = [X~; U~; eps~], X~ = [x~(1); ...; x~(Np)]): the dynamics are equality rows
x~(k+1) - A~ x~(k) - B~ u~(k) = w~ (first row: = A~ x~0 + w~); the cost and output rows act on
Cz~ x~(k) directly, so P is block diagonal and only the first dynamics row and q depend on the step.

``formulation="auto"`` picks condensed for Np < ``SPARSE_FROM_HORIZON`` and sparse from there on
(threshold measured with the backends of :mod:`supervisor.mpc.backends`, docs/decisions/0027).
Both give the same solution. The QP is built once per model (:meth:`QpFormulation.matrices`, on
a fixed sparsity pattern so that a re-linearisation only replaces values) and only q, l and u
change per step (:meth:`QpFormulation.vectors`).

The module is pure: no clock, no I/O, no logging.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from supervisor.mpc.backends import SoftRows
from supervisor.mpc.cost import PlanCost
from supervisor.mpc.model import (
    BoolArray,
    FloatArray,
    MpcConfig,
    MpcModel,
    PendingPrediction,
    sqrt_psd,
    vector,
    weight,
)

_ONE = np.ones(1)

#: Horizon from which ``formulation="auto"`` uses the sparse QP (measured, docs/decisions/0027).
SPARSE_FROM_HORIZON = 200

# Default slack weights in scaled, normalised units (see the module docstring and docs/mpc.md):
# rho_l~ = max(_SLACK_LINEAR_MIN, _SLACK_LINEAR_PER_STEP * Np) exceeds the output-bound multipliers
# measured on the three-tank model (at most 1.0 / 1.5 / 6.9 at Np = 10 / 40 / 160) about tenfold;
# far larger values make OSQP's cost scaling (driven by max |q|) stall the ADMM iterations.
_SLACK_LINEAR_MIN = 10.0
_SLACK_LINEAR_PER_STEP = 0.5
_SLACK_QUADRATIC = 1.0


def _csc(values: FloatArray, mask: BoolArray) -> sp.csc_matrix:
    """CSC matrix holding ``values`` on every True entry of ``mask`` (explicit zeros kept).

    The data order (column-major over ``mask``) is what OSQP's ``update(Px=..., Ax=...)`` expects (``.data``),
    so a fixed mask gives a fixed sparsity pattern across model updates.
    """
    cols, rows = np.nonzero(mask.T)  # transposed: column-major order, rows sorted in each column
    indptr = np.zeros(mask.shape[1] + 1, dtype=np.int64)
    np.cumsum(np.bincount(cols, minlength=mask.shape[1]), out=indptr[1:])
    return sp.csc_matrix((values[rows, cols], rows, indptr), shape=mask.shape)


def _shift_index(offset: int, blocks: int, size: int) -> NDArray[np.int64]:
    """Indices that shift ``blocks`` consecutive blocks of ``size`` one block forward (last repeated)."""
    if blocks == 0 or size == 0:
        return np.zeros(0, dtype=np.int64)
    idx = np.concatenate([np.arange(size, blocks * size), np.arange((blocks - 1) * size, blocks * size)])
    return (idx + offset).astype(np.int64)


def resolve(config: MpcConfig) -> tuple[Literal["condensed", "sparse"], Literal["daqp", "osqp"]]:
    """The QP form and the backend of a configuration ("auto" resolved, see ``MpcConfig``)."""
    form = config.formulation
    if form == "auto":
        form = "sparse" if config.horizon >= SPARSE_FROM_HORIZON and config.solver != "daqp" else "condensed"
    solver = config.solver
    if solver == "auto":
        solver = "daqp" if form == "condensed" else "osqp"
    return form, solver


class QpFormulation:
    """The scaled QP of one model and configuration, and the maps between it and SI values.

    Holds the validated bounds [SI], the scales s_x, s_u, s_z, the scaled weights and the block
    layout of the variables v and rows of ``l <= Aqp v <= u`` (module docstring). Pure: the
    controller asks it for the per-step vectors and for the plan, prediction and cost of a
    solution; solvers never see SI values.
    """

    def __init__(self, model: MpcModel, config: MpcConfig, Bd: FloatArray) -> None:
        self.model = model
        self.config = config
        n, m, nz = model.n_states, model.n_inputs, model.n_controlled
        N = config.horizon
        self.n, self.m, self.nz, self.N = n, m, nz, N
        self.Bd = Bd
        self.n_eta = Bd.shape[1]
        # -- bounds ------------------------------------------------------------------------------
        self.u_min = vector(config.u_min, m, "u_min")
        self.u_max = vector(config.u_max, m, "u_max")
        if np.any(self.u_min >= self.u_max):
            raise ValueError("u_min must be < u_max element-wise")
        self.du_min = vector(config.du_min, m, "du_min", allow_inf=True)
        self.du_max = vector(config.du_max, m, "du_max", allow_inf=True)
        if np.any(self.du_min > 0.0) or np.any(self.du_max < 0.0) or np.any(self.du_min >= self.du_max):
            raise ValueError("rate bounds need du_min <= 0 <= du_max and du_min < du_max element-wise")
        self.z_min = vector(config.z_min, nz, "z_min", allow_inf=True)
        self.z_max = vector(config.z_max, nz, "z_max", allow_inf=True)
        if np.any(self.z_min >= self.z_max) or np.any(self.z_min == np.inf) or np.any(self.z_max == -np.inf):
            raise ValueError("output bounds need z_min < z_max element-wise (z_min < inf, z_max > -inf)")
        self.has_z_rows = bool(np.any(np.isfinite(self.z_min)) or np.any(np.isfinite(self.z_max)))
        self.rate_rows = N if config.first_move_rate_limited else N - 1
        self.has_rate_rows = bool(np.any(np.isfinite(self.du_min)) or np.any(np.isfinite(self.du_max)))
        # where u(-1) is clipped to so that its rate window meets the input box [m^3/s]
        self.symmetric_rates = bool(np.array_equal(self.du_min, -self.du_max))
        # the same as Python floats for the projection's per-move loops
        self.u_min_list, self.u_max_list = self.u_min.tolist(), self.u_max.tolist()
        self.du_min_list, self.du_max_list = self.du_min.tolist(), self.du_max.tolist()
        self.u_prev_min_list = (self.u_min - self.du_max).tolist()
        self.u_prev_max_list = (self.u_max - self.du_min).tolist()
        if not self.has_rate_rows:
            self.rate_rows = 0

        # -- scaling -----------------------------------------------------------------------------
        z_range = self.z_max - self.z_min
        finite_range = z_range[np.isfinite(z_range)]
        if config.x_scale is None:
            sx_default = float(np.max(finite_range)) if finite_range.size else 1.0
            self.sx = np.full(n, sx_default)
        else:
            self.sx = vector(config.x_scale, n, "x_scale")
            if np.any(self.sx <= 0.0):
                raise ValueError("x_scale must be > 0")
        self.su = self.u_max - self.u_min
        sz_from_x = np.max(np.abs(model.Cz) * self.sx[None, :], axis=1)
        self.sz = np.where(np.isfinite(z_range), z_range, sz_from_x)
        if np.any(self.sz <= 0.0):
            raise ValueError("every row of Cz must be nonzero (a controlled output needs a scale)")

        # -- weights -----------------------------------------------------------------------------
        self.Qz = weight(config.Qz, nz, "Qz")
        self.S = weight(config.S, m, "S")
        self.R = weight(config.R, m, "R")
        self.Lq, self.Ls, self.Lr = (sqrt_psd(W) for W in (self.Qz, self.S, self.R))
        Dz, Du = np.diag(self.sz), np.diag(self.su)
        scaled = [Dz @ self.Qz @ Dz, Du @ self.S @ Du, Du @ self.R @ Du]
        self.c = max(float(np.max(np.diag(W))) for W in scaled)
        if not self.c > 0.0:
            raise ValueError("Qz, S and R are all zero: the cost has no weight")
        self.Qt, self.St, self.Rt = (W / self.c for W in scaled)
        self.use_R = bool(np.any(self.R != 0.0))
        if config.slack_linear is None:
            self.rho_l_t = np.full(nz, max(_SLACK_LINEAR_MIN, _SLACK_LINEAR_PER_STEP * N))
        else:
            rho_l = vector(config.slack_linear, nz, "slack_linear")
            if np.any(rho_l <= 0.0):
                raise ValueError("slack_linear must be > 0")
            self.rho_l_t = rho_l * self.sz / self.c
        if config.slack_quadratic is None:
            self.rho_q_t = np.full(nz, _SLACK_QUADRATIC)
        else:
            rho_q = vector(config.slack_quadratic, nz, "slack_quadratic")
            if np.any(rho_q < 0.0):
                raise ValueError("slack_quadratic must be >= 0")
            self.rho_q_t = rho_q * self.sz**2 / self.c
        self.slack_si = self.slack_weights  # fixed from here on
        self.half_rho_q_si, self.rho_l_si = 0.5 * self.slack_si[0], self.slack_si[1]

        # -- form and solver ---------------------------------------------------------------------
        self.formulation, self.solver = resolve(config)
        self.layout()
        self.set_model(model, Bd)

    @property
    def slack_weights(self) -> tuple[FloatArray, FloatArray]:
        """(rho_q [1/m^2], rho_l [1/m]), each (nz,), of the output slacks in SI units."""
        return self.c * self.rho_q_t / self.sz**2, self.c * self.rho_l_t / self.sz

    def set_model(self, model: MpcModel, Bd: FloatArray) -> None:
        """Take a (re-linearised) model and disturbance matrix: the scaled model, the prediction
        matrices and the constant parts of the per-step vectors."""
        self.model = model
        self.Bd = Bd
        self.set_model_matrices(model.A, model.B)
        self.cost = PlanCost(
            Lq=self.Lq,
            Ls=self.Ls,
            Lr=self.Lr,
            use_R=self.use_R,
            steady_state_target=self.config.input_target != "operating_point",
            target_pinv=self.target_pinv,
            n=self.n,
            Bd=Bd,
            sx=self.sx,
            u_op=model.u_op,
            su=self.su,
            z_op=model.Cz @ model.x_op,
            sz=self.sz,
            z_min=self.z_min,
            z_max=self.z_max,
            has_z_rows=self.has_z_rows,
            half_rho_q=self.half_rho_q_si,
            rho_l=self.rho_l_si,
        )
        self.set_vector_bases()
        self.set_vector_map()
        self.set_prediction_map()

    def layout(self) -> None:
        """Offsets of the variable and constraint blocks, and the warm-start shift indices."""
        n, m, nz, N = self.n, self.m, self.nz, self.N
        ns = N * nz if self.has_z_rows else 0
        if self.formulation == "sparse":
            self.x_off, self.u_off = 0, N * n
        else:
            self.x_off, self.u_off = 0, 0
        nx_vars = N * n if self.formulation == "sparse" else 0
        self.eps_off = nx_vars + N * m
        self.nv = self.eps_off + ns
        # rows: [dynamics (sparse)] [u bounds] [rates] [z low] [z high] [eps >= 0]
        r = 0
        self.row_dyn = r
        r += nx_vars
        self.row_u = r
        r += N * m
        self.row_rate = r
        r += self.rate_rows * m
        self.row_zlo = r
        r += ns
        self.row_zhi = r
        r += ns
        self.row_eps = r
        r += ns
        self.nc = r
        self.shift_x = np.concatenate(
            [
                _shift_index(self.x_off, N, n) if nx_vars else np.zeros(0, dtype=np.int64),
                _shift_index(self.u_off, N, m),
                _shift_index(self.eps_off, N, nz) if ns else np.zeros(0, dtype=np.int64),
            ]
        )
        self.shift_y = np.concatenate(
            [
                _shift_index(self.row_dyn, N, n) if nx_vars else np.zeros(0, dtype=np.int64),
                _shift_index(self.row_u, N, m),
                _shift_index(self.row_rate, self.rate_rows, m),
                _shift_index(self.row_zlo, N, nz) if ns else np.zeros(0, dtype=np.int64),
                _shift_index(self.row_zhi, N, nz) if ns else np.zeros(0, dtype=np.int64),
                _shift_index(self.row_eps, N, nz) if ns else np.zeros(0, dtype=np.int64),
            ]
        )

    def set_model_matrices(self, A: FloatArray, B: FloatArray) -> None:
        """Scaled model, condensed prediction matrices and the steady-state target map."""
        n, m, N = self.n, self.m, self.N
        Dx_inv = np.diag(1.0 / self.sx)
        self.A = A
        self.B = B
        self.At = Dx_inv @ A @ np.diag(self.sx)
        self.Bt = Dx_inv @ B @ np.diag(self.su)
        self.Czt = np.diag(1.0 / self.sz) @ self.model.Cz @ np.diag(self.sx)
        self.QtCzt = self.Qt.T @ self.Czt  # the sparse form's q on the states, per stage
        # condensed prediction (also used for exact output prediction of any plan)
        Phi = np.zeros((N * n, n))
        Psi = np.zeros((N * n, n))
        Gam = np.zeros((N * n, N * m))
        AkB = []
        M = self.Bt
        for _ in range(N):
            AkB.append(M)
            M = self.At @ M
        Ak = np.eye(n)
        Ssum = np.zeros((n, n))
        for k in range(1, N + 1):
            Ssum = Ssum + Ak
            Ak = self.At @ Ak
            rs = slice((k - 1) * n, k * n)
            Phi[rs] = Ak
            Psi[rs] = Ssum
            for j in range(k):
                Gam[rs, j * m : (j + 1) * m] = AkB[k - 1 - j]
        Cbar = np.kron(np.eye(N), self.Czt)
        self.Phi_z = Cbar @ Phi
        self.Psi_z = Cbar @ Psi
        self.Gam_z = Cbar @ Gam
        # z~(1..Np) = Zx dx0 + Zeta eta + Gam_z U~ (unscaled dx0 and eta, _scaled_z)
        self.Zx = self.Phi_z / self.sx[None, :]
        self.Zeta = self.Psi_z @ (self.Bd / self.sx[:, None])
        # steady-state target: [[I - A~, -B~], [Cz~, 0]] [x~s; u~s] = [w~; r~]
        T = np.block([[np.eye(n) - self.At, -self.Bt], [self.Czt, np.zeros((self.nz, m))]])
        self.target_pinv = np.linalg.pinv(T)

    def qp_matrices(self) -> tuple[sp.csc_matrix, sp.csc_matrix]:
        """P (upper triangle) and the constraint matrix, on the fixed sparsity pattern."""
        P, Pmask, Aqp, Amask = self.qp_dense()
        self.Pmask, self.Amask = Pmask, Amask
        return _csc(P, Pmask), _csc(Aqp, Amask)

    def qp_dense(self) -> tuple[FloatArray, BoolArray, FloatArray, BoolArray]:
        """P (upper triangle) and Aqp as dense arrays, with the masks of their structural entries."""
        n, m, nz, N = self.n, self.m, self.nz, self.N
        nv, nc = self.nv, self.nc
        ns = N * nz if self.has_z_rows else 0
        P = np.zeros((nv, nv))
        Pmask = np.zeros((nv, nv), dtype=bool)
        Aqp = np.zeros((nc, nv))
        Amask = np.zeros((nc, nv), dtype=bool)
        uo, eo = self.u_off, self.eps_off
        us = slice(uo, uo + N * m)
        # difference matrix D (N m x N m): I on the diagonal, -I on the first sub-diagonal
        D = np.eye(N * m) - np.eye(N * m, k=-m)
        Sbar = np.kron(np.eye(N), self.St)
        Rbar = np.kron(np.eye(N), self.Rt)
        Qbar = np.kron(np.eye(N), self.Qt)
        Puu = D.T @ Sbar @ D + Rbar
        if self.formulation == "condensed":
            Puu = Puu + self.Gam_z.T @ Qbar @ self.Gam_z
            P[us, us] = Puu
            Pmask[us, us] = np.triu(np.ones((N * m, N * m), dtype=bool))
        else:
            xs = slice(self.x_off, self.x_off + N * n)
            P[xs, xs] = np.kron(np.eye(N), self.Czt.T @ self.Qt @ self.Czt)
            Pmask[xs, xs] = np.kron(np.eye(N, dtype=bool), np.triu(np.ones((n, n), dtype=bool)))
            P[us, us] = Puu
            band = np.kron(np.eye(N, dtype=bool), np.ones((m, m), dtype=bool))
            band |= np.kron(np.eye(N, k=1, dtype=bool), np.ones((m, m), dtype=bool))
            Pmask[us, us] = np.triu(band)
            # dynamics: x(k+1) - A x(k) - B u(k) = w
            r0 = self.row_dyn
            for k in range(N):
                rows = slice(r0 + k * n, r0 + (k + 1) * n)
                Aqp[rows, k * n : (k + 1) * n] = np.eye(n)
                Amask[rows, k * n : (k + 1) * n] = np.eye(n, dtype=bool)
                if k > 0:
                    Aqp[rows, (k - 1) * n : k * n] = -self.At
                    Amask[rows, (k - 1) * n : k * n] = True
                Aqp[rows, uo + k * m : uo + (k + 1) * m] = -self.Bt
                Amask[rows, uo + k * m : uo + (k + 1) * m] = True
        if ns:
            es = slice(eo, eo + ns)
            P[es, es] = np.diag(np.tile(self.rho_q_t, N))
            Pmask[es, es] = np.eye(ns, dtype=bool)
        # input bounds
        Aqp[self.row_u : self.row_u + N * m, us] = np.eye(N * m)
        Amask[self.row_u : self.row_u + N * m, us] = np.eye(N * m, dtype=bool)
        # rate rows (all N, or the last N - 1 paper-literal)
        if self.rate_rows:
            first = N - self.rate_rows
            rr = slice(self.row_rate, self.row_rate + self.rate_rows * m)
            Aqp[rr, us] = D[first * m :]
            Amask[rr, us] = D[first * m :] != 0.0
        if ns:
            zlo = slice(self.row_zlo, self.row_zlo + ns)
            zhi = slice(self.row_zhi, self.row_zhi + ns)
            if self.formulation == "condensed":
                gmask = np.kron(np.tril(np.ones((N, N), dtype=bool)), np.ones((nz, m), dtype=bool))
                for rows in (zlo, zhi):
                    Aqp[rows, us] = self.Gam_z
                    Amask[rows, us] = gmask
            else:
                xs = slice(self.x_off, self.x_off + N * n)
                cz = np.kron(np.eye(N), self.Czt)
                czmask = np.kron(np.eye(N, dtype=bool), np.ones((nz, n), dtype=bool))
                for rows in (zlo, zhi):
                    Aqp[rows, xs] = cz
                    Amask[rows, xs] = czmask
            Aqp[zlo, es] = np.eye(ns)
            Aqp[zhi, es] = -np.eye(ns)
            Aqp[self.row_eps : self.row_eps + ns, es] = np.eye(ns)
            for rows in (zlo, zhi, slice(self.row_eps, self.row_eps + ns)):
                Amask[rows, es] = np.eye(ns, dtype=bool)
        return P, Pmask, Aqp, Amask

    def soft_rows(self) -> SoftRows | None:
        """The output slacks as :class:`~supervisor.mpc.backends.SoftRows` (None without output
        bounds): eps~ of stage k and output i is the slack of rows z~low and z~high of the same
        stage and output, with the weights rho_q~ and rho_l~ (constant in q)."""
        if not self.has_z_rows:
            return None
        ns = self.N * self.nz
        k = np.arange(ns, dtype=np.int64)
        return SoftRows(
            columns=self.eps_off + k,
            bound_rows=self.row_eps + k,
            lower_rows=self.row_zlo + k,
            upper_rows=self.row_zhi + k,
            quadratic=np.tile(self.rho_q_t, self.N),
            linear=np.tile(self.rho_l_t, self.N),
        )

    def scaled_w(self, eta: FloatArray) -> FloatArray:
        return self.cost.scaled_w(eta)

    def u_target(self, w_t: FloatArray, r_t_last: FloatArray) -> FloatArray:
        """Scaled u_ss for the R term."""
        return self.cost.u_target(w_t, r_t_last)

    def set_vector_bases(self) -> None:
        """The parts of q, l and u that do not change from step to step (operating point fixed)."""
        m, nz, N = self.m, self.nz, self.N
        model = self.model
        ns = N * nz if self.has_z_rows else 0
        q = np.zeros(self.nv)
        lo = np.zeros(self.nc)
        up = np.zeros(self.nc)
        if ns:
            q[self.eps_off : self.eps_off + ns] = np.tile(self.rho_l_t, N)
        self.umin_t = (self.u_min - model.u_op) / self.su
        self.umax_t = (self.u_max - model.u_op) / self.su
        lo[self.row_u : self.row_u + N * m] = np.tile(self.umin_t, N)
        up[self.row_u : self.row_u + N * m] = np.tile(self.umax_t, N)
        self.dmin_t = self.du_min / self.su
        self.dmax_t = self.du_max / self.su
        if self.rate_rows:
            rr = slice(self.row_rate, self.row_rate + self.rate_rows * m)
            lo[rr] = np.tile(self.dmin_t, self.rate_rows)
            up[rr] = np.tile(self.dmax_t, self.rate_rows)
        self.z_op = model.Cz @ model.x_op
        self.y_op = model.C @ model.x_op
        if ns:
            zlo = slice(self.row_zlo, self.row_zlo + ns)
            zhi = slice(self.row_zhi, self.row_zhi + ns)
            lo[zlo] = np.tile((self.z_min - self.z_op) / self.sz, N)
            up[zlo] = np.inf
            lo[zhi] = -np.inf
            up[zhi] = np.tile((self.z_max - self.z_op) / self.sz, N)
            es = slice(self.row_eps, self.row_eps + ns)
            lo[es] = 0.0
            up[es] = np.inf
        self.q_base, self.l_base, self.u_base = q, lo, up

    def qp_vectors(
        self, dx0: FloatArray, eta: FloatArray, r_abs: FloatArray, u_prev: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q, l, u of the scaled QP for deviation state dx0, disturbance eta, absolute r (N, nz), u(-1)."""
        up_t = (u_prev - self.model.u_op) / self.su
        return self._vectors(dx0, eta, r_abs, up_t, self._rate_base(up_t))

    def _rate_base(self, up_t: FloatArray) -> FloatArray:
        """u~(-1) for the first rate row: clipped so that [u(-1) + du_min, u(-1) + du_max] and
        [u_min, u_max] intersect even if the applied u(-1) lies outside the input bounds (the
        physical bounds win)."""
        return np.minimum(np.maximum(up_t, self.umin_t - self.dmax_t), self.umax_t - self.dmin_t)

    def step_data(
        self, dx0: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray, u_base: list[float]
    ) -> FloatArray:
        """th = [dx0, eta, r, u(-1), u(-1) clipped, 1], the step's data for a constant reference
        r (nz,): the QP's vectors are [q; l; u] = ``vector_map`` th (equal to :meth:`qp_vectors`
        to rounding; the vectors are affine in th, :meth:`set_vector_map`). ``u_base`` is u(-1)
        [m^3/s] clipped to [u_min - du_max, u_max - du_min] (:meth:`rate_window_base`)."""
        return np.concatenate((dx0, eta, r, u_prev, u_base, _ONE))

    def rate_window_base(self, u_prev: list[float]) -> list[float]:
        """u(-1) [m^3/s] clipped so that its rate window [u(-1) + du_min, u(-1) + du_max] meets
        [u_min, u_max] (the physical bounds win), in Python floats (m numbers): the base of the
        first rate row and of the projection's first move."""
        bounds = zip(u_prev, self.u_prev_min_list, self.u_prev_max_list, strict=True)
        return [min(max(v, lo), hi) for v, lo, hi in bounds]

    def constant_r_vectors(
        self, dx0: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`qp_vectors` for a constant reference r (nz,) as one product (:meth:`step_data`)."""
        th = self.step_data(dx0, eta, r, u_prev, self.rate_window_base(u_prev.tolist()))
        out = self.vector_map @ th
        nv, nc = self.nv, self.nc
        return out[:nv], out[nv : nv + nc], out[nv + nc :]

    def set_vector_map(self) -> None:
        """The affine map [q; l; u] = M th of :meth:`step_data`, from :meth:`_vectors`
        at a base point and one step per entry of th of the size of its range (so that the
        differences carry no cancellation); rows infinite at the base are constant (+-inf)."""
        n, ne, nz, m = self.n, self.n_eta, self.nz, self.m
        w_per_eta = np.abs(self.Bd / self.sx[:, None]).max(axis=0, initial=0.0)
        eta_step = 1.0 / np.where(w_per_eta > 0.0, w_per_eta, 1.0)
        u_mid = 0.5 * (self.u_min + self.u_max)
        base = np.concatenate(
            [
                np.zeros(n),
                np.zeros(ne),
                self.z_op,
                u_mid,
                self.rate_window_base(u_mid.tolist()),
            ]
        )
        steps = np.concatenate([self.sx, eta_step, self.sz, 0.25 * self.su, 0.25 * self.su])
        cut = np.cumsum([n, ne, nz, m])

        def vectors(th: FloatArray) -> FloatArray:
            dx0, eta, r, u_prev, u_base = np.split(th, cut)
            r_abs = np.broadcast_to(r, (self.N, nz))
            up_t = (u_prev - self.model.u_op) / self.su
            up_eff = (u_base - self.model.u_op) / self.su
            return np.concatenate(self._vectors(dx0, eta, r_abs, up_t, up_eff))

        f0 = vectors(base)
        finite = np.isfinite(f0)
        J = np.zeros((f0.size, base.size))
        for j, h in enumerate(steps):
            th = base.copy()
            th[j] += h
            np.subtract(vectors(th), f0, out=J[:, j], where=finite)
            J[:, j] /= h
        self.vector_map = np.ascontiguousarray(np.column_stack([J, np.where(finite, f0 - J @ base, f0)]))

    def _vectors(
        self, dx0: FloatArray, eta: FloatArray, r_abs: FloatArray, up_t: FloatArray, up_eff: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q, l, u from the scaled u~(-1) (the move cost) and its clipped value (the rate row)."""
        n, m, nz, N = self.n, self.m, self.nz, self.N
        x0t = dx0 / self.sx
        wt = self.scaled_w(eta)
        rt = ((r_abs - self.z_op) / self.sz).reshape(-1)
        ns = N * nz if self.has_z_rows else 0
        q = self.q_base.copy()
        lo = self.l_base.copy()
        up = self.u_base.copy()
        us = slice(self.u_off, self.u_off + N * m)
        qu = q[us]  # view
        qu[:m] -= self.St @ up_t
        if self.use_R:
            uss_t = self.u_target(wt, rt[-nz:])
            qu -= np.tile(self.Rt @ uss_t, N)
        if self.formulation == "condensed":
            f = self.Phi_z @ x0t + self.Psi_z @ wt
            qu += self.Gam_z.T @ self.qbar_mul(f - rt)
            if ns:
                lo[self.row_zlo : self.row_zlo + ns] -= f
                up[self.row_zhi : self.row_zhi + ns] -= f
        else:
            q[self.x_off : self.x_off + N * n] = -(rt.reshape(N, nz) @ self.QtCzt).reshape(-1)
            dyn = lo[self.row_dyn : self.row_dyn + N * n].reshape(N, n)  # view
            dyn[:] = wt
            dyn[0] += self.At @ x0t
            up[self.row_dyn : self.row_dyn + N * n] = dyn.reshape(-1)
        if self.rate_rows and self.config.first_move_rate_limited:
            lo[self.row_rate : self.row_rate + m] += up_eff
            up[self.row_rate : self.row_rate + m] += up_eff
        return q, lo, up

    def qbar_mul(self, v: FloatArray) -> FloatArray:
        """(I_N (x) Qz~) v for v of length N nz."""
        return (v.reshape(self.N, self.nz) @ self.Qt.T).reshape(-1)

    # ------------------------------------------------------------------------------------------
    # a solution in SI terms
    # ------------------------------------------------------------------------------------------
    def plan_of(self, v: FloatArray) -> FloatArray:
        """The absolute plan u(0..Np-1) [m^3/s], (Np, m), of a solution v of the scaled QP."""
        u_t = v[self.u_off : self.u_off + self.N * self.m].reshape(self.N, self.m)
        plan = u_t * self.su
        plan += self.model.u_op  # u_op + u~ s_u (one array: addition commutes exactly)
        return plan

    def set_prediction_map(self) -> None:
        """The map of :meth:`predict_z` in SI units: z(1..Np) stacked = z_op (tiled) + Dz_N (Zx dx0
        + Zeta eta + Gam_z Du_N^-1 (U - u_op)), Dz_N = I_N (x) diag(s_z), Du_N = I_N (x) diag(s_u),
        as one matrix on [dx0; eta; U - u_op]."""
        N = self.N
        sz_N = np.tile(self.sz, N)[:, None]
        self.z_map = np.ascontiguousarray(
            np.hstack([sz_N * self.Zx, sz_N * self.Zeta, sz_N * self.Gam_z / np.tile(self.su, N)[None, :]])
        )
        self.z_op_N = np.tile(self.z_op, N)

    def predict_z(self, dx0: FloatArray, eta: FloatArray, plan: FloatArray) -> FloatArray:
        """z(1..Np) [m] of the linear model for the plan (exact prediction, any formulation; one
        product, :meth:`set_prediction_map`; what a result's ``predicted_z`` evaluates)."""
        return PendingPrediction(
            self.model.x_op, self.model.u_op, self.z_map, self.z_op_N, dx0, eta, plan
        ).predicted_z()

    def scaled_z(self, dx0: FloatArray, eta: FloatArray, u_t: FloatArray) -> FloatArray:
        """z~(1..Np) stacked, of dx0 [m], eta and U~ (vectors, or matrices column by column)."""
        return self.Zx @ dx0 + self.Zeta @ eta + self.Gam_z @ u_t
