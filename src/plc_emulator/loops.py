"""The PLC program's loops and how the site config becomes their blocks and shells.

A `Loop` holds one control loop's constants (tank, pump, MV range, error scale), the state of its
requests (setpoint, mode, held values, gains and their source) and its place in a shell. The
loops are grouped (`build_groups`): PID loops coupled by ``cross_gains`` share one MIMO
``plc_emulator.pid.Pid`` (the connected components of the cross-gain graph), each NL-PI and MRAC
loop gets a ``plc_emulator.loop.LoopShell`` around its law. Every shell works in its block's
units: SP and PV [m] times ``block_scale`` (the PID's ``error_unit``: the rig's gains assume cm,
so the PID's setpoint limits and ramp scale with it; 1 for the NL-PI and MRAC, which work in m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from plc_emulator.loop import LoopShell, ShellConfig
from plc_emulator.mrac import Mrac, MracConfig
from plc_emulator.nlpi import AdaptiveNlPi, AdaptiveNlPiConfig, NlPi, NlPiConfig
from plc_emulator.pid import Pid, PidConfig
from plc_emulator.single_loop import SingleLoopBlock
from plc_emulator.tuning import nlpi_gains
from tanklab.config import LoopSpec, SiteConfig
from tanklab.enums import GainSource, LoopMode, RemoteSource
from tanklab.gains import GainBox, LoopGains, LoopLimits, PidGains

__all__ = ["ERROR_SCALE", "Group", "Loop", "build_groups", "group_gains", "make_loops"]

ERROR_SCALE = {"m": 1.0, "cm": 100.0}
"""Factor from metres to the loop's error unit."""


@dataclass
class Loop:
    """One control loop of the program: its constants, its requests' state and its block."""

    spec: LoopSpec
    index: int  # index among all loops (LIC order)
    tank: int  # tank index of its PV
    pump: int  # pump index of its actuator
    mv_min: float
    mv_max: float
    scale: float
    sp_m: float
    mode: LoopMode
    manual_mv: float
    remote_mv: float
    shell: LoopShell | None = None  # the loop shell of the loop's group (set by build_groups)
    slot: int = 0  # the loop's position in that shell
    block_scale: float = 1.0  # SP and PV [m] times this is what the block sees (PID: error unit)
    block: NlPi | AdaptiveNlPi | Mrac | None = None  # the law of a single-loop block
    fixed: LoopGains | None = None
    applied: LoopGains | None = None
    last_accepted: LoopGains | None = None
    staged: LoopGains | None = None
    gain_box: GainBox | None = None  # the admissible SetGains (1 x 1), from the config
    staged_source: GainSource | None = None  # the GainSource the staged set brings at the boundary
    source: GainSource = GainSource.FIXED
    remote_source: RemoteSource = RemoteSource.SUPERVISOR  # who drives the loop in REMOTE
    mode_changed_scan: int = -1  # scan_count when the mode last changed (pending until that scan ran)
    mv: float = 0.0
    pv_m: float = math.nan  # PV used this scan [m]; NaN while bad
    pv_bad: bool = False
    pv_last_good_m: float = 0.0  # published while the PV is bad
    substituted: bool = False  # the substitute output was applied this scan
    sp_low_m: float = 0.0  # operator setpoint limits set by the engineer [m], inside the config's
    sp_high_m: float = math.inf

    @property
    def pid(self) -> Pid | None:
        """The MIMO PID block of the loop's group (block pid), else None."""
        return self.shell if isinstance(self.shell, Pid) else None

    @property
    def working_sp_m(self) -> float | None:
        """The ramped setpoint of the last scan [m] (None before the first)."""
        assert self.shell is not None
        if not self.shell.started:
            return None
        return float(self.shell.working_sp[self.slot]) / self.block_scale

    @property
    def loop_shell(self) -> LoopShell:
        """The loop's shell (after construction)."""
        assert self.shell is not None
        return self.shell


@dataclass
class Group:
    """Loops run by one shell: PID loops coupled by cross gains (one MIMO block), or one
    single-loop block."""

    loops: list[Loop]
    shell: LoopShell
    sp: list[float] = field(default_factory=list)  # the scan's inputs to the shell (reused)
    pv: list[float] = field(default_factory=list)
    ok: list[bool] = field(default_factory=list)

    def __post_init__(self) -> None:
        n = len(self.loops)
        self.sp, self.pv, self.ok = [0.0] * n, [math.nan] * n, [False] * n


def make_loops(site: SiteConfig) -> list[Loop]:
    """The loops of a site's ``plc`` section, in LIC order (gains and gain box converted from the
    file format to the kernel's types here, once).

    Raises
    ------
    ValueError
        A loop's MV range does not overlap its pump's command range.
    """
    assert site.plc is not None
    tanks, pumps = site.tank_names, site.pump_names
    loops: list[Loop] = []
    for j, spec in enumerate(site.plc.loops):
        pump = site.plant.pump(spec.actuator)
        # The loop's MV range never leaves the pump's command range.
        lo = max(spec.mv_min, pump.command_min) if spec.mv_min is not None else pump.command_min
        hi = min(spec.mv_max, pump.command_max) if spec.mv_max is not None else pump.command_max
        if not lo < hi:
            raise ValueError(
                f"plc.loops {spec.name}: MV range [{spec.mv_min}, {spec.mv_max}] does not overlap "
                f"{pump.name}'s command range [{pump.command_min}, {pump.command_max}]"
            )
        manual = spec.manual_mv if spec.manual_mv is not None else pump.initial_command
        mv0 = min(max(pump.initial_command, lo), hi)
        gains = LoopGains.of_spec(spec.gains) if spec.gains is not None else None  # file -> kernel type
        loops.append(
            Loop(
                spec=spec,
                index=j,
                tank=tanks.index("T" + spec.pv[2:]),
                pump=pumps.index(spec.actuator),
                mv_min=lo,
                mv_max=hi,
                scale=ERROR_SCALE[spec.error_unit],
                sp_m=spec.setpoint_m,
                mode=spec.mode_enum,
                manual_mv=min(max(manual, lo), hi),
                remote_mv=mv0,
                mv=mv0,
                fixed=gains,
                applied=gains,
                last_accepted=gains,
                gain_box=GainBox.of_spec(spec.gain_box) if spec.gain_box is not None else None,
            )
        )
    return loops


def build_groups(loops: list[Loop], ts_s: float) -> tuple[list[Group], list[Group]]:
    """One shell per group: a MIMO PID per group of loops coupled by cross gains, a
    single-loop block per NL-PI or MRAC loop (fixed from here on: the scan needs no search).

    Returns the PID groups and all groups (PID groups first), each loop attached to its shell.

    Raises
    ------
    ValueError
        PID loops coupled by cross gains disagree on ``pv_bad_scans`` or ``derivative_filter_s``.
    """
    pid_loops = [lp for lp in loops if lp.spec.block == "pid"]
    pid_groups = [_make_pid_group(g, ts_s) for g in _coupled_groups(pid_loops)]
    groups = list(pid_groups)
    for lp in loops:
        if lp.spec.block == "nlpi":
            lp.block = _make_nlpi(lp, ts_s)
        elif lp.spec.block == "mrac":
            lp.block = _make_mrac(lp, ts_s)
        else:
            continue
        shell = LoopShell(SingleLoopBlock(lp.block), _shell_config([lp], ts_s))
        _attach([lp], shell)
        groups.append(Group(loops=[lp], shell=shell))
    return pid_groups, groups


def _shell_config(loops: list[Loop], ts_s: float) -> ShellConfig:
    """The shell's constants of a group of loops, in the blocks' units (``block_scale``)."""
    return ShellConfig(
        limits=tuple(LoopLimits(lp.mv_min, lp.mv_max, lp.spec.du_max or math.inf) for lp in loops),
        sp_min=tuple(lp.spec.sp_min_m * lp.block_scale for lp in loops),
        sp_max=tuple(lp.spec.sp_max_m * lp.block_scale for lp in loops),
        sp_step=tuple((lp.spec.sp_ramp_m_s or math.inf) * lp.block_scale * ts_s for lp in loops),
        pv_bad_scans=loops[0].spec.pv_bad_scans,
        substitute=tuple(lp.spec.substitute for lp in loops),
        substitute_mv=tuple(min(max(lp.spec.substitute_mv, lp.mv_min), lp.mv_max) for lp in loops),
        initial_mv=tuple(lp.mv for lp in loops),
        initial_mode=tuple(lp.mode for lp in loops),
    )


def _attach(loops: list[Loop], shell: LoopShell) -> None:
    for k, lp in enumerate(loops):
        lp.shell = shell
        lp.slot = k
        if lp.mode is LoopMode.MANUAL:
            shell.set_mode(k, LoopMode.MANUAL, lp.manual_mv)


def _coupled_groups(loops: list[Loop]) -> list[list[Loop]]:
    """Connected components of the cross-gain graph (loops in LIC order within a group)."""
    parent = {lp.spec.name: lp.spec.name for lp in loops}

    def root(name: str) -> str:
        while parent[name] != name:
            name = parent[name]
        return name

    for lp in loops:
        for other in lp.spec.cross_gains:
            if other in parent:
                parent[root(other)] = root(lp.spec.name)
    groups: dict[str, list[Loop]] = {}
    for lp in loops:
        groups.setdefault(root(lp.spec.name), []).append(lp)
    return list(groups.values())


def _make_pid_group(loops: list[Loop], ts_s: float) -> Group:
    for attr in ("pv_bad_scans", "derivative_filter_s"):
        values = {getattr(lp.spec, attr) for lp in loops}
        if len(values) > 1:
            names = ", ".join(lp.spec.name for lp in loops)
            raise ValueError(f"plc.loops {names}: loops coupled by cross_gains must share {attr}")
    for lp in loops:
        lp.block_scale = lp.scale
    sc = _shell_config(loops, ts_s)
    cfg = PidConfig(
        n_loops=len(loops),
        ts_s=ts_s,
        u_min=[lim.mv_min for lim in sc.limits],
        u_max=[lim.mv_max for lim in sc.limits],
        du_max=[lim.du_max for lim in sc.limits],
        d_filter_tf_s=loops[0].spec.derivative_filter_s,
        setpoint_weight_p=[lp.spec.setpoint_weight_p for lp in loops],
        setpoint_weight_d=[lp.spec.setpoint_weight_d for lp in loops],
        sp_min=list(sc.sp_min),
        sp_max=list(sc.sp_max),
        sp_rate=[(lp.spec.sp_ramp_m_s or math.inf) * lp.scale for lp in loops],
        initial_mv=list(sc.initial_mv),
        pv_bad_scans=sc.pv_bad_scans,
        substitute=list(sc.substitute),
        substitute_mv=list(sc.substitute_mv),
        initial_mode=list(sc.initial_mode),
    )
    pid = Pid(cfg, group_gains(loops))
    _attach(loops, pid)
    return Group(loops=loops, shell=pid)


def group_gains(loops: list[Loop]) -> PidGains:
    """The group's gain matrices: applied gains on the diagonal, fixed cross gains off it."""
    n = len(loops)
    kp, ki, kd = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    index = {lp.spec.name: k for k, lp in enumerate(loops)}
    for i, lp in enumerate(loops):
        assert lp.applied is not None
        kp[i, i], ki[i, i], kd[i, i] = lp.applied.kp, lp.applied.ki, lp.applied.kd
        for other, g in lp.spec.cross_gains.items():
            j = index.get(other)
            if j is not None:
                kp[i, j], ki[i, j], kd[i, j] = g.kp, g.ki, g.kd
    return PidGains(kp, ki, kd)


def _make_nlpi(lp: Loop, ts_s: float) -> NlPi | AdaptiveNlPi:
    p = lp.spec.nlpi
    assert p is not None
    if p.adaptive:
        return AdaptiveNlPi(
            AdaptiveNlPiConfig(
                ts_s=ts_s,
                zeta=p.zeta,
                wn=p.wn_rad_s,
                b0=p.b,
                a_prime0=p.a_prime,
                u_min=lp.mv_min,
                u_max=lp.mv_max,
                initial_mv=lp.mv,
                memory_s=p.memory_s,
            )
        )
    gains = nlpi_gains(p.b, p.a_prime, p.zeta, p.wn_rad_s)
    return NlPi(NlPiConfig(ts_s=ts_s, gains=gains, u_min=lp.mv_min, u_max=lp.mv_max, initial_mv=lp.mv))


def _make_mrac(lp: Loop, ts_s: float) -> Mrac:
    p = lp.spec.mrac
    assert p is not None
    return Mrac(
        MracConfig(
            ts_s=ts_s,
            law="mit" if p.law == "mit" else "pi",
            wn=p.wn_rad_s,
            delta=p.delta,
            gamma=p.gamma,
            alpha=p.alpha,
            theta0=p.theta_initial,
            theta_min=p.theta_min,
            theta_max=p.theta_max,
            u_min=lp.mv_min,
            u_max=lp.mv_max,
            initial_mv=lp.mv,
        )
    )
