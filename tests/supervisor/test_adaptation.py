"""Tests of supervisor.adaptation: gain fitting, closed-loop matrix, and every admissibility guard.

The fitting and proposal tests here pin the former estimator (``LEGACY``: exponentially
forgetting RLS from the fixed gains, straight line in gain space, Kd free, no noise limit): its
properties (exact recovery of a teacher, one-sided projections, the guards) stay tested and the
option stays available. The default estimator (prior at the model-based tuning, directional
forgetting) is tested in ``test_adaptation_prior.py`` and judged by outcome in
``test_adaptation_outcome.py``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm

from supervisor.adaptation import (
    AdaptationConfig,
    GainBox,
    LoopModel,
    PidGainAdapter,
    PidGains,
    RejectReason,
    SampleStatus,
    closed_loop_matrix,
    closed_loop_spectral_radius,
    input_bound_violation,
    simulate_pid_inputs,
)

# --------------------------------------------------------------------------- the three-tank model
# Digest 1.1, first row (MPC-based PID paper, simulation), linearised at h = (0.4, 0.2, 0.3).
AT, AP, G = 0.0154, 5e-5, 9.81
MU13 = MU32 = 0.5
MU20 = 0.675
H_OP = np.array([0.4, 0.2, 0.3])
QMAX = 1.2e-4
TS = 1.0


def three_tank_model() -> LoopModel:
    h1, h2, h3 = H_OP
    k = AP * math.sqrt(2 * G) / (2 * AT)
    a13 = MU13 * k / math.sqrt(h1 - h3)
    a32 = MU32 * k / math.sqrt(h3 - h2)
    a20 = MU20 * k / math.sqrt(h2)
    Ac = np.array([[-a13, 0.0, a13], [0.0, -(a32 + a20), a32], [a13, a32, -(a13 + a32)]])
    Bc = np.array([[1 / AT, 0.0], [0.0, 1 / AT], [0.0, 0.0]])
    # ZOH: expm([[Ac, Bc], [0, 0]] Ts) = [[Ad, Bd], [0, I]]
    M = np.zeros((5, 5))
    M[:3, :3], M[:3, 3:] = Ac, Bc
    E = expm(M * TS)
    # Equilibrium flows holding (0.4, 0.2): Q1 = q13, Q2 = q20 - q32 (digest: 3.502e-5, 3.184e-5).
    q13 = MU13 * AP * math.sqrt(2 * G * (h1 - h3))
    q32 = MU32 * AP * math.sqrt(2 * G * (h3 - h2))
    q20 = MU20 * AP * math.sqrt(2 * G * h2)
    u_op = np.array([q13, q20 - q32])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # loops: h1 -> pump 1, h2 -> pump 2
    return LoopModel(E[:3, :3], E[:3, 3:], C, TS, np.zeros(2), np.full(2, QMAX), x_op=H_OP, u_op=u_op)


MODEL = three_tank_model()


def Legacy(**kwargs: Any) -> AdaptationConfig:
    """The former estimator and proposer (module doc), with ``kwargs`` on top."""
    base: dict[str, Any] = {
        "estimator": "rls",
        "path": "linear",
        "kd_keep_sign": False,
        "noise_move_budget": None,
    }
    return AdaptationConfig(**{**base, **kwargs})


LEGACY = Legacy()
# The paper's fixed gains (digest 2.1): PID I on h1 / pump 1, PID II on h2 / pump 2.
PAPER = PidGains.diagonal([4.29e-4, 10.83e-4], [5.32e-6, 3.94e-5], [-1.42e-4, -13.51e-4])


def test_model_matches_the_digest() -> None:
    np.testing.assert_allclose(MODEL.u_op, [3.502e-5, 3.184e-5], rtol=1e-3)
    assert MODEL.B[1, 1] == pytest.approx(64.22, abs=0.005)  # digest: ZOH gives 64.22
    slow = -1.0 / np.log(np.abs(np.linalg.eigvals(MODEL.A)))
    np.testing.assert_allclose(np.sort(slow), [27.2, 57.5, 455.6], rtol=2e-3)  # modes 27, 58, 456 s


# --------------------------------------------------------------------------- readings helpers
def equilibrium_readings(adapter: PidGainAdapter, n: int = 3, scan0: int = 0) -> None:
    for k in range(scan0, scan0 + n):
        adapter.observe(scan=k, t_s=k * TS, sp=H_OP[:2], pv=H_OP[:2], mv=MODEL.u_op, u_mpc=MODEL.u_op, x=H_OP)


def teacher_readings(
    teacher: PidGains,
    n: int,
    *,
    seed: int = 0,
    e_std: float = 0.002,
    start: int = 0,
    mv_mean: float = 6e-5,
) -> Iterator[dict[str, Any]]:
    """Readings whose MPC input is exactly the teacher PID's move from the applied MV, clamped.

    e ~ N(0, e_std^2) i.i.d. per loop (rich excitation); the applied MV wanders around ``mv_mean``
    (whatever the PLC did); u_MPC(k) = MV(k-1) + sum_j [Kp De + Ki Ts e + (Kd/Ts) D2e], clamped to
    [0, Qmax] like a real MPC's input (never binding at the default mid-range MV).
    """
    rng = np.random.default_rng(seed)
    e = e_std * rng.standard_normal((n, MODEL.n_loops))
    mv = mv_mean + 2e-6 * rng.standard_normal((n, MODEL.n_u))
    sp = H_OP[:2]
    for k in range(n):
        if k >= 2:
            de = e[k] - e[k - 1]
            d2e = e[k] - 2 * e[k - 1] + e[k - 2]
            u_mpc = mv[k - 1] + teacher.kp @ de + teacher.ki @ e[k] * TS + teacher.kd @ d2e / TS
            u_mpc = np.clip(u_mpc, 0.0, QMAX)
        else:
            u_mpc = mv[k]
        pv = sp - e[k]
        yield {
            "scan": start + k,
            "t_s": (start + k) * TS,
            "sp": sp,
            "pv": pv,
            "mv": mv[k],
            "u_mpc": u_mpc,
            "x": np.array([pv[0], pv[1], H_OP[2]]),
        }


def rho(g: PidGains) -> float:
    return closed_loop_spectral_radius(MODEL.A, MODEL.B, MODEL.C, g.kp, g.ki, g.kd, TS)


def rel_err(est: PidGains, true: PidGains) -> float:
    t, g = true.stacked(), est.stacked()
    nz = t != 0
    return float(np.max(np.abs(g[nz] - t[nz]) / np.abs(t[nz])))


# --------------------------------------------------------------------------- gain recovery
def test_recovers_known_diagonal_pid_gains_from_velocity_form_data() -> None:
    teacher = PidGains.diagonal([5.0e-4, 9.0e-4], [6.0e-6, 3.5e-5], [-1.2e-4, -12.0e-4])
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    statuses = [adapter.observe(**r) for r in teacher_readings(teacher, 1200)]
    assert statuses[:2] == [SampleStatus.WARMUP, SampleStatus.WARMUP]
    assert set(statuses[2:]) == {SampleStatus.FORMED}
    est = adapter.estimate()
    assert rel_err(est, teacher) < 1e-6
    # Off-diagonal gains are not fitted in diagonal mode: they stay at the applied values (0).
    assert est.kp[0, 1] == est.kp[1, 0] == 0.0
    diag = adapter.diagnostics()
    assert diag.samples_formed == 1198
    for i, p in enumerate(diag.pumps):
        assert p.samples_used == 1197  # the first formed sample only sets the excitation reference
        assert p.dropped_saturated == 0
        assert p.ready
        np.testing.assert_allclose(p.theta, [teacher.kp[i, i], teacher.ki[i, i], teacher.kd[i, i]], rtol=1e-6)
        assert 0 < p.covariance_trace <= 3 * adapter.config.p0


def test_recovers_known_full_mimo_pid_gains() -> None:
    teacher = PidGains(
        np.array([[5.0e-4, 1.0e-5], [-2.0e-5, 9.0e-4]]),
        np.array([[6.0e-6, 1.0e-7], [2.0e-7, 3.5e-5]]),
        np.array([[-1.2e-4, 3.0e-6], [-4.0e-6, -12.0e-4]]),
    )
    adapter = PidGainAdapter(MODEL, PAPER, Legacy(full_mimo=True))
    for r in teacher_readings(teacher, 1200, seed=3):
        adapter.observe(**r)
    assert rel_err(adapter.estimate(), teacher) < 1e-6
    assert all(p.theta.shape == (6,) for p in adapter.diagnostics().pumps)


def test_paper_regressor_would_be_rank_deficient_and_ours_is_not() -> None:
    # The paper's third slot De/Ts makes columns 1 and 3 proportional; D2e/Ts does not.
    rng = np.random.default_rng(0)
    e = rng.standard_normal(50)
    de = e[2:] - e[1:-1]
    d2e = e[2:] - 2 * e[1:-1] + e[:-2]
    paper = np.column_stack([de, TS * e[2:], de / TS])
    ours = np.column_stack([de, TS * e[2:], d2e / TS])
    assert np.linalg.matrix_rank(paper) == 2
    assert np.linalg.matrix_rank(ours) == 3


# --------------------------------------------------------------------------- closed-loop matrix
def test_spectral_radius_scalar_p_only() -> None:
    # x(k+1) = a x + b u, e = -x, velocity P: u(k) = u(k-1) + Kp (e(k) - e(k-1)).
    # For z != 1, (1 - 1/z) u = Kp (1 - 1/z) e  =>  u = Kp e, loop pole z = a - b Kp.
    # The velocity form also conserves u - Kp e (the held bias): an eigenvalue at exactly 1.
    # State [x, u(k-1), e(k-1), e(k-2)]: the e(k-1) delay and the unused e(k-2) give two zeros.
    # Characteristic polynomial: z^2 (z - 1) (z - (a - b Kp)).
    a, b, kp = 0.9, 0.5, 0.4
    M = closed_loop_matrix([[a]], [[b]], [[1.0]], [[kp]], [[0.0]], [[0.0]], 1.0)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(M).real), [0.0, 0.0, a - b * kp, 1.0], atol=1e-7)
    assert closed_loop_spectral_radius([[a]], [[b]], [[1.0]], [[kp]], [[0.0]], [[0.0]], 1.0) == pytest.approx(
        1.0, abs=1e-12
    )


def test_spectral_radius_scalar_pi() -> None:
    # PI: (1 - 1/z) u = (Kp (1 - 1/z) + Ki Ts) e  =>  (z - 1) u = ((Kp + Ki Ts) z - Kp) e.
    # With e = -b/(z - a) u:  (z - 1)(z - a) + b ((Kp + Ki Ts) z - Kp) = 0, i.e.
    #   z^2 - (1 + a - b (Kp + Ki Ts)) z + (a - b Kp) = 0,   times z^2 for the two delay states.
    a, b, kp, ki, ts = 0.95, 0.2, 1.5, 0.3, 0.5
    M = closed_loop_matrix([[a]], [[b]], [[1.0]], [[kp]], [[ki]], [[0.0]], ts)
    quad = np.roots([1.0, -(1 + a - b * (kp + ki * ts)), a - b * kp])
    expected = np.concatenate([quad, [0.0, 0.0]])
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(M)), np.sort_complex(expected), atol=1e-7)
    rho = closed_loop_spectral_radius([[a]], [[b]], [[1.0]], [[kp]], [[ki]], [[0.0]], ts)
    assert rho == pytest.approx(np.abs(quad).max(), rel=1e-12)
    assert rho < 1.0


@settings(max_examples=60, deadline=None)
@given(
    a=st.floats(-1.2, 1.2),
    b=st.floats(-2.0, 2.0),
    kp=st.floats(-2.0, 2.0),
    ki=st.floats(-2.0, 2.0),
    kd=st.floats(-2.0, 2.0),
    ts=st.floats(0.05, 5.0),
)
def test_scalar_pid_characteristic_polynomial(
    a: float, b: float, kp: float, ki: float, kd: float, ts: float
) -> None:
    # Full PID: (z - 1) u = (G0 z^2 - G1 z + G2)/z e, e = -b/(z - a) u, with
    # G0 = Kp + Ki Ts + Kd/Ts, G1 = Kp + 2 Kd/Ts, G2 = Kd/Ts. Clearing denominators and adding
    # the factor z of the fourth state:
    #   z [ z (z - 1)(z - a) + b (G0 z^2 - G1 z + G2) ]
    #   = z^4 + (b G0 - 1 - a) z^3 + (a - b G1) z^2 + b G2 z
    g0, g1, g2 = kp + ki * ts + kd / ts, kp + 2 * kd / ts, kd / ts
    M = closed_loop_matrix([[a]], [[b]], [[1.0]], [[kp]], [[ki]], [[kd]], ts)
    coeffs = [1.0, b * g0 - 1 - a, a - b * g1, b * g2, 0.0]
    # Compare det(zI - M) with the polynomial at a few points (robust where eigenvalues repeat).
    for z in (0.3 + 0.7j, 1.5, -0.8, 2.0j):
        det = np.linalg.det(z * np.eye(4) - M)
        poly = np.polyval(coeffs, z)
        scale = sum(abs(c) * abs(z) ** (4 - i) for i, c in enumerate(coeffs))
        assert abs(det - poly) <= 1e-12 * scale


def test_paper_gains_are_stable_on_the_three_tank_model() -> None:
    rho = closed_loop_spectral_radius(MODEL.A, MODEL.B, MODEL.C, PAPER.kp, PAPER.ki, PAPER.kd, TS)
    assert rho == pytest.approx(0.98799, abs=1e-5)  # measured 0.987987: below 1 and below 0.995
    assert rho < 0.995
    # Without integral action the velocity form keeps an eigenvalue at 1 (not asymptotically stable).
    rho_p = closed_loop_spectral_radius(MODEL.A, MODEL.B, MODEL.C, PAPER.kp, 0 * PAPER.ki, PAPER.kd, TS)
    assert rho_p == pytest.approx(1.0, abs=1e-9)
    # 100 x Kp: unstable (measured 5.88).
    rho_100 = closed_loop_spectral_radius(MODEL.A, MODEL.B, MODEL.C, 100 * PAPER.kp, PAPER.ki, PAPER.kd, TS)
    assert rho_100 > 5.0


def test_closed_loop_matrix_validation() -> None:
    with pytest.raises(ValueError, match="Kp must have shape"):
        closed_loop_matrix(MODEL.A, MODEL.B, MODEL.C, np.ones((2, 3)), PAPER.ki, PAPER.kd, TS)
    with pytest.raises(ValueError, match="A must be square"):
        closed_loop_matrix(np.ones((2, 3)), MODEL.B, MODEL.C, PAPER.kp, PAPER.ki, PAPER.kd, TS)
    with pytest.raises(ValueError, match="Ki must be finite"):
        closed_loop_matrix(MODEL.A, MODEL.B, MODEL.C, PAPER.kp, PAPER.ki * math.nan, PAPER.kd, TS)
    with pytest.raises(ValueError, match="ts_s"):
        closed_loop_matrix(MODEL.A, MODEL.B, MODEL.C, PAPER.kp, PAPER.ki, PAPER.kd, 0.0)


def test_simulated_inputs_match_the_closed_loop_matrix() -> None:
    # With r = C x_op (zero deviation setpoint), simulate_pid_inputs is z(k+1) = M z(k).
    rng = np.random.default_rng(4)
    x0 = H_OP + 0.01 * rng.standard_normal(3)
    u0 = MODEL.u_op + 1e-6 * rng.standard_normal(2)
    e0, e_prev = 0.01 * rng.standard_normal(2), 0.01 * rng.standard_normal(2)
    u = simulate_pid_inputs(MODEL, PAPER, x0=x0, u0=u0, e0=e0, e_prev=e_prev, r=H_OP[:2], n_steps=50)
    M = closed_loop_matrix(MODEL.A, MODEL.B, MODEL.C, PAPER.kp, PAPER.ki, PAPER.kd, TS)
    # z(k+1) = [x(k+1), u(k), e(k), e(k-1)] with x(k+1) = A x(k) + B u(k) (deviations).
    z = np.concatenate([MODEL.A @ (x0 - H_OP) + MODEL.B @ (u0 - MODEL.u_op), u0 - MODEL.u_op, e0, e_prev])
    for s in range(50):
        z = M @ z
        np.testing.assert_allclose(u[s], z[3:5] + MODEL.u_op, rtol=1e-9, atol=1e-18)
    assert input_bound_violation(u, MODEL.u_min, MODEL.u_max) == 0.0
    assert input_bound_violation([[1.3e-4, 0.0]], MODEL.u_min, MODEL.u_max) == pytest.approx(0.1 / 1.2)


# --------------------------------------------------------------------------- guards
def setpoint_step_readings(adapter: PidGainAdapter, e1: float, u_mpc: Any = None) -> None:
    """Two scans at equilibrium, then a setpoint step e1 on loop 1 the PLC answered with G0 e1.

    ``u_mpc``: the MPC's input in the step scan (default: the operating point, not at a bound).
    """
    equilibrium_readings(adapter, n=2)
    g0 = PAPER.kp + PAPER.ki * TS + PAPER.kd / TS
    mv = MODEL.u_op + g0 @ np.array([e1, 0.0])
    u = MODEL.u_op if u_mpc is None else np.asarray(u_mpc, dtype=float)
    status = adapter.observe(
        scan=2, t_s=2.0, sp=H_OP[:2] + np.array([e1, 0.0]), pv=H_OP[:2], mv=mv, u_mpc=u, x=H_OP
    )
    assert status is SampleStatus.FORMED


def scaled(g: PidGains, i: int, j: int, *, kp: float = 1.0, ki: float = 1.0, kd: float = 1.0) -> PidGains:
    out = g.stacked().copy()
    out[:, i, j] *= [kp, ki, kd]
    return PidGains.from_stacked(out)


TIGHT_BOX = GainBox(
    lower=PidGains(np.zeros((2, 2)), np.diag([1e-7, 1e-6]), np.diag([-2e-4, -2e-3])),
    upper=PidGains(np.diag([5e-4, 1.2e-3]), np.diag([1e-5, 1e-4]), np.zeros((2, 2))),
)
WIDE_BOX = GainBox(
    lower=PidGains(-np.ones((2, 2)), -np.ones((2, 2)), -np.ones((2, 2))),
    upper=PidGains(np.ones((2, 2)), np.ones((2, 2)), np.ones((2, 2))),
)


def _nan_candidate() -> PidGains:
    g = PAPER.stacked().copy()
    g[0, 0, 0] = math.nan
    return PidGains.from_stacked(g)


GUARD_CASES: list[tuple[RejectReason, AdaptationConfig, PidGains, float | None]] = [
    # (reason, config, candidate, setpoint step for the horizon state; None: equilibrium)
    (RejectReason.NON_FINITE, Legacy(), _nan_candidate(), None),
    # Kp1 + 21 %: inside the 25 % rate limit, above the box's 5e-4.
    (RejectReason.OUTSIDE_BOX, Legacy(box=TIGHT_BOX), scaled(PAPER, 0, 0, kp=1.21), None),
    # Ki1 - 20 %: inside the rate limit and the default box, below Ki_min = 4.5e-6.
    (RejectReason.SIGN, Legacy(ki_min=(4.5e-6, 3e-5)), scaled(PAPER, 0, 0, ki=0.8), None),
    # Kp2 + 40 %: inside the default box (10 x), stable, beyond the 25 % rate limit.
    (RejectReason.RATE_LIMIT, Legacy(), scaled(PAPER, 1, 1, kp=1.4), None),
    # Kp 100 x everywhere: destabilising; box and rate limit opened so only stability speaks.
    (
        RejectReason.UNSTABLE,
        Legacy(box=WIDE_BOX, max_change_fraction=1e3),
        PidGains(100 * PAPER.kp, PAPER.ki, PAPER.kd),
        None,
    ),
    # Kd1 x 3 after a 0.15 m setpoint step: stable and in the box, but the derivative kick of
    # the next scans drives pump 1 to 1.44e-4 > Qmax (the applied gains peak at 1.0e-4).
    (
        RejectReason.INPUT_BOUNDS,
        Legacy(max_change_fraction=10.0),
        scaled(PAPER, 0, 0, kd=3.0),
        0.15,
    ),
]


@pytest.mark.parametrize(
    ("reason", "config", "candidate", "step"), GUARD_CASES, ids=[c[0].value for c in GUARD_CASES]
)
def test_each_guard_rejects_its_own_bad_candidate(
    reason: RejectReason, config: AdaptationConfig, candidate: PidGains, step: float | None
) -> None:
    adapter = PidGainAdapter(MODEL, PAPER, config)
    if step is None:
        equilibrium_readings(adapter)
    else:
        setpoint_step_readings(adapter, step)
    applied_before = adapter.applied
    decision = adapter.submit(candidate, t_s=42.0)
    assert not decision.accepted
    assert decision.reasons == (reason,), decision.detail
    assert decision.reason is reason
    assert decision.detail
    assert decision.t_s == 42.0
    assert adapter.applied is applied_before
    assert adapter.applied.allclose(PAPER, rtol=0.0)
    diag = adapter.diagnostics()
    assert (diag.accepted_pushes, diag.rejected_pushes) == (0, 1)
    assert diag.rejected_by_reason == {reason.value: 1}
    assert diag.last_reject_reason is reason
    if reason is RejectReason.UNSTABLE:
        assert decision.spectral_radius > 5.0  # measured 5.88


@pytest.mark.parametrize(
    ("u_mpc_1", "accepted"),
    [(QMAX, True), (QMAX * (1 - 0.004), True), (0.0, False), (None, False)],
    ids=["mpc_at_qmax", "mpc_within_band_of_qmax", "mpc_at_zero", "mpc_inside"],
)
def test_input_bound_guard_exempts_only_the_side_the_mpc_is_pinned_at(
    u_mpc_1: float | None, accepted: bool
) -> None:
    # The input_bounds case of the table: Kd1 x 3 after a 0.15 m step drives pump 1 to 1.44e-4 in
    # the linear simulation (Qmax 1.2e-4; the applied gains peak at 1.0e-4). When the MPC itself
    # sits at Qmax in that scan, the PID is being taught to saturate there: not counted. Pinned
    # at zero or inside its range, the excursion above Qmax still counts.
    adapter = PidGainAdapter(MODEL, PAPER, Legacy(max_change_fraction=10.0))
    u = None if u_mpc_1 is None else [u_mpc_1, MODEL.u_op[1]]
    setpoint_step_readings(adapter, 0.15, u_mpc=u)
    decision = adapter.evaluate(scaled(PAPER, 0, 0, kd=3.0))
    assert decision.accepted is accepted, decision.detail
    if accepted:
        assert decision.input_violation == 0.0
    else:
        assert decision.reasons == (RejectReason.INPUT_BOUNDS,)
        assert decision.input_violation == pytest.approx(0.2, abs=0.01)  # (1.44e-4 - Qmax) / Qmax


def test_input_bound_violation_allowances_are_per_side_and_per_input() -> None:
    # Excursions: pump 1 above by 0.1e-4, pump 2 below by 0.12e-4 and above by 0.3e-4.
    u = np.array([[1.3e-4, -0.12e-4], [1.0e-4, 1.5e-4]])
    lo, hi = np.zeros(2), np.full(2, QMAX)
    assert input_bound_violation(u, lo, hi) == pytest.approx(0.3 / 1.2)
    assert input_bound_violation(u, lo, hi, allow_above=[False, True]) == pytest.approx(0.12 / 1.2)
    assert input_bound_violation(u, lo, hi, allow_below=[False, True]) == pytest.approx(0.3 / 1.2)
    both = {"allow_above": [False, True], "allow_below": [False, True]}
    assert input_bound_violation(u, lo, hi, **both) == pytest.approx(0.1 / 1.2)
    assert input_bound_violation(u, lo, hi, allow_above=[True, True], allow_below=[False, True]) == 0.0


def test_admissible_candidate_is_accepted_and_becomes_applied() -> None:
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    equilibrium_readings(adapter)
    candidate = scaled(scaled(PAPER, 0, 0, kp=1.2, ki=1.1, kd=0.9), 1, 1, kp=0.85, ki=1.2)
    decision = adapter.submit(candidate, t_s=1.0)
    assert decision.accepted and decision.reasons == () and decision.reason is None
    assert decision.changed
    assert decision.spectral_radius < 0.995
    assert decision.input_violation == 0.0
    assert adapter.applied is candidate
    assert adapter.diagnostics().accepted_pushes == 1


def test_input_guard_compares_with_the_applied_gains_when_those_already_saturate() -> None:
    # A 0.3 m step: even the applied gains drive pump 1 beyond Qmax on the linear model.
    adapter = PidGainAdapter(MODEL, PAPER, Legacy(max_change_fraction=10.0))
    setpoint_step_readings(adapter, 0.3)
    same = adapter.evaluate(PAPER)
    assert same.accepted and same.input_violation > 0.0
    worse = adapter.evaluate(scaled(PAPER, 0, 0, kd=3.0))
    assert worse.reasons == (RejectReason.INPUT_BOUNDS,)
    milder = adapter.evaluate(scaled(PAPER, 0, 0, kd=0.5))
    assert milder.accepted and milder.input_violation < same.input_violation


def test_rate_limit_has_an_absolute_floor_for_gains_near_zero() -> None:
    # A cross gain at 0 may move by the floor: 0.25 * 0.1 * (largest Kp of that pump's row).
    adapter = PidGainAdapter(MODEL, PAPER, Legacy(full_mimo=True))
    equilibrium_readings(adapter)
    floor = 0.25 * 0.1 * 4.29e-4
    ok = PAPER.stacked().copy()
    ok[0, 0, 1] = 0.99 * floor
    assert adapter.evaluate(PidGains.from_stacked(ok)).accepted
    bad = PAPER.stacked().copy()
    bad[0, 0, 1] = 1.01 * floor
    assert adapter.evaluate(PidGains.from_stacked(bad)).reasons == (RejectReason.RATE_LIMIT,)


def test_diagonal_mode_pins_cross_gains_with_the_default_box() -> None:
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    equilibrium_readings(adapter)
    g = PAPER.stacked().copy()
    g[0, 0, 1] = 1e-9
    assert adapter.evaluate(PidGains.from_stacked(g)).reason is RejectReason.OUTSIDE_BOX


def test_negative_own_kp_is_a_sign_violation() -> None:
    cfg = Legacy(box=WIDE_BOX, max_change_fraction=1e3)
    adapter = PidGainAdapter(MODEL, PAPER, cfg)
    equilibrium_readings(adapter)
    decision = adapter.evaluate(scaled(PAPER, 1, 1, kp=-0.01))
    assert decision.reason is RejectReason.SIGN
    assert "Kp[1,1]" in decision.detail


# --------------------------------------------------------------------------- proposing
def test_no_push_before_enough_samples_or_before_min_time() -> None:
    teacher = scaled(PAPER, 0, 0, kp=1.1)
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    readings = list(teacher_readings(teacher, 40))
    # Two warm-up scans, then 2 formed samples: the first sets the excitation reference,
    # so each pump has 1 update < 3 parameters.
    for r in readings[:4]:
        adapter.observe(**r)
    assert [p.samples_used for p in adapter.diagnostics().pumps] == [1, 1]
    assert adapter.propose(100.0) is None
    # Enough samples by scan 5, but the minimum time (10 s from the first reading) has not passed.
    for r in readings[4:10]:
        adapter.observe(**r)
    assert all(p.ready for p in adapter.diagnostics().pumps)
    assert adapter.propose(9.0) is None
    decision = adapter.propose(10.0)
    assert decision is not None and decision.accepted
    # Push period: nothing before 10 s more.
    assert adapter.propose(15.0) is None
    assert adapter.propose(20.0) is not None


def test_proposals_move_toward_the_teacher_within_the_rate_limit_and_converge() -> None:
    teacher = scaled(scaled(PAPER, 0, 0, kp=1.6, ki=1.3, kd=0.8), 1, 1, kp=0.7, ki=1.2, kd=1.1)
    assert rho(teacher) < 0.995
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    decisions = []
    for r in teacher_readings(teacher, 1200, seed=5):
        adapter.observe(**r)
        before = adapter.applied
        d = adapter.propose(r["t_s"])
        if d is not None:
            decisions.append(d)
            assert d.accepted, d.detail
            step = np.abs(d.candidate.stacked() - before.stacked())
            assert (step <= 0.25 * np.abs(before.stacked()) * (1 + 1e-9) + 1e-30).all()
    assert len(decisions) == 119  # t = 10, 20, ..., 1190 s
    assert [d.t_s for d in decisions[:3]] == [10.0, 20.0, 30.0]
    assert rel_err(adapter.applied, teacher) < 1e-6
    assert not decisions[-1].changed or rel_err(decisions[-1].candidate, teacher) < 1e-6
    diag = adapter.diagnostics()
    assert diag.accepted_pushes == 119 and diag.rejected_pushes == 0


def test_each_proposal_moves_along_the_straight_line_to_the_estimate() -> None:
    # Per pump, candidate - applied = alpha (estimate - applied) with 0 < alpha <= 1, and when
    # alpha < 1 the gain that binds sits exactly at its rate limit (the others inside theirs).
    teacher = scaled(scaled(PAPER, 0, 0, kp=1.6, ki=1.3, kd=0.8), 1, 1, kp=0.7, ki=1.2, kd=1.1)
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    floor = 0.25 * 0.1 * np.abs(PAPER.stacked())  # the default floor (diagonal fixed gains)
    alphas = []
    for r in teacher_readings(teacher, 300, seed=5):
        adapter.observe(**r)
        before, est = adapter.applied.stacked(), adapter.estimate().stacked()
        d = adapter.propose(r["t_s"])
        if d is None:
            continue
        assert d.accepted, d.detail
        step, delta = d.candidate.stacked() - before, est - before
        limit = np.maximum(0.25 * np.abs(before), floor)
        for i in range(2):
            s_i, d_i, lim_i = step[:, i, i], delta[:, i, i], limit[:, i, i]
            if not d_i.any():
                continue
            alpha = float(s_i @ d_i / (d_i @ d_i))
            alphas.append(alpha)
            assert 0.0 < alpha <= 1.0 + 1e-12
            np.testing.assert_allclose(s_i, alpha * d_i, rtol=1e-9, atol=1e-22)
            np.testing.assert_array_less(np.abs(s_i), lim_i * (1 + 1e-9))
            if alpha < 1.0:
                assert float(np.max(np.abs(s_i) / lim_i)) == pytest.approx(1.0, rel=1e-9)
    assert min(alphas) < 1.0 and max(alphas) == pytest.approx(1.0)  # both regimes exercised


def test_rejected_proposals_keep_the_applied_gains_admissible() -> None:
    # Teacher with 3 x Kp on pump 1 and the same Ki: rho = 0.9959 > 0.995 (raising Kp alone moves
    # a pole toward the PI zero at Kp / (Kp + Ki Ts), near 1). The rate limit is opened so the
    # candidates follow the estimate; once it gets close to the teacher they must be refused.
    teacher = scaled(PAPER, 0, 0, kp=3.0)
    assert rho(teacher) == pytest.approx(0.99591, abs=1e-5)
    adapter = PidGainAdapter(MODEL, PAPER, Legacy(max_change_fraction=10.0))
    decisions = []
    for r in teacher_readings(teacher, 600, seed=2):
        adapter.observe(**r)
        applied_before = adapter.applied
        d = adapter.propose(r["t_s"])
        if d is None:
            continue
        decisions.append(d)
        if d.accepted:
            assert d.spectral_radius < 0.995
            assert adapter.applied is d.candidate
        else:
            assert d.reason is RejectReason.UNSTABLE, d.detail
            assert adapter.applied is applied_before
    rejected = [d for d in decisions if not d.accepted]
    assert len(rejected) >= 10
    diag = adapter.diagnostics()
    assert diag.rejected_pushes == len(rejected)
    assert diag.accepted_pushes == len(decisions) - len(rejected)
    assert diag.rejected_by_reason == {"unstable": len(rejected)}
    assert diag.last_reject_reason is RejectReason.UNSTABLE
    assert rho(adapter.applied) < 0.995


# --------------------------------------------------------------------------- data hygiene
def test_gap_in_scan_counter_drops_the_samples_spanning_it() -> None:
    teacher = PidGains.diagonal([5.0e-4, 9.0e-4], [6.0e-6, 3.5e-5], [-1.2e-4, -12.0e-4])
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    readings = list(teacher_readings(teacher, 1200, seed=9))
    statuses = {}
    for r in readings:
        if r["scan"] == 1190:
            continue  # this scan's read was lost
        statuses[r["scan"]] = adapter.observe(**r)
    assert statuses[1189] is SampleStatus.FORMED
    assert statuses[1191] is SampleStatus.GAP  # window 1189..1191 spans the gap
    assert statuses[1192] is SampleStatus.GAP  # window 1190..1192 too
    assert statuses[1193] is SampleStatus.FORMED
    diag = adapter.diagnostics()
    assert diag.dropped_gap == 2
    assert diag.samples_formed == 1198 - 3
    # Had the adapter bridged the gap (e(k-1) from scan 1189 as if it were 1190, MV(1189) as the
    # applied input before 591), the last few samples would be wrong and the fit would be off.
    assert rel_err(adapter.estimate(), teacher) < 1e-6


def test_invalid_and_duplicate_readings() -> None:
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    equilibrium_readings(adapter, n=3)
    kw = {"sp": H_OP[:2], "mv": MODEL.u_op, "u_mpc": MODEL.u_op}
    assert adapter.observe(scan=2, t_s=2.0, pv=H_OP[:2], **kw) is SampleStatus.DUPLICATE
    assert adapter.observe(scan=3, t_s=3.0, pv=[math.nan, 0.2], **kw) is SampleStatus.INVALID
    assert adapter.observe(scan=4, t_s=4.0, pv=H_OP[:2], **kw) is SampleStatus.GAP
    assert adapter.observe(scan=5, t_s=5.0, pv=H_OP[:2], **kw) is SampleStatus.GAP
    assert adapter.observe(scan=6, t_s=6.0, pv=H_OP[:2], **kw) is SampleStatus.FORMED
    # A restarted PLC (counter going back) is a gap too.
    assert adapter.observe(scan=0, t_s=7.0, pv=H_OP[:2], **kw) is SampleStatus.GAP
    diag = adapter.diagnostics()
    assert (diag.duplicates, diag.dropped_invalid, diag.dropped_gap, diag.samples_formed) == (1, 1, 3, 2)


def test_constant_error_history_means_no_adaptation() -> None:
    # Constant offsets: De = D2e = 0 and Ts e constant, so the regressor never moves. The MPC's
    # input wanders all the while (a nonzero target), which must not be learned from.
    rng = np.random.default_rng(1)
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    e = np.array([0.01, -0.005])
    for k in range(300):
        u_mpc = MODEL.u_op + 5e-6 * rng.standard_normal(2)
        adapter.observe(scan=k, t_s=float(k), sp=H_OP[:2], pv=H_OP[:2] - e, mv=MODEL.u_op, u_mpc=u_mpc)
        assert adapter.propose(float(k)) is None
    diag = adapter.diagnostics()
    assert diag.samples_formed == 298
    for p in diag.pumps:
        assert p.samples_used == 0
        assert p.skipped_unexcited == 298
        assert not p.ready
        assert p.covariance_trace == pytest.approx(3 * adapter.config.p0)
    assert adapter.applied.allclose(PAPER, rtol=0.0)
    assert adapter.estimate().allclose(PAPER, rtol=1e-15)
    assert diag.accepted_pushes == diag.rejected_pushes == 0


def test_samples_with_the_mpc_at_a_bound_are_inequalities_not_equalities() -> None:
    # The applied MV wanders near Qmax, so the teacher's move often passes Qmax and the (clamped)
    # MPC input sits at the bound: such a sample only says "at least this much".
    teacher = PidGains.diagonal([5.0e-4, 9.0e-4], [6.0e-6, 3.5e-5], [-1.2e-4, -12.0e-4])
    readings = list(teacher_readings(teacher, 1200, seed=4, mv_mean=1.18e-4))
    band = 0.005 * QMAX
    n_sat = [sum(r["u_mpc"][i] >= QMAX - band for r in readings[2:]) for i in range(2)]
    assert min(n_sat) > 100
    fits = {}
    for mode in ("one_sided", "drop", "equality"):
        adapter = PidGainAdapter(MODEL, PAPER, Legacy(saturated=mode))
        for r in readings:
            adapter.observe(**r)
        fits[mode] = adapter
    for i, p in enumerate(fits["one_sided"].diagnostics().pumps):
        assert p.dropped_saturated + p.one_sided_updates == n_sat[i]
        assert p.one_sided_updates > 0  # early on, the paper's gains fall short of some bounds
    for i, p in enumerate(fits["drop"].diagnostics().pumps):
        assert p.dropped_saturated == n_sat[i] and p.one_sided_updates == 0
    # Used as inequalities (or dropped) the clamped moves do not bias the fit; fitted as
    # equalities they drag the gains toward the clamped move.
    assert rel_err(fits["one_sided"].estimate(), teacher) < 1e-6
    assert rel_err(fits["drop"].estimate(), teacher) < 1e-5  # fewer samples: measured 1.8e-6
    assert all(p.dropped_saturated == 0 for p in fits["equality"].diagnostics().pumps)
    assert rel_err(fits["equality"].estimate(), teacher) > 1e-2


def fill_readings(n: int) -> Iterator[dict[str, Any]]:
    """A fill from below at Qmax as the shadow MPC sees it: both tanks rise 6 mm per scan, the MPC
    is pinned at Qmax, and the applied PID (the paper's gains) lets its output sag 2.5e-6 per scan
    (its Kp De outweighs its Ki e)."""
    for k in range(n):
        e = np.array([0.4, 0.2]) - 0.006 * k
        yield {
            "scan": k,
            "t_s": float(k),
            "sp": H_OP[:2],
            "pv": H_OP[:2] - e,
            "mv": np.full(2, 1.17e-4 - 2.5e-6 * k),
            "u_mpc": np.full(2, QMAX),
            "x": np.array([H_OP[0] - e[0], H_OP[1] - e[1], 0.1]),
        }


#: The loops' gain_box of configs/three_tank_energies_sim.yaml.
ENERGIES_BOX = GainBox(
    lower=PidGains(np.zeros((2, 2)), np.zeros((2, 2)), np.diag([-1e-2, -1e-2])),
    upper=PidGains(np.diag([1e-2, 1e-2]), np.diag([1e-3, 1e-3]), np.diag([1e-2, 1e-2])),
)


def test_a_pinned_mpc_teaches_a_pid_that_falls_short_of_it() -> None:
    readings = list(fill_readings(20))
    dropped = PidGainAdapter(MODEL, PAPER, Legacy(box=ENERGIES_BOX, saturated="drop"))
    taught = PidGainAdapter(MODEL, PAPER, Legacy(box=ENERGIES_BOX))
    for r in readings:
        dropped.observe(**r)
        taught.observe(**r)
    # Dropping learns nothing: no estimate, never ready, no push (the starvation of the fill).
    assert dropped.estimate().allclose(PAPER, rtol=0.0)
    assert not any(p.ready for p in dropped.diagnostics().pumps)
    assert dropped.propose(19.0) is None
    # As inequalities: every sample whose move fell short corrected the estimate, the covariance
    # is untouched (no equality was observed) and the pumps are ready.
    diag = taught.diagnostics()
    for p in diag.pumps:
        assert p.samples_used == 0 and p.one_sided_updates > 3 and p.ready
        assert p.covariance_trace == pytest.approx(3 * taught.config.p0, rel=1e-12)
    est = taught.estimate()
    assert (est.ki.diagonal() > 10 * PAPER.ki.diagonal()).all()  # the integral action grows
    # The last sample's inequality holds: the estimated PID's move reaches Qmax from the sagging MV.
    r0, r1, r2 = readings[-1], readings[-2], readings[-3]
    e0, e1, e2 = (r["sp"] - r["pv"] for r in (r0, r1, r2))
    move = est.kp @ (e0 - e1) + est.ki @ e0 * TS + est.kd @ (e0 - 2 * e1 + e2) / TS
    np.testing.assert_array_less(QMAX - r1["mv"] - 1e-12, move)
    assert taught.propose(19.0) is not None


def test_non_finite_mpc_input_skips_only_that_pump() -> None:
    teacher = PidGains.diagonal([5.0e-4, 9.0e-4], [6.0e-6, 3.5e-5], [-1.2e-4, -12.0e-4])
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    for r in teacher_readings(teacher, 50, seed=4):
        if r["scan"] == 20:
            r["u_mpc"] = np.array([math.nan, r["u_mpc"][1]])
        adapter.observe(**r)
    p1, p2 = adapter.diagnostics().pumps
    assert p1.skipped_nonfinite == 1 and p2.skipped_nonfinite == 0
    assert p1.samples_used == p2.samples_used - 1


# --------------------------------------------------------------------------- validation
NONNEG = PidGains(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)))
ONES = PidGains(np.ones((2, 2)), np.ones((2, 2)), np.ones((2, 2)))


def test_adapter_and_config_validation() -> None:
    with pytest.raises(ValueError, match="max_spectral_radius"):
        Legacy(max_spectral_radius=1.01)
    with pytest.raises(ValueError, match="push_period_s"):
        Legacy(push_period_s=0.0)
    with pytest.raises(ValueError, match="memory_s"):
        Legacy(memory_s=-1.0)
    with pytest.raises(ValueError, match="horizon_steps"):
        Legacy(horizon_steps=0)
    with pytest.raises(ValueError, match="saturated"):
        AdaptationConfig(saturated="skip")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="fixed gains must have shape"):
        PidGainAdapter(MODEL, PidGains.diagonal([1e-4], [1e-6], [0.0]))
    with pytest.raises(ValueError, match="inside the gain box"):
        PidGainAdapter(MODEL, PAPER, Legacy(box=GainBox(lower=NONNEG, upper=ONES)))  # Kd < 0
    with pytest.raises(ValueError, match="sign guard"):
        PidGainAdapter(MODEL, PAPER, Legacy(ki_min=1e-5))  # PID I's Ki 5.32e-6 < 1e-5
    with pytest.raises(ValueError, match="own_loop"):
        PidGainAdapter(MODEL, PAPER, Legacy(own_loop=(0, 2)))
    with pytest.raises(ValueError, match="u_min must be < u_max"):
        LoopModel(MODEL.A, MODEL.B, MODEL.C, TS, np.full(2, QMAX), np.zeros(2))
    with pytest.raises(ValueError, match="C must have shape"):
        LoopModel(MODEL.A, MODEL.B, np.eye(2), TS, np.zeros(2), np.full(2, QMAX))
    with pytest.raises(ValueError, match="same shape"):
        PidGains(np.eye(2), np.eye(3), np.eye(2))
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    with pytest.raises(ValueError, match="sp must have shape"):
        adapter.observe(scan=0, t_s=0.0, sp=[0.4], pv=H_OP[:2], mv=MODEL.u_op, u_mpc=MODEL.u_op)
    with pytest.raises(TypeError, match="scan"):
        adapter.observe(scan=1.0, t_s=0.0, sp=H_OP[:2], pv=H_OP[:2], mv=MODEL.u_op, u_mpc=MODEL.u_op)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="finite"):
        adapter.set_applied(_nan_candidate())


def test_set_applied_resynchronises_the_rate_limit_reference() -> None:
    adapter = PidGainAdapter(MODEL, PAPER, LEGACY)
    equilibrium_readings(adapter)
    other = scaled(PAPER, 1, 1, kp=1.2)
    adapter.set_applied(other)
    assert adapter.applied is other
    # 1.45 x the paper's Kp2 is 1.21 x the new reference: inside the rate limit now.
    assert adapter.evaluate(scaled(PAPER, 1, 1, kp=1.45)).accepted
