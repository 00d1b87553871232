"""The MPC's affine laws (supervisor.mpc._AffineLaw) and the step's lean paths.

Oracles: the controller's own exact path on the same QP (a reference given as an (Np, nz)
preview never uses a law, so a twin controller fed the tiled reference solves every step by
factorisation and its KKT check); ``_ActiveSetQp.solve`` at single parameter points (the affine
KKT solution must equal it, and its linear certificate must agree with the direct check); hand
examples for the affine-map helper; a plain numpy move-by-move loop for the projection; and the
filter's predictor and corrector called one after the other.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from supervisor.estimator import AugmentedKalmanFilter
from supervisor.mpc import _REPEATED, KKT_TOL, MpcConfig, MpcController, MpcModel, MpcResult, _affine_map

U_RANGE = 1.2e-4
X_OP = np.array([0.4, 0.2, 0.3])
U_OP = np.array([5e-5, 3e-5])


def _controller(**cfg: object) -> MpcController:
    a = np.array([[0.98, 0.0, 0.01], [0.0, 0.97, 0.015], [0.015, 0.01, 0.975]])
    b = np.array([[160.0, 0.0], [0.0, 160.0], [0.0, 0.0]])
    model = MpcModel(A=a, B=b, C=np.eye(3), Cz=np.eye(3)[:2], x_op=X_OP, u_op=U_OP, ts_s=2.5)
    settings_: dict[str, object] = dict(
        horizon=20, u_min=0.0, u_max=U_RANGE, du_min=-1e-6, du_max=1e-6, z_min=0.0, z_max=0.63, S=1e8
    )
    settings_.update(cfg)
    return MpcController(model, MpcConfig(**settings_))  # type: ignore[arg-type]


def _same(a: MpcResult, b: MpcResult) -> None:
    assert np.max(np.abs(a.planned_u - b.planned_u)) <= 1e-10 * U_RANGE
    assert np.max(np.abs(a.predicted_z - b.predicted_z)) <= 1e-10
    assert a.objective == pytest.approx(b.objective, rel=1e-9, abs=1e-15)
    assert a.max_output_violation == pytest.approx(b.max_output_violation, abs=1e-12)
    assert a.status == b.status


def _warm(ctrl: MpcController, twin: MpcController, x: np.ndarray, r: np.ndarray, u: np.ndarray) -> None:
    """The same history for both: OSQP, then the repeated set (which builds the law)."""
    for _ in range(2):
        ctrl.plan(x, r, u)
        twin.plan(x, np.tile(r, (twin.horizon, 1)), u)


@settings(max_examples=30, deadline=None)
@given(
    dx=st.lists(st.floats(-2e-3, 2e-3), min_size=3, max_size=3),
    dr=st.lists(st.floats(-2e-3, 2e-3), min_size=2, max_size=2),
    du=st.lists(st.floats(-3e-7, 3e-7), min_size=2, max_size=2),
    eta=st.lists(st.floats(-2e-6, 2e-6), min_size=2, max_size=2),
    output_bound=st.sampled_from([0.63, 0.4102, 0.40]),  # 0.40: x1 starts above it, slack paid
)
def test_a_law_step_equals_the_exact_solve_of_the_same_qp(
    dx: list[float], dr: list[float], du: list[float], eta: list[float], output_bound: float
) -> None:
    ctrl, twin = _controller(z_max=output_bound), _controller(z_max=output_bound)
    x, r, u = np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2]), U_OP.copy()
    _warm(ctrl, twin, x, r, u)
    assert ctrl._law is not None and twin._law is None  # a preview never builds one
    x2, r2, u2, d2 = x + np.array(dx), r + np.array(dr), u + np.array(du), np.array(eta)
    fast = ctrl.plan(x2, r2, u2, d2)
    slow = twin.plan(x2, np.tile(r2, (twin.horizon, 1)), u2, d2)
    _same(fast, slow)
    # the law answered exactly when the previous set is still optimal (the twin says so)
    assert (fast.solved_by == "law") == (slow.solved_by == "previous")
    assert (ctrl._ws_law is not None) == (fast.solved_by == "law")
    if fast.solved_by == "law":
        # the law's plan meets the input and rate bounds as computed: projecting it moves nothing
        projected, moved = ctrl._project(fast.planned_u.copy(), u2)
        assert not moved and np.array_equal(projected, fast.planned_u)


def test_the_law_path_is_taken_near_a_steady_state_and_its_warm_start_is_the_solution() -> None:
    ctrl, twin = _controller(), _controller()
    x, r, u = np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2]), U_OP.copy()
    _warm(ctrl, twin, x, r, u)
    fast = ctrl.plan(x + 1e-4, r, u)
    slow = twin.plan(x + 1e-4, np.tile(r, (twin.horizon, 1)), u)
    assert fast.solved_by == "law" and slow.solved_by == "previous"
    assert fast.iterations == 0 and fast.osqp_status == _REPEATED
    _same(fast, slow)
    # OSQP's warm start, made only when needed, is the exact solution shifted by one sample
    ctrl._settle_warm_start()
    assert ctrl._ws_law is None and ctrl._ws_x is not None and twin._ws_x is not None
    assert np.max(np.abs(ctrl._ws_x - twin._ws_x)) <= 1e-9
    assert ctrl._ws_y is not None and twin._ws_y is not None
    assert np.max(np.abs(ctrl._ws_y - twin._ws_y)) <= 1e-9 * max(1.0, float(np.max(np.abs(twin._ws_y))))


def test_a_law_refuses_when_its_set_is_no_longer_optimal() -> None:
    ctrl, twin = _controller(), _controller()
    x, u = np.array([0.41, 0.19, 0.3]), U_OP.copy()
    _warm(ctrl, twin, x, np.array([0.41, 0.2]), u)
    far = np.array([0.6, 0.1])  # the rate-limited ramp activates other rows
    res = ctrl.plan(x, far, u)
    ref = twin.plan(x, np.tile(far, (twin.horizon, 1)), u)
    assert res.solved_by != "law"  # the law said no; the step went the exact / OSQP way
    assert res.solved_by == ref.solved_by
    _same(res, ref)
    assert np.all(np.abs(np.diff(np.vstack([u, res.planned_u]), axis=0)) <= 1e-6 * (1 + 1e-12))


def test_u_prev_outside_the_rate_window_is_outside_every_law() -> None:
    # _qp_vectors clips such a u(-1); the law is affine only where it does not
    ctrl, twin = _controller(), _controller()
    x, r = np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2])
    _warm(ctrl, twin, x, r, U_OP.copy())
    u_out = np.array([U_RANGE + 5e-6, 3e-5])
    res = ctrl.plan(x, r, u_out)
    ref = twin.plan(x, np.tile(r, (twin.horizon, 1)), u_out)
    assert res.solved_by != "law"
    _same(res, ref)


def test_model_update_drops_the_laws() -> None:
    ctrl, twin = _controller(), _controller()
    x, r, u = np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2]), U_OP.copy()
    _warm(ctrl, twin, x, r, u)
    ctrl.plan(x, r, u)  # a law step: its warm start is still pending
    assert ctrl._laws and ctrl._ws_law is not None
    ctrl.update_model(ctrl.model.A * 0.999, ctrl.model.B)
    twin.plan(x, np.tile(r, (twin.horizon, 1)), u)
    twin.update_model(twin.model.A * 0.999, twin.model.B)
    assert not ctrl._laws and ctrl._law is None and ctrl._ws_law is None
    for _ in range(3):  # the new model's laws are built again from its own factorisations
        _same(ctrl.plan(x, r, u), twin.plan(x, np.tile(r, (twin.horizon, 1)), u))
    assert ctrl._law is not None


@settings(max_examples=40, deadline=None)
@given(scale=st.floats(0.0, 3.0), seed=st.integers(0, 2**16))
def test_the_affine_kkt_solution_and_certificate_agree_with_a_direct_solve(scale: float, seed: int) -> None:
    ctrl = _controller()
    x, r, u = np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2]), U_OP.copy()
    for _ in range(2):
        ctrl.plan(x, r, u)
    assert ctrl._active is not None
    lower, upper = ctrl._active
    assert ctrl._maps is not None  # computed with the model
    Qm, Lm, Um = ctrl._maps
    kkt = ctrl._kkt.affine(lower, upper, Qm, Lm, Um)
    assert kkt is not None
    rng = np.random.default_rng(seed)
    dx0 = np.array([0.01, -0.01, 0.0]) + scale * rng.uniform(-0.02, 0.02, 3)
    eta = scale * rng.uniform(-2e-6, 2e-6, 2)
    r2 = r + scale * rng.uniform(-0.02, 0.02, 2)
    u2 = U_OP + scale * rng.uniform(-2e-6, 2e-6, 2)
    theta = np.concatenate([dx0, eta, r2, u2, [1.0]])
    q, lo, up = ctrl._qp_vectors(dx0, eta, np.tile(r2, (ctrl.horizon, 1)), u2)
    # the affine maps reproduce the QP's vectors (infinite bounds stay infinite)
    assert np.allclose(Qm @ theta, q, rtol=0, atol=1e-12)
    finite = np.isfinite(lo)
    assert np.array_equal(np.isfinite(Lm[:, -1]), finite)
    assert np.allclose((Lm @ theta)[finite], lo[finite], rtol=0, atol=1e-12)
    direct = ctrl._kkt.solve(q, lo, up, lower, upper)
    assert direct is not None
    assert np.max(np.abs(kkt.x @ theta - direct.x)) <= 1e-10
    assert np.max(np.abs(kkt.y @ theta - direct.y)) <= 1e-10 * max(1.0, float(np.max(np.abs(direct.y))))
    margin = float((kkt.checks @ theta).min())
    if abs(margin - KKT_TOL) > 1e-11:  # away from the tolerance's edge both must say the same
        assert (margin >= 0.0) == direct.certified


def test_affine_map_of_hand_examples() -> None:
    def f(t: np.ndarray) -> np.ndarray:
        return np.array([2.0 * t[0] - 3.0 * t[1] + 1.0, np.inf, -np.inf, 0.5 * t[1]])

    M = _affine_map(f, np.array([1.0, 2.0]), np.array([0.5, 4.0]))
    assert np.array_equal(M, [[2.0, -3.0, 1.0], [0.0, 0.0, np.inf], [0.0, 0.0, -np.inf], [0.0, 0.5, 0.0]])


def _reference_projection(ctrl: MpcController, plan: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
    """The projection written as plain numpy, move by move (the definition)."""
    umin, umax, dmin, dmax = ctrl._u_min, ctrl._u_max, ctrl._du_min, ctrl._du_max
    out = np.minimum(np.maximum(plan, umin), umax)
    base = np.minimum(np.maximum(u_prev, umin - dmax), umax - dmin)
    out[0] = np.minimum(np.maximum(out[0], np.maximum(umin, base + dmin)), np.minimum(umax, base + dmax))
    d = out[1:] - out[:-1]
    if (d >= dmin).all() and (d <= dmax).all():
        return out
    for k in range(1, plan.shape[0]):
        lo = np.maximum(umin, out[k - 1] + dmin)
        hi = np.minimum(umax, out[k - 1] + dmax)
        out[k] = np.minimum(np.maximum(out[k], lo), hi)
    return out


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    spread=st.sampled_from([1e-7, 1e-6, 3e-6, 5e-5]),
    u_prev=st.lists(st.floats(-2e-5, 1.5e-4), min_size=2, max_size=2),
    symmetric=st.booleans(),
)
def test_projection_equals_the_move_by_move_definition_bit_for_bit(
    seed: int, spread: float, u_prev: list[float], symmetric: bool
) -> None:
    ctrl = _controller() if symmetric else _controller(du_min=-2e-6, du_max=1e-6)
    rng = np.random.default_rng(seed)
    plan = 6e-5 + np.cumsum(rng.uniform(-spread, spread, (ctrl.horizon, 2)), axis=0)
    up = np.array(u_prev)
    out, moved = ctrl._project(plan.copy(), up)
    ref = _reference_projection(ctrl, plan.copy(), up)
    assert np.array_equal(out, ref)
    assert moved == (not np.array_equal(out, plan))


# ------------------------------------------------------------------------------------------------
# the filter's sample as one product
# ------------------------------------------------------------------------------------------------
def _filter() -> AugmentedKalmanFilter:
    a = np.array([[0.98, 0.0, 0.01], [0.0, 0.97, 0.015], [0.015, 0.01, 0.975]])
    b = np.array([[160.0, 0.0], [0.0, 160.0], [0.0, 0.0]])
    return AugmentedKalmanFilter(a, b, np.eye(3))


def test_one_product_update_equals_predict_then_correct() -> None:
    kf, ref = _filter(), _filter()
    rng = np.random.default_rng(3)
    for k in range(20):
        y, u = rng.normal(0.0, 0.01, 3), rng.normal(0.0, 1e-6, 2)
        est = kf.update(y, u)
        if k:
            ref.predict(u)
        want = ref.correct(y)
        pairs = ((est.x, want.x), (est.disturbance, want.disturbance), (est.innovation, want.innovation))
        for got, exp in pairs:
            assert np.allclose(got, exp, rtol=1e-12, atol=1e-15)
            assert not got.flags.writeable


def test_estimates_handed_out_do_not_change_afterwards() -> None:
    kf = _filter()
    kf.update(np.full(3, 0.01), np.zeros(2))
    est = kf.update(np.full(3, 0.012), np.full(2, 1e-6))
    x_before = est.x.copy()
    kf.shift_state(np.full(3, 0.05))
    kf.update(np.full(3, 0.02), np.zeros(2))
    assert np.array_equal(est.x, x_before)
    with pytest.raises(ValueError, match="assignment destination is read-only"):
        est.x[0] = 1.0


def test_a_non_finite_measurement_is_refused_and_loses_nothing() -> None:
    kf = _filter()
    kf.update(np.full(3, 0.01), np.zeros(2))
    before = kf.estimate
    with pytest.raises(ValueError, match="y must be finite"):
        kf.update(np.array([0.01, np.nan, 0.0]), np.zeros(2))
    after = kf.estimate
    assert before is not None and after is not None and np.array_equal(before.x, after.x)
    # check_finite=False is for a caller that checked already: NaN then goes through (scipy's rule)
    est = kf.update(np.array([0.01, np.nan, 0.0]), np.zeros(2), check_finite=False)
    assert np.isnan(est.x).any()
    with pytest.raises(ValueError, match="shape"):
        kf.update(np.zeros(2), np.zeros(2), check_finite=False)


def test_the_controller_refuses_non_finite_step_inputs_naming_them() -> None:
    ctrl = _controller()
    y, r, u = np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2]), U_OP.copy()
    ctrl.step(y, r, u)
    prior = ctrl.estimator.estimate
    for bad_y, bad_r, bad_u, name in (
        (np.array([0.41, np.nan, 0.3]), r, u, "y"),
        (y, np.array([np.inf, 0.2]), u, "r"),
        (y, r, np.array([np.nan, 3e-5]), "u_prev"),
    ):
        with pytest.raises(ValueError, match=f"^{name} must be"):
            ctrl.step(bad_y, bad_r, bad_u)
    after = ctrl.estimator.estimate
    assert prior is not None and after is not None and np.array_equal(prior.x, after.x)
