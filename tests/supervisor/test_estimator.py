"""Augmented steady-state Kalman filter (supervisor.estimator) and offset-free tracking on the
LINEAR three-tank model (the model built here from the digest's formulas, section 1.1)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from digest_models import three_tank_continuous, zoh
from supervisor.estimator import AugmentedKalmanFilter, augmented_model, check_disturbance_observability
from supervisor.mpc import MpcConfig, MpcController, MpcModel
from tanklab.enums import MpcStatus

AT, AP, MU, G = 0.0154, 5e-5, 0.84, 9.81
H_OP = np.array([0.4037, 0.2289, 0.3163])
Q_OP = np.array([5.5e-5, 3.4e-5])
TS = 2.5
QMAX = 1.2e-4


def kortela_matrices() -> tuple[np.ndarray, np.ndarray]:
    return zoh(*three_tank_continuous(AT, AP, MU, MU, MU, H_OP), TS)


A, B = kortela_matrices()
C = np.eye(3)
E3 = np.array([[0.0], [0.0], [1.0]])
MODEL = MpcModel(A=A, B=B, C=C, Cz=C[:2], x_op=H_OP, u_op=Q_OP, ts_s=TS)


def config(**kw: Any) -> MpcConfig:
    base: dict[str, Any] = {
        "horizon": 40,
        "u_min": 0.0,
        "u_max": QMAX,
        "du_min": -1e-5,
        "du_max": 1e-5,
        "z_min": 0.0,
        "z_max": 0.63,
    }
    base.update(kw)
    return MpcConfig(**base)


# ------------------------------------------------------------------------------------------------
# the filter
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("rows", "Bd"),
    [
        pytest.param([0, 1, 2], B, id="all-levels-Bd=B"),
        pytest.param([0, 1], B, id="h1-h2-Bd=B"),
        pytest.param([0, 1, 2], np.hstack([B, E3]), id="all-levels-Bd=[B,e3]"),
    ],
)
def test_filter_converges_to_true_state_and_constant_disturbance(rows: list[int], Bd: np.ndarray) -> None:
    """Noise-free data from the augmented linear model, a wrong prior: the error vanishes."""
    rng = np.random.default_rng(1)
    kf = AugmentedKalmanFilter(A, B, C[rows], Bd)
    d_true = rng.uniform(-1e-5, 1e-5, Bd.shape[1])
    x = np.array([0.03, -0.02, 0.01])
    kf.reset(x=np.zeros(3), disturbance=np.zeros(Bd.shape[1]))
    u_prev = np.zeros(2)
    for _ in range(3000):  # the slowest error mode (Bd = [B, e3]) decays by 0.9936 per sample
        est = kf.update(C[rows] @ x, u_prev)
        u_prev = rng.uniform(-2e-5, 2e-5, 2)  # applied over the next sample
        x = A @ x + B @ u_prev + Bd @ d_true
    est = kf.update(C[rows] @ x, u_prev)
    assert np.max(np.abs(est.innovation)) < 1e-10
    assert np.allclose(est.x, x, rtol=0, atol=1e-10)
    assert np.allclose(est.disturbance, d_true, rtol=0, atol=1e-12)
    assert kf.error_spectral_radius < 1.0


def test_gain_matches_an_independent_riccati_iteration() -> None:
    """The DARE solution equals the fixed point of the filter Riccati recursion."""
    kf = AugmentedKalmanFilter(
        A, B, C, B, state_noise_std=1e-4, disturbance_noise_std=1e-6, measurement_noise_std=1e-3
    )
    Aa = np.block([[A, B], [np.zeros((2, 3)), np.eye(2)]])
    Ca = np.hstack([C, np.zeros((3, 2))])
    Q = np.diag([1e-8] * 3 + [1e-12] * 2)
    R = 1e-6 * np.eye(3)
    P = np.eye(5) * 1e-6
    for _ in range(100_000):
        S = Ca @ P @ Ca.T + R
        P_next = Aa @ P @ Aa.T - Aa @ P @ Ca.T @ np.linalg.inv(S) @ Ca @ P @ Aa.T + Q
        done = np.max(np.abs(P_next - P)) <= 1e-14 * np.max(np.abs(P_next))
        P = P_next
        if done:
            break
    else:
        pytest.fail("Riccati iteration did not converge")
    K = P @ Ca.T @ np.linalg.inv(Ca @ P @ Ca.T + R)
    assert np.allclose(kf.covariance, P, rtol=1e-6, atol=1e-20)
    assert np.allclose(kf.gain, K, rtol=1e-6, atol=1e-12)
    Aa2, Ba2, Ca2 = augmented_model(A, B, C, B)
    assert np.array_equal(Aa2, Aa) and np.array_equal(Ca2, Ca)
    assert np.array_equal(Ba2, np.vstack([B, np.zeros((2, 2))]))


def test_filter_validation() -> None:
    with pytest.raises(ValueError, match="A must be square"):
        AugmentedKalmanFilter(A[:2], B, C)
    with pytest.raises(ValueError, match="B must have shape"):
        AugmentedKalmanFilter(A, B[:2], C)
    with pytest.raises(ValueError, match="measurement_noise_std must be finite and > 0"):
        AugmentedKalmanFilter(A, B, C, measurement_noise_std=0.0)
    with pytest.raises(ValueError, match="state_noise_std must be a scalar or have shape"):
        AugmentedKalmanFilter(A, B, C, state_noise_std=[1e-4, 1e-4])
    with pytest.raises(ValueError, match=r"rank \[\[I - A, -Bd\], \[C, 0\]\] must equal n \+ n_eta = 6"):
        AugmentedKalmanFilter(A, B, C[:2], np.hstack([B, E3]))
    with pytest.raises(ValueError, match="not observable"):
        check_disturbance_observability(A, C, np.hstack([B, B]))
    with pytest.raises(TypeError, match="A must be a real 2-D array"):
        AugmentedKalmanFilter("A", B, C)
    kf = AugmentedKalmanFilter(A, B, C)
    with pytest.raises(ValueError, match="predict needs a corrected estimate"):
        kf.predict(np.zeros(2))
    with pytest.raises(ValueError, match="y must be finite"):
        kf.update([np.nan, 0, 0], np.zeros(2))
    assert kf.estimate is None  # nothing changed


def test_set_model_keeps_the_estimate_and_recomputes_the_gain() -> None:
    kf = AugmentedKalmanFilter(A, B, C)
    est = kf.update([0.01, -0.01, 0.0], np.zeros(2))
    K0 = kf.gain
    kf.set_model(0.99 * A, 1.1 * B)
    assert not np.allclose(kf.gain, K0)
    assert np.allclose(kf.Bd, 1.1 * B)  # Bd follows B when it was defaulted
    now = kf.estimate
    assert now is not None and np.array_equal(now.x, est.x)
    fresh = AugmentedKalmanFilter(0.99 * A, 1.1 * B, C)
    assert np.allclose(kf.gain, fresh.gain)


# ------------------------------------------------------------------------------------------------
# offset-free MPC on the linear model
# ------------------------------------------------------------------------------------------------
def linear_loop(
    ctrl: MpcController,
    steps: int,
    r_of_k: Any,
    *,
    input_disturbance: np.ndarray | None = None,
    state_disturbance: np.ndarray | None = None,
    start: int = 0,
) -> dict[str, np.ndarray]:
    """x(k+1) = A x + B (u + d_u) + d_x (deviations), disturbances switched on at ``start``."""
    dx = np.zeros(3)
    u = Q_OP.copy()
    hs, us, rs, st = [], [], [], []
    for k in range(steps):
        h = H_OP + dx
        r = r_of_k(k)
        res = ctrl.step(h, r, u)
        assert np.all(np.isfinite(res.u))
        u = np.array(res.u)
        hs.append(h)
        us.append(u)
        rs.append(r)
        st.append(int(res.status))
        du = np.zeros(2) if input_disturbance is None or k < start else input_disturbance
        dxs = np.zeros(3) if state_disturbance is None or k < start else state_disturbance
        dx = A @ dx + B @ (u - Q_OP + du) + dxs
    return {"h": np.array(hs), "u": np.array(us), "r": np.array(rs), "status": np.array(st)}


def _assert_constraints(log: dict[str, np.ndarray], du_max: float) -> None:
    u = log["u"]
    assert np.all(u >= 0.0) and np.all(u <= QMAX)
    moves = np.diff(np.vstack([Q_OP, u]), axis=0)
    assert np.all(np.abs(moves) <= du_max + 1e-18)


@pytest.mark.parametrize("formulation", ["condensed", "sparse"])
def test_zero_offset_under_a_constant_input_disturbance(formulation: str) -> None:
    """A leak-like outflow of 2e-5 m^3/s on T1 plus a setpoint step: h1, h2 reach r exactly."""
    ctrl = MpcController(MODEL, config(formulation=formulation))
    r_of_k = lambda k: np.array([0.42, 0.2289]) if k >= 100 else H_OP[:2]  # noqa: E731
    log = linear_loop(ctrl, 700, r_of_k, input_disturbance=np.array([-2e-5, 0.0]), start=20)
    _assert_constraints(log, 1e-5)
    err = np.abs(log["h"][:, :2] - log["r"])
    assert np.max(err[-50:]) < 1e-6
    assert np.max(err[100:130]) > 1e-3  # it did have to move
    assert np.all(log["status"] == MpcStatus.SOLVED)
    res = ctrl.step(log["h"][-1], log["r"][-1], log["u"][-1])
    assert np.allclose(res.disturbance, [-2e-5, 0.0], rtol=0, atol=1e-9)  # eta estimates the leak


def test_zero_offset_with_the_papers_rate_limit() -> None:
    """Digest 2.5 tuning (du = 1e-6 per sample, first move limited): slower, still offset-free."""
    ctrl = MpcController(MODEL, config(du_min=-1e-6, du_max=1e-6))
    log = linear_loop(ctrl, 800, lambda k: H_OP[:2], input_disturbance=np.array([-1e-5, 5e-6]), start=10)
    _assert_constraints(log, 1e-6)
    assert np.max(np.abs(log["h"][-50:, :2] - H_OP[:2])) < 1e-6


def test_t3_leak_needs_as_many_disturbances_as_filtered_outputs() -> None:
    """Digest 2.5: a T3 leak with three levels filtered and Bd = B leaves an offset; feeding only
    h1, h2, or adding a third disturbance Bd = [B, e3], removes it."""
    leak = np.array([0.0, 0.0, -1e-5 * TS / AT])  # 1e-5 m^3/s out of T3, as metres per sample
    cases = {
        "all-levels-Bd=B": config(),
        "h1-h2-Bd=B": config(estimator_outputs=[0, 1]),
        "all-levels-Bd=[B,e3]": config(disturbance_matrix=np.hstack([B, E3])),
    }
    offsets = {}
    for name, cfg in cases.items():
        # 1500 samples: with Bd = [B, e3] the slowest estimation mode decays by 0.9936 per sample
        log = linear_loop(
            MpcController(MODEL, cfg), 1500, lambda k: H_OP[:2], state_disturbance=leak, start=10
        )
        offsets[name] = np.max(np.abs(log["h"][-20:, :2] - H_OP[:2]))
    assert offsets["all-levels-Bd=B"] > 1e-4
    assert offsets["h1-h2-Bd=B"] < 1e-6
    assert offsets["all-levels-Bd=[B,e3]"] < 1e-6


def test_input_weight_variant_stays_offset_free_with_the_steady_state_target() -> None:
    """R > 0 with u_ss from the target problem: zero offset; with u_ss = u_op (the 2.4 paper's
    literal deviation form) the input weight pulls u back toward u_op and leaves an offset."""
    d = np.array([-2e-5, 0.0])
    target = MpcController(MODEL, config(R=1e8))
    log = linear_loop(target, 1500, lambda k: H_OP[:2], input_disturbance=d, start=10)
    assert np.max(np.abs(log["h"][-20:, :2] - H_OP[:2])) < 1e-6
    literal = MpcController(MODEL, config(R=1e8, input_target="operating_point"))
    log = linear_loop(literal, 700, lambda k: H_OP[:2], input_disturbance=d, start=10)
    assert np.max(np.abs(log["h"][-20:, :2] - H_OP[:2])) > 1e-3
