"""Closed-loop tests of the soft PLC through the co-simulation, on the nonlinear plant.

The PLC program (plc_emulator.program) and the plant (plant_sim) are stepped together on model
time by tankctl.cosim.CoSimulation, exactly as in lock-step. Each test reproduces a number of the
seeds digest or an item of issue 3 and states the measured value next to the assertion:

- Energies default config from empty tanks (fixed PID, e(-1) = 0): T1 overshoot 3.10 %,
  settling (2 % band) 288 s; the digest: 3.1 % and about 290 s.
- Single tank NL-PI at Ts = 0.01 s, steps 0.05 / 0.10 / 0.15 m: 4.39 / 4.34 / 4.32 % (4.3 % within
  0.5 points at every level); a plain velocity-form PI placed at wn, zeta on the linearisation at
  0.15 m: 0.00 / 0.25 / 3.26 % (it does not).
- A full leak on T1 is rejected (back within 1 cm of SP), heartbeat loss falls back within
  Timeout + 1 scan and holds the levels within 2 cm, an interlock trips within one scan, a lost
  field link is ridden through, and two runs give identical traces.

Kept fast: the Energies runs start at the operating point (the equilibrium flows as the pumps'
initial commands) except the one that reproduces the start from empty.
"""

from __future__ import annotations

import copy
import math
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from numpy.typing import NDArray

from plant_sim.linearize import operating_point
from plant_sim.models import TankNetwork, default_inputs
from plc_emulator.program import GainStatus
from plc_emulator.publish import status_values
from tankctl.cosim import CoSimulation, Trace
from tanklab.config import SiteConfig, site_from_mapping
from tanklab.enums import GainSource, LoopMode

ROOT = Path(__file__).resolve().parents[2]
SPAN = 1.2e-4  # Energies pump range [0, 1.2e-4] m^3/s
FloatArray = NDArray[np.float64]


def raw(name: str) -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((ROOT / "configs" / name).read_text())
    return data


@cache
def energies_op() -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Equilibrium levels and pump flows of the Energies config at its operating point."""
    site = site_from_mapping(raw("three_tank_energies_sim.yaml"))
    net = TankNetwork.from_config(site.plant)
    op = operating_point(net, site.plant, default_inputs(net, site.plant))
    return tuple(map(float, op.equilibrium_levels_m)), tuple(map(float, op.flows_m3_s))


def energies_at_op(**loop2: Any) -> dict[str, Any]:
    """The Energies config starting at rest at its operating point (0.4, 0.2, 0.3 m)."""
    d = raw("three_tank_energies_sim.yaml")
    levels, flows = energies_op()
    for tank, h in zip(d["plant"]["tanks"], levels, strict=True):
        tank["initial_level_m"] = h
    for pump, q in zip(d["plant"]["pumps"], flows, strict=True):
        pump["initial_command"] = q
    d["plc"]["loops"][1].update(loop2)
    return d


def site_of(data: dict[str, Any]) -> SiteConfig:
    return site_from_mapping(copy.deepcopy(data))


def overshoot_pct(h: FloatArray, before: float, after: float) -> float:
    """Peak overshoot of a step from ``before`` to ``after`` [% of the step]."""
    return float((h.max() - after) / (after - before) * 100.0)


def settling_s(t: FloatArray, h: FloatArray, sp: float, band: float = 0.02) -> float:
    """First time after which h stays within ``band`` (fraction) of ``sp`` [s]."""
    outside = np.nonzero(np.abs(h - sp) > band * sp)[0]
    return float(t[outside[-1] + 1]) if outside.size else float(t[0])


# =========================================================================== Energies from empty
def test_energies_fixed_pid_from_empty_reproduces_the_digest() -> None:
    # Digest 2.1: with e(-1) = e(-2) = 0 and u(-1) = 0, T1's overshoot from empty is 3.1 % and
    # it settles in about 290 s. Measured here: 3.098 % and 288 s (2 % band), T2: 7.96 %, 177 s.
    # Tolerance: the plant is noise-free and deterministic, and the adaptive solver (solve_ivp)
    # gives the same overshoot to 2e-6 points (checked below), so what is left is the digest's
    # own rounding: 3.1 % printed to 0.1 point (+-0.05), "about 290 s" at a 1 s scan (+-10 s).
    site = site_of(raw("three_tank_energies_sim.yaml"))
    tr = CoSimulation(site).run(600.0)
    ref = CoSimulation(site, integrator="adaptive").run(600.0)
    t, h = tr.array("t_s"), tr.array("levels_m")
    os1, ts1 = overshoot_pct(h[:, 0], 0.0, 0.4), settling_s(t, h[:, 0], 0.4)
    os2, ts2 = overshoot_pct(h[:, 1], 0.0, 0.2), settling_s(t, h[:, 1], 0.2)
    print(f"\nEnergies from empty: T1 OS {os1:.3f} % ts {ts1:.0f} s; T2 OS {os2:.3f} % ts {ts2:.0f} s")
    assert os1 == pytest.approx(overshoot_pct(ref.array("levels_m")[:, 0], 0.0, 0.4), abs=1e-4)
    assert os1 == pytest.approx(3.1, abs=0.05)
    assert ts1 == pytest.approx(290.0, abs=10.0)
    assert abs(h[-1, 0] - 0.4) < 1e-3 and abs(h[-1, 1] - 0.2) < 1e-3  # integral action: no offset
    u = tr.array("commands")
    assert np.all((u >= 0.0) & (u <= SPAN))
    # The literal PID II: Kp + Ki Ts + Kd/Ts < 0, so its first move from empty is down (clamped at 0).
    assert u[0, 1] == 0.0


# =========================================================================== NL-PI vs plain PI
SINGLE_TS = 0.01
STEPS = ((0.0, 0.05), (0.05, 0.10), (0.10, 0.15))  # (before, after) at t = 0, 50, 100 s


def step_overshoots(data: dict[str, Any]) -> list[float]:
    """Run the paper's schedule at Ts = 0.01 s; overshoot of each step in its 50 s window."""
    cs = CoSimulation(site_of(data), scan_period_s=SINGLE_TS)
    per_step = round(50.0 / SINGLE_TS)
    for _, sp in STEPS:
        cs.plc.set_sp("LIC1", sp)
        for _ in range(per_step):
            cs.step()
    h = cs.trace.array("levels_m")[:, 0]
    return [
        overshoot_pct(h[k * per_step : (k + 1) * per_step], before, after)
        for k, (before, after) in enumerate(STEPS)
    ]


def test_nlpi_gives_the_same_second_order_step_at_every_level() -> None:
    # Digest 2.2: zeta = 0.7071 gives 4.32 % at every level in continuous time; measured at
    # Ts = 0.01 s: 4.39 / 4.34 / 4.32 %.
    os_ = step_overshoots(raw("single_tank_short_sim.yaml"))
    print(f"\nNL-PI overshoots at 0.05 / 0.10 / 0.15 m: {', '.join(f'{x:.3f}' for x in os_)} %")
    assert os_ == pytest.approx([4.32] * 3, abs=0.5)
    assert max(os_) - min(os_) < 0.1  # the same response at every level


def test_plain_pi_tuned_at_one_level_does_not() -> None:
    # Linearised at h0 = 0.15 m, dh/dt = b du - a dh with a = a' / (2 sqrt h0) = 0.6455 /s; a PI
    # (P on the error, as the velocity form has it) places s^2 + (a + b Kp) s + b Ki at the same
    # wn = 0.5, zeta = 0.7071: Kp = (2 zeta wn - a) / b = 0.0308, Ki = wn^2 / b = 0.125.
    # Measured: 0.00 / 0.25 / 3.26 % (and tuned at 0.10 m instead, Kp = -0.0417: 0.0 / 2.5 / 9.8 %).
    b, a_prime, zeta, wn, h0 = 2.0, 0.5, 0.7071, 0.5, 0.15
    a = a_prime / (2.0 * math.sqrt(h0))
    data = raw("single_tank_short_sim.yaml")
    loop = data["plc"]["loops"][0]
    loop["block"] = "pid"
    loop["gains"] = {"kp": (2.0 * zeta * wn - a) / b, "ki": wn**2 / b, "kd": 0.0}
    os_ = step_overshoots(data)
    print(f"\nplain PI (tuned at 0.15 m) overshoots: {', '.join(f'{x:.3f}' for x in os_)} %")
    assert all(abs(x - 4.32) > 0.5 for x in os_)
    assert max(os_) - min(os_) > 2.0  # the response changes with the level


# =========================================================================== disturbances
def test_leak_on_t1_is_rejected() -> None:
    # Full leak on T1 at 50 s (about 3.5e-5 m^3/s at 0.4 m, as much as P1's operating flow):
    # measured dip 4.3 cm, back within 1 cm of SP 218 s after the leak opened, P1 at 7.0e-5.
    cs = CoSimulation(site_of(energies_at_op()))
    cs.run(50.0)
    cs.plant.set_leak("T1", 1.0)
    tr = cs.run(450.0)
    t, h = tr.array("t_s"), tr.array("levels_m")[:, 0]
    after = t >= 50.0
    dip = float(np.max(0.4 - h[after]))
    back = settling_s(t[after], h[after], 0.4, band=0.01 / 0.4) - 50.0
    print(f"\nleak: dip {100 * dip:.2f} cm, back within 1 cm after {back:.0f} s, P1 {tr.commands[-1][0]:.3e}")
    assert dip > 0.02  # the leak is a real disturbance
    assert back < 300.0
    assert abs(h[-1] - 0.4) < 0.01
    assert tr.commands[-1][0] > 1.9 * energies_op()[1][0]  # P1 now also feeds the leak


# =========================================================================== watchdog
def test_heartbeat_loss_falls_back_within_timeout_plus_one_scan() -> None:
    # The supervisor beats every scan, pushes gains for LIC1 and drives LIC2 in REMOTE at the
    # equilibrium flow; a leak on T1 (opening 0.3) at 40 s keeps both loops moving. The supervisor
    # dies after the scan at 60 s. LIC1 goes SUPERVISOR -> FALLBACK and LIC2 REMOTE -> AUTO on the
    # same scan, at 63 s (last write before the scan at 60 s, Timeout 3 s, Ts 1 s: within
    # Timeout + 1 scan); measured dMV on that scan 1.45e-7 and 1.6e-8 m^3/s (0.12 % and 0.013 %
    # of the span); both levels then stay within 2 cm of SP for 300 s.
    cs = CoSimulation(site_of(energies_at_op(mode="REMOTE")))
    plc = cs.plc
    q2 = energies_op()[1][1]
    t_last_write = 60.0
    gains_staged = False
    switch: dict[str, float] = {}
    dmv: dict[str, float] = {}
    while cs.t_s < t_last_write + 305.0:
        t = cs.t_s
        if t == 40.0:
            cs.plant.set_leak("T1", 0.3)
        if t <= t_last_write:
            plc.heartbeat(round(t))
            if plc.loop("LIC2").mode is LoopMode.REMOTE:
                plc.set_remote_mv("LIC2", q2)
            if not gains_staged and plc.supervisor_trusted:
                assert plc.stage_gains("LIC1", 1.2 * 4.29e-4, 1.2 * 5.32e-6, -1.42e-4) is GainStatus.STAGED
                gains_staged = True
        before = {lp.spec.name: lp.mv for lp in plc.loops}
        cs.step()
        lic1, lic2 = plc.loop("LIC1"), plc.loop("LIC2")
        if "LIC1" not in switch and lic1.source is GainSource.FALLBACK:
            switch["LIC1"], dmv["LIC1"] = t, lic1.mv - before["LIC1"]
        if "LIC2" not in switch and lic2.mode is LoopMode.AUTO:
            switch["LIC2"], dmv["LIC2"] = t, lic2.mv - before["LIC2"]
    assert gains_staged
    tr = cs.trace
    times, h = tr.array("t_s"), tr.array("levels_m")
    print(f"\nheartbeat loss: switch at {switch} (last write before {t_last_write} s), dMV {dmv}")
    assert switch == {"LIC1": t_last_write + 3.0, "LIC2": t_last_write + 3.0}
    assert all(s <= t_last_write + 3.0 + cs.ts_s for s in switch.values())
    assert all(d != 0.0 for d in dmv.values())  # the loops are active at the switch
    assert all(abs(d) <= 0.01 * SPAN for d in dmv.values())
    after = times >= switch["LIC1"]
    assert np.max(np.abs(h[after, 0] - 0.4)) < 0.02
    assert np.max(np.abs(h[after, 1] - 0.2)) < 0.02
    assert status_values(plc.status())["PLC.Alarms.SupervisorLost"] is True


# =========================================================================== interlock
def test_interlock_trips_when_the_setpoint_is_driven_high() -> None:
    # T1's high-high lowered to 0.45 m (reset below 0.43 m). SP 0.55 at 20 s drives T1 up; on
    # the first scan whose reading is at or above 0.45 P1 is commanded 0, and stays at 0 (latched)
    # while the level falls. The operator sets SP 0.40 and presses Reset every scan: refused until
    # T1 < 0.43; after the reset the loop resumes from 0 without a bump.
    def lower_hh(d: dict[str, Any]) -> None:
        d["plc"]["interlocks"][0].update(high_high_m=0.45, reset_below_m=0.43)

    data = energies_at_op()
    lower_hh(data)
    cs = CoSimulation(site_of(data))
    plc = cs.plc
    cs.run(20.0)
    plc.set_sp("LIC1", 0.55)
    trip_scan = None
    reset_at = None
    while cs.t_s < 400.0:
        reading = float(cs.plant.readings[0])
        if trip_scan is not None and reset_at is None:
            plc.set_sp("LIC1", 0.40)
            if plc.reset_interlocks():
                reset_at = cs.t_s
        cs.step()
        tripped = status_values(plc.status())["PLC.Interlock.T1HH"]
        u1 = cs.trace.commands[-1][0]
        if reading >= 0.45 and trip_scan is None:
            trip_scan = cs.t_s - cs.ts_s
            assert tripped and u1 == 0.0  # within the scan that read it
        if trip_scan is not None and reset_at is None:
            assert tripped and u1 == 0.0  # latched until the reset
    assert trip_scan is not None and reset_at is not None
    t, h, u = cs.trace.array("t_s"), cs.trace.array("levels_m")[:, 0], cs.trace.array("commands")[:, 0]
    k_reset = int(np.searchsorted(t, reset_at))
    print(
        f"\ninterlock: tripped at {trip_scan:.0f} s, peak {h.max():.4f} m, reset at {reset_at:.0f} s "
        f"(T1 {h[k_reset]:.4f} m), first MV after reset {u[k_reset]:.3e}"
    )
    assert h.max() < 0.45 + SPAN / 0.0154 * cs.ts_s  # overshoots HH by at most one scan's rise
    assert h[k_reset] < 0.43
    assert abs(u[k_reset] - u[k_reset - 1]) <= 0.01 * SPAN
    assert abs(h[-1] - 0.40) < 0.02  # back under control


# =========================================================================== field link
def test_link_loss_then_recovery_substitutes_and_resumes_bumplessly() -> None:
    # A leak on T1 (opening 0.25) at 20 s keeps both loops moving; then 20 scans without the field
    # link from 50 s. LIC1 holds (substitute "hold"), LIC2 goes to its substitute value 3.2e-5 on
    # the 3rd bad scan (pv_bad_scans 3); the plant keeps the last commands it got. IoHealthy is
    # false all along. When the link returns, both loops resume from their applied MV with an
    # integral-only move (measured 6.6e-8 and 1.5e-8 m^3/s), the plant's commands move by less
    # than 1 % of the span, and T1 stays within 1.4 cm of SP.
    sub = 3.2e-5
    cs = CoSimulation(site_of(energies_at_op(substitute="value", substitute_mv=sub)))
    plc = cs.plc
    cs.run(20.0)
    cs.plant.set_leak("T1", 0.25)
    cs.run(30.0)
    mv_before = cs.trace.commands[-1].copy()
    healthy = []
    for _ in range(20):
        cs.io_healthy = False
        cs.step()
        healthy.append(status_values(plc.status())["PLC.Status.IoHealthy"])
    lost = cs.trace.array("commands")[-20:]
    plant_cmd = cs.plant.commands  # what the plant kept running on
    cs.io_healthy = True
    cs.run(200.0)
    u = cs.trace.array("commands")
    k = 70  # first scan after the link came back (t = 70 s)
    h = cs.trace.array("levels_m")
    print(
        f"\nlink loss: LIC2 substitute from scan {50 + int(np.argmax(lost[:, 1] == sub))}, "
        f"dMV on recovery {u[k] - u[k - 1]}, max |dh1| {np.max(np.abs(h[50:, 0] - 0.4)):.2e} m"
    )
    assert not any(healthy)
    assert np.all(lost[:, 0] == mv_before[0])  # hold
    assert np.all(lost[:2, 1] == mv_before[1]) and np.all(lost[2:, 1] == sub)  # value after 3 scans
    assert np.all(plant_cmd == mv_before)
    assert np.all(u[k] != u[k - 1])  # the loops are active
    assert np.all(np.abs(u[k] - u[k - 1]) <= 0.01 * SPAN)  # PLC side: bumpless
    assert np.all(np.abs(u[k] - plant_cmd) <= 0.01 * SPAN)  # plant side
    assert np.max(np.abs(h[50:, 0] - 0.4)) < 0.02 and np.max(np.abs(h[50:, 1] - 0.2)) < 0.02
    assert abs(h[-1, 0] - 0.4) < 0.01


# =========================================================================== determinism
def _noisy_scenario() -> Trace:
    data = energies_at_op()
    for tank in data["plant"]["tanks"]:
        tank["transmitter"] = {"noise_std_m": 1e-3, "quantization_m": 1e-4}
    cs = CoSimulation(site_of(data))

    def events(c: CoSimulation) -> None:
        if c.t_s == 30.0:
            c.plc.set_sp("LIC1", 0.45)
        if c.t_s == 80.0:
            c.plant.set_leak("T2", 0.5)
        c.plc.heartbeat(round(c.t_s) if c.t_s < 100.0 else 0)

    return cs.run(200.0, events)


def test_two_runs_give_identical_traces() -> None:
    a, b = _noisy_scenario(), _noisy_scenario()
    for name in ("t_s", "levels_m", "readings_m", "commands", "setpoints_m", "flows_m3_s"):
        assert np.array_equal(a.array(name), b.array(name)), name
    assert np.std(np.diff(a.array("readings_m")[:, 0])) > 1e-4  # the noise is really there
