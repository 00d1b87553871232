"""The MPC step's lean paths: the projection and the filter's sample.

Oracles: a plain numpy move-by-move loop for the projection (``MpcController.project``); the
filter's predictor and corrector called one after the other; the step's input checks.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from supervisor.estimator import AugmentedKalmanFilter
from supervisor.mpc import MpcConfig, MpcController, MpcModel, MpcResult

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


def _reference_projection(ctrl: MpcController, plan: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
    """The projection written as plain numpy, move by move (the definition)."""
    cfg = ctrl.config
    umin, umax, dmin, dmax = (
        np.broadcast_to(np.asarray(v, dtype=float), (2,))
        for v in (cfg.u_min, cfg.u_max, cfg.du_min, cfg.du_max)
    )
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
    out = ctrl.project(plan.copy(), up)
    ref = _reference_projection(ctrl, plan.copy(), up)
    assert np.array_equal(out, ref)


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


@settings(max_examples=30, deadline=None)
@given(
    dx=st.lists(st.floats(-5e-2, 5e-2), min_size=3, max_size=3),
    r=st.lists(st.floats(0.0, 0.63), min_size=2, max_size=2),
    u_prev=st.lists(st.floats(-2e-5, 1.4e-4), min_size=2, max_size=2),
    eta=st.lists(st.floats(-2e-5, 2e-5), min_size=2, max_size=2),
    first_move_limited=st.booleans(),
)
def test_the_one_product_vectors_equal_the_qp_vectors_of_a_tiled_reference(
    dx: list[float], r: list[float], u_prev: list[float], eta: list[float], first_move_limited: bool
) -> None:
    """A constant reference takes q, l, u as one product (the usual step): the same vectors as the
    step-by-step construction of a preview that repeats r, to rounding (u(-1) outside the box too)."""
    ctrl = _controller(first_move_rate_limited=first_move_limited, R=1e6)
    dx0, r_, up, eta_ = np.array(dx), np.array(r), np.array(u_prev), np.array(eta)
    x0 = X_OP + dx0
    fast = ctrl.plan(x0, r_, up, eta_)
    slow = MpcController(ctrl.model, ctrl.config).plan(x0, np.tile(r_, (ctrl.horizon, 1)), up, eta_)
    assert np.max(np.abs(fast.planned_u - slow.planned_u)) <= 1e-9 * U_RANGE
    assert fast.objective == pytest.approx(slow.objective, rel=1e-9, abs=1e-15)


def _si_cost(res: MpcResult, r: np.ndarray, u_prev: np.ndarray) -> float:
    """The SI objective written out for :func:`_controller`'s weights (Qz = 1, S = 1e8, R = 0;
    output bounds not reached): tracking plus moves."""
    plan, z = res.planned_u, res.predicted_z
    du = np.diff(np.vstack([u_prev, plan]), axis=0)
    return 0.5 * float(np.sum((z - r) ** 2)) + 0.5 * 1e8 * float(np.sum(du**2))


def test_the_cost_read_later_is_the_solved_models_and_ignores_later_changes_to_the_inputs() -> None:
    ctrl = _controller()
    r = np.array([0.42, 0.21])
    u_prev = U_OP.copy()
    res = ctrl.plan(X_OP + np.array([0.01, -0.01, 0.0]), r, u_prev)
    expected = _si_cost(res, r.copy(), u_prev.copy())
    assert res.max_output_violation == 0.0
    # the caller reuses its buffers and the controller re-linearises before the cost is read
    r[:] = 0.1
    u_prev[:] = 0.0
    model = ctrl.model
    ctrl.update_model(model.A * 0.99, model.B * 1.1)
    assert res.objective == pytest.approx(expected, rel=1e-9)


def test_a_result_made_by_of_step_is_the_dataclass_made_by_its_init() -> None:
    ctrl = _controller()
    res = ctrl.step(np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2]), U_OP.copy())
    values = {f.name: getattr(res, f.name) for f in dataclasses.fields(MpcResult)}
    made = MpcResult(**values)
    assert res == made and repr(res) == repr(made)
    assert res.objective == made.objective and res.max_output_violation == made.max_output_violation
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.u = res.u  # type: ignore[misc]
    with pytest.raises(TypeError, match="exactly the fields"):
        MpcResult.of_step(**{k: v for k, v in values.items() if k != "cost"})


def _linear_prediction(ctrl: MpcController, x0: np.ndarray, eta: np.ndarray, plan: np.ndarray) -> np.ndarray:
    """z(1..Np) of the model simulated sample by sample (the definition of ``predicted_z``)."""
    model, Bd = ctrl.model, ctrl.disturbance_matrix
    dx, out = x0 - model.x_op, []
    for u in plan:
        dx = model.A @ dx + model.B @ (u - model.u_op) + Bd @ eta
        out.append(model.Cz @ (model.x_op + dx))
    return np.array(out)


def test_state_and_prediction_read_later_are_those_of_the_solved_model_and_plan() -> None:
    """``state`` and ``predicted_z`` are evaluated on first read: after the caller reused its
    arrays, two more steps and a re-linearisation they are still this step's (the oracle: the
    model simulated sample by sample), read-only and the same array on every read."""
    ctrl = _controller()
    x0, r, u_prev, eta = (
        X_OP + np.array([0.02, -0.01, 0.005]),
        np.array([0.43, 0.19]),
        U_OP.copy(),
        np.zeros(2),
    )
    res = ctrl.plan(x0, r, u_prev, eta)
    expected = _linear_prediction(ctrl, x0, eta, res.planned_u)
    state = X_OP + (x0 - X_OP)
    x0[:] = X_OP  # the caller's buffers, reused
    ctrl.plan(x0, r, u_prev, np.zeros(2))
    model = ctrl.model
    ctrl.update_model(model.A * 0.99, model.B * 1.1)
    ctrl.plan(x0 + 0.01, r, u_prev, np.zeros(2))
    assert np.array_equal(res.state, state)
    np.testing.assert_allclose(res.predicted_z, expected, rtol=1e-12, atol=1e-15)
    assert res.predicted_z is res.predicted_z and res.state is res.state
    assert not res.predicted_z.flags.writeable and not res.state.flags.writeable
    assert res.predicted_z.shape == (ctrl.horizon, 2)


def test_a_plan_from_float_arrays_is_the_plan_from_lists_bit_for_bit() -> None:
    """The usual case fills the step buffer in place; the general path checks and converts each
    input: the same QP data, so the same plan and result, and a step's result keeps its own
    state when the buffer is refilled by the next step."""
    fast, slow = _controller(), _controller()
    inputs = [
        (X_OP + np.array([0.02, -0.01, 0.005]), np.array([0.43, 0.19]), U_OP.copy(), np.array([1e-6, -2e-6])),
        (X_OP + np.array([-0.01, 0.02, 0.0]), np.array([0.38, 0.22]), U_OP + 1e-6, np.zeros(2)),
    ]
    results = []
    for x, r, u, eta in inputs:
        a = fast.plan(x, r, u, eta)
        b = slow.plan(x.tolist(), r.tolist(), u.tolist(), eta.tolist())
        for name in ("u", "planned_u", "predicted_z", "state", "disturbance"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.objective == b.objective and a.iterations == b.iterations
        results.append(a)
    assert np.array_equal(results[0].state, X_OP + (inputs[0][0] - X_OP))


def test_a_non_finite_input_on_the_buffered_path_is_named_and_the_next_step_is_unaffected() -> None:
    ctrl = _controller()
    x, r, u, eta = X_OP.copy(), np.array([0.4, 0.2]), U_OP.copy(), np.zeros(2)
    ref = _controller()
    first, ref_first = ctrl.plan(x, r, u, eta), ref.plan(x, r, u, eta)
    with pytest.raises(ValueError, match="x"):
        ctrl.plan(np.array([np.nan, 0.2, 0.3]), r, u, eta)
    with pytest.raises(ValueError, match="disturbance"):
        ctrl.plan(x, r, u, np.array([np.inf, 0.0]))
    with pytest.raises(ValueError, match="u_prev"):
        ctrl.plan(x, r, np.array([np.nan, 0.0]), eta)
    x2 = X_OP + np.array([0.01, 0.0, -0.01])
    after, ref_after = ctrl.plan(x2, r, u, eta), ref.plan(x2, r, u, eta)
    assert np.array_equal(first.state, ref_first.state)  # the failed steps left the result alone
    assert np.array_equal(after.planned_u, ref_after.planned_u) and np.array_equal(
        after.state, ref_after.state
    )
    assert after.failures == 0


def test_of_step_with_a_pending_prediction_takes_the_other_fields_only() -> None:
    ctrl = _controller()
    res = ctrl.step(np.array([0.41, 0.19, 0.3]), np.array([0.41, 0.2]), U_OP.copy())
    values = {f.name: getattr(res, f.name) for f in dataclasses.fields(MpcResult)}
    pending = res.__dict__["_pending"]
    with pytest.raises(TypeError, match="exactly the fields"):
        MpcResult.of_step(pending, **values)
    eager = {k: v for k, v in values.items() if k not in ("state", "predicted_z")}
    lazy = MpcResult.of_step(pending, **eager)
    assert np.array_equal(lazy.predicted_z, res.predicted_z) and np.array_equal(lazy.state, res.state)
    with pytest.raises(AttributeError, match="no_such_field"):
        _ = res.no_such_field  # type: ignore[attr-defined]
