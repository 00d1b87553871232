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
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from asyncua import Client, ua

from tankctl.ops.errors import UsageError
from tanklab.errors import TanklabError

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

EVENT_FIELDS: tuple[str, ...] = ("Time", "EventType", "SourceName", "Severity", "Message", "EventId")
"""What ``alarms --history`` selects of every event (BaseEventType fields)."""

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


@dataclass(frozen=True)
class HistoryRow:
    """One value of a tag's history: its time (source time; an aggregate's interval start),
    the value (None when the server gave none), and the status code's name and number."""

    time: datetime
    value: Any
    status: str
    status_code: int

    def as_json(self, tag: str) -> dict[str, Any]:
        value = (
            self.value
            if isinstance(self.value, bool | int | float | str) or self.value is None
            else str(self.value)
        )
        return {
            "tag": tag,
            "time": self.time.isoformat(),
            "value": value,
            "status": self.status,
            "status_code": self.status_code,
        }


@dataclass(frozen=True)
class EventRow:
    """One recorded event: :data:`EVENT_FIELDS` as plain values."""

    time: datetime
    event_type: str
    source: str
    severity: int
    message: str
    event_id: str

    def as_json(self) -> dict[str, Any]:
        return {
            "time": self.time.isoformat(),
            "event_type": self.event_type,
            "source": self.source,
            "severity": self.severity,
            "message": self.message,
            "event_id": self.event_id,
        }


class HistoryReadError(TanklabError):
    """The historian refused a read: the tag and the status code's name."""

    def __init__(self, tag: str, status: ua.StatusCode) -> None:
        self.tag, self.status = tag, status
        super().__init__(f"history of {tag}: {status.name}")


def _row(dv: ua.DataValue) -> HistoryRow:
    status = dv.StatusCode if dv.StatusCode is not None else ua.StatusCode(ua.StatusCodes.Good)
    time = dv.SourceTimestamp or dv.ServerTimestamp
    assert time is not None, "the historian stamps every value"
    value = dv.Value.Value if dv.Value is not None else None
    return HistoryRow(
        time.replace(tzinfo=UTC) if time.tzinfo is None else time, value, status.name, status.value
    )


async def _pages(client: Client, details: Any, node: ua.NodeId, what: str) -> list[ua.HistoryData]:
    """Every page of one node's HistoryRead for ``details``, continuation points followed until
    the server has none left; a refused page raises :class:`HistoryReadError` naming ``what``."""
    pages: list[ua.HistoryData] = []
    point: bytes | None = None
    while True:
        params = ua.HistoryReadParameters()
        params.HistoryReadDetails = details
        params.TimestampsToReturn = ua.TimestampsToReturn.Both
        params.ReleaseContinuationPoints = False
        item = ua.HistoryReadValueId()
        item.NodeId = node
        item.ContinuationPoint = point
        params.NodesToRead = [item]
        (result,) = await client.uaclient.history_read(params)
        if not result.StatusCode.is_good():
            raise HistoryReadError(what, result.StatusCode)
        pages.append(result.HistoryData)
        point = result.ContinuationPoint or None
        if point is None:
            return pages


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
    """``tag``'s history in [start, end]: raw, or one ``aggregate`` per ``interval_s``."""
    node = ua.NodeId(tag, ns)
    details: Any
    if aggregate is None:
        details = ua.ReadRawModifiedDetails()
        details.IsReadModified = False
        details.StartTime, details.EndTime = start, end
        details.NumValuesPerNode = 0
        details.ReturnBounds = False
    else:
        assert interval_s is not None, "an aggregate needs its processing interval"
        details = ua.ReadProcessedDetails()
        details.StartTime, details.EndTime = start, end
        details.ProcessingInterval = interval_s * 1000.0
        details.AggregateType = [aggregate_id(aggregate)]
    return [_row(dv) for page in await _pages(client, details, node, tag) for dv in page.DataValues or []]


async def read_event_history(
    client: Client, start: datetime, end: datetime, *, min_severity: int = 0, limit: int = 0
) -> list[EventRow]:
    """The events recorded in [start, end] (the Server object's event history)."""
    details = ua.ReadEventDetails()
    details.StartTime, details.EndTime = start, end
    details.NumValuesPerNode = limit
    evfilter = ua.EventFilter()
    evfilter.SelectClauses = [_event_field(name) for name in EVENT_FIELDS]
    if min_severity > 0:
        element = ua.ContentFilterElement()
        element.FilterOperator = ua.FilterOperator.GreaterThanOrEqual
        element.FilterOperands = [
            _event_field("Severity"),
            ua.LiteralOperand(Value=ua.Variant(min_severity, ua.VariantType.UInt16)),
        ]
        evfilter.WhereClause.Elements.append(element)
    details.Filter = evfilter
    pages = await _pages(client, details, ua.NodeId(ua.ObjectIds.Server), "events")
    return [_event_row([f.Value for f in ev.EventFields]) for page in pages for ev in page.Events or []]


def _event_field(name: str) -> ua.SimpleAttributeOperand:
    """The BaseEventType field ``name`` (namespace 0) as a select or where-clause operand."""
    op = ua.SimpleAttributeOperand()
    op.TypeDefinitionId = ua.NodeId(ua.ObjectIds.BaseEventType)
    op.BrowsePath = [ua.QualifiedName(name, 0)]
    op.AttributeId = ua.AttributeIds.Value
    return op


def _event_row(fields: Sequence[Any]) -> EventRow:
    time, event_type, source, severity, message, event_id = fields
    text = message.Text if isinstance(message, ua.LocalizedText) else message
    return EventRow(
        time.replace(tzinfo=UTC) if time is not None and time.tzinfo is None else time,
        event_type.to_string() if isinstance(event_type, ua.NodeId) else str(event_type),
        str(source or ""),
        int(severity or 0),
        str(text or ""),
        event_id.hex() if isinstance(event_id, bytes) else str(event_id),
    )
