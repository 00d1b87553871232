"""The HistoryRead service over a :class:`~historian.store.base.HistoryStore` (OPC UA Part 11).

:class:`HistoryReadService` takes a ``ua.HistoryReadParameters`` (the details, the
``HistoryReadValueId`` list, TimestampsToReturn, ReleaseContinuationPoints) and returns the
``ua.HistoryReadResult`` list, one per node, never raising for a client's bad input:

* ``ReadRawModifiedDetails``: raw values (:func:`tanklab.history.raw.plan_raw`: start inclusive,
  start > end reads newest first, two of start/end/NumValuesPerNode, bounds), a page at a time;
  ReadModified returns an empty ``HistoryModifiedData`` (Good_NoData): history is never modified.
* ``ReadProcessedDetails``: Part 13 aggregates (:mod:`tanklab.history.aggregates`) by the
  aggregate function's NodeId (``i=2342`` Average...), one per node or one for all.
* ``ReadAtTimeDetails``: the interpolated bounding value at each requested time (simple bounds,
  i.e. stepped, with ``UseSimpleBounds``).
* ``ReadEventDetails`` on the Server object (every event) or on a recorded object (its events
  and those of its children by SourceName): the where-clause may be an ``OfType`` (with the
  type's subtypes; BaseEventType: any), ``EventType InList`` literals (what asyncua's clients
  send), ``GreaterThanOrEqual``/``GreaterThan`` on ``Severity``, ``And`` of those and ``Or`` of
  type filters; the select clauses' fields are returned in their order.

Codes (operation level): Bad_NodeIdUnknown (no tag for the NodeId), Bad_AggregateNotSupported,
Bad_AggregateListMismatch, Bad_InvalidTimestampArgument (Part 11's time-domain rules),
Bad_InvalidArgument (negative processing interval), Bad_ContinuationPointInvalid (unknown,
evicted, released or another node's), Bad_TimestampsToReturnInvalid (Neither),
Bad_TimestampNotSupported (Server: only source timestamps are recorded),
Bad_EventFilterInvalid / Bad_FilterOperatorUnsupported (a where-clause it cannot evaluate),
Good_NoData (nothing in the range). HistoryUpdate: Bad_HistoryOperationUnsupported for every
item (nobody may update history).

**Continuation points** are 16 random bytes naming a server-side state in a bounded table
(``max_continuation_points``, oldest evicted first: a client holding an evicted one gets
Bad_ContinuationPointInvalid, Part 11, 6.3). A response carries at most ``max_values`` values per
node; NumValuesPerNode with both times given is the page size, with one time the total.

The service is synchronous (the stores are); :func:`install_history_read` runs it on an asyncua
server in one worker thread.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import secrets
from collections import OrderedDict
from collections.abc import Callable, Collection, Iterable, Iterator
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

from asyncua import Server, ua
from asyncua.ua.ua_binary import struct_to_binary

from historian.store.base import EventCursor, HistoryStore
from historian.ua_encode import datavalue_bytes, history_data_extension_object
from tanklab.history.aggregates import AGGREGATES, aggregate, interpolated_value
from tanklab.history.intervals import intervals
from tanklab.history.model import EventRecord, Sample, Value
from tanklab.history.raw import HistoryArgumentError, RawPlan, plan_processed, plan_raw
from tanklab.history.status import (
    BAD_AGGREGATE_NOT_SUPPORTED,
    BAD_BOUND_NOT_FOUND,
    BAD_CONTINUATION_POINT_INVALID,
    BAD_HISTORY_OPERATION_UNSUPPORTED,
    BAD_INVALID_ARGUMENT,
    BAD_INVALID_TIMESTAMP_ARGUMENT,
    BAD_NODE_ID_UNKNOWN,
    GOOD,
    GOOD_NO_DATA,
    AggregateConfig,
)

__all__ = [
    "AGGREGATE_NODE_IDS",
    "HistoryReadService",
    "install_history_read",
    "site_source_mapper",
    "site_tag_mapper",
]

_log = logging.getLogger(__name__)

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
BAD_AGGREGATE_LIST_MISMATCH = 0x80D4_0000
BAD_EVENT_FILTER_INVALID = 0x8047_0000
BAD_FILTER_OPERATOR_UNSUPPORTED = 0x80C2_0000
BAD_TIMESTAMP_NOT_SUPPORTED = 0x80A1_0000
BAD_TIMESTAMPS_TO_RETURN_INVALID = 0x802B_0000

AGGREGATE_NODE_IDS: dict[int, str] = {
    getattr(ua.ObjectIds, f"AggregateFunction_{name}"): name for name in AGGREGATES
}
"""The aggregate functions' NodeIds (namespace 0) -> the kernel's aggregate names."""

_BASE_EVENT_TYPE = "i=2041"
_READ_CHUNK = 50_000
"""Store page while gathering a processed read's samples."""

TagMapper = Callable[[ua.NodeId], str | None]


def _us(dt: datetime | None) -> int | None:
    """A request's UtcTime [us], ``None`` when unspecified (DateTime.MinValue, 1601)."""
    if dt is None:
        return None
    ticks = ua.datetime_to_win_epoch(dt)
    if ticks <= 0:
        return None
    return (ticks - 116_444_736_000_000_000) // 10


def _dt(t_us: int) -> datetime:
    return _EPOCH + timedelta(microseconds=t_us)


def _variant(value: Value) -> ua.Variant:
    if value is None:
        return ua.Variant()
    if isinstance(value, bool):
        return ua.Variant(value, ua.VariantType.Boolean)
    if isinstance(value, float):
        return ua.Variant(value, ua.VariantType.Double)
    if isinstance(value, int):
        vt = ua.VariantType.Int32 if -(2**31) <= value < 2**31 else ua.VariantType.Int64
        return ua.Variant(value, vt)
    return ua.Variant(value, ua.VariantType.String)


def _datavalue(s: Sample) -> ua.DataValue:
    return ua.DataValue(
        Value=_variant(s.value), StatusCode=ua.StatusCode(s.status), SourceTimestamp=_dt(s.t_us)
    )


def _fit(sizes: Iterable[int], budget: int, *, at_least: int = 1) -> int:
    """How many leading items of a page to send: the most whose encoded ``sizes`` [bytes], with
    the list's Int32 length, stay within ``budget``; never fewer than ``at_least`` (a page always
    makes progress, and a start bound stays with its first value)."""
    used, count = 4, 0
    for size in sizes:
        used += size
        if used > budget and count >= at_least:
            break
        count += 1
    return count


def _event_fields_bytes(fields: ua.HistoryEventFieldList) -> int:
    return len(struct_to_binary(fields))


def _result(status: int, data: Any = None, cp: bytes | None = None) -> ua.HistoryReadResult:
    r = ua.HistoryReadResult()
    r.StatusCode = ua.StatusCode(status)
    r.ContinuationPoint = cp
    if data is not None:
        r.HistoryData = data
    return r


def _history_data(samples: list[Sample], binary: bool = False) -> ua.HistoryData | ua.ExtensionObject:
    if binary:
        return history_data_extension_object(samples)
    d = ua.HistoryData()
    d.DataValues = [_datavalue(s) for s in samples]
    return d


class _ReadError(Exception):
    def __init__(self, status: int, message: str = "") -> None:
        super().__init__(message)
        self.status = status


@dataclass
class _RawState:
    node: ua.NodeId
    tag: str
    plan: RawPlan
    total: int | None
    returned: int = 0
    after_us: int | None = None


@dataclass
class _ListState:
    """A processed or at-time read's remaining results."""

    node: ua.NodeId
    rest: list[Sample]


@dataclass
class _EventState:
    node: ua.NodeId
    start_us: int
    end_us: int
    total: int | None
    types: frozenset[str] | None
    min_severity: int
    source: str | None
    select: list[list[str]]
    page: int | None
    returned: int = 0
    after: EventCursor | None = None


@dataclass
class _EventFilter:
    types: frozenset[str] | None = None
    min_severity: int = 0


def site_source_mapper(namespace_index: int) -> TagMapper:
    """NodeId -> SourceName for event reads: any string NodeId in the site namespace
    (``ns=<urn:tanklab>;s=PLC.T1`` reads the events of ``PLC.T1`` and ``PLC.T1.*``)."""

    def source_for(node: ua.NodeId) -> str | None:
        if node.NamespaceIndex != namespace_index or not isinstance(node.Identifier, str):
            return None
        return node.Identifier

    return source_for


def site_tag_mapper(store: HistoryStore, namespace_index: int) -> TagMapper:
    """NodeId -> tag for the historian's mirror of the tiers: a string NodeId in the site
    namespace (``ns=<urn:tanklab>;s=PLC.LIC1.PV``) whose tag the store holds; anything else is
    ``None`` (Bad_NodeIdUnknown). The store's tags are listed again when a name is not known, so
    a tag recorded after the server started is found."""
    known: set[str] = set()

    def tag_for(node: ua.NodeId) -> str | None:
        if node.NamespaceIndex != namespace_index or not isinstance(node.Identifier, str):
            return None
        name = node.Identifier
        if name not in known:
            known.update(t.tag for t in store.tags())
        return name if name in known else None

    return tag_for


@dataclass
class HistoryReadService:
    """Part 11 HistoryRead over one store (see the module docstring).

    ``tag_for_nodeid`` maps a requested NodeId to its tag (``None``: not recorded);
    ``event_subtypes`` maps an event type NodeId string (``i=2041``) to itself and its subtypes
    (default: only itself); ``stepped_tags`` are read as stepped (enumerations and flags step
    whatever this says).
    """

    store: HistoryStore
    tag_for_nodeid: TagMapper
    max_values: int = 100_000
    max_continuation_points: int = 100
    config: AggregateConfig = field(default_factory=AggregateConfig)
    event_subtypes: Callable[[str], Collection[str]] | None = None
    stepped_tags: frozenset[str] = frozenset()
    source_for_nodeid: TagMapper | None = None
    """NodeId of an event notifier -> the SourceName it stands for (its events and those below
    it); default :attr:`tag_for_nodeid`. The Server object always reads every event."""
    max_response_bytes: int = 196_608
    """Bound of the encoded results of one response, shared equally by its nodes [bytes]: a
    page stops early (with a continuation point) where the next value or event would pass its
    node's share. The tiers' servers send at most ``Limits.message_bytes`` (262,140 bytes, four
    64 KiB chunks) per message; the rest is the response header, the per-node result fields and
    the chunks' security overhead. A page holds at least one value or event, whatever its size."""
    binary: bool = False
    """Return HistoryData pre-encoded (:mod:`historian.ua_encode`): what a server sends; the
    objects (``False``) are for callers that read the results in Python."""
    _cps: OrderedDict[bytes, _RawState | _ListState | _EventState] = field(default_factory=OrderedDict)

    # --- entry points -------------------------------------------------------------------

    def read(self, params: ua.HistoryReadParameters) -> list[ua.HistoryReadResult]:
        """One result per ``params.NodesToRead`` item."""
        details = params.HistoryReadDetails
        nodes = list(params.NodesToRead)
        if params.ReleaseContinuationPoints:
            for rv in nodes:
                if rv.ContinuationPoint:
                    self._cps.pop(bytes(rv.ContinuationPoint), None)
            return [_result(GOOD) for _ in nodes]
        ts = params.TimestampsToReturn
        if ts in (ua.TimestampsToReturn.Neither, ua.TimestampsToReturn.Invalid):
            return [_result(BAD_TIMESTAMPS_TO_RETURN_INVALID) for _ in nodes]
        if ts == ua.TimestampsToReturn.Server:
            return [_result(BAD_TIMESTAMP_NOT_SUPPORTED) for _ in nodes]
        out = []
        budget = self.max_response_bytes // len(nodes) if nodes else 0
        for i, rv in enumerate(nodes):
            try:
                out.append(self._read_one(details, rv, i, len(nodes), budget))
            except (_ReadError, HistoryArgumentError) as e:
                _log.info("HistoryRead of %s: %s (0x%08X)", rv.NodeId, e, e.status)
                out.append(_result(e.status))
        return out

    def update(self, params: ua.HistoryUpdateParameters) -> list[ua.HistoryUpdateResult]:
        """Nobody may update history: Bad_HistoryOperationUnsupported for every item."""
        results = []
        for _ in params.HistoryUpdateDetails:
            r = ua.HistoryUpdateResult()
            r.StatusCode = ua.StatusCode(BAD_HISTORY_OPERATION_UNSUPPORTED)
            results.append(r)
        return results

    def continuation_points(self) -> int:
        """How many continuation points are held."""
        return len(self._cps)

    # --- dispatch -----------------------------------------------------------------------

    def _read_one(
        self, details: Any, rv: ua.HistoryReadValueId, index: int, count: int, budget: int
    ) -> ua.HistoryReadResult:
        """One node's result; ``budget`` bounds its encoded values or events [bytes]."""
        if rv.ContinuationPoint:
            return self._resume(bytes(rv.ContinuationPoint), rv.NodeId, details, budget)
        if isinstance(details, ua.ReadRawModifiedDetails):
            return self._raw(details, rv.NodeId, budget)
        if isinstance(details, ua.ReadProcessedDetails):
            return self._processed(details, rv.NodeId, index, count, budget)
        if isinstance(details, ua.ReadAtTimeDetails):
            return self._at_time(details, rv.NodeId, budget)
        if isinstance(details, ua.ReadEventDetails):
            return self._events(details, rv.NodeId, budget)
        raise _ReadError(BAD_HISTORY_OPERATION_UNSUPPORTED, f"{type(details).__name__} is not supported")

    def _tag(self, node: ua.NodeId) -> str:
        tag = self.tag_for_nodeid(node)
        if tag is None:
            raise _ReadError(BAD_NODE_ID_UNKNOWN, "no history for this node")
        return tag

    def _keep(self, state: _RawState | _ListState | _EventState) -> bytes:
        token = secrets.token_bytes(16)
        self._cps[token] = state
        while len(self._cps) > self.max_continuation_points:
            self._cps.popitem(last=False)
        return token

    def _resume(self, token: bytes, node: ua.NodeId, details: Any, budget: int) -> ua.HistoryReadResult:
        state = self._cps.pop(token, None)
        if state is None or state.node != node:
            raise _ReadError(BAD_CONTINUATION_POINT_INVALID, "unknown continuation point")
        if isinstance(state, _RawState):
            if not isinstance(details, ua.ReadRawModifiedDetails):
                raise _ReadError(BAD_CONTINUATION_POINT_INVALID, "continuation point of another read")
            return self._raw_page(state, budget, first=False)
        if isinstance(state, _EventState):
            if not isinstance(details, ua.ReadEventDetails):
                raise _ReadError(BAD_CONTINUATION_POINT_INVALID, "continuation point of another read")
            return self._event_page(state, budget)
        if isinstance(details, ua.ReadRawModifiedDetails | ua.ReadEventDetails):
            raise _ReadError(BAD_CONTINUATION_POINT_INVALID, "continuation point of another read")
        return self._list_page(state, budget)

    # --- raw ----------------------------------------------------------------------------

    def _raw(self, d: ua.ReadRawModifiedDetails, node: ua.NodeId, budget: int) -> ua.HistoryReadResult:
        tag = self._tag(node)
        start, end = _us(d.StartTime), _us(d.EndTime)
        plan = plan_raw(start, end, int(d.NumValuesPerNode), bool(d.ReturnBounds))
        if d.IsReadModified:
            return _result(GOOD_NO_DATA, ua.HistoryModifiedData())
        one_time = start is None or end is None
        state = _RawState(node, tag, plan, plan.limit if one_time else None)
        return self._raw_page(state, budget, first=True)

    def _raw_page(self, st: _RawState, budget: int, *, first: bool) -> ua.HistoryReadResult:
        plan = st.plan
        out: list[Sample] = []
        if first and plan.start_bound:
            b = self._bound(st.tag, plan.start_us, before=not plan.reverse)
            if b is None or b.t_us != plan.start_us:
                out.append(b or Sample(plan.start_us, None, BAD_BOUND_NOT_FOUND))
        page = self.max_values if plan.limit is None else min(plan.limit, self.max_values)
        if st.total is not None:
            page = min(page, st.total - st.returned)
        got = self.store.read_raw(st.tag, plan.start_us, plan.end_us, limit=page, after_us=st.after_us)
        final = got.cursor is None or (st.total is not None and st.returned + len(got.samples) >= st.total)
        end: list[Sample] = []
        if final and plan.end_bound and plan.start_us != plan.end_us:
            b = self._bound(st.tag, plan.end_us, before=plan.reverse)
            end.append(b or Sample(plan.end_us, None, BAD_BOUND_NOT_FOUND))
        # what fits the budget; at least one value or bound beyond a start bound (progress)
        items = out + got.samples + end
        keep = _fit(map(datavalue_bytes, items), budget, at_least=len(out) + 1)
        samples = got.samples[: keep - len(out)]
        out += samples
        st.returned += len(samples)
        if keep < len(items):  # cut short: the rest (and the end bound) on the next page
            st.after_us = samples[-1].t_us
            return _result(GOOD, _history_data(out, self.binary), self._keep(st))
        if not final:
            st.after_us = got.cursor
            return _result(GOOD, _history_data(out, self.binary), self._keep(st))
        out += end
        return _result(GOOD if out else GOOD_NO_DATA, _history_data(out, self.binary))

    def _bound(self, tag: str, t_us: int, *, before: bool) -> Sample | None:
        b = self.store.bounds(tag, t_us)
        return b.before if before else b.after

    # --- processed and at-time ------------------------------------------------------------

    def _config(self, tag: str, c: ua.AggregateConfiguration | None) -> AggregateConfig:
        base = self.config
        stepped = base.stepped or tag in self.stepped_tags
        if c is None or c.UseServerCapabilitiesDefaults:
            return AggregateConfig(
                base.treat_uncertain_as_bad, base.percent_data_bad, base.percent_data_good, False, stepped
            )
        try:
            return AggregateConfig(
                bool(c.TreatUncertainAsBad), int(c.PercentDataBad), int(c.PercentDataGood), False, stepped
            )
        except ValueError as e:
            raise _ReadError(BAD_INVALID_ARGUMENT, str(e)) from e

    def _gather(self, tag: str, lo_us: int, hi_us: int) -> list[Sample]:
        """Every sample in ``[lo, hi]`` with the raw and the Good bounds beyond both ends."""
        rows: list[Sample] = []
        after: int | None = None
        while True:
            page = self.store.read_raw(tag, lo_us, hi_us + 1, limit=_READ_CHUNK, after_us=after)
            rows += page.samples
            if page.cursor is None:
                break
            after = page.cursor
        extra: dict[int, Sample] = {}
        for t, good in ((lo_us, False), (lo_us, True), (hi_us, False), (hi_us, True)):
            b = self.store.bounds(tag, t, good_only=good)
            for s in (b.before, b.after):
                if s is not None:
                    extra[s.t_us] = s
        for s in rows:
            extra.pop(s.t_us, None)
        return sorted([*rows, *extra.values()], key=lambda s: s.t_us)

    def _processed(
        self, d: ua.ReadProcessedDetails, node: ua.NodeId, index: int, count: int, budget: int
    ) -> ua.HistoryReadResult:
        tag = self._tag(node)
        types = list(d.AggregateType)
        if len(types) not in (1, count):
            raise _ReadError(BAD_AGGREGATE_LIST_MISMATCH, f"{len(types)} aggregates for {count} nodes")
        agg = types[0] if len(types) == 1 else types[index]
        name = AGGREGATE_NODE_IDS.get(agg.Identifier) if agg.NamespaceIndex == 0 else None
        if name is None or not isinstance(agg.Identifier, int):
            raise _ReadError(BAD_AGGREGATE_NOT_SUPPORTED, f"aggregate {agg}")
        start, end, p_us = plan_processed(_us(d.StartTime), _us(d.EndTime), float(d.ProcessingInterval))
        try:
            ivs = intervals(start, end, p_us)
        except ValueError as e:
            raise _ReadError(BAD_INVALID_ARGUMENT, str(e)) from e
        cfg = self._config(tag, d.AggregateConfiguration)
        samples = self._gather(tag, min(start, end), max(start, end))
        return self._list_page(_ListState(node, aggregate(name, samples, ivs, cfg)), budget)

    def _at_time(self, d: ua.ReadAtTimeDetails, node: ua.NodeId, budget: int) -> ua.HistoryReadResult:
        tag = self._tag(node)
        times = [_us(t) for t in d.ReqTimes]
        if any(t is None for t in times):
            raise _ReadError(BAD_INVALID_TIMESTAMP_ARGUMENT, "a requested time is unspecified")
        cfg = self._config(tag, None)
        if d.UseSimpleBounds:
            cfg = dataclasses.replace(cfg, stepped=True)
        out = []
        for t in times:
            assert t is not None
            out.append(interpolated_value(self._gather(tag, t, t), t, cfg))
        return self._list_page(_ListState(node, out), budget)

    def _list_page(self, st: _ListState, budget: int) -> ua.HistoryReadResult:
        head = st.rest[: self.max_values]
        keep = _fit(map(datavalue_bytes, head), budget)
        now, st.rest = st.rest[:keep], st.rest[keep:]
        cp = self._keep(st) if st.rest else None
        return _result(GOOD if now else GOOD_NO_DATA, _history_data(now, self.binary), cp)

    # --- events -----------------------------------------------------------------------------

    def _events(self, d: ua.ReadEventDetails, node: ua.NodeId, budget: int) -> ua.HistoryReadResult:
        if node == ua.NodeId(ua.ObjectIds.Server):
            source = None
        else:
            mapper = self.source_for_nodeid or self.tag_for_nodeid
            source = mapper(node)
            if source is None:
                raise _ReadError(BAD_NODE_ID_UNKNOWN, "no event history for this node")
        start, end = _us(d.StartTime), _us(d.EndTime)
        plan = plan_raw(start, end, int(d.NumValuesPerNode), False)
        flt = self._where(d.Filter.WhereClause)
        select = [[q.Name for q in op.BrowsePath] for op in d.Filter.SelectClauses]
        total = plan.limit if start is None or end is None else None
        st = _EventState(
            node, plan.start_us, plan.end_us, total, flt.types, flt.min_severity, source, select, plan.limit
        )
        return self._event_page(st, budget)

    def _event_page(self, st: _EventState, budget: int) -> ua.HistoryReadResult:
        limit = self.max_values if st.page is None else min(st.page, self.max_values)
        if st.total is not None:
            limit = min(limit, st.total - st.returned)
        events: list[EventRecord] = []
        cursor = st.after
        more = False
        # a source filter is applied here, so read until the page is full or the range ends
        while len(events) < limit:
            page = self.store.read_events(
                st.start_us,
                st.end_us,
                limit=limit - len(events),
                event_types=st.types,
                min_severity=st.min_severity,
                after=cursor,
            )
            events += [e for e in page.events if _from_source(e, st.source)]
            cursor = page.cursor
            if cursor is None:
                break
        fields = [self._fields(e, st.select) for e in events]
        keep = _fit(map(_event_fields_bytes, fields), budget)
        if keep < len(events):
            events, fields = events[:keep], fields[:keep]
            cursor = (events[-1].t_us, events[-1].event_id)
        more = cursor is not None
        st.returned += len(events)
        if st.total is not None and st.returned >= st.total:
            more = False
        data = ua.HistoryEvent()
        data.Events = fields
        if more:
            st.after = cursor
            return _result(GOOD, data, self._keep(st))
        return _result(GOOD if events else GOOD_NO_DATA, data)

    def _fields(self, e: EventRecord, select: list[list[str]]) -> ua.HistoryEventFieldList:
        fl = ua.HistoryEventFieldList()
        fl.EventFields = [_event_field(e, path) for path in select]
        return fl

    def _where(self, where: ua.ContentFilter) -> _EventFilter:
        elements = list(where.Elements)
        if not elements:
            return _EventFilter()
        return self._element(elements, 0, set())

    def _element(self, elements: list[ua.ContentFilterElement], i: int, seen: set[int]) -> _EventFilter:
        if i in seen or not 0 <= i < len(elements):
            raise _ReadError(BAD_EVENT_FILTER_INVALID, f"element {i}")
        seen = seen | {i}
        el = elements[i]
        ops = list(el.FilterOperands)
        op = el.FilterOperator
        if op == ua.FilterOperator.OfType:
            if len(ops) != 1 or not isinstance(ops[0], ua.LiteralOperand):
                raise _ReadError(BAD_EVENT_FILTER_INVALID, "OfType takes one NodeId literal")
            return _EventFilter(types=_any_type(self._subtypes(ops[0].Value.Value)))
        if op == ua.FilterOperator.InList:
            # asyncua's clients send EventType InList [the types and their subtypes]
            if (
                len(ops) < 2
                or not isinstance(ops[0], ua.SimpleAttributeOperand)
                or [q.Name for q in ops[0].BrowsePath] != ["EventType"]
                or not all(isinstance(o, ua.LiteralOperand) for o in ops[1:])
            ):
                raise _ReadError(BAD_FILTER_OPERATOR_UNSUPPORTED, "only EventType InList literals")
            return _EventFilter(
                types=_any_type(set().union(*(self._subtypes(o.Value.Value) for o in ops[1:])))
            )
        if op in (ua.FilterOperator.GreaterThanOrEqual, ua.FilterOperator.GreaterThan):
            if (
                len(ops) != 2
                or not isinstance(ops[0], ua.SimpleAttributeOperand)
                or [q.Name for q in ops[0].BrowsePath] != ["Severity"]
                or not isinstance(ops[1], ua.LiteralOperand)
            ):
                raise _ReadError(BAD_FILTER_OPERATOR_UNSUPPORTED, "only Severity >= / > a literal")
            try:
                n = int(ops[1].Value.Value)
            except (TypeError, ValueError) as e:
                raise _ReadError(BAD_EVENT_FILTER_INVALID, "severity literal") from e
            return _EventFilter(min_severity=n + (op == ua.FilterOperator.GreaterThan))
        if op in (ua.FilterOperator.And, ua.FilterOperator.Or):
            if len(ops) != 2 or not all(isinstance(o, ua.ElementOperand) for o in ops):
                raise _ReadError(BAD_EVENT_FILTER_INVALID, "And/Or take two element operands")
            a, b = (self._element(elements, o.Index, seen) for o in ops)
            if op == ua.FilterOperator.And:
                types = a.types if b.types is None else b.types if a.types is None else a.types & b.types
                return _EventFilter(types, max(a.min_severity, b.min_severity))
            if a.types is None or b.types is None or a.min_severity or b.min_severity:
                raise _ReadError(BAD_FILTER_OPERATOR_UNSUPPORTED, "Or only of OfType elements")
            return _EventFilter(a.types | b.types)
        raise _ReadError(BAD_FILTER_OPERATOR_UNSUPPORTED, f"filter operator {op}")

    def _subtypes(self, type_id: object) -> Collection[str]:
        if not isinstance(type_id, ua.NodeId):
            raise _ReadError(BAD_EVENT_FILTER_INVALID, "OfType needs a NodeId")
        s = type_id.to_string()
        if self.event_subtypes is None:
            return {s}
        return self.event_subtypes(s)


def _any_type(types: Collection[str]) -> frozenset[str] | None:
    """BaseEventType among the types matches every event (whatever its type's namespace)."""
    return None if _BASE_EVENT_TYPE in types else frozenset(types)


def _from_source(e: EventRecord, source: str | None) -> bool:
    return source is None or e.source == source or e.source.startswith(source + ".")


def _event_field(e: EventRecord, path: list[str]) -> ua.Variant:
    key = "/".join(path)
    if key == "EventId":
        return ua.Variant(e.event_id, ua.VariantType.ByteString)
    if key == "EventType":
        return ua.Variant(ua.NodeId.from_string(e.event_type), ua.VariantType.NodeId)
    if key == "SourceName":
        return ua.Variant(e.source, ua.VariantType.String)
    if key in ("Time", "ReceiveTime"):
        return ua.Variant(_dt(e.t_us), ua.VariantType.DateTime)
    if key == "Severity":
        return ua.Variant(e.severity, ua.VariantType.UInt16)
    if key == "Message":
        return ua.Variant(ua.LocalizedText(e.message), ua.VariantType.LocalizedText)
    value = e.fields.get(key)
    if isinstance(value, bool | int | float | str):
        return _variant(value)
    return ua.Variant() if value is None else ua.Variant(str(value), ua.VariantType.String)


def _aspace_subtypes(server: Server) -> Callable[[str], Collection[str]]:
    """An event type and its subtypes, from the server's address space (HasSubtype, cached)."""
    cache: dict[str, frozenset[str]] = {}
    has_subtype = ua.NodeId(ua.ObjectIds.HasSubtype)

    def walk(root: ua.NodeId) -> Iterator[ua.NodeId]:
        todo, seen = [root], {root}
        while todo:
            n = todo.pop()
            yield n
            data = server.iserver.aspace.get(n)
            for ref in [] if data is None else data.references:
                if ref.IsForward and ref.ReferenceTypeId == has_subtype and ref.NodeId not in seen:
                    seen.add(ref.NodeId)
                    todo.append(ref.NodeId)

    def subtypes(type_id: str) -> Collection[str]:
        if type_id not in cache:
            cache[type_id] = frozenset(n.to_string() for n in walk(ua.NodeId.from_string(type_id)))
        return cache[type_id]

    return subtypes


def install_history_read(
    server: Server,
    store: HistoryStore,
    tag_for_nodeid: TagMapper,
    *,
    executor: Executor | None = None,
    **options: Any,
) -> HistoryReadService:
    """Serve HistoryRead of ``server`` (every details kind) from ``store``, HistoryUpdate refused.

    asyncua routes a session's HistoryRead to ``server.iserver.history_manager.read_history``
    (and HistoryUpdate to its ``update_history``); both are replaced on that instance. Reads run
    in ``executor``: pass the single worker thread that owns the store, so that reads and the
    collector's writes never use its connection at once (default: a private one-thread pool).
    ``options`` go to :class:`HistoryReadService` (``max_values``, ``config``...); event types'
    subtypes come from the server's address space unless ``event_subtypes`` is given, and the
    HistoryData is pre-encoded in the worker thread (``binary``) unless ``binary=False``.
    """
    options.setdefault("event_subtypes", _aspace_subtypes(server))
    options.setdefault("binary", True)
    service = HistoryReadService(store, tag_for_nodeid, **options)
    pool = executor or ThreadPoolExecutor(max_workers=1, thread_name_prefix="history-read")
    manager = server.iserver.history_manager

    async def read_history(params: ua.HistoryReadParameters) -> list[ua.HistoryReadResult]:
        return await asyncio.get_running_loop().run_in_executor(pool, service.read, params)

    manager.read_history = read_history
    manager.update_history = service.update
    if executor is None:
        stop = manager.stop

        async def stop_and_release() -> None:
            await stop()
            pool.shutdown(wait=False, cancel_futures=True)

        manager.stop = stop_and_release
    return service
