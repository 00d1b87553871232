"""The MPC's data types: the linear model, the tuning and the result of one step (SI units).

Validation lives here too, so that a wrong shape, a NaN or a bad bound fails when the model or
controller is built, with the field's name, not inside a solver. Everything is absolute SI
(levels m, flows m^3/s); deviations and scaling belong to :mod:`supervisor.mpc.formulation`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tanklab.enums import MpcStatus

if TYPE_CHECKING:
    from supervisor.mpc.cost import PlanCost

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: How a step's plan was found: the daqp backend, the OSQP backend, or ``"held"`` (no solution:
#: the last safe plan shifted by one sample).
SolvedBy = Literal["daqp", "osqp", "held"]


# ----------------------------------------------------------------------------------------------
# validation helpers (shared by the package)
# ----------------------------------------------------------------------------------------------
def as_float(value: ArrayLike, name: str) -> FloatArray:
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be numeric, got {type(value).__name__}")
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name} must be numeric, got {type(value).__name__}") from e


def matrix(value: ArrayLike, name: str, rows: int | None, cols: int | None) -> FloatArray:
    arr = as_float(value, name)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got shape {arr.shape}")
    if (rows is not None and arr.shape[0] != rows) or (cols is not None and arr.shape[1] != cols):
        raise ValueError(f"{name} must have shape ({rows}, {cols}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def vector(
    value: ArrayLike, size: int, name: str, *, allow_inf: bool = False, copy: bool = True
) -> FloatArray:
    """Scalar (broadcast) or 1-D of length ``size``; NaN never allowed, +-inf only if ``allow_inf``
    (``copy=False``: a float vector of the right shape comes back as it is, for values only read)."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (size,):
        # the per-step fast path (a float vector already): the value check
        if not (np.isfinite(value).all() if not allow_inf else not np.isnan(value).any()):
            raise ValueError(f"{name} must be {'non-NaN' if allow_inf else 'finite'}")
        return value.copy() if copy else value
    arr = as_float(value, name)
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    if arr.shape != (size,):
        raise ValueError(f"{name} must be a scalar or have shape ({size},), got {arr.shape}")
    if np.any(np.isnan(arr)) or (not allow_inf and not np.all(np.isfinite(arr))):
        raise ValueError(f"{name} must be {'non-NaN' if allow_inf else 'finite'}")
    return arr


def weight(value: ArrayLike, size: int, name: str) -> FloatArray:
    """A symmetric positive semidefinite weight: scalar, diagonal (size,) or full (size, size)."""
    arr = as_float(value, name)
    if arr.ndim <= 1:
        W = np.diag(vector(arr, size, name))
    else:
        W = matrix(arr, name, size, size)
    if not np.allclose(W, W.T, rtol=1e-12, atol=0.0):
        raise ValueError(f"{name} must be symmetric")
    W = 0.5 * (W + W.T)
    if size and np.min(np.linalg.eigvalsh(W)) < -1e-12 * max(1.0, float(np.max(np.abs(W)))):
        raise ValueError(f"{name} must be positive semidefinite")
    return W


def sqrt_psd(W: FloatArray) -> FloatArray:
    """L with L' L = W for a symmetric PSD W (the square roots of a diagonal W exactly)."""
    if np.count_nonzero(W - np.diag(np.diag(W))) == 0:
        return np.diag(np.sqrt(np.diag(W)))
    lam, V = np.linalg.eigh(W)
    return np.sqrt(np.clip(lam, 0.0, None))[:, None] * V.T


def readonly(a: FloatArray) -> FloatArray:
    """``a`` made read-only (``setflags``: a fifth of the cost of ``a.flags.writeable = False``,
    which builds a flags object first; measured 0.2 against 1.7 us)."""
    a.setflags(write=False)
    return a


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
        A = matrix(self.A, "A", None, None)
        n = A.shape[0]
        if A.shape != (n, n) or n == 0:
            raise ValueError(f"A must be square and non-empty, got shape {A.shape}")
        B = matrix(self.B, "B", n, None)
        if B.shape[1] == 0:
            raise ValueError("B must have at least one column (input)")
        C = matrix(self.C, "C", None, n)
        Cz = matrix(self.Cz, "Cz", None, n)
        if C.shape[0] == 0 or Cz.shape[0] == 0:
            raise ValueError("C and Cz must have at least one row")
        x_op = vector(self.x_op, n, "x_op")
        u_op = vector(self.u_op, B.shape[1], "u_op")
        if isinstance(self.ts_s, bool) or not isinstance(self.ts_s, (int, float, np.floating, np.integer)):
            raise TypeError(f"ts_s must be a real number, got {type(self.ts_s).__name__}")
        if not (math.isfinite(float(self.ts_s)) and float(self.ts_s) > 0.0):
            raise ValueError(f"ts_s must be finite and > 0, got {self.ts_s}")
        for name, val in (("A", A), ("B", B), ("C", C), ("Cz", Cz), ("x_op", x_op), ("u_op", u_op)):
            object.__setattr__(self, name, readonly(val))
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
Solver = Literal["auto", "daqp", "osqp"]
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
        QP form; "auto" uses sparse from ``SPARSE_FROM_HORIZON`` on (condensed below it).
    solver : {"auto", "daqp", "osqp"}
        QP backend (:mod:`supervisor.mpc.backends`). "auto": daqp (dense dual active set, hot
        started) on the condensed QP, OSQP (sparse ADMM with the tolerance ladder) on the sparse
        QP. "daqp" needs the condensed form.
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
        OSQP backend only. The tolerance ladder: OSQP eps_abs = eps_rel per rung, scaled units,
        strictly decreasing.
        Default (1e-4, 1e-5, 1e-6): meets the accuracy guard (closed-loop IAE within 1 % of an
        interior-point reference; measured <= 0.09 %, docs/mpc.md).
    polish : bool
        OSQP backend only: solution polishing at every rung. Default True. False: one rung at the
        last tolerance.
    max_iter : int
        Iteration budget per step: OSQP's, shared by the rungs, or daqp's active-set changes.
        Default 10000.
    check_termination : int
        OSQP backend only: convergence checked every this many iterations. Default 5.
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
    solver: Solver = "auto"
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
        if self.solver not in ("auto", "daqp", "osqp"):
            raise ValueError(f"solver must be 'auto', 'daqp' or 'osqp', got {self.solver!r}")
        if self.solver == "daqp" and self.formulation == "sparse":
            raise ValueError("solver 'daqp' needs formulation 'condensed' or 'auto' (it is a dense solver)")
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


class PendingPrediction:
    """What a step's ``state`` and ``predicted_z`` are evaluated from when first read (the control
    loop reads neither, so the step does not pay for them; :meth:`MpcResult.of_step`)::

        state       = x_op + dx0                                         (n,)      [m]
        predicted_z = z_op_N + z_map [dx0; eta; vec(U - u_op)]  as (Np, nz)          [m]

    with the solved model's arrays (``QpFormulation.set_prediction_map``; a later
    re-linearisation makes new ones), this step's own copy of dx0 and its eta and plan (read-only
    arrays of the result). The same floating-point operations as evaluating them in the step.
    """

    __slots__ = ("dx0", "eta", "plan", "u_op", "x_op", "z_map", "z_op_N")

    def __init__(
        self,
        x_op: FloatArray,
        u_op: FloatArray,
        z_map: FloatArray,
        z_op_N: FloatArray,
        dx0: FloatArray,
        eta: FloatArray,
        plan: FloatArray,
    ) -> None:
        self.x_op, self.u_op, self.z_map, self.z_op_N = x_op, u_op, z_map, z_op_N
        self.dx0, self.eta, self.plan = dx0, eta, plan

    def state(self) -> FloatArray:
        """x(k|k) = x_op + dx0 [m]."""
        return self.x_op + self.dx0

    def predicted_z(self) -> FloatArray:
        """z(1..Np) [m], (Np, nz), of the linear model for the plan (one product)."""
        zin = np.concatenate((self.dx0, self.eta, (self.plan - self.u_op).reshape(-1)))
        z = self.z_map @ zin
        z += self.z_op_N
        return z.reshape(self.plan.shape[0], -1)


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
        The QP backend's status string for this step (the name is kept from the OSQP-only
        controller: daqp's exit, e.g. "optimal", or OSQP's, e.g. "solved").
    iterations : int
        Solver iterations of this step: daqp's active-set changes or OSQP's ADMM iterations.
    solve_time_s : float
        Solver-reported time of this step [s]: daqp's solve time, or OSQP's update + solve +
        polish time summed over the rungs.
    planned_u : ndarray, shape (Np, m)
        Planned inputs u(0..Np-1) [m^3/s]; ``planned_u[0] == u``.
    predicted_z : ndarray, shape (Np, nz)
        Controlled outputs z(1..Np) predicted for the plan [m]. Evaluated on first read in a
        controller's result (:class:`PendingPrediction`), with the model the step was solved on.
    disturbance : ndarray, shape (n_eta,)
        Disturbance estimate used [eta units; m^3/s for Bd = B].
    state : ndarray, shape (n,)
        State estimate x(k|k) used [m] (evaluated on first read, as ``predicted_z``).
    objective : float
        SI cost of the returned plan (all terms, constants included). Evaluated on first read
        (no caller in the control loop reads it), with the model the step was solved on.
    max_output_violation : float
        Largest predicted violation of the output bounds over the plan [m] (0 if none);
        evaluated with ``objective``.
    failures : int
        Total HELD steps since construction or :meth:`MpcController.reset`.
    consecutive_failures : int
        HELD steps in a row up to and including this one.
    inaccurate : int
        Total INACCURATE steps since construction or reset.
    solved_by : str
        How this step's plan was found: ``"daqp"`` or ``"osqp"`` (the backend that solved it) or
        ``"held"`` (no solution: the shifted last plan).
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
    failures: int
    consecutive_failures: int
    inaccurate: int
    solved_by: SolvedBy = "daqp"
    #: the cost terms and the step's reference (nz,) or (Np, nz) [m] and u(-1) (m,) [m^3/s],
    #: this step's own read-only copies: what ``objective`` is evaluated from
    cost: PlanCost | None = field(default=None, repr=False, compare=False)
    reference: FloatArray | None = field(default=None, repr=False, compare=False)
    u_prev: FloatArray | None = field(default=None, repr=False, compare=False)

    @classmethod
    def of_step(cls, pending: PendingPrediction | None = None, **values: Any) -> MpcResult:
        """The result of a step from every field's value, made by the controller (which has just
        made or checked them): the instance's dict is filled directly. The frozen dataclass's
        ``__init__`` sets each of the 16 fields through ``object.__setattr__``, about 10x the cost
        (12-15 us against 1-2.5 us on the loaded benchmark machine, ~10 % of a whole Np = 40
        step); the result is the same object (equal, frozen, ``objective`` evaluated when read;
        a test checks it against ``MpcResult(**values)``).

        With ``pending`` (:class:`PendingPrediction`), ``state`` and ``predicted_z`` are left out
        of ``values`` and evaluated from it when first read (then kept: the same array on every
        read, read-only like the others)."""
        need = _RESULT_FIELDS if pending is None else _EAGER_FIELDS
        if values.keys() != need:
            raise TypeError(f"MpcResult.of_step needs exactly the fields {sorted(need)}")
        obj = object.__new__(cls)
        obj.__dict__.update(values)
        if pending is not None:
            obj.__dict__["_pending"] = pending
        return obj

    def __getattr__(self, name: str) -> Any:
        """A lazy field of :meth:`of_step` (called only for names not in the instance's dict)."""
        pending = self.__dict__.get("_pending")
        if pending is None or name not in _LAZY_FIELDS:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        value = getattr(pending, name)()
        value.setflags(write=False)
        self.__dict__[name] = value
        return value

    @cached_property
    def _cost_and_violation(self) -> tuple[float, float]:
        """(objective, max_output_violation), evaluated once on first read: the control loop
        never reads them, so the step does not pay for them (decision 0027's follow-up)."""
        if self.cost is None or self.reference is None or self.u_prev is None:
            return math.nan, math.nan
        plan, z = self.planned_u, self.predicted_z
        return self.cost.evaluate(plan, z, self.reference, self.u_prev, self.disturbance)

    @property
    def objective(self) -> float:
        """SI cost of the returned plan (class docstring); NaN for a result built without ``cost``."""
        return self._cost_and_violation[0]

    @property
    def max_output_violation(self) -> float:
        """Largest predicted output-bound violation [m] (class docstring)."""
        return self._cost_and_violation[1]


_RESULT_FIELDS = frozenset(f.name for f in fields(MpcResult))
#: the fields :meth:`MpcResult.of_step` can leave to a :class:`PendingPrediction`
_LAZY_FIELDS = frozenset({"state", "predicted_z"})
_EAGER_FIELDS = _RESULT_FIELDS - _LAZY_FIELDS
