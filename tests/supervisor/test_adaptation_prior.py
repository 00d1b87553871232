"""Tests of the well-conditioned adaptation (ADR 0014): PriorRls, the model-based tuning, the
log-space push path, the box-limit diagnostic and the noise estimate. Hand-computed oracles and
Hypothesis properties; no clock."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from supervisor.adaptation import (
    AdaptationConfig,
    GainBox,
    LoopModel,
    PidGainAdapter,
    PidGains,
    gain_path_step,
    model_based_gains,
)
from supervisor.prior_rls import PriorRls

# --------------------------------------------------------------------------- PriorRls: oracles


def test_without_data_the_estimate_is_the_prior_and_the_health_is_the_prior_s() -> None:
    rls = PriorRls([1.0, -2.0], [4.0, 0.25], forgetting=0.9)
    np.testing.assert_array_equal(rls.theta, [1.0, -2.0])
    assert rls.excitation == 0.0 and rls.energy == 0.0
    assert rls.condition_number == pytest.approx(16.0)  # 4 / 0.25
    assert rls.trace == pytest.approx(0.25 + 4.0)  # trace of L0^-1


def test_one_sample_weighs_against_the_prior() -> None:
    # theta = (l0 theta_p + x y) / (l0 + x^2) = (2 * 1 + 1 * 4) / (2 + 1) = 2.
    rls = PriorRls([1.0], [2.0], forgetting=1.0)
    assert rls.update([1.0], 4.0)
    assert rls.theta[0] == pytest.approx(2.0)
    assert rls.last_error == pytest.approx(3.0)  # a-priori: 4 - 1
    assert rls.n_updates == 1


def test_directional_forgetting_discounts_only_the_direction_measured() -> None:
    # lambda = 0.5, a negligible prior. Samples (e1, 1), (e2, 2), then (e1, 3): the third sample
    # measures e1 again, so only e1's old sample is discounted by 0.5:
    #   theta_1 = (0.5 * 1 + 3) / (0.5 + 1) = 7/3,   theta_2 = 2 (e2's information kept whole).
    rls = PriorRls([0.0, 0.0], [1e-12, 1e-12], forgetting=0.5)
    for x, y in (([1.0, 0.0], 1.0), ([0.0, 1.0], 2.0), ([1.0, 0.0], 3.0)):
        assert rls.update(x, y)
    np.testing.assert_allclose(rls.data_information, np.diag([1.5, 1.0]), atol=1e-12)
    np.testing.assert_allclose(rls.theta, [7.0 / 3.0, 2.0], rtol=1e-9)


def test_a_quiet_direction_does_not_wind_up() -> None:
    # Exponential forgetting would divide the information along e2 by lambda at every e1 sample
    # (P blows up along e2). Directional forgetting leaves it alone: R[1, 1] stays 1.
    rls = PriorRls([0.0, 0.0], [1e-3, 1e-3], forgetting=0.9)
    rls.update([0.0, 1.0], 1.0)
    for _ in range(500):
        rls.update([1.0, 0.0], 2.0)
    R = rls.data_information
    assert R[1, 1] == pytest.approx(1.0)
    assert R[0, 0] == pytest.approx(1.0 / (1.0 - 0.9), rel=1e-6)  # x x' / (1 - lambda), bounded
    np.testing.assert_allclose(rls.theta, [2.0, 1.0], rtol=1e-3)


def test_non_finite_and_unexcited_samples_leave_the_state_untouched() -> None:
    rls = PriorRls([1.0, 1.0], [1.0, 1.0], forgetting=0.99, excitation_threshold=0.1)
    assert not rls.update([0.0, 1.0], 1.0)  # first sample: sets the reference only
    before = (rls.theta, rls.data_information)
    assert not rls.update([math.nan, 1.0], 1.0)
    assert not rls.update([0.0, 1.0], math.inf)
    assert not rls.update([0.05, 1.0], 1.0)  # moved 0.05 < 0.1: dead zone
    np.testing.assert_array_equal(rls.theta, before[0])
    np.testing.assert_array_equal(rls.data_information, before[1])
    assert rls.n_skipped_nonfinite == 2 and rls.n_skipped_unexcited == 2 and rls.n_updates == 0


def test_a_satisfied_inequality_teaches_nothing_and_a_violated_one_is_absorbed() -> None:
    rls = PriorRls([1.0], [1.0], forgetting=1.0)
    assert not rls.constrain([1.0], 0.5, "ge")  # 1 >= 0.5 already
    assert rls.theta[0] == 1.0 and rls.n_constrained == 0
    # Violated: absorbed as the equality sample (1, 3): theta = (1 * 1 + 3) / 2 = 2, the prior
    # still in the cost (a projection onto x' theta = 3 would have given 3).
    assert rls.constrain([1.0], 3.0, "ge")
    assert rls.theta[0] == pytest.approx(2.0)
    assert rls.n_constrained == 1 and rls.n_updates == 0
    assert not rls.constrain([1.0], 3.0, "le")  # 2 <= 3
    with pytest.raises(ValueError):
        rls.constrain([1.0], 1.0, "eq")  # type: ignore[arg-type]


def test_bounds_clip_the_estimate_and_the_prior() -> None:
    rls = PriorRls([5.0], [1.0], forgetting=1.0, lower=[0.0], upper=[2.0])
    assert rls.theta[0] == 2.0 and rls.prior[0] == 2.0
    rls.update([1.0], -10.0)
    assert rls.theta[0] == 0.0
    rls.set_bounds([-20.0], [20.0])
    assert rls.theta[0] == pytest.approx((2.0 - 10.0) / 2.0)


def test_constructor_refuses_bad_settings() -> None:
    with pytest.raises(ValueError):
        PriorRls([1.0], [0.0], forgetting=0.9)
    with pytest.raises(ValueError):
        PriorRls([1.0], [1.0], forgetting=0.0)
    with pytest.raises(ValueError):
        PriorRls([math.nan], [1.0], forgetting=0.9)
    with pytest.raises(ValueError):
        PriorRls([1.0, 2.0], [1.0], forgetting=0.9)
    with pytest.raises(ValueError):
        PriorRls([1.0], [1.0], forgetting=0.9, lower=[2.0], upper=[1.0])


# --------------------------------------------------------------------------- PriorRls: properties
samples = st.lists(
    st.tuples(
        st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3),
        st.floats(-10.0, 10.0),
    ),
    min_size=1,
    max_size=60,
)


@settings(max_examples=60, deadline=None)
@given(data=samples, lam=st.floats(0.5, 1.0), l0=st.lists(st.floats(1e-3, 1e3), min_size=3, max_size=3))
def test_the_information_matrix_is_always_at_least_the_prior_s(
    data: list[tuple[list[float], float]], lam: float, l0: list[float]
) -> None:
    rls = PriorRls([0.1, 0.2, 0.3], l0, forgetting=lam)
    for x, y in data:
        rls.update(x, y)
        R = rls.data_information
        assert np.isfinite(R).all() and np.isfinite(rls.theta).all()
        np.testing.assert_allclose(R, R.T, atol=1e-9 * (1.0 + np.abs(R).max()))
        w = np.linalg.eigvalsh(R)
        assert w[0] >= -1e-9 * (1.0 + w[-1])
        # cond(L0 + R) <= (lambda_max(R) + max l0) / min l0
        bound = (w[-1] + max(l0)) / min(l0)
        assert rls.condition_number <= bound * (1.0 + 1e-9)


@settings(max_examples=40, deadline=None)
@given(truth=st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3), seed=st.integers(0, 2**31 - 1))
def test_rich_noiseless_data_recover_the_truth_through_a_weak_prior(truth: list[float], seed: int) -> None:
    rng = np.random.default_rng(seed)
    rls = PriorRls([0.0, 0.0, 0.0], [1e-9] * 3, forgetting=0.98)
    for _ in range(200):
        x = rng.normal(size=3)
        rls.update(x, float(x @ np.array(truth)))
    np.testing.assert_allclose(rls.theta, truth, rtol=1e-5, atol=1e-6)


# --------------------------------------------------------------------------- model-based tuning
def _scalar(a: float, b: float) -> LoopModel:
    return LoopModel(np.array([[a]]), np.array([[b]]), np.array([[1.0]]), 1.0, np.zeros(1), np.ones(1))


def test_simc_tuning_of_a_first_order_lag() -> None:
    # tau = 50 s (a = exp(-1/50)), K = b / (1 - a) = 100, Ts = 1 s, theta = 0.5 s, tau_c = 4 s:
    # Kp = tau / (K (tau_c + theta)) = 50 / 450, Ti = min(50, 4 * 4.5) = 18 s, Ki = Kp / 18, Kd = 0.
    a = math.exp(-1.0 / 50.0)
    g = model_based_gains(_scalar(a, 100.0 * (1.0 - a)), None, 4.0)
    assert g.kp[0, 0] == pytest.approx(50.0 / 450.0)
    assert g.ki[0, 0] == pytest.approx(50.0 / 450.0 / 18.0)
    assert g.kd[0, 0] == 0.0


def test_simc_tuning_of_an_integrating_tank() -> None:
    # a = 1, slope k' = b / Ts = 0.01: Kp = 1 / (k' (tau_c + theta)) = 1 / 0.045, Ti = 18 s.
    g = model_based_gains(_scalar(1.0, 0.01), None, 4.0)
    assert g.kp[0, 0] == pytest.approx(1.0 / 0.045)
    assert g.ki[0, 0] == pytest.approx(1.0 / 0.045 / 18.0)


def test_a_pump_that_does_not_move_its_tank_gets_zero_gains() -> None:
    g = model_based_gains(_scalar(0.9, 0.0), None, 4.0)
    assert g.kp[0, 0] == 0.0 and g.ki[0, 0] == 0.0
    with pytest.raises(ValueError):
        model_based_gains(_scalar(0.9, 1.0), None, 0.0)


# --------------------------------------------------------------------------- the adapter
A = math.exp(-1.0 / 50.0)
MODEL = LoopModel(
    np.array([[A]]),
    np.array([[100.0 * (1.0 - A)]]),
    np.array([[1.0]]),
    1.0,
    np.zeros(1),
    np.ones(1),
    x_op=np.array([0.5]),
    u_op=np.array([0.005]),
)
FIXED = PidGains.diagonal([0.02], [1e-3], [-0.01])
MB = model_based_gains(MODEL, None, 4.0)  # Kp 0.111, Ki 6.17e-3


def test_the_estimate_starts_at_the_model_based_tuning_and_is_ready_at_once() -> None:
    ada = PidGainAdapter(MODEL, FIXED)
    assert ada.prior.kp[0, 0] == pytest.approx(MB.kp[0, 0])
    assert ada.prior.kd[0, 0] == 0.0  # between the fixed -0.01 and 0: 0
    assert ada.estimate().allclose(ada.prior)
    # Ready from the start: the first proposal after min_time_s moves toward the tuning.
    ada.observe(scan=0, t_s=0.0, sp=[0.5], pv=[0.5], mv=[0.005], u_mpc=[0.005])
    d = ada.propose(10.0)
    assert d is not None and d.accepted and d.changed


def test_a_push_moves_along_the_straight_line_in_log_space() -> None:
    # Applied Kp 1 -> 4 and Ki 1 -> 2 with a 0.44 rate limit: alpha = ln 1.44 / ln 4, so Kp moves
    # to 4^alpha = 1.44 (at its limit) and Ki to 2^alpha = 1.2; Kd 0 -> 0 stays.
    applied = np.array([[1.0], [1.0], [0.0]])
    target = np.array([[4.0], [2.0], [0.0]])
    limit = 0.44 * np.abs(applied)
    step = gain_path_step(applied, target, limit, "geometric")
    alpha = math.log(1.44) / math.log(4.0)
    np.testing.assert_allclose(step[:, 0], [1.44, 2.0**alpha, 0.0], rtol=1e-12)
    # The linear path (the former proposer) for comparison: alpha = 0.44 / 3.
    np.testing.assert_allclose(
        gain_path_step(applied, target, limit, "linear")[:, 0], [1.44, 1.0 + 0.44 / 3.0, 0.0]
    )


def test_a_gain_the_box_decides_is_reported_on_the_limit() -> None:
    inside = PidGainAdapter(MODEL, FIXED)
    assert not inside.on_box_limit(0)
    d = inside.diagnostics().pumps[0]
    assert not d.on_box_limit
    assert d.box_distance.shape == (3,) and (d.box_distance >= 0.0).all() and (d.box_distance <= 0.5).all()
    # A box whose Kp limit (0.05) is below the model-based Kp (0.111): the estimate sits on it.
    box = GainBox(PidGains.diagonal([0.0], [0.0], [-0.1]), PidGains.diagonal([0.05], [0.1], [0.1]))
    tight = PidGainAdapter(MODEL, FIXED, AdaptationConfig(box=box))
    assert tight.on_box_limit(0)
    p = tight.diagnostics().pumps[0]
    assert p.on_box_limit and p.box_distance[0] == 0.0


def test_the_noise_estimate_and_the_noise_limit() -> None:
    # Levels = x_op + white noise of 2 mm at the operating input: the model's one-step errors
    # differenced give d = v_k - (1 + a) v_k-1 + a v_k-2, var d = (1 + (1 + a)^2 + a^2) sigma^2,
    # so the estimate is sqrt((1 + (1 + a)^2 + a^2) / 6) sigma = 0.995 sigma.
    sigma = 2e-3
    rng = np.random.default_rng(7)
    ada = PidGainAdapter(MODEL, FIXED, AdaptationConfig(noise_move_budget=0.0035))
    for k in range(3000):
        x = 0.5 + sigma * rng.normal()
        ada.observe(scan=k, t_s=float(k), sp=[0.5], pv=[x], mv=[0.005], u_mpc=[0.005], x=[x])
    expected = math.sqrt((1.0 + (1.0 + A) ** 2 + A**2) / 6.0) * sigma
    assert ada.noise_std()[0] == pytest.approx(expected, rel=0.1)
    d = ada.propose(3000.0)
    assert d is not None
    # Kp limit budget U / (sqrt 2 sigma) = 0.0035 / 2.83e-3 = 1.24 >> the model-based 0.111: no limit.
    assert math.isinf(ada.noise_gain_limit[0])
    # A budget of 1e-4 binds: 1e-4 / (sqrt 2 x 2e-3) = 0.035 < 0.111 / 1.2.
    tight = PidGainAdapter(MODEL, FIXED, AdaptationConfig(noise_move_budget=1e-4))
    for k in range(3000):
        x = 0.5 + sigma * rng.normal()
        tight.observe(scan=k, t_s=float(k), sp=[0.5], pv=[x], mv=[0.005], u_mpc=[0.005], x=[x])
    for t in range(10, 400, 10):
        tight.propose(float(3000 + t))
    limit = tight.noise_gain_limit[0]
    assert limit == pytest.approx(1e-4 / (math.sqrt(2.0) * tight.noise_std()[0]), rel=0.25)
    # The applied loop gain rises to the limit (from the fixed 0.02) and never exceeds it.
    assert 0.9 * limit <= tight.applied.kp[0, 0] <= limit * (1.0 + 1e-9)
