"""Offset-free constrained MPC (supervisor.mpc): QP against an independent solver, bounds, slacks,
preview, failure handling, rate-limit switch, warm start, re-linearisation, closed loop.

The three-tank model is built here from the digest's formulas (section 1.1), independently of
plant_sim; the nonlinear closed loops use plant_sim's tank network (models + RK4 integrator).

The reference solver is cvxpy + CLARABEL (interior point) on the same QP written directly in
UNSCALED SI deviation variables (flows of 1e-5 m^3/s, levels of 0.1 m), with tight tolerances.

Tolerances. With the papers' tuning (Qz = S = I in SI units) the move weight is about 4e-8 of the
tracking weight, so the QP is nearly flat along "move timing" directions (u(k) up, u(k+1) down):
plans that differ in their tail by 1 % of the input range differ in cost by ~1e-9 relative. The
controller's answers are exact where OSQP's polish identifies the active set and accurate to its
last tolerance rung (1e-6 in scaled units) otherwise. So we compare what is determined: the
applied move to 1e-3 of the input range (1.2e-7 m^3/s, 12 % of the tightest rate limit; observed
<= 8e-5), the predicted outputs to 1e-4 m over the first half of the horizon (1e-3 m at its end,
which hangs on the flat tail), the objective to 1e-5 relative (observed <= 1e-5), and the whole
plan only where the problem is well conditioned.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cvxpy as cp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from digest_models import three_tank_continuous, zoh
from supervisor.mpc import SPARSE_FROM_HORIZON, MpcConfig, MpcController, MpcModel, QpSolution
from tanklab.enums import MpcStatus

ROOT = Path(__file__).resolve().parents[2]

# --- the OPC UA MPC paper's three-tank plant (digest 1.1 and 2.5) ------------------------------
AT, AP, MU, G = 0.0154, 5e-5, 0.84, 9.81
H_OP = np.array([0.4037, 0.2289, 0.3163])
Q_OP = np.array([5.5e-5, 3.4e-5])
TS = 2.5
QMAX = 1.2e-4
HMAX = 0.63
RANGE_U = QMAX  # input range used to express tolerances


def kortela_matrices(h: np.ndarray = H_OP, ts: float = TS) -> tuple[np.ndarray, np.ndarray]:
    """ZOH discretisation of the digest's linearisation at levels h (h1 > h3 > h2)."""
    return zoh(*three_tank_continuous(AT, AP, MU, MU, MU, h), ts)


def equilibrium(h1: float, h2: float) -> tuple[np.ndarray, np.ndarray]:
    """Levels and pump flows of the equilibrium holding h1, h2 (equal mu: h3 halfway)."""
    h3 = 0.5 * (h1 + h2)
    q13 = MU * AP * math.sqrt(2 * G * (h1 - h3))
    q20 = MU * AP * math.sqrt(2 * G * h2)
    return np.array([h1, h2, h3]), np.array([q13, q20 - q13])


def kortela_model(h: np.ndarray = H_OP, q: np.ndarray = Q_OP) -> MpcModel:
    A, B = kortela_matrices(h)
    return MpcModel(A=A, B=B, C=np.eye(3), Cz=np.eye(3)[:2], x_op=h, u_op=q, ts_s=TS)


MODEL = kortela_model()


def paper_config(**kw: Any) -> MpcConfig:
    """Digest 2.5 tuning: Np = 40, Qz = S = I, u in [0, 1.2e-4], du in +-1e-6, z in [0, 0.63]."""
    base: dict[str, Any] = {
        "horizon": 40,
        "u_min": 0.0,
        "u_max": QMAX,
        "du_min": -1e-6,
        "du_max": 1e-6,
        "z_min": 0.0,
        "z_max": HMAX,
        "Qz": 1.0,
        "S": 1.0,
    }
    base.update(kw)
    return MpcConfig(**base)


# --- the independent reference: cvxpy + CLARABEL in unscaled SI deviation variables ---------------
class ReferenceQp:
    """The MPC QP of digest 2.5 written directly in SI deviations (no scaling), DPP-parameterised."""

    def __init__(self, model: MpcModel, mpc: MpcController, *, hard_outputs: bool = False) -> None:
        cfg = mpc.config
        N, (n, m), nz = cfg.horizon, model.B.shape, model.Cz.shape[0]
        self.model, self.N = model, N
        vec = lambda v, k: np.broadcast_to(np.asarray(v, dtype=float), (k,)).copy()  # noqa: E731
        u_min, u_max = vec(cfg.u_min, m), vec(cfg.u_max, m)
        du_min, du_max = vec(cfg.du_min, m), vec(cfg.du_max, m)
        z_min, z_max = vec(cfg.z_min, nz), vec(cfg.z_max, nz)
        sq = lambda W, k: np.diag(np.sqrt(vec(W, k)))  # noqa: E731  (diagonal weights only)
        Wq, Ws, Wr = sq(cfg.Qz, nz), sq(cfg.S, m), sq(cfg.R, m)
        rho_q, rho_l = mpc.slack_weights
        self.x0 = cp.Parameter(n)
        self.w = cp.Parameter(n)
        self.r = cp.Parameter((N, nz))
        self.up = cp.Parameter(m)
        self.uss = cp.Parameter(m)
        dx = cp.Variable((N + 1, n))
        self.du = cp.Variable((N, m))
        eps = cp.Variable((N, nz), nonneg=True)
        z_op = model.Cz @ model.x_op
        cons = [dx[0] == self.x0]
        cost: Any = 0
        for k in range(N):
            cons.append(dx[k + 1] == model.A @ dx[k] + model.B @ self.du[k] + self.w)
            z = model.Cz @ dx[k + 1] + z_op
            move = self.du[k] - (self.du[k - 1] if k > 0 else self.up)
            cost += 0.5 * cp.sum_squares(Wq @ (z - self.r[k])) + 0.5 * cp.sum_squares(Ws @ move)
            cost += 0.5 * cp.sum_squares(Wr @ (self.du[k] - self.uss))
            cons += [self.du[k] + model.u_op >= u_min, self.du[k] + model.u_op <= u_max]
            if (k > 0 or cfg.first_move_rate_limited) and np.all(np.isfinite(du_max)):
                cons += [move <= du_max, move >= du_min]
            if hard_outputs:
                cons += [z <= z_max, z >= z_min]
            else:
                cons += [z - eps[k] <= z_max, z + eps[k] >= z_min]
                cost += cp.sum(0.5 * cp.multiply(rho_q, cp.square(eps[k])) + cp.multiply(rho_l, eps[k]))
        self.prob = cp.Problem(cp.Minimize(cost), cons)

    def solve(
        self, x: np.ndarray, r: np.ndarray, u_prev: np.ndarray, eta: np.ndarray, uss: np.ndarray | None = None
    ) -> tuple[np.ndarray, float]:
        m = self.model
        self.x0.value = x - m.x_op
        self.w.value = m.B @ eta
        self.r.value = np.broadcast_to(r, (self.N, m.Cz.shape[0])).copy()
        self.up.value = u_prev - m.u_op
        self.uss.value = np.zeros(m.B.shape[1]) if uss is None else uss - m.u_op
        self.prob.solve(solver="CLARABEL", tol_feas=1e-12, tol_gap_abs=1e-14, tol_gap_rel=1e-12, max_iter=500)
        assert self.prob.status == "optimal", self.prob.status
        du = self.du.value
        assert du is not None
        return np.asarray(du) + m.u_op, float(self.prob.value)


def steady_state_input(model: MpcModel, eta: np.ndarray, r: np.ndarray) -> np.ndarray:
    """u_s of [[I - A, -B], [Cz, 0]] [x_s; u_s] = [B eta; r - Cz x_op] (square, invertible here)."""
    n, m = model.B.shape
    T = np.block([[np.eye(n) - model.A, -model.B], [model.Cz, np.zeros((model.Cz.shape[0], m))]])
    sol = np.linalg.solve(T, np.concatenate([model.B @ eta, r - model.Cz @ model.x_op]))
    return model.u_op + sol[n:]


def random_cases(seed: int, count: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """States, references, previous inputs and disturbances that make bounds active."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        x0 = rng.uniform(0.1, 0.6, 3)
        r = rng.uniform(0.05, 0.6, 2)
        u_prev = rng.uniform(0.0, QMAX, 2)
        eta = rng.uniform(-1e-5, 1e-5, 2)
        out.append((x0, r, u_prev, eta))
    return out


# ------------------------------------------------------------------------------------------------
# agreement with the independent solver
# ------------------------------------------------------------------------------------------------
REF_CONFIGS = [
    pytest.param({"horizon": 20}, id="paper-rate-1e-6"),
    pytest.param({"horizon": 20, "du_min": -1e-5, "du_max": 1e-5, "z_max": 0.45}, id="rate-1e-5-zmax-0.45"),
    pytest.param(
        {
            "horizon": 20,
            "du_min": -5e-5,
            "du_max": 5e-5,
            "z_min": 0.15,
            "z_max": 0.40,
            "first_move_rate_limited": False,
        },
        id="paper-literal-tight-z",
    ),
    pytest.param(
        {"horizon": 15, "du_min": -np.inf, "du_max": np.inf, "Qz": [1.0, 0.5], "S": [2e3, 1e3]}, id="no-rate"
    ),
]


@pytest.mark.parametrize("kw", REF_CONFIGS)
def test_qp_agrees_with_independent_unscaled_solver(kw: dict[str, Any]) -> None:
    """Condensed and sparse OSQP (scaled) vs CLARABEL (unscaled SI) on random active-constraint cases."""
    # a generous iteration budget: this test is about the QP; the budget's semantics are tested below
    ctrls = {
        f: MpcController(MODEL, paper_config(formulation=f, max_iter=100_000, **kw))
        for f in ("condensed", "sparse")
    }
    ref = ReferenceQp(MODEL, ctrls["sparse"])
    for x0, r, u_prev, eta in random_cases(seed=len(str(kw)), count=6):
        U, J = ref.solve(x0, r, u_prev, eta)
        for name, ctrl in ctrls.items():
            ctrl.reset()
            res = ctrl.plan(x0, r, u_prev, eta)
            assert res.status == MpcStatus.SOLVED, (name, res.osqp_status)
            assert np.all(np.abs(res.u - U[0]) <= 1e-3 * RANGE_U), (name, res.u, U[0])
            assert abs(res.objective - J) <= 1e-5 * abs(J) + 1e-12, (name, res.objective, J)
            # predicted outputs of the reference plan, through the model
            dx = x0 - MODEL.x_op
            z_ref_traj = []
            for k in range(ctrl.horizon):
                dx = MODEL.A @ dx + MODEL.B @ (U[k] - MODEL.u_op) + MODEL.B @ eta
                z_ref_traj.append(MODEL.Cz @ (MODEL.x_op + dx))
            z_err = np.abs(res.predicted_z - np.array(z_ref_traj))
            assert np.max(z_err[: ctrl.horizon // 2]) <= 1e-4, name  # the well-determined half
            assert np.max(z_err) <= 1e-3, name  # the end of the horizon hangs on the flat tail
        # condensed == sparse
        a, b = (ctrls[f].plan(x0, r, u_prev, eta) for f in ("condensed", "sparse"))
        assert np.all(np.abs(a.u - b.u) <= 1e-3 * RANGE_U)
        assert abs(a.objective - b.objective) <= 1e-5 * abs(b.objective) + 1e-12


def test_well_conditioned_plan_agrees_entirely() -> None:
    """With real move suppression (S = 1e8 SI) the whole plan is determined and agrees to 1e-6."""
    for f in ("condensed", "sparse"):
        ctrl = MpcController(MODEL, paper_config(horizon=20, formulation=f, S=1e8, du_min=-1e-5, du_max=1e-5))
        ref = ReferenceQp(MODEL, ctrl)
        for x0, r, u_prev, eta in random_cases(seed=3, count=4):
            U, _ = ref.solve(x0, r, u_prev, eta)
            ctrl.reset()
            res = ctrl.plan(x0, r, u_prev, eta)
            assert np.max(np.abs(res.planned_u - U)) <= 1e-6 * RANGE_U, f


def test_scaling_does_not_change_the_optimum() -> None:
    """Other state scales (any s_x > 0) give the same optimum; the SI objective is reported."""
    x0, r, u_prev, eta = random_cases(seed=11, count=1)[0]
    results = []
    for x_scale in (None, [0.1, 0.2, 0.3], 5.0):
        ctrl = MpcController(
            MODEL, paper_config(horizon=20, x_scale=x_scale, S=1e8, du_min=-1e-5, du_max=1e-5)
        )
        results.append(ctrl.plan(x0, r, u_prev, eta))
    for res in results[1:]:
        assert np.max(np.abs(res.planned_u - results[0].planned_u)) <= 1e-6 * RANGE_U
        assert res.objective == pytest.approx(results[0].objective, rel=1e-7)


def test_r_weight_variant_uses_the_offset_free_input_target() -> None:
    """The 2.4 variant: 1/2 ||u - u_ss||^2_R with u_ss from the steady-state target problem."""
    kw = {"horizon": 20, "R": 1e8, "du_min": -1e-5, "du_max": 1e-5}
    ctrl = MpcController(MODEL, paper_config(**kw))
    ref = ReferenceQp(MODEL, ctrl)
    for x0, r, u_prev, eta in random_cases(seed=5, count=3):
        uss = steady_state_input(MODEL, eta, r)
        U, J = ref.solve(x0, r, u_prev, eta, uss)
        ctrl.reset()
        res = ctrl.plan(x0, r, u_prev, eta)
        assert np.all(np.abs(res.u - U[0]) <= 1e-3 * RANGE_U)
        assert res.objective == pytest.approx(J, rel=1e-5)


# ------------------------------------------------------------------------------------------------
# bounds, slacks, preview
# ------------------------------------------------------------------------------------------------
def _assert_input_feasible(res: Any, u_prev: np.ndarray, du: float, first_limited: bool = True) -> None:
    plan = np.asarray(res.planned_u)
    assert np.all(np.isfinite(plan))
    assert np.array_equal(plan[0], res.u)
    assert np.all(plan >= 0.0) and np.all(plan <= QMAX)
    moves = np.diff(plan, axis=0)
    assert np.all(np.abs(moves) <= du + 1e-18)
    if first_limited and np.all((u_prev >= 0.0) & (u_prev <= QMAX)):
        assert np.all(np.abs(res.u - u_prev) <= du + 1e-18)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    x0=st.lists(st.floats(0.02, 0.62), min_size=3, max_size=3),
    r=st.lists(st.floats(0.0, 0.7), min_size=2, max_size=2),
    u_prev=st.lists(st.floats(-2e-5, 1.5e-4), min_size=2, max_size=2),
    du=st.sampled_from([1e-6, 1e-5, 1e-4]),
    formulation=st.sampled_from(["condensed", "sparse"]),
)
def test_input_and_rate_bounds_never_violated(
    x0: list[float], r: list[float], u_prev: list[float], du: float, formulation: str
) -> None:
    ctrl = MpcController(MODEL, paper_config(horizon=10, du_min=-du, du_max=du, formulation=formulation))
    up = np.array(u_prev)
    res = ctrl.plan(np.array(x0), np.array(r), up)
    _assert_input_feasible(res, up, du)
    if np.any((up < 0.0) | (up > QMAX)):
        # u(-1) outside the input box: the physical bounds win, the move goes toward the box
        base = np.clip(up, 0.0 - du, QMAX + du)
        assert np.all(np.abs(res.u - base) <= du + 1e-18)
    assert np.all(np.isfinite(res.predicted_z)) and math.isfinite(res.objective)


def test_output_slack_keeps_an_infeasible_output_bound_solvable() -> None:
    """T1 starts 5 cm above z_max: no input can comply at k = 1, the QP still solves."""
    x0 = np.array([0.50, 0.23, 0.31])
    for f in ("condensed", "sparse"):
        ctrl = MpcController(
            MODEL, paper_config(horizon=20, z_max=0.45, du_min=-1e-5, du_max=1e-5, formulation=f)
        )
        res = ctrl.plan(x0, [0.40, 0.23], Q_OP)
        assert res.status == MpcStatus.SOLVED
        assert res.max_output_violation > 0.01
        assert res.predicted_z[-1, 0] < res.predicted_z[0, 0]  # heading back inside
        _assert_input_feasible(res, Q_OP, 1e-5)
        U, J = ReferenceQp(MODEL, ctrl).solve(x0, np.array([0.40, 0.23]), Q_OP, np.zeros(2))
        assert np.all(np.abs(res.u - U[0]) <= 1e-3 * RANGE_U)
        assert res.objective == pytest.approx(J, rel=1e-5)


def test_slack_penalty_is_exact_when_the_hard_problem_is_feasible() -> None:
    """Reference above z_max: the bound is active, the soft QP returns the hard QP's optimum.

    Active output bounds on this nearly flat QP converge slowly in ADMM (also with hard bounds:
    ~8e4 iterations cold), hence the budget here; see the next test for the default budget.
    """
    ctrl = MpcController(
        MODEL, paper_config(horizon=20, z_max=0.42, du_min=-1e-5, du_max=1e-5, max_iter=100_000)
    )
    hard = ReferenceQp(MODEL, ctrl, hard_outputs=True)
    for x0, u_prev in ((H_OP, Q_OP), (np.array([0.41, 0.25, 0.33]), np.array([8e-5, 3e-5]))):
        U, _ = hard.solve(x0, np.array([0.47, 0.23]), u_prev, np.zeros(2))
        ctrl.reset()
        res = ctrl.plan(x0, [0.47, 0.23], u_prev)
        assert res.max_output_violation <= 1e-6
        assert np.max(res.predicted_z[:, 0]) == pytest.approx(0.42, abs=1e-6)
        assert np.all(np.abs(res.u - U[0]) <= 1e-3 * RANGE_U)


def test_exhausted_iteration_budget_returns_the_looser_solution_as_inaccurate() -> None:
    """Default budget on the slow case above: the first rung's (1e-4) solution is used, flagged
    (OSQP's ladder: the backend with a tolerance and a budget that runs out)."""
    ctrl = MpcController(
        MODEL, paper_config(horizon=20, z_max=0.42, du_min=-1e-5, du_max=1e-5, solver="osqp")
    )
    res = ctrl.plan(H_OP, [0.47, 0.23], Q_OP)
    assert res.status == MpcStatus.INACCURATE and res.inaccurate == 1 and res.failures == 0
    assert res.iterations == ctrl.config.max_iter
    assert res.max_output_violation <= 1e-4
    _assert_input_feasible(res, Q_OP, 1e-5)
    U, _ = ReferenceQp(MODEL, ctrl, hard_outputs=True).solve(H_OP, np.array([0.47, 0.23]), Q_OP, np.zeros(2))
    assert np.all(np.abs(res.u - U[0]) <= 2e-2 * RANGE_U)


def test_reference_preview_and_constant_reference() -> None:
    ctrl_c = MpcController(MODEL, paper_config(horizon=20, du_min=-1e-5, du_max=1e-5))
    ctrl_p = MpcController(MODEL, paper_config(horizon=20, du_min=-1e-5, du_max=1e-5))
    r = np.array([0.45, 0.22])
    a = ctrl_c.plan(H_OP, r, Q_OP)
    b = ctrl_p.plan(H_OP, np.tile(r, (20, 1)), Q_OP)
    assert np.array_equal(a.planned_u, b.planned_u)  # the same QP data
    # a setpoint step known 10 samples ahead: the reference solver with the same preview agrees
    preview = np.tile(H_OP[:2], (20, 1))
    preview[10:, 0] = 0.45
    ctrl_p.reset()
    res = ctrl_p.plan(H_OP, preview, Q_OP)
    U, J = ReferenceQp(MODEL, ctrl_p).solve(H_OP, preview, Q_OP, np.zeros(2))
    assert np.all(np.abs(res.u - U[0]) <= 1e-3 * RANGE_U)
    assert res.objective == pytest.approx(J, rel=1e-5)
    assert abs(res.u[0] - a.u[0]) > 1e-6  # not the move for a step now
    with pytest.raises(ValueError, match="r must have shape"):
        ctrl_p.plan(H_OP, np.zeros((19, 2)), Q_OP)


def test_paper_literal_switch_leaves_the_first_move_free() -> None:
    """Digest 2.5: the paper's rate matrix has Np - 1 rows, so u(0) - u(-1) is not limited."""
    limited = MpcController(MODEL, paper_config(horizon=20))
    literal = MpcController(MODEL, paper_config(horizon=20, first_move_rate_limited=False))
    assert limited.qp_size[1] - literal.qp_size[1] == 2  # one block of m = 2 rate rows less
    r = [0.50, 0.2289]
    a = limited.plan(H_OP, r, Q_OP)
    b = literal.plan(H_OP, r, Q_OP)
    assert abs(a.u[0] - Q_OP[0]) <= 1e-6 + 1e-18
    assert abs(b.u[0] - Q_OP[0]) > 2e-6  # the applied move is not rate-limited
    assert np.all(np.abs(np.diff(b.planned_u, axis=0)) <= 1e-6 + 1e-18)  # the later ones are
    _assert_input_feasible(b, Q_OP, 1e-6, first_limited=False)


# ------------------------------------------------------------------------------------------------
# failure handling
# ------------------------------------------------------------------------------------------------
def test_solver_failure_before_any_plan_holds_the_previous_input() -> None:
    ctrl = MpcController(MODEL, paper_config(horizon=10, max_iter=1))
    u_prev = np.array([6e-5, 3e-5])
    res = ctrl.plan(H_OP, [0.5, 0.3], u_prev)
    assert res.status == MpcStatus.HELD
    assert res.osqp_status == "maximum iterations reached"
    assert np.array_equal(res.u, u_prev)
    assert res.failures == 1 and res.consecutive_failures == 1
    assert np.all(np.isfinite(res.planned_u)) and np.all(np.isfinite(res.predicted_z))
    # held input outside the box: clipped, as fast as the rate limit allows
    res = ctrl.plan(H_OP, [0.5, 0.3], np.array([1.25e-4, -5e-7]))
    assert res.status == MpcStatus.HELD
    assert np.allclose(res.u, [1.2e-4, 0.0], rtol=0, atol=1e-18)
    assert res.failures == 2 and res.consecutive_failures == 2


def _fake_solve(status: str, x: np.ndarray | None) -> Any:
    """A backend's ``solve`` and ``solve_data`` (any arguments: the QP's vectors, or the step's
    data) that report ``status`` with solution ``x`` (the failures to test)."""

    def solve(*vectors: np.ndarray) -> QpSolution:
        return QpSolution(x=x, accurate=x is not None, status=status, iterations=7, time_s=3e-6)

    return solve


def _patch_solves(monkeypatch: pytest.MonkeyPatch, backend: Any, solve: Any, solve_data: Any) -> None:
    """Both entries of a backend the controller calls (a constant reference goes through
    ``solve_data``, a preview through ``solve``)."""
    monkeypatch.setattr(backend, "solve", solve)
    monkeypatch.setattr(backend, "solve_data", solve_data)


@pytest.mark.parametrize("formulation", ["condensed", "sparse"])
def test_solver_failure_uses_the_shifted_last_plan_and_counts(
    formulation: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    ctrl = MpcController(MODEL, paper_config(horizon=20, formulation=formulation))
    r = [0.45, 0.2289]
    good = ctrl.plan(H_OP, r, Q_OP)
    assert good.status == MpcStatus.SOLVED
    nv, _ = ctrl.qp_size
    real_solve, real_solve_data = ctrl.backend.solve, ctrl.backend.solve_data
    # 1) the solver gives up (max iterations) -> shifted plan
    gives_up = _fake_solve("maximum iterations reached", None)
    _patch_solves(monkeypatch, ctrl.backend, gives_up, gives_up)
    held = ctrl.plan(H_OP, r, good.u)
    assert held.status == MpcStatus.HELD
    assert np.array_equal(held.u, good.planned_u[1])
    assert np.array_equal(held.planned_u[:-1], good.planned_u[1:])
    assert held.failures == 1 and held.consecutive_failures == 1
    # 2) "solved" but with NaN in the solution -> also held, shifted once more
    nan = _fake_solve("solved", np.full(nv, np.nan))
    _patch_solves(monkeypatch, ctrl.backend, nan, nan)
    held2 = ctrl.plan(H_OP, r, held.u)
    assert held2.status == MpcStatus.HELD
    assert np.array_equal(held2.u, good.planned_u[2])
    assert held2.failures == 2 and held2.consecutive_failures == 2
    for res in (held, held2):
        assert np.all(np.isfinite(res.planned_u)) and np.all(np.isfinite(res.predicted_z))
        assert math.isfinite(res.objective)
    # 3) a held plan is re-projected on the rate window of the input actually applied
    held3 = ctrl.plan(H_OP, r, held2.u + 5e-6)
    assert np.all(np.abs(held3.u - (held2.u + 5e-6)) <= 1e-6 + 1e-18)
    # 4) recovery
    _patch_solves(monkeypatch, ctrl.backend, real_solve, real_solve_data)
    ok = ctrl.plan(H_OP, r, held3.u)
    assert ok.status == MpcStatus.SOLVED
    assert ok.failures == 3 and ok.consecutive_failures == 0


def test_non_finite_inputs_are_rejected_before_any_state_changes() -> None:
    ctrl = MpcController(MODEL, paper_config(horizon=10))
    ctrl.step(H_OP, H_OP[:2], Q_OP)
    before = ctrl.estimator.estimate
    assert before is not None
    for bad in (
        {"y": [np.nan, 0.2, 0.3]},
        {"r": [np.inf, 0.2]},
        {"u_prev": [np.nan, 1e-5]},
    ):
        args: dict[str, Any] = {"y": H_OP, "r": H_OP[:2], "u_prev": Q_OP, **bad}
        with pytest.raises(ValueError, match=next(iter(bad))):
            ctrl.step(**args)
    after = ctrl.estimator.estimate
    assert after is not None
    assert np.array_equal(after.x, before.x) and np.array_equal(after.disturbance, before.disturbance)


# ------------------------------------------------------------------------------------------------
# construction, observability, warm start, re-linearisation
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kw", "exc", "match"),
    [
        ({"horizon": 0}, ValueError, "horizon"),
        ({"horizon": 2.5}, TypeError, "horizon"),
        ({"u_min": QMAX, "u_max": 0.0}, ValueError, "u_min"),
        ({"u_max": np.inf}, ValueError, "u_max"),
        ({"du_min": 1e-7}, ValueError, "du_min"),
        ({"z_min": 0.7}, ValueError, "z_min"),
        ({"Qz": [[1.0, 2.0], [2.0, 1.0]]}, ValueError, "Qz must be positive semidefinite"),
        ({"S": [1.0, 2.0, 3.0]}, ValueError, "S"),
        ({"Qz": 0.0, "S": 0.0}, ValueError, "all zero"),
        ({"formulation": "dense"}, ValueError, "formulation"),
        ({"tolerances": (1e-6, 1e-4)}, ValueError, "decreasing"),
        ({"estimator_outputs": [0, 3]}, ValueError, "estimator_outputs"),
        ({"slack_linear": -1.0}, ValueError, "slack_linear"),
        ({"u_min": "zero"}, TypeError, "u_min"),
    ],
)
def test_invalid_configuration_is_rejected(kw: dict[str, Any], exc: type[Exception], match: str) -> None:
    with pytest.raises(exc, match=match):
        MpcController(MODEL, paper_config(**kw))


def test_invalid_model_is_rejected() -> None:
    A, B = kortela_matrices()
    with pytest.raises(ValueError, match="B must have shape"):
        MpcModel(A=A, B=B[:2], C=np.eye(3), Cz=np.eye(3)[:2], x_op=H_OP, u_op=Q_OP, ts_s=TS)
    with pytest.raises(ValueError, match="ts_s"):
        MpcModel(A=A, B=B, C=np.eye(3), Cz=np.eye(3)[:2], x_op=H_OP, u_op=Q_OP, ts_s=0.0)
    with pytest.raises(ValueError, match="x_op"):
        MpcModel(A=A, B=B, C=np.eye(3), Cz=np.eye(3)[:2], x_op=np.array([np.nan, 0, 0]), u_op=Q_OP, ts_s=TS)


def test_observability_check_rejects_an_unobservable_disturbance_model() -> None:
    B = MODEL.B
    e3 = np.array([[0.0], [0.0], [1.0]])
    # three disturbances but only two outputs fed to the filter
    with pytest.raises(ValueError, match=r"rank \[\[I - A, -Bd\], \[C, 0\]\]"):
        MpcController(MODEL, paper_config(disturbance_matrix=np.hstack([B, e3]), estimator_outputs=[0, 1]))
    # two disturbances acting identically on the outputs
    with pytest.raises(ValueError, match="not observable"):
        MpcController(MODEL, paper_config(disturbance_matrix=np.hstack([B[:, :1], 2 * B[:, :1]])))
    # the digest's remedies are accepted
    MpcController(MODEL, paper_config(disturbance_matrix=np.hstack([B, e3])))
    MpcController(MODEL, paper_config(estimator_outputs=[0, 1]))


def test_auto_formulation_follows_the_measured_threshold() -> None:
    assert MpcController(MODEL, paper_config(horizon=SPARSE_FROM_HORIZON - 1)).formulation == "condensed"
    assert MpcController(MODEL, paper_config(horizon=SPARSE_FROM_HORIZON)).formulation == "sparse"
    assert MpcController(MODEL, paper_config(horizon=80, formulation="condensed")).formulation == "condensed"


@pytest.mark.parametrize("formulation", ["condensed", "sparse"])
def test_warm_start_reduces_iterations(formulation: str) -> None:
    """Receding horizon on the exact model: the shifted solution warm-starts the next sample.

    ``polish=False`` switches the exact active-set solves off, so every sample runs OSQP.
    """

    def config() -> MpcConfig:
        return paper_config(formulation=formulation, du_min=-1e-5, du_max=1e-5, polish=False)

    ctrl = MpcController(MODEL, config())
    r = [0.45, 0.22]
    first = ctrl.plan(H_OP, r, Q_OP)
    x1 = MODEL.x_op + MODEL.A @ (H_OP - MODEL.x_op) + MODEL.B @ (first.u - MODEL.u_op)
    warm = ctrl.plan(x1, r, first.u)
    cold = MpcController(MODEL, config()).plan(x1, r, first.u)
    assert warm.status == cold.status == MpcStatus.SOLVED
    assert 0 < warm.iterations < cold.iterations
    assert np.all(np.abs(warm.u - cold.u) <= 1e-3 * RANGE_U)
    # at a steady state (away from the operating point) the plan is to stay; the second sample
    # starts from the first one's solution (daqp: its working set; OSQP: the shifted iterate)
    # and needs far fewer iterations (daqp: one, the solve on the kept working set; its cold
    # start at a steady state inside the bounds is one iteration too, since the output slacks
    # are daqp's soft rows and no slack bound has to be activated)
    u_s = np.array([6.5e-5, 2.8e-5])
    x_s = MODEL.x_op + np.linalg.solve(np.eye(3) - MODEL.A, MODEL.B @ (u_s - MODEL.u_op))
    r_s = MODEL.Cz @ x_s
    fresh = MpcController(MODEL, replace(config(), polish=True))
    cold_s = fresh.plan(x_s, r_s, u_s)
    again = fresh.plan(x_s, r_s, u_s)
    assert np.allclose(cold_s.planned_u, u_s, rtol=0, atol=1e-6 * RANGE_U)
    assert cold_s.iterations > 0 and again.iterations <= max(1, cold_s.iterations // 10)
    # daqp's answer is exact on its active set; OSQP's polished one to about its tolerance
    exact = 1e-9 if fresh.solver == "daqp" else 1e-6
    assert np.allclose(again.planned_u, u_s, rtol=0, atol=exact * RANGE_U)


@pytest.mark.parametrize("formulation", ["condensed", "sparse"])
def test_update_model_relinearises_in_place(formulation: str) -> None:
    """Replacing A, B and the operating point equals building a new controller there."""
    h2, q2 = equilibrium(0.45, 0.25)
    A2, B2 = kortela_matrices(h2)
    cfg = paper_config(horizon=20, formulation=formulation, du_min=-1e-5, du_max=1e-5)
    ctrl = MpcController(MODEL, cfg)
    ctrl.step(H_OP, H_OP[:2], Q_OP)
    ctrl.update_model(A2, B2, x_op=h2, u_op=q2)
    fresh = MpcController(kortela_model(h2, q2), cfg)
    assert np.allclose(ctrl.estimator.gain, fresh.estimator.gain)
    assert np.array_equal(ctrl.model.A, A2) and np.array_equal(ctrl.model.x_op, h2)
    ctrl.reset()
    x0, r = np.array([0.44, 0.26, 0.35]), np.array([0.47, 0.24])
    a = ctrl.plan(x0, r, q2)
    b = fresh.plan(x0, r, q2)
    assert np.all(np.abs(a.u - b.u) <= 1e-3 * RANGE_U)
    assert a.objective == pytest.approx(b.objective, rel=1e-5)
    with pytest.raises(ValueError, match="A must have shape"):
        ctrl.update_model(A2[:2], B2)


def test_identical_runs_give_identical_traces() -> None:
    """Lock-step reproducibility: no wall-clock dependence (OSQP's adaptive rho by iteration count)."""

    def run() -> np.ndarray:
        ctrl = MpcController(MODEL, paper_config(horizon=20))
        x, u, us = H_OP.copy(), Q_OP.copy(), []
        for k in range(30):
            res = ctrl.step(x, [0.43 if k > 2 else H_OP[0], H_OP[1]], u)
            u = np.array(res.u)
            us.append(u)
            x = MODEL.x_op + MODEL.A @ (x - MODEL.x_op) + MODEL.B @ (u - MODEL.u_op)
        return np.array(us)

    assert np.array_equal(run(), run())


def test_result_arrays_are_read_only_and_absolute() -> None:
    ctrl = MpcController(MODEL, paper_config(horizon=10))
    res = ctrl.step(H_OP, H_OP[:2], Q_OP)
    assert res.planned_u.shape == (10, 2) and res.predicted_z.shape == (10, 2)
    assert res.state.shape == (3,) and res.disturbance.shape == (2,)
    assert np.allclose(res.state, H_OP, atol=1e-12)  # absolute levels, not deviations
    assert np.allclose(res.u, Q_OP, atol=1e-12)  # absolute flows
    with pytest.raises(ValueError):
        res.u[0] = 0.0


# ------------------------------------------------------------------------------------------------
# closed loop on the nonlinear plant (plant_sim's tank network, RK4)
# ------------------------------------------------------------------------------------------------
def _plant() -> tuple[Any, Any, Any]:
    from plant_sim.integrate import step_rk4
    from plant_sim.models import PlantInputs, TankNetwork, default_inputs
    from tanklab.config import load_site

    site = load_site(ROOT / "configs/three_tank_kortela.yaml")
    net = TankNetwork.from_config(site.plant)
    u0 = default_inputs(net, site.plant)

    def advance(x: np.ndarray, q: np.ndarray, leak: np.ndarray) -> np.ndarray:
        u = PlantInputs(
            pump_commands=net.pump_commands_for(q),
            valve_openings=u0.valve_openings,
            leak_openings=leak,
            disturbances_m3_s=u0.disturbances_m3_s,
        )
        # 5 RK4 sub-steps of 0.5 s: the fastest mode is 15 s, local error ~ (0.5 / 15)^5; the
        # equilibria (what offset-freeness is about) are exact for any step size
        return step_rk4(net, x, u, TS, max_substep_s=0.5)

    return net, advance, u0


def closed_loop(controller: Any, steps: int, r_of_k: Any, leak_of_k: Any = None) -> dict[str, np.ndarray]:
    """Run controller.step(y, r, u_prev) against the nonlinear plant from the equilibrium."""
    net, advance, _ = _plant()
    x = net.initial_state(H_OP, Q_OP)
    u = Q_OP.copy()
    hs, us, rs, statuses = [], [], [], []
    for k in range(steps):
        h = net.levels(x)
        r = r_of_k(k)
        res = controller.step(h, r, u)
        u = np.array(res.u)
        hs.append(h)
        us.append(u)
        rs.append(r)
        statuses.append(int(getattr(res, "status", MpcStatus.SOLVED)))
        leak = np.zeros(3) if leak_of_k is None else leak_of_k(k)
        x = advance(x, u, leak)
    return {"h": np.array(hs), "u": np.array(us), "r": np.array(rs), "status": np.array(statuses)}


class ReferenceController:
    """The same estimator and QP, solved by CLARABEL in SI units: the accuracy guard's reference."""

    def __init__(self, mpc: MpcController) -> None:
        from supervisor.estimator import AugmentedKalmanFilter

        m = mpc.model
        self.model, self.N = m, mpc.horizon
        self.qp = ReferenceQp(m, mpc)
        self.kf = AugmentedKalmanFilter(m.A, m.B, m.C, m.B)

    def step(self, y: np.ndarray, r: np.ndarray, u_prev: np.ndarray) -> SimpleNamespace:
        est = self.kf.update(y - self.model.C @ self.model.x_op, u_prev - self.model.u_op)
        U, _ = self.qp.solve(self.model.x_op + est.x, r, u_prev, np.array(est.disturbance))
        return SimpleNamespace(u=U[0])


@functools.cache
def _reference_loop(steps: int) -> dict[str, np.ndarray]:
    return closed_loop(ReferenceController(MpcController(MODEL, paper_config())), steps, STEP_R)


STEP_R = lambda k: H_OP[:2] + (np.array([0.05, 0.0]) if k >= 4 else 0.0)  # noqa: E731


@pytest.mark.parametrize("formulation", ["condensed", "sparse"])
def test_closed_loop_iae_within_one_percent_of_reference_solver(formulation: str) -> None:
    """The project's accuracy guard, on the paper's tuning (the hardest case: rate 1e-6, S = I).

    Benchmark step: h1 setpoint +5 cm at 10 s from the equilibrium, 500 s, nonlinear plant.
    """
    steps = 200
    ref = _reference_loop(steps)
    log = closed_loop(MpcController(MODEL, paper_config(formulation=formulation)), steps, STEP_R)
    iae_ref = np.sum(np.abs(ref["h"][:, :2] - ref["r"]), axis=0) * TS
    iae = np.sum(np.abs(log["h"][:, :2] - log["r"]), axis=0) * TS
    assert abs(iae.sum() - iae_ref.sum()) <= 0.01 * iae_ref.sum(), (iae, iae_ref)
    assert abs(iae[0] - iae_ref[0]) <= 0.01 * iae_ref[0]
    assert np.all(log["status"] == MpcStatus.SOLVED)


def test_nonlinear_closed_loop_rejects_a_t1_leak_without_offset() -> None:
    """Constant leak on T1 (mu_L = 0.25, ~3.5e-5 m^3/s) from t = 25 s: zero offset on h1, h2."""
    ctrl = MpcController(MODEL, paper_config(du_min=-1e-5, du_max=1e-5, estimator_outputs=[0, 1]))
    steps = 600
    leak = lambda k: np.array([1.0, 0.0, 0.0]) if k >= 10 else np.zeros(3)  # noqa: E731
    log = closed_loop(ctrl, steps, lambda k: H_OP[:2], leak)
    u, h = log["u"], log["h"]
    assert np.all(u >= 0.0) and np.all(u <= QMAX)
    assert np.all(np.abs(np.diff(np.vstack([Q_OP, u]), axis=0)) <= 1e-5 + 1e-18)
    assert np.all(h >= 0.0) and np.all(h <= HMAX)
    assert np.max(np.abs(h[-20:, :2] - H_OP[:2])) < 1e-6
    assert u[-1, 0] > Q_OP[0] + 2.5e-5  # pump 1 supplies the leak
    assert np.all(log["status"] != MpcStatus.HELD)
