r"""The MPC controller: estimate, solve, hold or project, and the step's result (pure core).

One step (:meth:`MpcController.step`): the steady-state Kalman filter of
:mod:`supervisor.estimator` updates x(k|k) and eta(k|k) from the measured outputs; the QP of
:mod:`supervisor.mpc.formulation` gets this step's q, l and u and is solved by the configured
backend of :mod:`supervisor.mpc.backends` (daqp hot-started on the condensed QP by default, OSQP
with its tolerance ladder on the sparse one); the plan is read back in SI units.

Status, every step: the backend's optimum -> SOLVED; a usable inexact solution (OSQP only) ->
INACCURATE (the plan is used); no solution or a non-finite one -> HELD: the last safe plan shifted
by one sample is used (before any plan exists, u(-1) is held), and the failure is counted. Every
applied move and every returned plan is projected onto u_min <= u <= u_max and the rate limits
(relative to the applied u(-1); a u(-1) outside the input box is first clipped to where the rate
window meets it, the physical bounds win), so bounds hold exactly even at solver tolerance and on
the held path; NaN is never returned.

``update_model`` replaces A and B (and optionally the operating point): the formulation rebuilds
its matrices on the same sparsity pattern and the backend takes the new values.

Where the step's time goes (decision 0027, follow-ups): daqp's update and solve are a fifth of
it; the rest is numpy's per-call cost on arrays of 2 to 560 numbers. So the usual case does
little per step:

- the step's data th = [dx0; eta; r; u(-1); u(-1) clipped; 1] is written into one buffer
  (``_set_step_buffers``) and checked for finite values in one pass; the QP's vectors and daqp's
  bounds are one product M th (``QpFormulation.set_vector_map``, ``DaqpBackend.set_vector_map``);
- the projection clips the plan to per-move bounds lo, hi (Np, m): the input box, the first row
  narrowed to the first move's rate window max(u_min, u_b + du_min) .. min(u_max, u_b + du_max)
  with u_b = u(-1) clipped to [u_min - du_max, u_max - du_min]; clipping to the box and then to a
  window inside it is clipping to the window, so this is the box clip followed by the first
  move's clamp, to the bit; the move-by-move pass runs only from the first move that breaks a
  rate bound;
- x(k|k) = x_op + dx0 and z(1..Np) = z_op + z_map [dx0; eta; U - u_op] are evaluated when first
  read (``PendingPrediction``: the control loop reads neither), as are the plan's SI cost and
  output-bound violation (``supervisor.mpc.cost``).

The module is pure: no clock, no I/O, no logging.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from supervisor.estimator import AugmentedKalmanFilter
from supervisor.mpc.backends import QpBackend, QpSolution, make_backend
from supervisor.mpc.formulation import QpFormulation
from supervisor.mpc.model import (
    FloatArray,
    MpcConfig,
    MpcModel,
    MpcResult,
    PendingPrediction,
    SolvedBy,
    as_float,
    matrix,
    readonly,
    vector,
)
from tanklab.enums import MpcStatus

_ONE = np.ones(1)


class MpcController:
    """Offset-free constrained MPC with a steady-state Kalman filter (see the package docstring).

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
        unobservable disturbance model, or a solver setup error.
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
        self._n, self._m, self._nz, self._N = n, m, nz, config.horizon
        if config.disturbance_matrix is None:
            self._Bd_follows_B = True
            Bd = model.B.copy()
        else:
            self._Bd_follows_B = False
            Bd = matrix(config.disturbance_matrix, "disturbance_matrix", n, None)
        self._n_eta = Bd.shape[1]
        # bounds, scaling, weights and the QP's layout (validated there)
        self._qp = QpFormulation(model, config, Bd)

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

        # -- the QP and its solver ---------------------------------------------------------------
        qp = self._qp
        self._backend: QpBackend = make_backend(
            qp.solver,
            tolerances=config.tolerances,
            polish=config.polish,
            max_iter=config.max_iter,
            check_termination=config.check_termination,
            shift_x=qp.shift_x,
            shift_y=qp.shift_y,
            soft=qp.soft_rows(),
        )
        P, Aqp = qp.qp_matrices()
        q, lo, up = qp.qp_vectors(np.zeros(n), np.zeros(self._n_eta), np.zeros((self._N, nz)), model.u_op)
        self._backend.setup(P, Aqp, q, lo, up)
        self._backend.set_vector_map(qp.vector_map)
        self._set_correct_map()
        self._set_step_buffers()
        # the bounds of each move for the projection (Np, m) [m^3/s]: the input box, the first
        # row narrowed to the first move's rate window every step (:meth:`_project`)
        self._move_lo = np.tile(self._qp.u_min, (self._N, 1))
        self._move_hi = np.tile(self._qp.u_max, (self._N, 1))
        self._reset_runtime_state()

    def _set_step_buffers(self) -> None:
        """The step's data th = [dx0; eta; r; u(-1); u(-1) clipped; 1] (``QpFormulation.step_data``)
        as one buffer filled in place by :meth:`plan`'s usual case, with a view per block: the
        inputs are written once and checked for finite values in one pass over th."""
        n, ne, nz, m = self._n, self._n_eta, self._nz, self._m
        th = np.empty(n + ne + nz + 2 * m + 1)
        th[-1] = 1.0
        cut = np.cumsum([n, ne, nz, m, m])
        self._th = th
        self._th_dx, self._th_eta, self._th_r, self._th_u, self._th_ub, _ = np.split(th, cut)

    def _reset_runtime_state(self) -> None:
        self._plan: FloatArray | None = None
        self._failures = 0
        self._consecutive = 0
        self._inaccurate = 0
        self._backend.reset()

    def reset(self, x: ArrayLike | None = None, disturbance: ArrayLike | None = None) -> None:
        """Forget the plan, the warm start and the counters; restart the filter.

        Parameters
        ----------
        x : array_like, shape (n,), optional
            Prior state for the first :meth:`step` [m, absolute]; default x_op.
        disturbance : array_like, shape (n_eta,), optional
            Prior disturbance estimate; default zeros.
        """
        dx = None if x is None else vector(x, self._n, "x") - self._model.x_op
        d = None if disturbance is None else vector(disturbance, self._n_eta, "disturbance")
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
        y_dev = y_ - self._qp.y_op
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
            vector(v, size, name, copy=False),
            vector(u_prev, m, "u_prev", copy=False),
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
        if (  # the usual case, four float vectors of the right shapes: written into th at once
            type(x) is np.ndarray
            and type(r) is np.ndarray
            and type(u_prev) is np.ndarray
            and type(disturbance) is np.ndarray
            and x.dtype == r.dtype == u_prev.dtype == disturbance.dtype == np.float64
            and x.shape == (self._n,)
            and r.shape == (self._nz,)
            and u_prev.shape == (self._m,)
            and disturbance.shape == (self._n_eta,)
        ):
            dx0 = np.subtract(x, self._model.x_op, out=self._th_dx)
            self._th_eta[:] = disturbance
            self._th_r[:] = r
            self._th_u[:] = u_prev
            # x - x_op is finite iff x is (x_op is): one check of th covers the four inputs
            if np.isfinite(self._th).all():
                return self._solve_th(dx0, disturbance, r, u_prev)
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
            d_ = vector(disturbance, self._n_eta, "disturbance")
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
        (x, disturbance) : x(k|k) [m, absolute], shape (n,), and eta(k|k), shape (n_eta,) (read-only;
        one product, :meth:`_set_correct_map`).
        """
        if (
            type(y) is np.ndarray
            and type(x_prior) is np.ndarray
            and type(disturbance_prior) is np.ndarray
            and y.dtype == x_prior.dtype == disturbance_prior.dtype == np.float64
            and y.shape == (self._model.n_measured,)
            and x_prior.shape == (self._n,)
            and disturbance_prior.shape == (self._n_eta,)
        ):
            data = np.concatenate((x_prior, disturbance_prior, y, _ONE))
            if not np.isfinite(data).all():  # the checks below name the value
                data = self._correct_data(y, x_prior, disturbance_prior)
        else:
            data = self._correct_data(y, x_prior, disturbance_prior)
        out = self._correct_map @ data
        out.setflags(write=False)
        na, n = self._n + self._n_eta, self._n
        self._estimator.set_corrected(out[:na], out[na : 2 * na])
        return out[2 * na :], out[na + n : 2 * na]

    def _correct_data(self, y: ArrayLike, x_prior: ArrayLike, disturbance_prior: ArrayLike) -> FloatArray:
        """[x_prior; eta_prior; y; 1] of :meth:`correct`, each value checked (ValueError naming it)."""
        y_ = vector(y, self._model.n_measured, "y")
        x_ = vector(x_prior, self._n, "x_prior")
        d_ = vector(disturbance_prior, self._n_eta, "disturbance_prior")
        return np.concatenate((x_, d_, y_, _ONE))

    def _set_correct_map(self) -> None:
        """The map of :meth:`correct`: [prior; posterior; x(k|k)] = M [x_prior; eta_prior; y; 1]
        with prior = [x_prior - x_op; eta_prior] and posterior = (I - Kf Ca) prior + Kf S (y - y_op)
        (S selects the filtered rows of y), deviation variables, and x(k|k) = x_op + its state
        part [m]; rebuilt with the filter's gain on every model change."""
        n, ne, ny = self._n, self._n_eta, self._model.n_measured
        na = n + ne
        K = self._estimator.gain
        Ca = self._estimator.augmented[2]
        x_op = self._model.x_op
        E = np.zeros((na, na + ny + 1))  # prior = E data
        E[:, :na] = np.eye(na)
        E[:n, -1] = -x_op
        Y = np.zeros((self._est_rows.size, na + ny + 1))  # S (y - y_op) = Y data
        Y[np.arange(self._est_rows.size), na + self._est_rows] = 1.0
        Y[:, -1] = -self._qp.y_op[self._est_rows]
        post = (np.eye(na) - K @ Ca) @ E + K @ Y
        x_abs = post[:n].copy()
        x_abs[:, -1] += x_op
        self._correct_map = np.ascontiguousarray(np.vstack([E, post, x_abs]))

    def _reference(self, r: ArrayLike) -> FloatArray:
        """r checked: (nz,) for a constant reference or (Np, nz) for a preview (both broadcast
        against (Np, nz) arrays; only read, so a float array comes back as it is)."""
        arr = r if type(r) is np.ndarray and r.dtype == np.float64 else as_float(r, "r")
        if arr.shape not in ((self._nz,), (self._N, self._nz)):
            raise ValueError(f"r must have shape ({self._nz},) or ({self._N}, {self._nz}), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError("r must be finite")
        return arr

    def _solve_th(self, dx0: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray) -> MpcResult:
        """:meth:`_solve` for a constant reference with dx0, eta, r and u(-1) already in the step
        buffer th (:meth:`_set_step_buffers`; ``dx0`` is its view): only u(-1) clipped is added."""
        u_base = self._qp.rate_window_base(u_prev.tolist())
        self._th_ub[:] = u_base
        return self._finish(self._backend.solve_data(self._th), dx0, eta, r, u_prev, u_base)

    def _solve(self, dx0: FloatArray, eta: FloatArray, r: FloatArray, u_prev: FloatArray) -> MpcResult:
        """The step from the state estimate, disturbance, reference ((nz,) or (Np, nz)) and u(-1)."""
        qp = self._qp
        # u(-1) clipped to where its rate window meets the input box: the first rate row's base
        # in the QP and the projection's first move (Python floats, m numbers)
        u_base = qp.rate_window_base(u_prev.tolist())
        # a constant reference (the usual case, also as a preview that repeats one row) takes
        # the vectors as one product of the step's data, in the backend (which keeps its own
        # form of them from the same product); so the same QP data always gives the same plan
        backend = self._backend
        if r.ndim == 1:
            sol = backend.solve_data(qp.step_data(dx0, eta, r, u_prev, u_base))
        elif (r == r[0]).all():
            sol = backend.solve_data(qp.step_data(dx0, eta, r[0], u_prev, u_base))
        else:
            sol = backend.solve(*qp.qp_vectors(dx0, eta, r, u_prev))
        return self._finish(sol, dx0, eta, r, u_prev, u_base)

    def _finish(
        self,
        sol: QpSolution,
        dx0: FloatArray,
        eta: FloatArray,
        r: FloatArray,
        u_prev: FloatArray,
        u_base: list[float],
    ) -> MpcResult:
        """Status, held path, projection, prediction and result of a solve (``dx0`` is only read
        here: it may be a view of the step buffer)."""
        qp = self._qp
        backend = self._backend
        solved_by: SolvedBy = backend.name
        if sol.x is not None and np.isfinite(sol.x).all():
            plan = qp.plan_of(sol.x)
            if sol.accurate:
                status = MpcStatus.SOLVED
            else:
                status = MpcStatus.INACCURATE
                self._inaccurate += 1
            self._consecutive = 0
        else:
            status, solved_by = MpcStatus.HELD, "held"
            self._failures += 1
            self._consecutive += 1
            if self._plan is not None:
                plan = np.vstack([self._plan[1:], self._plan[-1:]])
            else:
                plan = np.tile(u_prev, (self._N, 1))  # nothing safe to shift yet: hold u(-1)
        plan = self._project(plan, u_base)
        if status != MpcStatus.HELD or self._plan is not None:
            self._plan = plan  # the last safe plan (a held u(-1) is not one)
        return self._make_result(plan, status, sol, solved_by, dx0, eta, r, u_prev)

    def _make_result(
        self,
        plan: FloatArray,
        status: MpcStatus,
        sol: QpSolution,
        solved_by: SolvedBy,
        dx0: FloatArray,
        eta: FloatArray,
        r: FloatArray,
        u_prev: FloatArray,
    ) -> MpcResult:
        """The step's result. ``plan`` (also kept as the last plan) and ``eta`` are this step's
        own arrays, handed out read-only; dx0 (perhaps the step buffer's view), r and u(-1) are
        the caller's, so copied. The state, the prediction (:class:`PendingPrediction`) and the
        cost are evaluated from them when first read."""
        planned = readonly(plan)
        qp, model = self._qp, self._model
        return MpcResult.of_step(
            PendingPrediction(model.x_op, model.u_op, qp.z_map, qp.z_op_N, dx0.copy(), eta, planned),
            u=planned[0],
            status=status,
            osqp_status=sol.status,
            iterations=sol.iterations,
            solve_time_s=sol.time_s,
            planned_u=planned,
            disturbance=readonly(eta),
            failures=self._failures,
            consecutive_failures=self._consecutive,
            inaccurate=self._inaccurate,
            solved_by=solved_by,
            cost=self._qp.cost,
            reference=readonly(r.copy()),
            u_prev=readonly(u_prev.copy()),
        )

    def project(self, plan: FloatArray, u_prev: FloatArray) -> FloatArray:
        """A plan (Np, m) [m^3/s] projected, move by move, onto the input bounds and the rate
        bounds (every returned plan is; public for tests and callers holding a plan of their own).

        The first move is rate-limited relative to u(-1) (clipped so that the rate window meets
        the input box, as in the QP) when ``first_move_rate_limited``; corrections are at solver
        tolerance except on the held path. A plan that rides a rate bound breaks it by rounding
        errors, so the sequential pass (in Python floats: a few dozen numbers) starts at the first
        move that breaks one, and skips ahead again after a move it leaves unchanged.
        """
        return self._project(plan, self._qp.rate_window_base(u_prev.tolist()))

    def _project(self, plan: FloatArray, u_base: list[float]) -> FloatArray:
        """:meth:`project` with u(-1) already clipped to its window (``QpFormulation.rate_window_base``)."""
        qp = self._qp
        lo, hi = self._move_lo, self._move_hi
        if qp.has_rate_rows and self._config.first_move_rate_limited:
            # the first move's rate window within the box (the same numbers as _clamp_move's):
            # clipping to the box and then to a window inside it is clipping to the window
            lo[0] = [max(a, b + d) for a, b, d in zip(qp.u_min_list, u_base, qp.du_min_list, strict=True)]
            hi[0] = [min(a, b + d) for a, b, d in zip(qp.u_max_list, u_base, qp.du_max_list, strict=True)]
        out = np.minimum(np.maximum(plan, lo), hi)  # np.clip's result, less call overhead
        if qp.has_rate_rows:
            first = self._first_broken(out)
            if first:
                out = self._project_moves(out, first)
        return out

    def _first_broken(self, plan: FloatArray) -> int:
        """Index of the first move of ``plan`` (rows of moves, the first one excluded) that breaks
        a rate bound relative to the row before it; 0 if none does."""
        qp = self._qp
        d = plan[1:] - plan[:-1]
        if qp.symmetric_rates:  # |d| <= du_max is d >= du_min and d <= du_max, exactly
            broken = np.abs(d, out=d) > qp.du_max
        else:
            broken = (d < qp.du_min) | (d > qp.du_max)
        flat = broken.reshape(-1)  # row-major: the first True is in the first broken move
        if not flat.size:
            return 0
        i = int(flat.argmax())
        return i // self._m + 1 if flat[i] else 0

    def _project_moves(self, plan: FloatArray, first: int) -> FloatArray:
        """Clip moves ``first``..Np-1 in turn to the rate window of the move before. A move the
        clip leaves unchanged makes the rest of the plan its own again, so the pass jumps to the
        next move that breaks a bound (the same result as clipping every move)."""
        rows = plan.tolist()
        k, n = first, len(rows)
        while k < n:
            moved = self._clamp_move(rows[k], rows[k - 1])
            if moved == rows[k]:
                ahead = self._first_broken(plan[k:])
                if not ahead:
                    break
                k += ahead
                continue
            rows[k] = moved
            k += 1
        return np.array(rows)

    def _clamp_move(self, move: list[float], prev: list[float]) -> list[float]:
        """``move`` clipped to the rate window of ``prev``, within the input bounds (Python floats;
        the same floating-point operations as ``np.minimum(np.maximum(...))``)."""
        qp = self._qp
        umin, umax = qp.u_min_list, qp.u_max_list
        dmin, dmax = qp.du_min_list, qp.du_max_list
        out = []
        for j, v in enumerate(move):
            lo = max(umin[j], prev[j] + dmin[j])
            hi = min(umax[j], prev[j] + dmax[j])
            out.append(min(max(v, lo), hi))
        return out

    def update_model(
        self, A: ArrayLike, B: ArrayLike, x_op: ArrayLike | None = None, u_op: ArrayLike | None = None
    ) -> None:
        """Re-linearise: replace A and B (same shapes) and optionally the operating point.

        The QP matrices keep their sparsity pattern (every structurally possible entry is stored,
        explicit zeros included), so OSQP takes their values with ``update(Px=, Ax=)`` (a
        refactorisation, no new setup) and daqp is set up again on the dense matrices. The
        filter gain is recomputed (Bd follows B when it was defaulted) and the state estimate is
        carried over, shifted if x_op moves. The new (x_op, u_op) must be an equilibrium of the
        new model.

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
        A_ = matrix(A, "A", self._n, self._n)
        B_ = matrix(B, "B", self._n, self._m)
        new_model = replace(
            self._model,
            A=A_,
            B=B_,
            x_op=self._model.x_op if x_op is None else vector(x_op, self._n, "x_op"),
            u_op=self._model.u_op if u_op is None else vector(u_op, self._m, "u_op"),
        )
        Bd = B_.copy() if self._Bd_follows_B else self._qp.Bd
        self._estimator.set_model(A_, B_, Bd)  # validates before changing anything
        self._estimator.shift_state(self._model.x_op - new_model.x_op)
        qp = self._qp
        old_u_op = self._model.u_op
        self._model = new_model
        qp.set_model(new_model, Bd)
        P, Aqp = qp.qp_matrices()
        # a kept warm start stays the same absolute plan when u_op moves
        x_offset = np.zeros(qp.nv)
        x_offset[qp.u_off : qp.u_off + self._N * self._m] = np.tile(
            (old_u_op - new_model.u_op) / qp.su, self._N
        )
        self._backend.update_matrices(P, Aqp, x_offset)
        self._backend.set_vector_map(qp.vector_map)
        self._set_correct_map()

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
    def solver(self) -> Literal["daqp", "osqp"]:
        """The QP backend in use ("auto" resolved)."""
        return self._qp.solver

    @property
    def backend(self) -> QpBackend:
        """The QP backend object (:mod:`supervisor.mpc.backends`)."""
        return self._backend

    @property
    def formulation(self) -> Literal["condensed", "sparse"]:
        """The QP form in use ("auto" resolved)."""
        return self._qp.formulation

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
        return self._qp.Bd.copy()

    @property
    def failures(self) -> int:
        """Total HELD steps since construction or :meth:`reset`."""
        return self._failures

    @property
    def slack_weights(self) -> tuple[FloatArray, FloatArray]:
        """(rho_q [1/m^2], rho_l [1/m]), each (nz,), of the output slacks in SI units."""
        return self._qp.slack_weights

    @property
    def scales(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(s_x (n,) [m], s_u (m,) [m^3/s], s_z (nz,) [m]) used to scale the QP (copies)."""
        return self._qp.sx.copy(), self._qp.su.copy(), self._qp.sz.copy()

    @property
    def qp_size(self) -> tuple[int, int]:
        """(number of QP variables, number of constraint rows)."""
        return self._qp.nv, self._qp.nc

    @property
    def cost_scale(self) -> float:
        """c: the SI cost equals c times the scaled QP cost (plus constants)."""
        return self._qp.c
