"""Closed-loop tests of the supervisor on the nonlinear plant (in-process co-simulation).

Every run is the same pure cores the processes use (plant RK4, PLC program, supervisor cycle)
stepped on model time by :class:`tankctl.cosim.CoSimulation`: no sleeps, no wall clock, and two
runs of one scenario are identical.

- The Energies scenario (digest 2.4 defaults, architecture settled detail "RLS data"): from empty
  tanks with u(-1) = 0 to the config's setpoints 0.4 / 0.2 m, a leak on T1 (opening 1.0, mu_L =
  0.25) from 600 s to 700 s, 1000 s at Ts = 1 s. The adapted PID's IAE must come within 20 % of
  the MPC's on both loops, and every gain set it pushed must pass the guards.
- The data pairing the adaptation rests on: on PLC-produced snapshots, MV(k) - MV(k-1) equals
  psi(k)' theta exactly, and the adapter recovers the PLC's gains from them.
- MPC mode on the OPC UA MPC paper's plant (digest 2.5): constraints hold on the nonlinear plant
  and a constant leak leaves no offset.
- Two hours at a constant setpoint with 0.1 mm of level noise (from equilibrium, and after the
  fill): bounded covariance, no gain drift.
- A destabilising gain set forced through the adapter never reaches the PLC; ADVISORY pushes
  nothing while its RLS learns.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from plant_sim.linearize import operating_point
from plant_sim.models import TankNetwork, default_inputs
from supervisor.adaptation import (
    AdaptationConfig,
    Decision,
    PidGainAdapter,
    PidGains,
    RejectReason,
    closed_loop_spectral_radius,
)
from supervisor.cycle import PlcSnapshot, SupervisorCore
from tankctl.cosim import CoSimulation, Trace
from tanklab.config import SiteConfig, load_site
from tanklab.enums import GainSource, LoopMode

ROOT = Path(__file__).resolve().parents[2]
ENERGIES = ROOT / "configs/three_tank_energies_sim.yaml"
KORTELA = ROOT / "configs/three_tank_kortela.yaml"

QMAX = 1.2e-4  # both pumps of both three-tank configs [m^3/s]
LEAK_OPEN_S, LEAK_CLOSE_S = 600.0, 700.0
ENERGIES_S = 1000.0


# --------------------------------------------------------------------------- helpers
def iae(trace: Trace) -> np.ndarray:
    """IAE per loop, sum |SP - level| Ts over the run [m s] (T1 = LIC1, T2 = LIC2; true levels)."""
    err = np.abs(trace.array("setpoints_m") - trace.array("levels_m")[:, :2])
    ts = float(np.diff(trace.array("t_s"))[0])
    return np.asarray(err.sum(axis=0) * ts)


def leak_on_t1(cs: CoSimulation) -> None:
    """Digest 2.4: T1's leak valve (mu_L = 0.25 in the config) open for samples 600 to 699."""
    if abs(cs.t_s - LEAK_OPEN_S) < 1e-9:
        cs.plant.set_leak("T1", 1.0)
    elif abs(cs.t_s - LEAK_CLOSE_S) < 1e-9:
        cs.plant.set_leak("T1", 0.0)


def decision_recorder(cs: CoSimulation, decisions: list[Decision]) -> Callable[[CoSimulation], None]:
    """A before_scan hook collecting every decision the adapter took (propose or submit)."""

    def hook(c: CoSimulation) -> None:
        assert c.supervisor is not None and c.supervisor.adapter is not None
        d = c.supervisor.adapter.last_decision
        if d is not None and (not decisions or decisions[-1] is not d):
            decisions.append(d)

    return hook


@dataclasses.dataclass
class EnergiesRun:
    cs: CoSimulation
    trace: Trace
    iae: np.ndarray
    decisions: list[Decision]


@cache
def energies(mode: str) -> EnergiesRun:
    """The Energies scenario in one supervisor mode (cached: each mode runs once per session)."""
    cs = CoSimulation(load_site(ENERGIES), supervisor_mode=mode)  # type: ignore[arg-type]
    decisions: list[Decision] = []
    record = decision_recorder(cs, decisions) if mode in ("ADVISORY", "ADAPTIVE_PID") else None

    def before_scan(c: CoSimulation) -> None:
        leak_on_t1(c)
        if record is not None:
            record(c)

    trace = cs.run(ENERGIES_S, before_scan)
    if record is not None:
        record(cs)  # the decision of the last cycle
    return EnergiesRun(cs, trace, iae(trace), decisions)


def at_equilibrium(site: SiteConfig, *, noise_std_m: float = 0.0) -> SiteConfig:
    """A copy of ``site`` starting at its operating point: levels and pump commands (so the PLC's
    u(-1) is the equilibrium flow), with transmitter noise ``noise_std_m`` on every tank."""
    site = site.model_copy(deep=True)
    net = TankNetwork.from_config(site.plant)
    op = operating_point(net, site.plant, default_inputs(net, site.plant))
    for tank, level in zip(site.plant.tanks, op.equilibrium_levels_m, strict=True):
        tank.initial_level_m = float(level)
        tank.transmitter.noise_std_m = noise_std_m
    for pump, command in zip(site.plant.pumps, op.commands, strict=True):
        pump.initial_command = float(command)
    return site


def gains_of(rows: np.ndarray) -> PidGains:
    """Diagonal gains from a trace row of applied (Kp, Ki, Kd) per loop, shape (n_loops, 3)."""
    return PidGains.diagonal(rows[:, 0], rows[:, 1], rows[:, 2])


# --------------------------------------------------------------------------- the outcome criterion
def test_energies_adapted_pid_within_20_percent_of_the_mpc() -> None:
    pid, adapted, mpc = energies("OFF"), energies("ADAPTIVE_PID"), energies("MPC")
    ratio = adapted.iae / mpc.iae
    numbers = (
        f"IAE T1 / T2 [m s]: pid {pid.iae.round(2)}, mpc_pid {adapted.iae.round(2)}, "
        f"mpc {mpc.iae.round(2)}; mpc_pid / mpc {ratio.round(3)}"
    )
    # Measured: pid 28.28 / 6.96, mpc_pid 15.58 / 5.68, mpc 13.99 / 5.45; ratios 1.113 / 1.043.
    assert (ratio <= 1.2).all(), numbers
    assert (adapted.iae < pid.iae).all(), numbers
    # The MPC's own fill is near the physical bound (both pumps at Qmax from empty: 15.7 / 7.4 over
    # an infinite horizon, digest 2.5): a sanity check that the comparison is not against a weak MPC.
    assert mpc.iae[0] < 15.0 and mpc.iae[1] < 6.0, numbers


def test_energies_adaptation_pushed_only_admissible_changed_gains() -> None:
    run = energies("ADAPTIVE_PID")
    core = run.cs.supervisor
    assert core is not None and core.adapter is not None
    adapter = core.adapter
    fixed = adapter.fixed
    frac = adapter.config.max_change_fraction
    floor = adapter.change_floor.stacked()  # the rate-limit floor in force (ADR 0014)
    site = run.cs.site
    assert site.plc is not None
    boxes = [lp.gain_box for lp in site.plc.loops]

    accepted = [d for d in run.decisions if d.accepted and d.changed]
    assert len(accepted) >= 1
    assert all(not d.reasons for d in accepted)
    assert core.pushes_refused == 0
    assert all(lp.source is GainSource.SUPERVISOR for lp in run.cs.plc.loops)

    # Every gain set the PLC applied is the fixed set or an accepted candidate, and passes the
    # guards recomputed here: box, signs, rate limit against the previous set, spectral radius.
    g = run.trace.array("gains")  # (scans, loops, 3)
    changes = [0] + [k for k in range(1, len(g)) if not np.array_equal(g[k], g[k - 1])]
    assert len(changes) >= 2
    candidates = [d.candidate for d in accepted]
    m = adapter.model
    previous = fixed
    for k in changes:
        applied = gains_of(g[k])
        assert applied.allclose(fixed, rtol=1e-12) or any(applied.allclose(c, rtol=1e-12) for c in candidates)
        for j, box in enumerate(boxes):
            assert box is not None and box.contains(*g[k, j])
            assert g[k, j, 0] >= 0.0 and g[k, j, 1] >= 0.1 * fixed.ki[j, j]
        step = np.abs(applied.stacked() - previous.stacked())
        limit = np.maximum(frac * np.abs(previous.stacked()), floor)
        assert (step <= limit * (1 + 1e-9)).all()
        rho = closed_loop_spectral_radius(m.A, m.B, m.C, applied.kp, applied.ki, applied.kd, m.ts_s)
        assert rho < adapter.config.max_spectral_radius
        previous = applied

    # The gains really changed (not the fixed ones pushed back): the final set is far from them.
    final = gains_of(g[-1])
    ki_growth = final.ki.diagonal() / fixed.ki.diagonal()
    assert ki_growth.min() > 2.0, ki_growth  # both Ki grew more than twofold


# --------------------------------------------------------------------------- data pairing
def test_plc_snapshots_satisfy_the_regression_exactly_and_the_adapter_recovers_their_gains() -> None:
    # The PLC runs "teacher" gains (not the config's fixed ones) from equilibrium through setpoint
    # steps small enough that no MV clamps. The supervisor's snapshots (one Read per scan: SP, PV,
    # MV, gains, scan counter) then satisfy MV(k) - MV(k-1) = psi(k)' theta with psi(k) from
    # snapshots k, k-1, k-2: the pairing SupervisorCore._compute relies on (the shadow MPC's u(-1)
    # is the previous snapshot's MV; its u_MPC(k) is regressed on psi(k) of the current one).
    base = load_site(ENERGIES)
    teacher_site = at_equilibrium(base)
    assert teacher_site.plc is not None
    teacher_gains = [(6.0e-4, 2.0e-5, -1.0e-4), (9.0e-4, 6.0e-5, -8.0e-4)]
    for lp, (kp, ki, kd) in zip(teacher_site.plc.loops, teacher_gains, strict=True):
        assert lp.gains is not None
        lp.gains.kp, lp.gains.ki, lp.gains.kd = kp, ki, kd
    cs = CoSimulation(teacher_site, supervisor_mode="ADVISORY")
    snaps: list[PlcSnapshot] = []
    steps = {20.0: ("LIC1", 0.42), 80.0: ("LIC2", 0.185), 150.0: ("LIC1", 0.39), 220.0: ("LIC2", 0.21)}

    def before_scan(c: CoSimulation) -> None:
        assert c.supervisor is not None
        if c.supervisor.last is not None:
            snaps.append(c.supervisor.last)
        for t, (loop, sp) in steps.items():
            if abs(c.t_s - t) < 1e-9:
                c.plc.set_sp(loop, sp)

    cs.run(300.0, before_scan)
    assert [s.scan for s in snaps] == list(range(1, len(snaps) + 1))
    mv = np.array([s.mv for s in snaps])
    assert ((mv > 0.0) & (mv < QMAX)).all()  # never clamped: the increment is the PID's exactly
    worst = 0.0
    for s0, s1, s2 in zip(snaps, snaps[1:], snaps[2:], strict=False):
        e0, e1, e2 = (s.sp_m - s.pv_m for s in (s0, s1, s2))
        psi = np.stack([e2 - e1, e2, e2 - 2 * e1 + e0], axis=1)  # Ts = 1 s
        worst = max(worst, float(np.abs((s2.mv - s1.mv) - (psi * s2.gains).sum(axis=1)).max()))
    assert worst < 1e-18  # measured 9e-21 (rounding of ~1e-5 m^3/s moves)

    # An adapter for the config's fixed gains, taught by the PLC's own PID (u_MPC := MV), recovers
    # the teacher gains. The data are noiseless and four steps are little excitation, so this
    # adapter fits them all (no dead zone, no forgetting, a prior as weak as the cap allows).
    core = SupervisorCore(base)
    assert core.adapter is not None
    cfg = dataclasses.replace(
        core.adapter.config, excitation_threshold=0.0, memory_s=math.inf, prior_weight=1e-9
    )
    adapter = PidGainAdapter(core.adapter.model, core.adapter.fixed, cfg)
    for s in snaps:
        adapter.observe(scan=s.scan, t_s=s.t_s, sp=s.sp_m, pv=s.pv_m, mv=s.mv, u_mpc=s.mv, x=s.levels_m)
    est = adapter.estimate().stacked()
    teacher = PidGains.diagonal(*np.array(teacher_gains).T).stacked()
    # Measured: 1.3e-5 relative (what is left of the prior); the fixed gains differ by 17 to 280 %.
    np.testing.assert_allclose(est.diagonal(axis1=1, axis2=2), teacher.diagonal(axis1=1, axis2=2), rtol=1e-4)


# --------------------------------------------------------------------------- MPC mode, Kortela plant
def test_kortela_mpc_keeps_every_constraint_and_removes_a_constant_leak_offset() -> None:
    # Digest 2.5 tuning: Np = 40, Qz = S = I, u in [0, 1.2e-4], |du| <= 1e-6 m^3/s per 2.5 s step on
    # every move (first included), z in [0, 0.63] m. Setpoint steps, then T1's leak valve fully
    # open from 1000 s: q_L = 0.25 * 5e-5 * sqrt(2 g 0.38) = 3.4e-5 m^3/s, 60 % of Q1's operating
    # flow. At 1e-6 per step the MPC needs at least 34 moves (85 s) to add that much flow; the
    # estimator's disturbance estimate and the move-by-move limit make it take a few hundred
    # seconds (measured: |e1| 5.5e-4 m at 1200 s, 2e-10 m at 1500 s). The run goes to 3000 s and
    # the offset is checked over the last 1000 s.
    cs = CoSimulation(load_site(KORTELA), supervisor_mode="MPC")

    def before_scan(c: CoSimulation) -> None:
        if abs(c.t_s - 25.0) < 1e-9:
            c.plc.set_sp("LIC1", 0.45)
            c.plc.set_sp("LIC2", 0.25)
        elif abs(c.t_s - 500.0) < 1e-9:
            c.plc.set_sp("LIC1", 0.38)
        elif abs(c.t_s - 1000.0) < 1e-9:
            c.plant.set_leak("T1", 1.0)

    tr = cs.run(3000.0, before_scan)
    t = tr.array("t_s")
    levels, sp = tr.array("levels_m"), tr.array("setpoints_m")
    flows, cmd = tr.array("flows_m3_s"), tr.array("commands")
    core = cs.supervisor
    assert core is not None and core.result is not None
    assert core.result.failures == 0
    # The MPC drives from the first cycle on (loops in REMOTE, bumpless entry at the applied MV).
    assert (tr.array("modes")[1:] == int(LoopMode.REMOTE)).all()
    # Constraints, on the nonlinear plant, at every scan.
    assert flows.min() >= 0.0 and flows.max() <= QMAX
    du = np.abs(np.diff(cmd, axis=0))
    assert du.max() <= 1e-6 + 1e-12  # measured: exactly 1e-6, the limit binds
    assert levels.min() >= 0.0 and levels.max() <= 0.63
    # The rate limit is what makes the leak recovery slow: it binds on many moves after the leak.
    after_leak = t[1:] > 1000.0
    assert int((du[after_leak, 0] >= 1e-6 * (1 - 1e-9)).sum()) >= 30
    # Zero offset under the constant leak, after settling. Bound: 1e-5 m (0.01 mm), far below what
    # a transmitter resolves and well above the solver tolerance (measured 3e-11 m).
    settled = t >= 2000.0
    offset = np.abs(sp[settled] - levels[settled, :2]).max(axis=0)
    assert (offset < 1e-5).all(), offset
    # ...and the leak really is being compensated: pump 1 delivers the leak flow on top.
    before = flows[(t > 900.0) & (t <= 1000.0), 0].mean()
    assert flows[settled, 0].mean() - before > 3.0e-5


# --------------------------------------------------------------------------- two hours, no drift
@pytest.mark.parametrize("start", ["equilibrium", "after_the_fill"])
def test_two_hours_at_a_constant_setpoint_with_level_noise_neither_inflate_nor_drift(start: str) -> None:
    # 0.1 mm of transmitter noise on every tank (digest 2.3: the bare RLS drifts 66 % in such
    # conditions; with the default 0.1 mm dead zone the adapter's Ki1 grew 188-fold in 2 h),
    # setpoints held, ADAPTIVE_PID, 7200 s of constant phase:
    # - "equilibrium": starts at 0.4 / 0.2 / 0.3 m with the pumps at the equilibrium flows (so the
    #   PLC's u(-1) is the operating flow); the RLS is at its prior (trace = the cap);
    # - "after_the_fill": the Energies fill from empty first (300 s, the gains adapt), so the
    #   constant phase starts from a learned covariance below the cap.
    base = load_site(ENERGIES)
    if start == "equilibrium":
        site, t_start = at_equilibrium(base, noise_std_m=1e-4), 0.0
    else:
        site, t_start = base.model_copy(deep=True), 300.0
        for tank in site.plant.tanks:
            tank.transmitter.noise_std_m = 1e-4
    cs = CoSimulation(site, supervisor_mode="ADAPTIVE_PID")
    core = cs.supervisor
    assert core is not None and core.adapter is not None
    adapter = core.adapter
    cap = 3 * adapter.config.p0  # the default cap n_params * p0 (3 parameters per pump)
    traces: list[list[float]] = []

    def before_scan(c: CoSimulation) -> None:
        traces.append([p.covariance_trace for p in adapter.diagnostics().pumps])

    tr = cs.run(t_start + 7200.0, before_scan)
    traces.append([p.covariance_trace for p in adapter.diagnostics().pumps])
    trace_p = np.array(traces)
    assert np.isfinite(trace_p).all()
    assert (trace_p <= cap * (1 + 1e-12)).all()  # bounded at every sample
    k0 = int(np.searchsorted(tr.array("t_s"), t_start))
    if start == "after_the_fill":
        assert (trace_p[k0:] < 0.6 * cap).all()  # learned (measured 1350 / 1486 of 3000), and stays
        assert not np.array_equal(tr.array("gains")[k0], tr.array("gains")[0])  # the fill adapted
    # From the model-based tuning on (ADR 0014: the first pushes move the printed gains to it and
    # the fill's data correct it; 600 s is ample), the gains hold: noise adapts nothing (the dead
    # zone) and the noise limit's hysteresis keeps its scatter out (measured: 15 % drift without).
    k1 = int(np.searchsorted(tr.array("t_s"), t_start + 600.0)) if start == "equilibrium" else k0
    g = tr.array("gains")[k1:]
    drift = np.abs(g - g[0]) / np.maximum(np.abs(g[0]), 1e-12)
    assert drift.max() <= 0.05, drift.max(axis=0)  # measured 0 (equilibrium), 0.2 % (after the fill)
    # The loops held their setpoints through it (no limit cycle, no slow wander).
    dev = np.abs(tr.array("levels_m")[k0:, :2] - tr.array("setpoints_m")[k0:])
    assert dev.max() < 2e-3  # measured 0.08 mm / 0.43 mm
    assert adapter.diagnostics().rejected_pushes == 0


# --------------------------------------------------------------------------- guards in closed loop
def test_a_destabilising_gain_set_forced_through_the_adapter_never_reaches_the_plc(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    site = load_site(ENERGIES)
    cs = CoSimulation(site, supervisor_mode="ADAPTIVE_PID")
    core = cs.supervisor
    assert core is not None and core.adapter is not None and site.plc is not None
    adapter = core.adapter
    # LIC1 with Kp = 0, Ki = 1e-3, Kd = -1e-2 (G0 = Kp + Ki Ts + Kd / Ts < 0): rho = 1.076 on the
    # model, unstable. Inside the PLC's gain_box, so only the adapter's guards stand between it and
    # the PLC.
    box = site.plc.loops[0].gain_box
    assert box is not None and box.contains(0.0, 1e-3, -1e-2)
    forced_at = {100.0, 200.0, 300.0}
    forced: list[Decision] = []
    real_propose = adapter.propose

    def propose(t_s: float) -> Decision | None:
        if t_s in forced_at:
            g = adapter.applied.stacked().copy()
            g[:, 0, 0] = [0.0, 1e-3, -1e-2]
            decision = adapter.submit(PidGains.from_stacked(g), t_s)
            forced.append(decision)
            return decision
        return real_propose(t_s)

    monkeypatch.setattr(adapter, "propose", propose)
    tr = cs.run(400.0, leak_on_t1)
    assert [d.t_s for d in forced] == sorted(forced_at)
    for d in forced:
        assert not d.accepted and RejectReason.UNSTABLE in d.reasons
        assert d.spectral_radius > 1.0  # unstable, not merely inside the margin
    g = tr.array("gains")
    assert not np.any((g[:, 0, 0] == 0.0) & (g[:, 0, 2] == -1e-2))
    # The cycle that took each forced decision wrote no gains: the next scan runs the same set.
    t = tr.array("t_s")
    for t_forced in forced_at:
        k = int(np.searchsorted(t, t_forced))
        assert t[k] == t_forced and np.array_equal(g[k + 1], g[k])
    assert core.pushes_refused == 0
    assert adapter.diagnostics().rejected_by_reason.get("unstable", 0) >= len(forced_at)


def test_advisory_pushes_nothing_while_its_rls_learns() -> None:
    run = energies("ADVISORY")
    core = run.cs.supervisor
    assert core is not None and core.adapter is not None
    adapter = core.adapter
    g = run.trace.array("gains")
    assert (g == g[0]).all()
    assert gains_of(g[0]).allclose(adapter.fixed, rtol=0.0)
    assert all(lp.source is GainSource.FIXED for lp in run.cs.plc.loops)
    assert run.decisions == []
    diag = adapter.diagnostics()
    assert diag.accepted_pushes == diag.rejected_pushes == 0
    # ...while the RLS state moved: informative samples and an estimate away from the fixed gains.
    for i, p in enumerate(diag.pumps):
        assert p.samples_used + p.one_sided_updates > 10
        fixed_i = [adapter.fixed.kp[i, i], adapter.fixed.ki[i, i], adapter.fixed.kd[i, i]]
        assert not np.allclose(p.theta, fixed_i, rtol=0.1)
    # Same plant response as the supervisor-free PID: advice only.
    np.testing.assert_array_equal(run.trace.array("levels_m"), energies("OFF").trace.array("levels_m"))


def test_adaptation_config_of_the_energies_site() -> None:
    # The values the outcome rests on, stated in the config with their reasons (ADR 0006).
    core = SupervisorCore(load_site(ENERGIES))
    assert core.adapter is not None
    cfg = core.adapter.config
    assert cfg.saturated == "one_sided"
    assert cfg.max_change_fraction == pytest.approx(np.exp(10.0 / 27.2) - 1.0, abs=0.005)
    assert cfg.excitation_threshold == 0.02
    assert isinstance(cfg, AdaptationConfig)


def test_mpc_sheds_to_advisory_when_a_loop_leaves_remote() -> None:
    """An operator takes LIC1 out of REMOTE under a running MPC: the supervisor stops claiming
    MPC (sheds to ADVISORY, counted, with the reason), puts LIC2 back to AUTO bumplessly and
    leaves LIC1 as the operator set it; an engineer's new request re-engages MPC."""
    from tankctl.cosim import CoSimulation
    from tanklab.config import load_site
    from tanklab.enums import LoopMode
    from tanklab.enums import SupervisorMode as Mode

    site = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
    cs = CoSimulation(site, supervisor_mode="MPC")
    cs.run(30.0)
    sup = cs.supervisor
    assert sup is not None and sup.mode is Mode.MPC
    assert [lp.mode for lp in cs.plc.loops] == [LoopMode.REMOTE, LoopMode.REMOTE]
    cs.plc.set_mode("LIC1", LoopMode.MANUAL)
    mv2 = cs.plc.loop("LIC2").mv
    cs.run(5.0)
    assert sup.mode is Mode.ADVISORY and sup.sheds == 1
    assert "LIC1 left REMOTE" in sup.shed_reason
    assert [lp.mode for lp in cs.plc.loops] == [LoopMode.MANUAL, LoopMode.AUTO]
    assert abs(cs.trace.commands[-5][1] - mv2) <= 0.01 * 1.2e-4  # LIC2's switch to AUTO is bumpless
    cs.plc.set_mode("LIC1", LoopMode.AUTO)
    sup.request_mode(Mode.MPC)
    cs.run(5.0)
    assert sup.mode is Mode.MPC and sup.sheds == 1
    assert [lp.mode for lp in cs.plc.loops] == [LoopMode.REMOTE, LoopMode.REMOTE]
