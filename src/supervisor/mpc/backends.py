r"""QP solvers for the MPC behind one small interface: daqp (dense dual active set) and OSQP (ADMM).

Both solve the scaled QP of :mod:`supervisor.mpc.formulation` in OSQP's form::

    min 1/2 v' P v + q' v   s.t.  l <= Aqp v <= u        (P given as its upper triangle)

A backend is set up once per model (``setup``), gets new matrix values when the model is
re-linearised (``update_matrices``, same sparsity pattern) and new vectors every step (``solve``).
It keeps its own warm or hot start between steps: the controller never sees a solver's state.

daqp (:class:`DaqpBackend`, the default on the condensed QP): a dual active-set method for small
dense QPs, exact on its final active set (the optimum to rounding, no tolerance ladder). Rows of
Aqp that are a unit vector on one variable (the input box u~ in [u~min, u~max]) become daqp's
simple bounds; the other rows are general constraints. The model object is set up once; each
step updates the bounds and solves hot-started from the previous step's working set (near a
steady state the set is unchanged and daqp only re-solves on it).

Soft rows (:class:`SoftRows`, the formulation's output slacks): a slack eps >= 0 of the pair
a'v + eps >= l, a'v - eps <= u with the cost 1/2 rho_q eps^2 + rho_l eps is not given to daqp.
The pair becomes one two-sided row l <= a'v <= u that daqp keeps soft, with its slack weights
(reciprocal quadratic 1/rho_q, linear rho_l) on either side::

    min over eps >= max(0, l - a'v, a'v - u) of 1/2 rho_q eps^2 + rho_l eps = phi(s),
    s = max(0, l - a'v, a'v - u),   phi(s) = 1/2 rho_q s^2 + rho_l s

(phi increases on s >= 0, and with l < u at most one side is violated): the same optimum in the
other variables, with Np nz fewer variables and 2 Np nz fewer rows for daqp. The slacks of the
returned v are s at the solution (0 unless daqp's exit is "soft optimal").

daqp is given the QP without its linear term, in the variable w = v - c shifted by the
unconstrained minimiser c = -P^-1 q (P is positive definite on the condensed QP)::

    1/2 v' P v + q' v = 1/2 w' P w + const,   l - Aqp c <= Aqp w <= u - Aqp c

so a step changes only daqp's bounds. daqp refreshes its whole internal (LDP) form when f
changes, a product with its constraint matrix, ~30 us of the ~50 us of daqp per step at Np = 40
(160 x 240), against ~5 us for the bounds alone. c and the shifted bounds are affine in the
step's data th, like q, l and u (``QpFormulation.vector_map``): ``set_vector_map`` folds the
shift into that map once per model, and ``vectors(th)`` gives q, l, u and daqp's bounds and c
from one product. The solution is v = w + c (equal to the unshifted QP's to rounding: 2e-13 of
the input range on the Kortela loop at Np = 40, cond(P) = 4e3).

OSQP (:class:`OsqpBackend`, the default on the sparse QP): warm-started from the previous primal
and dual solution shifted by one sample. Tolerance ladder (decision 0009): with the papers' tuning
the QP is nearly flat along "move timing" directions, so ADMM's residual test at a loose tolerance
accepts first moves ~1 % of the input range off the optimum. Each step solves with eps_abs =
eps_rel = 1e-4 and polishes (an exact solve on the identified active set: the optimum whenever it
succeeds); only if the polish fails it continues the same iterates at 1e-5 and then 1e-6
(``MpcConfig.tolerances``), within one iteration budget ``max_iter``. The last rung's solution is
accepted polished or not; a looser rung's when a tighter one ran out of iterations, or OSQP's
"solved inaccurate", is INACCURATE. OSQP's adaptive rho runs on an iteration count, so results
are deterministic.

The module is pure: no clock reads of its own (the times are the solvers' own reports), no I/O.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import daqp
import numpy as np
import osqp
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from supervisor.mpc.model import FloatArray

BackendName = Literal["daqp", "osqp"]

# OSQP status values (osqp.SolverStatus; the names are stable across 1.x).
_OSQP_SOLVED = 1
_OSQP_SOLVED_INACCURATE = 2

#: daqp's exit flags (docs of daqp 0.11: > 0 success, < 0 failure) and the status strings
#: reported for them (an exhausted budget worded as OSQP's, so both backends say it alike).
DAQP_STATUS = {
    1: "optimal",
    2: "soft optimal",
    -1: "infeasible",
    -2: "cycling",
    -3: "unbounded",
    -4: "maximum iterations reached",
    -5: "nonconvex",
    -6: "initial point infeasible",
}


@dataclass(frozen=True)
class QpSolution:
    """What one solve produced (scaled QP variables).

    Attributes
    ----------
    x : ndarray or None
        The accepted primal solution v, (nv,), finite; None when there is none (the step holds).
    accurate : bool
        True: the optimum (daqp's exact solve, OSQP's polished or last-rung solution). False: a
        usable but inexact solution (the controller reports INACCURATE).
    status : str
        The solver's own status string.
    iterations : int
        daqp's active-set iterations, or OSQP's ADMM iterations summed over the rungs.
    time_s : float
        The solver's reported time [s]: daqp's solve time, or OSQP's update + solve + polish.
    """

    x: FloatArray | None
    accurate: bool
    status: str
    iterations: int
    time_s: float

    @classmethod
    def of(
        cls, x: FloatArray | None, accurate: bool, status: str, iterations: int, time_s: float
    ) -> QpSolution:
        """The same object as ``QpSolution(x, accurate, ...)``, its dict filled directly (the
        frozen ``__init__`` sets each field through ``object.__setattr__``: a few times the
        cost, paid every step; as ``MpcResult.of_step``)."""
        obj = object.__new__(cls)
        obj.__dict__.update(x=x, accurate=accurate, status=status, iterations=iterations, time_s=time_s)
        return obj


class QpBackend(Protocol):
    """A QP solver as the controller uses it (module docstring): set up once, solve per step."""

    @property
    def name(self) -> BackendName:
        """``"daqp"`` or ``"osqp"`` (``MpcResult.solved_by``)."""
        ...

    def setup(
        self, P: sp.csc_matrix, A: sp.csc_matrix, q: FloatArray, lo: FloatArray, up: FloatArray
    ) -> None:
        """Take the QP (P upper triangle, CSC) once; raise ValueError if the solver refuses it."""
        ...

    def update_matrices(self, P: sp.csc_matrix, A: sp.csc_matrix, x_offset: FloatArray) -> None:
        """New values of P and A on the pattern given to ``setup``; ``x_offset`` is added to a
        kept primal warm start (the plan moves in scaled units when u_op moves)."""
        ...

    def set_vector_map(self, M: FloatArray) -> None:
        """Take the affine map [q; l; u] = M th from the step's data th to the QP's vectors
        (``QpFormulation.vector_map``); called after ``setup`` and every ``update_matrices``."""
        ...

    def vectors(self, th: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q, l, u of the step's data th (read-only views of one product). The backend keeps its
        own form of the same vectors from that product and uses it when ``solve`` is given
        exactly these arrays."""
        ...

    def solve(self, q: FloatArray, lo: FloatArray, up: FloatArray) -> QpSolution:
        """Solve with this step's vectors, warm- or hot-started from the previous step."""
        ...

    def solve_data(self, th: FloatArray) -> QpSolution:
        """``solve(*vectors(th))``, the step's data th straight to the solver (the same numbers)."""
        ...

    def reset(self) -> None:
        """Forget the warm or hot start (the next solve starts cold)."""
        ...


def _one_blas_thread() -> Any:
    """A context with BLAS on one thread: OpenBLAS's blocked Cholesky and its products round
    differently on two threads than on one (5e-16 in the plans), and the tiers run on one
    (tanklab_io.threads); so the matrices daqp is given are the same in every process (the
    co-simulation and the lock-step processes agree bit for bit). Setup and model updates only;
    a no-op where BLAS is on one thread already."""
    return threadpool_limits(limits=1, user_api="blas")


def _full_symmetric(P_upper: sp.csc_matrix) -> FloatArray:
    """The dense symmetric matrix of an upper triangle."""
    U = P_upper.toarray()
    return np.ascontiguousarray(U + U.T - np.diag(np.diag(U)))


def _simple_bounds(
    A: sp.csc_matrix, dropped: NDArray[np.bool_]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(bound_row, general): for each variable j the first row of A, not ``dropped``, that is
    the unit vector e_j' in A's stored pattern (-1 if none), and the remaining rows not
    ``dropped``, in order."""
    csr = A.tocsr()
    counts = np.diff(csr.indptr)
    bound_row = np.full(A.shape[1], -1, dtype=np.int64)
    for row in np.flatnonzero((counts == 1) & ~dropped):
        j = int(csr.indices[csr.indptr[row]])
        if csr.data[csr.indptr[row]] == 1.0 and bound_row[j] < 0:
            bound_row[j] = row
    used = dropped.copy()
    used[bound_row[bound_row >= 0]] = True
    return bound_row, np.flatnonzero(~used).astype(np.int64)


@dataclass(frozen=True)
class SoftRows:
    """Slack variables of soft two-sided rows, as the formulation lays them out.

    Slack ``columns[i]`` (a variable eps_i >= 0 by its unit row ``bound_rows[i]``, with the
    cost 1/2 ``quadratic[i]`` eps_i^2 + ``linear[i]`` eps_i and no cross term in P) enters row
    ``lower_rows[i]`` with +1 (a' v + eps_i >= l, upper bound +inf) and row ``upper_rows[i]``
    with -1 (a' v - eps_i <= u, lower bound -inf), the two rows equal elsewhere. The linear
    weights are constants of the QP (q's entries for the slacks never change).
    """

    columns: NDArray[np.int64]
    bound_rows: NDArray[np.int64]
    lower_rows: NDArray[np.int64]
    upper_rows: NDArray[np.int64]
    quadratic: FloatArray
    linear: FloatArray


#: daqp's sense flag of a soft constraint (daqp's constants: ACTIVE 1, LOWER 2, IMMUTABLE 4, SOFT 8).
_DAQP_SOFT = 8
#: daqp's exit flag of an optimum that violates a soft constraint (``DAQP_STATUS``).
_DAQP_SOFT_OPTIMAL = 2


class DaqpBackend:
    """daqp's hot-started model on the dense QP, given without its linear term (module docstring).

    Parameters
    ----------
    iter_limit : int
        daqp's iteration budget per solve (``MpcConfig.max_iter``).
    soft : SoftRows, optional
        The QP's output slacks: daqp is given the QP without them, each pair of rows merged into
        one two-sided row that daqp keeps soft with the same weights (module docstring).
    """

    def __init__(self, iter_limit: int, soft: SoftRows | None = None) -> None:
        self._iter_limit = int(iter_limit)
        self._soft = soft
        self._model: Any = None
        self._keep = np.zeros(0, dtype=np.int64)
        self._keep_prefix = True  # the kept variables are 0..nk-1
        self._bu_index = np.zeros(0, dtype=np.int64)
        self._bl_index = np.zeros(0, dtype=np.int64)
        self._soft_pos = np.zeros(0, dtype=np.int64)
        self._sense = np.zeros(0, dtype=np.int32)
        self._n_rows = 0
        self._nv = 0
        self._nk = 0
        self._map = np.zeros((0, 0))
        self._daqp_map = np.zeros((0, 0))
        # the arrays last handed out by ``vectors`` and daqp's form of them (same product)
        self._given: tuple[FloatArray, FloatArray, FloatArray] | None = None
        self._shifted: tuple[FloatArray, FloatArray, FloatArray] | None = None

    @property
    def name(self) -> BackendName:
        return "daqp"

    @property
    def size(self) -> tuple[int, int]:
        """(variables, general rows) of the QP daqp is given (slacks folded into soft rows)."""
        return self._nk, self._bu_index.size - self._nk

    def setup(
        self, P: sp.csc_matrix, A: sp.csc_matrix, q: FloatArray, lo: FloatArray, up: FloatArray
    ) -> None:
        nc, nv = A.shape
        self._n_rows, self._nv = nc, nv
        drop_cols = np.zeros(nv, dtype=bool)
        drop_rows = np.zeros(nc, dtype=bool)
        upper_of = np.arange(nc)
        soft = self._soft
        if soft is not None:
            drop_cols[soft.columns] = True
            drop_rows[soft.bound_rows] = True
            drop_rows[soft.upper_rows] = True
            upper_of[soft.lower_rows] = soft.upper_rows
            self._check_soft(P, A, soft, drop_cols)
        self._keep = np.flatnonzero(~drop_cols).astype(np.int64)
        A_keep = A.tocsc()[:, self._keep]
        bound_row, general = _simple_bounds(A_keep, drop_rows)
        self._general = general
        # daqp's rows: one simple bound per kept variable (a missing one is the extra, infinite
        # entry at index nc), then the general rows; a merged soft row takes its lower bound
        # from the lower row and its upper bound from the upper row
        simple = np.where(bound_row >= 0, bound_row, nc)
        self._bl_index = np.concatenate([simple, general])
        self._bu_index = np.concatenate([simple, upper_of[general]])
        self._nk = self._keep.size
        self._keep_prefix = bool(np.array_equal(self._keep, np.arange(self._nk)))
        sense = np.zeros(self._bl_index.size, dtype=np.int32)
        if soft is not None:
            pos = {int(r): k for k, r in enumerate(general)}
            self._soft_pos = np.array([self._nk + pos[int(r)] for r in soft.lower_rows], dtype=np.int64)
            sense[self._soft_pos] = _DAQP_SOFT
        self._sense = sense
        # l and u with one extra, infinite entry each (the missing bounds), filled per step
        self._ext_lo = np.full(nc + 1, -np.inf)
        self._ext_up = np.full(nc + 1, np.inf)
        self._make(P, A, q, lo, up)

    @staticmethod
    def _check_soft(P: sp.csc_matrix, A: sp.csc_matrix, soft: SoftRows, drop_cols: NDArray[np.bool_]) -> None:
        """ValueError unless P and A have the layout ``soft`` describes (:class:`SoftRows`)."""
        Pd = P.toarray()
        cols = soft.columns
        block = Pd[np.ix_(cols, cols)]
        if np.any(Pd[np.ix_(~drop_cols, cols)]) or np.any(Pd[np.ix_(cols, ~drop_cols)]):
            raise ValueError("daqp setup failed: the slacks have cross terms in P")
        if not np.array_equal(block, np.diag(soft.quadratic)) or np.any(soft.quadratic <= 0.0):
            raise ValueError("daqp setup failed: P's slack block is not diag(quadratic) > 0")
        Ad = A.toarray()
        lower, upper = Ad[soft.lower_rows], Ad[soft.upper_rows]
        k = np.arange(cols.size)
        if not (
            np.array_equal(lower[:, ~drop_cols], upper[:, ~drop_cols])
            and np.array_equal(lower[k, cols], np.ones(cols.size))
            and np.array_equal(upper[k, cols], -np.ones(cols.size))
            and np.count_nonzero(lower[:, drop_cols]) == cols.size
            and np.count_nonzero(upper[:, drop_cols]) == cols.size
        ):
            raise ValueError("daqp setup failed: the soft rows are not pairs a'v + eps >= l, a'v - eps <= u")

    def _make(
        self, P: sp.csc_matrix, A: sp.csc_matrix, q: FloatArray, lo: FloatArray, up: FloatArray
    ) -> None:
        keep = self._keep
        H = np.ascontiguousarray(_full_symmetric(P)[np.ix_(keep, keep)])
        try:
            with _one_blas_thread():
                chol = scipy.linalg.cho_factor(H)
        except np.linalg.LinAlgError as e:
            raise ValueError(f"daqp setup failed: P is not positive definite ({e})") from e
        A_general = np.ascontiguousarray(A.tocsr()[self._general].toarray()[:, keep])
        self._chol, self._A_general = chol, A_general
        self._A_soft = np.ascontiguousarray(A_general[self._soft_pos - self._nk])
        self._given = self._shifted = None
        _, bu, bl = self._shift(q, lo, up)
        model = daqp.Model()
        # no linear term: f = 0 (module docstring)
        flag, _ = model.setup(H, None, A_general, bu, bl, self._sense.copy())
        if flag < 0:
            raise ValueError(f"daqp setup failed: exit flag {flag} (is P positive definite?)")
        model.settings = {"iter_limit": self._iter_limit}
        if self._soft is not None:
            nd = self._sense.size
            rho = np.ones(nd)
            w = np.zeros(nd)
            rho[self._soft_pos] = 1.0 / self._soft.quadratic
            w[self._soft_pos] = self._soft.linear
            model.soft_weights(rho_l=rho, rho_u=rho, w_l=w, w_u=w)
        self._model = model

    def _bounds(self, lo: FloatArray, up: FloatArray) -> tuple[FloatArray, FloatArray]:
        """daqp's (bupper, blower): the rows reordered (daqp takes +-inf as an absent bound)."""
        n = self._n_rows
        self._ext_up[:n] = up
        self._ext_lo[:n] = lo
        return self._ext_up[self._bu_index], self._ext_lo[self._bl_index]

    def _shift(
        self, q: FloatArray, lo: FloatArray, up: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(c, bupper, blower) for w = v - c, c = -P^-1 q (kept variables): daqp's bounds
        (:meth:`_bounds`) minus c on the simple bounds and minus A_general c on the general rows
        (+-inf stay +-inf)."""
        if self._soft is not None and not np.array_equal(q[self._soft.columns], self._soft.linear):
            raise ValueError("the slacks' linear cost is a constant of the QP (SoftRows.linear)")
        c = -scipy.linalg.cho_solve(self._chol, q[self._keep])
        bu, bl = self._bounds(lo, up)
        nk = self._nk
        shift = self._A_general @ c
        for b in (bu, bl):
            b[:nk] -= c
            b[nk:] -= shift
        return c, bu, bl

    def set_vector_map(self, M: FloatArray) -> None:
        """The map th -> [c; bupper; blower] (daqp's row order) from [q; l; u] = M th: c = -P^-1 q
        and the bounds shifted as in :meth:`_shift`, column by column (rows infinite in M, whose
        th-part is zero, stay the constant +-inf); kept with M itself in one matrix, and alone
        for :meth:`solve_data`."""
        nv, nc = self._nv, self._n_rows
        Mq, Ml, Mu = M[:nv], M[nv : nv + nc], M[nv + nc :]
        with _one_blas_thread():
            C = -scipy.linalg.cho_solve(self._chol, Mq[self._keep])
            # daqp's rows act on w as the identity (simple bounds) and A_general (general rows)
            shift = np.vstack([C, self._A_general @ C])
        maps = []
        for Mb, inf, index in ((Mu, np.inf, self._bu_index), (Ml, -np.inf, self._bl_index)):
            ext = np.vstack([Mb, np.zeros(Mb.shape[1])])
            ext[-1, -1] = inf  # the missing simple bounds (index nc of the daqp rows)
            B = ext[index]
            finite = np.isfinite(B[:, -1])
            B[finite] -= shift[finite]
            maps.append(B)
        self._daqp_map = np.ascontiguousarray(np.vstack([C, *maps]))
        self._map = np.ascontiguousarray(np.vstack([M, self._daqp_map]))
        self._given = self._shifted = None

    def _split(self, out: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(c, bupper, blower) of one product with daqp's map."""
        nk, nd = self._nk, self._bu_index.size
        return out[:nk], out[nk : nk + nd], out[nk + nd :]

    def vectors(self, th: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        out = self._map @ th
        nv, nc = self._nv, self._n_rows
        q, lo, up = out[:nv], out[nv : nv + nc], out[nv + nc : nv + 2 * nc]
        for v in (q, lo, up):
            v.setflags(write=False)  # what is handed out is what daqp's form was made from
        self._given = (q, lo, up)
        self._shifted = self._split(out[nv + 2 * nc :])
        return q, lo, up

    def update_matrices(self, P: sp.csc_matrix, A: sp.csc_matrix, x_offset: FloatArray) -> None:
        # a re-linearisation changes H and A: a new setup (the hot start is a working set of
        # the old QP, so it is not carried over); the caller sets the new vector map
        del x_offset
        q = np.zeros(P.shape[0])
        if self._soft is not None:
            q[self._soft.columns] = self._soft.linear
        self._make(P, A, q, np.full(self._n_rows, -np.inf), np.full(self._n_rows, np.inf))

    def solve(self, q: FloatArray, lo: FloatArray, up: FloatArray) -> QpSolution:
        given, self._given = self._given, None
        if given is not None and self._shifted is not None and all(map(operator.is_, given, (q, lo, up))):
            c, bu, bl = self._shifted  # the product of ``vectors`` that made q, lo and up
        else:
            c, bu, bl = self._shift(q, lo, up)
        return self._solve(c, bu, bl)

    def solve_data(self, th: FloatArray) -> QpSolution:
        """Solve the QP of the step's data th ([q; l; u] = M th, :meth:`set_vector_map`): one
        product gives daqp's bounds and c, no q, l, u are formed (the same numbers as
        ``solve(*vectors(th))``)."""
        self._given = None
        return self._solve(*self._split(self._daqp_map @ th))

    def _solve(self, c: FloatArray, bu: FloatArray, bl: FloatArray) -> QpSolution:
        model = self._model
        model.update(bupper=bu, blower=bl)
        w, _, exit_flag, info = model.solve()
        flag = int(exit_flag)
        status = DAQP_STATUS.get(flag) or f"exit flag {flag}"
        iterations, time_s = int(info["iterations"]), float(info["solve_time"])
        if flag > 0 and w.shape == (self._nk,) and np.isfinite(w).all():
            x = self._primal(w, c, bu, bl, flag == _DAQP_SOFT_OPTIMAL)
            return QpSolution.of(x, True, status, iterations, time_s)
        self.reset()  # a failed solve's working set is no start for the next one
        return QpSolution(x=None, accurate=False, status=status, iterations=iterations, time_s=time_s)

    def _primal(
        self, w: FloatArray, c: FloatArray, bu: FloatArray, bl: FloatArray, violated: bool
    ) -> FloatArray:
        """v = w + c on the kept variables; each slack at its optimum given them, the violation
        max(0, l - a'v, a'v - u) of its soft row (rows on w against the shifted bounds). daqp
        says ``violated`` (exit flag 2) when a soft row is violated; otherwise every slack is 0
        (a violation within daqp's primal tolerance included) and the rows are not evaluated."""
        if self._soft is None:
            x = np.array(w, dtype=np.float64)
            x += c
            return x
        x = np.zeros(self._nv)
        if self._keep_prefix:  # the slacks last (the formulation's layout): one add into x
            np.add(w, c, out=x[: self._nk])
        else:
            x[self._keep] = w + c
        if violated:
            pos = self._soft_pos
            row = self._A_soft @ w
            x[self._soft.columns] = np.maximum(np.maximum(bl[pos] - row, row - bu[pos]), 0.0)
        return x

    def reset(self) -> None:
        if self._model is not None:
            # an explicit sense (all inactive, the soft rows kept soft) overrides the hot start
            self._model.update(sense=self._sense.copy())


class OsqpBackend:
    """OSQP with the shifted warm start and the tolerance ladder (module docstring).

    Parameters
    ----------
    tolerances : tuple of float
        eps_abs = eps_rel per rung, strictly decreasing (``MpcConfig.tolerances``).
    polish : bool
        Polish at every rung; False: one rung at the last tolerance.
    max_iter, check_termination : int
        OSQP's iteration budget per step (shared by the rungs) and its convergence-check period.
    shift_x, shift_y : ndarray of int
        Indices that shift a primal and a dual solution one sample forward (the warm start).
    """

    def __init__(
        self,
        tolerances: tuple[float, ...],
        polish: bool,
        max_iter: int,
        check_termination: int,
        shift_x: NDArray[np.int64],
        shift_y: NDArray[np.int64],
    ) -> None:
        tol = tuple(float(e) for e in tolerances)
        self._ladder = tol if polish else tol[-1:]
        self._polish = polish
        self._max_iter = int(max_iter)
        self._check = int(check_termination)
        self._shift_x, self._shift_y = shift_x, shift_y
        self._solver = osqp.OSQP()
        self._eps = self._ladder[0]
        self._budget = self._max_iter
        self._ws_x: FloatArray | None = None
        self._ws_y: FloatArray | None = None
        self._nv = self._nc = 0
        self._map = np.zeros((0, 0))

    @property
    def name(self) -> BackendName:
        return "osqp"

    def setup(
        self, P: sp.csc_matrix, A: sp.csc_matrix, q: FloatArray, lo: FloatArray, up: FloatArray
    ) -> None:
        self._nv, self._nc = A.shape[1], A.shape[0]
        try:
            self._solver.setup(
                P,
                q,
                A,
                lo,
                up,
                verbose=False,
                eps_abs=self._ladder[0],
                eps_rel=self._ladder[0],
                polishing=self._polish,
                max_iter=self._max_iter,
                check_termination=self._check,
                adaptive_rho=True,
                adaptive_rho_interval=50,  # iteration-based, not time-based: deterministic
                warm_starting=True,
            )
        except Exception as e:  # OSQPException / ValueError from the extension
            raise ValueError(f"OSQP setup failed: {e!r}") from e

    def set_vector_map(self, M: FloatArray) -> None:
        self._map = M

    def vectors(self, th: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        out = self._map @ th
        out.setflags(write=False)
        nv, nc = self._nv, self._nc
        return out[:nv], out[nv : nv + nc], out[nv + nc :]

    def update_matrices(self, P: sp.csc_matrix, A: sp.csc_matrix, x_offset: FloatArray) -> None:
        self._solver.update(Px=P.data, Ax=A.data)
        if self._ws_x is not None:
            self._ws_x = self._ws_x + x_offset

    def reset(self) -> None:
        self._ws_x = self._ws_y = None

    def solve_data(self, th: FloatArray) -> QpSolution:
        return self.solve(*self.vectors(th))

    def solve(self, q: FloatArray, lo: FloatArray, up: FloatArray) -> QpSolution:
        """The ladder: each rung solves to its tolerance with polishing, continuing the ADMM
        iterations of the previous rung (OSQP keeps its iterate between ``solve`` calls). A
        successful polish gives the exact optimum of the identified active set and ends the
        ladder. If a rung stops without converging, the previous rung's solution (if any) is
        used, flagged inexact, unless OSQP reports "solved inaccurate" at a rung whose 10 x
        tolerance is tighter still."""
        self._solver.update(q=q, l=lo, u=up)
        if self._ws_x is None or self._ws_y is None:
            self._solver.warm_start(x=np.zeros(self._nv), y=np.zeros(self._nc))
        else:
            self._solver.warm_start(x=self._ws_x, y=self._ws_y)
        status, iterations, time_s = "not run", 0, 0.0
        best: tuple[FloatArray, FloatArray] | None = None
        last: tuple[FloatArray, FloatArray] | None = None
        accurate = False
        held_eps = math.inf  # tolerance met by the solution held in ``best``
        for rung, eps in enumerate(self._ladder):
            left = self._max_iter - iterations
            if left <= 0:
                break
            if self._eps != eps or self._budget != left:
                self._solver.update_settings(eps_abs=eps, eps_rel=eps, max_iter=left)
                self._eps, self._budget = eps, left
            res = self._solver.solve(raise_error=False)
            info = res.info
            iterations += int(info.iter)
            time_s += float(info.update_time) + float(info.solve_time) + float(info.polish_time)
            status = str(info.status)
            x = np.array(res.x, dtype=np.float64)
            y = np.array(res.y, dtype=np.float64)
            finite = x.shape == (self._nv,) and bool(np.isfinite(x).all()) and bool(np.isfinite(y).all())
            if finite:
                last = (x, y)
            status_val = int(info.status_val)
            if status_val == _OSQP_SOLVED and finite:
                done = int(info.status_polish) == 1 or rung == len(self._ladder) - 1
                best, accurate, held_eps = (x, y), done, eps
                if done:
                    break
                continue
            # OSQP's "solved inaccurate" meets 10 x its tolerance: keep it if that is still tighter
            if status_val == _OSQP_SOLVED_INACCURATE and finite and 10.0 * eps < held_eps:
                best, accurate = (x, y), False
            break
        start = best if best is not None else last  # an unfinished iterate still beats an old plan
        if start is not None:
            self._ws_x, self._ws_y = start[0][self._shift_x], start[1][self._shift_y]
        elif self._ws_x is not None and self._ws_y is not None:
            self._ws_x, self._ws_y = self._ws_x[self._shift_x], self._ws_y[self._shift_y]
        return QpSolution(
            x=None if best is None else best[0],
            accurate=accurate,
            status=status,
            iterations=iterations,
            time_s=time_s,
        )


def make_backend(
    name: BackendName,
    *,
    tolerances: tuple[float, ...],
    polish: bool,
    max_iter: int,
    check_termination: int,
    shift_x: NDArray[np.int64],
    shift_y: NDArray[np.int64],
    soft: SoftRows | None = None,
) -> QpBackend:
    """The backend ``name`` with the configuration's settings (``soft``: daqp only)."""
    if name == "daqp":
        return DaqpBackend(max_iter, soft)
    return OsqpBackend(tolerances, polish, max_iter, check_termination, shift_x, shift_y)
