"""The MPC's QP backends (supervisor.mpc.backends): daqp and OSQP behind one interface.

Oracles: cvxpy + CLARABEL at 1e-12 on random strictly convex QPs (each backend's answer must be
its optimum); the other backend on the controller's own QPs (daqp's hot-started answer must equal
OSQP's at a tight polished tolerance, step after step of a rate-limited transient); a freshly
built controller after a model update.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, reject, settings
from hypothesis import strategies as st

from supervisor.mpc import DaqpBackend, MpcConfig, MpcController, MpcModel, OsqpBackend, QpBackend, SoftRows
from tanklab.enums import MpcStatus

U_RANGE = 1.2e-4


def _random_qp(seed: int, n: int = 8, rows: int = 14) -> tuple[sp.csc_matrix, sp.csc_matrix, np.ndarray]:
    """A strictly convex QP: P = G'G + I; A = random sparse rows, then unit rows on some of the
    variables (one of them twice), so a backend meets bounds, missing bounds and general rows."""
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(n, n))
    P = G.T @ G + np.eye(n)
    extra = rng.normal(size=(rows - n, n)) * (rng.random((rows - n, n)) < 0.4)
    bounded = np.flatnonzero(rng.random(n) < 0.7)
    unit = np.eye(n)[np.concatenate([bounded, bounded[:1]])]
    A = np.vstack([extra, unit])
    return sp.csc_matrix(np.triu(P)), sp.csc_matrix(A), rng.normal(size=n) * 3.0


def _clarabel(
    P: sp.csc_matrix, A: sp.csc_matrix, q: np.ndarray, lo: np.ndarray, up: np.ndarray
) -> np.ndarray:
    v = cp.Variable(P.shape[0])
    Pd = P.toarray()
    Pd = Pd + np.triu(Pd, 1).T
    prob = cp.Problem(
        cp.Minimize(0.5 * cp.quad_form(v, cp.psd_wrap(Pd)) + q @ v),
        [A.toarray() @ v >= lo, A.toarray() @ v <= up],
    )
    try:
        prob.solve(solver="CLARABEL", tol_feas=1e-12, tol_gap_abs=1e-12, tol_gap_rel=1e-12)
    except cp.error.SolverError:
        reject()  # no oracle for this example (CLARABEL gives up at 1e-12 on a few random QPs)
    assert prob.status == "optimal"
    return np.asarray(v.value)


def _backends(nv: int, nc: int) -> list[QpBackend]:
    shift_x, shift_y = np.arange(nv), np.arange(nc)  # no shift: the QPs are unrelated
    return [DaqpBackend(1000), OsqpBackend((1e-8,), True, 200_000, 5, shift_x, shift_y)]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000))
def test_each_backend_finds_the_optimum_of_random_qps(seed: int) -> None:
    P, A, q = _random_qp(seed)
    nc, nv = A.shape
    rng = np.random.default_rng(seed + 2)
    lo = -rng.random(nc) - 0.1
    up = rng.random(nc) + 0.1
    lo[rng.random(nc) < 0.2] = -np.inf  # one-sided rows too
    ref = _clarabel(P, A, q, lo, up)
    for backend in _backends(nv, nc):
        backend.setup(P, A, q, lo, up)
        sol = backend.solve(q, lo, up)
        assert sol.x is not None and sol.accurate, (backend.name, sol.status)
        assert np.max(np.abs(sol.x - ref)) <= 1e-6, backend.name
        z = A @ sol.x
        assert np.all(z >= lo - 1e-8) and np.all(z <= up + 1e-8)


def _slack_qp(
    seed: int, n: int = 6, soft: int = 4, hard: int = 3, wide: bool = False
) -> tuple[sp.csc_matrix, sp.csc_matrix, np.ndarray, np.ndarray, np.ndarray, SoftRows]:
    """A QP in the formulation's slack layout: v = [x (n); eps (soft)], P = blkdiag(G'G + I,
    diag(rho_q)), q = [random; rho_l]; rows: a box on x, ``hard`` random rows, then the pairs
    g'x + eps >= l and g'x - eps <= u, then eps >= 0. The bounds of the soft rows are drawn so
    that some of them cannot hold at the optimum (daqp's "soft optimal"), or ``wide`` so that
    all of them hold (|g'x| <= |g| sqrt(n) on the box)."""
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(n, n))
    rho_q = rng.uniform(0.5, 3.0, soft)
    rho_l = rng.uniform(0.0, 2.0, soft)
    P = np.zeros((n + soft, n + soft))
    P[:n, :n] = G.T @ G + np.eye(n)
    P[n:, n:] = np.diag(rho_q)
    q = np.concatenate([rng.normal(size=n) * 3.0, rho_l])
    Gs = rng.normal(size=(soft, n))
    H = rng.normal(size=(hard, n))
    E = np.eye(soft)
    A = np.vstack(
        [
            np.hstack([np.eye(n), np.zeros((n, soft))]),
            np.hstack([H, np.zeros((hard, soft))]),
            np.hstack([Gs, E]),
            np.hstack([Gs, -E]),
            np.hstack([np.zeros((soft, n)), E]),
        ]
    )
    centre = rng.normal(size=soft) * 2.0
    width = rng.uniform(0.05, 1.0, soft)
    if wide:
        width += np.abs(centre) + np.linalg.norm(Gs, axis=1) * np.sqrt(n)
    lo = np.concatenate(
        [np.full(n, -1.0), np.full(hard, -1.5), centre - width, np.full(soft, -np.inf), np.zeros(soft)]
    )
    up = np.concatenate(
        [np.full(n, 1.0), np.full(hard, 1.5), np.full(soft, np.inf), centre + width, np.full(soft, np.inf)]
    )
    k = np.arange(soft)
    layout = SoftRows(
        columns=n + k,
        bound_rows=2 * soft + n + hard + k,
        lower_rows=n + hard + k,
        upper_rows=n + hard + soft + k,
        quadratic=rho_q,
        linear=rho_l,
    )
    return sp.csc_matrix(np.triu(P)), sp.csc_matrix(A), q, lo, up, layout


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000))
def test_daqp_with_soft_rows_finds_the_optimum_of_the_slack_qp(seed: int) -> None:
    """daqp given the slacks as soft rows: the whole v (slacks included) is the slack QP's optimum."""
    P, A, q, lo, up, layout = _slack_qp(seed)
    ref = _clarabel(P, A, q, lo, up)
    backend = DaqpBackend(1000, layout)
    backend.setup(P, A, q, lo, up)
    assert backend.size == (6, 3 + 4)  # the slacks and their rows are folded away
    for _ in range(2):  # cold, then hot-started on the same QP
        sol = backend.solve(q, lo, up)
        assert sol.x is not None and sol.accurate, sol.status
        assert np.max(np.abs(sol.x - ref)) <= 1e-6
    violated = ref[6:] > 1e-6
    assert sol.status == ("soft optimal" if violated.any() else "optimal")


def test_daqp_soft_rows_violated_and_not() -> None:
    """Both daqp exits of the soft form on one QP family: a soft row that cannot hold (the slack
    at max(0, l - g'x, g'x - u) of the optimum) and, with wide soft bounds, none (slacks 0)."""
    seen = set()
    for seed in range(20):
        P, A, q, lo, up, layout = _slack_qp(seed, wide=seed % 2 == 1)
        backend = DaqpBackend(1000, layout)
        backend.setup(P, A, q, lo, up)
        sol = backend.solve(q, lo, up)
        assert sol.x is not None
        assert np.max(np.abs(sol.x - _clarabel(P, A, q, lo, up))) <= 1e-6
        seen.add(sol.status)
        backend.reset()  # forgets the working set, keeps the rows soft and their weights
        again = backend.solve(q, lo, up)
        assert again.status == sol.status and again.x is not None
        assert np.max(np.abs(again.x - sol.x)) <= 1e-9
        if seed % 2:
            assert sol.status == "optimal" and np.array_equal(sol.x[6:], np.zeros(4))
    assert seen == {"optimal", "soft optimal"}


def test_daqp_refuses_a_soft_layout_that_is_not_the_qps() -> None:
    P, A, q, lo, up, layout = _slack_qp(3)
    bad = SoftRows(
        columns=layout.columns,
        bound_rows=layout.bound_rows,
        lower_rows=layout.upper_rows,  # swapped: +1 and -1 rows exchanged
        upper_rows=layout.lower_rows,
        quadratic=layout.quadratic,
        linear=layout.linear,
    )
    with pytest.raises(ValueError, match="soft rows are not pairs"):
        DaqpBackend(1000, bad).setup(P, A, q, lo, up)
    wrong_weight = SoftRows(
        columns=layout.columns,
        bound_rows=layout.bound_rows,
        lower_rows=layout.lower_rows,
        upper_rows=layout.upper_rows,
        quadratic=layout.quadratic * 2.0,
        linear=layout.linear,
    )
    with pytest.raises(ValueError, match="slack block"):
        DaqpBackend(1000, wrong_weight).setup(P, A, q, lo, up)
    backend = DaqpBackend(1000, layout)
    backend.setup(P, A, q, lo, up)
    q2 = q.copy()
    q2[-1] += 1.0  # a slack's linear weight is a constant of the QP
    with pytest.raises(ValueError, match="constant"):
        backend.solve(q2, lo, up)


def test_daqp_hot_start_reuses_the_working_set_and_a_new_qp_still_solves() -> None:
    P, A, q = _random_qp(7)
    nc = A.shape[0]
    lo, up = np.full(nc, -0.3), np.full(nc, 0.3)
    backend = DaqpBackend(1000)
    backend.setup(P, A, q, lo, up)
    cold = backend.solve(q, lo, up)
    hot = backend.solve(q, lo, up)
    assert cold.x is not None and hot.x is not None
    assert cold.iterations > 1 and hot.iterations <= 1
    assert np.array_equal(cold.x, hot.x)
    # a different right-hand side from that working set: the optimum of the new QP
    q2 = -q
    moved = backend.solve(q2, lo, up)
    assert moved.x is not None
    assert np.max(np.abs(moved.x - _clarabel(P, A, q2, lo, up))) <= 1e-6
    # reset forgets the start: the same QP again costs what a cold solve costs
    backend.reset()
    assert backend.solve(q2, lo, up).iterations > 1


def test_an_infeasible_qp_gives_no_solution_and_the_next_one_solves() -> None:
    P, A, q = _random_qp(11)
    nc, nv = A.shape
    lo, up = np.full(nc, -0.3), np.full(nc, 0.3)
    for backend in _backends(nv, nc):
        backend.setup(P, A, q, lo, up)
        # the last unit row repeats an earlier one (_random_qp): contradictory bounds on it
        twin = int(np.flatnonzero((A.toarray() == A.toarray()[-1]).all(axis=1))[0])
        bad_lo, bad_up = lo.copy(), up.copy()
        bad_lo[twin], bad_up[twin] = 0.1, 0.2
        bad_lo[-1], bad_up[-1] = 0.25, 0.3
        failed = backend.solve(q, bad_lo, bad_up)
        assert failed.x is None and not failed.accurate, backend.name
        good = backend.solve(q, lo, up)
        assert good.x is not None and good.accurate, backend.name


def _kortela_like(**cfg: object) -> MpcController:
    a = np.array([[0.98, 0.0, 0.01], [0.0, 0.97, 0.015], [0.015, 0.01, 0.975]])
    b = np.array([[160.0, 0.0], [0.0, 160.0], [0.0, 0.0]])
    model = MpcModel(
        A=a,
        B=b,
        C=np.eye(3),
        Cz=np.eye(3)[:2],
        x_op=np.array([0.4, 0.2, 0.3]),
        u_op=np.array([5e-5, 3e-5]),
        ts_s=2.5,
    )
    base: dict[str, object] = dict(
        horizon=20,
        u_min=0.0,
        u_max=U_RANGE,
        du_min=-1e-6,
        du_max=1e-6,
        z_min=0.0,
        z_max=0.63,
        S=1e8,
        formulation="condensed",
    )
    base.update(cfg)
    return MpcController(model, MpcConfig(**base))  # type: ignore[arg-type]


@pytest.mark.parametrize("z_max", [0.63, 0.46])  # 0.46: the output bound becomes active
def test_a_transient_on_daqp_matches_osqp_at_a_tight_tolerance(z_max: float) -> None:
    """A new setpoint moves the rate-limited plan's active set every sample: daqp, hot-started
    from the previous working set, gives OSQP's polished optimum at 1e-8 each sample."""
    ctrl = _kortela_like(z_max=z_max)
    check = _kortela_like(z_max=z_max, solver="osqp", tolerances=(1e-8,), max_iter=200_000)
    assert ctrl.solver == "daqp" and check.solver == "osqp"
    x = np.array([0.41, 0.19, 0.3])
    u_prev = np.array([5e-5, 3e-5])
    model = ctrl.model
    hot = 0
    for k in range(30):
        r = np.array([0.45, 0.2]) if k < 3 else np.array([0.5, 0.17])
        res = ctrl.plan(x, r, u_prev)
        ref = check.plan(x, r, u_prev)
        assert res.status == ref.status == MpcStatus.SOLVED
        assert res.solved_by == "daqp" and ref.solved_by == "osqp"
        assert np.max(np.abs(res.planned_u - ref.planned_u)) <= 1e-6 * U_RANGE
        assert res.objective == pytest.approx(ref.objective, rel=1e-6)
        hot += res.iterations <= 2
        x = model.x_op + model.A @ (x - model.x_op) + model.B @ (res.u - model.u_op)
        u_prev = res.u
    assert hot >= 5  # near the end of the transient the working set barely changes


def test_a_violated_output_bound_on_daqp_soft_rows_matches_osqp_on_the_slacks() -> None:
    """T1 starts 4 cm above z_max: the first predicted levels cannot meet it, so daqp's soft
    rows are violated ("soft optimal"); the plans, costs and violations equal OSQP's polished
    optimum of the QP with its slack variables at 1e-8, sample by sample, while the
    rate-limited plan brings the level down."""
    ctrl = _kortela_like(z_max=0.46)
    check = _kortela_like(z_max=0.46, solver="osqp", tolerances=(1e-8,), max_iter=200_000)
    x = np.array([0.5, 0.2, 0.3])
    u_prev = np.array([5e-5, 3e-5])
    model = ctrl.model
    statuses = []
    for _ in range(12):
        r = np.array([0.45, 0.2])
        res = ctrl.plan(x, r, u_prev)
        ref = check.plan(x, r, u_prev)
        assert res.status == ref.status == MpcStatus.SOLVED
        assert np.max(np.abs(res.planned_u - ref.planned_u)) <= 1e-6 * U_RANGE
        assert res.objective == pytest.approx(ref.objective, rel=1e-6)
        assert res.max_output_violation == pytest.approx(ref.max_output_violation, rel=1e-6, abs=1e-9)
        if res.max_output_violation > 1e-5:  # [m], well above daqp's primal tolerance
            statuses.append(res.osqp_status)
        x = model.x_op + model.A @ (x - model.x_op) + model.B @ (res.u - model.u_op)
        u_prev = res.u
    assert len(statuses) == 12 and set(statuses) == {"soft optimal"}


def test_model_update_on_daqp_equals_a_fresh_controller() -> None:
    ctrl = _kortela_like()
    x, r, u_prev = np.array([0.41, 0.19, 0.3]), np.array([0.45, 0.2]), np.array([5e-5, 3e-5])
    ctrl.plan(x, r, u_prev)
    ctrl.update_model(ctrl.model.A * 0.999, ctrl.model.B, u_op=np.array([5.2e-5, 2.9e-5]))
    fresh = MpcController(ctrl.model, ctrl.config)
    a, b = ctrl.plan(x, r, u_prev), fresh.plan(x, r, u_prev)
    assert np.max(np.abs(a.planned_u - b.planned_u)) <= 1e-9 * U_RANGE
    assert a.objective == pytest.approx(b.objective, rel=1e-9)


def test_the_solver_choice_follows_the_form_and_refuses_daqp_on_the_sparse_form() -> None:
    assert _kortela_like().solver == "daqp"
    assert _kortela_like(formulation="sparse").solver == "osqp"
    assert _kortela_like(solver="osqp").solver == "osqp"
    with pytest.raises(ValueError, match="solver 'daqp' needs formulation"):
        _kortela_like(formulation="sparse", solver="daqp")
    with pytest.raises(ValueError, match="solver must be"):
        _kortela_like(solver="qpoases")
    # with the solver named, "auto" picks the form daqp solves, at any horizon
    assert _kortela_like(horizon=60, solver="daqp", formulation="auto").formulation == "condensed"


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_the_vectors_of_the_step_data_are_the_qps_and_solve_to_the_same_plan(solver: str) -> None:
    """backend.vectors(th) gives formulation.qp_vectors' q, l, u (to rounding), read-only; daqp
    solves them from its own product (the shifted bounds) and from copies (shifting them itself)
    to the same optimum."""
    ctrl = _kortela_like(solver=solver, formulation="condensed", z_max=0.46)
    qp, backend = ctrl._qp, ctrl.backend
    x, r, u_prev = np.array([0.41, 0.19, 0.3]), np.array([0.45, 0.2]), np.array([5e-5, 3.05e-5])
    dx0, eta = x - ctrl.model.x_op, np.array([2e-7, -1e-7])
    th = qp.step_data(dx0, eta, r, u_prev, qp.rate_window_base(u_prev.tolist()))
    q, lo, up = backend.vectors(th)
    ref = qp.qp_vectors(dx0, eta, np.broadcast_to(r, (ctrl.horizon, 2)), u_prev)
    for got, want in zip((q, lo, up), ref, strict=True):
        assert not got.flags.writeable
        finite = np.isfinite(want)
        assert np.array_equal(np.isfinite(got), finite) and np.array_equal(got[~finite], want[~finite])
        scale = max(1.0, float(np.abs(want[finite]).max()))
        assert np.max(np.abs(got[finite] - want[finite])) <= 1e-12 * scale
    mapped = backend.solve(q, lo, up)
    copied = backend.solve(q.copy(), lo.copy(), up.copy())
    assert mapped.x is not None and copied.x is not None
    assert np.max(np.abs(mapped.x - copied.x)) <= 1e-9


def test_correct_after_a_model_update_uses_the_new_gain_and_operating_point() -> None:
    ctrl = _kortela_like()
    ctrl.update_model(ctrl.model.A * 0.999, ctrl.model.B, x_op=ctrl.model.x_op + 0.01)
    kf, x_op = ctrl.estimator, ctrl.model.x_op
    y, x_prior, eta_prior = x_op + 0.003, x_op - 0.002, np.array([1e-7, -2e-7])
    x, eta = ctrl.correct(y, x_prior, eta_prior)
    prior = np.concatenate([x_prior - x_op, eta_prior])
    post = prior + kf.gain @ ((y - x_op) - kf.augmented[2] @ prior)
    np.testing.assert_allclose(x, x_op + post[:3], rtol=0, atol=1e-15)
    np.testing.assert_allclose(eta, post[3:], rtol=0, atol=1e-18)
    est = kf.estimate
    assert est is not None and np.allclose(est.x, post[:3], rtol=0, atol=1e-15)
