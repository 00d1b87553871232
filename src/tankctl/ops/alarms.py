"""Alarms: ``alarms`` (both tiers' conditions, one Read per tier), ``ack``, ``shelve``,
``unshelve`` (issue 15).

The PLC's and the supervisor's alarms are OPC UA Part 9 conditions (docs/alarms.md):
``PLC.Conditions.<name>`` and ``Supervisor.Conditions.<name>`` (:func:`tanklab.paths.condition`),
their state variables its children (``<id>.AckedState.Id``, :mod:`tanklab_io.conditions.fields`),
their methods too (``<id>.Acknowledge``, ``<id>.ShelvingState.TimedShelve``). The names come from
the site (:func:`plc_alarms`, :func:`supervisor_alarms`), so a name is checked, and its tier found,
before anything is sent, and ``tankctl alarms`` reads every condition's state in one Read per
tier (the two tiers at once), with no event subscription. A tier that does not answer is one
line on stderr; the other tier's alarms are still listed.

Condition names are unique across the tiers (the PLC's: ``T1Level``, ``LIC1PvBad``, ``IoFault``,
``SupervisorLost``, ``T1Trip``; the supervisor's: ``MpcFailing``, ``AdaptationUnhealthy``,
``PlcLinkLost``; a unit test checks it on every shipped site), so ``ack NAME`` finds the tier by
itself; ``plc/NAME`` or ``supervisor/NAME`` names the tier explicitly.

Pure helpers (:func:`parse_duration_ms`, :func:`condition_rows`, :func:`render_rows`) do the
parsing and formatting; the commands are thin shells around one Read and one Call.
"""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated, Any

import typer
from asyncua import ua

from tankctl.ops.client import TierClient
from tankctl.ops.errors import UnreachableError, UsageError
from tankctl.ops.history_output import render_events
from tankctl.ops.history_read import parse_time, read_event_history
from tankctl.ops.options import JsonOpt, StackOptions, stack_command
from tankctl.ops.run import check_usage, fail, run
from tankctl.ops.stack import Stack
from tanklab import paths
from tanklab.alarms.definitions import plc_alarms, supervisor_alarms
from tanklab.alarms.model import AlarmDefinition, ShelvingState
from tanklab.tags import Tier
from tanklab_io.ua_alarms import (
    LIMIT_FIELD,
    STATE_FIELDS,
    AlarmRow,
    child,
    condition_row,
    condition_rows,
    fields_of,
    priority_name,
    read_paths,
)

__all__ = [
    "LIMIT_FIELD",
    "STATE_FIELDS",
    "AlarmRow",
    "TierAlarms",
    "child",
    "condition_row",
    "condition_rows",
    "fields_of",
    "find",
    "known",
    "parse_duration_ms",
    "priority_name",
    "read_paths",
    "render_rows",
]

ALARM_TIERS: tuple[Tier, ...] = ("plc", "supervisor")
"""The tiers with conditions, in the order ``tankctl alarms`` lists them."""
TIER_NAMES: dict[Tier, str] = {"plant": "plant", "plc": "PLC", "supervisor": "supervisor"}
"""How messages name a tier."""

_UNITS_MS = {"ms": 1.0, "s": 1000.0, "m": 60_000.0, "h": 3_600_000.0, "d": 86_400_000.0}
_PART = re.compile(r"(\d+(?:\.\d+)?)(ms|s|m|h|d)")


def parse_duration_ms(text: str) -> float:
    """A shelving duration (``15m``, ``900s``, ``1h``, ``1h30m``, ``500ms``, ``2d``) in ms.

    A bare number is seconds. Raises UsageError for anything else or a duration of 0.
    """
    t = text.strip().lower().replace(" ", "")
    if re.fullmatch(r"\d+(?:\.\d+)?", t):
        ms = float(t) * 1000.0
    elif re.fullmatch(f"(?:{_PART.pattern})+", t):
        ms = sum(float(n) * _UNITS_MS[u] for n, u in _PART.findall(t))
    else:
        raise UsageError(f"a duration is like 15m, 900s or 1h (units ms, s, m, h, d), got {text!r}")
    if not ms > 0:
        raise UsageError(f"a shelving duration must be longer than 0, got {text!r}")
    return ms


COLUMNS = ("TIER", "NAME", "PRIORITY", "STATE", "LIMIT", "SINCE", "MESSAGE")


def render_rows(rows: Sequence[AlarmRow], *, every: bool = False) -> str:
    """The rows as a plain text table (no colours: it goes to logs and pipes as well)."""
    if not rows:
        return "no conditions" if every else "no standing alarms"
    table = [COLUMNS] + [
        (
            r.tier,
            r.name,
            f"{r.priority} ({r.severity})"
            if r.priority
            else (str(r.severity) if r.severity is not None else "?"),
            r.state,
            r.limit or "-",
            r.since or "-",
            r.message,
        )
        for r in rows
    ]
    widths = [max(len(line[i]) for line in table) for i in range(len(COLUMNS) - 1)]
    return "\n".join(
        "  ".join([*(cell.ljust(w) for cell, w in zip(line[:-1], widths, strict=True)), line[-1]]).rstrip()
        for line in table
    )


# ---- the commands ---------------------------------------------------------------------------


@dataclass(frozen=True)
class TierAlarms:
    """One tier's conditions (its definitions, in the tier's order)."""

    tier: Tier
    definitions: tuple[AlarmDefinition, ...]


def alarm_tiers(stack: Stack) -> list[TierAlarms]:
    """The tiers of the stack's site that have conditions, PLC first (UsageError if none)."""
    site = stack.site
    out = []
    if stack.has("plc"):
        out.append(TierAlarms("plc", plc_alarms(site)))
    if stack.has("supervisor"):
        out.append(TierAlarms("supervisor", supervisor_alarms(site)))
    if not out:
        raise UsageError(f"the site {site.name} has no alarms (no plc or supervisor section)")
    return out


def find(tiers: Sequence[TierAlarms], name: str) -> tuple[TierAlarms, AlarmDefinition]:
    """The condition called ``name`` (case-insensitive; ``plc/NAME`` or ``supervisor/NAME``
    looks on that tier only) and its tier, else UsageError naming every one, per tier."""
    text = name.strip()
    among = list(tiers)
    if "/" in text:
        prefix, text = (part.strip() for part in text.split("/", 1))
        among = [t for t in tiers if t.tier == prefix.lower()]
        if not among:
            have = ", ".join(t.tier for t in tiers)
            raise UsageError(f"unknown tier {prefix!r} in {name!r} (alarms are on {have})")
    found = [(t, d) for t in among for d in t.definitions if d.name.lower() == text.lower()]
    if len(found) == 1:
        return found[0]
    if found:  # not with the shipped names (unique across tiers), but never a guess
        qualified = " or ".join(f"{t.tier}/{d.name}" for t, d in found)
        raise UsageError(f"alarm {name!r} is on more than one tier: give {qualified}")
    have = "; ".join(
        f"the {TIER_NAMES[t.tier]} has {', '.join(d.name for d in t.definitions) or 'none'}" for t in among
    )
    raise UsageError(f"unknown alarm {name!r} ({have})")


def known(definitions: Sequence[AlarmDefinition], name: str, tier: Tier = "plc") -> AlarmDefinition:
    """The condition of one tier called ``name`` (case-insensitive), else UsageError naming
    every one (:func:`find` over that tier alone)."""
    return find([TierAlarms(tier, tuple(definitions))], name)[1]


async def read_rows(
    client: TierClient, definitions: Sequence[AlarmDefinition], every: bool, tier: Tier = "plc"
) -> list[AlarmRow]:
    values = await client.read(read_paths(definitions, tier))
    return condition_rows(definitions, values, every=every, tier=tier)


async def _tier_rows(stack: Stack, t: TierAlarms, every: bool) -> list[AlarmRow] | UnreachableError:
    """One tier's rows from its one Read (with the identity, when not connected yet), or why
    the tier did not answer."""
    nodes = read_paths(t.definitions, t.tier)
    try:
        async with stack.client(t.tier).will_read(nodes) as client:
            return await read_rows(client, t.definitions, every, t.tier)
    except UnreachableError as e:
        return e


async def collect_rows(stack: Stack, every: bool) -> tuple[list[AlarmRow], list[UnreachableError]]:
    """Every alarm tier's rows (the tiers read at once), in tier order, and the tiers down."""
    results = await asyncio.gather(*(_tier_rows(stack, t, every) for t in alarm_tiers(stack)))
    rows = [r for res in results if not isinstance(res, UnreachableError) for r in res]
    return rows, [res for res in results if isinstance(res, UnreachableError)]


@stack_command
def alarms(
    json_out: JsonOpt = False,
    every: Annotated[
        bool, typer.Option("--all", help="Every condition, not only the standing ones.")
    ] = False,
    history: Annotated[
        bool,
        typer.Option(
            "--history",
            help="The alarm and audit events the historian recorded in [--from, --to].",
        ),
    ] = False,
    start: Annotated[
        str, typer.Option("--from", help="--history: start (ISO 8601 UTC, now, -15m, -1d).")
    ] = "-1h",
    end: Annotated[str, typer.Option("--to", help="--history: end (as --from).")] = "now",
    min_severity: Annotated[
        int, typer.Option(help="--history: only events of at least this Severity (1..1000).")
    ] = 0,
    historian_url: Annotated[
        str | None, typer.Option(help="--history: historian endpoint (env TANKLAB_HISTORIAN_ENDPOINT).")
    ] = None,
    *,
    options: StackOptions,
) -> None:
    """The standing alarms (active or unacknowledged) of the PLC and the supervisor: tier,
    priority, state, limit, since, message. A tier that is down is one line on stderr (exit 0
    while another tier answers, 2 when none does). With --history: the events the historian
    recorded (time, severity, source, message)."""
    if history:
        _alarm_history(json_out, start, end, min_severity, historian_url, options)
        return
    stack = options.stack()

    async def main() -> int:
        await stack.resolve("plc", "supervisor")
        rows, down = await collect_rows(stack, every)
        if json_out:
            typer.echo(json.dumps([r.as_json() for r in rows], indent=2))
        else:
            typer.echo(render_rows(rows, every=every))
        for e in down:
            typer.echo(f"tankctl: {e} (its alarms are not listed)", err=True)
        return 2 if down and len(down) == len(alarm_tiers(stack)) else 0

    run(main)


def _alarm_history(
    json_out: bool, start: str, end: str, min_severity: int, historian_url: str | None, options: StackOptions
) -> None:
    """``alarms --history``: one ReadEventDetails of the historian's Server object."""
    now = datetime.now(UTC)

    def parsed() -> tuple[datetime, datetime]:
        t0, t1 = parse_time(start, now, "--from"), parse_time(end, now, "--to")
        if t0 >= t1:
            raise UsageError(f"--from {start!r} is not before --to {end!r}")
        if not 0 <= min_severity <= 1000:
            raise UsageError(f"--min-severity must be 0..1000, got {min_severity}")
        return t0, t1

    t0, t1 = check_usage(parsed)
    stack = options.stack(historian_url=historian_url)

    async def main() -> int:
        await stack.resolve("historian")
        async with stack.client("historian") as client:
            rows = await read_event_history(client.client, t0, t1, min_severity=min_severity)
        typer.echo(render_events(rows, json_out))
        return 0

    run(main)


def _one_line(row: AlarmRow) -> str:
    """``ACTIVE UNACK, limit Low`` (``, TimedShelved`` when shelved)."""
    limit = f", limit {row.limit}" if row.limit else ""
    shelved = f", {row.shelved}" if row.shelved not in (None, ShelvingState.UNSHELVED.value) else ""
    return f"{row.state}{limit}{shelved}"


Arguments = Callable[[AlarmDefinition, Mapping[str, Any]], tuple[list[ua.Variant], str]]
"""The call's arguments and how they are shown, from the condition's state read just before
(keyed by field path: ``EventId``, ``AckedState/Id``)."""


def _no_arguments(definition: AlarmDefinition, values: Mapping[str, Any]) -> tuple[list[ua.Variant], str]:
    return [], ""


async def _call_and_tell(stack: Stack, name: str, method: str, arguments: Arguments, verb: str) -> None:
    """Find the condition's tier, read its state (one Read), call ``method`` (a child path below
    it) with ``arguments(state)``, read it again and print ``NAME: VERB (was STATE; now STATE)``;
    a Bad status is a CallRefusedError (one line, exit 1), an unknown name a UsageError (exit 2)."""
    await stack.resolve("plc", "supervisor")
    t, d = find(alarm_tiers(stack), name)
    nodes = [child(d.name, f, t.tier) for f in fields_of(d)]
    async with stack.client(t.tier).will_read(nodes) as client:
        values = await client.read(nodes)
        variants, shown = arguments(d, {_field_of(d, t.tier, k): v for k, v in values.items()})
        await client.call_variants(child(d.name, method, t.tier), variants, shown)
        after = condition_row(d, await client.read(nodes), t.tier)
    before = condition_row(d, values, t.tier)
    typer.echo(f"{d.name}: {verb} (was {_one_line(before)}; now {_one_line(after)})")


def _field_of(d: AlarmDefinition, tier: Tier, node: str) -> str:
    """A read node's field path (``AckedState/Id``) from its NodeId string."""
    return node.removeprefix(paths.condition(tier, d.name) + ".").replace(".", "/")


def acknowledge_arguments(comment: str) -> Arguments:
    """Acknowledge's (EventId ByteString, Comment LocalizedText), the EventId the latest read
    (``values`` keyed by field path, ``EventId``)."""

    def arguments(d: AlarmDefinition, values: Mapping[str, Any]) -> tuple[list[ua.Variant], str]:
        event_id = values.get("EventId")
        raw = event_id if isinstance(event_id, bytes) else b""
        variants = [
            ua.Variant(raw, ua.VariantType.ByteString),
            ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
        ]
        return variants, f"EventId {raw.hex() or '?'}, {comment!r}"

    return arguments


@stack_command
def ack(
    name: Annotated[
        str, typer.Argument(help="Condition, e.g. T1Level or PlcLinkLost (see tankctl alarms --all).")
    ],
    comment: Annotated[str, typer.Option(help="Comment stored with the acknowledgement.")] = "",
    *,
    options: StackOptions,
) -> None:
    """Acknowledge an alarm: read its latest EventId, call its Acknowledge(EventId, Comment)."""
    stack = options.stack()
    note = f", comment {comment!r}" if comment else ""

    async def main() -> int:
        await _call_and_tell(
            stack, name, "Acknowledge", acknowledge_arguments(comment), f"acknowledged{note}"
        )
        return 0

    run(main)


@stack_command
def shelve(
    name: Annotated[str, typer.Argument(help="Condition, e.g. T1Level.")],
    duration: Annotated[
        str | None, typer.Option("--for", help="Timed shelving for DURATION (15m, 900s, 1h) of model time.")
    ] = None,
    once: Annotated[
        bool, typer.Option("--once", help="One-shot: shelved until the alarm returns to normal.")
    ] = False,
    *,
    options: StackOptions,
) -> None:
    """Shelve an alarm: --for DURATION (TimedShelve, in ms) or --once (OneShotShelve)."""
    if (duration is None) == (not once):
        raise fail("give one of --for DURATION and --once", 2)
    ms = check_usage(lambda: parse_duration_ms(duration)) if duration is not None else None
    stack = options.stack()

    async def main() -> int:
        if ms is None:
            verb = "shelved once (until it returns to normal)"
            await _call_and_tell(stack, name, "ShelvingState/OneShotShelve", _no_arguments, verb)
        else:

            def timed(d: AlarmDefinition, values: Mapping[str, Any]) -> tuple[list[ua.Variant], str]:
                return [ua.Variant(ms, ua.VariantType.Double)], f"{ms:.0f} ms"

            await _call_and_tell(stack, name, "ShelvingState/TimedShelve", timed, f"shelved for {duration}")
        return 0

    run(main)


@stack_command
def unshelve(
    name: Annotated[str, typer.Argument(help="Condition, e.g. T1Level.")],
    *,
    options: StackOptions,
) -> None:
    """Unshelve an alarm (its ShelvingState's Unshelve)."""
    stack = options.stack()

    async def main() -> int:
        await _call_and_tell(stack, name, "ShelvingState/Unshelve", _no_arguments, "unshelved")
        return 0

    run(main)
