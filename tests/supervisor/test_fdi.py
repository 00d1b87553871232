"""FDI (supervisor.fdi): thresholds against hand computations, the GLR against a hand-summed
oracle, and every fault class injected in the co-simulation (fixed seed) detected and isolated
within a bound of model time; no alarm in a long fault-free run; a restart warms up afresh."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.linearize import operating_point
from plant_sim.models import default_inputs
from supervisor.fdi import FaultKind, FdiConfig, FdiCore, FdiState, glr_threshold, stuck_run
from tankctl.cosim import CoSimulation
from tanklab.config import SiteConfig
from tanklab.enums import SensorFault
from tanklab_testing.sites import SITE, noisy_site


def run(site: SiteConfig, duration_s: float, inject=None, t_fault_s: float = 100.0, fdi=None):  # type: ignore[no-untyped-def]
    cs = CoSimulation(site)
    core = fdi or FdiCore(site)
    first = None
    for k in range(round(duration_s / cs.ts_s)):
        if inject is not None and abs(cs.t_s - t_fault_s) < 1e-9:
            inject(cs)
        cs.step()
        r = core.step(k, cs.trace.t_s[-1], cs.trace.readings_m[-1], np.ones(3, bool), cs.trace.commands[-1])
        if first is None and r.state in (FdiState.DETECTED, FdiState.ISOLATED):
            first = r.t_s
    return core, first


def test_threshold_by_hand() -> None:
    # a = 1/day, Ts = 1 s, H = 17, N = 60: alpha = 1/86400 = 1.157e-5 per scan, / 1020 = 1.135e-8;
    # chi2_1 upper 1.135e-8 = z^2 with z = 5.709 (normal tail 5.67e-9 each side): 32.6
    assert glr_threshold(1.0, 1.0, 17, 60) == pytest.approx(5.709**2, rel=1e-3)
    # ten times the rate: the threshold falls (z = 5.3 at 1.135e-7)
    assert glr_threshold(10.0, 1.0, 17, 60) < glr_threshold(1.0, 1.0, 17, 60)


def test_stuck_run_by_hand() -> None:
    # sigma 1 mm, q 1 mm: p = 2 Phi(1/sqrt 2) - 1 = 0.5205; alpha 1e-6: ln(1e-6)/ln(0.5205) = 21.1 -> 22
    assert stuck_run(1e-3, 1e-3, 1e-6) == 22
    assert stuck_run(1e-3, 0.0, 1e-6) == 3  # exact repeats of unquantized noise: never
    assert stuck_run(0.0, 1e-3, 1e-6) is None  # a noise-free transmitter cannot tell


def test_hypotheses_follow_the_site() -> None:
    core = FdiCore(SITE)
    names = {h.name for h in core.hypotheses}
    assert {
        "Leak_T1",
        "Clog_V13",
        "Clog_V32",
        "Clog_V20",
        "Pump_P1",
        "Bias_LT3",
        "Drift_LT2",
        "Stuck_LT1",
    } <= names
    s = SITE.model_copy(deep=True)
    s.plant.tanks[0].leak_area_m2 = 0.0  # no leak valve on T1: no leak hypothesis
    assert "Leak_T1" not in {h.name for h in FdiCore(s).hypotheses}


def test_bad_config_is_refused() -> None:
    with pytest.raises(ValueError, match="observer_gain"):
        FdiConfig(observer_gain=1.5)


@settings(max_examples=20, deadline=None)
@given(st.floats(-0.02, 0.02).filter(lambda b: abs(b) > 1e-3), st.integers(0, 3))
def test_glr_matches_a_hand_summed_oracle(bias: float, onset: int) -> None:
    """A bias on LT1 at a steady plant: the bias hypothesis' sums equal g' W eps summed by hand
    along the recursion g = e + m, e <- J((1 - l) e - l m) with the same J, and the estimate is
    the bias (no noise: the floor's weight only)."""
    site = noisy_site(noise_m=0.0)
    core = FdiCore(site, FdiConfig(warmup_s=0.0))
    net = core.net
    h0 = np.array([t.initial_level_m for t in site.plant.tanks])
    op = operating_point(net, site.plant, default_inputs(net, site.plant))
    mv = net.pump_commands_for(op.flows_m3_s)[core.loop_pump]  # the steady state's
    k_b = core.glr.index(next(h for h in core.glr if h.name == "Bias_LT1"))
    s1 = s2 = 0.0
    e = np.zeros(3)
    l_gain = core.cfg.observer_gain
    for k in range(12):
        m = np.array([bias, 0.0, 0.0]) if k >= onset + 1 else np.zeros(3)
        x_prev = core.x
        core.step(k, float(k), h0 + m, np.ones(3, bool), mv)
        if k >= onset + 1 and x_prev is not None:
            if k == onset + 1:
                e = np.zeros(3)
            g = e + np.array([1.0, 0.0, 0.0])
            x_pred = core._predict(x_prev, core.u, 1)
            eps = h0 + m - x_pred[:3]
            s1 += float(g @ (core._w * eps))
            s2 += float(g @ (core._w * g))
            jac = core._jacobian(x_prev, x_pred, core.u)
            e = jac @ ((1 - l_gain) * e - l_gain * np.array([1.0, 0.0, 0.0]))
    slot = (onset + 1 - 1) % core.cfg.window_scans  # the onset started at step onset+1 (slot = steps - 1)
    assert core.s1[k_b, slot] == pytest.approx(s1, rel=1e-6, abs=1e-9)
    assert core.s2[k_b, slot] == pytest.approx(s2, rel=1e-6)
    assert core.s1[k_b, slot] / core.s2[k_b, slot] == pytest.approx(bias, rel=0.02)


def _leak3(cs: CoSimulation) -> None:
    cs.plant.set_leak("T3", 0.2)


def _clog(valve: str):  # type: ignore[no-untyped-def]
    return lambda cs: cs.plant.set_valve(valve, 0.8)


def _sensor(lt: str, fault: SensorFault, value: float = 0.0):  # type: ignore[no-untyped-def]
    return lambda cs: cs.plant.set_fault(lt, fault, value)


@pytest.mark.parametrize(
    ("inject", "name", "size", "tol", "bound_s"),
    [
        (_leak3, "Leak_T3", 0.2, 0.04, 60.0),
        (_clog("V13"), "Clog_V13", 0.2, 0.04, 30.0),
        (_clog("V32"), "Clog_V32", 0.2, 0.04, 30.0),
        (_clog("V20"), "Clog_V20", 0.2, 0.04, 60.0),
        (_sensor("LT1", SensorFault.BIAS, 0.01), "Bias_LT1", 0.01, 0.002, 20.0),
        (_sensor("LT3", SensorFault.BIAS, -0.01), "Bias_LT3", -0.01, 0.002, 20.0),
        (_sensor("LT2", SensorFault.DRIFT, 1e-4), "Drift_LT2", 1e-4, 4e-5, 90.0),
        (_sensor("LT1", SensorFault.STUCK), "Stuck_LT1", None, None, 10.0),
    ],
)
def test_fault_isolated_within_a_bound(inject, name, size, tol, bound_s) -> None:  # type: ignore[no-untyped-def]
    core, _ = run(noisy_site(), 100.0 + bound_s + 5.0, inject)
    d = core.diagnosis
    assert d is not None, f"{name} not isolated within {bound_s} s"
    assert d.hypothesis.name == name
    assert d.t_s - 100.0 <= bound_s
    if size is not None:
        assert d.size == pytest.approx(size, abs=tol)
        assert d.size_std > 0.0


@pytest.mark.parametrize(
    "inject", [lambda cs: cs.plant.set_leak("T1", 0.2), lambda cs: cs.plant.set_pump_fraction("P1", 0.8)]
)
def test_leak_and_pump_loss_in_a_pumped_tank_are_detected(inject) -> None:  # type: ignore[no-untyped-def]
    """At a steady state a leak in T1 and P1's loss are both a constant deficit of T1's inflow:
    detected within 60 s; isolated only if a hypothesis pulls ahead, never as another class."""
    core, first = run(noisy_site(), 200.0, inject)
    assert first is not None and first - 100.0 <= 60.0
    rep = core.report
    assert rep is not None and rep.best is not None
    assert rep.best.name in ("Leak_T1", "Pump_P1")
    if core.diagnosis is not None:
        assert core.diagnosis.hypothesis.name in ("Leak_T1", "Pump_P1")


def test_no_alarm_in_a_long_fault_free_run() -> None:
    """Two hours of model time with 1 mm noise and setpoint changes: nothing detected."""

    def sp_changes(cs: CoSimulation) -> None:
        if round(cs.t_s) % 1200 == 600:
            cs.plc.set_sp("LIC1", 0.45 if round(cs.t_s) % 2400 == 600 else 0.4)

    cs = CoSimulation(noisy_site(seed=7))
    core = FdiCore(cs.site)
    worst = 0.0
    for k in range(7200):
        sp_changes(cs)
        cs.step()
        r = core.step(k, cs.trace.t_s[-1], cs.trace.readings_m[-1], np.ones(3, bool), cs.trace.commands[-1])
        assert r.state in (FdiState.WARMUP, FdiState.NORMAL), f"false alarm at {r.t_s} s: {r.best}"
        worst = max(worst, *(h.statistic for h in r.hypotheses if h.hypothesis.kind is not FaultKind.STUCK))
    assert 0.0 < worst < core.threshold


def test_restart_warms_up_without_false_alarm() -> None:
    """A reset mid-run (a supervisor restart) starts the observer at the next readings: warm-up,
    then normal; no alarm from the jump of the estimate."""
    core, _ = run(noisy_site(), 200.0)
    core.reset()
    cs = CoSimulation(noisy_site(seed=3))
    cs.run(150.0)  # the plant went on meanwhile (other seed: other readings)
    states = []
    for k in range(120):
        cs.step()
        r = core.step(
            1000 + k, cs.trace.t_s[-1], cs.trace.readings_m[-1], np.ones(3, bool), cs.trace.commands[-1]
        )
        states.append(r.state)
    assert states[0] is FdiState.WARMUP
    assert states[-1] is FdiState.NORMAL
    assert FdiState.DETECTED not in states and FdiState.ISOLATED not in states


def test_nan_reading_is_a_sensor_fault_not_a_crash() -> None:
    core, _ = run(noisy_site(), 60.0)
    y = np.array([math.nan, 0.2, 0.3])
    mv = np.array([3.5e-5, 3.2e-5])
    for k in range(5):
        r = core.step(100 + k, 60.0 + k, y, np.array([False, True, True]), mv)
    assert r.diagnosis is not None
    assert r.diagnosis.hypothesis.name == "Stuck_LT1"
    assert all(math.isfinite(h.statistic) and math.isfinite(h.size) for h in r.hypotheses)
