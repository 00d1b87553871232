"""Scenarios: a site, an initial state, timed events, and controller variants to compare.

A scenario file (YAML, ``configs/scenarios/``) is used two ways: ``tankctl simulate`` runs it
in the co-simulation once per variant, and ``tankctl scenario run`` applies its timed events to
a running stack. Validated like site configs (``extra="forbid"``, one-line errors naming the
file, the field and the rule).

Example::

    name: energies_mpc_pid_vs_pid
    site: ../three_tank_energies_sim.yaml      # relative to this file
    duration_s: 1000
    initial: {levels_m: [0, 0, 0]}
    events:
      - {at_s: 600, kind: leak, tank: T1, opening: 1.0}
      - {at_s: 700, kind: leak, tank: T1, opening: 0.0}
    variants:
      - {name: pid, supervisor_mode: OFF}
      - {name: mpc_pid, supervisor_mode: ADAPTIVE_PID}
      - {name: mpc, supervisor_mode: MPC}

A variant may change the site for its run with ``set``: dotted paths into the site file
(list items by index) mapped to new values, e.g. ``{"plc.loops.0.gains.kp": 2.1e-3}``.

An optional ``expect:`` list states bounds on a loop's metrics, which ``tankctl scenario check``
runs and checks (a CI gate for a controller)::

    expect:
      - {variant: mpc, loop: LIC1, metric: iae, max: 2.5}
      - {loop: LIC1, metric: overshoot_pct, max: 5}      # every variant
      - {loop: LIC2, metric: interlock_trips, max: 0}

The metrics are those of ``tankctl simulate`` (:class:`tankctl.metrics.LoopMetrics`: ``iae``,
``ise``, ``itae`` over the whole run, the worst ``overshoot_pct`` and ``settling_time_s`` over the
loop's steps, ``max_du``, ``constraint_violations``) and ``interlock_trips``, the number of times
the high-high interlock of the tank the loop's pump feeds latched.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from pydantic import Field, model_validator

from tanklab.config import (
    LOOP_NAME,
    TANK_NAME,
    TRANSMITTER_NAME,
    VALVE_NAME,
    ConfigError,
    Finite,
    Fraction,
    Model,
    NonNegFloat,
    PositiveFloat,
    SiteConfig,
    load_model,
    read_yaml,
    sibling_file,
    site_from_mapping,
)


class _Event(Model):
    at_s: NonNegFloat = Field(description="Model time of the event [s] from the start of the run.")


class SetpointEvent(_Event):
    """Change a loop's setpoint."""

    kind: Literal["setpoint"] = Field(description="Event kind.")
    loop: str = Field(pattern=LOOP_NAME, description="Loop, e.g. LIC1.")
    value_m: NonNegFloat = Field(description="New setpoint [m].")


class LeakEvent(_Event):
    """Open or close a tank's leak valve."""

    kind: Literal["leak"] = Field(description="Event kind.")
    tank: str = Field(pattern=TANK_NAME, description="Tank, e.g. T1.")
    opening: Fraction = Field(description="Leak valve opening 0 (closed) .. 1.")


class ValveEvent(_Event):
    """Change a connecting or outlet valve's opening (a clog)."""

    kind: Literal["valve"] = Field(description="Event kind.")
    valve: str = Field(pattern=VALVE_NAME, description="Valve, e.g. V13.")
    opening: Fraction = Field(description="Opening 0 (clogged) .. 1.")


class FaultEvent(_Event):
    """Inject (or clear, with NONE) a level-transmitter fault."""

    kind: Literal["fault"] = Field(description="Event kind.")
    transmitter: str = Field(pattern=TRANSMITTER_NAME, description="Transmitter, e.g. LT1.")
    fault: Literal["NONE", "BIAS", "STUCK", "DRIFT"] = Field(description="Fault type.")
    value: Finite = Field(0.0, description="Bias [m] or drift rate [m/s].")


class DisturbanceEvent(_Event):
    """Set an extra inflow (+) or outflow (-) of a tank."""

    kind: Literal["disturbance"] = Field(description="Event kind.")
    tank: str = Field(pattern=TANK_NAME, description="Tank, e.g. T1.")
    flow_m3_s: Finite = Field(
        description="Disturbance flow [m^3/s]; 0 ends it. At most the plant's largest pump flow in magnitude."
    )


class LoopModeEvent(_Event):
    """Switch a loop's mode (MANUAL with an output in percent of the MV range)."""

    kind: Literal["loop_mode"] = Field(description="Event kind.")
    loop: str = Field(pattern=LOOP_NAME, description="Loop, e.g. LIC1.")
    mode: Literal["MANUAL", "AUTO", "REMOTE"] = Field(description="New mode.")
    mv_percent: Annotated[float, Field(ge=0, le=100)] | None = Field(
        None, description="MANUAL output in percent of the MV range; null keeps the current MV."
    )


class SupervisorModeEvent(_Event):
    """Switch the supervisor's mode."""

    kind: Literal["supervisor_mode"] = Field(description="Event kind.")
    mode: Literal["OFF", "ADVISORY", "ADAPTIVE_PID", "MPC"] = Field(description="New mode.")


Event = Annotated[
    SetpointEvent
    | LeakEvent
    | ValveEvent
    | FaultEvent
    | DisturbanceEvent
    | LoopModeEvent
    | SupervisorModeEvent,
    Field(discriminator="kind"),
]


class InitialState(Model):
    """Where a run starts (every field optional: default = the site config's initial state)."""

    levels_m: list[NonNegFloat] | None = Field(None, description="Level of each tank at start [m].")
    valves: dict[str, Fraction] = Field(default_factory=dict, description="Valve openings at start.")
    leaks: dict[str, Fraction] = Field(default_factory=dict, description="Leak openings at start, by tank.")
    setpoints_m: dict[str, NonNegFloat] = Field(default_factory=dict, description="Setpoints at start [m].")
    modes: dict[str, Literal["MANUAL", "AUTO", "REMOTE"]] = Field(
        default_factory=dict, description="Loop modes at start."
    )
    pump_commands: list[Finite] | None = Field(
        None, description="Pump commands at start (pump units); default: the site's initial commands."
    )


class Variant(Model):
    """One controller configuration to run the scenario with."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$", description="Variant name (pid, mpc, mpc_pid, ...).")
    description: str = Field("", description="What this variant is.")
    supervisor_mode: Literal["OFF", "ADVISORY", "ADAPTIVE_PID", "MPC"] = Field(
        "OFF", description="Supervisor mode at start (OFF: the PLC alone)."
    )
    scan_period_s: PositiveFloat | None = Field(None, description="PLC scan period override [s].")
    set: dict[str, Any] = Field(
        default_factory=dict,
        description="Site overrides for this variant: dotted path (list items by index) -> value.",
    )


class PublishedMetric(Model):
    """A number a paper printed, for `tankctl compare`."""

    variant: str = Field(description="Our variant it corresponds to.")
    loop: str = Field(description="Loop (LIC1, ...).")
    metric: str = Field(description="Metric key (iae, overshoot_pct, settling_time_s, ...).")
    value: Finite = Field(description="The printed value, in our units.")
    note: str = Field("", description="Where it was printed and how it was converted.")


LoopMetricName = Literal[
    "iae",
    "ise",
    "itae",
    "overshoot_pct",
    "settling_time_s",
    "max_du",
    "constraint_violations",
]
"""The per-loop metrics of ``tankctl simulate`` (the fields of ``tankctl.metrics.LoopMetrics``)."""

LOOP_METRICS: tuple[str, ...] = get_args(LoopMetricName)

ExpectMetric = Literal[LoopMetricName, "interlock_trips"]
"""The metrics an expectation may bound (see the module docstring for their meaning)."""

EXPECT_METRICS: tuple[str, ...] = get_args(ExpectMetric)


class Expectation(Model):
    """A bound on one loop's metric in one variant's run (or in every variant's)."""

    variant: str | None = Field(None, description="Variant it applies to; every variant when omitted.")
    loop: str = Field(pattern=LOOP_NAME, description="Loop whose metric is bounded, e.g. LIC1.")
    metric: ExpectMetric = Field(description="Metric key, in the units of `tankctl simulate`.")
    max: Finite | None = Field(None, description="Largest value that passes (inclusive).")
    min: Finite | None = Field(None, description="Smallest value that passes (inclusive).")
    note: str = Field("", description="Why this bound (where it comes from).")

    @model_validator(mode="after")
    def _bounded(self) -> Expectation:
        if self.max is None and self.min is None:
            raise ValueError("an expectation needs max, min or both")
        if self.max is not None and self.min is not None and self.min > self.max:
            raise ValueError(f"min {self.min:g} is above max {self.max:g}")
        return self


class Scenario(Model):
    """A scenario file."""

    name: str = Field(description="Scenario name.")
    description: str = Field("", description="What it reproduces, and every unprinted choice made.")
    site: str = Field(description="Site config file, relative to the scenario file.")
    duration_s: PositiveFloat = Field(description="Run length in model time [s].")
    initial: InitialState = Field(default_factory=InitialState, description="Initial state.")
    events: list[Event] = Field(default_factory=list, description="Timed events, in any order.")
    variants: list[Variant] = Field(
        default_factory=lambda: [Variant(name="default")], description="Controller variants to compare."
    )
    settling_band: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.02, description="Settling band as a fraction of the step size (default 2 %)."
    )
    published: list[PublishedMetric] = Field(default_factory=list, description="The paper's numbers.")
    expect: list[Expectation] = Field(
        default_factory=list, description="Bounds on loop metrics that `tankctl scenario check` checks."
    )

    @model_validator(mode="after")
    def _unique_variants(self) -> Scenario:
        names = [v.name for v in self.variants]
        if len(set(names)) != len(names):
            raise ValueError("variant names must be unique")
        for i, e in enumerate(self.expect):
            if e.variant is not None and e.variant not in names:
                raise ValueError(
                    f"expect[{i}].variant: no variant {e.variant!r} (variants: {', '.join(names)})"
                )
        return self

    def sorted_events(self) -> list[Event]:
        """Events by time (stable for equal times)."""
        return sorted(self.events, key=lambda e: e.at_s)


def apply_overrides(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """A deep copy of ``data`` with each dotted path set (list items by index).

    Raises
    ------
    KeyError
        If a path does not exist in ``data`` (a typo must not pass silently).
    """
    out = copy.deepcopy(data)
    for path, value in overrides.items():
        parts = path.split(".")
        node: Any = out
        for i, part in enumerate(parts[:-1]):
            node = _child(node, part, ".".join(parts[: i + 1]))
        last = parts[-1]
        if isinstance(node, list):
            node[int(last)] = value
        elif isinstance(node, dict):
            node[last] = value
        else:
            raise KeyError(f"{path}: cannot set inside a {type(node).__name__}")
    return out


def _child(node: Any, part: str, where: str) -> Any:
    if isinstance(node, list):
        try:
            return node[int(part)]
        except (ValueError, IndexError):
            raise KeyError(f"{where}: no list item {part}") from None
    if isinstance(node, dict) and part in node:
        return node[part]
    raise KeyError(f"{where}: no such field")


def load_scenario(path: str | Path) -> tuple[Scenario, Path]:
    """Read and validate a scenario file; return it and the resolved site file path."""
    p = Path(path)
    scenario = load_model(p, Scenario)
    return scenario, sibling_file(p, "site", scenario.site)


def variant_site(scenario: Scenario, site_path: Path, variant: Variant) -> SiteConfig:
    """The site config of one variant: the site file with the variant's overrides applied."""
    data = read_yaml(site_path)
    try:
        data = apply_overrides(data, variant.set)
    except (KeyError, ValueError) as e:
        raise ConfigError(f"{scenario.name}: variants[{variant.name}].set: {e}") from e
    site = site_from_mapping(data, f"{site_path} (variant {variant.name})")
    if variant.scan_period_s is not None and site.plc is not None:
        site.plc.scan_period_s = variant.scan_period_s
    check_against_site(scenario, site)
    return site


def check_against_site(scenario: Scenario, site: SiteConfig) -> None:
    """Every tank, valve, loop and transmitter a scenario names exists in the site."""
    tanks, valves, loops = set(site.tank_names), set(site.valve_names), set(site.loop_names)
    lts = {f"LT{t[1:]}" for t in tanks}
    where = f"{scenario.name}"
    init = scenario.initial
    if init.levels_m is not None and len(init.levels_m) != len(tanks):
        raise ConfigError(f"{where}: initial.levels_m: needs {len(tanks)} levels")
    if init.pump_commands is not None and len(init.pump_commands) != len(site.pump_names):
        raise ConfigError(f"{where}: initial.pump_commands: needs {len(site.pump_names)} commands")
    for name in init.valves:
        if name not in valves:
            raise ConfigError(f"{where}: initial.valves: unknown valve {name}")
    for name in init.leaks:
        if name not in tanks:
            raise ConfigError(f"{where}: initial.leaks: unknown tank {name}")
    for name in list(init.setpoints_m) + list(init.modes):
        if name not in loops:
            raise ConfigError(f"{where}: initial: unknown loop {name}")
    for i, e in enumerate(scenario.expect):
        if e.loop not in loops:
            raise ConfigError(f"{where}: expect[{i}].loop: unknown loop {e.loop}")
    for i, ev in enumerate(scenario.events):
        target: str | None = None
        for attr in ("loop", "tank", "valve", "transmitter"):
            target = target or getattr(ev, attr, None)
        if target is not None and target not in loops | tanks | valves | lts:
            raise ConfigError(f"{where}: events[{i}]: unknown {ev.kind} target {target}")
        limit = site.plant.disturbance_limit_m3_s
        if isinstance(ev, DisturbanceEvent) and abs(ev.flow_m3_s) > limit:
            raise ConfigError(
                f"{where}: events[{i}].flow_m3_s: must lie in [-{limit:g}, {limit:g}] (the largest pump)"
            )


def live_unappliable(scenario: Scenario) -> list[str]:
    """What a running stack cannot take from ``scenario``, one ``field (reason)`` each.

    ``tankctl scenario run`` applies the initial valves, leaks, setpoints and modes and the
    timed events; a live stack cannot take the initial levels and pump commands (the plant's
    levels are states, the PLC owns the pumps) nor any variant setting a variant states
    explicitly (its supervisor mode, scan period and ``set`` overrides: a variant is a
    co-simulation run of a changed site, and a running stack's site is fixed at its start).
    Settings left at their defaults are not listed (a scenario without variants lists none).
    """
    out: list[str] = []
    init = scenario.initial
    if init.levels_m is not None:
        out.append("initial.levels_m (a running plant's levels are not writable)")
    if init.pump_commands is not None:
        out.append("initial.pump_commands (the PLC owns the pump commands)")
    for v in scenario.variants:
        where = f"variants[{v.name}]"
        if "supervisor_mode" in v.model_fields_set:
            out.append(f"{where}.supervisor_mode {v.supervisor_mode} (variants are `tankctl simulate` runs)")
        if v.scan_period_s is not None:
            out.append(f"{where}.scan_period_s (the PLC's scan period is fixed at its start)")
        for path in v.set:
            out.append(f"{where}.set {path} (a running stack's site is fixed at its start)")
    return out
