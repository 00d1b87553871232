"""``tankctl simulate`` and ``tankctl compare``: scenarios in the in-process co-simulation.

A scenario (:mod:`tanklab.scenario`, ``configs/scenarios/*.yaml``, documented in
``docs/scenarios.md``) runs once per controller variant. Each run wires the same pure cores the
processes use (:class:`tankctl.cosim.CoSimulation`: plant, PLC scan, supervisor cycle) on a
virtual clock:

    for each scan k (t_k = k Ts):  apply the events due (at_s <= t_k)  ->  PLC scan  ->  supervisor
                                   cycle  ->  plant advances Ts

An event at ``at_s`` acts before the first scan at or after it (scan ``ceil(at_s / Ts)``); events
after the end are not applied. The scenario's ``initial`` section is written into the variant's
site before the run (levels, valve and leak openings, setpoints, modes, pump commands), so the
PLC starts from it as from a configured state.

Per variant the run gives trajectories (levels, setpoints, pump commands and flows, gains, modes
per scan), loop metrics and step metrics (:mod:`tankctl.metrics`), and for every step the
bang-bang minimum-time settling time of the nonlinear plant (:mod:`tankctl.limits`) and the
ratio of the controller's settling time to it. Levels in the metrics are the true levels [m]
(the shipped plants have noise-free transmitters, so they equal the readings).

JSON (``--json``)::

    {"scenario": NAME, "site": FILE, "duration_s": T,
     "variants": {VARIANT: {"description": ..., "supervisor_mode": ..., "scan_period_s": Ts,
                            "loops": {LOOP: {"iae", "ise", "itae", "overshoot_pct",
                                             "settling_time_s", "max_du", "constraint_violations"}},
                            "steps": [{"loop", "time", "setpoint", "from", "overshoot_pct",
                                       "settling_time_s", "min_time_s", "settling_ratio",
                                       "min_time_method"}],
                            "disturbances": [{"loop", "time", "event", "window_s", "iae",
                                              "peak_error_m"}]}}}

Units: iae m s, ise m^2 s, itae m s^2, time and settling s (from the step), setpoint and from m,
max_du in the pump's command unit per scan. ``disturbances`` lists, for every plant event (leak,
valve, fault, disturbance flow) and controlled loop, the IAE [m s] and peak |e| [m] from the
event to the next event of any kind. A settling time that did not happen within the
step's window is null.

``--csv OUT`` writes one CSV per variant: ``OUT/<variant>.csv`` when OUT is a directory (or ends
with ``/``), else ``<OUT stem>_<variant>.csv`` (a ``.csv`` suffix on OUT is dropped first).
``--plot OUT.png`` draws every variant side by side (:mod:`tankctl.plots`).
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plant_sim.models import PlantInputs
from plc_emulator.mrac import Mrac
from plc_emulator.nlpi import AdaptiveNlPi, NlPi
from tankctl.cosim import CoSimEvents, CoSimulation
from tankctl.events import apply_event as apply_events_table
from tankctl.limits import LevelStep, MinTimeResult, imc_tf_experiment, min_time_step
from tankctl.metrics import (
    LoopMetrics,
    StepMetrics,
    constraint_violations,
    find_steps,
    iae,
    loop_metrics,
    max_du,
    step_metrics,
)

# The commands live in tankctl.simulate_cli (light: no co-simulation import); re-exported.
from tankctl.simulate_cli import compare_command, register, simulate_command
from tanklab.config import ConfigError, SiteConfig, site_from_mapping
from tanklab.enums import LoopMode
from tanklab.scenario import (
    DisturbanceEvent,
    Event,
    FaultEvent,
    InitialState,
    LeakEvent,
    LoopModeEvent,
    Scenario,
    SetpointEvent,
    ValveEvent,
    Variant,
    load_scenario,
    variant_site,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "DisturbanceResult",
    "ScenarioResult",
    "StepResult",
    "VariantResult",
    "apply_initial",
    "compare_command",
    "compare_text",
    "csv_paths",
    "markdown_report",
    "mrac_sweep_markdown",
    "published_rows",
    "regenerate_docs",
    "register",
    "result_json",
    "run_scenario",
    "run_variant",
    "simulate_command",
    "summary_text",
    "tf_markdown",
    "write_csv",
]

_TIME_EPS = 1e-9
"""Tolerance, in scans, on an event's scan index (at_s / Ts accumulated in floating point)."""


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StepResult:
    """One setpoint step of one loop, with its minimum-time bound."""

    loop: str
    time_s: float
    from_m: float
    setpoint_m: float
    overshoot_pct: float
    settling_time_s: float | None
    min_time_s: float | None
    min_time_method: str | None

    @property
    def settling_ratio(self) -> float | None:
        """Controller settling time / minimum-time bound (None if either is missing)."""
        if self.settling_time_s is None or self.min_time_s is None or self.min_time_s <= 0:
            return None
        return self.settling_time_s / self.min_time_s

    def as_dict(self) -> dict[str, Any]:
        """JSON entry (keys of the issue: loop, time, setpoint, overshoot_pct, settling_time_s)."""
        return {
            "loop": self.loop,
            "time": self.time_s,
            "setpoint": self.setpoint_m,
            "from": self.from_m,
            "overshoot_pct": self.overshoot_pct,
            "settling_time_s": self.settling_time_s,
            "min_time_s": self.min_time_s,
            "settling_ratio": self.settling_ratio,
            "min_time_method": self.min_time_method,
        }


@dataclass(frozen=True)
class DisturbanceResult:
    """How one loop rode out a plant event (leak, valve, fault, disturbance flow): over the window
    from the event to the next event of any kind (or the end), IAE [m s] and the peak |e| [m]."""

    loop: str
    time_s: float
    event: str
    window_s: float
    iae: float
    peak_error_m: float

    def as_dict(self) -> dict[str, Any]:
        """JSON entry."""
        return {
            "loop": self.loop,
            "time": self.time_s,
            "event": self.event,
            "window_s": self.window_s,
            "iae": self.iae,
            "peak_error_m": self.peak_error_m,
        }


@dataclass
class VariantResult:
    """One variant's run: trajectories (one row per scan) and metrics.

    Arrays: ``t_s`` (N,) [s]; ``levels_m`` (N, tanks) [m]; ``setpoints_m`` (N, loops) [m];
    ``commands`` (N, pumps) [pump unit]; ``flows_m3_s`` (N, pumps); ``gains`` (N, loops, 3) in
    the block's units (``gain_names`` says which; NaN where a block has fewer); ``modes``
    (N, loops) LoopMode values.
    """

    name: str
    description: str
    supervisor_mode: str
    site: SiteConfig
    ts_s: float
    t_s: FloatArray
    levels_m: FloatArray
    setpoints_m: FloatArray
    commands: FloatArray
    flows_m3_s: FloatArray
    gains: FloatArray
    gain_names: list[tuple[str, str, str]]
    modes: FloatArray
    reference_m: FloatArray
    """(N, loops) reference-model output y_m of MRAC loops [m] (NaN for other blocks)."""
    loops: dict[str, LoopMetrics] = field(default_factory=dict)
    steps: list[StepResult] = field(default_factory=list)
    disturbances: list[DisturbanceResult] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """The variant's JSON entry."""
        return {
            "description": self.description,
            "supervisor_mode": self.supervisor_mode,
            "scan_period_s": self.ts_s,
            "loops": {name: m.as_dict() for name, m in self.loops.items()},
            "steps": [s.as_dict() for s in self.steps],
            "disturbances": [d.as_dict() for d in self.disturbances],
        }


@dataclass
class ScenarioResult:
    """Every variant of one scenario."""

    scenario: Scenario
    site_path: Path
    duration_s: float
    variants: dict[str, VariantResult]
    events: list[tuple[float, str]] = field(default_factory=list)
    """(time [s], short label) of every applied event, for plots."""


def _finite_or_none(x: Any) -> Any:
    """JSON has no NaN: non-finite numbers become null (recursively)."""
    if isinstance(x, dict):
        return {k: _finite_or_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite_or_none(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def result_json(result: ScenarioResult) -> dict[str, Any]:
    """The JSON document of ``tankctl simulate --json``."""
    doc = {
        "scenario": result.scenario.name,
        "site": str(result.site_path),
        "duration_s": result.duration_s,
        "variants": {name: v.as_dict() for name, v in result.variants.items()},
    }
    cleaned: dict[str, Any] = _finite_or_none(doc)
    return cleaned


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------


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


def _describe(ev: Event) -> str:
    if isinstance(ev, SetpointEvent):
        return f"{ev.loop} SP {ev.value_m:g} m"
    if isinstance(ev, LeakEvent):
        return f"leak {ev.tank} {ev.opening:g}"
    if isinstance(ev, ValveEvent):
        return f"{ev.valve} {ev.opening:g}"
    if isinstance(ev, FaultEvent):
        return f"{ev.transmitter} {ev.fault}"
    if isinstance(ev, DisturbanceEvent):
        return f"d {ev.tank} {ev.flow_m3_s:+.3g}" if ev.flow_m3_s else f"d {ev.tank} 0"
    if isinstance(ev, LoopModeEvent):
        return f"{ev.loop} {ev.mode}"
    return f"supervisor {ev.mode}"


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
    scenario: Scenario, site_path: Path, variant: Variant, *, duration_s: float | None = None
) -> VariantResult:
    """Run one variant of a scenario; metrics and minimum-time bounds included.

    Raises
    ------
    ConfigError
        The variant's site is invalid, or an event cannot be applied (one line, naming it).
    """
    site = variant_site(scenario, site_path, variant)
    site = apply_initial(site, scenario.initial, f"{scenario.name}: initial (variant {variant.name})")
    if variant.supervisor_mode != "OFF" and site.supervisor is None:
        raise ConfigError(
            f"{scenario.name}: variants[{variant.name}].supervisor_mode: the site has no supervisor section"
        )
    cs = CoSimulation(site, supervisor_mode=variant.supervisor_mode if site.supervisor else None)
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
    for s in sorted(res.steps, key=lambda s: (s.time_s, s.loop)):
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
) -> ScenarioResult:
    """Load a scenario file and run its variants (all, or the ones named), in file order.

    Parameters
    ----------
    path : the scenario YAML file.
    config : a site file to use instead of the scenario's own.
    variants : names of the variants to run; None: every variant.
    duration_s : run length [s] instead of the scenario's (the golden tests trim runs).

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
    runs = {v.name: run_variant(scenario, site_path, v, duration_s=duration) for v in chosen}
    events = [(ev.at_s, _describe(ev)) for ev in scenario.sorted_events() if ev.at_s < duration]
    return ScenarioResult(scenario, site_path, duration, runs, events)


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------


def csv_paths(out: str | Path, names: Sequence[str]) -> dict[str, Path]:
    """Where ``--csv OUT`` writes each variant (see the module docstring).

    OUT is a directory when it exists as one or is written with a trailing ``/`` (pass a str:
    ``Path`` drops the slash); otherwise a file stem.
    """
    path = Path(out)
    if path.is_dir() or str(out).endswith(("/", "\\")):
        return {name: path / f"{name}.csv" for name in names}
    stem = path.with_suffix("") if path.suffix.lower() == ".csv" else path
    return {name: stem.parent / f"{stem.name}_{name}.csv" for name in names}


def write_csv(result: ScenarioResult, out: str | Path) -> list[Path]:
    """Write one CSV per variant; return the files written.

    Columns: ``t_s``, ``level_<tank>_m``, ``sp_<loop>_m``, ``mode_<loop>``,
    ``command_<pump>`` (pump unit), ``flow_<pump>_m3_s``, ``<loop>_<gain>`` (block units), and
    ``ym_<loop>_m`` (reference-model output) for MRAC loops.
    """
    paths = csv_paths(out, list(result.variants))
    written = []
    for name, v in result.variants.items():
        site = v.site
        header = ["t_s"]
        header += [f"level_{t}_m" for t in site.tank_names]
        header += [f"sp_{lp}_m" for lp in site.loop_names]
        header += [f"mode_{lp}" for lp in site.loop_names]
        header += [f"command_{p}" for p in site.pump_names]
        header += [f"flow_{p}_m3_s" for p in site.pump_names]
        gain_cols = [
            (j, g, f"{lp}_{label}")
            for j, lp in enumerate(site.loop_names)
            for g, label in enumerate(v.gain_names[j])
            if label
        ]
        header += [c for _, _, c in gain_cols]
        ym_cols = [j for j in range(len(site.loop_names)) if np.isfinite(v.reference_m[:, j]).any()]
        header += [f"ym_{site.loop_names[j]}_m" for j in ym_cols]
        path = paths[name]
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for k in range(v.t_s.size):
                row: list[Any] = [f"{v.t_s[k]:.6g}"]
                row += [repr(float(x)) for x in v.levels_m[k]]
                row += [repr(float(x)) for x in v.setpoints_m[k]]
                row += [LoopMode(int(m)).name for m in v.modes[k]]
                row += [repr(float(x)) for x in v.commands[k]]
                row += [repr(float(x)) for x in v.flows_m3_s[k]]
                row += [repr(float(v.gains[k, j, g])) for j, g, _ in gain_cols]
                row += [repr(float(v.reference_m[k, j])) for j in ym_cols]
                w.writerow(row)
        written.append(path)
    return written


def _fmt(x: float | int | None, spec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "-"
    return format(x, spec)


def summary_text(result: ScenarioResult) -> str:
    """The readable table ``tankctl simulate`` prints without ``--json``."""
    sc = result.scenario
    lines = [f"scenario {sc.name}: {result.duration_s:g} s, site {result.site_path.name}"]
    lines.append(
        f"settling band {sc.settling_band * 100:g} % of each step; IAE in m s, ISE m^2 s, ITAE m s^2"
    )
    for name, v in result.variants.items():
        lines.append("")
        desc = f" - {v.description}" if v.description else ""
        lines.append(f"[{name}] supervisor {v.supervisor_mode}, scan {v.ts_s:g} s{desc}")
        lines.append(
            f"  {'loop':<6}{'IAE':>11}{'ISE':>11}{'ITAE':>11}{'OS %':>8}{'ts s':>9}{'max du':>11}{'viol':>6}"
        )
        for loop, m in v.loops.items():
            lines.append(
                f"  {loop:<6}{_fmt(m.iae):>11}{_fmt(m.ise):>11}{_fmt(m.itae):>11}"
                f"{_fmt(m.overshoot_pct, '.2f'):>8}{_fmt(m.settling_time_s, '.1f'):>9}"
                f"{_fmt(m.max_du, '.3g'):>11}{m.constraint_violations:>6}"
            )
        if v.steps:
            lines.append(
                f"  {'step':<6}{'t s':>8}{'from m':>9}{'to m':>9}{'OS %':>8}{'ts s':>9}"
                f"{'t_min s':>10}{'ratio':>8}"
            )
            for s in v.steps:
                lines.append(
                    f"  {s.loop:<6}{s.time_s:>8.6g}{s.from_m:>9.4f}{s.setpoint_m:>9.4f}"
                    f"{s.overshoot_pct:>8.2f}{_fmt(s.settling_time_s, '.1f'):>9}"
                    f"{_fmt(s.min_time_s, '.3g'):>10}{_fmt(s.settling_ratio, '.3g'):>8}"
                )
    return "\n".join(lines)


def _our_value(result: ScenarioResult, variant: str, loop: str, metric: str) -> float | None:
    v = result.variants.get(variant)
    if v is None or loop not in v.loops:
        return None
    value = v.loops[loop].as_dict().get(metric)
    return None if value is None else float(value)


def published_rows(result: ScenarioResult) -> list[dict[str, Any]]:
    """One row per published number: variant, loop, metric, ours, paper, note."""
    rows = []
    for pm in result.scenario.published:
        rows.append(
            {
                "variant": pm.variant,
                "loop": pm.loop,
                "metric": pm.metric,
                "ours": _our_value(result, pm.variant, pm.loop, pm.metric),
                "paper": pm.value,
                "note": pm.note,
            }
        )
    return rows


def _orderings(rows: list[dict[str, Any]]) -> list[str]:
    """For each (loop, metric) with two or more published variants: the paper's order and ours."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["loop"], r["metric"]), []).append(r)
    out = []
    for (loop, metric), rs in groups.items():
        if len(rs) < 2 or any(r["ours"] is None for r in rs):
            continue
        paper = " < ".join(r["variant"] for r in sorted(rs, key=lambda r: r["paper"]))
        ours = " < ".join(r["variant"] for r in sorted(rs, key=lambda r: r["ours"]))
        verdict = "same order" if paper == ours else "DIFFERENT order"
        out.append(f"  {loop} {metric}: paper {paper}; ours {ours} ({verdict})")
    return out


TF_REFERENCES = {"imc_pi_coupled"}
"""Scenarios whose paper ran on a transfer function: `compare` also prints that experiment."""


def compare_text(result: ScenarioResult) -> str:
    """The table ``tankctl compare`` prints: our metrics beside the paper's published ones."""
    sc = result.scenario
    lines = [f"scenario {sc.name}: our metrics beside the paper's (units: ours; see notes)"]
    rows = published_rows(result)
    if rows:
        lines.append(
            f"  {'variant':<12}{'loop':<6}{'metric':<17}{'ours':>11}{'paper':>11}{'ours/paper':>11}  note"
        )
        for r in rows:
            ratio = r["ours"] / r["paper"] if r["ours"] is not None and r["paper"] else None
            lines.append(
                f"  {r['variant']:<12}{r['loop']:<6}{r['metric']:<17}{_fmt(r['ours']):>11}"
                f"{_fmt(r['paper']):>11}{_fmt(ratio, '.3g'):>11}  {r['note']}"
            )
        order = _orderings(rows)
        if order:
            lines.append("orderings (smaller first):")
            lines.extend(order)
    else:
        lines.append("  (the paper printed no metric for this scenario)")
    lines.append("settling time / minimum-time (bang-bang) bound, per step:")
    lines.append(f"  {'variant':<12}{'loop':<6}{'t s':>8}{'to m':>9}{'ts s':>9}{'t_min s':>10}{'ratio':>9}")
    for name, v in result.variants.items():
        for s in v.steps:
            lines.append(
                f"  {name:<12}{s.loop:<6}{s.time_s:>8.6g}{s.setpoint_m:>9.4f}"
                f"{_fmt(s.settling_time_s, '.1f'):>9}{_fmt(s.min_time_s, '.3g'):>10}"
                f"{_fmt(s.settling_ratio, '.3g'):>9}"
            )
    if sc.name in TF_REFERENCES:
        lines.append("")
        lines.append(
            "the paper's own experiment, on its transfer function 28.82 / (29.6 s^2 + 14.7 s + 1) "
            "(scipy.signal; unit SP step at 0 s, 10 % input disturbance at 50 s; 2 % band):"
        )
        lines.append(f"  {'controller':<42}{'Kc':>8}{'Ti s':>8}{'Td s':>8}{'OS %':>8}{'ts s':>8}{'IAE':>8}")
        for tf in imc_tf_experiment():
            lines.append(
                f"  {tf.name:<42}{tf.Kc:>8.4f}{tf.Ti:>8.3f}{tf.Td:>8.3f}{tf.overshoot_pct:>8.2f}"
                f"{_fmt(tf.settling_time_s, '.2f'):>8}{tf.iae:>8.3f}"
            )
        lines.append(
            "  digest 2.7: IMC PID first order (tau 1 s), PI without Td 35.7 % and 19 s; "
            "paper's Kc 0.5091, Ti 14.714 s"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Markdown (docs/reproduction.md is regenerated from runs, never hand-copied)
# --------------------------------------------------------------------------------------------


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def markdown_report(result: ScenarioResult, figure: str | None = None) -> str:
    """Markdown of a run: ours beside the paper, every loop metric, the steps with their bounds."""
    parts = []
    rows = published_rows(result)
    if rows:
        parts.append("Ours beside the paper's printed numbers (ours in the units of the note):\n")
        table = []
        for r in rows:
            ratio = r["ours"] / r["paper"] if r["ours"] is not None and r["paper"] else None
            table.append(
                [
                    r["variant"],
                    r["loop"],
                    r["metric"],
                    _fmt(r["ours"]),
                    _fmt(r["paper"]),
                    _fmt(ratio, ".3g"),
                    r["note"],
                ]
            )
        parts.append(_md_table(["variant", "loop", "metric", "ours", "paper", "ours / paper", "note"], table))
        order = _orderings(rows)
        if order:
            parts.append("\nOrderings (smaller first):\n")
            parts.append("\n".join(f"- {line.strip()}" for line in order))
    parts.append("\nEvery loop (IAE m s, ISE m^2 s, ITAE m s^2, max du in the pump's unit per scan):\n")
    table = []
    for name, v in result.variants.items():
        for loop, m in v.loops.items():
            table.append(
                [
                    name,
                    loop,
                    _fmt(m.iae),
                    _fmt(m.ise),
                    _fmt(m.itae),
                    _fmt(m.overshoot_pct, ".2f"),
                    _fmt(m.settling_time_s, ".1f"),
                    _fmt(m.max_du, ".3g"),
                    str(m.constraint_violations),
                ]
            )
    parts.append(
        _md_table(
            ["variant", "loop", "IAE", "ISE", "ITAE", "overshoot %", "settling s", "max du", "violations"],
            table,
        )
    )
    parts.append("\nSteps, and the settling time as a multiple of the bang-bang minimum time:\n")
    table = []
    for name, v in result.variants.items():
        for st in v.steps:
            table.append(
                [
                    name,
                    st.loop,
                    f"{st.time_s:g}",
                    f"{st.from_m:.4f} -> {st.setpoint_m:.4f}",
                    f"{st.overshoot_pct:.2f}",
                    _fmt(st.settling_time_s, ".1f"),
                    _fmt(st.min_time_s, ".3g") + (f" ({st.min_time_method})" if st.min_time_method else ""),
                    _fmt(st.settling_ratio, ".3g"),
                ]
            )
    parts.append(
        _md_table(
            [
                "variant",
                "loop",
                "t s",
                "from -> to m",
                "overshoot %",
                "settling s",
                "minimum time s",
                "ratio",
            ],
            table,
        )
    )
    dist = [(name, d) for name, v in result.variants.items() for d in v.disturbances]
    if dist:
        parts.append("\nPlant events: IAE and peak error from the event to the next event (or the end):\n")
        table = [
            [
                name,
                d.loop,
                f"{d.time_s:g}",
                d.event,
                f"{d.window_s:g}",
                _fmt(d.iae),
                _fmt(d.peak_error_m, ".3g"),
            ]
            for name, d in dist
        ]
        parts.append(
            _md_table(["variant", "loop", "t s", "event", "window s", "IAE m s", "peak abs(e) m"], table)
        )
    if figure:
        parts.append(f"\n![{result.scenario.name}]({figure})")
    return "\n".join(parts) + "\n"


def tf_markdown() -> str:
    """The IMC paper's transfer-function experiment as a markdown table."""
    rows = [
        [
            tf.name,
            f"{tf.Kc:.4f}",
            f"{tf.Ti:.3f}",
            f"{tf.Td:.3f}",
            f"{tf.overshoot_pct:.2f}",
            _fmt(tf.settling_time_s, ".2f"),
            f"{tf.disturbance_peak:.4f}",
            f"{tf.iae:.3f}",
        ]
        for tf in imc_tf_experiment()
    ]
    header = [
        "controller",
        "Kc",
        "Ti s",
        "Td s",
        "overshoot %",
        "settling s (2 %)",
        "disturbance peak",
        "IAE",
    ]
    return _md_table(header, rows) + "\n"


MRAC_GAMMAS = (1e-4, 3e-4, 1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0)
"""The gamma grid of the MRAC sweep in docs/reproduction.md."""


def mrac_sweep_markdown(path: str | Path, gammas: Sequence[float] = MRAC_GAMMAS) -> str:
    """The gamma sweep behind mrac_two_tank.yaml's choice: model-following error per law and gamma.

    Every other setting is the scenario's (alpha, bounds, delta, wn); only gamma changes, in both
    loops. "steps settled" = both setpoint steps settled within their windows (a diverging
    adaptation does not).
    """
    scenario, site_path = load_scenario(path)
    rows = []
    for law in ("mit", "api"):
        base = next(v for v in scenario.variants if v.name == law)
        for g in gammas:
            overrides = dict(base.set)
            for key, value in base.set.items():
                if key.endswith(".mrac"):
                    overrides[key] = dict(value, gamma=g)
            run = run_variant(scenario, site_path, base.model_copy(update={"set": overrides}))
            err = np.nanmean(np.abs(run.levels_m - run.reference_m), axis=0)
            settled = all(st.settling_time_s is not None for st in run.steps)
            iaes = [m.iae for m in run.loops.values()]
            chosen = any(
                key.endswith(".mrac") and float(value["gamma"]) == g for key, value in base.set.items()
            )
            rows.append(
                [
                    law + (" (chosen)" if chosen else ""),
                    f"{g:g}",
                    " / ".join(f"{100 * x:.3f}" for x in err),
                    f"{100 * float(np.sum(err)):.3f}",
                    "yes" if settled else "NO",
                    " / ".join(f"{x:.3g}" for x in iaes),
                ]
            )
    header = [
        "law",
        "gamma",
        "mean abs(y - y_m) cm (T1 / T2)",
        "sum cm",
        "steps settled",
        "IAE m s (T1 / T2)",
    ]
    return _md_table(header, rows) + "\n"


_BLOCK = re.compile(
    r"(<!-- generated:(?P<kind>[a-z-]+) (?P<arg>[^ ]+) -->\n)(?P<body>.*?)(<!-- /generated -->)", re.S
)


def regenerate_docs(doc: str | Path, *, root: str | Path = ".") -> list[str]:
    """Rewrite every generated block of ``doc`` from fresh runs; return what was regenerated.

    Blocks: ``<!-- generated:scenario FILE -->`` (markdown_report of the scenario, and its figure
    written to ``docs/figures/<name>.png``), ``<!-- generated:tf imc -->`` (the transfer-function
    experiment), ``<!-- generated:mrac-sweep FILE -->`` (the gamma sweep),
    ``<!-- generated:kortela-notes FILE -->`` and ``<!-- generated:energies-notes FILE -->`` (the
    OPC UA MPC and MPC-based PID papers' findings as sentences) and
    ``<!-- generated:ratios all -->`` (the settling ratios of every scenario run above it), each
    closed by ``<!-- /generated -->``. Paths are relative to ``root``; a scenario runs once.
    """
    from tankctl.doc_notes import energies_notes, kortela_notes, ratio_notes

    base = Path(root)
    doc_path = base / doc
    text = doc_path.read_text(encoding="utf-8")
    done: list[str] = []
    runs: dict[str, ScenarioResult] = {}

    def run(arg: str) -> ScenarioResult:
        if arg not in runs:
            runs[arg] = run_scenario(base / arg)
        return runs[arg]

    def render(m: re.Match[str]) -> str:
        kind, arg = m["kind"], m["arg"]
        if kind == "scenario":
            result = run(arg)
            fig = doc_path.parent / "figures" / f"{result.scenario.name}.png"
            from tankctl.plots import plot_scenario

            plot_scenario(result, fig)
            body = markdown_report(result, f"figures/{fig.name}")
        elif kind == "tf":
            body = tf_markdown()
        elif kind == "mrac-sweep":
            body = mrac_sweep_markdown(base / arg)
        elif kind == "kortela-notes":
            body = kortela_notes(run(arg))
        elif kind == "energies-notes":
            body = energies_notes(run(arg))
        elif kind == "ratios":
            body = ratio_notes({r.scenario.name: r for r in runs.values()})
        else:
            raise ValueError(f"{doc}: unknown generated block {kind!r}")
        done.append(f"{kind} {arg}")
        return m.group(1) + body + m.group(5)

    doc_path.write_text(_BLOCK.sub(render, text), encoding="utf-8")
    return done


if __name__ == "__main__":  # python -m tankctl.simulate [docs/reproduction.md]: refresh the doc
    import sys

    for item in regenerate_docs(sys.argv[1] if len(sys.argv) > 1 else "docs/reproduction.md"):
        print(f"regenerated {item}")
