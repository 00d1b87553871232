"""Random operator scenarios for the co-simulation: seeded, reproducible, inside the contract.

A random scenario is an initial state and a list of timed requests, each one a write an operator,
an engineer or the supervisor can make through the OPC UA nodes, drawn inside that node's range
(``tanklab.tags``):

- ``PLC.LIC*.SP`` in [sp_min_m, sp_max_m] (the node's EURange, enforced again by ``set_sp``);
- ``Plant.T*.Leak`` in [0, 1];
- ``Plant.T*.Disturbance`` in [-d_max, +d_max], d_max = the largest pump's flow (the EURange;
  :attr:`ScenarioSpace.inflows` can bound the inflow side by what the plant passes, see below);
- ``PLC.LIC*.SetGains`` inside the loop's ``gain_box`` (PID loops that have one, on sites with a
  supervisor: the PLC stages gains only while a supervisor is trusted), through
  :meth:`plc_emulator.program.PlcProgram.stage_gains`, the path the supervisor's pushes take;
- ``PLC.LIC*.Mode`` (MANUAL with ``ManualMV`` in the MV range, AUTO, REMOTE);
- ``Supervisor.Mode`` (OFF, ADVISORY, ADAPTIVE_PID, MPC; sites with a supervisor);
- ``PLC.Interlock.Reset`` (takes effect only below the reset level, as on the PLC).

Values are drawn uniformly in their range, with the range's ends drawn on purpose (probability
:data:`EDGE_PROBABILITY` each): the ends (a setpoint at sp_max, a gain at the box's corner, a leak
fully open then shut) are where an overflow would come from. Initial levels are uniform between
empty and the high switch LSH. Request times form a Poisson process on whole scans. One
``numpy.random.Generator`` seeded with the scenario's seed draws everything, so
``generate(site, seed, space)`` is the same scenario on every machine.

:func:`run_scenario` runs one in :class:`tankctl.cosim.CoSimulation` (no clock read) and checks,
with V = cumulative volumes [m^3], A_i tank areas [m^2], h_i true levels [m]:

- **no overflow**: V_spilled = 0 throughout (the plant's own overflow account, fed by every flow
  over a tank top and by every level the integrator moves back under Hmax);
- **levels in range**: 0 <= h_i <= Hmax_i at every scan;
- **water balance**: sum_i A_i h_i + V_out + V_leaked + V_spilled - V_in - V_stored(0) = 0 (the
  plant's accounts), and V_in against an independent account sum_k Ts (sum_j Q_j(k) + sum_i
  max(d_i(k), 0)) from the recorded pump flows and the disturbances written (pumps without lag:
  the flow is constant over a scan);
- **interlock**: a scan that reads LT_i >= HH_i commands every pump into T_i to its minimum.

What zero overflows relies on. The PLC's only means against a rising level is to stop pumps:

1. Between two scans a pump-fed tank rises at most (sum of its pumps' flows) Ts / A_i
   (:func:`scan_rise_m`); the HH interlock catches it before the top only if that is less than
   Hmax_i - HH_i (Energies: 7.8 mm per 1 s scan against 40 mm).
2. A tank without a pump must fill only from tanks the interlocks keep below the top (on the
   Energies plant T3 fills from T1 alone, so h3 < h1).
3. An injected *inflow* must be one the orifices pass even when the PLC holds the other tanks as
   high as it may: :class:`InflowAuthority`. Beyond that no controller can prevent a spill, so
   ``ScenarioSpace(inflows="passable")`` draws inflows inside it, and :func:`first_unpassable`
   tells whether an overflow under ``"eurange"`` inflows had such an inflow before it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from plant_sim.models import FloatArray
from plc_emulator.program import GainStatus
from tankctl.cosim import CoSimEvents, CoSimulation
from tankctl.events import apply_event as apply_scenario_event
from tankctl.inflow_authority import InflowAuthority, inflow_capacity_m3_s, scan_rise_m
from tanklab import paths
from tanklab.config import SiteConfig
from tanklab.scenario import (
    DisturbanceEvent,
    LeakEvent,
    LoopModeEvent,
    SetpointEvent,
    SupervisorModeEvent,
)

SupervisorModeName = Literal["OFF", "ADVISORY", "ADAPTIVE_PID", "MPC"]
EventKind = Literal["setpoint", "leak", "disturbance", "gains", "loop_mode", "supervisor_mode", "reset"]

__all__ = [
    "EDGE_PROBABILITY",
    "GainsEvent",
    "InflowAuthority",
    "InterlockResetEvent",
    "RandomEvent",
    "RandomScenario",
    "RunResult",
    "ScenarioSpace",
    "apply_event",
    "describe",
    "first_unpassable",
    "generate",
    "inflow_capacity_m3_s",
    "run_scenario",
    "scan_rise_m",
]

EDGE_PROBABILITY = 0.15
"""Probability of drawing each end of a range (the rest is uniform inside it)."""

DEFAULT_WEIGHTS: Mapping[EventKind, float] = {
    "setpoint": 3.0,
    "leak": 2.0,
    "disturbance": 1.5,
    "gains": 1.5,
    "loop_mode": 1.0,
    "supervisor_mode": 0.5,
    "reset": 1.0,
}
"""Relative frequency of each request kind (kinds a site does not offer are dropped)."""


# --------------------------------------------------------------------------------------------
# Requests that have no scenario-file event
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GainsEvent:
    """``PLC.LIC*.SetGains(Kp, Ki, Kd)``, staged for the next scan boundary."""

    at_s: float
    loop: str
    kp: float
    ki: float
    kd: float
    kind: Literal["gains"] = "gains"


@dataclass(frozen=True)
class InterlockResetEvent:
    """``PLC.Interlock.Reset()``: resets the trips whose level is below their reset level."""

    at_s: float
    kind: Literal["reset"] = "reset"


RandomEvent = (
    SetpointEvent
    | LeakEvent
    | DisturbanceEvent
    | LoopModeEvent
    | SupervisorModeEvent
    | GainsEvent
    | InterlockResetEvent
)


def describe(ev: RandomEvent) -> str:
    """One line: the request as an operator would read it in a log."""
    if isinstance(ev, SetpointEvent):
        return f"{ev.loop}.SP = {ev.value_m:.6g} m"
    if isinstance(ev, LeakEvent):
        return f"{ev.tank}.Leak = {ev.opening:.6g}"
    if isinstance(ev, DisturbanceEvent):
        return f"{ev.tank}.Disturbance = {ev.flow_m3_s:+.6g} m^3/s"
    if isinstance(ev, LoopModeEvent):
        mv = "" if ev.mv_percent is None else f" (ManualMV {ev.mv_percent:.4g} %)"
        return f"{ev.loop}.Mode = {ev.mode}{mv}"
    if isinstance(ev, SupervisorModeEvent):
        return f"{paths.supervisor.mode} = {ev.mode}"
    if isinstance(ev, GainsEvent):
        return f"{ev.loop}.SetGains({ev.kp:.6g}, {ev.ki:.6g}, {ev.kd:.6g})"
    return "Interlock.Reset()"


# --------------------------------------------------------------------------------------------
# The space of scenarios and the generator
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScenarioSpace:
    """How long a random scenario runs, how often requests come, and which kinds.

    Attributes
    ----------
    duration_s : (min, max) run length in model time [s], drawn uniformly (whole scans).
    mean_interval_s : mean model time between two requests [s] (Poisson process).
    weights : relative frequency of each request kind.
    inflows : upper end of a disturbance write: ``"eurange"``, the node's EURange (the plant's
        disturbance limit); ``"passable"``, the largest inflow that, with the inflows already
        injected into the other tanks, the plant still passes without spilling when the PLC
        holds the other tanks as high as it may (:meth:`InflowAuthority.headroom`). The outflow
        side always spans the whole EURange.
    supervisor_modes : supervisor modes drawn at start and by ``supervisor_mode`` requests.
    """

    duration_s: tuple[float, float] = (600.0, 1000.0)
    mean_interval_s: float = 60.0
    weights: Mapping[EventKind, float] = field(default_factory=lambda: dict(DEFAULT_WEIGHTS))
    inflows: Literal["eurange", "passable"] = "eurange"
    supervisor_modes: tuple[SupervisorModeName, ...] = ("OFF", "ADVISORY", "ADAPTIVE_PID", "MPC")

    def __post_init__(self) -> None:
        lo, hi = self.duration_s
        if not 0 < lo <= hi or not math.isfinite(hi):
            raise ValueError(f"duration_s must be 0 < min <= max, got {self.duration_s}")
        if not (self.mean_interval_s > 0 and math.isfinite(self.mean_interval_s)):
            raise ValueError(f"mean_interval_s must be positive, got {self.mean_interval_s}")
        if any(w < 0 or not math.isfinite(w) for w in self.weights.values()):
            raise ValueError("weights must be finite and non-negative")
        if self.inflows not in ("eurange", "passable"):
            raise ValueError(f"inflows must be 'eurange' or 'passable', got {self.inflows!r}")


@dataclass(frozen=True)
class RandomScenario:
    """One generated scenario: reproduced exactly by ``generate(site, seed, space)``.

    Attributes
    ----------
    seed : seed of the generator that drew it.
    site : the site it runs on (initial levels already set from ``initial_levels_m``).
    duration_s : run length [s], a whole number of scans.
    initial_levels_m : (n_tanks,) levels at start [m].
    supervisor_mode : the supervisor's mode at start; None on a site without a supervisor.
    events : requests, sorted by time (requests at the same time in the order drawn).
    """

    seed: int
    site: SiteConfig
    duration_s: float
    initial_levels_m: tuple[float, ...]
    supervisor_mode: SupervisorModeName | None
    events: tuple[RandomEvent, ...]

    @classmethod
    def build(
        cls,
        site: SiteConfig,
        events: Sequence[RandomEvent],
        *,
        duration_s: float,
        initial_levels_m: Sequence[float] | None = None,
        supervisor_mode: SupervisorModeName | None = None,
        seed: int = -1,
    ) -> RandomScenario:
        """A scenario written by hand (a regression case), run like a generated one.

        ``initial_levels_m`` default: the site's; events are sorted by time (stable).
        """
        levels = tuple(
            float(h)
            for h in (
                initial_levels_m
                if initial_levels_m is not None
                else [t.initial_level_m for t in site.plant.tanks]
            )
        )
        return cls(
            seed=seed,
            site=_with_levels(site, levels),
            duration_s=float(duration_s),
            initial_levels_m=levels,
            supervisor_mode=supervisor_mode,
            events=tuple(sorted(events, key=lambda ev: ev.at_s)),
        )

    def describe(self) -> str:
        """The whole scenario, one request per line (what a failure message prints)."""
        levels = ", ".join(f"{h:.4g}" for h in self.initial_levels_m)
        lines = [
            f"seed {self.seed} on {self.site.name}: {self.duration_s:g} s, supervisor "
            f"{self.supervisor_mode}, initial levels [{levels}] m, {len(self.events)} requests"
        ]
        lines += [f"  t = {ev.at_s:7.1f} s  {describe(ev)}" for ev in self.events]
        return "\n".join(lines)


def _draw(rng: np.random.Generator, lo: float, hi: float) -> float:
    """Uniform in [lo, hi], with each end drawn with probability EDGE_PROBABILITY."""
    u = rng.random()
    if u < EDGE_PROBABILITY:
        return lo
    if u < 2 * EDGE_PROBABILITY:
        return hi
    return float(rng.uniform(lo, hi))


def _gain_loops(site: SiteConfig) -> list[str]:
    """PID loops that accept SetGains: a gain box, and a supervisor to be trusted."""
    if site.plc is None or site.supervisor is None:
        return []
    return [lp.name for lp in site.plc.loops if lp.block == "pid" and lp.gain_box is not None]


def generate(site: SiteConfig, seed: int, space: ScenarioSpace | None = None) -> RandomScenario:
    """Draw one random scenario for ``site`` from ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    site : a site with a ``plc`` section.
    seed : the generator's seed; the same (site, seed, space) gives the same scenario.
    space : durations, rates and kinds; default :class:`ScenarioSpace`.

    Raises
    ------
    ValueError
        The site has no PLC program.
    """
    if site.plc is None:
        raise ValueError(f"site {site.name!r} has no plc section")
    space = space or ScenarioSpace()
    rng = np.random.default_rng(seed)
    plant, plc = site.plant, site.plc
    ts = plc.scan_period_s
    limit = plant.disturbance_limit_m3_s
    inflow = _InflowBound(site, limit, InflowAuthority(site) if space.inflows == "passable" else None)
    gain_loops = _gain_loops(site)
    sup_modes: tuple[SupervisorModeName, ...] = space.supervisor_modes if site.supervisor else ()
    if site.supervisor is not None and not all(
        lp.block == "pid" and lp.gains is not None for lp in plc.loops
    ):
        sup_modes = tuple(m for m in sup_modes if m != "ADAPTIVE_PID")

    offered: dict[EventKind, bool] = {
        "setpoint": True,
        "leak": True,
        "disturbance": True,
        "gains": bool(gain_loops),
        "loop_mode": True,
        "supervisor_mode": bool(sup_modes),
        "reset": bool(plc.interlocks),
    }
    kinds = [k for k, w in space.weights.items() if w > 0 and offered.get(k, False)]
    if not kinds:
        raise ValueError(f"no request kind of {dict(space.weights)} is offered by site {site.name!r}")
    p = np.array([space.weights[k] for k in kinds], dtype=float)
    p /= p.sum()

    n_scans = max(1, round(float(rng.uniform(*space.duration_s)) / ts))
    duration = n_scans * ts
    levels = tuple(float(rng.uniform(0.0, t.switch_levels().high_m)) for t in plant.tanks)
    mode0: SupervisorModeName | None = sup_modes[int(rng.integers(len(sup_modes)))] if sup_modes else None

    events: list[RandomEvent] = []
    for lp in plc.loops:  # the operator's first setpoints
        events.append(
            SetpointEvent(
                at_s=0.0, kind="setpoint", loop=lp.name, value_m=_draw(rng, lp.sp_min_m, lp.sp_max_m)
            )
        )
    t = 0.0
    while True:
        t += float(rng.exponential(space.mean_interval_s))
        k = math.ceil(t / ts)
        if k >= n_scans:
            break
        at = k * ts
        kind = kinds[int(rng.choice(len(kinds), p=p))]
        events.append(_request(rng, site, kind, at, inflow, gain_loops, sup_modes))
    return RandomScenario(
        seed=seed,
        site=_with_levels(site, levels),
        duration_s=duration,
        initial_levels_m=levels,
        supervisor_mode=mode0,
        events=tuple(events),
    )


@dataclass
class _InflowBound:
    """The disturbances injected so far while generating, and the upper end of the next one."""

    site: SiteConfig
    limit: float
    authority: InflowAuthority | None
    active: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        self.active = np.zeros(len(self.site.tank_names))

    def upper(self, tank: int) -> float:
        if self.authority is None:
            return self.limit
        return self.authority.headroom(self.active, tank)


def _request(
    rng: np.random.Generator,
    site: SiteConfig,
    kind: EventKind,
    at_s: float,
    inflow: _InflowBound,
    gain_loops: Sequence[str],
    sup_modes: Sequence[SupervisorModeName],
) -> RandomEvent:
    """One request of ``kind`` at ``at_s``, its value drawn inside the node's range."""
    assert site.plc is not None
    loops = site.plc.loops
    tanks = site.tank_names
    if kind == "setpoint":
        lp = loops[int(rng.integers(len(loops)))]
        value = _draw(rng, lp.sp_min_m, lp.sp_max_m)
        return SetpointEvent(at_s=at_s, kind="setpoint", loop=lp.name, value_m=value)
    if kind == "leak":
        tank = tanks[int(rng.integers(len(tanks)))]
        return LeakEvent(at_s=at_s, kind="leak", tank=tank, opening=_draw(rng, 0.0, 1.0))
    if kind == "disturbance":
        i = int(rng.integers(len(tanks)))
        tank = tanks[i]
        # A quarter of the writes end the disturbance (0 is inside the range, not at an end).
        flow = 0.0 if rng.random() < 0.25 else _draw(rng, -inflow.limit, inflow.upper(i))
        inflow.active[i] = flow
        return DisturbanceEvent(at_s=at_s, kind="disturbance", tank=tank, flow_m3_s=flow)
    if kind == "gains":
        name = gain_loops[int(rng.integers(len(gain_loops)))]
        box = next(lp.gain_box for lp in loops if lp.name == name)
        assert box is not None
        kp, ki, kd = (_draw(rng, *box.kp), _draw(rng, *box.ki), _draw(rng, *box.kd))
        return GainsEvent(at_s=at_s, loop=name, kp=kp, ki=ki, kd=kd)
    if kind == "loop_mode":
        lp = loops[int(rng.integers(len(loops)))]
        mode = ("MANUAL", "AUTO", "REMOTE")[int(rng.integers(3))]
        mv = _draw(rng, 0.0, 100.0) if mode == "MANUAL" else None
        return LoopModeEvent(at_s=at_s, kind="loop_mode", loop=lp.name, mode=mode, mv_percent=mv)
    if kind == "supervisor_mode":
        sup = sup_modes[int(rng.integers(len(sup_modes)))]
        return SupervisorModeEvent(at_s=at_s, kind="supervisor_mode", mode=sup)
    return InterlockResetEvent(at_s=at_s)


def _with_levels(site: SiteConfig, levels_m: Sequence[float]) -> SiteConfig:
    """A copy of ``site`` that starts at ``levels_m`` (validated on assignment)."""
    out = site.model_copy(deep=True)
    for tank, level in zip(out.plant.tanks, levels_m, strict=True):
        tank.initial_level_m = level
    return out


def first_unpassable(scenario: RandomScenario, until_s: float | None = None) -> str | None:
    """The first disturbance write (at or before ``until_s``) after which the injected inflows
    no longer pass (:meth:`InflowAuthority.passes`), described; None if there is none."""
    authority = InflowAuthority(scenario.site)
    names = scenario.site.tank_names
    d = np.zeros(len(names))
    for ev in scenario.events:
        if until_s is not None and ev.at_s > until_s:
            break
        if isinstance(ev, DisturbanceEvent):
            d[names.index(ev.tank)] = ev.flow_m3_s
            if not authority.passes(d):
                return (
                    f"t = {ev.at_s:g} s {describe(ev)} (inflows now {np.array2string(d, precision=4)} m^3/s)"
                )
    return None


# --------------------------------------------------------------------------------------------
# Running and checking
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunResult:
    """What one random scenario did to the plant, and every oracle's measurement.

    Attributes
    ----------
    scenario : the scenario run.
    spilled_m3 : V_spilled at the end [m^3].
    first_spill_s : model time of the first scan that ended with V_spilled > 0 [s] (None: never).
    max_levels_m, min_levels_m : (n_tanks,) extreme true levels over the run [m].
    height_max_m : (n_tanks,) overflow heights Hmax [m].
    volume_in_m3 : V_in at the end [m^3].
    balance_error_m3 : the plant's balance error at the end [m^3].
    inflow_error_m3 : V_in minus the independent inflow account [m^3]; NaN with lagged pumps.
    interlock_misses : scans that read LT_i >= HH_i and left a pump into T_i above its minimum.
    trips : how many times an interlock latched.
    refused : requests the PLC refused, with the reason (gains while the supervisor is not yet
        trusted, ...): refusals are part of the contract, not failures.
    """

    scenario: RandomScenario
    spilled_m3: float
    first_spill_s: float | None
    max_levels_m: tuple[float, ...]
    min_levels_m: tuple[float, ...]
    height_max_m: tuple[float, ...]
    volume_in_m3: float
    balance_error_m3: float
    inflow_error_m3: float
    interlock_misses: int
    trips: int
    refused: tuple[str, ...]

    @property
    def margins_m(self) -> tuple[float, ...]:
        """(n_tanks,) Hmax_i - max_t h_i(t) [m]: how close each tank came to spilling."""
        return tuple(h - m for h, m in zip(self.height_max_m, self.max_levels_m, strict=True))

    @property
    def worst_margin_m(self) -> float:
        """The smallest margin to a tank top [m]."""
        return min(self.margins_m)

    def violations(self, balance_rtol: float = 1e-9) -> list[str]:
        """Every broken oracle, one line each (empty when the run is clean).

        ``balance_rtol`` is relative to the water handled, max(V_in, V_stored(0)) (rounding of
        the cumulative sums; the integrator keeps the balance an exact invariant otherwise).
        """
        out = []
        if self.spilled_m3 > 0.0:
            out.append(f"overflow: {self.spilled_m3:.6g} m^3 spilled, first at t = {self.first_spill_s} s")
        for i, name in enumerate(self.scenario.site.tank_names):
            if self.min_levels_m[i] < 0.0 or self.max_levels_m[i] > self.height_max_m[i]:
                out.append(
                    f"{name} level left [0, {self.height_max_m[i]:g}] m: "
                    f"[{self.min_levels_m[i]:.6g}, {self.max_levels_m[i]:.6g}]"
                )
        stored0 = float(sum(t.area_m2 * t.initial_level_m for t in self.scenario.site.plant.tanks))
        tol = balance_rtol * max(self.volume_in_m3, stored0, 1e-12)
        if not abs(self.balance_error_m3) <= tol:
            out.append(f"balance error {self.balance_error_m3:.3g} m^3 > {tol:.3g} m^3")
        if not (math.isnan(self.inflow_error_m3) or abs(self.inflow_error_m3) <= tol):
            out.append(f"V_in differs from the pumped + injected volume by {self.inflow_error_m3:.3g} m^3")
        if self.interlock_misses:
            out.append(f"{self.interlock_misses} scans read a level at or above HH with its pump running")
        return out


def apply_event(cs: CoSimulation, ev: RandomEvent) -> str | None:
    """Apply one request between scans, as its client would write it; return a refusal or None.

    Raises
    ------
    ValueError
        A request outside its node's range (a generator bug: the OPC UA layer would refuse it).
    """
    if isinstance(ev, GainsEvent):
        status = cs.plc.stage_gains(ev.loop, ev.kp, ev.ki, ev.kd)
        if status is not GainStatus.STAGED:
            return f"t = {ev.at_s:g} s {describe(ev)}: {status.value}"
    elif not isinstance(ev, InterlockResetEvent):
        apply_scenario_event(CoSimEvents(cs), ev)  # the scenario kinds: the one table (tankctl.events)
    else:
        cs.plc.reset_interlocks()
    return None


def run_scenario(scenario: RandomScenario) -> RunResult:
    """Run ``scenario`` in the co-simulation (RK4 plant, the PLC program, the supervisor if any).

    Requests due at a scan are applied just before it, in the order drawn; every scan is checked
    (levels, overflow, interlock) and the balances are taken at the end.
    """
    site = scenario.site
    cs = CoSimulation(site, supervisor_mode=scenario.supervisor_mode)
    plant, plc = cs.plant, cs.plc
    net = plant.net
    ts = cs.ts_s
    n_scans = round(scenario.duration_s / ts)
    due: dict[int, list[RandomEvent]] = {}
    for ev in scenario.events:
        due.setdefault(round(ev.at_s / ts), []).append(ev)
    feeds = [np.flatnonzero(net.pump_tank == il.tank) for il in plc.interlocks]
    spill_index = net.n_tanks + net.n_pumps + 3
    lagged = bool(np.any(net.pump_lag_s > 0))
    hmax = net.hmax_m
    lo = plant.levels.copy()
    hi = plant.levels.copy()
    pumped = 0.0
    misses = 0
    trips = 0
    first_spill: float | None = None
    refused: list[str] = []
    for k in range(n_scans):
        for ev in due.get(k, ()):
            why = apply_event(cs, ev)
            if why is not None:
                refused.append(why)
        was_tripped = [il.tripped for il in plc.interlocks]
        readings = plant.readings.copy()
        cs.step()
        commands = cs.trace.commands[-1]
        for il, pumps, before in zip(plc.interlocks, feeds, was_tripped, strict=True):
            trips += int(il.tripped and not before)
            if readings[il.tank] >= il.high_high_m and np.any(commands[pumps] > plc.pump_min[pumps]):
                misses += 1
        # Pump flows are held over the scan (no lag); disturbances as written before it.
        pumped += ts * (
            float(cs.trace.flows_m3_s[-1].sum())
            + float(np.maximum(plant.inputs.disturbances_m3_s, 0.0).sum())
        )
        h = plant.levels
        np.minimum(lo, h, out=lo)
        np.maximum(hi, h, out=hi)
        if first_spill is None and plant.x[spill_index] > 0.0:
            first_spill = plant.t_s
    bal = plant.balance()
    return RunResult(
        scenario=scenario,
        spilled_m3=bal.v_spilled,
        first_spill_s=first_spill,
        max_levels_m=tuple(map(float, hi)),
        min_levels_m=tuple(map(float, lo)),
        height_max_m=tuple(map(float, hmax)),
        volume_in_m3=bal.v_in,
        balance_error_m3=bal.error,
        inflow_error_m3=math.nan if lagged else bal.v_in - pumped,
        interlock_misses=misses,
        trips=trips,
        refused=tuple(refused),
    )
