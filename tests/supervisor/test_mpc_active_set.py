"""The MPC's exact solve on the previous step's active set (supervisor.mpc._ActiveSetQp).

Oracles: a one-variable QP solved by hand (the KKT check must accept the right active set and
refuse the wrong ones), and the controller's own OSQP-polished solution of the same QP (the
certified solution must equal it, and skip OSQP).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from supervisor.mpc import KKT_TOL, MpcConfig, MpcController, MpcModel, _ActiveSetQp
from tanklab.enums import MpcStatus


def _one_variable() -> _ActiveSetQp:
    # min 1/2 v^2 - 2 v  s.t.  -10 <= v <= 1: unconstrained optimum 2, constrained 1 with y = +1
    return _ActiveSetQp(sp.csc_matrix([[1.0]]), sp.csc_matrix([[1.0]]))


def test_kkt_check_accepts_the_optimum_and_refuses_wrong_active_sets() -> None:
    qp = _one_variable()
    q, lo, up = np.array([-2.0]), np.array([-10.0]), np.array([1.0])
    none, yes = np.array([False]), np.array([True])
    free = qp.solve(q, lo, up, none, none)
    assert free is not None and free.x[0] == 2.0 and not free.certified  # violates v <= 1
    upper = qp.solve(q, lo, up, none, yes)
    assert upper is not None and upper.certified
    assert abs(upper.x[0] - 1.0) < 1e-15 and abs(upper.y[0] - 1.0) < 1e-15  # y > 0: upper bound
    lower = qp.solve(q, lo, up, yes, none)
    assert lower is not None and not lower.certified  # v = -10 with a multiplier of the wrong sign
    # the reverse problem: the optimum lies inside, so the upper bound's multiplier is wrong-signed
    inside = qp.solve(np.array([0.5]), lo, up, none, yes)
    assert inside is not None and not inside.certified
    assert qp.solve(np.array([0.5]), lo, up, none, none).certified  # type: ignore[union-attr]


def _controller() -> MpcController:
    # a small three-tank-like chain, in the shape the supervisor builds (m^3/s inputs, metre levels)
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
    # real move suppression (S = 1e8, docs/mpc.md): a well-conditioned QP that OSQP polishes
    cfg = MpcConfig(
        horizon=20, u_min=0.0, u_max=1.2e-4, du_min=-1e-6, du_max=1e-6, z_min=0.0, z_max=0.63, S=1e8
    )
    return MpcController(model, cfg)


def test_a_repeated_qp_is_solved_exactly_without_osqp() -> None:
    ctrl = _controller()
    x = np.array([0.41, 0.19, 0.3])
    r = np.array([0.45, 0.2])
    u_prev = np.array([5e-5, 3e-5])
    first = ctrl.plan(x, r, u_prev)
    second = ctrl.plan(x, r, u_prev)  # same active set twice in a row: the candidate for the next
    third = ctrl.plan(x, r, u_prev)
    assert first.iterations > 0 and second.iterations > 0
    assert third.iterations == 0 and third.solve_time_s == 0.0
    assert third.osqp_status.startswith("skipped")
    assert third.status == MpcStatus.SOLVED
    # the same optimum as OSQP's polished one (polish = exact on the same active set)
    assert np.max(np.abs(third.planned_u - second.planned_u)) <= 1e-9 * 1.2e-4
    assert abs(third.objective - second.objective) <= 1e-9 * abs(second.objective)


def test_a_changed_qp_falls_back_to_osqp_and_stays_within_bounds() -> None:
    ctrl = _controller()
    x = np.array([0.41, 0.19, 0.3])
    u_prev = np.array([5e-5, 3e-5])
    for _ in range(3):
        ctrl.plan(x, np.array([0.45, 0.2]), u_prev)
    # a far setpoint: the rate-limited ramp activates other rows, the old set fails the check
    res = ctrl.plan(x, np.array([0.6, 0.1]), u_prev)
    assert res.iterations > 0 and res.status == MpcStatus.SOLVED
    assert np.all(np.abs(np.diff(np.vstack([u_prev, res.planned_u]), axis=0)) <= 1e-6 * (1 + 1e-12))


def test_model_update_drops_cached_factorisations() -> None:
    ctrl = _controller()
    x, r, u_prev = np.array([0.41, 0.19, 0.3]), np.array([0.45, 0.2]), np.array([5e-5, 3e-5])
    for _ in range(3):
        ctrl.plan(x, r, u_prev)
    assert ctrl._kkt._cache
    ctrl.update_model(ctrl.model.A * 0.999, ctrl.model.B)
    assert not ctrl._kkt._cache
    fresh = MpcController(ctrl.model, ctrl.config)
    a, b = ctrl.plan(x, r, u_prev), fresh.plan(x, r, u_prev)
    assert np.max(np.abs(a.u - b.u)) <= 1e-6 * 1.2e-4
    assert KKT_TOL <= 1e-6 * 1e-2  # the certificate is far tighter than the last ladder rung
