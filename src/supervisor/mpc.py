r"""Constrained offset-free linear MPC on OSQP (pure core of the supervisor's MPC mode).

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
OSQP is given the problem in dimensionless variables, fractions of their ranges: with unscaled flows
of 1e-4 m^3/s next to levels of 0.4 m its absolute tolerances exceed the whole input range and its
iterations stall (measured in docs/mpc.md)::

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
(threshold measured on the development machine, docs/mpc.md). Both give the same solution.

Solver use
----------
The OSQP problem is set up once in the constructor; ``step`` only updates q, l and u (and the
tolerance settings, below) and warm-starts from the previous primal and dual solution shifted by
one sample. Before that, ``step`` looks for the exact optimum by active sets
(:class:`_ActiveSetQp`): the previous step's active set (the usual case near a steady state: one
triangular solve on a cached sparse LU), then primal-dual active-set corrections from that set
shifted by one sample (a rate-limited transient: the plan's active rate bounds move about one
sample per step), each set solved through a Schur complement on the last LU. A set whose
solution passes the KKT check to ``KKT_TOL`` gives the optimum, and OSQP does not run. A set that
is optimal twice in a row gets an affine law (:class:`_AffineLaw`): for a constant reference the
plan, its prediction, its cost and the KKT certificate are affine in [dx0, eta, r, u(-1), 1] on that
set, so the next steps are one matrix-vector product and a check until the set changes.
``update_model`` replaces A and B (and optionally the operating point) through OSQP's
matrix-value update on a fixed sparsity pattern (every structurally possible entry is stored).

Tolerance ladder. With the papers' tuning (S = I in SI units is ~4e-8 of the tracking weight after
scaling) the QP is nearly flat along "move timing" directions, so ADMM's residual test at a loose
tolerance accepts first moves that differ from the optimum by ~1 % of the input range, and active
output bounds converge slowly. Each step therefore solves with eps_abs = eps_rel = 1e-4, polishes
(an exact solve on the identified active set: the optimum whenever it succeeds), and only if the
polish fails continues the same ADMM iterates at 1e-5 and then 1e-6 (``MpcConfig.tolerances``),
within one iteration budget ``max_iter``. The last rung's solution is accepted polished or not.

The status is checked every step: a polished solution or one at the last rung -> SOLVED; a
looser rung's solution when a tighter one ran out of iterations, or OSQP's "solved inaccurate" ->
INACCURATE (the plan is used); no solution or a non-finite one -> HELD: the last safe plan shifted
by one sample is used (before any plan exists, u(-1) is held), and the failure is counted. Every
applied move and every returned plan is projected onto u_min <= u <= u_max and the rate limits
(relative to the applied u(-1); a u(-1) outside the input box is first clipped to where the rate
window meets it, the physical bounds win), so bounds hold exactly even at solver tolerance and on
the held path; NaN is never returned. Solve time is OSQP's own update + solve + polish time summed
over the rungs of the step [s] (0 when an active set gave the optimum); OSQP's adaptive rho
runs on an iteration count, so results are deterministic.

The module is pure: no clock, no I/O, no logging.
"""

from __future__ import annotations

import itertools
import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import osqp
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import lapack
from scipy.sparse.csgraph import reverse_cuthill_mckee

from supervisor.estimator import AugmentedKalmanFilter
from tanklab.enums import MpcStatus

__all__ = ["SPARSE_FROM_HORIZON", "MpcConfig", "MpcController", "MpcModel", "MpcResult", "SolvedBy"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Horizon from which ``formulation="auto"`` uses the sparse QP (measured, docs/mpc.md).
SPARSE_FROM_HORIZON = 20

# OSQP status values (osqp.SolverStatus; the names are stable across 1.x).
_OSQP_SOLVED = 1
_OSQP_SOLVED_INACCURATE = 2

# Default slack weights in scaled, normalised units (see the module docstring and docs/mpc.md):
# rho_l~ = max(_SLACK_LINEAR_MIN, _SLACK_LINEAR_PER_STEP * Np) exceeds the output-bound multipliers
# measured on the three-tank model (at most 1.0 / 1.5 / 6.9 at Np = 10 / 40 / 160) about tenfold;
# far larger values make OSQP's cost scaling (driven by max |q|) stall the ADMM iterations.
_SLACK_LINEAR_MIN = 10.0
_SLACK_LINEAR_PER_STEP = 0.5
_SLACK_QUADRATIC = 1.0


# ----------------------------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------------------------
def _as_float(value: ArrayLike, name: str) -> FloatArray:
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be numeric, got {type(value).__name__}")
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name} must be numeric, got {type(value).__name__}") from e


def _matrix(value: ArrayLike, name: str, rows: int | None, cols: int | None) -> FloatArray:
    arr = _as_float(value, name)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got shape {arr.shape}")
    if (rows is not None and arr.shape[0] != rows) or (cols is not None and arr.shape[1] != cols):
        raise ValueError(f"{name} must have shape ({rows}, {cols}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _vector(
    value: ArrayLike, size: int, name: str, *, allow_inf: bool = False, copy: bool = True
) -> FloatArray:
    """Scalar (broadcast) or 1-D of length ``size``; NaN never allowed, +-inf only if ``allow_inf``
    (``copy=False``: a float vector of the right shape comes back as it is, for values only read)."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (size,):
        # the per-step fast path (a float vector already): the value check
        if not (np.isfinite(value).all() if not allow_inf else not np.isnan(value).any()):
            raise ValueError(f"{name} must be {'non-NaN' if allow_inf else 'finite'}")
        return value.copy() if copy else value
    arr = _as_float(value, name)
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    if arr.shape != (size,):
        raise ValueError(f"{name} must be a scalar or have shape ({size},), got {arr.shape}")
    if np.any(np.isnan(arr)) or (not allow_inf and not np.all(np.isfinite(arr))):
        raise ValueError(f"{name} must be {'non-NaN' if allow_inf else 'finite'}")
    return arr


def _weight(value: ArrayLike, size: int, name: str) -> FloatArray:
    """A symmetric positive semidefinite weight: scalar, diagonal (size,) or full (size, size)."""
    arr = _as_float(value, name)
    if arr.ndim <= 1:
        W = np.diag(_vector(arr, size, name))
    else:
        W = _matrix(arr, name, size, size)
    if not np.allclose(W, W.T, rtol=1e-12, atol=0.0):
        raise ValueError(f"{name} must be symmetric")
    W = 0.5 * (W + W.T)
    if size and np.min(np.linalg.eigvalsh(W)) < -1e-12 * max(1.0, float(np.max(np.abs(W)))):
        raise ValueError(f"{name} must be positive semidefinite")
    return W


def _sqrt_psd(W: FloatArray) -> FloatArray:
    """L with L' L = W for a symmetric PSD W (the square roots of a diagonal W exactly)."""
    if np.count_nonzero(W - np.diag(np.diag(W))) == 0:
        return np.diag(np.sqrt(np.diag(W)))
    lam, V = np.linalg.eigh(W)
    return np.sqrt(np.clip(lam, 0.0, None))[:, None] * V.T


def _readonly(a: FloatArray) -> FloatArray:
    a.flags.writeable = False
    return a


def _csc(values: FloatArray, mask: BoolArray) -> sp.csc_matrix:
    """CSC matrix holding ``values`` on every True entry of ``mask`` (explicit zeros kept).

    The data order (column-major over ``mask``) is what OSQP's ``update(Px=..., Ax=...)`` expects,
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


# ----------------------------------------------------------------------------------------------
# exact solutions on an active set
# ----------------------------------------------------------------------------------------------
#: KKT certificate tolerance, absolute, in the scaled QP's units (fractions of the ranges; the cost
#: divided by c): primal feasibility, stationarity and the multipliers' signs. 1000 x tighter than
#: the last tolerance rung's 1e-6.
KKT_TOL = 1e-9

#: Factorisations kept, keyed by the active set (a steady state or a ramp revisits a few sets).
_KKT_CACHE = 8

#: Active sets that differ from the last sparse LU in at most this many rows are solved through a
#: Schur complement on that LU instead of a new factorisation (a transient moves a few rows per
#: step; measured in docs/mpc.md).
_SCHUR_MAX_ROWS = 48

#: Distinct rows bordered onto one LU before a new LU is made (the memory of its border columns).
_BORDER_ROWS = 4 * _SCHUR_MAX_ROWS

#: A bordered matrix whose smallest LU pivot is below this fraction of its largest is singular.
_SCHUR_PIVOT_MIN = 1e-13

#: Active sets tried per step by the primal-dual active-set corrections before OSQP runs.
PDAS_MAX_SETS = 12

#: Affine laws kept, keyed by the active set (:class:`_AffineLaw`).
_LAW_CACHE = 4

_ONE = np.ones(1)
_ZERO = np.zeros(1)

#: Margin [fraction of the range] by which an affine law's plan must clear its inactive input and
#: rate bounds: far above the rounding of the law's product, so the plan needs no projection.
_PLAN_MARGIN = 1e-12

_REPEATED = "skipped: the previous active set is optimal"

SolvedBy = Literal["law", "previous", "corrections", "osqp", "held"]


def _absmax(a: FloatArray) -> float:
    return float(np.abs(a).max()) if a.size else 0.0


@dataclass
class _KktSolution:
    """A solution of the scaled QP on an active set, checked against the KKT conditions."""

    x: FloatArray
    y: FloatArray
    z: FloatArray
    """A x."""
    certified: bool
    """Primal feasible, stationary and with multipliers of the right signs: the optimum."""


class _LuFactor:
    """Sparse LU of the KKT matrix of one active set (rows ``idx``), in the band order.

    Also keeps, per row bordered onto it by a :class:`_SchurFactor`, the border column c (sparse:
    its positions and values) and K^-1 c: a transient borders mostly the same rows step after
    step, so each is solved once.
    """

    def __init__(
        self, act: BoolArray, lu: spla.SuperLU, idx: NDArray[np.int64], pos: NDArray[np.int64], nv: int
    ) -> None:
        self.act = act
        self.idx = idx
        self.lu = lu
        self.pos = pos
        self.pos_v = pos[:nv]
        self.pos_w = pos[nv:]
        self.border_col: dict[int, int] = {}
        """Slot of a bordered constraint row in :attr:`c_pos`, :attr:`c_val` and :attr:`z_rows`."""
        self.c_pos: list[NDArray[np.int64]] = []
        """Per slot, the positions of the border column's nonzeros (a constraint row has a few)."""
        self.c_val: list[FloatArray] = []
        """Per slot, the values at :attr:`c_pos`."""
        self.z_rows = np.zeros((_BORDER_ROWS, pos.size))
        """Per slot, (K^-1 c)'."""

    def solve(self, q: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
        """v, y_W with P v + A_W' y_W = -q and A_W v = b (q, b vectors, or matrices column by column)."""
        rhs = np.empty((self.pos.size, *q.shape[1:]))
        rhs[self.pos_v] = -q
        rhs[self.pos_w] = b
        sol = self.lu.solve(rhs)
        return sol[self.pos_v], sol[self.pos_w]


class _SchurFactor:
    r"""The KKT system of an active set W solved on the LU of a nearby set W0 (bordered system).

    With K0 the KKT matrix of W0 (unknowns s = [v; y_W0]), each row i added (in W, not in W0)
    borders K0 with the column [a_i'; 0] and the equation a_i v = b_i (its multiplier is the
    border unknown t_i); each row j dropped (in W0, not in W) borders it with the unit column
    e_{y_j} and the equation y_j = 0 (t_j then takes up row j's equation, which no longer
    binds)::

        [ K0  C ] [ s ]   [ r0 ]
        [ C'  0 ] [ t ] = [ r1 ]   =>   (C' K0^-1 C) t = C' K0^-1 r0 - r1,   s = K0^-1 (r0 - C t)

    Z = K0^-1 C and the LU of the small dense M = C' Z are computed once per set (Z's columns once
    per row and base, :class:`_LuFactor`). C is kept sparse (``c_pos``, ``c_val``, the columns'
    nonzeros one after another from offsets ``starts``): a border column has a few nonzeros out
    of some 500 rows, so C' x is a gather and a segmented sum instead of a dense product.
    """

    def __init__(
        self,
        act: BoolArray,
        base: _LuFactor,
        idx: NDArray[np.int64],
        keep_t: NDArray[np.int64],
        keep_0: NDArray[np.int64],
        add_t: NDArray[np.int64],
        border: tuple[NDArray[np.int64], FloatArray, NDArray[np.int64]],
        Zt: FloatArray,
        M_lu: tuple[FloatArray, NDArray[np.int32]],
        n_add: int,
    ) -> None:
        self.act = act
        self.idx = idx
        self._base = base
        self._keep_t = keep_t
        self._pos_keep = base.pos_w[keep_0]
        self._add_t = add_t
        self._c_pos, self._c_val, self._starts = border
        self._Zt = Zt
        self._M_lu = M_lu
        self._n_add = n_add

    def solve(self, q: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
        """v, y_W with P v + A_W' y_W = -q and A_W v = b (q, b vectors, or matrices column by column)."""
        base = self._base
        cols = q.shape[1:]
        r0 = np.zeros((base.pos.size, *cols))
        r0[base.pos_v] = -q
        r0[self._pos_keep] = b[self._keep_t]
        s = base.lu.solve(r0)
        r1 = np.zeros((self._starts.size, *cols))
        r1[: self._n_add] = b[self._add_t]
        val = self._c_val if not cols else self._c_val[:, None]
        t, _ = lapack.dgetrs(*self._M_lu, np.add.reduceat(s[self._c_pos] * val, self._starts) - r1)
        s -= self._Zt.T @ t
        y = np.empty((self.idx.size, *cols))
        y[self._keep_t] = s[self._pos_keep]
        y[self._add_t] = t[: self._n_add]
        return s[base.pos_v], y


@dataclass
class _Correction:
    """The outcome of :meth:`_ActiveSetQp.correct`."""

    solution: _KktSolution | None
    """The certified optimum, or None if none of the sets tried was optimal."""
    lower: BoolArray
    upper: BoolArray
    sets: int
    """Active sets solved."""


@dataclass
class _AffineKkt:
    """The KKT solution of one active set as an affine function of a parameter vector.

    The QP's vectors are affine in the parameters, ``q = Qm th``, ``l = Lm th``, ``u = Um th``
    (th's last entry is 1), and on a fixed active set so is the KKT solution: ``x = X th``,
    ``y = Y th``, ``A x = Z th``. The certificate becomes linear too: the solution is the optimum
    to ``KKT_TOL`` iff ``checks @ th >= 0`` (inactive rows within their bounds and active
    multipliers of the right signs, the tolerance folded into the last column), provided the
    KKT residual, at most ``residual @ |th|``, is within ``KKT_TOL``.
    """

    x: FloatArray
    """(nv, p)"""
    y: FloatArray
    """(nc, p)"""
    checks: FloatArray
    """(k, p)"""
    residual: FloatArray
    """(p,): the largest KKT residual of each column of [X; Y]."""


def _pdas_step(
    sol: _KktSolution,
    lower: BoolArray,
    upper: BoolArray,
    lo: FloatArray,
    up: FloatArray,
    eq: BoolArray,
    single: bool,
) -> tuple[BoolArray, BoolArray]:
    """The next active set after ``sol`` (see :meth:`_ActiveSetQp.correct`)."""
    y, z = sol.y, sol.z
    free = ~(lower | upper)
    below = np.where(free, lo - z, 0.0)  # > 0: violated lower bound
    above = np.where(free, z - up, 0.0)
    wrong_l = np.where(lower & ~eq, y, 0.0)  # > 0: wrong sign on an active lower bound
    wrong_u = np.where(upper & ~eq, -y, 0.0)
    if not single:
        add_l, add_u = below > KKT_TOL, above > KKT_TOL
        new_lower = (lower & ~(wrong_l > KKT_TOL)) | add_l
        new_upper = ((upper & ~(wrong_u > KKT_TOL)) | add_u) & ~new_lower
        return new_lower, new_upper
    lower, upper = lower.copy(), upper.copy()
    worst = np.maximum(below, above)
    i = int(np.argmax(worst))
    if worst[i] > KKT_TOL:
        (lower if below[i] >= above[i] else upper)[i] = True
        return lower, upper
    wrong = np.maximum(wrong_l, wrong_u)
    i = int(np.argmax(wrong))
    lower[i] = upper[i] = False
    return lower, upper


class _ActiveSetQp:
    r"""Exact solutions of ``min 1/2 v'Pv + q'v s.t. l <= Av <= u`` on a given active set.

    With W the active rows (lower bound ``l`` or upper bound ``u``; equality rows always), the
    optimum of the equality-constrained problem solves the KKT system::

        [ P    A_W' ] [ v   ]   [ -q  ]
        [ A_W  0    ] [ y_W ] = [ b_W ],      b_W = l or u per row, y = 0 off W

    (OSQP's sign convention: y < 0 on an active lower bound, y > 0 on an active upper bound). The
    solution is the QP's optimum if and only if it also satisfies the inactive rows and the
    multipliers have the right signs (sufficient for a convex QP): :meth:`solve` checks both to
    ``KKT_TOL`` together with stationarity. Factorisations are sparse LU (SuperLU) of the KKT
    matrix in a reverse Cuthill-McKee order computed once (the QP is a chain of stages, so the
    order is a band); a set within ``_SCHUR_MAX_ROWS`` rows of the last LU is solved on that LU
    through a Schur complement (:class:`_SchurFactor`) instead. Both are cached per active set:
    only ``q`` and ``b`` change between steps, so a step that keeps the active set of the previous
    one costs one triangular solve.

    :meth:`correct` searches for the optimal set from a guess by primal-dual active-set steps
    (Hintermueller, Ito and Kunisch 2002): drop the active rows whose multipliers have the wrong
    sign, add the inactive rows that the solution violates, repeat; it stops at the optimum, at
    a set seen before (a cycle), at a singular set, or after a given number of sets.
    """

    def __init__(self, P_upper: sp.csc_matrix, A: sp.csc_matrix) -> None:
        self._nv = A.shape[1]
        self._nc = A.shape[0]
        self._cache: OrderedDict[bytes, _LuFactor | _SchurFactor | None] = OrderedDict()
        self._base: _LuFactor | None = None
        self.set_values(P_upper, A)
        P_full = self._P
        pattern = sp.bmat(
            [[abs(P_full) + sp.eye(self._nv), abs(A).T], [abs(A), sp.eye(self._nc)]], format="csr"
        )
        self._perm = reverse_cuthill_mckee(pattern, symmetric_mode=True).astype(np.int64)
        self._rank = np.empty(self._perm.size, dtype=np.int64)
        self._rank[self._perm] = np.arange(self._perm.size)
        self._keep = np.ones(self._perm.size, dtype=bool)

    def set_values(self, P_upper: sp.csc_matrix, A: sp.csc_matrix) -> None:
        """New matrix values (same shapes); drops every cached factorisation."""
        P = (P_upper + sp.triu(P_upper, k=1).T).tocoo()
        self._P = P.tocsr()
        self._Pi, self._Pj, self._Pv = P.row.astype(np.int64), P.col.astype(np.int64), P.data
        Ac = A.tocoo()
        self._Ai, self._Aj, self._Av = Ac.row.astype(np.int64), Ac.col.astype(np.int64), Ac.data
        self._A = A.tocsr()
        # [[P, A'], [A, 0]] [x; y] = [P x + A' y; A x]: every residual in one product
        self._K = sp.bmat([[self._P, A.T], [A, None]], format="csr")
        self._cache.clear()
        self._base = None

    def _lu(self, act: BoolArray) -> _LuFactor | None:
        """LU of the reduced KKT matrix of ``act`` (None if singular).

        Unknowns are [v; y_W]. ``pos`` gives each one's place in the band order restricted to
        the active rows: ``pos[:nv]`` for v, ``pos[nv:]`` for the active rows' multipliers.
        """
        nv = self._nv
        idx = np.flatnonzero(act)
        self._keep[nv:] = act
        pos_of = (np.cumsum(self._keep[self._perm]) - 1)[self._rank]  # valid where kept
        pos = np.concatenate([pos_of[:nv], pos_of[nv + idx]])
        on = act[self._Ai]
        ri = pos_of[nv + self._Ai[on]]
        cj = pos_of[self._Aj[on]]
        av = self._Av[on]
        size = nv + idx.size
        K = sp.csc_matrix(
            (
                np.concatenate([self._Pv, av, av]),
                (np.concatenate([pos_of[self._Pi], ri, cj]), np.concatenate([pos_of[self._Pj], cj, ri])),
            ),
            shape=(size, size),
        )
        try:
            lu = spla.splu(K, permc_spec="NATURAL")  # already in band order
        except RuntimeError:  # exactly singular: dependent active rows
            return None
        return _LuFactor(act, lu, idx, pos, nv)

    def _schur(self, base: _LuFactor, act: BoolArray) -> _SchurFactor | _LuFactor | None:
        """The KKT system of ``act`` bordered onto ``base`` (None if singular); a new LU once the
        base has bordered ``_BORDER_ROWS`` distinct rows."""
        idx = np.flatnonzero(act)
        added = np.flatnonzero(act & ~base.act)
        dropped = np.flatnonzero(base.act & ~act)
        border = np.concatenate([added, dropped]).tolist()
        new = [r for r in border if r not in base.border_col]
        first = len(base.border_col)
        if first + len(new) > _BORDER_ROWS:
            return self._lu(act)  # this base has served its transient: a new one
        if new:
            C_new = np.zeros((len(new), base.pos.size))
            A = self._A
            for k, r in enumerate(new):
                if base.act[r]:  # a dropped row: y_r = 0
                    pos, val = base.pos_w[np.searchsorted(base.idx, r)][None], _ONE
                elif A.indptr[r + 1] > A.indptr[r]:  # an added row: a_r v = b_r
                    lo, hi = A.indptr[r], A.indptr[r + 1]
                    pos, val = base.pos_v[A.indices[lo:hi]], A.data[lo:hi]
                else:  # an empty row (singular set): one explicit zero keeps every segment nonempty
                    pos, val = base.pos_v[:1], _ZERO
                C_new[k, pos] = val
                base.c_pos.append(pos)
                base.c_val.append(val)
                base.border_col[r] = first + k
            base.z_rows[first : first + len(new)] = base.lu.solve(C_new.T).T
        cols = [base.border_col[r] for r in border]
        c_pos = np.concatenate([base.c_pos[c] for c in cols])
        c_val = np.concatenate([base.c_val[c] for c in cols])
        counts = np.fromiter((base.c_pos[c].size for c in cols), dtype=np.int64, count=len(cols))
        starts = np.cumsum(counts) - counts
        Zt = base.z_rows[cols]
        # M = C' Z, entry (i, j) = c_i' z_j: the nonzeros of each c_i gathered from Z and summed
        M = np.add.reduceat(Zt.T[c_pos] * c_val[:, None], starts)
        lu, piv, info = lapack.dgetrf(M)
        d = np.abs(np.diag(lu))
        if info != 0 or d.min() <= _SCHUR_PIVOT_MIN * d.max():
            return None  # (numerically) singular: dependent rows in the new set
        in_base = base.act[idx]
        keep_t = np.flatnonzero(in_base)
        keep_0 = np.searchsorted(base.idx, idx[keep_t])
        add_t = np.flatnonzero(~in_base)
        border_c = (c_pos, c_val, starts)
        return _SchurFactor(act, base, idx, keep_t, keep_0, add_t, border_c, Zt, (lu, piv), added.size)

    def _factor(self, act: BoolArray) -> _LuFactor | _SchurFactor | None:
        """The cached factorisation of ``act``, else a Schur complement on the last LU if it is
        near, else a new LU (which becomes the base for the next sets)."""
        key = act.tobytes()
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        base = self._base
        entry: _LuFactor | _SchurFactor | None
        moved = -1 if base is None else int(np.count_nonzero(act != base.act))
        if moved == 0:
            entry = base  # the base itself, evicted from the cache since
        elif 0 < moved <= _SCHUR_MAX_ROWS:
            entry = self._schur(base, act)  # type: ignore[arg-type]
        else:
            entry = self._lu(act)
        if isinstance(entry, _LuFactor):
            self._base = entry  # a new LU (or the base again): the next sets border onto it
        self._cache[key] = entry
        if len(self._cache) > _KKT_CACHE:
            self._cache.popitem(last=False)
        return entry

    def solve(
        self, q: FloatArray, lo: FloatArray, up: FloatArray, lower: BoolArray, upper: BoolArray
    ) -> _KktSolution | None:
        """The KKT solution on W = lower | upper, checked; None if the KKT matrix is singular."""
        act = lower | upper
        factor = self._factor(act)
        if factor is None:
            return None
        nv = self._nv
        idx = factor.idx
        b = np.where(lower[idx], lo[idx], up[idx])
        xy = np.zeros(nv + self._nc)
        xy[:nv], xy[nv + idx] = factor.solve(q, b)
        Kxy = self._K @ xy
        r_dual = Kxy[:nv] + q
        r_act = b - Kxy[nv + idx]
        if _absmax(r_dual) > KKT_TOL or _absmax(r_act) > KKT_TOL:
            # one step of iterative refinement with the same factors (ill-conditioned flat QPs)
            dv, dy = factor.solve(r_dual, r_act)
            xy[:nv] += dv
            xy[nv + idx] += dy
            Kxy = self._K @ xy
            r_dual = Kxy[:nv] + q
            r_act = b - Kxy[nv + idx]
            if _absmax(r_dual) > KKT_TOL or _absmax(r_act) > KKT_TOL:
                return None  # not solved accurately: no certificate either way
        # the optimum iff the inactive rows hold and the multipliers have the right signs
        x, y, z = xy[:nv], xy[nv:], Kxy[nv:]
        free = ~act
        eq = lo == up
        certified = not (
            (free & ((z < lo - KKT_TOL) | (z > up + KKT_TOL))).any()
            or (((lower & (y > KKT_TOL)) | (upper & (y < -KKT_TOL))) & ~eq).any()
        )
        return _KktSolution(x, y, z, certified)

    def correct(
        self, q: FloatArray, lo: FloatArray, up: FloatArray, lower: BoolArray, upper: BoolArray, max_sets: int
    ) -> _Correction:
        """Primal-dual active-set steps from the guess (lower, upper), at most ``max_sets`` sets.

        Each step drops every active row with a wrong-signed multiplier and adds every violated
        inactive row. If that leads back to a set seen before, or to a singular one (added rows
        that depend on active ones, e.g. a rate row between two active input bounds), the search
        goes on one change at a time from the last solved set: add the most violated row, or if
        none is violated drop the row with the most wrong-signed multiplier.
        """
        eq = lo == up
        seen: set[bytes] = set()
        sets = 0
        last: tuple[_KktSolution, BoolArray, BoolArray] | None = None
        single = False
        while sets < max_sets:
            key = lower.tobytes() + upper.tobytes()
            sol = None
            if key not in seen:
                seen.add(key)
                sol = self.solve(q, lo, up, lower, upper)
                sets += 1
                if sol is not None and sol.certified:
                    return _Correction(sol, lower, upper, sets)
            if sol is None:  # a cycle or a singular set: one change at a time from the last one
                if last is None or single:
                    break
                single = True
                sol, lower, upper = last
            last = (sol, lower, upper)
            lower, upper = _pdas_step(sol, lower, upper, lo, up, eq, single)
        return _Correction(None, lower, upper, sets)

    def affine(
        self,
        lower: BoolArray,
        upper: BoolArray,
        Qm: FloatArray,
        Lm: FloatArray,
        Um: FloatArray,
        strict: BoolArray | None = None,
    ) -> _AffineKkt | None:
        """The solution on W = lower | upper for every parameter (see :class:`_AffineKkt`).

        ``Qm`` (nv, p), ``Lm`` and ``Um`` (nc, p): the QP's q, l and u as affine maps of the
        parameters (last column the constant; an infinite bound has an infinite constant and a
        zero row). Each column is one solve on the set's factorisation and one step of iterative
        refinement. The inactive rows in ``strict`` must hold with a margin of ``_PLAN_MARGIN``
        instead of the tolerance ``KKT_TOL`` (so that rounding cannot break them). None if the
        set is singular or bounds an active row at infinity.
        """
        act = lower | upper
        factor = self._factor(act)
        if factor is None:
            return None
        nv, p = self._nv, Qm.shape[1]
        idx = factor.idx
        Bm = np.where(lower[idx, None], Lm[idx], Um[idx])
        if not np.isfinite(Bm).all():
            return None
        XY = np.zeros((nv + self._nc, p))
        Rd, Ra = -Qm, Bm  # the first sweep solves the system itself, the second refines
        for _sweep in range(2):
            dv, dy = factor.solve(-Rd, Ra)
            XY[:nv] += dv
            XY[nv + idx] += dy
            KXY = self._K @ XY
            Rd = -(KXY[:nv] + Qm)
            Ra = Bm - KXY[nv + idx]
        residual = np.maximum(np.abs(Rd).max(axis=0), np.abs(Ra).max(axis=0, initial=0.0))
        X, Y, Z = XY[:nv], XY[nv:], KXY[nv:]
        # rows that hold the same value for every parameter: equality rows, no sign condition
        eq = (Lm == Um).all(axis=1)
        tol = np.zeros(p)
        tol[-1] = KKT_TOL
        free = ~act
        lo_rows = free & np.isfinite(Lm[:, -1])
        up_rows = free & np.isfinite(Um[:, -1])
        checks = np.vstack(
            [
                Z[lo_rows] - Lm[lo_rows],
                Um[up_rows] - Z[up_rows],
                -Y[lower & ~eq] + tol,  # y <= 0 on an active lower bound
                Y[upper & ~eq] + tol,
            ]
        )
        slack = np.where(strict, -_PLAN_MARGIN, KKT_TOL) if strict is not None else np.full(self._nc, KKT_TOL)
        checks[: lo_rows.sum() + up_rows.sum(), -1] += np.concatenate([slack[lo_rows], slack[up_rows]])
        return _AffineKkt(X, Y, checks, residual)

    def guess(
        self, lo: FloatArray, up: FloatArray, x: FloatArray, y: FloatArray
    ) -> tuple[BoolArray, BoolArray]:
        """The active set of an ADMM iterate by OSQP's polish rule (z = A x): lower where
        z - l < -y, upper where u - z < y."""
        z = self._A @ x
        lower = z - lo < -y
        upper = ~lower & (up - z < y)
        return lower | ((lo == up) & ~upper), upper


# ----------------------------------------------------------------------------------------------
# public data types
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MpcModel:
    """Discrete linear model of the plant around an equilibrium.

    Attributes
    ----------
    A : ndarray, shape (n, n)
        Discrete state matrix (ZOH at ``ts_s``).
    B : ndarray, shape (n, m)
        Discrete input matrix [m per m^3/s].
    C : ndarray, shape (ny, n)
        Measured outputs y = C x [m].
    Cz : ndarray, shape (nz, n)
        Controlled outputs z = Cz x [m].
    x_op : ndarray, shape (n,)
        Operating-point state (levels) [m]; with ``u_op`` an equilibrium of the model.
    u_op : ndarray, shape (m,)
        Operating-point inputs (pump flows) [m^3/s].
    ts_s : float
        Sample time [s] (informational: the matrices are already discrete).
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    Cz: FloatArray
    x_op: FloatArray
    u_op: FloatArray
    ts_s: float

    def __post_init__(self) -> None:
        A = _matrix(self.A, "A", None, None)
        n = A.shape[0]
        if A.shape != (n, n) or n == 0:
            raise ValueError(f"A must be square and non-empty, got shape {A.shape}")
        B = _matrix(self.B, "B", n, None)
        if B.shape[1] == 0:
            raise ValueError("B must have at least one column (input)")
        C = _matrix(self.C, "C", None, n)
        Cz = _matrix(self.Cz, "Cz", None, n)
        if C.shape[0] == 0 or Cz.shape[0] == 0:
            raise ValueError("C and Cz must have at least one row")
        x_op = _vector(self.x_op, n, "x_op")
        u_op = _vector(self.u_op, B.shape[1], "u_op")
        if isinstance(self.ts_s, bool) or not isinstance(self.ts_s, (int, float, np.floating, np.integer)):
            raise TypeError(f"ts_s must be a real number, got {type(self.ts_s).__name__}")
        if not (math.isfinite(float(self.ts_s)) and float(self.ts_s) > 0.0):
            raise ValueError(f"ts_s must be finite and > 0, got {self.ts_s}")
        for name, val in (("A", A), ("B", B), ("C", C), ("Cz", Cz), ("x_op", x_op), ("u_op", u_op)):
            object.__setattr__(self, name, _readonly(val))
        object.__setattr__(self, "ts_s", float(self.ts_s))

    @property
    def n_states(self) -> int:
        """n."""
        return int(self.A.shape[0])

    @property
    def n_inputs(self) -> int:
        """m."""
        return int(self.B.shape[1])

    @property
    def n_measured(self) -> int:
        """ny."""
        return int(self.C.shape[0])

    @property
    def n_controlled(self) -> int:
        """nz."""
        return int(self.Cz.shape[0])


Formulation = Literal["auto", "condensed", "sparse"]
InputTarget = Literal["steady_state", "operating_point"]


@dataclass(frozen=True, kw_only=True)
class MpcConfig:
    """Tuning, bounds, estimator and solver settings of :class:`MpcController` (SI units).

    Vector fields accept a scalar (broadcast) or an array of the stated length; weights accept a
    scalar, a diagonal (length) or a full symmetric PSD matrix.

    Attributes
    ----------
    horizon : int
        Prediction and control horizon Np [samples], >= 1.
    u_min, u_max : array_like, (m,)
        Hard absolute input bounds [m^3/s]; finite, u_min < u_max (they also set the input scaling).
    du_min, du_max : array_like, (m,)
        Rate bounds per sample [m^3/s]; du_min <= 0 <= du_max, du_min < du_max; +-inf allowed.
    z_min, z_max : array_like, (nz,)
        Soft absolute output bounds [m]; +-inf allowed (no output rows if all are infinite).
    Qz : array_like
        Tracking weight [1/m^2], (nz,) or (nz, nz). Default 1 (the OPC UA MPC paper: Qz = I).
    S : array_like
        Move weight [1/(m^3/s)^2], (m,) or (m, m). Default 1 (the paper: S = I).
    R : array_like
        Input weight on u - u_ss [1/(m^3/s)^2]. Default 0.
    first_move_rate_limited : bool
        True (default): the rate bound applies to u(0) - u(-1) too. False: paper-literal, only to
        the Np - 1 moves inside the plan (the applied move is free).
    formulation : {"auto", "condensed", "sparse"}
        QP form; "auto" uses sparse from ``SPARSE_FROM_HORIZON`` on.
    x_scale : array_like or None
        State scale s_x, (n,) [state units]. None: the largest finite z range for every state,
        or 1 if no z bound is finite.
    slack_linear, slack_quadratic : array_like or None
        Output-slack penalties rho_l [1/m] and rho_q [1/m^2], (nz,). None: max(10, Np / 2) and 1 in
        scaled units (converted as in the module docstring; see ``MpcController.slack_weights``).
    input_target : {"steady_state", "operating_point"}
        u_ss in the R term: the offset-free steady-state target (default) or u_op (the 2.4 paper's
        literal deviation form, which leaves an offset under disturbances when R > 0).
    disturbance_matrix : array_like or None
        Bd, (n, n_eta). None: B (input disturbances).
    estimator_outputs : sequence of int or None
        Indices of the rows of C fed to the filter. None: all.
    state_noise_std, disturbance_noise_std, measurement_noise_std : array_like
        Filter standard deviations per sample: 1e-4 m, 1e-6 (eta units), 1e-3 m.
    tolerances : tuple of float
        The tolerance ladder: OSQP eps_abs = eps_rel per rung, scaled units, strictly decreasing.
        Default (1e-4, 1e-5, 1e-6): meets the accuracy guard (closed-loop IAE within 1 % of an
        interior-point reference; measured <= 0.09 %, docs/mpc.md).
    polish : bool
        OSQP solution polishing at every rung. Default True. False: one rung at the last tolerance.
    max_iter : int
        OSQP iteration budget per step, shared by the rungs. Default 10000.
    check_termination : int
        OSQP checks convergence every this many iterations. Default 5.
    """

    horizon: int
    u_min: ArrayLike
    u_max: ArrayLike
    du_min: ArrayLike = -np.inf
    du_max: ArrayLike = np.inf
    z_min: ArrayLike = -np.inf
    z_max: ArrayLike = np.inf
    Qz: ArrayLike = 1.0
    S: ArrayLike = 1.0
    R: ArrayLike = 0.0
    first_move_rate_limited: bool = True
    formulation: Formulation = "auto"
    x_scale: ArrayLike | None = None
    slack_linear: ArrayLike | None = None
    slack_quadratic: ArrayLike | None = None
    input_target: InputTarget = "steady_state"
    disturbance_matrix: ArrayLike | None = None
    estimator_outputs: Sequence[int] | None = None
    state_noise_std: ArrayLike = 1e-4
    disturbance_noise_std: ArrayLike = 1e-6
    measurement_noise_std: ArrayLike = 1e-3
    tolerances: tuple[float, ...] = (1e-4, 1e-5, 1e-6)
    polish: bool = True
    max_iter: int = 10000
    check_termination: int = 5

    def __post_init__(self) -> None:
        for name in ("horizon", "max_iter", "check_termination"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, (int, np.integer)):
                raise TypeError(f"{name} must be an int, got {type(val).__name__}")
            if val < 1:
                raise ValueError(f"{name} must be >= 1, got {val}")
        for name in ("first_move_rate_limited", "polish"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name} must be a bool")
        if self.formulation not in ("auto", "condensed", "sparse"):
            raise ValueError(f"formulation must be 'auto', 'condensed' or 'sparse', got {self.formulation!r}")
        if self.input_target not in ("steady_state", "operating_point"):
            raise ValueError(
                f"input_target must be 'steady_state' or 'operating_point', got {self.input_target!r}"
            )
        tol = self.tolerances
        if not isinstance(tol, tuple) or not tol:
            raise TypeError("tolerances must be a non-empty tuple of floats")
        for val in tol:
            if isinstance(val, bool) or not isinstance(val, (int, float, np.floating)):
                raise TypeError(f"tolerances must hold floats, got {type(val).__name__}")
            if not (math.isfinite(val) and val > 0.0):
                raise ValueError(f"tolerances must be finite and > 0, got {val}")
        if any(b >= a for a, b in itertools.pairwise(tol)):
            raise ValueError(f"tolerances must be strictly decreasing, got {tol}")


@dataclass(frozen=True)
class MpcResult:
    """Outcome and diagnostics of one MPC step (absolute SI values; arrays read-only).

    Attributes
    ----------
    u : ndarray, shape (m,)
        Input to apply now [m^3/s], within the input and rate bounds.
    status : MpcStatus
        SOLVED, INACCURATE (plan used) or HELD (solver failed: shifted previous plan used).
    osqp_status : str
        OSQP's status string for this step.
    iterations : int
        ADMM iterations of this step (0: OSQP did not run).
    solve_time_s : float
        OSQP-reported update + solve + polish time of this step [s]; 0 when OSQP did not run
        (the previous step's active set was optimal).
    planned_u : ndarray, shape (Np, m)
        Planned inputs u(0..Np-1) [m^3/s]; ``planned_u[0] == u``.
    predicted_z : ndarray, shape (Np, nz)
        Controlled outputs z(1..Np) predicted for the plan [m].
    disturbance : ndarray, shape (n_eta,)
        Disturbance estimate used [eta units; m^3/s for Bd = B].
    state : ndarray, shape (n,)
        State estimate x(k|k) used [m].
    objective : float
        SI cost of the returned plan (all terms, constants included).
    max_output_violation : float
        Largest predicted violation of the output bounds over the plan [m] (0 if none).
    failures : int
        Total HELD steps since construction or :meth:`MpcController.reset`.
    consecutive_failures : int
        HELD steps in a row up to and including this one.
    inaccurate : int
        Total INACCURATE steps since construction or reset.
    solved_by : str
        How this step's plan was found: ``"law"`` (the affine law of the previous active set),
        ``"previous"`` (the previous active set, solved on its factorisation), ``"corrections"``
        (primal-dual active-set corrections), ``"osqp"`` (OSQP's tolerance ladder) or ``"held"``
        (no solution: the shifted last plan).
    """

    u: FloatArray
    status: MpcStatus
    osqp_status: str
    iterations: int
    solve_time_s: float
    planned_u: FloatArray
    predicted_z: FloatArray
    disturbance: FloatArray
    state: FloatArray
    objective: float
    max_output_violation: float
    failures: int
    consecutive_failures: int
    inaccurate: int
    solved_by: SolvedBy = "osqp"


@dataclass
class _OsqpOutcome:
    """What the QP solve produced in one step (scaled QP variables)."""

    status: str = "not run"
    iterations: int = 0
    time_s: float = 0.0
    x: FloatArray | None = None
    y: FloatArray | None = None
    accurate: bool = False
    last_x: FloatArray | None = None
    last_y: FloatArray | None = None
    active: tuple[BoolArray, BoolArray] | None = None
    """The active set (lower, upper) of the accepted solution: exact when certified or polished,
    OSQP's guess otherwise; the next step's first candidate."""
    solved_by: SolvedBy = "osqp"


@dataclass
class _AffineLaw:
    r"""The controller's plan on one active set as an affine function of the step's data.

    For a constant reference the QP's vectors are affine in th = [dx0 (n) [m], eta (n_eta),
    r (nz) [m], u(-1) (m) [m^3/s], 1], and so, on a fixed active set, are its KKT solution, the
    plan, the predicted outputs and the cost's residuals (:class:`_AffineKkt`). ``out = G th``
    stacks, in this order (``ends`` marks where each block ends):

    1. the plan u(0..Np-1), row-major (absolute [m^3/s]);
    2. the predicted outputs z(1..Np) for that plan (absolute [m]);
    3. the weighted residuals w of :meth:`MpcController._residual_roots` (1/2 |w|^2 is the
       plan's cost without the slack terms);
    4. z - z_max and z_min - z for the finite output bounds (all <= 0: no slack cost);
    5. checks, all >= 0 iff the plan is the QP's certified optimum and u(-1) lies where the
       first rate row is not clipped (``_qp_vectors``).

    Near a steady state the active set repeats, and a step is one small matrix-vector product.
    """

    G: FloatArray
    ends: tuple[int, int, int, int]
    exact_plan: bool
    """No rate row is active: the plan meets every input and rate bound as computed (inactive
    ones by ``_PLAN_MARGIN``, active input bounds exactly), so it needs no projection."""
    xy: FloatArray
    """(nv + nc, p): the scaled QP's primal and dual solution, for OSQP's warm start."""

    def evaluate(self, theta: FloatArray) -> FloatArray | None:
        """G th, or None if the set is not certified optimal at th."""
        out = self.G @ theta
        return out if out[self.ends[3] :].min() >= 0.0 else None


def _affine_map(f: Callable[[FloatArray], FloatArray], base: FloatArray, steps: FloatArray) -> FloatArray:
    """[J, c] of an affine ``f(th) = J th + c`` (c the last column), from f at ``base`` and at
    ``base + steps[j] e_j``. Rows where f is infinite at the base are constant: zero J, c = +-inf."""
    f0 = f(base)
    finite = np.isfinite(f0)
    J = np.zeros((f0.size, base.size))
    for j, h in enumerate(steps):
        th = base.copy()
        th[j] += h
        np.subtract(f(th), f0, out=J[:, j], where=finite)
        J[:, j] /= h
    return np.column_stack([J, np.where(finite, f0 - J @ base, f0)])


# ----------------------------------------------------------------------------------------------
# the controller
# ----------------------------------------------------------------------------------------------
class MpcController:
    """Offset-free constrained MPC with a steady-state Kalman filter (see the module docstring).

    Parameters
    ----------
    model : MpcModel
        Discrete model and operating point.
    config : MpcConfig
        Horizon, weights, bounds, estimator and solver settings.

    Raises
    ------
    ValueError
        Inconsistent shapes or bounds, a weight that is not PSD, all weights zero, an
        unobservable disturbance model, or an OSQP setup error.
    TypeError
        A non-numeric argument.
    """

    def __init__(self, model: MpcModel, config: MpcConfig) -> None:
        if not isinstance(model, MpcModel):
            raise TypeError(f"model must be an MpcModel, got {type(model).__name__}")
        if not isinstance(config, MpcConfig):
            raise TypeError(f"config must be an MpcConfig, got {type(config).__name__}")
        self._model = model
        self._config = config
        n, m, nz, ny = model.n_states, model.n_inputs, model.n_controlled, model.n_measured
        N = config.horizon
        self._n, self._m, self._nz, self._N = n, m, nz, N

        # -- bounds ------------------------------------------------------------------------------
        self._u_min = _vector(config.u_min, m, "u_min")
        self._u_max = _vector(config.u_max, m, "u_max")
        if np.any(self._u_min >= self._u_max):
            raise ValueError("u_min must be < u_max element-wise")
        self._du_min = _vector(config.du_min, m, "du_min", allow_inf=True)
        self._du_max = _vector(config.du_max, m, "du_max", allow_inf=True)
        if np.any(self._du_min > 0.0) or np.any(self._du_max < 0.0) or np.any(self._du_min >= self._du_max):
            raise ValueError("rate bounds need du_min <= 0 <= du_max and du_min < du_max element-wise")
        self._z_min = _vector(config.z_min, nz, "z_min", allow_inf=True)
        self._z_max = _vector(config.z_max, nz, "z_max", allow_inf=True)
        if (
            np.any(self._z_min >= self._z_max)
            or np.any(self._z_min == np.inf)
            or np.any(self._z_max == -np.inf)
        ):
            raise ValueError("output bounds need z_min < z_max element-wise (z_min < inf, z_max > -inf)")
        self._has_z_rows = bool(np.any(np.isfinite(self._z_min)) or np.any(np.isfinite(self._z_max)))
        self._rate_rows = N if config.first_move_rate_limited else N - 1
        self._has_rate_rows = bool(np.any(np.isfinite(self._du_min)) or np.any(np.isfinite(self._du_max)))
        # where u(-1) is clipped to so that its rate window meets the input box [m^3/s]
        self._symmetric_rates = bool(np.array_equal(self._du_min, -self._du_max))
        # the same as Python floats for the projection's per-move loops
        self._u_min_list, self._u_max_list = self._u_min.tolist(), self._u_max.tolist()
        self._du_min_list, self._du_max_list = self._du_min.tolist(), self._du_max.tolist()
        self._u_prev_min_list = (self._u_min - self._du_max).tolist()
        self._u_prev_max_list = (self._u_max - self._du_min).tolist()
        if not self._has_rate_rows:
            self._rate_rows = 0

        # -- scaling -----------------------------------------------------------------------------
        z_range = self._z_max - self._z_min
        finite_range = z_range[np.isfinite(z_range)]
        if config.x_scale is None:
            sx_default = float(np.max(finite_range)) if finite_range.size else 1.0
            self._sx = np.full(n, sx_default)
        else:
            self._sx = _vector(config.x_scale, n, "x_scale")
            if np.any(self._sx <= 0.0):
                raise ValueError("x_scale must be > 0")
        self._su = self._u_max - self._u_min
        sz_from_x = np.max(np.abs(model.Cz) * self._sx[None, :], axis=1)
        self._sz = np.where(np.isfinite(z_range), z_range, sz_from_x)
        if np.any(self._sz <= 0.0):
            raise ValueError("every row of Cz must be nonzero (a controlled output needs a scale)")

        # -- weights -----------------------------------------------------------------------------
        self._Qz = _weight(config.Qz, nz, "Qz")
        self._S = _weight(config.S, m, "S")
        self._R = _weight(config.R, m, "R")
        self._Lq, self._Ls, self._Lr = (_sqrt_psd(W) for W in (self._Qz, self._S, self._R))
        Dz, Du = np.diag(self._sz), np.diag(self._su)
        scaled = [Dz @ self._Qz @ Dz, Du @ self._S @ Du, Du @ self._R @ Du]
        self._c = max(float(np.max(np.diag(W))) for W in scaled)
        if not self._c > 0.0:
            raise ValueError("Qz, S and R are all zero: the cost has no weight")
        self._Qt, self._St, self._Rt = (W / self._c for W in scaled)
        self._use_R = bool(np.any(self._R != 0.0))
        if config.slack_linear is None:
            self._rho_l_t = np.full(nz, max(_SLACK_LINEAR_MIN, _SLACK_LINEAR_PER_STEP * N))
        else:
            rho_l = _vector(config.slack_linear, nz, "slack_linear")
            if np.any(rho_l <= 0.0):
                raise ValueError("slack_linear must be > 0")
            self._rho_l_t = rho_l * self._sz / self._c
        if config.slack_quadratic is None:
            self._rho_q_t = np.full(nz, _SLACK_QUADRATIC)
        else:
            rho_q = _vector(config.slack_quadratic, nz, "slack_quadratic")
            if np.any(rho_q < 0.0):
                raise ValueError("slack_quadratic must be >= 0")
            self._rho_q_t = rho_q * self._sz**2 / self._c
        self._slack_si = self.slack_weights  # fixed from here on
        self._half_rho_q_si, self._rho_l_si = 0.5 * self._slack_si[0], self._slack_si[1]

        # -- estimator ---------------------------------------------------------------------------
        if config.estimator_outputs is None:
            self._est_rows = np.arange(ny)
        else:
            rows = list(config.estimator_outputs)
            if not rows or any(isinstance(i, bool) or not isinstance(i, (int, np.integer)) for i in rows):
                raise TypeError("estimator_outputs must be a non-empty sequence of int")
            if len(set(rows)) != len(rows) or min(rows) < 0 or max(rows) >= ny:
                raise ValueError(f"estimator_outputs must be distinct row indices of C in 0..{ny - 1}")
            self._est_rows = np.array(rows, dtype=np.int64)
        self._est_subset = not np.array_equal(self._est_rows, np.arange(ny))
        if config.disturbance_matrix is None:
            self._Bd_follows_B = True
            Bd = model.B.copy()
        else:
            self._Bd_follows_B = False
            Bd = _matrix(config.disturbance_matrix, "disturbance_matrix", n, None)
        self._Bd = Bd
        self._n_eta = Bd.shape[1]
        # the filter checks rank [[I - A, -Bd], [C, 0]] = n + n_eta and raises ValueError
        self._estimator = AugmentedKalmanFilter(
            model.A,
            model.B,
            model.C[self._est_rows],
            Bd,
            state_noise_std=config.state_noise_std,
            disturbance_noise_std=config.disturbance_noise_std,
            measurement_noise_std=config.measurement_noise_std,
        )

        # -- formulation and QP ------------------------------------------------------------------
        if config.formulation == "auto":
            self._formulation: Literal["condensed", "sparse"] = (
                "sparse" if N >= SPARSE_FROM_HORIZON else "condensed"
            )
        else:
            self._formulation = config.formulation
        self._layout()
        self._set_model_matrices(model.A, model.B)
        self._set_vector_bases()
        P, Aqp = self._qp_matrices()
        self._kkt = _ActiveSetQp(P, Aqp)
        self._laws: OrderedDict[bytes, _AffineLaw | None] = OrderedDict()
        self._maps: tuple[FloatArray, FloatArray, FloatArray] | None = None
        q, lo, up = self._qp_vectors(np.zeros(n), np.zeros(self._n_eta), np.zeros((N, nz)), model.u_op)
        # the tolerance ladder: polish at each rung; without polishing only the last rung is used
        self._tolerances = tuple(float(e) for e in config.tolerances)
        if not config.polish:
            self._tolerances = self._tolerances[-1:]
        self._osqp_eps = self._tolerances[0]
        self._osqp_budget = int(config.max_iter)
        self._solver = osqp.OSQP()
        try:
            self._solver.setup(
                P,
                q,
                Aqp,
                lo,
                up,
                verbose=False,
                eps_abs=float(self._tolerances[0]),
                eps_rel=float(self._tolerances[0]),
                polishing=config.polish,
                max_iter=int(config.max_iter),
                check_termination=int(config.check_termination),
                adaptive_rho=True,
                adaptive_rho_interval=50,  # iteration-based, not time-based: deterministic
                warm_starting=True,
            )
        except Exception as e:  # OSQPException / ValueError from the extension
            raise ValueError(f"OSQP setup failed: {e!r}") from e

        self._reset_runtime_state()
        self._set_vector_maps()

    # ------------------------------------------------------------------------------------------
    # layout and matrices
    # ------------------------------------------------------------------------------------------
    def _layout(self) -> None:
        """Offsets of the variable and constraint blocks, and the warm-start shift indices."""
        n, m, nz, N = self._n, self._m, self._nz, self._N
        ns = N * nz if self._has_z_rows else 0
        if self._formulation == "sparse":
            self._x_off, self._u_off = 0, N * n
        else:
            self._x_off, self._u_off = 0, 0
        nx_vars = N * n if self._formulation == "sparse" else 0
        self._eps_off = nx_vars + N * m
        self._nv = self._eps_off + ns
        # rows: [dynamics (sparse)] [u bounds] [rates] [z low] [z high] [eps >= 0]
        r = 0
        self._row_dyn = r
        r += nx_vars
        self._row_u = r
        r += N * m
        self._row_rate = r
        r += self._rate_rows * m
        self._row_zlo = r
        r += ns
        self._row_zhi = r
        r += ns
        self._row_eps = r
        r += ns
        self._nc = r
        self._shift_x = np.concatenate(
            [
                _shift_index(self._x_off, N, n) if nx_vars else np.zeros(0, dtype=np.int64),
                _shift_index(self._u_off, N, m),
                _shift_index(self._eps_off, N, nz) if ns else np.zeros(0, dtype=np.int64),
            ]
        )
        self._shift_y = np.concatenate(
            [
                _shift_index(self._row_dyn, N, n) if nx_vars else np.zeros(0, dtype=np.int64),
                _shift_index(self._row_u, N, m),
                _shift_index(self._row_rate, self._rate_rows, m),
                _shift_index(self._row_zlo, N, nz) if ns else np.zeros(0, dtype=np.int64),
                _shift_index(self._row_zhi, N, nz) if ns else np.zeros(0, dtype=np.int64),
                _shift_index(self._row_eps, N, nz) if ns else np.zeros(0, dtype=np.int64),
            ]
        )

    def _set_model_matrices(self, A: FloatArray, B: FloatArray) -> None:
        """Scaled model, condensed prediction matrices and the steady-state target map."""
        n, m, N = self._n, self._m, self._N
        Dx_inv = np.diag(1.0 / self._sx)
        self._A = A
        self._B = B
        self._At = Dx_inv @ A @ np.diag(self._sx)
        self._Bt = Dx_inv @ B @ np.diag(self._su)
        self._Czt = np.diag(1.0 / self._sz) @ self._model.Cz @ np.diag(self._sx)
        self._QtCzt = self._Qt.T @ self._Czt  # the sparse form's q on the states, per stage
        # condensed prediction (also used for exact output prediction of any plan)
        Phi = np.zeros((N * n, n))
        Psi = np.zeros((N * n, n))
        Gam = np.zeros((N * n, N * m))
        AkB = []
        M = self._Bt
        for _ in range(N):
            AkB.append(M)
            M = self._At @ M
        Ak = np.eye(n)
        Ssum = np.zeros((n, n))
        for k in range(1, N + 1):
            Ssum = Ssum + Ak
            Ak = self._At @ Ak
            rs = slice((k - 1) * n, k * n)
            Phi[rs] = Ak
            Psi[rs] = Ssum
            for j in range(k):
                Gam[rs, j * m : (j + 1) * m] = AkB[k - 1 - j]
        Cbar = np.kron(np.eye(N), self._Czt)
        self._Phi_z = Cbar @ Phi
        self._Psi_z = Cbar @ Psi
        self._Gam_z = Cbar @ Gam
        # z~(1..Np) = Zx dx0 + Zeta eta + Gam_z U~ (unscaled dx0 and eta, _scaled_z)
        self._Zx = self._Phi_z / self._sx[None, :]
        self._Zeta = self._Psi_z @ (self._Bd / self._sx[:, None])
        # steady-state target: [[I - A~, -B~], [Cz~, 0]] [x~s; u~s] = [w~; r~]
        T = np.block([[np.eye(n) - self._At, -self._Bt], [self._Czt, np.zeros((self._nz, m))]])
        self._target_pinv = np.linalg.pinv(T)

    def _qp_matrices(self) -> tuple[sp.csc_matrix, sp.csc_matrix]:
        """P (upper triangle) and the constraint matrix, on the fixed sparsity pattern."""
        P, Pmask, Aqp, Amask = self._qp_dense()
        self._Pmask, self._Amask = Pmask, Amask
        return _csc(P, Pmask), _csc(Aqp, Amask)

    def _qp_dense(self) -> tuple[FloatArray, BoolArray, FloatArray, BoolArray]:
        n, m, nz, N = self._n, self._m, self._nz, self._N
        nv, nc = self._nv, self._nc
        ns = N * nz if self._has_z_rows else 0
        P = np.zeros((nv, nv))
        Pmask = np.zeros((nv, nv), dtype=bool)
        Aqp = np.zeros((nc, nv))
        Amask = np.zeros((nc, nv), dtype=bool)
        uo, eo = self._u_off, self._eps_off
        us = slice(uo, uo + N * m)
        # difference matrix D (N m x N m): I on the diagonal, -I on the first sub-diagonal
        D = np.eye(N * m) - np.eye(N * m, k=-m)
        Sbar = np.kron(np.eye(N), self._St)
        Rbar = np.kron(np.eye(N), self._Rt)
        Qbar = np.kron(np.eye(N), self._Qt)
        Puu = D.T @ Sbar @ D + Rbar
        if self._formulation == "condensed":
            Puu = Puu + self._Gam_z.T @ Qbar @ self._Gam_z
            P[us, us] = Puu
            Pmask[us, us] = np.triu(np.ones((N * m, N * m), dtype=bool))
        else:
            xs = slice(self._x_off, self._x_off + N * n)
            P[xs, xs] = np.kron(np.eye(N), self._Czt.T @ self._Qt @ self._Czt)
            Pmask[xs, xs] = np.kron(np.eye(N, dtype=bool), np.triu(np.ones((n, n), dtype=bool)))
            P[us, us] = Puu
            band = np.kron(np.eye(N, dtype=bool), np.ones((m, m), dtype=bool))
            band |= np.kron(np.eye(N, k=1, dtype=bool), np.ones((m, m), dtype=bool))
            Pmask[us, us] = np.triu(band)
            # dynamics: x(k+1) - A x(k) - B u(k) = w
            r0 = self._row_dyn
            for k in range(N):
                rows = slice(r0 + k * n, r0 + (k + 1) * n)
                Aqp[rows, k * n : (k + 1) * n] = np.eye(n)
                Amask[rows, k * n : (k + 1) * n] = np.eye(n, dtype=bool)
                if k > 0:
                    Aqp[rows, (k - 1) * n : k * n] = -self._At
                    Amask[rows, (k - 1) * n : k * n] = True
                Aqp[rows, uo + k * m : uo + (k + 1) * m] = -self._Bt
                Amask[rows, uo + k * m : uo + (k + 1) * m] = True
        if ns:
            es = slice(eo, eo + ns)
            P[es, es] = np.diag(np.tile(self._rho_q_t, N))
            Pmask[es, es] = np.eye(ns, dtype=bool)
        # input bounds
        Aqp[self._row_u : self._row_u + N * m, us] = np.eye(N * m)
        Amask[self._row_u : self._row_u + N * m, us] = np.eye(N * m, dtype=bool)
        # rate rows (all N, or the last N - 1 paper-literal)
        if self._rate_rows:
            first = N - self._rate_rows
            rr = slice(self._row_rate, self._row_rate + self._rate_rows * m)
            Aqp[rr, us] = D[first * m :]
            Amask[rr, us] = D[first * m :] != 0.0
        if ns:
            zlo = slice(self._row_zlo, self._row_zlo + ns)
            zhi = slice(self._row_zhi, self._row_zhi + ns)
            if self._formulation == "condensed":
                gmask = np.kron(np.tril(np.ones((N, N), dtype=bool)), np.ones((nz, m), dtype=bool))
                for rows in (zlo, zhi):
                    Aqp[rows, us] = self._Gam_z
                    Amask[rows, us] = gmask
            else:
                xs = slice(self._x_off, self._x_off + N * n)
                cz = np.kron(np.eye(N), self._Czt)
                czmask = np.kron(np.eye(N, dtype=bool), np.ones((nz, n), dtype=bool))
                for rows in (zlo, zhi):
                    Aqp[rows, xs] = cz
                    Amask[rows, xs] = czmask
            Aqp[zlo, es] = np.eye(ns)
            Aqp[zhi, es] = -np.eye(ns)
            Aqp[self._row_eps : self._row_eps + ns, es] = np.eye(ns)
            for rows in (zlo, zhi, slice(self._row_eps, self._row_eps + ns)):
                Amask[rows, es] = np.eye(ns, dtype=bool)
        return P, Pmask, Aqp, Amask

    def _scaled_w(self, eta: FloatArray) -> FloatArray:
        return (self._Bd @ eta) / self._sx

    def _u_target(self, w_t: FloatArray, r_t_last: FloatArray) -> FloatArray:
        """Scaled u_ss for the R term."""
        if not self._use_R or self._config.input_target == "operating_point":
            return np.zeros(self._m)
        sol = self._target_pinv @ np.concatenate([w_t, r_t_last])
        return sol[self._n :]

    def _set_vector_bases(self) -> None:
        """The parts of q, l and u that do not change from step to step (operating point fixed)."""
        m, nz, N = self._m, self._nz, self._N
        model = self._model
        ns = N * nz if self._has_z_rows else 0
        q = np.zeros(self._nv)
        lo = np.zeros(self._nc)
        up = np.zeros(self._nc)
        if ns:
            q[self._eps_off : self._eps_off + ns] = np.tile(self._rho_l_t, N)
        self._umin_t = (self._u_min - model.u_op) / self._su
        self._umax_t = (self._u_max - model.u_op) / self._su
        lo[self._row_u : self._row_u + N * m] = np.tile(self._umin_t, N)
        up[self._row_u : self._row_u + N * m] = np.tile(self._umax_t, N)
        self._dmin_t = self._du_min / self._su
        self._dmax_t = self._du_max / self._su
        if self._rate_rows:
            rr = slice(self._row_rate, self._row_rate + self._rate_rows * m)
            lo[rr] = np.tile(self._dmin_t, self._rate_rows)
            up[rr] = np.tile(self._dmax_t, self._rate_rows)
        self._z_op = model.Cz @ model.x_op
        self._y_op = model.C @ model.x_op
        if ns:
            zlo = slice(self._row_zlo, self._row_zlo + ns)
            zhi = slice(self._row_zhi, self._row_zhi + ns)
            lo[zlo] = np.tile((self._z_min - self._z_op) / self._sz, N)
            up[zlo] = np.inf
            lo[zhi] = -np.inf
            up[zhi] = np.tile((self._z_max - self._z_op) / self._sz, N)
            es = slice(self._row_eps, self._row_eps + ns)
            lo[es] = 0.0
            up[es] = np.inf
        self._q_base, self._l_base, self._u_base = q, lo, up

    def _qp_vectors(
        self, dx0: FloatArray, eta: FloatArray, r_abs: FloatArray, u_prev: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q, l, u of the scaled QP for deviation state dx0, disturbance eta, absolute r (N, nz), u(-1)."""
        n, m, nz, N = self._n, self._m, self._nz, self._N
        model = self._model
        x0t = dx0 / self._sx
        wt = self._scaled_w(eta)
        rt = ((r_abs - self._z_op) / self._sz).reshape(-1)
        up_t = (u_prev - model.u_op) / self._su
        ns = N * nz if self._has_z_rows else 0
        q = self._q_base.copy()
        lo = self._l_base.copy()
        up = self._u_base.copy()
        us = slice(self._u_off, self._u_off + N * m)
        qu = q[us]  # view
        qu[:m] -= self._St @ up_t
        if self._use_R:
            uss_t = self._u_target(wt, rt[-nz:])
            qu -= np.tile(self._Rt @ uss_t, N)
        if self._formulation == "condensed":
            f = self._Phi_z @ x0t + self._Psi_z @ wt
            qu += self._Gam_z.T @ self._qbar_mul(f - rt)
            if ns:
                lo[self._row_zlo : self._row_zlo + ns] -= f
                up[self._row_zhi : self._row_zhi + ns] -= f
        else:
            q[self._x_off : self._x_off + N * n] = -(rt.reshape(N, nz) @ self._QtCzt).reshape(-1)
            dyn = lo[self._row_dyn : self._row_dyn + N * n].reshape(N, n)  # view
            dyn[:] = wt
            dyn[0] += self._At @ x0t
            up[self._row_dyn : self._row_dyn + N * n] = dyn.reshape(-1)
        if self._rate_rows and self._config.first_move_rate_limited:
            # keep [u(-1) + du_min, u(-1) + du_max] and [u_min, u_max] intersecting even if the
            # applied u(-1) lies outside the input bounds (the physical bounds win)
            up_eff = np.minimum(np.maximum(up_t, self._umin_t - self._dmax_t), self._umax_t - self._dmin_t)
            lo[self._row_rate : self._row_rate + m] += up_eff
            up[self._row_rate : self._row_rate + m] += up_eff
        return q, lo, up

    def _qbar_mul(self, v: FloatArray) -> FloatArray:
        """(I_N (x) Qz~) v for v of length N nz."""
        return (v.reshape(self._N, self._nz) @ self._Qt.T).reshape(-1)

    # ------------------------------------------------------------------------------------------
    # runtime
    # ------------------------------------------------------------------------------------------
    def _reset_runtime_state(self) -> None:
        self._plan: FloatArray | None = None
        self._active: tuple[BoolArray, BoolArray] | None = None
        self._law: _AffineLaw | None = None
        self._ws_x: FloatArray | None = None
        self._ws_y: FloatArray | None = None
        self._ws_law: tuple[_AffineLaw, FloatArray] | None = None
        self._failures = 0
        self._consecutive = 0
        self._inaccurate = 0

    def reset(self, x: ArrayLike | None = None, disturbance: ArrayLike | None = None) -> None:
        """Forget the plan, the warm start and the counters; restart the filter.

        Parameters
        ----------
        x : array_like, shape (n,), optional
            Prior state for the first :meth:`step` [m, absolute]; default x_op.
        disturbance : array_like, shape (n_eta,), optional
            Prior disturbance estimate; default zeros.
        """
        dx = None if x is None else _vector(x, self._n, "x") - self._model.x_op
        d = None if disturbance is None else _vector(disturbance, self._n_eta, "disturbance")
        self._estimator.reset(dx, d)
        self._reset_runtime_state()

    def step(self, y: ArrayLike, r: ArrayLike, u_prev: ArrayLike) -> MpcResult:
        """One control step: update the estimate with y, solve the QP, return the move to apply.

        Parameters
        ----------
        y : array_like, shape (ny,)
            All measured outputs y = C x [m, absolute]; the rows in ``estimator_outputs`` are used.
        r : array_like, shape (nz,) or (Np, nz)
            Reference for z [m]: constant, or a preview whose row j is the setpoint for z(j+1).
        u_prev : array_like, shape (m,)
            Input applied over the last sample [m^3/s] (u(-1) of the QP and the filter's input).

        Returns
        -------
        MpcResult
        """
        y_, u_prev_, r_ = self._step_inputs(y, self._model.n_measured, "y", u_prev, r)
        y_dev = y_ - self._y_op
        if self._est_subset:
            y_dev = y_dev[self._est_rows]
        # y_dev and the input deviation are finite: made of the vectors just checked
        est = self._estimator.update(y_dev, u_prev_ - self._model.u_op, check_finite=False)
        return self._solve(est.x, est.disturbance, r_, u_prev_)

    def _step_inputs(
        self, v: ArrayLike, size: int, name: str, u_prev: ArrayLike, r: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """A vector ``v`` of ``size`` (y for :meth:`step`, x for :meth:`plan`; ``name`` in the
        error), u(-1) and r checked (as :func:`_vector` and :meth:`_reference`; only read, never
        kept, so float vectors come back as they are). The usual case, three float vectors of
        the right shapes, is checked for finite values in one pass."""
        m, nz = self._m, self._nz
        if (
            type(v) is np.ndarray
            and type(u_prev) is np.ndarray
            and type(r) is np.ndarray
            and v.dtype == u_prev.dtype == r.dtype == np.float64
            and v.shape == (size,)
            and u_prev.shape == (m,)
            and r.shape == (nz,)
            and np.isfinite(np.concatenate((v, u_prev, r))).all()
        ):
            return v, u_prev, r
        return (
            _vector(v, size, name, copy=False),
            _vector(u_prev, m, "u_prev", copy=False),
            self._reference(r),
        )

    def plan(
        self, x: ArrayLike, r: ArrayLike, u_prev: ArrayLike, disturbance: ArrayLike | None = None
    ) -> MpcResult:
        """Solve the QP from a given state and disturbance, leaving the filter untouched.

        Same bookkeeping as :meth:`step` (warm start, held plan, counters). Used when the state is
        known (tests, a shadow MPC fed by another estimator).

        Parameters
        ----------
        x : array_like, shape (n,)
            Current state [m, absolute].
        r : array_like, shape (nz,) or (Np, nz)
            Reference [m] as in :meth:`step`.
        u_prev : array_like, shape (m,)
            Input applied over the last sample [m^3/s].
        disturbance : array_like, shape (n_eta,), optional
            Disturbance held over the horizon; default zeros.
        """
        if disturbance is None:
            d_ = np.zeros(self._n_eta)
        elif (
            type(disturbance) is np.ndarray
            and disturbance.dtype == np.float64
            and disturbance.shape == (self._n_eta,)
            and np.isfinite(disturbance).all()
        ):
            d_ = disturbance
        else:
            d_ = _vector(disturbance, self._n_eta, "disturbance")
        x_, u_prev_, r_ = self._step_inputs(x, self._n, "x", u_prev, r)
        return self._solve(x_ - self._model.x_op, d_, r_, u_prev_)

    def correct(
        self, y: ArrayLike, x_prior: ArrayLike, disturbance_prior: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Fold a measurement into a prior predicted by the caller (the filter's corrector only).

        For a caller that propagates the estimate itself, on a finer grid than the MPC's sample
        (:class:`supervisor.timing.ScanPredictor`): the prior xi(k|k-1) = [x_prior; eta_prior] is
        corrected with the filter's steady-state gain, xi(k|k) = xi(k|k-1) + Kf (y(k) - Ca xi(k|k-1)).

        Parameters
        ----------
        y : array_like, shape (ny,)
            All measured outputs [m, absolute]; the rows in ``estimator_outputs`` are used.
        x_prior : array_like, shape (n,)
            Predicted state x(k|k-1) [m, absolute].
        disturbance_prior : array_like, shape (n_eta,)
            Predicted disturbance eta(k|k-1).

        Returns
        -------
        (x, disturbance) : x(k|k) [m, absolute], shape (n,), and eta(k|k), shape (n_eta,).
        """
        n = self._n
        if (
            type(y) is np.ndarray
            and type(x_prior) is np.ndarray
            and type(disturbance_prior) is np.ndarray
            and y.dtype == x_prior.dtype == disturbance_prior.dtype == np.float64
            and y.shape == (self._model.n_measured,)
            and x_prior.shape == (n,)
            and disturbance_prior.shape == (self._n_eta,)
            and np.isfinite(np.concatenate((y, x_prior, disturbance_prior))).all()
        ):
            y_, x_, d_ = y, x_prior, disturbance_prior
        else:
            y_ = _vector(y, self._model.n_measured, "y")
            x_ = _vector(x_prior, n, "x_prior")
            d_ = _vector(disturbance_prior, self._n_eta, "disturbance_prior")
        y_dev = y_ - self._y_op
        if self._est_subset:
            y_dev = y_dev[self._est_rows]
        x_op = self._model.x_op
        post = self._estimator.correct_prior(np.concatenate((x_ - x_op, d_)), y_dev)
        return x_op + post[:n], post[n:]

    def _reference(self, r: ArrayLike) -> FloatArray:
        """r checked: (nz,) for a constant reference or (Np, nz) for a preview (both broadcast
        against (Np, nz) arrays; only read, so a float array comes back as it is)."""
        arr = r if type(r) is np.ndarray and r.dtype == np.float64 else _as_float(r, "r")
        if arr.shape not in ((self._nz,), (self._N, self._nz)):
            raise ValueError(f"r must have shape ({self._nz},) or ({self._N}, {self._nz}), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError("r must be finite")
        return arr

    def _solve_qp(self, q: FloatArray, lo: FloatArray, up: FloatArray) -> _OsqpOutcome:
        """Solve the scaled QP; return the accepted solution (scaled QP variables).

        1. With ``polish``, exact solves on active sets first (:class:`_ActiveSetQp`): the
           previous step's set, then primal-dual active-set corrections from that set shifted by
           one sample (the plan's constraints move one sample closer each step), at most
           ``PDAS_MAX_SETS`` sets. A set that passes the KKT check gives the optimum to
           ``KKT_TOL`` and OSQP does not run. Near a steady state this is one triangular solve;
           in a rate-limited transient, a few Schur-complement solves on a cached LU.
        2. Otherwise the tolerance ladder: each rung solves to eps_abs = eps_rel = its tolerance
           with polishing, continuing the ADMM iterations of the previous rung (OSQP keeps its
           iterate between ``solve`` calls), warm-started from the previous solution shifted by
           one sample. A successful polish gives the exact optimum of the identified active set
           and ends the ladder; otherwise the next, tighter rung runs. The last rung's solution is
           accepted polished or not.

        The iteration budget ``max_iter`` is shared by all rungs. If a rung stops without
        converging, the solution of the previous rung (if any) is used, flagged inexact, unless
        OSQP reports "solved inaccurate" at a rung whose 10 x tolerance is tighter still.
        """
        out = _OsqpOutcome()
        cand = self._active
        if self._config.polish and cand is not None:
            sol = self._kkt.solve(q, lo, up, *cand)
            if sol is not None and sol.certified:
                out.status = _REPEATED
                out.x, out.y, out.accurate, out.active, out.solved_by = sol.x, sol.y, True, cand, "previous"
                return out
            shift = self._shift_y
            fix = self._kkt.correct(q, lo, up, cand[0][shift], cand[1][shift], PDAS_MAX_SETS)
            if fix.solution is not None:
                out.status = f"skipped: optimal active set found in {fix.sets} exact solves"
                out.x, out.y, out.accurate = fix.solution.x, fix.solution.y, True
                out.active, out.solved_by = (fix.lower, fix.upper), "corrections"
                return out
        self._solver.update(q=q, l=lo, u=up)
        if self._ws_x is None or self._ws_y is None:
            self._solver.warm_start(x=np.zeros(self._nv), y=np.zeros(self._nc))
        else:
            self._solver.warm_start(x=self._ws_x, y=self._ws_y)
        ladder = self._tolerances
        budget = int(self._config.max_iter)
        held_eps = math.inf  # tolerance met by the solution held in ``out``
        for rung, eps in enumerate(ladder):
            left = budget - out.iterations
            if left <= 0:
                break
            if self._osqp_eps != eps or self._osqp_budget != left:
                self._solver.update_settings(eps_abs=eps, eps_rel=eps, max_iter=left)
                self._osqp_eps, self._osqp_budget = eps, left
            res = self._solver.solve(raise_error=False)
            info = res.info
            out.iterations += int(info.iter)
            out.time_s += float(info.update_time) + float(info.solve_time) + float(info.polish_time)
            out.status = str(info.status)
            x = np.array(res.x, dtype=np.float64)
            y = np.array(res.y, dtype=np.float64)
            finite = x.shape == (self._nv,) and bool(np.all(np.isfinite(x))) and bool(np.all(np.isfinite(y)))
            if finite:
                out.last_x, out.last_y = x, y
            status_val = int(info.status_val)
            if status_val == _OSQP_SOLVED and finite:
                polished = int(info.status_polish) == 1
                done = polished or rung == len(ladder) - 1
                out.x, out.y, out.accurate = x, y, done
                held_eps = eps
                if done:
                    break
                continue
            # OSQP's "solved inaccurate" meets 10 x its tolerance: keep it if that is still tighter
            if status_val == _OSQP_SOLVED_INACCURATE and finite and 10.0 * eps < held_eps:
                out.x, out.y, out.accurate = x, y, False
            break
        if out.x is not None and out.y is not None:
            # the next step's first candidate (exact when polished, OSQP's guess otherwise)
            out.active = self._kkt.guess(lo, up, out.x, out.y)
        return out

    def _solve(self, dx0: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray) -> MpcResult:
        """The step from the state estimate, disturbance, reference ((nz,) or (Np, nz)) and u(-1)."""
        law = self._law
        constant_r = r.ndim == 1
        if law is not None and constant_r:
            theta = np.concatenate((dx0, eta, r, u_prev, _ONE))
            fast = law.evaluate(theta)
            if fast is not None:
                return self._law_step(law, theta, fast, dx0, eta, r, u_prev)
        self._settle_warm_start()
        r_abs = np.broadcast_to(r, (self._N, self._nz))
        q, lo, up = self._qp_vectors(dx0, eta, r_abs, u_prev)
        out = self._solve_qp(q, lo, up)
        self._set_active(out.active, build_law=out.solved_by == "previous" and constant_r)
        sol_x, sol_y = out.x, out.y
        model = self._model
        N, m = self._N, self._m
        if sol_x is not None and sol_y is not None:
            u_t = sol_x[self._u_off : self._u_off + N * m].reshape(N, m)
            plan = model.u_op + u_t * self._su
            if out.accurate:
                status = MpcStatus.SOLVED
            else:
                status = MpcStatus.INACCURATE
                self._inaccurate += 1
            self._consecutive = 0
            self._ws_x = sol_x[self._shift_x]
            self._ws_y = sol_y[self._shift_y]
        else:
            status = MpcStatus.HELD
            out.solved_by = "held"
            self._failures += 1
            self._consecutive += 1
            if self._plan is not None:
                plan = np.vstack([self._plan[1:], self._plan[-1:]])
            else:
                plan = np.tile(u_prev, (N, 1))  # nothing safe to shift yet: hold u(-1)
            if out.last_x is not None and out.last_y is not None:
                # an unfinished ADMM iterate is still a better start than the older plan
                self._ws_x = out.last_x[self._shift_x]
                self._ws_y = out.last_y[self._shift_y]
            elif self._ws_x is not None and self._ws_y is not None:
                self._ws_x = self._ws_x[self._shift_x]
                self._ws_y = self._ws_y[self._shift_y]
        plan, _ = self._project(plan, u_prev)
        if status != MpcStatus.HELD or self._plan is not None:
            self._plan = plan  # the last safe plan (a held u(-1) is not one)
        z_pred = self._predict_z(dx0, eta, plan)
        objective, violation = self._objective(plan, z_pred, r_abs, u_prev, eta)
        return self._make_result(plan, z_pred, status, out, dx0, eta, objective, violation)

    def _law_step(
        self,
        law: _AffineLaw,
        theta: FloatArray,
        out: FloatArray,
        dx0: FloatArray,
        eta: FloatArray,
        r: FloatArray,
        u_prev: FloatArray,
    ) -> MpcResult:
        """The step when the previous active set's law certifies its plan (``out = G th``)."""
        N, m, nz = self._N, self._m, self._nz
        self._ws_law = (law, theta)  # the warm start, computed only if OSQP is needed later
        self._consecutive = 0
        ends = law.ends
        raw = out[: ends[0]].reshape(N, m)
        plan, moved = (raw, False) if law.exact_plan else self._project(raw, u_prev)
        self._plan = plan
        if moved:
            # the projection moves a certified plan by rounding errors at most, but the contract
            # is the prediction and cost of the plan returned
            z_pred = self._predict_z(dx0, eta, plan)
            cost, violation = self._objective(plan, z_pred, r, u_prev, eta)
        else:
            z_pred = out[ends[0] : ends[1]].reshape(N, nz)
            w = out[ends[1] : ends[2]]
            if ends[3] > ends[2] and out[ends[2] : ends[3]].max() > 0.0:
                slack, violation = self._slack(z_pred)
            else:
                slack, violation = 0.0, 0.0
            cost = 0.5 * float(np.vdot(w, w)) + slack
        outcome = _OsqpOutcome(_REPEATED, solved_by="law")
        return self._make_result(plan, z_pred, MpcStatus.SOLVED, outcome, dx0, eta, cost, violation)

    def _make_result(
        self,
        plan: FloatArray,
        z_pred: FloatArray,
        status: MpcStatus,
        out: _OsqpOutcome,
        dx0: FloatArray,
        eta: FloatArray,
        objective: float,
        violation: float,
    ) -> MpcResult:
        """The step's result. ``plan`` (also kept as the last plan), ``z_pred`` and ``eta`` are
        this step's own arrays, handed out read-only."""
        planned = _readonly(plan)
        return MpcResult(
            u=planned[0],
            status=status,
            osqp_status=out.status,
            iterations=out.iterations,
            solve_time_s=out.time_s,
            planned_u=planned,
            predicted_z=_readonly(z_pred),
            disturbance=_readonly(eta),
            state=_readonly(self._model.x_op + dx0),
            objective=objective,
            max_output_violation=violation,
            failures=self._failures,
            consecutive_failures=self._consecutive,
            inaccurate=self._inaccurate,
            solved_by=out.solved_by,
        )

    # ------------------------------------------------------------------------------------------
    # affine laws
    # ------------------------------------------------------------------------------------------
    def _set_active(self, active: tuple[BoolArray, BoolArray] | None, build_law: bool) -> None:
        """Remember the accepted active set and its law (built when the set repeats)."""
        self._active = active
        self._law = None
        if active is None or not self._config.polish:
            return
        key = active[0].tobytes() + active[1].tobytes()
        if key in self._laws:
            self._laws.move_to_end(key)
            self._law = self._laws[key]
        elif build_law:
            self._law = self._laws[key] = self._make_law(*active)  # None: singular, not retried
            if len(self._laws) > _LAW_CACHE:
                self._laws.popitem(last=False)

    def _settle_warm_start(self) -> None:
        """OSQP's warm start from the last law step's solution (shifted by one sample)."""
        if self._ws_law is not None:
            law, theta = self._ws_law
            xy = law.xy @ theta
            self._ws_x = xy[: self._nv][self._shift_x]
            self._ws_y = xy[self._nv :][self._shift_y]
            self._ws_law = None

    def _law_point(self) -> tuple[FloatArray, FloatArray]:
        """A parameter point th (without its 1) inside the laws' domain, and a step per entry of
        the size of its range (so the affine maps are computed without cancellation)."""
        w_per_eta = np.abs(self._Bd / self._sx[:, None]).max(axis=0, initial=0.0)
        eta_step = 1.0 / np.where(w_per_eta > 0.0, w_per_eta, 1.0)
        base = np.concatenate(
            [np.zeros(self._n), np.zeros(self._n_eta), self._z_op, 0.5 * (self._u_min + self._u_max)]
        )
        return base, np.concatenate([self._sx, eta_step, self._sz, 0.25 * self._su])

    def _split(self, theta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(dx0, eta, r (Np, nz), u(-1)) of th (without its 1)."""
        n, ne, nz = self._n, self._n_eta, self._nz
        r = np.broadcast_to(theta[n + ne : n + ne + nz], (self._N, nz))
        return theta[:n], theta[n : n + ne], r, theta[n + ne + nz :]

    def _set_vector_maps(self) -> None:
        """q, l and u of the scaled QP as affine maps of th (``_qp_vectors`` for a constant r
        while u(-1) leaves the first rate row unclipped), for the affine laws.

        They depend on the model only, so they are computed with it (here and in
        :meth:`update_model`; about 0.4 ms at Np = 40), not by the first step that builds a law.
        """
        self._maps = None
        if not self._config.polish:
            return  # no laws without the exact active-set solves
        nv, nc = self._nv, self._nc

        def vectors(theta: FloatArray) -> FloatArray:
            return np.concatenate(self._qp_vectors(*self._split(theta)))

        M = _affine_map(vectors, *self._law_point())
        self._maps = (M[:nv], M[nv : nv + nc], M[nv + nc :])

    def _make_law(self, lower: BoolArray, upper: BoolArray) -> _AffineLaw | None:
        """The affine law of the active set (lower, upper); None if the set is singular."""
        assert self._maps is not None  # set with the model whenever laws are in use
        Qm, Lm, Um = self._maps
        N, m, n, ne, nz = self._N, self._m, self._n, self._n_eta, self._nz
        # input and rate rows: inactive ones must clear their bounds by _PLAN_MARGIN, so that a
        # plan with no active rate row is feasible as computed and skips the projection
        box = slice(self._row_u, self._row_u + N * m)
        moves = slice(self._row_rate, self._row_zlo)
        strict = np.zeros(self._nc, dtype=bool)
        strict[box] = strict[moves] = True
        kkt = self._kkt.affine(lower, upper, Qm, Lm, Um, strict)
        if kkt is None:
            return None
        p = Qm.shape[1]
        u_t = kkt.x[self._u_off : self._u_off + N * m]
        plan = u_t * np.tile(self._su, N)[:, None]
        plan[:, -1] += np.tile(self._model.u_op, N)
        # a move on an active input bound is that bound, exactly (not u_op + s_u u~ rounded)
        for active, bound in ((lower[box], self._u_min), (upper[box], self._u_max)):
            at = np.flatnonzero(active)
            plan[at] = 0.0
            plan[at, -1] = np.tile(bound, N)[at]
        pick = np.eye(p)
        z = self._scaled_z(pick[:n], pick[n : n + ne], u_t) * np.tile(self._sz, N)[:, None]
        z[:, -1] += np.tile(self._z_op, N)

        def residuals(theta: FloatArray) -> FloatArray:
            _, eta, r, u_prev = self._split(theta)
            th = np.append(theta, 1.0)
            return self._residual_roots((plan @ th).reshape(N, m), (z @ th).reshape(N, nz), r, u_prev, eta)

        w = _affine_map(residuals, *self._law_point())
        excess = []
        for bound, sign in ((self._z_max, 1.0), (self._z_min, -1.0)):
            finite = np.tile(np.isfinite(bound), N)
            rows = sign * z[finite]
            rows[:, -1] -= sign * np.tile(bound, N)[finite]
            excess.append(rows)
        # the KKT residual at th is at most residual @ |th|, so within KKT_TOL wherever
        # |th_j| <= KKT_TOL / (p residual_j) for every parameter j: two linear checks each
        res = kkt.residual
        if res[-1] * p > KKT_TOL:
            return None  # not even the constant part is solved accurately: no law
        rows = [plan, z, w, *excess, kkt.checks]
        ends = np.cumsum([len(b) for b in rows[:5]])
        for j in np.flatnonzero(res[:-1] > 0.0):
            for sign in (1.0, -1.0):
                row = np.zeros(p)
                row[j] = sign
                row[-1] = KKT_TOL / (p * res[j])
                rows.append(row[None, :])
        if self._rate_rows and self._config.first_move_rate_limited:
            # _qp_vectors clips u~(-1) to [u~min - du~max, u~max - du~min] for the first rate row;
            # the law holds where that clip does nothing
            u_col = n + ne + nz
            for lim, sign in ((self._umin_t - self._dmax_t, 1.0), (self._umax_t - self._dmin_t, -1.0)):
                for j in np.flatnonzero(np.isfinite(lim)):
                    row = np.zeros(p)
                    row[u_col + j] = sign / self._su[j]
                    row[-1] = -sign * (self._model.u_op[j] / self._su[j] + lim[j])
                    rows.append(row[None, :])
        return _AffineLaw(
            G=np.ascontiguousarray(np.vstack(rows)),
            ends=(int(ends[0]), int(ends[1]), int(ends[2]), int(ends[4])),
            exact_plan=not (lower[moves] | upper[moves]).any(),
            xy=np.vstack([kkt.x, kkt.y]),
        )

    def _project(self, plan: FloatArray, u_prev: FloatArray) -> tuple[FloatArray, bool]:
        """Project a plan, move by move, onto the input bounds and the rate bounds; also say
        whether anything moved.

        The first move is rate-limited relative to u(-1) (clipped so that the rate window meets
        the input box, as in the QP) when ``first_move_rate_limited``; corrections are at solver
        tolerance except on the held path. A plan that rides a rate bound breaks it by rounding
        errors, so the sequential pass (in Python floats: a few dozen numbers) starts at the first
        move that breaks one.
        """
        umin, umax = self._u_min, self._u_max
        out = np.minimum(np.maximum(plan, umin), umax)  # np.clip's result, less call overhead
        if self._has_rate_rows:
            dmin, dmax = self._du_min, self._du_max
            if self._config.first_move_rate_limited:
                out[0] = self._first_move(out[0].tolist(), u_prev.tolist())
            d = out[1:] - out[:-1]
            if self._symmetric_rates:  # |d| <= du_max is d >= du_min and d <= du_max, exactly
                broken = np.abs(d) > dmax
            else:
                broken = (d < dmin) | (d > dmax)
            if broken.any():
                out = self._project_moves(out, int(broken.any(axis=1).argmax()) + 1)
        return out, bool((out != plan).any())

    def _first_move(self, u0: list[float], u_prev: list[float]) -> list[float]:
        """u0 clipped to the rate window of u(-1), itself first clipped to where that window
        meets the input box (u0 already in the box; m numbers, in Python floats)."""
        lo_prev, hi_prev = self._u_prev_min_list, self._u_prev_max_list
        base = [min(max(v, lo_prev[j]), hi_prev[j]) for j, v in enumerate(u_prev)]
        return self._clamp_move(u0, base)

    def _project_moves(self, plan: FloatArray, first: int) -> FloatArray:
        """Clip moves ``first``..Np-1 in turn to the rate window of the move before."""
        rows = plan.tolist()
        for k in range(first, len(rows)):
            rows[k] = self._clamp_move(rows[k], rows[k - 1])
        return np.array(rows)

    def _clamp_move(self, move: list[float], prev: list[float]) -> list[float]:
        """``move`` clipped to the rate window of ``prev``, within the input bounds (Python floats;
        the same floating-point operations as ``np.minimum(np.maximum(...))``)."""
        umin, umax = self._u_min_list, self._u_max_list
        dmin, dmax = self._du_min_list, self._du_max_list
        out = []
        for j, v in enumerate(move):
            lo = max(umin[j], prev[j] + dmin[j])
            hi = min(umax[j], prev[j] + dmax[j])
            out.append(min(max(v, lo), hi))
        return out

    def _predict_z(self, dx0: FloatArray, eta: FloatArray, plan: FloatArray) -> FloatArray:
        """z(1..Np) [m] of the linear model for the plan (exact prediction, any formulation)."""
        u_t = ((plan - self._model.u_op) / self._su).reshape(-1)
        return self._z_op + self._scaled_z(dx0, eta, u_t).reshape(self._N, self._nz) * self._sz

    def _scaled_z(self, dx0: FloatArray, eta: FloatArray, u_t: FloatArray) -> FloatArray:
        """z~(1..Np) stacked, of dx0 [m], eta and U~ (vectors, or matrices column by column)."""
        return self._Zx @ dx0 + self._Zeta @ eta + self._Gam_z @ u_t

    def _objective(
        self, plan: FloatArray, z: FloatArray, r: FloatArray, u_prev: FloatArray, eta: FloatArray
    ) -> tuple[float, float]:
        """SI cost of the plan (constants included) and its largest output-bound violation [m];
        r is (nz,) or (Np, nz)."""
        w = self._residual_roots(plan, z, r, u_prev, eta)
        slack, violation = self._slack(z)
        return 0.5 * float(np.vdot(w, w)) + slack, violation

    def _residual_roots(
        self, plan: FloatArray, z: FloatArray, r: FloatArray, u_prev: FloatArray, eta: FloatArray
    ) -> FloatArray:
        """w with 1/2 |w|^2 the plan's tracking, move and input cost (SI): z - r, the moves and
        u - u_ss, each times a square root L of its weight (L' L = Qz, S, R)."""
        du = np.empty_like(plan)
        du[0] = plan[0] - u_prev
        np.subtract(plan[1:], plan[:-1], out=du[1:])
        parts = [((z - r) @ self._Lq.T).reshape(-1), (du @ self._Ls.T).reshape(-1)]
        if self._use_R:
            model = self._model
            rt_last = ((r if r.ndim == 1 else r[-1]) - self._z_op) / self._sz
            uss = model.u_op + self._u_target(self._scaled_w(eta), rt_last) * self._su
            parts.append(((plan - uss) @ self._Lr.T).reshape(-1))
        return np.concatenate(parts)

    def _slack(self, z: FloatArray) -> tuple[float, float]:
        """The slack cost (SI) of the output-bound violations of z and the largest one [m]."""
        if not self._has_z_rows:
            return 0.0, 0.0
        viol = np.maximum(np.maximum(z - self._z_max, self._z_min - z), 0.0)
        return float(np.vdot(viol, self._half_rho_q_si * viol + self._rho_l_si)), float(viol.max())

    # ------------------------------------------------------------------------------------------
    # model update
    # ------------------------------------------------------------------------------------------
    def update_model(
        self, A: ArrayLike, B: ArrayLike, x_op: ArrayLike | None = None, u_op: ArrayLike | None = None
    ) -> None:
        """Re-linearise: replace A and B (same shapes) and optionally the operating point.

        The OSQP matrices keep their sparsity pattern (every structurally possible entry is stored,
        explicit zeros included), so their values are replaced with OSQP's ``update(Px=, Ax=)``
        (a refactorisation, no new setup). The filter gain is recomputed (Bd follows B when it was
        defaulted) and the state estimate is carried over, shifted if x_op moves. The new
        (x_op, u_op) must be an equilibrium of the new model.

        Parameters
        ----------
        A : array_like, shape (n, n)
        B : array_like, shape (n, m)
        x_op : array_like, shape (n,), optional
            New operating-point state [m]; default unchanged.
        u_op : array_like, shape (m,), optional
            New operating-point inputs [m^3/s]; default unchanged.

        Raises
        ------
        ValueError
            Wrong shape, non-finite values, or an unobservable disturbance model (the controller is
            left unchanged).
        """
        A_ = _matrix(A, "A", self._n, self._n)
        B_ = _matrix(B, "B", self._n, self._m)
        new_model = replace(
            self._model,
            A=A_,
            B=B_,
            x_op=self._model.x_op if x_op is None else _vector(x_op, self._n, "x_op"),
            u_op=self._model.u_op if u_op is None else _vector(u_op, self._m, "u_op"),
        )
        Bd = B_.copy() if self._Bd_follows_B else self._Bd
        self._estimator.set_model(A_, B_, Bd)  # validates before changing anything
        self._settle_warm_start()  # from the old law, before the laws go
        self._laws.clear()
        self._law = None
        self._estimator.shift_state(self._model.x_op - new_model.x_op)
        old_u_op = self._model.u_op
        self._model = new_model
        self._Bd = Bd
        self._set_model_matrices(new_model.A, new_model.B)
        self._set_vector_bases()
        P, _, Aqp, _ = self._qp_dense()
        self._solver.update(Px=_csc_data(P, self._Pmask), Ax=_csc_data(Aqp, self._Amask))
        self._kkt.set_values(_csc(P, self._Pmask), _csc(Aqp, self._Amask))
        self._set_vector_maps()
        if self._ws_x is not None:
            # keep the warm start in absolute terms when u_op moves
            us = slice(self._u_off, self._u_off + self._N * self._m)
            self._ws_x = self._ws_x.copy()
            self._ws_x[us] += np.tile((old_u_op - new_model.u_op) / self._su, self._N)

    # ------------------------------------------------------------------------------------------
    # properties
    # ------------------------------------------------------------------------------------------
    @property
    def model(self) -> MpcModel:
        """The current model (after :meth:`update_model`)."""
        return self._model

    @property
    def config(self) -> MpcConfig:
        """The configuration."""
        return self._config

    @property
    def formulation(self) -> Literal["condensed", "sparse"]:
        """The QP form in use ("auto" resolved)."""
        return self._formulation

    @property
    def horizon(self) -> int:
        """Np."""
        return self._N

    @property
    def estimator(self) -> AugmentedKalmanFilter:
        """The augmented steady-state Kalman filter (deviation variables)."""
        return self._estimator

    @property
    def disturbance_matrix(self) -> FloatArray:
        """Bd, shape (n, n_eta) (copy)."""
        return self._Bd.copy()

    @property
    def failures(self) -> int:
        """Total HELD steps since construction or :meth:`reset`."""
        return self._failures

    @property
    def slack_weights(self) -> tuple[FloatArray, FloatArray]:
        """(rho_q [1/m^2], rho_l [1/m]), each (nz,), of the output slacks in SI units."""
        return self._c * self._rho_q_t / self._sz**2, self._c * self._rho_l_t / self._sz

    @property
    def scales(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(s_x (n,) [m], s_u (m,) [m^3/s], s_z (nz,) [m]) used to scale the QP (copies)."""
        return self._sx.copy(), self._su.copy(), self._sz.copy()

    @property
    def qp_size(self) -> tuple[int, int]:
        """(number of QP variables, number of constraint rows)."""
        return self._nv, self._nc

    @property
    def cost_scale(self) -> float:
        """c: the SI cost equals c times the scaled QP cost (plus constants)."""
        return self._c


def _csc_data(values: FloatArray, mask: BoolArray) -> FloatArray:
    """Entries of ``values`` on ``mask`` in CSC (column-major) order."""
    cols, rows = np.nonzero(mask.T)
    return np.ascontiguousarray(values[rows, cols])
