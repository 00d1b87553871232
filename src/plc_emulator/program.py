"""The soft PLC's program: one scan, in PLC order, as a pure function of its inputs.

A scan (period Ts of model time) does, in order:

1. **Watchdog**: the supervisor's heartbeat must change within ``timeout_s`` of model time
   (counted from the scan that saw the last change; the first timeout after start is a grace
   period counted from the first scan). On timeout ``Alive`` goes false; loops on SUPERVISOR
   gains go to FALLBACK gains (the fixed ones or the last accepted ones), loops in REMOTE shed
   to AUTO at their current setpoint, both bumpless (the velocity form continues from the
   applied MV; NL-PI and MRAC re-initialise from it), and the supervisor's gains staged since
   the last scan are dropped. ENGINEER gains, and an engineer's or operator's staged request
   (SetGains, ResetGains), are never touched by the watchdog. Supervisor gains are accepted
   again only after the heartbeat has been good for ``good_scans_to_accept`` scans.
2. **Boundary**: gains staged since the last scan (``SetGains``, ``ResetGains``) take effect
   now, all three at once, so no scan runs with half-applied gains, and the loop's
   ``GainSource`` changes with them.
3. **Read inputs**: the level transmitters' readings and their quality. A reading is bad when
   the field link failed (``io_healthy`` false), the link flagged it, it is not finite, outside
   the transmitter range, or frozen (``pv_frozen_scans`` identical readings in a row, when
   enabled).
4. **Execute blocks**: one ``plc_emulator.loop.LoopShell`` per group of loops, whatever its block
   (decision 0029): the PID loops as MIMO velocity-form blocks (one per group of loops coupled
   by ``cross_gains``), the NL-PI and MRAC loops as single-loop blocks. The shell owns the SP
   ramp, the modes and held values, the substitute output (``hold`` or ``value``, at the rate
   limit) after ``pv_bad_scans`` bad scans in AUTO and REMOTE, the rate limit and the clamp, so
   every block is bumpless in every direction.
5. **Interlocks**: a delivered, finite reading at or above high-high (over-range and frozen
   readings included: fail-safe) trips its tank's pumps to their lowest command in every mode,
   with any gains, supervisor alive or not. The trip latches until the level is below the reset
   level and an operator resets it. The blocks are told where the actuator really is
   (``track``), and a loop in MANUAL or REMOTE holds the forced value, so the loop resumes
   bumplessly after the reset and no pump restarts by itself at an old manual value.
6. **Write outputs**: one command per pump, in the pump's own unit, always inside the pump's
   command range.
7. **Publish**: every PLC node's value the program owns, keyed by tag path (``values()``).

Gain sources (``tanklab.enums.GainSource``, one per PID loop):

- FIXED: the configured gains (at start, after ``ResetGains``), or gains left in place by
  ``ReleaseGains`` until the supervisor pushes again.
- SUPERVISOR: the supervisor's last accepted ``SetGains``.
- FALLBACK: the supervisor was lost; the fixed or its last accepted gains (``watchdog.fallback``).
- ENGINEER: an engineer's own ``SetGains`` (whatever the supervisor's state). While a loop is
  ENGINEER the supervisor's ``SetGains`` on it is refused (INVALID_STATE) and the watchdog
  leaves it alone, until ``ReleaseGains`` (the gains stay, source FIXED) or ``ResetGains`` (the
  fixed gains at the next boundary, source FIXED) hands it back.

Errors are SP - PV in the loop's ``error_unit``: the rig's gains assume centimetres, so SP and PV
are scaled by 100 before the PID block sees them (the PID's setpoint limits and ramp scale with
them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plc_emulator.loop import LoopShell, ShellConfig
from plc_emulator.mrac import Mrac, MracConfig
from plc_emulator.nlpi import AdaptiveNlPi, AdaptiveNlPiConfig, NlPi, NlPiConfig
from plc_emulator.pid import Pid, PidConfig
from plc_emulator.single_loop import SingleLoopBlock
from plc_emulator.tuning import nlpi_gains
from tanklab.config import LoopSpec, SiteConfig
from tanklab.enums import GainSource, LoopMode
from tanklab.gains import GainBox, LoopGains, LoopLimits, PidGains
from tanklab.tags import link_status_paths

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

ERROR_SCALE = {"m": 1.0, "cm": 100.0}
"""Factor from metres to the loop's error unit."""

RUNTIME_OWNED_TAGS = (
    "PLC.Status.ScanPeriod",
    "PLC.Status.LastScanDuration",
    "PLC.Status.Overruns",
    "PLC.Supervisor.Heartbeat",
    "PLC.Supervisor.Timeout",
    *link_status_paths("PLC.Status.PlantLink").values(),
)
"""PLC variables the runtime publishes, not :meth:`PlcProgram.values` (plus ``PLC.LIC*.Block``):
its scan timing, the supervisor's heartbeat and timeout, and its field link's status."""

_TIME_EPS_SCANS = 1e-6
"""Tolerance on model-time comparisons, in scan periods: model time accumulated as a sum of Ts
(0.01 s 300 times is not exactly 3.0) must not delay a timeout by a whole scan."""


class GainStatus(Enum):
    """Outcome of staging a gain set (the OPC UA layer maps it to a status code)."""

    STAGED = "Good"
    OUT_OF_RANGE = "BadOutOfRange"
    INVALID_STATE = "BadInvalidState"


@dataclass(frozen=True)
class ScanInputs:
    """What a scan reads.

    Attributes
    ----------
    t_s : model time at the start of the scan [s].
    levels_m : (n_tanks,) transmitter readings [m] (NaN where unavailable).
    good : (n_tanks,) quality of each reading as delivered by the field link.
    io_healthy : whether the field link worked this scan (False makes every reading bad).
    """

    t_s: float
    levels_m: FloatArray
    good: BoolArray
    io_healthy: bool = True


@dataclass(frozen=True)
class ScanOutputs:
    """What a scan writes: pump commands (pump order, pump units) and the values to publish."""

    commands: FloatArray
    values: dict[str, Any]


@dataclass
class _Loop:
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
    shell: LoopShell | None = None  # the loop shell of the loop's group (set by _build_blocks)
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
class _Watchdog:
    timeout_s: float
    good_scans_needed: int
    last_value: int | None = None
    last_change_s: float | None = None  # None until the first scan (grace period starts there)
    alive: bool = False
    ever_alive: bool = False
    good_scans: int = 0
    expired: bool = False


@dataclass
class _Interlock:
    tank: int
    tank_name: str
    high_high_m: float
    reset_below_m: float
    tripped: bool = False


@dataclass
class _Frozen:
    last: list[float]  # the previous scan's readings
    repeats: list[int]  # consecutive scans each reading has repeated the one before


@dataclass
class _Group:
    """Loops run by one shell: PID loops coupled by cross gains (one MIMO block), or one
    single-loop block."""

    loops: list[_Loop]
    shell: LoopShell


class PlcProgram:
    """The PLC program of a site, scanned by :meth:`scan`.

    Operator and supervisor requests (``set_sp``, ``set_mode``, ``set_manual_mv``,
    ``set_remote_mv``, ``heartbeat``, ``stage_gains``, ``reset_gains``, ``release_gains``,
    ``reset_interlocks``) take effect at the next scan; the value checks of the contract (type,
    finiteness, EURange) are the OPC UA layer's job, the checks that need the program's state are
    made here (``ValueError`` on refusal; the gain requests answer a :class:`GainStatus`).

    Parameters
    ----------
    site : a site config with a ``plc`` section.
    watchdog_timeout_s : heartbeat timeout in model time; default: the config's (the runtime
        raises it to a wall-clock floor at high speed).

    Raises
    ------
    ValueError
        No ``plc`` section; a loop's MV range does not overlap its pump's command range; PID loops
        coupled by cross gains disagree on ``pv_bad_scans`` or ``derivative_filter_s``.
    """

    def __init__(self, site: SiteConfig, *, watchdog_timeout_s: float | None = None) -> None:
        if site.plc is None:
            raise ValueError(f"site {site.name!r} has no plc section")
        self.site = site
        plc = site.plc
        self.ts_s = plc.scan_period_s
        tanks = site.tank_names
        pumps = site.pump_names
        self.n_tanks = len(tanks)
        self.n_pumps = len(pumps)
        self.scan_count = 0
        self.t_s = 0.0
        # Constants per pump and per tank, as arrays (read by other modules and tests) ...
        self.pump_min = np.array([p.command_min for p in site.plant.pumps], dtype=float)
        self.pump_max = np.array([p.command_max for p in site.plant.pumps], dtype=float)
        self.pump_tank = np.array([tanks.index(p.feeds) for p in site.plant.pumps], dtype=np.int64)
        self.tr_range = np.array([t.transmitter_range() for t in site.plant.tanks], dtype=float)
        sw = [t.switch_levels() for t in site.plant.tanks]
        self.high_m = np.array([s.high_m for s in sw])
        self.low_m = np.array([s.low_m for s in sw])
        # ... and as Python floats for the scan, which works per tank and per pump: with a handful
        # of each, numpy's per-call overhead on 3-element arrays costs more than the loops.
        self._pump_min: list[float] = self.pump_min.tolist()
        self._pump_max: list[float] = self.pump_max.tolist()
        self._pump_tank: list[int] = self.pump_tank.tolist()
        self._tr_range: list[tuple[float, float]] = [(lo, hi) for lo, hi in self.tr_range.tolist()]
        # Per-tank and per-pump state as lists (the array attributes are properties built from them)
        n = self.n_tanks
        self._shape = (n,)
        self._commands: list[float] = np.array(
            [p.initial_command for p in site.plant.pumps], dtype=float
        ).tolist()
        self._levels_m: list[float] = [math.nan] * n  # readings used this scan; NaN where bad
        self._good: list[bool] = [False] * n
        self._last_good_m: list[float] = [0.0] * n
        self._raw_m: list[float] = [math.nan] * n  # delivered, finite readings (for interlocks)
        self.io_healthy = False
        self.pv_frozen_scans = plc.pv_frozen_scans
        self._frozen = _Frozen(last=[math.nan] * n, repeats=[0] * n)
        self.watchdog = _Watchdog(
            timeout_s=plc.watchdog.timeout_s if watchdog_timeout_s is None else watchdog_timeout_s,
            good_scans_needed=plc.watchdog.good_scans_to_accept,
        )
        self.fallback = plc.watchdog.fallback
        self.interlocks = [
            _Interlock(tanks.index(il.tank), il.tank, il.high_high_m, il.reset_below_m)
            for il in plc.interlocks
        ]
        self.hh_m = np.full(self.n_tanks, math.inf)
        for il in self.interlocks:
            self.hh_m[il.tank] = min(self.hh_m[il.tank], il.high_high_m)
        self.loops: list[_Loop] = []
        for j, spec in enumerate(plc.loops):
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
            gains = spec.gains.to_gains() if spec.gains is not None else None  # file -> kernel type
            self.loops.append(
                _Loop(
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
                    gain_box=spec.gain_box.to_box() if spec.gain_box is not None else None,
                )
            )
        self._pending_heartbeat: int | None = None
        self._build_blocks()

    # ---- state after the last scan (arrays built on request) -----------------------------

    @property
    def levels_m(self) -> FloatArray:
        """(n_tanks,) readings the last scan used [m], NaN where bad (a new array)."""
        return np.array(self._levels_m, dtype=float)

    @property
    def good(self) -> BoolArray:
        """(n_tanks,) quality of each reading in the last scan (a new array)."""
        return np.array(self._good, dtype=bool)

    @property
    def last_good_m(self) -> FloatArray:
        """(n_tanks,) each transmitter's last good reading [m], 0 before the first (a new array)."""
        return np.array(self._last_good_m, dtype=float)

    @property
    def commands(self) -> FloatArray:
        """(n_pumps,) the last scan's pump commands, pump units (initial commands before the first
        scan; a new array)."""
        return np.array(self._commands, dtype=float)

    # ---- construction -------------------------------------------------------------------

    def _build_blocks(self) -> None:
        """One shell per group: a MIMO PID per group of loops coupled by cross gains, a
        single-loop block per NL-PI or MRAC loop (fixed from here on: the scan needs no search)."""
        self.pid_loops = [lp for lp in self.loops if lp.spec.block == "pid"]
        self.pid_groups = [self._make_pid_group(g) for g in self._coupled_groups(self.pid_loops)]
        self.groups: list[_Group] = list(self.pid_groups)
        for lp in self.loops:
            if lp.spec.block == "nlpi":
                lp.block = self._make_nlpi(lp)
            elif lp.spec.block == "mrac":
                lp.block = self._make_mrac(lp)
            else:
                continue
            self.groups.append(_Group(loops=[lp], shell=self._shell_of([lp], SingleLoopBlock(lp.block))))

    def _shell_config(self, loops: list[_Loop]) -> ShellConfig:
        """The shell's constants of a group of loops, in the blocks' units (``block_scale``)."""
        return ShellConfig(
            limits=tuple(LoopLimits(lp.mv_min, lp.mv_max, lp.spec.du_max or math.inf) for lp in loops),
            sp_min=tuple(lp.spec.sp_min_m * lp.block_scale for lp in loops),
            sp_max=tuple(lp.spec.sp_max_m * lp.block_scale for lp in loops),
            sp_step=tuple((lp.spec.sp_ramp_m_s or math.inf) * lp.block_scale * self.ts_s for lp in loops),
            pv_bad_scans=loops[0].spec.pv_bad_scans,
            substitute=tuple(lp.spec.substitute for lp in loops),
            substitute_mv=tuple(min(max(lp.spec.substitute_mv, lp.mv_min), lp.mv_max) for lp in loops),
            initial_mv=tuple(lp.mv for lp in loops),
            initial_mode=tuple(lp.mode for lp in loops),
        )

    def _shell_of(self, loops: list[_Loop], block: SingleLoopBlock) -> LoopShell:
        shell = LoopShell(block, self._shell_config(loops))
        self._attach(loops, shell)
        return shell

    @staticmethod
    def _attach(loops: list[_Loop], shell: LoopShell) -> None:
        for k, lp in enumerate(loops):
            lp.shell = shell
            lp.slot = k
            if lp.mode is LoopMode.MANUAL:
                shell.set_mode(k, LoopMode.MANUAL, lp.manual_mv)

    @staticmethod
    def _coupled_groups(loops: list[_Loop]) -> list[list[_Loop]]:
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
        groups: dict[str, list[_Loop]] = {}
        for lp in loops:
            groups.setdefault(root(lp.spec.name), []).append(lp)
        return list(groups.values())

    def _make_pid_group(self, loops: list[_Loop]) -> _Group:
        for attr in ("pv_bad_scans", "derivative_filter_s"):
            values = {getattr(lp.spec, attr) for lp in loops}
            if len(values) > 1:
                names = ", ".join(lp.spec.name for lp in loops)
                raise ValueError(f"plc.loops {names}: loops coupled by cross_gains must share {attr}")
        for lp in loops:
            lp.block_scale = lp.scale
        sc = self._shell_config(loops)
        cfg = PidConfig(
            n_loops=len(loops),
            ts_s=self.ts_s,
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
        pid = Pid(cfg, self._group_gains(loops))
        self._attach(loops, pid)
        return _Group(loops=loops, shell=pid)

    @staticmethod
    def _group_gains(loops: list[_Loop]) -> PidGains:
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

    def _make_nlpi(self, lp: _Loop) -> NlPi | AdaptiveNlPi:
        p = lp.spec.nlpi
        assert p is not None
        if p.adaptive:
            return AdaptiveNlPi(
                AdaptiveNlPiConfig(
                    ts_s=self.ts_s,
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
        return NlPi(
            NlPiConfig(ts_s=self.ts_s, gains=gains, u_min=lp.mv_min, u_max=lp.mv_max, initial_mv=lp.mv)
        )

    def _make_mrac(self, lp: _Loop) -> Mrac:
        p = lp.spec.mrac
        assert p is not None
        return Mrac(
            MracConfig(
                ts_s=self.ts_s,
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

    # ---- requests between scans ---------------------------------------------------------

    def loop(self, name: str) -> _Loop:
        """The loop called ``name`` (LIC1, ...)."""
        for lp in self.loops:
            if lp.spec.name == name:
                return lp
        raise KeyError(f"unknown loop {name!r}")

    def set_sp(self, name: str, sp_m: float) -> None:
        """Operator setpoint [m]; must lie in the loop's program limits [SPLow, SPHigh]."""
        lp = self.loop(name)
        lo, hi = self.sp_limits(name)
        if not (math.isfinite(sp_m) and lo <= sp_m <= hi):
            raise ValueError(f"{name} SP {sp_m} outside [{lo}, {hi}]")
        lp.sp_m = float(sp_m)

    def sp_limits(self, name: str) -> tuple[float, float]:
        """The operator's setpoint range of a loop now [m]: the engineer's limits, which lie
        inside the config's [sp_min_m, sp_max_m] (the defaults)."""
        lp = self.loop(name)
        return max(lp.sp_low_m, lp.spec.sp_min_m), min(lp.sp_high_m, lp.spec.sp_max_m)

    def set_sp_limits(self, name: str, low_m: float | None = None, high_m: float | None = None) -> None:
        """Engineer: narrow (or restore) the operator's setpoint range of a loop [m].

        Both limits must be finite, inside the config's [sp_min_m, sp_max_m], low <= high, and
        the current setpoint must lie inside the new range (move it first); else ValueError and
        nothing changes.
        """
        lp = self.loop(name)
        lo_now, hi_now = self.sp_limits(name)
        lo = lo_now if low_m is None else float(low_m)
        hi = hi_now if high_m is None else float(high_m)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError(f"{name} setpoint limits must be finite")
        if not lp.spec.sp_min_m <= lo <= hi <= lp.spec.sp_max_m:
            raise ValueError(
                f"{name} setpoint limits [{lo}, {hi}] must lie in [{lp.spec.sp_min_m}, {lp.spec.sp_max_m}]"
            )
        if not lo <= lp.sp_m <= hi:
            raise ValueError(f"{name} SP {lp.sp_m} lies outside the new limits [{lo}, {hi}]")
        lp.sp_low_m, lp.sp_high_m = lo, hi

    def set_mode(self, name: str, mode: LoopMode) -> None:
        """Switch a loop's mode (bumpless in every direction: MANUAL and REMOTE start from the MV)."""
        lp = self.loop(name)
        mode = LoopMode(mode)
        if mode is lp.mode:
            return
        lp.mode_changed_scan = self.scan_count
        shell = lp.loop_shell
        shell.set_mode(lp.slot, mode)
        # Entering MANUAL or REMOTE holds the applied MV (until the operator or the supervisor
        # writes ManualMV or RemoteMV).
        if mode is LoopMode.REMOTE:
            lp.remote_mv = shell.held_mv(lp.slot)[1]
        elif mode is LoopMode.MANUAL:
            lp.manual_mv = shell.held_mv(lp.slot)[0]
        lp.mode = mode

    def set_manual_mv(self, name: str, mv: float) -> None:
        """Operator output for MANUAL [pump unit]; must lie in the MV range."""
        lp = self.loop(name)
        self._check_mv(lp, mv)
        lp.manual_mv = float(mv)
        lp.loop_shell.set_manual_mv(lp.slot, mv)

    def set_remote_mv(self, name: str, mv: float) -> None:
        """Supervisor output for REMOTE [pump unit]; must lie in the MV range."""
        lp = self.loop(name)
        self._check_mv(lp, mv)
        lp.remote_mv = float(mv)
        lp.loop_shell.set_remote_mv(lp.slot, mv)

    @staticmethod
    def _check_mv(lp: _Loop, mv: float) -> None:
        if not (math.isfinite(mv) and lp.mv_min <= mv <= lp.mv_max):
            raise ValueError(f"{lp.spec.name} MV {mv} outside [{lp.mv_min}, {lp.mv_max}]")

    def heartbeat(self, value: int) -> None:
        """The supervisor wrote its heartbeat (any change counts as alive at the next scan)."""
        self._pending_heartbeat = int(value)

    @property
    def supervisor_trusted(self) -> bool:
        """Alive, and alive long enough for its gains to be accepted."""
        w = self.watchdog
        return w.alive and w.good_scans >= w.good_scans_needed

    def stage_gains(
        self, name: str, kp: float, ki: float, kd: float, source: GainSource = GainSource.SUPERVISOR
    ) -> GainStatus:
        """Validate (Kp, Ki, Kd) and stage them for the next scan boundary; all or nothing.

        Parameters
        ----------
        name : the loop (LIC1, ...).
        kp, ki, kd : the gains, in the loop's error unit.
        source : who asks: SUPERVISOR (the supervisor's identity) or ENGINEER (an engineer's own
            call); the applied gains carry it as their GainSource from the boundary on.

        Order of the checks: a block without PID gains answers INVALID_STATE; a non-finite value
        or one outside the loop's ``gain_box`` (when configured) OUT_OF_RANGE; then, for the
        supervisor only: a loop held by an engineer (GainSource ENGINEER, or an engineer's
        SetGains or a ResetGains staged) INVALID_STATE, a supervisor that is not trusted yet
        INVALID_STATE. An engineer's call works whatever the supervisor's state. A refused call
        changes nothing.

        Raises
        ------
        ValueError
            ``source`` is neither SUPERVISOR nor ENGINEER (a programming error).
        """
        if source not in (GainSource.SUPERVISOR, GainSource.ENGINEER):
            raise ValueError(f"SetGains is labelled SUPERVISOR or ENGINEER, not {source!r}")
        lp = self.loop(name)
        if lp.spec.block != "pid":
            return GainStatus.INVALID_STATE
        try:
            values = (float(kp), float(ki), float(kd))
        except (TypeError, ValueError):
            return GainStatus.OUT_OF_RANGE
        if not all(math.isfinite(v) for v in values):
            return GainStatus.OUT_OF_RANGE
        box = lp.gain_box
        if box is not None and not box.contains(LoopGains(*values)):
            return GainStatus.OUT_OF_RANGE
        if source is GainSource.SUPERVISOR and (self.engineer_holds(name) or not self.supervisor_trusted):
            return GainStatus.INVALID_STATE
        lp.staged = LoopGains(*values)
        lp.staged_source = source
        return GainStatus.STAGED

    def engineer_holds(self, name: str) -> bool:
        """Whether the supervisor is kept off a loop's gains: its GainSource is ENGINEER, or an
        engineer's SetGains or a ResetGains waits for the next boundary."""
        lp = self.loop(name)
        return lp.source is GainSource.ENGINEER or lp.staged_source in (GainSource.ENGINEER, GainSource.FIXED)

    def mode_change_pending(self, name: str) -> bool:
        """Whether a loop's mode changed since the last scan (the new mode has not run yet)."""
        return self.loop(name).mode_changed_scan == self.scan_count

    def reset_gains(self, name: str) -> GainStatus:
        """Return a PID loop to its configured (FIXED) gains at the next scan boundary.

        Staged like ``stage_gains`` (the velocity form makes the change bumpless: the scan after
        the boundary moves the MV by the fixed gains' increment only); the loop's GainSource
        becomes FIXED there, which also releases an engineer's hold. Until then the supervisor's
        SetGains on the loop is refused.

        Returns INVALID_STATE for a block without PID gains and while a mode change of the loop
        is pending (written since the last scan: the mode and the gains would change on the same
        scan; retry after it); else STAGED. A refused call changes nothing.
        """
        lp = self.loop(name)
        if lp.spec.block != "pid" or lp.fixed is None or self.mode_change_pending(name):
            return GainStatus.INVALID_STATE
        lp.staged = lp.fixed
        lp.staged_source = GainSource.FIXED
        return GainStatus.STAGED

    def release_gains(self, name: str) -> GainStatus:
        """Hand a loop held by an engineer back to adaptation, now.

        The applied gains stay; GainSource ENGINEER becomes FIXED (what it would be without the
        engineer: no tier changes these gains until the supervisor pushes again), and an
        engineer's SetGains still staged is dropped (the release is the later instruction). A
        loop not held is left as it is (STAGED: done). INVALID_STATE for a block without PID gains.
        """
        lp = self.loop(name)
        if lp.spec.block != "pid":
            return GainStatus.INVALID_STATE
        if lp.staged_source is GainSource.ENGINEER:
            lp.staged = None
            lp.staged_source = None
        if lp.source is GainSource.ENGINEER:
            lp.source = GainSource.FIXED
        return GainStatus.STAGED

    # ---- retentive memory (warm restart) -------------------------------------------------

    def retained(self) -> dict[str, Any]:
        """The retentive data of a warm restart (JSON-able).

        Per loop: SP, the engineer's SP limits, mode, manual MV, the applied gains and their source
        (ENGINEER included: an engineer's hold survives a restart) and the last MV (the fallback
        start value when the plant cannot be read at start). Latched interlocks (a trip survives
        a restart until an operator resets it), the scan counter (scans run so far) and the model
        time at the start of the last scan [s].
        """
        loops = {}
        for lp in self.loops:
            g = lp.applied
            loops[lp.spec.name] = {
                "sp_m": lp.sp_m,
                "sp_limits_m": list(self.sp_limits(lp.spec.name)),
                "mode": lp.mode.name,
                "gains": [g.kp, g.ki, g.kd] if g is not None else None,
                "source": lp.source.name,
                "manual_mv": lp.manual_mv,
                "mv": lp.mv,
            }
        return {
            "scan": self.scan_count,
            "t_s": self.t_s,
            "loops": loops,
            "tripped": [il.tank_name for il in self.interlocks if il.tripped],
        }

    def restore_retained(self, data: Mapping[str, Any]) -> list[str]:
        """Warm restart from :meth:`retained` output; return what could not be restored.

        Every value is checked as if it were written now (setpoint range, gain box, MV range);
        an entry that fails keeps the cold-start value and is reported, never half-applied.
        The scan counter and the model time continue from the retained ones (the next scan is
        ``scan + 1`` at ``t_s + Ts``: :attr:`next_scan_t_s`); each loop's MV starts at its
        retained MV until :meth:`resume_from_plant` puts it at the pump's command.
        Gains from the supervisor come back as SUPERVISOR; the watchdog turns them into FALLBACK
        if the supervisor does not return within its timeout. An engineer's gains come back as
        ENGINEER, still held (the supervisor stays off them until a release or a reset).
        """
        skipped: list[str] = []
        if "scan" in data or "t_s" in data:  # absent in files of earlier versions
            try:
                scan, t_s = data["scan"], float(data["t_s"])
                if type(scan) is not int or scan < 0 or not (math.isfinite(t_s) and t_s >= 0.0):
                    raise ValueError(f"scan {scan!r} and model time {t_s!r} must be >= 0")
            except (KeyError, ValueError, TypeError) as e:
                skipped.append(f"scan counter and model time: {e}")
            else:
                self.scan_count, self.t_s = scan, t_s
        for name, entry in dict(data.get("loops", {})).items():
            try:
                lp = self.loop(name)
                if "sp_limits_m" in entry:  # absent in files of earlier versions
                    lo, hi = (float(x) for x in entry["sp_limits_m"])
                    lp.sp_low_m, lp.sp_high_m = lp.spec.sp_min_m, lp.spec.sp_max_m
                    if not lo <= lp.sp_m <= hi:
                        self.set_sp(name, min(max(lp.sp_m, lo), hi))
                    self.set_sp_limits(name, lo, hi)
                self.set_sp(name, float(entry["sp_m"]))
                gains = entry.get("gains")
                if gains is not None and lp.spec.block == "pid":
                    kp, ki, kd = (float(x) for x in gains)
                    box = lp.gain_box
                    finite = all(math.isfinite(v) for v in (kp, ki, kd))
                    if not finite or (box is not None and not box.contains(LoopGains(kp, ki, kd))):
                        raise ValueError("retained gains outside the gain box")
                    source = GainSource[str(entry["source"])]
                    lp.applied = LoopGains(kp, ki, kd)
                    if source is not GainSource.ENGINEER:  # last_accepted: the supervisor's gains
                        lp.last_accepted = lp.applied
                    lp.source = source
                # Mode before the manual value: entering MANUAL tracks the applied MV.
                self.set_mode(name, LoopMode[str(entry["mode"])])
                lp.mode_changed_scan = -1  # a restored mode is not a change in progress
                self.set_manual_mv(name, float(entry["manual_mv"]))
                if "mv" in entry:  # the start value until the plant's command is read
                    mv = float(entry["mv"])
                    self._check_mv(lp, mv)
                    self._resume_mv(lp, mv, math.nan)
            except (KeyError, ValueError, TypeError) as e:
                skipped.append(f"{name}: {e}")
        self._set_pid_gains()
        tripped = set(data.get("tripped", []))
        for il in self.interlocks:
            il.tripped = il.tank_name in tripped
        return skipped

    @property
    def next_scan_t_s(self) -> float:
        """Model time of the next scan [s]: 0 before the first, else the last scan's + Ts."""
        return self.t_s + self.ts_s if self.scan_count > 0 else 0.0

    def resume_from_plant(self, commands: FloatArray, levels_m: FloatArray, good: BoolArray) -> None:
        """Warm restart: continue from the plant as it is now, before the first scan.

        Parameters
        ----------
        commands : (n_pumps,) the plant's pump commands now [pump units] (NaN: unknown; the
            loop keeps its retained MV).
        levels_m : (n_tanks,) the transmitter readings now [m].
        good : (n_tanks,) their quality.

        Each loop's MV becomes its pump's command (clamped to the loop's MV range), so the first
        scan does not move the output from where the pump is: a PID continues its velocity form
        from it, primed with the reading (``Pid.resume``: the first increment with the same SP
        and PV is ``Ki * Ts * e`` alone), NL-PI and MRAC track it, a loop in REMOTE holds it
        until the supervisor writes ``RemoteMV``; a loop in MANUAL applies its retained manual
        MV from the first scan on (the operator's value), rate-limited from the pump's command.
        The readings are shown on the PV nodes until the first scan replaces them.

        Raises
        ------
        ValueError
            An array does not have one entry per pump or tank (a programming error).
        """
        cmd = np.asarray(commands, dtype=float)
        levels = np.asarray(levels_m, dtype=float)
        ok = np.asarray(good, dtype=bool)
        if cmd.shape != (self.n_pumps,) or levels.shape != self._shape or ok.shape != self._shape:
            raise ValueError(
                f"resume needs {self.n_pumps} commands and {self.n_tanks} levels and qualities, got "
                f"shapes {cmd.shape}, {levels.shape} and {ok.shape}"
            )
        for k, x in enumerate(levels.tolist()):
            lo, hi = self._tr_range[k]
            if ok[k] and math.isfinite(x) and lo <= x <= hi:
                self._last_good_m[k] = x
            else:
                levels[k] = math.nan
        for lp in self.loops:
            c = float(cmd[lp.pump])
            mv = min(max(c, lp.mv_min), lp.mv_max) if math.isfinite(c) else lp.mv
            pv = float(levels[lp.tank])
            if math.isfinite(pv):
                lp.pv_last_good_m = pv
            self._resume_mv(lp, mv, pv)

    def _resume_mv(self, lp: _Loop, mv: float, pv_m: float) -> None:
        """Put a loop's applied MV at ``mv`` (and a PID's memory at the reading ``pv_m``)."""
        lp.mv = mv
        self._commands[lp.pump] = mv
        shell = lp.loop_shell
        shell.resume(lp.slot, mv, lp.sp_m * lp.block_scale, pv_m * lp.block_scale)
        if lp.mode is LoopMode.REMOTE:
            lp.remote_mv = mv
            shell.set_remote_mv(lp.slot, mv)

    def reset_interlocks(self) -> list[str]:
        """Reset latched trips whose (good) level is below the reset level; return the tanks reset."""
        reset = []
        for il in self.interlocks:
            level = self._levels_m[il.tank]
            if il.tripped and self._good[il.tank] and level < il.reset_below_m:
                il.tripped = False
                reset.append(il.tank_name)
        return reset

    # ---- the scan -----------------------------------------------------------------------

    def scan(self, inputs: ScanInputs, *, publish: bool = True) -> ScanOutputs:
        """Run one scan at model time ``inputs.t_s``; see the module docstring for the order.

        ``publish=False`` leaves ``ScanOutputs.values`` empty (a co-simulation without a
        supervisor reads no PLC node, and :meth:`values` is a tenth of a scan's time).

        Raises
        ------
        ValueError
            ``levels_m`` or ``good`` does not have one entry per tank (a programming error).
        """
        levels = np.asarray(inputs.levels_m, dtype=float)
        delivered = np.asarray(inputs.good, dtype=bool)
        if levels.shape != self._shape or delivered.shape != self._shape:
            raise ValueError(  # checked before anything changes: a refused scan leaves no trace
                f"scan inputs need {self.n_tanks} levels and qualities, got shapes "
                f"{levels.shape} and {delivered.shape}"
            )
        self.t_s = float(inputs.t_s)
        if self._run_watchdog():
            self._fall_back()
        self._apply_staged_gains()
        self._read_inputs(levels.tolist(), delivered.tolist(), bool(inputs.io_healthy))
        self._execute_blocks()
        self._write_outputs(self._apply_interlocks())
        self.scan_count += 1
        return ScanOutputs(
            commands=np.array(self._commands, dtype=float), values=self.values() if publish else {}
        )

    def _set_pid_gains(self) -> None:
        for group in self.pid_groups:
            g = self._group_gains(group.loops)
            assert isinstance(group.shell, Pid)
            group.shell.set_gains(g.kp, g.ki, g.kd)

    def _apply_staged_gains(self) -> None:
        changed = False
        for lp in self.loops:
            if lp.staged is not None:
                source = GainSource.SUPERVISOR if lp.staged_source is None else lp.staged_source
                lp.applied = lp.staged
                if source is GainSource.SUPERVISOR:
                    lp.last_accepted = lp.staged
                lp.staged = None
                lp.staged_source = None
                lp.source = source
                changed = True
        if changed:
            self._set_pid_gains()

    def _run_watchdog(self) -> bool:
        """Update Alive from the heartbeat; return whether the timeout has expired."""
        w = self.watchdog
        value = self._pending_heartbeat
        self._pending_heartbeat = None
        if w.last_change_s is None:
            w.last_change_s = self.t_s  # grace period: the first timeout counts from the first scan
        if value is not None and value != w.last_value:
            w.last_value = value
            w.last_change_s = self.t_s
        expired = self.t_s - w.last_change_s >= w.timeout_s - _TIME_EPS_SCANS * self.ts_s
        alive = w.last_value is not None and not expired
        if alive:
            w.good_scans += 1
            w.ever_alive = True
        else:
            w.good_scans = 0
        w.alive = alive
        w.expired = expired
        return expired

    def _fall_back(self) -> None:
        """Supervisor lost: the supervisor's staged gains dropped, supervisor gains -> FALLBACK,
        REMOTE -> AUTO (ENGINEER gains and an engineer's or a reset's staged set stay).

        Runs every scan while the supervisor is away (the co-simulation without one: always), so
        each loop is only read unless it has something to undo.
        """
        changed = False
        for lp in self.loops:
            if lp.staged is not None and lp.staged_source is GainSource.SUPERVISOR:
                lp.staged = None
                lp.staged_source = None
            if lp.source is GainSource.SUPERVISOR:
                lp.applied = lp.fixed if self.fallback == "fixed" else lp.last_accepted
                lp.source = GainSource.FALLBACK
                changed = True
            if lp.mode is LoopMode.REMOTE:
                self.set_mode(lp.spec.name, LoopMode.AUTO)
        if changed:
            self._set_pid_gains()

    def _read_inputs(self, levels: list[float], delivered: list[bool], io_healthy: bool) -> None:
        # Per tank on Python floats, the state updated in place (see __init__).
        self.io_healthy = io_healthy
        frozen_n = self.pv_frozen_scans
        ranges, raw, good, used, last_good = (
            self._tr_range,
            self._raw_m,
            self._good,
            self._levels_m,
            self._last_good_m,
        )
        last, repeats = self._frozen.last, self._frozen.repeats
        for k, x in enumerate(levels):
            delivered_k = delivered[k] and io_healthy and math.isfinite(x)
            raw[k] = x if delivered_k else math.nan
            lo, hi = ranges[k]
            ok = delivered_k and lo <= x <= hi
            if frozen_n > 0:
                repeats[k] = repeats[k] + 1 if x == last[k] else 0
                ok = ok and repeats[k] < frozen_n
            good[k] = ok
            if ok:
                used[k] = last_good[k] = x
            else:
                used[k] = math.nan
        if frozen_n > 0:
            self._frozen.last = levels  # the scan's own list (tolist of the input)

    def _execute_blocks(self) -> None:
        good, levels = self._good, self._levels_m
        for lp in self.loops:
            if good[lp.tank]:
                lp.pv_bad = False
                lp.pv_m = lp.pv_last_good_m = levels[lp.tank]
            else:
                lp.pv_bad = True
                lp.pv_m = math.nan
        # One call per shell, whatever the block: SP ramp, modes, the law, substitute, limits.
        for group in self.groups:
            loops = group.loops
            shell = group.shell
            mv = shell.scan(
                [lp.sp_m * lp.block_scale for lp in loops],
                [lp.pv_m * lp.block_scale for lp in loops],  # NaN where bad
                [not lp.pv_bad for lp in loops],
            )
            substituted = shell.substituted
            for k, lp in enumerate(loops):
                lp.mv = mv[k]
                lp.substituted = substituted[k]

    def _apply_interlocks(self) -> list[bool] | None:
        """Latch trips; return which pumps (pump order) are forced to their lowest command this
        scan (None: none)."""
        raw = self._raw_m
        any_tripped = False
        for il in self.interlocks:
            # Fail-safe: any delivered finite reading counts, even over-range or frozen.
            if raw[il.tank] >= il.high_high_m:
                il.tripped = True
            any_tripped = any_tripped or il.tripped
        if not any_tripped:  # the usual scan: no pump forced, no block to tell
            return None
        tripped = [False] * self.n_tanks
        for il in self.interlocks:
            tripped[il.tank] = tripped[il.tank] or il.tripped
        forced = [tripped[tank] for tank in self._pump_tank]
        for lp in self.loops:
            if not forced[lp.pump]:
                continue
            lp.mv = self._pump_min[lp.pump]
            held = lp.loop_shell.force(lp.slot, lp.mv)  # clamped to the loop's MV range
            if lp.mode is LoopMode.MANUAL:
                lp.manual_mv = held
            elif lp.mode is LoopMode.REMOTE:
                lp.remote_mv = held
        return forced

    def _write_outputs(self, forced: list[bool] | None) -> None:
        commands, lows, highs = self._commands, self._pump_min, self._pump_max
        for lp in self.loops:
            commands[lp.pump] = lp.mv
        for k, c in enumerate(commands):
            lo, hi = lows[k], highs[k]
            if forced is not None and forced[k]:
                commands[k] = lo
            else:  # min(max(c, lo), hi) as the builtins evaluate it, without their calls
                low = lo if lo > c else c
                commands[k] = hi if hi < low else low

    # ---- publishing ---------------------------------------------------------------------

    def values(self) -> dict[str, Any]:
        """Every PLC node's value the program owns, keyed by tag path (plain Python types).

        All variables of :func:`tanklab.tags.plc_tags` except :data:`RUNTIME_OWNED_TAGS`,
        ``PLC.LIC*.Block`` and ``PLC.Identity.*`` (constant: the nodes keep their initial
        values). A bad PV is published as its last good value (0 before the first one), with its
        quality on ``PLC.IO.LT*.Good`` and ``PLC.Alarms.LIC*PvBad``.
        """
        v: dict[str, Any] = {}
        for lp in self.loops:
            p = f"PLC.{lp.spec.name}"
            v[f"{p}.SP"] = float(lp.sp_m)
            v[f"{p}.SPLow"], v[f"{p}.SPHigh"] = self.sp_limits(lp.spec.name)
            v[f"{p}.PV"] = float(lp.pv_last_good_m)
            v[f"{p}.MV"] = float(lp.mv)
            v[f"{p}.Mode"] = int(lp.mode)
            v[f"{p}.ManualMV"] = float(lp.manual_mv)
            v[f"{p}.RemoteMV"] = float(lp.remote_mv)
            g = lp.applied
            v[f"{p}.Kp"] = float(g.kp) if g else 0.0
            v[f"{p}.Ki"] = float(g.ki) if g else 0.0
            v[f"{p}.Kd"] = float(g.kd) if g else 0.0
            v[f"{p}.GainSource"] = int(lp.source)
            v[f"PLC.Alarms.{lp.spec.name}PvBad"] = bool(lp.pv_bad)
        v["PLC.Status.Scan"] = int(self.scan_count)
        v["PLC.Status.IoHealthy"] = bool(self.io_healthy)
        v["PLC.Status.ModelTime"] = float(self.t_s)
        v["PLC.Supervisor.Alive"] = bool(self.watchdog.alive)
        v["PLC.Alarms.IoFault"] = not self.io_healthy
        v["PLC.Alarms.SupervisorLost"] = bool(self.watchdog.ever_alive and not self.watchdog.alive)
        for i, name in enumerate(self.site.tank_names):
            level = self._levels_m[i]
            ok = self._good[i]
            v[f"PLC.IO.LT{name[1:]}.PV"] = self._last_good_m[i]
            v[f"PLC.IO.LT{name[1:]}.Good"] = ok
            v[f"PLC.Alarms.{name}H"] = bool(ok and level >= self.high_m[i])
            v[f"PLC.Alarms.{name}L"] = bool(ok and level <= self.low_m[i])
            v[f"PLC.Alarms.{name}HH"] = bool(self._raw_m[i] >= self.hh_m[i])
        for il in self.interlocks:
            v[f"PLC.Interlock.{il.tank_name}HH"] = bool(il.tripped)
        return v
