"""Alarms: ``alarms`` (the PLC's conditions, one Read), ``ack``, ``shelve``, ``unshelve`` (issue 15).

The PLC's alarms are OPC UA Part 9 conditions (docs/alarms.md): ``PLC.Conditions.<name>``
(:func:`tanklab.paths.condition`), their state variables its children (``<id>.AckedState.Id``,
:mod:`tanklab_io.conditions.fields`), their methods too (``<id>.Acknowledge``,
``<id>.ShelvingState.TimedShelve``). The names come from the site (:func:`plc_alarms`), so a
name is checked before anything is sent and ``tankctl alarms`` reads every condition's state
in one Read, with no event subscription.

Pure helpers (:func:`parse_duration_ms`, :func:`condition_rows`, :func:`render_rows`) do the
parsing and formatting; the commands are thin shells around one Read and one Call.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from typing import Annotated, Any

import typer
from asyncua import ua

from tankctl.ops.client import TierClient
from tankctl.ops.errors import UsageError
from tankctl.ops.options import JsonOpt, StackOptions, stack_command
from tankctl.ops.run import check_usage, fail, run
from tankctl.ops.stack import Stack
from tanklab import paths
from tanklab.alarms.definitions import plc_alarms
from tanklab.alarms.model import AlarmDefinition, ConditionKind, Priority, ShelvingState

STATE_FIELDS: tuple[str, ...] = (
    "EventId",
    "Severity",
    "Message",
    "Time",
    "Retain",
    "EnabledState/Id",
    "ActiveState/Id",
    "AckedState/Id",
    "ShelvingState/CurrentState",
)
"""The browse paths below a condition that ``tankctl alarms`` reads (Part 9 names)."""
LIMIT_FIELD = "LimitState/CurrentState"
"""Read only for an exclusive level alarm (the other kinds have no LimitState)."""

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


def child(name: str, field: str) -> str:
    """The NodeId string of a PLC condition's child (``PLC.Conditions.T1Level.AckedState.Id``)."""
    return f"{paths.condition('plc', name)}.{field.replace('/', '.')}"


def fields_of(definition: AlarmDefinition) -> tuple[str, ...]:
    """The state fields read for one condition."""
    if definition.kind == ConditionKind.EXCLUSIVE_LEVEL:
        return (*STATE_FIELDS, LIMIT_FIELD)
    return STATE_FIELDS


def read_paths(definitions: Sequence[AlarmDefinition]) -> list[str]:
    """Every state variable of every condition: the nodes of the one Read."""
    return [child(d.name, f) for d in definitions for f in fields_of(d)]


@dataclass(frozen=True)
class AlarmRow:
    """One condition's state as ``tankctl alarms`` shows it (``--json``: these keys)."""

    name: str
    priority: str
    """The ISA-18.2 priority of the current Severity (LOW/MEDIUM/HIGH/URGENT), else ``""``."""
    severity: int | None
    active: bool | None
    acked: bool | None
    shelved: str | None
    """ShelvingState: Unshelved, OneShotShelved or TimedShelved (None if unread)."""
    enabled: bool | None
    retain: bool | None
    limit: str | None
    """The active limit of a level alarm (HighHigh, High, Low, LowLow), else None."""
    since: str | None
    """The condition's Time (its last state change), ISO 8601 UTC."""
    message: str

    @property
    def standing(self) -> bool:
        """Retained: active or unacknowledged (Part 9 Retain; the states when Retain is unread)."""
        if self.retain is not None:
            return self.retain
        return bool(self.active) or self.acked is False

    @property
    def state(self) -> str:
        """``ACTIVE``/``RTN``, ``UNACK``/``ACK``, then ``SHELVED`` and ``DISABLED`` when so."""
        words = ["ACTIVE" if self.active else "RTN", "ACK" if self.acked or self.acked is None else "UNACK"]
        if self.shelved not in (None, ShelvingState.UNSHELVED.value):
            words.append("SHELVED")
        if self.enabled is False:
            words.append("DISABLED")
        return " ".join(words)

    def as_json(self) -> dict[str, Any]:
        return {**asdict(self), "state": self.state, "standing": self.standing}


def _text(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, ua.LocalizedText):
        return value.Text
    return str(value)


def _iso(value: Any) -> str | None:
    if not isinstance(value, datetime):
        return None
    when = value if value.tzinfo is not None else value.replace(tzinfo=UTC)
    return when.astimezone(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def priority_name(severity: Any) -> str:
    """The priority whose Severity this is (docs/alarms.md's table), else ``""``."""
    try:
        return Priority(int(severity)).name
    except (TypeError, ValueError):
        return ""


def condition_row(definition: AlarmDefinition, values: Mapping[str, Any]) -> AlarmRow:
    """One row from the Read's values (keyed by :func:`child` NodeId strings; None = Bad)."""

    def v(field: str) -> Any:
        return values.get(child(definition.name, field))

    severity = v("Severity")
    is_level = definition.kind == ConditionKind.EXCLUSIVE_LEVEL
    return AlarmRow(
        name=definition.name,
        priority=priority_name(severity),
        severity=int(severity) if severity is not None else None,
        active=v("ActiveState/Id"),
        acked=v("AckedState/Id"),
        shelved=_text(v("ShelvingState/CurrentState")),
        enabled=v("EnabledState/Id"),
        retain=v("Retain"),
        limit=(_text(v(LIMIT_FIELD)) or None) if is_level else None,
        since=_iso(v("Time")),
        message=_text(v("Message")) or "",
    )


def condition_rows(
    definitions: Sequence[AlarmDefinition], values: Mapping[str, Any], *, every: bool = False
) -> list[AlarmRow]:
    """The rows ``tankctl alarms`` shows: the standing ones, or ``every`` condition."""
    rows = [condition_row(d, values) for d in definitions]
    return rows if every else [r for r in rows if r.standing]


COLUMNS = ("NAME", "PRIORITY", "STATE", "LIMIT", "SINCE", "MESSAGE")


def render_rows(rows: Sequence[AlarmRow], *, every: bool = False) -> str:
    """The rows as a plain text table (no colours: it goes to logs and pipes as well)."""
    if not rows:
        return "no conditions" if every else "no standing alarms"
    table = [COLUMNS] + [
        (
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


def definitions_of(stack: Stack) -> tuple[AlarmDefinition, ...]:
    """The PLC's conditions for the stack's site (UsageError if the site has no PLC)."""
    stack.require("plc")
    return plc_alarms(stack.site)


def known(definitions: Sequence[AlarmDefinition], name: str) -> AlarmDefinition:
    """The condition called ``name`` (case-insensitive), else UsageError naming every one."""
    for d in definitions:
        if d.name.lower() == name.strip().lower():
            return d
    have = ", ".join(d.name for d in definitions) or "none"
    raise UsageError(f"unknown alarm {name!r} (the PLC has {have})")


async def read_rows(plc: TierClient, definitions: Sequence[AlarmDefinition], every: bool) -> list[AlarmRow]:
    return condition_rows(definitions, await plc.read(read_paths(definitions)), every=every)


@stack_command
def alarms(
    json_out: JsonOpt = False,
    every: Annotated[
        bool, typer.Option("--all", help="Every condition, not only the standing ones.")
    ] = False,
    *,
    options: StackOptions,
) -> None:
    """The PLC's standing alarms (active or unacknowledged): priority, state, limit, since, message."""
    stack = options.stack()

    async def main() -> int:
        await stack.resolve("plc")
        defs = definitions_of(stack)
        async with stack.client("plc").will_read(read_paths(defs)) as plc:
            rows = await read_rows(plc, defs, every)
        if json_out:
            typer.echo(json.dumps([r.as_json() for r in rows], indent=2))
        else:
            typer.echo(render_rows(rows, every=every))
        return 0

    run(main)


def _one_line(row: AlarmRow) -> str:
    """``ACTIVE UNACK, limit Low`` (``, TimedShelved`` when shelved)."""
    limit = f", limit {row.limit}" if row.limit else ""
    shelved = f", {row.shelved}" if row.shelved not in (None, ShelvingState.UNSHELVED.value) else ""
    return f"{row.state}{limit}{shelved}"


Arguments = Callable[[AlarmDefinition, Mapping[str, Any]], tuple[list[ua.Variant], str]]
"""The call's arguments and how they are shown, from the condition's state read just before."""


def _no_arguments(definition: AlarmDefinition, values: Mapping[str, Any]) -> tuple[list[ua.Variant], str]:
    return [], ""


async def _call_and_tell(stack: Stack, name: str, method: str, arguments: Arguments, verb: str) -> None:
    """Read the condition's state (one Read), call ``method`` (a child path below it) with
    ``arguments(state)``, read it again and print ``NAME: VERB (was STATE; now STATE)``; a Bad
    status is a CallRefusedError (one line, exit 1), an unknown name a UsageError (exit 2)."""
    await stack.resolve("plc")
    d = known(definitions_of(stack), name)
    nodes = [child(d.name, f) for f in fields_of(d)]
    async with stack.client("plc").will_read(nodes) as plc:
        values = await plc.read(nodes)
        variants, shown = arguments(d, values)
        await plc.call_variants(child(d.name, method), variants, shown)
        after = condition_row(d, await plc.read(nodes))
    typer.echo(f"{d.name}: {verb} (was {_one_line(condition_row(d, values))}; now {_one_line(after)})")


def acknowledge_arguments(comment: str) -> Arguments:
    """Acknowledge's (EventId ByteString, Comment LocalizedText), the EventId the latest read."""

    def arguments(d: AlarmDefinition, values: Mapping[str, Any]) -> tuple[list[ua.Variant], str]:
        event_id = values.get(child(d.name, "EventId"))
        raw = event_id if isinstance(event_id, bytes) else b""
        variants = [
            ua.Variant(raw, ua.VariantType.ByteString),
            ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
        ]
        return variants, f"EventId {raw.hex() or '?'}, {comment!r}"

    return arguments


@stack_command
def ack(
    name: Annotated[str, typer.Argument(help="Condition, e.g. T1Level (see tankctl alarms --all).")],
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
