"""Plant physics: Torricelli flows, limits, pumps, sensors, integrators, the volume balance."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.integrate import step_adaptive, step_rk4
from plant_sim.models import PlantInputs, TankNetwork, default_inputs
from plant_sim.plant import PlantSimulator
from plant_sim.stiffness import fastest_rate_1_s, rate_bound_1_s
from tanklab.config import load_site
from tanklab.enums import SensorFault
from tanklab.errors import IntegrationError

ROOT = Path(__file__).resolve().parents[2]
SIM = load_site(ROOT / "configs/three_tank_energies_sim.yaml").plant
RIG = load_site(ROOT / "configs/three_tank_energies_rig.yaml").plant
G = 9.81


def test_torricelli_flows_by_hand() -> None:
    net = TankNetwork.from_config(SIM)
    u = default_inputs(net, SIM)
    h = np.array([0.4, 0.2, 0.3])
    q = net.valve_flows(h, u.valve_openings)
    # q13 = 0.5 * 5e-5 * sqrt(2 g (0.4 - 0.3)) = 2.5e-5 * 1.40071 = 3.50178e-5
    assert q[0] == pytest.approx(0.5 * 5e-5 * math.sqrt(2 * G * 0.1), rel=1e-12)
    assert q[0] == pytest.approx(3.50178e-5, rel=1e-5)
    # q32 = 0.5 * 5e-5 * sqrt(2 g 0.1); q20 = 0.675 * 5e-5 * sqrt(2 g 0.2) = 6.6957e-5
    assert q[1] == pytest.approx(q[0])
    assert q[2] == pytest.approx(0.675 * 5e-5 * math.sqrt(2 * G * 0.2), rel=1e-12)
    # Reversed order: T3 above T1 -> q13 flows back, same magnitude.
    q_rev = net.valve_flows(np.array([0.3, 0.2, 0.4]), u.valve_openings)
    assert q_rev[0] == pytest.approx(-q[0])
    # Half-open valve halves the flow; a closed one passes nothing.
    assert net.valve_flows(h, np.array([0.5, 0.0, 1.0]))[0] == pytest.approx(q[0] / 2)
    assert net.valve_flows(h, np.array([0.5, 0.0, 1.0]))[1] == 0.0
    # Leak fully open on T1: mu_L Ap sqrt(2 g h) = 0.25 * 5e-5 * sqrt(2 g 0.4)
    leak = net.leak_flows(h, np.array([1.0, 0.0, 0.0]))
    assert leak[0] == pytest.approx(0.25 * 5e-5 * math.sqrt(2 * G * 0.4), rel=1e-12)


def _inputs(
    net: TankNetwork, cmd=(0.0, 0.0), valves=(1, 1, 1), leaks=(0, 0, 0), dist=(0, 0, 0)
) -> PlantInputs:
    return PlantInputs(
        np.array(cmd, float), np.array(valves, float), np.array(leaks, float), np.array(dist, float)
    )


def test_levels_never_below_zero_and_overflow_is_spilled_and_counted() -> None:
    net = TankNetwork.from_config(SIM)
    x = net.initial_state(np.array([0.05, 0.01, 0.0]))
    stored0 = net.stored_volume(x)
    u = _inputs(net, leaks=(1, 1, 1), dist=(0, -1e-4, 0))
    for _ in range(600):
        x = step_rk4(net, x, u, 1.0)
        assert np.all(net.levels(x) >= 0.0)
    assert np.all(net.levels(x) < 1e-3)
    # Fill T1 with the valves closed at full pump flow: it overflows at Hmax and counts the spill.
    x = net.initial_state(np.array([0.6, 0.0, 0.0]))
    u = _inputs(net, cmd=(1.2e-4, 0.0), valves=(0, 0, 0))
    for _ in range(200):
        x = step_rk4(net, x, u, 1.0)
        assert net.levels(x)[0] <= SIM.tanks[0].height_max_m
    spilled = net.volumes(x)[3]
    # 200 s at 1.2e-4 m^3/s, minus the 0.02 m of headroom (3.08e-4 m^3) = 2.092e-2 m^3.
    assert spilled == pytest.approx(200 * 1.2e-4 - 0.02 * 0.0154, rel=1e-6)
    assert abs(net.balance_error(x, 0.6 * 0.0154)) < 1e-15 + 1e-9 * 200 * 1.2e-4
    assert stored0 > 0


def test_speed_pump_dead_zone_saturation_and_lag() -> None:
    net = TankNetwork.from_config(RIG)
    flows = net.pump_target_flows(np.array([450.0, 1350.0]))
    assert flows[0] == 0.0  # 2e-7 * 450 - 1e-4 < 0: dead zone
    assert flows[1] == pytest.approx(1.8e-4)
    assert net.pump_commands_for(np.array([7.5e-5, 1.7e-5])) == pytest.approx([875.0, 535.0])
    lagged = SIM.model_copy(deep=True)
    lagged.pumps[0].lag_s = 5.0
    lnet = TankNetwork.from_config(lagged)
    x = lnet.initial_state(np.zeros(3))
    x = step_rk4(lnet, x, _inputs(lnet, cmd=(1e-4, 0.0)), 5.0)
    # First order: Q(tau) = Q_target (1 - e^-1)
    assert lnet.pump_flows(x)[0] == pytest.approx(1e-4 * (1 - math.exp(-1)), rel=1e-6)


def test_rk4_agrees_with_the_adaptive_solver() -> None:
    net = TankNetwork.from_config(SIM)
    u = _inputs(net, cmd=(1.0e-4, 0.6e-4), leaks=(0.3, 0, 0.5))
    x_rk = x_ad = net.initial_state(np.array([0.1, 0.05, 0.0]))
    for k in range(200):
        x_rk = step_rk4(net, x_rk, u, 1.0, t_s=k)
        x_ad = step_adaptive(net, x_ad, u, 1.0, t_s=k, rtol=1e-10, atol=1e-13)
    assert np.max(np.abs(net.levels(x_rk) - net.levels(x_ad))) < 1e-7


ACCURACY_M = 1e-6
"""Bound on |RK4 - solve_ivp| of the automatic sub-step (measured <= 2e-7 m on these plants; a
tenth of the 1e-5 m asked for, and 1/100 of the 0.1 mm transmitter noise of the Energies set)."""


@pytest.mark.parametrize(
    "config",
    ["three_tank_energies_sim", "three_tank_kortela", "three_tank_energies_rig", "two_tank_interacting"],
)
def test_automatic_substep_agrees_with_the_adaptive_solver(config: str) -> None:
    """Fill from empty (laminar start, overflow), a transient from the operating point with leaks,
    and random openings and disturbances: every scan within ``ACCURACY_M`` of solve_ivp."""
    site = load_site(ROOT / f"configs/{config}.yaml")
    net = TankNetwork.from_config(site.plant)
    ts = site.plc.scan_period_s if site.plc is not None else 1.0
    rng = np.random.default_rng(7)
    qmax = net.pump_max_flow_m3_s
    cases = [
        (np.zeros(net.n_tanks), 0.8 * qmax, np.zeros(net.n_tanks), np.ones(net.n_valves), 0.0),
        (
            np.array(site.plant.operating_point.levels_m),
            0.6 * qmax,
            np.full(net.n_tanks, 0.5),
            np.ones(net.n_valves),
            0.0,
        ),
        (
            rng.uniform(0, 0.9, net.n_tanks) * net.hmax_m,
            rng.uniform(0, 1, net.n_pumps) * qmax,
            rng.uniform(0, 1, net.n_tanks),
            rng.uniform(0, 1, net.n_valves),
            0.2,
        ),
    ]
    for h0, q, leaks, valves, dist in cases:
        d = rng.uniform(-1, 1, net.n_tanks) * dist * float(qmax.max())
        u = PlantInputs(net.pump_commands_for(q), valves, leaks, d)
        x_rk = x_ad = net.initial_state(h0, net.pump_target_flows(u.pump_commands))
        for k in range(round(200 / ts)):
            x_rk = step_rk4(net, x_rk, u, ts, t_s=k * ts)
            x_ad = step_adaptive(net, x_ad, u, ts, t_s=k * ts, rtol=1e-10, atol=1e-13)
            assert np.max(np.abs(net.levels(x_rk) - net.levels(x_ad))) < ACCURACY_M, (config, k)


def _jacobian_levels(net: TankNetwork, x: np.ndarray, u: PlantInputs) -> np.ndarray:
    """d(dh/dt)/dh by central differences (steps well inside the laminar band)."""
    n = net.n_tanks
    J = np.empty((n, n))
    for j in range(n):
        e = np.zeros_like(x)
        e[j] = 1e-7
        J[:, j] = (net.rhs(0, x + e, u)[:n] - net.rhs(0, x - e, u)[:n]) / 2e-7
    return J


def _smooth_state(net: TankNetwork, levels: np.ndarray, zone: float) -> bool:
    """Every level and every head across a valve at least ``zone`` from zero (where the coarse
    step is kept)."""
    links = zip(net.valve_up, net.valve_down, strict=True)
    heads = [levels[up] - levels[down] for up, down in links if down >= 0]
    return bool(np.all(levels >= zone) and all(abs(dh) >= zone for dh in heads))


@pytest.mark.parametrize(
    "config", ["three_tank_energies_sim", "three_tank_kortela", "single_tank_short_sim", "two_tank_published"]
)
def test_automatic_substeps_are_inside_rk4s_stability_interval(config: str) -> None:
    """The coarse sub-step times the bound at heads >= SMOOTH_ZONE_M is within RK4's accurate
    range, and the fine sub-step times the bound anywhere within its stability interval; both
    bounds hold every Jacobian eigenvalue at random states and openings (the smooth one at the
    states outside the zone)."""
    from plant_sim.integrate import (
        EVENT_SUBSTEP_S,
        RK4_COARSE_H_LAMBDA,
        RK4_STABLE_H_LAMBDA,
        SMOOTH_ZONE_M,
        event_substep_s,
        rk4_substep_s,
    )

    rng = np.random.default_rng(3)
    net = TankNetwork.from_config(load_site(ROOT / f"configs/{config}.yaml").plant)
    smooth = rate_bound_1_s(net, SMOOTH_ZONE_M)
    assert smooth < fastest_rate_1_s(net)  # the laminar band is where the stiffness is
    assert rk4_substep_s(net) * smooth <= RK4_COARSE_H_LAMBDA + 1e-12
    assert event_substep_s(net) * fastest_rate_1_s(net) <= RK4_STABLE_H_LAMBDA + 1e-12
    assert event_substep_s(net) <= EVENT_SUBSTEP_S
    checked_smooth = 0
    for _ in range(60):
        scale = rng.choice([1e-3, 1e-2, 1.0])
        x = net.initial_state(rng.uniform(0, 1, net.n_tanks) * net.hmax_m * scale)
        u = PlantInputs(
            rng.uniform(0, 1, net.n_pumps) * net.pump_max_flow_m3_s,
            rng.uniform(0, 1, net.n_valves),
            rng.uniform(0, 1, net.n_tanks),
            np.zeros(net.n_tanks),
        )
        eig = float(np.max(np.abs(np.linalg.eigvals(_jacobian_levels(net, x, u)))))
        assert eig <= fastest_rate_1_s(net) * (1 + 1e-6)
        if _smooth_state(net, net.levels(x), SMOOTH_ZONE_M):
            checked_smooth += 1
            assert eig <= smooth * (1 + 1e-6)
    assert checked_smooth >= 10


def test_smooth_rate_bound_is_reached_at_the_zone_edge() -> None:
    """The bound at heads >= h is attained: a single tank draining through its valve at exactly
    the zone's edge has the mode c s / (2 A sqrt(h)), and the bound is never below it."""
    net = TankNetwork.from_config(load_site(ROOT / "configs/single_tank_short_sim.yaml").plant)
    h = 5e-3
    u = PlantInputs(np.zeros(net.n_pumps), np.ones(net.n_valves), np.ones(net.n_tanks), np.zeros(net.n_tanks))
    x = net.initial_state(np.full(net.n_tanks, h))
    eig = float(np.max(np.abs(np.linalg.eigvals(_jacobian_levels(net, x, u)))))
    assert eig == pytest.approx(rate_bound_1_s(net, h), rel=1e-5)
    with pytest.raises(ValueError, match="min_head_m"):
        rate_bound_1_s(net, 0.0)


def test_overflow_in_one_long_substep_is_refined() -> None:
    """A tank reaching Hmax within a scan: the automatic sub-step redoes that step finely (one
    1 s RK4 step across the spill edge is 7.5e-4 m off on the Energies rig)."""
    net = TankNetwork.from_config(RIG)
    u = _inputs(net, cmd=tuple(net.pump_commands_for(0.8 * net.pump_max_flow_m3_s)))
    x_rk = x_ad = net.initial_state(np.zeros(3), net.pump_target_flows(u.pump_commands))
    for k in range(130):  # T1 overflows at about 113 s
        x_rk = step_rk4(net, x_rk, u, 1.0, t_s=k)
        x_ad = step_adaptive(net, x_ad, u, 1.0, t_s=k, rtol=1e-10, atol=1e-13)
        assert np.max(np.abs(net.levels(x_rk) - net.levels(x_ad))) < ACCURACY_M
    assert net.levels(x_rk)[0] == RIG.tanks[0].height_max_m


def test_adaptive_integrator_raises_on_failure() -> None:
    net = TankNetwork.from_config(SIM)
    u = _inputs(net, cmd=(float("nan"), 0.0))
    with pytest.raises(IntegrationError):
        step_adaptive(net, net.initial_state(np.array([0.1, 0.1, 0.1])), u, 1.0)
    with pytest.raises(IntegrationError):
        step_rk4(net, net.initial_state(np.array([0.1, 0.1, 0.1])), u, 1.0)
    with pytest.raises(ValueError):
        step_rk4(net, net.initial_state(np.zeros(3)), u, -1.0)


@settings(max_examples=40, deadline=None)
@given(
    cmd=st.tuples(st.floats(0, 1.2e-4), st.floats(0, 1.2e-4)),
    valves=st.tuples(*[st.floats(0, 1)] * 3),
    leaks=st.tuples(*[st.floats(0, 1)] * 3),
    dist=st.tuples(*[st.floats(-1e-4, 1e-4)] * 3),
    h0=st.tuples(*[st.floats(0, 0.62)] * 3),
    dt=st.floats(0.05, 5.0),
)
def test_volume_balance_closes(cmd, valves, leaks, dist, h0, dt) -> None:
    """stored + out + leaked + spilled - in stays at zero to 1e-9 of the throughput."""
    net = TankNetwork.from_config(SIM)
    u = _inputs(net, cmd, valves, leaks, dist)
    x = net.initial_state(np.array(h0))
    stored0 = net.stored_volume(x)
    for k in range(12):
        x = step_rk4(net, x, u, dt, t_s=k * dt)
    v_in, v_out, v_leak, v_spill = net.volumes(x)
    throughput = max(v_in + v_out + v_leak + v_spill, stored0, 1e-12)
    assert abs(net.balance_error(x, stored0)) <= 1e-9 * throughput
    assert np.all(net.levels(x) >= 0) and np.all(net.levels(x) <= net.hmax_m)


def test_transmitters_noise_quantization_and_faults() -> None:
    plant = SIM.model_copy(deep=True)
    for t in plant.tanks:
        t.transmitter.noise_std_m = 1e-3
        t.transmitter.quantization_m = 5e-4
    a, b = PlantSimulator(plant), PlantSimulator(plant)
    ra = np.array([a.advance(1.0) for _ in range(200)])
    rb = np.array([b.advance(1.0) for _ in range(200)])
    assert np.array_equal(ra, rb), "seeded noise must be reproducible"
    assert np.allclose(ra / 5e-4, np.round(ra / 5e-4))
    sim = PlantSimulator(SIM)
    sim.set_command("P1", 1e-4)
    sim.advance(10.0)
    h = sim.levels[0]
    sim.set_fault("LT1", SensorFault.BIAS, 0.02)
    assert sim.advance(0.0)[0] == pytest.approx(h + 0.02)
    sim.set_fault("LT1", SensorFault.STUCK)
    stuck = sim.readings[0]
    sim.set_command("P1", 1e-4)
    sim.advance(5.0)
    assert sim.readings[0] == stuck and sim.levels[0] > h + 0.02
    sim.set_fault("LT1", SensorFault.DRIFT, 1e-3)
    h1 = sim.levels[0]
    assert sim.advance(0.0)[0] == pytest.approx(h1)
    sim.set_command("P1", 0.0)
    sim.set_valve("V13", 0.0)
    sim.advance(10.0)
    assert sim.readings[0] == pytest.approx(sim.levels[0] + 10 * 1e-3)
    with pytest.raises(ValueError, match="unknown fault"):
        sim.set_fault("LT1", 9)


def test_level_switches() -> None:
    sim = PlantSimulator(SIM)
    lsh, lsl = sim.switches()
    assert not lsh.any() and lsl.all()  # empty tanks: low switches on
    sim.set_valve("V13", 0.0)
    sim.set_command("P1", 1.2e-4)
    for _ in range(80):
        sim.set_command("P1", 1.2e-4)
        sim.advance(1.0)
    lsh, lsl = sim.switches()
    assert sim.levels[0] >= 0.9 * 0.62 and lsh[0] and not lsl[0]


def test_setters_refuse_bad_values_and_keep_state() -> None:
    sim = PlantSimulator(SIM)
    before = sim.inputs
    for call in (
        lambda: sim.set_command("P1", 2e-4),
        lambda: sim.set_command("P1", float("nan")),
        lambda: sim.set_valve("V13", 1.5),
        lambda: sim.set_leak("T1", -0.1),
        lambda: sim.set_disturbance("T2", float("inf")),
        lambda: sim.set_commands(np.array([1e-4, 5e-4])),
    ):
        with pytest.raises(ValueError):
            call()
    with pytest.raises(KeyError):
        sim.set_valve("V99", 0.5)
    assert sim.inputs is before


def test_pump_watchdog_stops_pumps_without_commands() -> None:
    sim = PlantSimulator(SIM)
    sim.set_command("P1", 1e-4)
    sim.advance(5.0)
    assert sim.pump_flows[0] == pytest.approx(1e-4)
    sim.advance(6.0)  # 11 s since the last command > 10 s timeout
    sim.advance(1.0)
    assert sim.watchdog_tripped and sim.pump_flows[0] == 0.0
    sim.set_command("P1", 1e-4)
    assert not sim.watchdog_tripped and sim.pump_flows[0] == pytest.approx(1e-4)


def test_checkpoint_round_trip() -> None:
    sim = PlantSimulator(SIM)
    sim.set_command("P1", 1e-4)
    sim.set_leak("T1", 0.5)
    sim.advance(30.0)
    other = PlantSimulator(SIM)
    other.restore(sim.snapshot())
    assert np.array_equal(other.x, sim.x) and other.t_s == sim.t_s
    assert other.inputs.leak_openings[0] == 0.5
    assert other.balance().error == pytest.approx(sim.balance().error, abs=1e-18)


@settings(max_examples=80, deadline=None)
@given(
    h=st.tuples(*[st.floats(-1e-3, 0.7)] * 3),
    q=st.tuples(st.floats(0, 1.2e-4), st.floats(0, 1.2e-4)),
    valves=st.tuples(*[st.floats(0, 1)] * 3),
    leaks=st.tuples(*[st.floats(0, 1)] * 3),
    dist=st.tuples(*[st.floats(-1e-4, 1e-4)] * 3),
    lag=st.booleans(),
)
def test_fast_path_rhs_equals_the_numpy_rhs(h, q, valves, leaks, dist, lag) -> None:
    from plant_sim.integrate import rk4_step
    from plant_sim.kernel import bind
    from plant_sim.models import HeldRhs

    plant = SIM.model_copy(deep=True)
    if lag:
        plant.pumps[0].lag_s = 3.0
    net = TankNetwork.from_config(plant)
    u = _inputs(net, q, valves, leaks, dist)
    x = net.initial_state(np.array(h), np.array([5e-5, 0.0]))
    x[-4:] = [1e-3, 2e-3, 3e-4, 1e-5]
    rhs = bind(HeldRhs(net, u), rk4_step).rhs
    assert np.allclose(rhs(x.tolist()), net.rhs(0.0, x, u), rtol=1e-12, atol=1e-18)


def test_step_lengths_are_validated_every_call_and_zero_steps_nothing() -> None:
    """The memoised sub-step plan never lets a bad step length through (NaN, inf, negative: the
    same error every time) and a zero step returns the state unchanged, as a copy."""
    net = TankNetwork.from_config(load_site(ROOT / "configs/three_tank_energies_sim.yaml").plant)
    n = net.n_tanks
    u = PlantInputs(np.full(net.n_pumps, 5e-5), np.ones(net.n_valves), np.zeros(n), np.zeros(n))
    x = net.initial_state(np.array([0.3, 0.2, 0.25]))
    first = step_rk4(net, x, u, 1.0)
    assert np.array_equal(step_rk4(net, x, u, 1.0), first)  # the memoised plan: the same bits
    for bad in (math.nan, math.inf, -1.0):
        for _ in range(2):
            with pytest.raises(ValueError, match="dt_s must be finite and >= 0"):
                step_rk4(net, x, u, bad)
    same = step_rk4(net, x, u, 0.0)
    assert np.array_equal(same, x) and same is not x
