"""Running a scenario in the co-simulation: the initial state into the site, the events between
scans (:func:`tankctl.events.apply_event`), one run per variant, then the metrics and bounds."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from plant_sim.models import PlantInputs
from plc_emulator.mrac import Mrac
from plc_emulator.nlpi import AdaptiveNlPi, NlPi
from tankctl.cosim import CoSimEvents, CoSimulation
from tankctl.events import apply_event as apply_events_table
from tankctl.limits import LevelStep, MinTimeResult, min_time_step
from tankctl.metrics import (
    StepMetrics,
    constraint_violations,
    find_steps,
    iae,
    loop_metrics,
    max_du,
    step_metrics,
)
from tankctl.simulate.results import DisturbanceResult, ScenarioResult, StepResult, VariantResult
from tanklab.config import ConfigError, SiteConfig, numeric_key, site_from_mapping
from tanklab.enums import LoopMode, SensorFault, SupervisorMode
from tanklab.errors import ControllerError
from tanklab.scenario import (
    DisturbanceEvent,
    Event,
    FaultEvent,
    InitialState,
    LeakEvent,
    Scenario,
    ValveEvent,
    Variant,
    load_scenario,
    variant_site,
)

FloatArray = NDArray[np.float64]


_TIME_EPS = 1e-9
"""Tolerance, in scans, on an event's scan index (at_s / Ts accumulated in floating point)."""


def apply_initial(site: SiteConfig, initial: InitialState, where: str = "initial") -> SiteConfig:
    """A copy of ``site`` whose initial state is the scenario's (validated again as a whole)."""
    data = site.model_dump(mode="python")
    plant = data["plant"]
    if initial.levels_m is not None:
        for tank, level in zip(plant["tanks"], initial.levels_m, strict=True):
            tank["initial_level_m"] = level
    for name, opening in initial.valves.items():
        next(v for v in plant["valves"] if v["name"] == name)["initial_opening"] = opening
    for name, opening in initial.leaks.items():
        next(t for t in plant["tanks"] if t["name"] == name)["initial_leak_opening"] = opening
    if initial.pump_commands is not None:
        for pump, cmd in zip(plant["pumps"], initial.pump_commands, strict=True):
            pump["initial_command"] = cmd
    loops = data["plc"]["loops"] if data.get("plc") else []
    for name, sp in initial.setpoints_m.items():
        next(lp for lp in loops if lp["name"] == name)["setpoint_m"] = sp
    for name, mode in initial.modes.items():
        next(lp for lp in loops if lp["name"] == name)["mode"] = mode
    return site_from_mapping(data, where)


class _Label:
    """An event as the short label of the reports and plots: the verbs of the one table of
    event kinds (:class:`tankctl.events.EventTarget`) returning text."""

    def setpoint(self, loop: str, value_m: float) -> str:
        return f"{loop} SP {value_m:g} m"

    def leak(self, tank: str, opening: float) -> str:
        return f"leak {tank} {opening:g}"

    def valve(self, valve: str, opening: float) -> str:
        return f"{valve} {opening:g}"

    def disturbance(self, tank: str, flow_m3_s: float) -> str:
        return f"d {tank} {flow_m3_s:+.3g}" if flow_m3_s else f"d {tank} 0"

    def fault(self, transmitter: str, fault: SensorFault, value: float) -> str:
        return f"{transmitter} {fault.name}"

    def loop_mode(self, loop: str, mode: LoopMode, mv_percent: float | None) -> str:
        return f"{loop} {mode.name}"

    def supervisor_mode(self, mode: SupervisorMode) -> str:
        return f"supervisor {mode.name}"


def _describe(ev: Event) -> str:
    return apply_events_table(_Label(), ev)


def apply_event(cs: CoSimulation, ev: Event) -> None:
    """Apply one scenario event to the co-simulation, as the operator's client would write it
    (the one table of event kinds: :func:`tankctl.events.apply_event`)."""
    apply_events_table(CoSimEvents(cs), ev)


def _gain_names(site: SiteConfig) -> list[tuple[str, str, str]]:
    assert site.plc is not None
    names = []
    for lp in site.plc.loops:
        if lp.block == "nlpi":
            names.append(("Kp", "Ki", "Kl"))
        elif lp.block == "mrac":
            assert lp.mrac is not None
            names.append(("theta1", "theta2", "") if lp.mrac.law == "mit" else ("kp", "ki", ""))
        else:
            names.append(("Kp", "Ki", "Kd"))
    return names


def _block_gains(cs: CoSimulation, pid_gains: FloatArray) -> FloatArray:
    """Gains each loop's block used this scan (PID: the applied Kp, Ki, Kd)."""
    out = pid_gains.copy()
    for j, lp in enumerate(cs.plc.loops):
        block = lp.block
        if isinstance(block, AdaptiveNlPi):
            g = block.controller.gains
            out[j] = (g.Kp, g.Ki, g.Kl)
        elif isinstance(block, NlPi):
            g = block.gains
            out[j] = (g.Kp, g.Ki, g.Kl)
        elif isinstance(block, Mrac):
            th = block.theta
            out[j] = (th[0], th[1], math.nan)
    return out


def _event_scan(at_s: float, ts_s: float) -> int:
    return max(0, math.ceil(at_s / ts_s - _TIME_EPS))


def run_variant(
    scenario: Scenario,
    site_path: Path,
    variant: Variant,
    *,
    duration_s: float | None = None,
    site: SiteConfig | None = None,
    controller: str | None = None,
) -> VariantResult:
    """Run one variant of a scenario; metrics and minimum-time bounds included.

    ``site`` is the variant's site when the caller built it already (a sweep's case changes the
    variant's site further, :mod:`tankctl.sweep.cases`); ``controller`` the supervisory
    controller's dotted path (``--controller``; default: the site's); default site: the site file with the
    variant's ``set`` applied (:func:`tanklab.scenario.variant_site`). The scenario's
    ``initial`` section is written into it either way.

    Raises
    ------
    ConfigError
        The variant's site is invalid, or an event cannot be applied (one line, naming it).
    """
    if site is None:
        site = variant_site(scenario, site_path, variant)
    site = apply_initial(site, scenario.initial, f"{scenario.name}: initial (variant {variant.name})")
    if variant.supervisor_mode != "OFF" and site.supervisor is None:
        raise ConfigError(
            f"{scenario.name}: variants[{variant.name}].supervisor_mode: the site has no supervisor section"
        )
    try:
        cs = CoSimulation(
            site, supervisor_mode=variant.supervisor_mode if site.supervisor else None, controller=controller
        )
    except ControllerError as e:
        # from the site file's supervisor.controller: name the file; from --controller: as is
        raise (ConfigError(f"{site_path}: {e}") if controller is None else e) from None
    ts = cs.ts_s
    duration = scenario.duration_s if duration_s is None else duration_s
    n = round(duration / ts)
    due: dict[int, list[tuple[int, Event]]] = {}
    for i, ev in enumerate(scenario.events):
        due.setdefault(_event_scan(ev.at_s, ts), []).append((i, ev))
    for group in due.values():
        group.sort(key=lambda pair: (pair[1].at_s, pair[0]))  # by time, then file order
    snapshots: dict[int, PlantInputs] = {0: cs.plant.inputs}
    gains = np.zeros((n, len(cs.plc.loops), 3))
    reference = np.full((n, len(cs.plc.loops)), math.nan)
    mrac = [(j, lp.block) for j, lp in enumerate(cs.plc.loops) if isinstance(lp.block, Mrac)]
    for k in range(n):
        for i, ev in due.get(k, []):
            try:
                apply_event(cs, ev)
            except (ValueError, KeyError) as e:
                msg = str(e).strip("'\"")
                raise ConfigError(f"{scenario.name}: events[{i}] ({ev.kind} at {ev.at_s:g} s): {msg}") from e
        if k in due:
            snapshots[k] = cs.plant.inputs
        for j, block in mrac:
            reference[k, j] = block.y_m
        cs.step()
        gains[k] = _block_gains(cs, cs.trace.gains[-1])
    tr = cs.trace
    result = VariantResult(
        name=variant.name,
        description=variant.description,
        supervisor_mode=variant.supervisor_mode,
        site=site,
        ts_s=ts,
        t_s=np.arange(n, dtype=np.float64)
        * ts,  # k Ts exactly (the plant's clock sums Ts: 2.000000000000001)
        levels_m=tr.array("levels_m"),
        setpoints_m=tr.array("setpoints_m"),
        commands=tr.array("commands"),
        flows_m3_s=tr.array("flows_m3_s"),
        gains=gains,
        gain_names=_gain_names(site),
        modes=tr.array("modes"),
        reference_m=reference,
        trips=tr.array("trips").reshape(n, len(cs.plc.interlocks)),
        interlock_tanks=[il.tank_name for il in cs.plc.interlocks],
    )
    event_scans = sorted(k for k in due if k < n)
    _evaluate(result, scenario.settling_band, event_scans, snapshots)
    plant_events = [
        (k, _describe(ev))
        for k in event_scans
        for _, ev in due[k]
        if isinstance(ev, LeakEvent | ValveEvent | FaultEvent | DisturbanceEvent)
    ]
    _disturbances(result, plant_events, event_scans)
    return result


def _evaluate(
    res: VariantResult, band: float, event_scans: list[int], snapshots: dict[int, PlantInputs]
) -> None:
    """Fill the loop and step metrics and the minimum-time bounds of a run."""
    site = res.site
    assert site.plc is not None
    tanks = site.tank_names
    pumps = site.pump_names
    n = res.t_s.size
    plant = site.plant
    init_flows = np.array([p.flow_of(p.initial_command) for p in plant.pumps])
    du_bound = site.supervisor.mpc.du_max_m3_s if site.supervisor is not None else None
    steps_by_scan: dict[int, list[tuple[int, float, float]]] = {}
    for j, lp in enumerate(site.plc.loops):
        if n and np.all(res.modes[:, j] == int(LoopMode.MANUAL)):
            continue  # a loop in MANUAL for the whole run controls nothing: no metrics
        i = tanks.index("T" + lp.pv[2:])
        p = pumps.index(lp.actuator)
        pump = plant.pumps[p]
        y, r = res.levels_m[:, i], res.setpoints_m[:, j]
        found = find_steps(r, res.t_s, float(y[0]) if n else 0.0)
        step_ms: list[StepMetrics] = []
        for st in found:
            end = next((k for k in event_scans if k > st.index), n)
            window = slice(st.index, end)
            sm = step_metrics(res.t_s[window], y[window], st.t_s, st.from_m, st.to_m, band)
            step_ms.append(sm)
            steps_by_scan.setdefault(st.index, []).append((j, st.from_m, st.to_m))
            res.steps.append(
                StepResult(
                    lp.name, st.t_s, st.from_m, st.to_m, sm.overshoot_pct, sm.settling_time_s, None, None
                )
            )
        remote = res.modes[:, j] == int(LoopMode.REMOTE)
        violations = constraint_violations(
            y,
            plant.tanks[i].height_max_m,
            res.commands[:, p],
            pump.command_min,
            pump.command_max,
            flows_m3_s=res.flows_m3_s[:, p],
            flow_before_m3_s=float(init_flows[p]),
            du_max_m3_s=du_bound,
            rate_checked=remote,
        )
        res.loops[lp.name] = loop_metrics(
            res.t_s,
            res.ts_s,
            y,
            r,
            step_ms,
            max_du_value=max_du(res.commands[:, p], pump.initial_command),
            violations=violations,
        )
    bounds = {}
    for k, group in steps_by_scan.items():
        end = next((e for e in event_scans if e > k), n)
        horizon = (end - k) * res.ts_s
        bounds.update(_bounds_at(res, k, group, horizon, band, snapshots, init_flows))
    with_bounds = []
    for s in sorted(res.steps, key=lambda s: (s.time_s, numeric_key(s.loop))):
        b = bounds.get((s.loop, s.time_s))
        with_bounds.append(
            StepResult(
                s.loop,
                s.time_s,
                s.from_m,
                s.setpoint_m,
                s.overshoot_pct,
                s.settling_time_s,
                b.settling_time_s if b is not None else None,
                b.method if b is not None else None,
            )
        )
    res.steps = with_bounds


def _disturbances(res: VariantResult, plant_events: list[tuple[int, str]], event_scans: list[int]) -> None:
    """IAE and peak error of every controlled loop over each plant event's window."""
    site = res.site
    assert site.plc is not None
    n = res.t_s.size
    for k, label in plant_events:
        end = next((e for e in event_scans if e > k), n)
        for j, lp in enumerate(site.plc.loops):
            if lp.name not in res.loops:
                continue
            i = site.tank_names.index("T" + lp.pv[2:])
            e = res.setpoints_m[k:end, j] - res.levels_m[k:end, i]
            res.disturbances.append(
                DisturbanceResult(
                    lp.name,
                    float(res.t_s[k]),
                    label,
                    (end - k) * res.ts_s,
                    iae(e, res.ts_s),
                    float(np.max(np.abs(e))) if e.size else 0.0,
                )
            )


def _bounds_at(
    res: VariantResult,
    k: int,
    group: list[tuple[int, float, float]],
    horizon_s: float,
    band: float,
    snapshots: dict[int, PlantInputs],
    init_flows: FloatArray,
) -> dict[tuple[str, float], MinTimeResult]:
    """Minimum-time bounds of the steps taken at scan k (see :mod:`tankctl.limits`)."""
    site = res.site
    assert site.plc is not None
    loops = site.plc.loops
    stepped = {j for j, _, _ in group}
    steps = [
        LevelStep(loops[j].actuator, "T" + loops[j].pv[2:], to_m, band * abs(to_m - from_m))
        for j, from_m, to_m in group
    ]
    held: dict[str, tuple[str, float]] = {}
    for j, lp in enumerate(loops):
        tank = "T" + lp.pv[2:]
        controlled = int(res.modes[k, j]) != int(LoopMode.MANUAL)
        if j not in stepped and controlled and site.plant.pump(lp.actuator).feeds == tank:
            held[lp.actuator] = (tank, float(res.setpoints_m[k, j]))
    flows_before = res.flows_m3_s[k - 1] if k > 0 else init_flows
    flows = {name: float(q) for name, q in zip(site.pump_names, flows_before, strict=True)}
    inputs = snapshots[max(s for s in snapshots if s <= k)]
    try:
        results = min_time_step(
            site.plant,
            res.levels_m[k],
            steps,
            horizon_s=horizon_s,
            held=held,
            flows_m3_s=flows,
            inputs=inputs,
        )
    except ValueError:
        return {}
    t = float(res.t_s[k])
    return {(loops[j].name, t): r for (j, _, _), r in zip(group, results, strict=True)}


def run_scenario(
    path: str | Path,
    *,
    config: str | Path | None = None,
    variants: Sequence[str] | None = None,
    duration_s: float | None = None,
    controller: str | None = None,
) -> ScenarioResult:
    """Load a scenario file and run its variants (all, or the ones named), in file order.

    Parameters
    ----------
    path : the scenario YAML file.
    config : a site file to use instead of the scenario's own.
    variants : names of the variants to run; None: every variant.
    duration_s : run length [s] instead of the scenario's (the golden tests trim runs).
    controller : the supervisory controller ``package.module:Class`` for every variant with a
        supervisor (default: the site's ``supervisor.controller``, else the shipped one).

    Raises
    ------
    ConfigError
        Bad scenario or site file, unknown variant name, or an event that cannot be applied.
    """
    scenario, site_path = load_scenario(path)
    if config is not None:
        site_path = Path(config).resolve()
        if not site_path.exists():
            raise ConfigError(f"--config: no such file {config}")
    chosen = list(scenario.variants)
    if variants:
        known = {v.name for v in chosen}
        for name in variants:
            if name not in known:
                raise ConfigError(f"{scenario.name}: no variant {name!r}; known: {', '.join(sorted(known))}")
        chosen = [v for v in chosen if v.name in set(variants)]
    duration = scenario.duration_s if duration_s is None else float(duration_s)
    runs = {}
    for v in chosen:
        runs[v.name] = run_variant(scenario, site_path, v, duration_s=duration, controller=controller)
    events = [(ev.at_s, _describe(ev)) for ev in scenario.sorted_events() if ev.at_s < duration]
    return ScenarioResult(scenario, site_path, duration, runs, events)


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------
