"""The supervisor's cycle: from one PLC snapshot to the actions the SCADA level takes.

The supervisor sees every PLC scan's snapshot (through :class:`supervisor.port.SupervisorDriver`):
in ONE Read, the PLC's scan counter, model time, every loop's SP, PV, MV, mode and applied gains,
and every level the PLC reads; so errors and MVs belong to the same scan. Between samples it only
tracks the MV the PLC applied (:meth:`SupervisorCore.track`); every ``supervisor.sample_time_s``
(a whole number of PLC scans) it runs a cycle (:meth:`SupervisorCore.cycle`): the estimate is
brought to the snapshot's scan with those MVs and corrected with its levels
(:mod:`supervisor.timing`), then, by mode:

- OFF: the estimate is kept up to date; nothing is planned or pushed; the heartbeat goes on.
- ADVISORY: the MPC runs in the shadow of the PLC's PID from x(k|k), with its previous input
  the MV applied over the scan before this one; the RLS learns; plans and estimates are
  published, nothing is pushed.
- ADAPTIVE_PID: as ADVISORY, and every push period the adapter proposes a gain set that passes
  every guard; it is pushed through ``SetGains`` (digest 2.4 with its corrections).
- MPC: the loops are put in REMOTE and the MPC's input, converted to each pump's unit, is
  written to ``RemoteMV`` every sample (the OPC UA MPC paper's architecture). The move reaches the
  pumps at the next PLC scan, so the plan starts from the state the committed MV(k) leads to one
  scan ahead, with u(-1) = MV(k) (the timing diagram is in :mod:`supervisor.timing`). When a loop
  leaves REMOTE behind the supervisor's back (the PLC's watchdog fell back after a stall, an
  operator took it), the supervisor sheds to ADVISORY and counts it (``sheds``): it never reports
  MPC while it no longer drives the pumps.

Bumpless switches: entering MPC first writes ``RemoteMV`` = the applied MV and only then the
REMOTE mode, and the MPC starts from the applied input; leaving MPC puts the loops back in AUTO,
where the velocity-form PID continues from the applied MV. Entering ADAPTIVE_PID starts the
adapter from the gains the PLC applies.

Units: the MPC plans pump flows [m^3/s]; pump commands are converted through the plant's pump
maps (rpm and fraction pumps included). The adapter works in the PLC's units: errors in the
loop's error unit (m or cm) and MVs in the pump's unit, with the linear model converted to them.

This module is pure: the snapshot carries the PLC's model time; no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plant_sim.linearize import equilibrium_flows, linearize, operating_point
from plant_sim.models import TankNetwork, default_inputs
from supervisor.adaptation import (
    AdaptationConfig,
    GainBox,
    LoopModel,
    PidGainAdapter,
    PidGains,
    PumpDiagnostics,
)
from supervisor.fdi import FdiCore, FdiReport
from supervisor.mpc import MpcConfig, MpcController, MpcModel, MpcResult
from supervisor.timing import ScanPredictor
from tanklab import paths
from tanklab.config import SiteConfig
from tanklab.enums import GainSource, LoopMode, SupervisorMode

FloatArray = NDArray[np.float64]
ERROR_SCALE = {"m": 1.0, "cm": 100.0}


@dataclass(frozen=True)
class PlcSnapshot:
    """One Read of the PLC: everything a cycle needs, from the same scan.

    Attributes
    ----------
    scan : PLC scan counter.  t_s : PLC model time [s].
    sp_m, pv_m : (n_loops,) setpoints and PVs [m].  mv : (n_loops,) applied MVs [pump unit].
    modes : (n_loops,) loop modes.  gains : (n_loops, 3) applied (Kp, Ki, Kd).
    levels_m : (n_tanks,) every level the PLC read [m].  good : (n_tanks,) their quality.
    sources : (n_loops,) where the applied gains came from (empty: not read).
    """

    scan: int
    t_s: float
    sp_m: FloatArray
    pv_m: FloatArray
    mv: FloatArray
    modes: tuple[LoopMode, ...]
    gains: FloatArray
    levels_m: FloatArray
    good: NDArray[np.bool_]
    sources: tuple[GainSource, ...] = ()

    @staticmethod
    def read_paths(loops: list[str], tanks: list[str]) -> list[str]:
        """The PLC paths one snapshot reads, in one Read."""
        read = [paths.plc.scan, paths.plc.model_time]
        read += [p for lp in loops for p in _loop_items(lp)]
        read += [p for t in tanks for p in (paths.plc.io(t).pv, paths.plc.io(t).good)]
        return read

    @classmethod
    def from_values(cls, values: Mapping[str, Any], loops: list[str], tanks: list[str]) -> PlcSnapshot:
        """Build a snapshot from PLC values keyed by path (a Read's results, or in the
        co-simulation the program's status mapped to the nodes as the PLC server publishes it)."""
        loop_vals = np.array([[float(values[p]) for p in _loop_items(lp)] for lp in loops])
        return cls(
            scan=int(values[paths.plc.scan]),
            t_s=float(values[paths.plc.model_time]),
            sp_m=loop_vals[:, 0],
            pv_m=loop_vals[:, 1],
            mv=loop_vals[:, 2],
            modes=tuple(LoopMode(int(m)) for m in loop_vals[:, 3]),
            gains=loop_vals[:, 4:7],
            levels_m=np.array([float(values[paths.plc.io(t).pv]) for t in tanks]),
            good=np.array([bool(values[paths.plc.io(t).good]) for t in tanks]),
            sources=tuple(GainSource(int(s)) for s in loop_vals[:, 7]),
        )

    def engineer_held(self) -> frozenset[int]:
        """Indices of the loops whose gains an engineer holds (GainSource ENGINEER)."""
        return frozenset(j for j, s in enumerate(self.sources) if s is GainSource.ENGINEER)


@cache
def _loop_items(loop: str) -> tuple[str, ...]:
    """A loop's snapshot paths in :class:`PlcSnapshot` column order: SP, PV, MV, Mode, Kp, Ki,
    Kd, GainSource."""
    lp = paths.plc.loop(loop)
    return (lp.sp, lp.pv, lp.mv, lp.mode, lp.kp, lp.ki, lp.kd, lp.gain_source)


@dataclass(frozen=True)
class LoopAdaptation:
    """What the adapter reports about one loop (published under ``Supervisor.RLS.<loop>``),
    every value finite (OPC UA carries no NaN to a client that expects a number).

    Attributes
    ----------
    theta : estimated gains [Kp, Ki, Kd] per loop used.  covariance_trace : RLS covariance trace.
    accepted : gain sets pushed and accepted.  last_reason : why the last candidate was rejected.
    excitation, condition_number : of the information matrix.  box_distance : each gain's distance
    to the nearest box limit (fraction of the width).  on_box_limit : a gain sits on a limit.
    prior : the SIMC gains regularised toward.  noise_std_m : transmitter noise estimate [m].
    """

    theta: tuple[float, ...]
    covariance_trace: float
    accepted: int
    last_reason: str
    excitation: float
    condition_number: float
    box_distance: tuple[float, ...]
    on_box_limit: bool
    prior: tuple[float, ...]
    noise_std_m: float


@dataclass(frozen=True)
class SupervisorStatus:
    """The supervisor's state to publish, as values (the server maps it to its tags).

    Attributes
    ----------
    mode : the running mode.  cycles : cycles run.
    mpc : the last MPC step's result (None: none ran yet).
    adaptation : per loop (loop name, report), in loop order; None without an adapter.
    rejected : candidate gain sets rejected by a guard or the PLC (the same for every loop).
    fdi : the fault diagnosis after the latest scan (:mod:`supervisor.fdi`; None before any).
    """

    mode: SupervisorMode
    cycles: int
    mpc: MpcResult | None
    adaptation: tuple[tuple[str, LoopAdaptation], ...] | None
    rejected: int
    fdi: FdiReport | None = None


@dataclass
class Actions:
    """What the runtime must write to the PLC after a cycle (in this order), and publish."""

    remote_mv: dict[str, float] = field(default_factory=dict)
    modes: dict[str, LoopMode] = field(default_factory=dict)
    gains: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    status: SupervisorStatus | None = None
    """The supervisor's state after the cycle (None on actions not made by a cycle)."""


def build_mpc(site: SiteConfig) -> tuple[MpcController, TankNetwork]:
    """The MPC of a site, linearized at its operating point (ZOH at the MPC's sample time)."""
    if site.supervisor is None or site.plc is None:
        raise ValueError(f"site {site.name!r} has no supervisor section")
    spec = site.supervisor.mpc
    net = TankNetwork.from_config(site.plant)
    u0 = default_inputs(net, site.plant)
    op = operating_point(net, site.plant, u0)
    ts = site.supervisor_sample_time_s
    lin = linearize(net, op.equilibrium_levels_m, op.flows_m3_s, u0, ts)
    tanks = site.tank_names
    n = len(tanks)
    cz = np.zeros((len(spec.controlled), n))
    for row, t in enumerate(spec.controlled):
        cz[row, tanks.index(t)] = 1.0
    filt = spec.filter_outputs or spec.controlled
    hmax = np.array([site.plant.tank(t).height_max_m for t in spec.controlled])
    z_max = spec.z_max_m if spec.z_max_m is not None else hmax
    model = MpcModel(
        A=lin.A, B=lin.B, C=np.eye(n), Cz=cz, x_op=op.equilibrium_levels_m, u_op=op.flows_m3_s, ts_s=ts
    )
    cfg = MpcConfig(
        horizon=spec.horizon,
        u_min=net.pump_target_flows(net.pump_cmd_min),
        u_max=net.pump_target_flows(net.pump_cmd_max),
        du_min=-spec.du_max_m3_s if spec.du_max_m3_s else -np.inf,
        du_max=spec.du_max_m3_s if spec.du_max_m3_s else np.inf,
        z_min=spec.z_min_m,
        z_max=z_max,
        Qz=np.array(spec.qz),
        S=np.array(spec.s),
        R=np.array(spec.r) if spec.r is not None else 0.0,
        first_move_rate_limited=spec.first_move_rate_limited,
        formulation=spec.formulation,
        estimator_outputs=[tanks.index(t) for t in filt],
        state_noise_std=spec.state_noise_m,
        disturbance_noise_std=spec.disturbance_noise_m3_s,
        measurement_noise_std=spec.measurement_noise_m,
    )
    return MpcController(model, cfg), net


class SupervisorCore:
    """The supervisor of a site: mode logic, shadow or direct MPC, gain adaptation.

    Parameters
    ----------
    site : a site with ``plc`` and ``supervisor`` sections; every loop must be a PID loop for
        ADAPTIVE_PID (the MPC and MPC mode work with any block).
    """

    def __init__(self, site: SiteConfig) -> None:
        if site.supervisor is None or site.plc is None:
            raise ValueError(f"site {site.name!r} has no supervisor section")
        self.site = site
        self.spec = site.supervisor
        self.loops = site.plc.loops
        self.loop_names = [lp.name for lp in self.loops]
        self.mpc, self.net = build_mpc(site)
        self.scan_period_s = site.plc.scan_period_s
        self.sample_scans = site.supervisor_sample_scans
        # The estimate carried scan by scan with the MVs the PLC applied (supervisor.timing).
        self.predictor = ScanPredictor(*self._scan_model(self.mpc.model.x_op, self.mpc.model.u_op))
        tanks = site.tank_names
        pumps = site.pump_names
        # Loop j drives pump self.loop_pump[j]; the MPC's inputs are all pumps in plant order.
        self.loop_pump = [pumps.index(lp.actuator) for lp in self.loops]
        self.loop_tank = [tanks.index("T" + lp.pv[2:]) for lp in self.loops]
        self.controlled = [tanks.index(t) for t in self.spec.mpc.controlled]
        # Start OFF and let the first cycle switch to the configured mode, so that a supervisor
        # configured for MPC enters it bumplessly (RemoteMV = applied MV, then REMOTE).
        self.mode = SupervisorMode.OFF
        self.requested = self.spec.mode_enum
        self.cycles = 0
        self.last: PlcSnapshot | None = None
        self.result: MpcResult | None = None
        self.result_scan: int | None = None  # the PLC scan of the sample whose MPC step made it
        self.push_scan = -10
        self.pushes_refused = 0
        self.held_loops = 0  # loops left out of the last proposed push: an engineer holds them
        self._rls_cache: tuple[tuple[str, LoopAdaptation], ...] | None = None  # until it changes
        self._rejected_pushes = 0
        self.remote_since_scan: int | None = None  # MPC: first scan that shows the loops in REMOTE
        self.sheds = 0  # MPC shed to ADVISORY because a loop left REMOTE
        self.shed_reason = ""
        self._last_r: FloatArray | None = None
        self.adapter: PidGainAdapter | None = self._build_adapter() if self._all_pid() else None
        self.fdi = FdiCore(site)  # fault diagnosis, fed every PLC scan (a restart warms it up afresh)

    # ---- construction -------------------------------------------------------------------

    def _scan_model(
        self, x_op: FloatArray, u_op: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The linear model over one PLC scan at (x_op, u_op), for the ScanPredictor."""
        if self.sample_scans == 1:
            m = self.mpc.model  # the MPC's own model is already the one-scan model
            return m.A, m.B, x_op, u_op
        lin = linearize(self.net, x_op, u_op, default_inputs(self.net, self.site.plant), self.scan_period_s)
        return lin.A, lin.B, x_op, u_op

    def _all_pid(self) -> bool:
        return self.site.supervisor_adapts_gains

    def _build_adapter(self) -> PidGainAdapter:
        """The gain adapter in the PLC's units (pump unit per loop error unit)."""
        spec = self.spec.adaptation
        lin_A, lin_B = self.mpc.model.A, self.mpc.model.B
        n_l = len(self.loops)
        pumps = [self.site.plant.pump(lp.actuator) for lp in self.loops]
        slope = np.array([p.slope for p in pumps])
        scale = np.array([ERROR_SCALE[lp.error_unit] for lp in self.loops])
        B = lin_B[:, self.loop_pump] * slope  # m per pump unit
        C = np.zeros((n_l, lin_A.shape[0]))
        for j, t in enumerate(self.loop_tank):
            C[j, t] = scale[j]  # error unit per m
        u_min = np.array([p.command_min for p in pumps])
        u_max = np.array([p.command_max for p in pumps])
        u_op = np.array(
            [p.command_of(q) for p, q in zip(pumps, self.mpc.model.u_op[self.loop_pump], strict=True)]
        )
        model = LoopModel(
            A=lin_A,
            B=B,
            C=C,
            ts_s=self.site.plc.scan_period_s if self.site.plc else 1.0,
            u_min=u_min,
            u_max=u_max,
            x_op=self.mpc.model.x_op,
            u_op=u_op,
        )
        fixed = PidGains.diagonal(
            [lp.gains.kp for lp in self.loops if lp.gains],
            [lp.gains.ki for lp in self.loops if lp.gains],
            [lp.gains.kd for lp in self.loops if lp.gains],
        )
        box = None
        if all(lp.gain_box is not None for lp in self.loops):
            lo = np.zeros((3, n_l, n_l))
            hi = np.zeros((3, n_l, n_l))
            for j, lp in enumerate(self.loops):
                assert lp.gain_box is not None
                for g, name in enumerate(("kp", "ki", "kd")):
                    lo[g, j, j], hi[g, j, j] = getattr(lp.gain_box, name)
            box = GainBox(PidGains.from_stacked(lo), PidGains.from_stacked(hi))
        cfg = AdaptationConfig(
            memory_s=spec.memory_s,
            trace_cap=spec.trace_cap,
            excitation_threshold=spec.excitation_threshold,
            error_scale=spec.error_scale_m * float(scale.max()),
            push_period_s=spec.push_period_s,
            min_time_s=spec.start_after_s,
            box=box,
            ki_min=spec.ki_min,
            max_change_fraction=spec.max_change_fraction,
            max_spectral_radius=spec.spectral_radius_max,
            estimator=spec.estimator,
            prior_closed_loop_s=spec.prior_closed_loop_s,
            prior_weight=spec.prior_weight,
            path=spec.path,
            kd_keep_sign=spec.kd_keep_sign,
            saturated=spec.saturated,
            noise_move_budget=spec.noise_move_budget,
            box_limit_fraction=spec.box_limit_fraction,
        )
        return PidGainAdapter(model, fixed, cfg)

    # ---- requests -----------------------------------------------------------------------

    def request_mode(self, mode: SupervisorMode) -> None:
        """Switch mode at the next cycle; ADAPTIVE_PID needs every loop to be a PID loop."""
        mode = SupervisorMode(mode)
        if mode is SupervisorMode.ADAPTIVE_PID and self.adapter is None:
            raise ValueError("ADAPTIVE_PID needs every loop to be a PID loop with fixed gains")
        if mode is SupervisorMode.ADAPTIVE_PID and self.sample_scans != 1:
            # the adapter pairs each scan's PID move with the MPC's move of the same scan
            raise ValueError(
                "ADAPTIVE_PID needs the supervisor to sample every PLC scan "
                f"(supervisor.sample_time_s is {self.sample_scans} scans)"
            )
        self.requested = mode

    def push_refused(self) -> None:
        """The PLC refused a push: resynchronise the adapter from the next snapshot."""
        self.pushes_refused += 1
        self.push_scan = -10

    # ---- the cycle ----------------------------------------------------------------------

    def flows_of(self, mv: FloatArray) -> FloatArray:
        """Pump flows [m^3/s] for the loops' MVs (pumps without a loop: operating flow)."""
        q = self.mpc.model.u_op.copy()
        for j, p in enumerate(self.loop_pump):
            q[p] = self.site.plant.pumps[p].flow_of(float(mv[j]))
        return q

    def commands_of(self, flows: FloatArray) -> FloatArray:
        """Loop MVs [pump unit] for pump flows [m^3/s]."""
        return np.array([self.site.plant.pumps[p].command_of(float(flows[p])) for p in self.loop_pump])

    def track(self, snap: PlcSnapshot) -> None:
        """A PLC scan between two samples: carry the estimate with the MV the PLC applied."""
        self._advance(snap)
        self.predictor.applied(self.flows_of(snap.mv))

    def cycle(self, snap: PlcSnapshot, r_preview: FloatArray | None = None) -> Actions:
        """Run one sample on a new PLC snapshot; return the actions to write and the values.

        The estimate is brought to the snapshot's scan with the MVs applied since the last one
        and corrected with its levels (when they are good); then, by mode, the MPC plans
        (supervisor.timing: from the look-ahead state in MPC mode, from the estimate in the
        shadow modes) and the adapter learns and proposes.
        """
        act = Actions()
        self._shed_if_loops_left_remote(snap, act)
        self._switch_mode(snap, act)
        self.cycles += 1
        self._advance(snap)
        u_before = self.predictor.u_m3_s  # applied over the scan before this snapshot's
        measured = self._correct(snap)
        self.predictor.applied(self.flows_of(snap.mv))
        if self.mode is not SupervisorMode.OFF and measured:
            self._compute(snap, u_before, act, r_preview)
        self.last = snap
        act.status = self.status()
        return act

    def _advance(self, snap: PlcSnapshot) -> None:
        self.fdi.step(snap.scan, snap.t_s, snap.levels_m, snap.good, snap.mv)
        if self.predictor.started:
            self.predictor.advance_to(snap.scan)
        else:
            self.predictor.start(snap.scan, self.flows_of(snap.mv))

    def _correct(self, snap: PlcSnapshot) -> bool:
        """Fold the snapshot's levels into the estimate; False (nothing changed) when any is bad."""
        if not bool(np.all(snap.good)) or not np.all(np.isfinite(snap.levels_m)):
            return False  # no correction, no MPC step on bad measurements: hold
        p = self.predictor
        p.corrected(*self.mpc.correct(snap.levels_m, p.x_m, p.eta_m3_s))
        return True

    def _shed_if_loops_left_remote(self, snap: PlcSnapshot, act: Actions) -> None:
        """MPC drives the pumps only through loops in REMOTE. When a loop has left REMOTE since
        the MPC put it there (the PLC's heartbeat watchdog fell back to AUTO, an operator took
        it), the supervisor sheds to ADVISORY instead of planning for pumps it no longer drives,
        and says so (``sheds``); an engineer re-engages MPC. It does not fight the PLC or the
        operator for the loops: loops still in REMOTE go back to AUTO (bumpless), the others
        keep what they were given."""
        if self.mode is not SupervisorMode.MPC or self.requested is not SupervisorMode.MPC:
            return
        if self.remote_since_scan is None or snap.scan <= self.remote_since_scan:
            return  # the REMOTE writes of the entry have not been seen yet
        left = [name for name, m in zip(self.loop_names, snap.modes, strict=True) if m is not LoopMode.REMOTE]
        if left:
            for name, m in zip(self.loop_names, snap.modes, strict=True):
                if m is LoopMode.REMOTE:
                    act.modes[name] = LoopMode.AUTO
            self.mode = self.requested = SupervisorMode.ADVISORY
            self.sheds += 1
            self.shed_reason = f"{', '.join(left)} left REMOTE at PLC scan {snap.scan}"

    def _switch_mode(self, snap: PlcSnapshot, act: Actions) -> None:
        if self.requested is self.mode:
            return
        if self.mode is SupervisorMode.MPC:
            for name in self.loop_names:
                act.modes[name] = LoopMode.AUTO
        if self.requested is SupervisorMode.MPC:
            for j, name in enumerate(self.loop_names):
                act.remote_mv[name] = float(snap.mv[j])
                act.modes[name] = LoopMode.REMOTE
            self.remote_since_scan = snap.scan + 1  # the first scan that can show them in REMOTE
        if self.requested is SupervisorMode.ADAPTIVE_PID and self.adapter is not None:
            self.adapter.set_applied(self._applied(snap))
            self._rls_cache = None
        self.mode = self.requested

    def _applied(self, snap: PlcSnapshot) -> PidGains:
        return PidGains.diagonal(snap.gains[:, 0], snap.gains[:, 1], snap.gains[:, 2])

    def _reference(self, snap: PlcSnapshot) -> FloatArray:
        r = self.mpc.model.x_op[self.controlled].copy()
        for row, tank in enumerate(self.controlled):
            if tank in self.loop_tank:
                r[row] = snap.sp_m[self.loop_tank.index(tank)]
        return r

    def _compute(
        self, snap: PlcSnapshot, u_before: FloatArray, act: Actions, preview: FloatArray | None
    ) -> None:
        direct = self.mode is SupervisorMode.MPC
        r = self._reference(snap) if preview is None else preview
        if self.spec.mpc.relinearize:
            self._relinearize(r if r.ndim == 1 else r[0])
        p = self.predictor
        if direct:
            # The move reaches the pumps at the next scan; MV(k) is committed until then.
            x0, u_prev = p.look_ahead(1), p.u_m3_s
        else:
            # Shadow of the PLC's PID, whose MV(k) acts at once: plan from x(k|k) with the input
            # applied before this scan. Snapshot k carries MV(k) = MV(k-1) + psi(k)' theta exactly
            # (psi from snapshots k, k-1, k-2), so u_MPC(k) - MV(k-1) regressed on psi(k) is the
            # right pairing (tests/supervisor/test_closed_loop.py checks it on PLC snapshots).
            x0, u_prev = p.x_m, u_before
        res = self.mpc.plan(x0, r, u_prev, p.eta_m3_s)
        self.result = res
        self.result_scan = snap.scan
        u_cmd = self.commands_of(res.u)
        if direct:
            for j, name in enumerate(self.loop_names):
                act.remote_mv.setdefault(name, float(u_cmd[j]))
            return
        if self.adapter is None:
            return
        scale = np.array([ERROR_SCALE[lp.error_unit] for lp in self.loops])
        if self.mode is SupervisorMode.ADAPTIVE_PID and snap.scan > self.push_scan + 1:
            # Resynchronise with what the PLC really applies (fallbacks, refusals, restarts).
            applied = self._applied(snap)
            if not applied.allclose(self.adapter.applied, rtol=1e-9):
                self.adapter.set_applied(applied)
        self._rls_cache = None  # the adapter learns (and may propose) now
        self.adapter.observe(
            scan=snap.scan,
            t_s=snap.t_s,
            sp=snap.sp_m * scale,
            pv=snap.pv_m * scale,
            mv=snap.mv,
            u_mpc=u_cmd,
            x=snap.levels_m,
        )
        if self.mode is SupervisorMode.ADAPTIVE_PID:
            decision = self.adapter.propose(snap.t_s)
            if decision is not None and decision.accepted and decision.changed:
                g = decision.candidate
                held = snap.engineer_held()  # an engineer's gains stay until handed back
                for j, name in enumerate(self.loop_names):
                    if j not in held:
                        act.gains[name] = (float(g.kp[j, j]), float(g.ki[j, j]), float(g.kd[j, j]))
                self.held_loops = len(held)
                if act.gains:
                    self.push_scan = snap.scan

    def _relinearize(self, r: FloatArray) -> None:
        """Gain scheduling: re-linearize at the equilibrium holding the current references."""
        if self._last_r is not None and np.allclose(r, self._last_r, atol=1e-6):
            return
        levels = self.mpc.model.x_op.copy()
        levels[self.controlled] = r
        u0 = default_inputs(self.net, self.site.plant)
        try:
            flows, eq = equilibrium_flows(self.net, levels, u0)
        except ValueError:
            return  # no equilibrium for this reference (e.g. above what the pumps can hold): keep
        lin = linearize(self.net, eq, flows, u0, self.mpc.model.ts_s)
        self.mpc.update_model(lin.A, lin.B, x_op=eq, u_op=flows)
        self.predictor.set_model(*self._scan_model(eq, flows))
        self._last_r = np.array(r, dtype=float)

    # ---- publishing ---------------------------------------------------------------------

    def status(self) -> SupervisorStatus:
        """The supervisor's state now (:class:`SupervisorStatus`)."""
        adaptation = None
        if self.adapter is not None:
            if self._rls_cache is None:
                self._rls_cache = self._adaptation()
            adaptation = self._rls_cache
        return SupervisorStatus(
            mode=self.mode,
            cycles=self.cycles,
            mpc=self.result,
            adaptation=adaptation,
            rejected=self._rejected_pushes + self.pushes_refused,
            fdi=self.fdi.report,
        )

    def _adaptation(self) -> tuple[tuple[str, LoopAdaptation], ...]:
        """The adapter's report per loop (diagnostics and health: eigenvalues and box distances,
        so computed only after the adapter changed, not every cycle: in MPC mode it never does)."""
        assert self.adapter is not None
        d = self.adapter.diagnostics()
        self._rejected_pushes = d.rejected_pushes
        reason = d.last_reject_reason.value if d.last_reject_reason else ""
        noise = self.adapter.noise_std()
        scale = [ERROR_SCALE[lp.error_unit] for lp in self.loops]
        return tuple(
            (name, _loop_adaptation(d.pumps[j], d.accepted_pushes, reason, float(noise[j]) / scale[j]))
            for j, name in enumerate(self.loop_names)
        )


def _loop_adaptation(pump: PumpDiagnostics, accepted: int, reason: str, noise_m: float) -> LoopAdaptation:
    """One loop's report (docs/adaptation.md 2.10), finite for OPC UA."""

    def fin(x: float, default: float = 0.0) -> float:
        return float(x) if math.isfinite(x) else default

    return LoopAdaptation(
        theta=tuple(float(x) for x in pump.theta),
        covariance_trace=fin(float(pump.covariance_trace)),
        accepted=accepted,
        last_reason=reason,
        excitation=fin(pump.excitation),
        condition_number=fin(pump.condition_number, 1.0),
        box_distance=tuple(fin(float(x)) for x in pump.box_distance),
        on_box_limit=bool(pump.on_box_limit),
        prior=tuple(float(x) for x in pump.prior),
        noise_std_m=fin(noise_m),
    )
