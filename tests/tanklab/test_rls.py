"""Tests of tanklab.rls.ExpForgettingRls: oracle, convergence, and every guard."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tanklab.rls import ExpForgettingRls


def bare_rls_step(
    theta: np.ndarray, P: np.ndarray, x: np.ndarray, y: float, lam: float
) -> tuple[np.ndarray, np.ndarray]:
    """The unguarded recursion of digest 2.3, written independently of the module."""
    Px = P @ x
    K = Px / (lam + x @ Px)
    theta = theta + K * (y - x @ theta)
    P = (P - np.outer(K, Px)) / lam
    return theta, P


# --------------------------------------------------------------------------- oracle
def test_two_updates_match_hand_computed_oracle() -> None:
    # lambda = 1/2, P0 = I, theta0 = 0; cap raised so it does not bind (trace reaches 8/3).
    rls = ExpForgettingRls(2, forgetting=0.5, p0=1.0, trace_cap=10.0)
    # Update 1: x = [1, 0], y = 2.
    #   P x = [1, 0], x'P x = 1, denominator = 1/2 + 1 = 3/2, K = [2/3, 0]
    #   e = 2 - 0 = 2, theta = [4/3, 0]
    #   P = (I - K x'P) / (1/2) = ([[1, 0], [0, 1]] - [[2/3, 0], [0, 0]]) * 2 = [[2/3, 0], [0, 2]]
    assert rls.update([1.0, 0.0], 2.0)
    np.testing.assert_allclose(rls.theta, [4 / 3, 0.0], rtol=1e-14)
    np.testing.assert_allclose(rls.covariance, [[2 / 3, 0.0], [0.0, 2.0]], rtol=1e-14)
    assert rls.last_error == pytest.approx(2.0)
    # Update 2: x = [1, 1], y = 3.
    #   P x = [2/3, 2], x'P x = 8/3, denominator = 1/2 + 8/3 = 19/6
    #   K = [2/3, 2] * 6/19 = [4/19, 12/19]
    #   e = 3 - x'theta = 3 - 4/3 = 5/3
    #   theta = [4/3 + (4/19)(5/3), (12/19)(5/3)] = [4/3 + 20/57, 20/19] = [32/19, 20/19]
    #   K (P x)' = [[8/57, 8/19], [8/19, 24/19]]
    #   P - K (P x)' = [[2/3 - 8/57, -8/19], [-8/19, 2 - 24/19]] = [[10/19, -8/19], [-8/19, 14/19]]
    #   P = that * 2 = [[20/19, -16/19], [-16/19, 28/19]], trace 48/19
    assert rls.update([1.0, 1.0], 3.0)
    np.testing.assert_allclose(rls.theta, [32 / 19, 20 / 19], rtol=1e-14)
    np.testing.assert_allclose(rls.covariance, [[20 / 19, -16 / 19], [-16 / 19, 28 / 19]], rtol=1e-13)
    assert rls.trace == pytest.approx(48 / 19, rel=1e-14)
    assert rls.last_error == pytest.approx(5 / 3)
    assert rls.n_updates == 2
    assert rls.n_skipped == 0


def test_trace_cap_scales_covariance_when_it_binds() -> None:
    # Same first update with the default cap n * p0 = 2: trace would be 2/3 + 2 = 8/3,
    # so P is scaled by 2 / (8/3) = 3/4: [[1/2, 0], [0, 3/2]]; theta is not affected by the cap.
    rls = ExpForgettingRls(2, forgetting=0.5, p0=1.0)
    assert rls.trace_cap == 2.0
    rls.update([1.0, 0.0], 2.0)
    np.testing.assert_allclose(rls.covariance, [[0.5, 0.0], [0.0, 1.5]], rtol=1e-14)
    np.testing.assert_allclose(rls.theta, [4 / 3, 0.0], rtol=1e-14)


# --------------------------------------------------------------------------- convergence
@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 5),
    memory=st.floats(20.0, 1e6),
)
def test_converges_to_true_parameters_on_noiseless_data(seed: int, n: int, memory: float) -> None:
    rng = np.random.default_rng(seed)
    theta_true = rng.uniform(-10.0, 10.0, size=n)
    lam = ExpForgettingRls.forgetting_from_memory(1.0, memory)
    rls = ExpForgettingRls(n, forgetting=lam, p0=1e6, excitation_threshold=1e-6)
    for _ in range(300):
        x = rng.standard_normal(n)  # well excited: i.i.d. unit-variance regressors
        rls.update(x, float(x @ theta_true))
    np.testing.assert_allclose(rls.theta, theta_true, rtol=1e-6, atol=1e-6)
    P = rls.covariance
    np.testing.assert_array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() > 0.0
    assert rls.trace <= rls.trace_cap


# --------------------------------------------------------------------------- validation
@pytest.mark.parametrize("bad", [0.0, -0.1, 1.0 + 1e-12, 2.0, math.nan, math.inf, -math.inf])
def test_forgetting_outside_unit_interval_is_a_value_error(bad: float) -> None:
    with pytest.raises(ValueError, match=r"forgetting must be in \(0, 1\]"):
        ExpForgettingRls(2, forgetting=bad)


@pytest.mark.parametrize("bad", ["0.98", True, None, [0.98]])
def test_forgetting_of_wrong_type_is_a_type_error(bad: object) -> None:
    with pytest.raises(TypeError, match="forgetting"):
        ExpForgettingRls(2, forgetting=bad)  # type: ignore[arg-type]


def test_forgetting_from_memory() -> None:
    assert ExpForgettingRls.forgetting_from_memory(1.0, 60.0) == pytest.approx(math.exp(-1 / 60))
    assert ExpForgettingRls.forgetting_from_memory(0.05, 30.0) == pytest.approx(math.exp(-0.05 / 30))
    assert ExpForgettingRls.forgetting_from_memory(1.0, math.inf) == 1.0
    for ts, mem in [(0.0, 60.0), (-1.0, 60.0), (math.inf, 60.0), (1.0, 0.0), (1.0, -5.0), (1.0, math.nan)]:
        with pytest.raises(ValueError, match=r"ts_s|memory_s"):
            ExpForgettingRls.forgetting_from_memory(ts, mem)


def test_constructor_validation() -> None:
    with pytest.raises(ValueError, match="n_params"):
        ExpForgettingRls(0, forgetting=0.99)
    with pytest.raises(TypeError, match="n_params"):
        ExpForgettingRls(2.0, forgetting=0.99)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="p0"):
        ExpForgettingRls(2, forgetting=0.99, p0=0.0)
    with pytest.raises(ValueError, match="trace_cap"):
        ExpForgettingRls(2, forgetting=0.99, p0=10.0, trace_cap=19.0)
    with pytest.raises(ValueError, match="trace_cap"):
        ExpForgettingRls(2, forgetting=0.99, trace_cap=-1.0)
    with pytest.raises(ValueError, match="excitation_threshold"):
        ExpForgettingRls(2, forgetting=0.99, excitation_threshold=-1.0)
    with pytest.raises(ValueError, match="lower must be <= upper"):
        ExpForgettingRls(2, forgetting=0.99, lower=[0.0, 1.0], upper=[1.0, 0.0])
    with pytest.raises(ValueError, match="lower"):
        ExpForgettingRls(2, forgetting=0.99, lower=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="theta0 must lie inside"):
        ExpForgettingRls(2, forgetting=0.99, theta0=[2.0, 0.0], upper=1.0)
    with pytest.raises(ValueError, match="theta0"):
        ExpForgettingRls(2, forgetting=0.99, theta0=[math.nan, 0.0])
    with pytest.raises(ValueError, match="excitation"):
        ExpForgettingRls(2, forgetting=0.99, excitation="energy")  # type: ignore[arg-type]
    rls = ExpForgettingRls(2, forgetting=0.99)
    with pytest.raises(ValueError, match=r"x must have shape \(2,\)"):
        rls.update([1.0, 2.0, 3.0], 1.0)


# --------------------------------------------------------------------------- boundedness
LAM_50S = ExpForgettingRls.forgetting_from_memory(1.0, 50.0)  # 0.9802 per 1 s sample


def test_unguarded_recursion_blows_up_under_a_constant_regressor() -> None:
    # The digest's failure: a regressor that stops moving leaves one direction unexcited and
    # P grows like lambda**-k along it. Bare recursion, p0 = 1e3, lambda = exp(-1/50):
    x = np.array([1.0, 1.0])
    theta, P = np.zeros(2), 1e3 * np.eye(2)
    lost_definiteness_at = None
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(40_000):
            theta, P = bare_rls_step(theta, P, x, 1.0, LAM_50S)
            if k == 150:
                assert np.trace(P) > 2e4  # measured 2.05e4 after 150 samples
            if k == 2000:
                assert np.trace(P) > 1e20  # measured 2.4e20
            if lost_definiteness_at is None and np.linalg.eigvals(P).real.min() < 0.0:
                lost_definiteness_at = k
            if not np.isfinite(P).all():
                break
    # Indefinite from rounding near trace 1e15 (measured: sample 1409), overflow near 35,000.
    assert lost_definiteness_at is not None and lost_definiteness_at < 2000
    assert not np.isfinite(P).all()
    assert 30_000 < k < 40_000


def test_class_with_guards_disabled_blows_up_but_never_stores_an_overflow() -> None:
    rls = ExpForgettingRls(2, forgetting=LAM_50S, p0=1e3, trace_cap=math.inf, excitation_threshold=0.0)
    for _ in range(2001):
        rls.update([1.0, 1.0], 1.0)
    assert rls.trace > 1e20  # same growth as the bare recursion
    assert rls.n_skipped == 0


def test_guarded_covariance_stays_bounded_symmetric_and_positive_definite() -> None:
    rls = ExpForgettingRls(2, forgetting=LAM_50S, p0=1e3)  # cap = 2e3, no dead zone
    for _ in range(3000):
        assert rls.update([1.0, 1.0], 1.0)
        P = rls.covariance
        assert rls.trace <= rls.trace_cap * (1 + 1e-12)
        np.testing.assert_array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > 0.0
    # The estimate still fits the only excited direction: x'theta = 1.
    assert rls.predict([1.0, 1.0]) == pytest.approx(1.0)


def test_collinear_regressors_with_a_slowly_varying_scale_stay_bounded() -> None:
    # x(k) = s(k) * [1, 2, -1]: collinear, excited in one direction only, always moving.
    rls = ExpForgettingRls(3, forgetting=0.95, p0=10.0)
    d = np.array([1.0, 2.0, -1.0])
    for k in range(2000):
        rls.update((1.0 + 0.5 * math.sin(0.01 * k)) * d, 3.0)
    assert rls.trace <= 30.0 * (1 + 1e-12)
    assert np.linalg.eigvalsh(rls.covariance).min() > 0.0


# --------------------------------------------------------------------------- dead zone
def test_no_regressor_change_means_no_update_and_no_covariance_inflation() -> None:
    rls = ExpForgettingRls(2, forgetting=0.9, p0=5.0, theta0=[1.0, -1.0], excitation_threshold=0.1)
    P0 = rls.covariance
    # First sample only sets the reference; the same regressor again is not excited.
    for _ in range(500):
        assert not rls.update([3.0, 4.0], 10.0)
    assert rls.n_updates == 0
    assert rls.n_skipped_unexcited == 500
    np.testing.assert_array_equal(rls.theta, [1.0, -1.0])
    np.testing.assert_array_equal(rls.covariance, P0)  # not divided by lambda 500 times
    # A change below the threshold is still skipped, one above it is applied.
    assert not rls.update([3.05, 4.05], 10.0)  # ||change|| = 0.0707
    assert rls.update([3.2, 4.0], 10.0)  # ||change|| = 0.2
    assert rls.n_updates == 1
    # The reference is now the last applied regressor.
    assert rls.excitation_of([3.2, 4.0]) == 0.0
    assert not rls.update([3.2, 4.0], 10.0)


def test_norm_measure_skips_small_regressors() -> None:
    rls = ExpForgettingRls(2, forgetting=0.9, excitation_threshold=0.5, excitation="norm")
    assert not rls.update([0.0, 0.0], 1.0)
    assert not rls.update([0.3, 0.3], 1.0)
    assert rls.update([1.0, 0.0], 1.0)
    assert rls.update([1.0, 0.0], 1.0)  # the norm measure does not look at the change


def test_zero_threshold_disables_the_dead_zone() -> None:
    rls = ExpForgettingRls(2, forgetting=0.9)
    assert rls.update([1.0, 1.0], 1.0)
    assert rls.update([1.0, 1.0], 1.0)
    assert rls.n_skipped == 0


# --------------------------------------------------------------------------- projection
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_projection_keeps_estimates_inside_bounds(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lower = np.array([0.5, 0.0, -1.0])
    upper = np.array([2.0, math.inf, 1.0])
    theta_true = np.array([-3.0, -2.0, 5.0])  # outside on every side that has a bound
    rls = ExpForgettingRls(3, forgetting=0.98, p0=100.0, theta0=[1.0, 1.0, 0.0], lower=lower, upper=upper)
    for _ in range(200):
        x = rng.standard_normal(3)
        rls.update(x, float(x @ theta_true + 0.1 * rng.standard_normal()))
        th = rls.theta
        assert (th >= lower).all()
        assert (th <= upper).all()


def test_projection_is_inactive_inside_bounds() -> None:
    rng = np.random.default_rng(7)
    theta_true = np.array([1.5, 0.2])
    rls = ExpForgettingRls(2, forgetting=1.0, p0=1e6, theta0=[1.0, 0.0], lower=[0.0, 0.0], upper=[10.0, 1.0])
    for _ in range(100):
        x = rng.standard_normal(2)
        rls.update(x, float(x @ theta_true))
    np.testing.assert_allclose(rls.theta, theta_true, rtol=1e-6)


# --------------------------------------------------------------------------- non-finite input
@pytest.mark.parametrize(
    ("x", "y"),
    [([math.nan, 1.0], 1.0), ([1.0, math.inf], 1.0), ([1.0, 1.0], math.nan), ([1.0, 1.0], -math.inf)],
)
def test_non_finite_input_is_skipped_counted_and_leaves_state_untouched(x: list[float], y: float) -> None:
    clean = ExpForgettingRls(2, forgetting=0.9, p0=10.0, excitation_threshold=0.01)
    dirty = ExpForgettingRls(2, forgetting=0.9, p0=10.0, excitation_threshold=0.01)
    data = [([1.0, 0.0], 1.0), ([0.0, 1.0], 2.0), ([1.0, 1.0], 2.5), ([2.0, -1.0], 0.5)]
    for i, (xi, yi) in enumerate(data):
        clean.update(xi, yi)
        dirty.update(xi, yi)
        if i == 1:
            theta, P = dirty.theta, dirty.covariance
            assert not dirty.update(x, y)
            np.testing.assert_array_equal(dirty.theta, theta)
            np.testing.assert_array_equal(dirty.covariance, P)
    np.testing.assert_array_equal(dirty.theta, clean.theta)
    np.testing.assert_array_equal(dirty.covariance, clean.covariance)
    assert dirty.n_skipped_nonfinite == 1
    assert dirty.n_skipped == clean.n_skipped + 1
    assert dirty.n_updates == clean.n_updates


# --------------------------------------------------------------------------- one-sided information
def test_constrain_matches_hand_computed_projection_and_leaves_covariance_alone() -> None:
    rls = ExpForgettingRls(2, forgetting=0.5, p0=1.0, trace_cap=10.0)
    rls.update([1.0, 0.0], 2.0)  # as in the oracle: theta = [4/3, 0], P = [[2/3, 0], [0, 2]]
    P_before = rls.covariance
    # x = [1, 1], x' theta >= 3 is violated (4/3): gap 5/3, P x = [2/3, 2], x' P x = 8/3,
    # theta += [2/3, 2] * (5/3) / (8/3) = [5/12, 5/4]  ->  theta = [7/4, 5/4], x' theta = 3.
    assert rls.constrain([1.0, 1.0], 3.0, "ge")
    np.testing.assert_allclose(rls.theta, [7 / 4, 5 / 4], rtol=1e-14)
    np.testing.assert_array_equal(rls.covariance, P_before)  # an inequality is not a measurement
    assert (rls.n_updates, rls.n_constrained) == (1, 1)
    # Satisfied inequalities change nothing, on either side.
    assert not rls.constrain([1.0, 1.0], 2.5, "ge")
    assert not rls.constrain([1.0, 1.0], 3.5, "le")
    np.testing.assert_allclose(rls.theta, [7 / 4, 5 / 4], rtol=1e-14)
    # "le": x = [1, 0], x' theta <= 1 violated (7/4): P x = [2/3, 0], theta_1 -> 1, theta_2 kept.
    assert rls.constrain([1.0, 0.0], 1.0, "le")
    np.testing.assert_allclose(rls.theta, [1.0, 5 / 4], rtol=1e-14)
    assert rls.n_constrained == 2 and rls.n_updates == 1


def test_constrain_moves_least_along_directions_the_covariance_is_sure_of() -> None:
    # After many updates along [1, 0] the first parameter is well known; a violated inequality on
    # [1, 1] is then satisfied almost entirely by moving the second one.
    rls = ExpForgettingRls(2, forgetting=1.0, p0=1e3)
    for k in range(200):
        rls.update([1.0, 0.0] if k % 2 else [1.0 + 1e-3, 0.0], 2.0)
    theta1 = rls.theta[0]
    assert rls.constrain([1.0, 1.0], theta1 + 5.0, "ge")
    assert abs(rls.theta[0] - theta1) < 1e-3
    assert rls.theta[1] == pytest.approx(5.0, rel=1e-3)


def test_constrain_respects_the_box_and_validates_its_input() -> None:
    rls = ExpForgettingRls(2, forgetting=1.0, p0=1.0, upper=[math.inf, 1.0])
    # Projection onto x' theta = 4 gives [2, 2]; the box clips the second to 1 (left short: 3).
    assert rls.constrain([1.0, 1.0], 4.0, "ge")
    np.testing.assert_array_equal(rls.theta, [2.0, 1.0])
    before = rls.theta
    assert not rls.constrain([math.nan, 1.0], 4.0, "ge")
    assert not rls.constrain([1.0, 1.0], math.inf, "ge")
    assert rls.n_skipped_nonfinite == 2
    assert not rls.constrain([0.0, 0.0], 1.0, "ge")  # no direction to move in
    np.testing.assert_array_equal(rls.theta, before)
    with pytest.raises(ValueError, match="sense"):
        rls.constrain([1.0, 1.0], 1.0, "gt")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="shape"):
        rls.constrain([1.0], 1.0, "ge")
    rls.reset()
    assert rls.n_constrained == 0


# --------------------------------------------------------------------------- API details
def test_properties_are_copies_and_reset_restores_the_prior() -> None:
    rls = ExpForgettingRls(2, forgetting=0.9, p0=2.0, theta0=[0.5, 0.5], lower=0.0)
    rls.theta[0] = 99.0
    rls.covariance[0, 0] = 99.0
    np.testing.assert_array_equal(rls.theta, [0.5, 0.5])
    assert rls.trace == 4.0
    rls.update([1.0, 0.0], 3.0)
    rls.update([math.nan, 0.0], 3.0)
    assert rls.n_updates == 1 and rls.n_skipped == 1
    rls.reset()
    np.testing.assert_array_equal(rls.theta, [0.5, 0.5])
    np.testing.assert_array_equal(rls.covariance, 2.0 * np.eye(2))
    assert (rls.n_updates, rls.n_skipped) == (0, 0)
    assert math.isnan(rls.last_error)
    rls.reset(theta0=[1.0, 2.0], p0=1.0)
    np.testing.assert_array_equal(rls.theta, [1.0, 2.0])
    assert rls.trace == 2.0
    with pytest.raises(ValueError, match="theta0 must lie inside"):
        rls.reset(theta0=[-1.0, 0.0])
    with pytest.raises(ValueError, match="trace_cap"):
        rls.reset(p0=3.0)  # 2 * 3 > cap 4


def test_accepts_numpy_scalars_and_zero_dim_arrays_as_target() -> None:
    rls = ExpForgettingRls(1, forgetting=1.0, p0=1.0)
    assert rls.update(np.array([2.0]), np.float64(4.0))
    assert rls.update(np.array([1.0]), np.array(2.0))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="y"):
        rls.update([1.0], "2.0")  # type: ignore[arg-type]
