"""``tankctl scenario run``: a scenario's initial settings and timed events on a running stack,
on the plant's model time, applied through :func:`tankctl.events.apply_event` over OPC UA."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated

import typer

from tankctl.events import apply_event
from tankctl.ops.client import TierClient
from tankctl.ops.errors import SiteMismatchError, StoppedError, UnreachableError, UsageError
from tankctl.ops.options import StackOptions, stack_command
from tankctl.ops.run import StopOnSignal, fail, run
from tankctl.ops.stack import TIERS, Stack
from tankctl.ops.writes import apply_loop_mode, write_and_tell
from tankctl.usage import OneLineUsage
from tanklab import paths
from tanklab.config import load_site
from tanklab.enums import LoopMode, SensorFault, SupervisorMode
from tanklab.errors import TanklabError
from tanklab.identity import SiteIdentity
from tanklab.scenario import (
    Event,
    LeakEvent,
    LoopModeEvent,
    Scenario,
    SetpointEvent,
    SupervisorModeEvent,
    ValveEvent,
    check_against_site,
    live_unappliable,
    load_scenario,
)
from tanklab.tags import Tier

DEFAULT_POLL_S = 0.05
"""Wall time between two reads of ``Plant.Sim.Time`` in ``scenario run`` [s] (the plant's tick)."""


def _event_tiers(scenario: Scenario) -> set[Tier]:
    tiers: set[Tier] = {"plant"}
    init = scenario.initial
    if init.setpoints_m or init.modes:
        tiers.add("plc")
    for ev in scenario.events:
        if isinstance(ev, SetpointEvent | LoopModeEvent):
            tiers.add("plc")
        elif isinstance(ev, SupervisorModeEvent):
            tiers.add("supervisor")
    return tiers


class _Described:
    """An event as ``scenario run`` prints it: the verbs of the one table of event kinds
    (:class:`tankctl.events.EventTarget`) returning text."""

    def setpoint(self, loop: str, value_m: float) -> str:
        return f"setpoint {loop} {value_m:g} m"

    def leak(self, tank: str, opening: float) -> str:
        return f"leak {tank} {opening:g}"

    def valve(self, valve: str, opening: float) -> str:
        return f"valve {valve} {opening:g}"

    def disturbance(self, tank: str, flow_m3_s: float) -> str:
        return f"disturbance {tank} {flow_m3_s:g} m^3/s"

    def fault(self, transmitter: str, fault: SensorFault, value: float) -> str:
        return f"fault {transmitter} {fault.name} {value:g}"

    def loop_mode(self, loop: str, mode: LoopMode, mv_percent: float | None) -> str:
        pct = f" {mv_percent:g} %" if mv_percent is not None else ""
        return f"loop {loop} {mode.name.lower()}{pct}"

    def supervisor_mode(self, mode: SupervisorMode) -> str:
        return f"supervisor mode {mode.name}"


def _describe_event(ev: Event) -> str:
    return apply_event(_Described(), ev)


class LiveEvents:
    """The scenario verbs (:class:`tankctl.events.EventTarget`) over OPC UA: each writes the
    nodes of the tier that owns them and returns the lines saying what was written."""

    def __init__(self, clients: Mapping[Tier, TierClient]) -> None:
        self.clients = clients

    async def setpoint(self, loop: str, value_m: float) -> list[str]:
        return [await write_and_tell(self.clients["plc"], paths.plc.loop(loop).sp, value_m)]

    async def leak(self, tank: str, opening: float) -> list[str]:
        return [await write_and_tell(self.clients["plant"], paths.plant.tank(tank).leak, opening)]

    async def valve(self, valve: str, opening: float) -> list[str]:
        return [await write_and_tell(self.clients["plant"], paths.plant.valve_opening(valve), opening)]

    async def disturbance(self, tank: str, flow_m3_s: float) -> list[str]:
        return [await write_and_tell(self.clients["plant"], paths.plant.tank(tank).disturbance, flow_m3_s)]

    async def fault(self, transmitter: str, fault: SensorFault, value: float) -> list[str]:
        # Its size first, then its kind, so the fault starts with the right value.
        lt = paths.plant.transmitter(transmitter)
        plant = self.clients["plant"]
        return [
            await write_and_tell(plant, lt.fault_value, value),
            await write_and_tell(plant, lt.fault, int(fault)),
        ]

    async def loop_mode(self, loop: str, mode: LoopMode, mv_percent: float | None) -> list[str]:
        return await apply_loop_mode(self.clients["plc"], loop, mode, mv_percent)

    async def supervisor_mode(self, mode: SupervisorMode) -> list[str]:
        return [await write_and_tell(self.clients["supervisor"], paths.supervisor.mode, int(mode))]


def _initial_events(scenario: Scenario) -> list[Event]:
    """The parts of ``initial`` a running stack can take, as events at 0 s (the rest is in
    :func:`tanklab.scenario.live_unappliable`)."""
    init = scenario.initial
    events: list[Event] = []
    for name, opening in init.valves.items():
        events.append(ValveEvent(at_s=0, kind="valve", valve=name, opening=opening))
    for name, opening in init.leaks.items():
        events.append(LeakEvent(at_s=0, kind="leak", tank=name, opening=opening))
    for name, sp in init.setpoints_m.items():
        events.append(SetpointEvent(at_s=0, kind="setpoint", loop=name, value_m=sp))
    for name, m in init.modes.items():
        events.append(LoopModeEvent(at_s=0, kind="loop_mode", loop=name, mode=m))
    return events


@stack_command
def scenario_run(
    file: Annotated[Path, typer.Argument(help="Scenario YAML file.")],
    speed_from_plant: Annotated[
        bool,
        typer.Option(
            "--speed-from-plant",
            help="Sleep between time polls for the model time left / Plant.Sim.Speed (max 1 s) "
            "instead of polling every 50 ms.",
        ),
    ] = False,
    until_end: Annotated[
        bool, typer.Option("--until-end", help="After the last event, wait until the scenario's duration_s.")
    ] = False,
    ignore_unappliable: Annotated[
        bool,
        typer.Option(
            "--ignore-unappliable",
            help="Run the events even though some of the scenario's fields cannot be applied to a "
            "running stack (initial levels, variant settings, another config of the site); each is "
            "printed as 'not applied:'.",
        ),
    ] = False,
    *,
    options: StackOptions,
) -> None:
    """Apply a scenario's initial settings and timed events to the running stack.

    Times are the plant's model time (Plant.Sim.Time) since the command started. The stack must
    run the scenario's site (its name; another config of it is a field not applied). Fields a
    running stack cannot take are refused in one line unless --ignore-unappliable.
    """
    try:
        scenario, site_path = load_scenario(file)
        scenario_site = load_site(site_path)
    except TanklabError as e:
        raise fail(str(e), 2) from None
    stack = options.stack(endpoints_of=scenario_site)

    async def main() -> int:
        needed = [t for t in TIERS if t in _event_tiers(scenario)]
        await stack.resolve(*needed)
        for tier in needed:
            stack.require(tier)
        clients = {t: stack.client(t) for t in needed}
        try:
            for c in clients.values():  # every tier the scenario writes must answer (and match) first
                await c.connect()
            skipped = _check_scenario(scenario, SiteIdentity.of(scenario_site), stack)
            if skipped and not ignore_unappliable:
                raise UsageError(
                    f"scenario {scenario.name}: {len(skipped)} field{'s' if len(skipped) > 1 else ''} cannot "
                    f"be applied to a running stack: {'; '.join(skipped)}; --ignore-unappliable runs its "
                    "events without them"
                )
            return await _play(
                scenario, clients, skipped, speed_from_plant=speed_from_plant, until_end=until_end
            )
        finally:
            for c in clients.values():
                await c.close()

    run(main)


def _check_scenario(scenario: Scenario, written_for: SiteIdentity, stack: Stack) -> list[str]:
    """Refuse a scenario for another site; return the fields the running stack cannot take.

    The scenario's site file must name the stack's site (else :class:`SiteMismatchError`); a
    different config of that site (another digest) is listed first among the fields not
    applied, since the scenario's author meant other parameters than the stack runs.
    """
    runs = stack.site_identity
    if written_for.name != runs.name:
        raise SiteMismatchError(
            f"scenario {scenario.name} is written for {written_for} (site: {scenario.site}), but the "
            f"stack runs {runs} ({stack.origin})"
        )
    check_against_site(scenario, stack.site)
    skipped = live_unappliable(scenario)
    if written_for.digest != runs.digest:
        skipped.insert(
            0, f"site (its {scenario.site} is config {written_for.short}, the stack runs {runs.short})"
        )
    return skipped


async def _play(
    scenario: Scenario,
    clients: Mapping[Tier, TierClient],
    skipped: Sequence[str],
    *,
    speed_from_plant: bool,
    until_end: bool,
) -> int:
    plant = clients["plant"]
    target = LiveEvents(clients)

    async def now() -> float:
        t = (await plant.read([paths.plant.sim_time]))[paths.plant.sim_time]
        if not isinstance(t, float):
            raise UnreachableError("plant", plant.url, f"{paths.plant.sim_time} did not read Good")
        return t

    t0 = await now()
    initial = _initial_events(scenario)
    events = scenario.sorted_events()
    typer.echo(
        f"scenario {scenario.name}: {len(events)} events over {scenario.duration_s:g} s of model time, "
        f"starting at plant time {t0:.1f} s"
    )
    for field_ in skipped:
        typer.echo(f"not applied: {field_}")
    applied = 0

    def say(t: float, label: str, lines: list[str]) -> None:
        typer.echo(f"t={t:8.1f} s  {label}: " + "; ".join(lines))

    with StopOnSignal() as stop:

        async def wait_for_model_time(at_s: float) -> float:
            while True:
                t = await now() - t0
                if t >= at_s:
                    return t
                if stop.is_set():
                    raise StoppedError(
                        f"scenario {scenario.name} interrupted at t={t:.1f} s "
                        f"({applied} of {len(events)} events applied)"
                    )
                wait = DEFAULT_POLL_S
                if speed_from_plant:
                    speed = (await plant.read([paths.plant.sim_speed]))[paths.plant.sim_speed]
                    if isinstance(speed, float) and speed > 0:  # 0 in lock-step: keep polling
                        wait = min(max((at_s - t) / speed, DEFAULT_POLL_S), 1.0)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), wait)

        for ev in initial:
            say(await now() - t0, f"initial {_describe_event(ev)}", await apply_event(target, ev))
        for ev in events:
            if until_end and ev.at_s > scenario.duration_s:
                break
            t = await wait_for_model_time(ev.at_s)
            say(t, f"@{ev.at_s:g} s {_describe_event(ev)}", await apply_event(target, ev))
            applied += 1
        if until_end:
            t = await wait_for_model_time(scenario.duration_s)
            typer.echo(f"t={t:8.1f} s  end of scenario (duration {scenario.duration_s:g} s)")
    typer.echo(f"done: {applied} of {len(events)} events applied")
    return 0


scenario_app = typer.Typer(
    help="Scenarios against a running stack.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
"""The ``tankctl scenario`` group."""


def add_scenario_commands(group: typer.Typer) -> None:
    """Add ``run`` to a ``scenario`` command group (this module's or an existing one)."""
    group.command("run", cls=OneLineUsage)(scenario_run)


add_scenario_commands(scenario_app)
