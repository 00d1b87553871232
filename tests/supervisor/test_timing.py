"""The supervisor's timing: the estimate carried scan by scan, the committed move, the seam's order.

Oracles: hand-computed one-scan steps; N scans of the one-scan ZOH model with a held input equal
the ZOH model at N Ts (exact composition); on its own linear model with exact measurements the
supervisor's prior is the true state whatever the PLC applied in each scan (zero innovation), and
the MPC-mode plan starts from the state the committed MV leads to. The driver's requests are
checked item by item against the order the module docstring of ``supervisor.port`` states.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.linearize import discretize_zoh
from supervisor.cycle import Actions, PlcSnapshot, SupervisorCore
from supervisor.port import PlcRequest, SupervisorDriver
from supervisor.timing import ScanPredictor
from tanklab.config import SiteConfig, site_from_mapping
from tanklab.enums import LoopMode, SupervisorMode
from tanklab.tags import HEARTBEAT_PATH

ROOT = Path(__file__).resolve().parents[2]


def _site(plc_scan_s: float = 0.5, sample_s: float = 2.5) -> SiteConfig:
    data = yaml.safe_load((ROOT / "configs/three_tank_kortela.yaml").read_text())
    data["plc"]["scan_period_s"] = plc_scan_s
    data["supervisor"]["sample_time_s"] = sample_s
    return site_from_mapping(data)


def _snapshot(site: SiteConfig, scan: int, levels: np.ndarray, mv: np.ndarray, mode: LoopMode) -> PlcSnapshot:
    n_l = len(site.loop_names)
    assert site.plc is not None
    return PlcSnapshot(
        scan=scan,
        t_s=scan * site.plc.scan_period_s,
        sp_m=np.array([lp.setpoint_m for lp in site.plc.loops]),
        pv_m=levels[[site.tank_names.index("T" + lp.pv[2:]) for lp in site.plc.loops]],
        mv=mv,
        modes=(mode,) * n_l,
        gains=np.zeros((n_l, 3)),
        levels_m=levels,
        good=np.ones(len(levels), dtype=bool),
    )


# ---- ScanPredictor --------------------------------------------------------------------------


def test_one_scan_is_the_affine_model_around_the_operating_point() -> None:
    # x+ = x_op + A (x - x_op) + B (u - u_op + eta): 1 + 0.9 (1.2 - 1) + 2 (0.7 - 0.5 + 0.1) = 1.78
    p = ScanPredictor([[0.9]], [[2.0]], [1.0], [0.5])
    p.start(10, [0.7])
    p.corrected([1.2], [0.1])
    assert p.look_ahead(1) == pytest.approx([1.78], abs=1e-15)
    assert p.advance_to(11) == 1
    assert p.x_m == pytest.approx([1.78], abs=1e-15)
    assert p.scan == 11
    assert p.bridged_scans == 0


def test_missed_scans_are_bridged_with_the_last_mv_held_and_counted() -> None:
    p = ScanPredictor([[0.5]], [[1.0]], [0.0], [0.0])
    p.start(0, [1.0])
    p.corrected([0.0], [0.0])
    assert p.advance_to(3) == 3  # 0 -> 1 -> 1.5 -> 1.75
    assert p.x_m == pytest.approx([1.75])
    assert p.bridged_scans == 2
    assert p.advance_to(1) == 0  # a counter that went back (PLC restart): no propagation
    assert p.scan == 1 and p.x_m == pytest.approx([1.75])


def test_advance_before_start_and_a_non_finite_model_are_refused() -> None:
    p = ScanPredictor([[0.5]], [[1.0]], [0.0], [0.0])
    with pytest.raises(ValueError, match="start"):
        p.advance_to(1)
    with pytest.raises(ValueError, match="finite"):
        ScanPredictor([[np.nan]], [[1.0]], [0.0], [0.0])
    with pytest.raises(ValueError, match="shape"):
        ScanPredictor([[0.5, 0.0]], [[1.0]], [0.0], [0.0])


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 6),
    seed=st.integers(0, 2**31 - 1),
    scans=st.integers(1, 8),
)
def test_scans_with_a_held_input_compose_to_the_model_at_the_sample_time(
    n: int, seed: int, scans: int
) -> None:
    rng = np.random.default_rng(seed)
    Ac = -np.diag(rng.uniform(0.01, 0.5, n)) + 0.05 * rng.standard_normal((n, n))
    Bc = rng.standard_normal((n, 2))
    ts = 0.5
    As, Bs = discretize_zoh(Ac, Bc, ts)
    AT, BT = discretize_zoh(Ac, Bc, scans * ts)
    x_op, u_op = rng.standard_normal(n), rng.standard_normal(2)
    x0, u, eta = rng.standard_normal(n), rng.standard_normal(2), rng.standard_normal(2)
    p = ScanPredictor(As, Bs, x_op, u_op)
    p.start(0, u)
    p.corrected(x0, eta)
    p.advance_to(scans)
    expected = x_op + AT @ (x0 - x_op) + BT @ (u - u_op + eta)
    np.testing.assert_allclose(p.x_m, expected, rtol=1e-9, atol=1e-9)


# ---- the core: filter fed what was applied, plan from the committed move ------------------


def _true_run(core: SupervisorCore, mode: LoopMode, samples: int, seed: int) -> list[np.ndarray]:
    """Drive ``core`` with snapshots of its own one-scan linear model and a new random MV every
    scan, up to and including its ``samples``-th sample scan; return the true states per scan."""
    rng = np.random.default_rng(seed)
    site = core.site
    A, B, x_op, u_op = core._scan_model(core.mpc.model.x_op, core.mpc.model.u_op)
    x = x_op.copy()
    lo = np.array([p.command_min for p in site.plant.pumps])
    hi = np.array([p.command_max for p in site.plant.pumps])
    states = []
    driver = SupervisorDriver(core)
    for scan in range(1, (samples - 1) * core.sample_scans + 2):
        mv = rng.uniform(lo + 0.3 * (hi - lo), hi - 0.3 * (hi - lo))
        states.append(x.copy())
        driver.on_snapshot(_snapshot(site, scan, x.copy(), mv, mode))
        x = x_op + A @ (x - x_op) + B @ (core.flows_of(mv) - u_op)  # the PLC applies MV(scan)
    return states


@pytest.mark.parametrize("sample_s", [0.5, 2.5])
def test_on_its_own_model_the_prior_is_the_true_state_whatever_was_applied(sample_s: float) -> None:
    core = SupervisorCore(_site(0.5, sample_s))
    core.request_mode(SupervisorMode.ADVISORY)
    states = _true_run(core, LoopMode.AUTO, samples=6, seed=3)
    # the first correction started from the operating point; from then on every prior is exact,
    # so the estimate equals the true state at the last scan and no disturbance is invented
    assert core.cycles == 6
    np.testing.assert_allclose(core.predictor.x_m, states[-1], atol=1e-12)
    np.testing.assert_allclose(core.predictor.eta_m3_s, 0.0, atol=1e-15)


def test_mpc_mode_plans_from_the_state_the_committed_move_leads_to() -> None:
    core = SupervisorCore(_site(0.5, 2.5))
    core.request_mode(SupervisorMode.MPC)
    _true_run(core, LoopMode.REMOTE, samples=3, seed=5)
    res = core.result
    assert res is not None and core.result_scan == 11  # samples at scans 1, 6, 11
    # the plan's first state is one scan ahead of x(k|k), with the MV the PLC applies now
    np.testing.assert_allclose(res.state, core.predictor.look_ahead(1), atol=1e-15)
    assert not np.allclose(res.state, core.predictor.x_m, atol=1e-9)
    np.testing.assert_allclose(res.planned_u[0], core.result.u)


def test_shadow_mode_plans_from_the_estimate_with_the_input_applied_before() -> None:
    core = SupervisorCore(_site(1.0, 1.0))
    core.request_mode(SupervisorMode.ADVISORY)
    _true_run(core, LoopMode.AUTO, samples=4, seed=9)
    res = core.result
    assert res is not None
    np.testing.assert_allclose(res.state, core.predictor.x_m, atol=1e-15)


# ---- the seam: requests and their order ----------------------------------------------------


def test_a_request_writes_remote_mv_then_mode_then_the_heartbeat() -> None:
    act = Actions(
        remote_mv={"LIC1": 1e-4, "LIC2": 2e-4}, modes={"LIC1": LoopMode.REMOTE, "LIC2": LoopMode.REMOTE}
    )
    req = PlcRequest.of(act, 7)
    assert [p for p, _ in req.writes] == [
        "PLC.LIC1.RemoteMV",
        "PLC.LIC2.RemoteMV",
        "PLC.LIC1.Mode",
        "PLC.LIC2.Mode",
        HEARTBEAT_PATH,
    ]
    assert req.writes[-1] == (HEARTBEAT_PATH, 7)
    assert req.gains == () and req.trailing == ()


def test_gain_pushes_come_between_the_write_and_a_trailing_heartbeat_that_wraps() -> None:
    req = PlcRequest.of(Actions(gains={"LIC1": (1.0, 0.1, 0.0)}), 2**32 + 5)
    assert req.writes == ()
    assert req.gains == (("LIC1", (1.0, 0.1, 0.0)),)
    assert req.trailing == ((HEARTBEAT_PATH, 5),)


def test_the_driver_samples_on_the_first_scan_then_every_sample_and_acknowledges_every_scan() -> None:
    site = _site(0.5, 2.5)
    core = SupervisorCore(site)
    driver = SupervisorDriver(core)
    x = core.mpc.model.x_op
    mv = np.array([0.5, 0.5])
    first = driver.on_snapshot(_snapshot(site, 0, x, mv, LoopMode.AUTO))
    assert first is not None and first.actions is None and first.writes == ((HEARTBEAT_PATH, 1),)
    assert core.cycles == 0  # scan 0: nothing measured yet
    sampled = []
    for scan in range(3, 15):
        req = driver.on_snapshot(_snapshot(site, scan, x, mv, LoopMode.AUTO))
        assert req is not None
        assert req.writes[-1] == (HEARTBEAT_PATH, scan - 1) or req.trailing[-1][1] == scan - 1
        if driver.sampled:
            sampled.append(scan)
        assert driver.on_snapshot(_snapshot(site, scan, x, mv, LoopMode.AUTO)) is None  # seen
    assert sampled == [3, 8, 13]
    assert core.cycles == 3


def test_correct_is_the_filters_corrector_from_the_given_prior() -> None:
    core = SupervisorCore(_site(2.5, 2.5))
    mpc = core.mpc
    kf = mpc.estimator
    x_op = mpc.model.x_op
    rng = np.random.default_rng(1)
    x_prior = x_op + 0.01 * rng.standard_normal(x_op.size)
    eta_prior = 1e-6 * rng.standard_normal(kf.n_disturbances)
    y = x_op + 0.01 * rng.standard_normal(x_op.size)
    x, eta = mpc.correct(y, x_prior, eta_prior)
    # oracle: xi(k|k) = xi(k|k-1) + Kf (y_f - Ca xi(k|k-1)) on the filtered rows, by hand
    rows = [core.site.tank_names.index(t) for t in core.spec.mpc.filter_outputs or core.spec.mpc.controlled]
    prior = np.concatenate([x_prior - x_op, eta_prior])
    Ca = kf.augmented[2]
    post = prior + kf.gain @ ((y - x_op)[rows] - Ca @ prior)
    np.testing.assert_allclose(x, x_op + post[: x_op.size], rtol=0, atol=1e-15)
    np.testing.assert_allclose(eta, post[x_op.size :], rtol=0, atol=1e-18)
    # the slow path (lists) gives the same; bad values are refused by name, nothing changed
    x2, eta2 = mpc.correct(list(y), list(x_prior), list(eta_prior))
    np.testing.assert_array_equal(x2, x)
    np.testing.assert_array_equal(eta2, eta)
    with pytest.raises(ValueError, match="x_prior"):
        mpc.correct(y, np.full(x_op.size, np.nan), eta_prior)
    with pytest.raises(ValueError, match="y"):
        mpc.correct(y[:-1], x_prior, eta_prior)


def test_the_adaptation_leaves_an_engineers_loop_alone_until_it_is_released() -> None:
    """ADAPTIVE_PID on the Energies site: an engineer's SetGains on LIC2 holds it (ENGINEER); the
    supervisor keeps pushing LIC1 only, the PLC refuses nothing, LIC2 keeps the engineer's gains;
    once released, the supervisor may push LIC2 again."""
    from tankctl.cosim import CoSimulation
    from tanklab.config import load_site
    from tanklab.enums import GainSource

    sim = CoSimulation(
        load_site(ROOT / "configs/three_tank_energies_sim.yaml"), supervisor_mode="ADAPTIVE_PID"
    )
    sup = sim.supervisor
    assert sup is not None
    sim.run(150.0)
    lic2 = sim.plc.loop("LIC2")
    assert lic2.applied is not None
    mine = (lic2.applied.kp * 0.9, lic2.applied.ki * 0.9, lic2.applied.kd * 0.9)
    assert sim.plc.stage_gains("LIC2", *mine, source=GainSource.ENGINEER).name == "STAGED"
    sim.run(1.0)
    assert lic2.source is GainSource.ENGINEER
    pushes_before, refused_before = sup.adapter.diagnostics().accepted_pushes, sup.pushes_refused  # type: ignore[union-attr]
    sim.run(400.0)
    assert lic2.source is GainSource.ENGINEER
    assert lic2.applied is not None and (lic2.applied.kp, lic2.applied.ki, lic2.applied.kd) == pytest.approx(
        mine
    )
    assert sup.pushes_refused == refused_before  # nothing was sent that the PLC had to refuse
    assert sup.adapter.diagnostics().accepted_pushes > pushes_before  # type: ignore[union-attr]
    assert sim.plc.loop("LIC1").source is GainSource.SUPERVISOR  # LIC1 went on being adapted
    assert sup.held_loops == 1
    assert sim.plc.release_gains("LIC2").name == "STAGED"
    assert lic2.source is GainSource.FIXED
    sim.run(200.0)
    assert lic2.source is GainSource.SUPERVISOR  # handed back: adapted again
    assert sup.held_loops == 0


def test_adaptive_pid_is_refused_when_the_supervisor_samples_slower_than_the_plc() -> None:
    core = SupervisorCore(_site(0.5, 2.5))
    with pytest.raises(ValueError, match="sample every PLC scan"):
        core.request_mode(SupervisorMode.ADAPTIVE_PID)
    assert core.requested is not SupervisorMode.ADAPTIVE_PID
    SupervisorCore(_site(2.5, 2.5)).request_mode(SupervisorMode.ADAPTIVE_PID)  # every scan: fine
