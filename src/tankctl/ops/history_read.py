"""Reading the historian's history for ``tankctl history`` and ``tankctl alarms --history``
(issue 16): time and interval arguments, the aggregates by their CLI names, and the HistoryRead
calls over one connected client, following continuation points to the end.

The historian mirrors the tiers' NodeIds (``ns=<urn:tanklab>;s=PLC.LIC1.PV``,
docs/historian.md), so a tag here is a tier's dotted path. Raw reads are
``ReadRawModifiedDetails`` without bounds (every recorded sample in [from, to], status and source
time as recorded, gap markers included); processed reads are ``ReadProcessedDetails`` with one
aggregate and a processing interval (Part 13: one value per interval starting at ``from``);
event reads are ``ReadEventDetails`` on the Server object, the select clauses of
:data:`EVENT_FIELDS`, optionally where Severity >= a minimum.

Times on the command line: ISO 8601 (a time without an offset is UTC, as every tanklab time),
``now``, or relative to now: ``-15m``, ``-2h``, ``-1d``, ``-30s``. :func:`parse_time` takes
``now`` as an argument (no clock read in pure code); the command passes the wall clock.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta

from asyncua import Client, ua

from tankctl.ops.errors import UsageError
from tanklab_io import ua_history
from tanklab_io.ua_history import (
    EVENT_FIELDS,
    EventRow,
    HistoryReadError,
    HistoryRow,
    read_event_history,
)

__all__ = [
    "AGGREGATES",
    "EVENT_FIELDS",
    "EventRow",
    "HistoryReadError",
    "HistoryRow",
    "aggregate_id",
    "parse_span_s",
    "parse_time",
    "read_event_history",
    "read_tag_history",
]

AGGREGATES: dict[str, int] = {
    "avg": ua.ObjectIds.AggregateFunction_Average,
    "timeavg": ua.ObjectIds.AggregateFunction_TimeAverage,
    "min": ua.ObjectIds.AggregateFunction_Minimum,
    "max": ua.ObjectIds.AggregateFunction_Maximum,
    "count": ua.ObjectIds.AggregateFunction_Count,
    "interp": ua.ObjectIds.AggregateFunction_Interpolative,
    "start": ua.ObjectIds.AggregateFunction_Start,
    "end": ua.ObjectIds.AggregateFunction_End,
    "total": ua.ObjectIds.AggregateFunction_Total,
    "delta": ua.ObjectIds.AggregateFunction_Delta,
}
"""The CLI's aggregate names and the Part 13 AggregateFunction they ask for."""

_UNITS_S = {"ms": 0.001, "s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0, "d": 86400.0}
_SPAN = re.compile(r"^(\d+(?:\.\d+)?)(ms|s|min|m|h|d)$")


def parse_span_s(text: str, what: str) -> float:
    """A positive span like ``60s``, ``500ms``, ``5m``, ``2h``, ``1d`` [s]."""
    match = _SPAN.match(text.strip())
    if match is None or float(match.group(1)) <= 0.0:
        raise UsageError(f"{what} {text!r}: give a positive number with a unit (500ms, 60s, 5m, 2h, 1d)")
    return float(match.group(1)) * _UNITS_S[match.group(2)]


def parse_time(text: str, now: datetime, what: str) -> datetime:
    """``text`` as an aware UTC time: ISO 8601 (no offset: UTC), ``now``, or ``-<span>``."""
    text = text.strip()
    if text == "now":
        return now.astimezone(UTC)
    if text.startswith("-"):
        try:
            return now.astimezone(UTC) - timedelta(seconds=parse_span_s(text[1:], what))
        except OverflowError:
            raise UsageError(f"{what} {text!r}: before the year 1") from None
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise UsageError(
            f"{what} {text!r}: give an ISO 8601 time (2026-12-03T08:00:00), 'now' or -15m / -2h / -1d"
        ) from None
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


def aggregate_id(name: str) -> ua.NodeId:
    """The AggregateFunction NodeId of a CLI aggregate name."""
    if name not in AGGREGATES:
        raise UsageError(f"aggregate {name!r}: one of {', '.join(AGGREGATES)}")
    return ua.NodeId(AGGREGATES[name])


async def read_tag_history(
    client: Client,
    ns: int,
    tag: str,
    start: datetime,
    end: datetime,
    *,
    aggregate: str | None = None,
    interval_s: float | None = None,
) -> list[HistoryRow]:
    """``tag``'s history in [start, end]: raw, or one ``aggregate`` (a CLI name) per ``interval_s``."""
    node = aggregate_id(aggregate) if aggregate is not None else None
    return await ua_history.read_tag_history(
        client, ns, tag, start, end, aggregate=node, interval_s=interval_s
    )
