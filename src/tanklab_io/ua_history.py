"""The client side of the historian's HistoryRead (issue 16): raw, processed and event reads
over one connected client, following continuation points to the end.

The historian mirrors the tiers' NodeIds (``ns=<urn:tanklab>;s=PLC.LIC1.PV``,
docs/historian.md), so a tag here is a tier's dotted path. Raw reads are
``ReadRawModifiedDetails`` without bounds (every recorded sample in [start, end], status and
source time as recorded, gap markers included); processed reads are ``ReadProcessedDetails``
with one aggregate and a processing interval [s] (Part 13: one value per interval starting at
``start``); event reads are ``ReadEventDetails`` on the Server object, the select clauses of
:data:`EVENT_FIELDS`, optionally where Severity >= a minimum.

Shared by the operator commands (:mod:`tankctl.ops.history_read`: ``tankctl history``,
``tankctl alarms --history``) and the HMI's trends and alarm history (:mod:`hmi.hub`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from asyncua import Client, ua

from tanklab.errors import TanklabError

__all__ = [
    "EVENT_FIELDS",
    "EventRow",
    "HistoryReadError",
    "HistoryRow",
    "read_event_history",
    "read_tag_history",
]

EVENT_FIELDS: tuple[str, ...] = ("Time", "EventType", "SourceName", "Severity", "Message", "EventId")
"""What ``alarms --history`` selects of every event (BaseEventType fields)."""


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
    aggregate: ua.NodeId | None = None,
    interval_s: float | None = None,
) -> list[HistoryRow]:
    """``tag``'s history in [start, end]: raw, or one ``aggregate`` (an AggregateFunction's
    NodeId) per ``interval_s`` [s]."""
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
        details.AggregateType = [aggregate]
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
