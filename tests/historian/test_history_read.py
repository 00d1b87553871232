"""The HistoryRead service on both back ends (SQLite, a real PostgreSQL): raw reads with bounds,
reverse and continuation, processed reads against the kernel's hand-computed oracles, at-time,
events with a where-clause, and every bad input's Part 11 code.

The series is the kernel test's (tests/tanklab/test_history_aggregates.py) shifted to T0:
0 s: 10, 10 s: 20, 20 s: 30 Bad, 30 s: 40, 50 s: 60.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import extensionobject_from_binary, extensionobject_to_binary, struct_to_binary
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from historian.history_read import HistoryReadService, site_source_mapper, site_tag_mapper
from historian.store import HistoryStore
from tanklab.history.model import EventRecord, Sample

S = 1_000_000
T0 = 1_764_633_600_000_000  # 2025-12-02 00:00 UTC [us]
NS = 2
TAG = "PLC.LIC1.PV"
NODE = ua.NodeId(TAG, NS)
BAD = 0x8000_0000
SERIES = [
    Sample(T0, 10.0),
    Sample(T0 + 10 * S, 20.0),
    Sample(T0 + 20 * S, 30.0, BAD),
    Sample(T0 + 30 * S, 40.0),
    Sample(T0 + 50 * S, 60.0),
]
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
MIN_DATE = datetime(1601, 1, 1, tzinfo=UTC)


def dt(t_us: int) -> datetime:
    return EPOCH + timedelta(microseconds=t_us)


def us(d: datetime) -> int:
    return (d - EPOCH) // timedelta(microseconds=1)


def service(store: HistoryStore, **kw: object) -> HistoryReadService:
    store.append_samples({TAG: SERIES})
    return HistoryReadService(store, site_tag_mapper(store, NS), **kw)  # type: ignore[arg-type]


def params(
    details: object, *nodes: ua.NodeId, cps: list[bytes | None] | None = None
) -> ua.HistoryReadParameters:
    p = ua.HistoryReadParameters()
    p.HistoryReadDetails = details
    p.TimestampsToReturn = ua.TimestampsToReturn.Source
    p.ReleaseContinuationPoints = False  # asyncua's default is True
    for i, n in enumerate(nodes or (NODE,)):
        rv = ua.HistoryReadValueId()
        rv.NodeId = n
        rv.ContinuationPoint = None if cps is None else cps[i]
        p.NodesToRead.append(rv)
    return p


def raw(start: int | None, end: int | None, n: int = 0, bounds: bool = False) -> ua.ReadRawModifiedDetails:
    d = ua.ReadRawModifiedDetails()
    d.IsReadModified = False
    d.StartTime = MIN_DATE if start is None else dt(start)
    d.EndTime = MIN_DATE if end is None else dt(end)
    d.NumValuesPerNode = n
    d.ReturnBounds = bounds
    return d


def processed(name: str, start: int, end: int, interval_s: float) -> ua.ReadProcessedDetails:
    d = ua.ReadProcessedDetails()
    d.StartTime, d.EndTime = dt(start), dt(end)
    d.ProcessingInterval = interval_s * 1000.0
    d.AggregateType = [ua.NodeId(getattr(ua.ObjectIds, f"AggregateFunction_{name}"))]
    return d


def values(r: ua.HistoryReadResult) -> list[tuple[float, object, int]]:
    return [
        ((us(v.SourceTimestamp) - T0) / S, v.Value.Value, v.StatusCode.value)
        for v in r.HistoryData.DataValues
    ]


def read_all(svc: HistoryReadService, details: object) -> tuple[list[tuple[float, object, int]], int]:
    out, cp, calls = [], None, 0
    while True:
        (r,) = svc.read(params(details, cps=[cp]))
        calls += 1
        assert r.StatusCode.value in (0, 0x00A5_0000)
        out += values(r)
        cp = r.ContinuationPoint
        if not cp:
            return out, calls


def test_raw_forward_reverse_and_bounds(backend) -> None:
    svc = service(backend.open())
    (r,) = svc.read(params(raw(T0 + 5 * S, T0 + 30 * S)))
    # start inclusive, end exclusive: 10 s, 20 s (Bad, as recorded)
    assert values(r) == [(10.0, 20.0, 0), (20.0, 30.0, BAD)]
    (r,) = svc.read(params(raw(T0 + 5 * S, T0 + 30 * S, bounds=True)))
    # bounds: the value at or before 5 s, the value at or after 30 s
    assert values(r) == [(0.0, 10.0, 0), (10.0, 20.0, 0), (20.0, 30.0, BAD), (30.0, 40.0, 0)]
    (r,) = svc.read(params(raw(T0 + 30 * S, T0 + 5 * S, bounds=True)))
    # reverse: (5 s, 30 s] newest first; bounds: at or after 30 s (in range), at or before 5 s
    assert values(r) == [(30.0, 40.0, 0), (20.0, 30.0, BAD), (10.0, 20.0, 0), (0.0, 10.0, 0)]
    (r,) = svc.read(params(raw(T0 + 55 * S, T0 + 70 * S, bounds=True)))
    assert values(r) == [(50.0, 60.0, 0), (70.0, None, 0x80D7_0000)]  # Bad_BoundNotFound
    (r,) = svc.read(params(raw(T0 + 60 * S, T0 + 70 * S)))
    assert r.StatusCode.value == 0x00A5_0000 and values(r) == []  # Good_NoData


def test_one_time_and_num_values(backend) -> None:
    svc = service(backend.open())
    (r,) = svc.read(params(raw(T0 + 10 * S, None, n=2)))
    assert [v[0] for v in values(r)] == [10.0, 20.0] and not r.ContinuationPoint
    (r,) = svc.read(params(raw(None, T0 + 30 * S, n=2)))
    # end and numValuesPerNode: reverse from the end (inclusive)
    assert [v[0] for v in values(r)] == [30.0, 20.0] and not r.ContinuationPoint


def test_continuation_pages_and_release(backend) -> None:
    svc = service(backend.open(), max_values=2)
    got, calls = read_all(svc, raw(T0, T0 + 60 * S))
    assert [v[0] for v in got] == [0.0, 10.0, 20.0, 30.0, 50.0] and calls == 3
    assert svc.continuation_points() == 0
    (r,) = svc.read(params(raw(T0, T0 + 60 * S)))
    assert r.ContinuationPoint and svc.continuation_points() == 1
    p = params(raw(T0, T0 + 60 * S), cps=[r.ContinuationPoint])
    p.ReleaseContinuationPoints = True
    (rel,) = svc.read(p)
    assert rel.StatusCode.is_good() and svc.continuation_points() == 0
    (again,) = svc.read(params(raw(T0, T0 + 60 * S), cps=[r.ContinuationPoint]))
    assert again.StatusCode.value == 0x804A_0000  # Bad_ContinuationPointInvalid


def test_continuation_table_is_bounded(backend) -> None:
    svc = service(backend.open(), max_values=1, max_continuation_points=3)
    cps = [svc.read(params(raw(T0, T0 + 60 * S)))[0].ContinuationPoint for _ in range(4)]
    assert svc.continuation_points() == 3
    (oldest,) = svc.read(params(raw(T0, T0 + 60 * S), cps=[cps[0]]))
    assert oldest.StatusCode.value == 0x804A_0000
    (newest,) = svc.read(params(raw(T0, T0 + 60 * S), cps=[cps[3]]))
    assert newest.StatusCode.is_good() and values(newest)[0][0] == 10.0
    (other,) = svc.read(params(raw(T0, T0 + 60 * S), ua.NodeId("PLC.LIC1.SP", NS), cps=[cps[2]]))
    assert other.StatusCode.value in (0x804A_0000, 0x8034_0000)


# the kernel's oracles (tests/tanklab/test_history_aggregates.py) through the service and a store
PROCESSED = {
    "Average": [(0.0, 15.0, 0x401), (20.0, 40.0, 0x40A40401), (40.0, 60.0, 0x401), (60.0, None, 0x809B0000)],
    "TimeAverage": [
        (0.0, 17.5, 0x401),
        (20.0, 45.0, 0x40A40401),
        (40.0, 55.0, 0x40A40401),
        (60.0, None, 0x809B0000),
    ],
    "Interpolative": [
        (0.0, 10.0, 0),
        (20.0, 30.0, 0x40A40402),
        (40.0, 50.0, 0x402),
        (60.0, 60.0, 0x40A40402),
    ],
    "Count": [(0.0, 2, 0x401), (20.0, 1, 0x40A40401), (40.0, 1, 0x401), (60.0, None, 0x809B0000)],
    "Minimum": [(0.0, 10.0, 0), (30.0, 40.0, 0x40A40000), (50.0, 60.0, 0), (60.0, None, 0x809B0000)],
}


@pytest.mark.parametrize("name", sorted(PROCESSED))
def test_processed_matches_the_oracles(backend, name: str) -> None:
    svc = service(backend.open())
    (r,) = svc.read(params(processed(name, T0, T0 + 80 * S, 20)))
    assert r.StatusCode.is_good()
    assert values(r) == PROCESSED[name]


def test_processed_inside_the_data_uses_the_bounds(backend) -> None:
    svc = service(backend.open())
    # [40, 50): no raw value inside; the bounds 40 (30 s) and 60 (50 s) give the line from 50 to 60
    (r,) = svc.read(params(processed("TimeAverage", T0 + 40 * S, T0 + 50 * S, 0)))
    assert values(r) == [(40.0, 55.0, 0x401)]


def test_at_time(backend) -> None:
    svc = service(backend.open())
    d = ua.ReadAtTimeDetails()
    d.ReqTimes = [dt(T0), dt(T0 + 40 * S), dt(T0 - S)]
    d.UseSimpleBounds = False  # asyncua's default is True
    (r,) = svc.read(params(d))
    assert values(r) == [(0.0, 10.0, 0), (40.0, 50.0, 0x402), (-1.0, None, 0x809B0000)]
    d.UseSimpleBounds = True
    (r,) = svc.read(params(d))
    assert values(r)[1] == (40.0, 40.0, 0x402)


def test_bad_inputs_get_their_part11_codes(backend) -> None:
    svc = service(backend.open())
    unknown = ua.NodeId("PLC.NOPE.PV", NS)
    other_ns = ua.NodeId(TAG, 3)
    codes = [r.StatusCode.value for r in svc.read(params(raw(T0 + S, T0 + 2 * S), unknown, other_ns, NODE))]
    assert codes == [0x8034_0000, 0x8034_0000, 0x00A5_0000]  # BadNodeIdUnknown x2, GoodNoData
    (r,) = svc.read(params(raw(None, None)))
    assert r.StatusCode.value == 0x80BD_0000  # BadInvalidTimestampArgument
    (r,) = svc.read(params(processed("Average", T0 + S, T0 + S, 1)))
    assert r.StatusCode.value == 0x80BD_0000
    (r,) = svc.read(params(processed("Average", T0, T0 + S, -1)))
    assert r.StatusCode.value == 0x80AB_0000  # BadInvalidArgument
    d = processed("Average", T0, T0 + 60 * S, 10)
    d.AggregateType = [ua.NodeId(ua.ObjectIds.AggregateFunction_StandardDeviationSample)]
    (r,) = svc.read(params(d))
    assert r.StatusCode.value == 0x80D5_0000  # BadAggregateNotSupported
    d.AggregateType = [ua.NodeId(ua.ObjectIds.AggregateFunction_Average)] * 2
    codes = [r.StatusCode.value for r in svc.read(params(d, NODE, NODE, NODE))]
    assert codes == [0x80D4_0000] * 3  # BadAggregateListMismatch
    (r,) = svc.read(params(raw(T0, T0 + S), cps=[b"\x00" * 16]))
    assert r.StatusCode.value == 0x804A_0000
    p = params(raw(T0, T0 + S))
    p.TimestampsToReturn = ua.TimestampsToReturn.Neither
    assert svc.read(p)[0].StatusCode.value == 0x802B_0000
    p.TimestampsToReturn = ua.TimestampsToReturn.Server
    assert svc.read(p)[0].StatusCode.value == 0x80A1_0000
    up = ua.HistoryUpdateParameters()
    up.HistoryUpdateDetails = [ua.UpdateDataDetails()]
    assert [r.StatusCode.value for r in svc.update(up)] == [0x8072_0000]  # HistoryOperationUnsupported


def _event(i: int, t_us: int, type_: str, severity: int, source: str) -> EventRecord:
    return EventRecord(
        t_us, f"ev-{i}".encode(), type_, source, severity, f"event {i}", {"ConditionName": f"C{i}"}
    )


def _event_details(where: list[ua.ContentFilterElement]) -> ua.ReadEventDetails:
    d = ua.ReadEventDetails()
    d.StartTime, d.EndTime = dt(T0), dt(T0 + 100 * S)
    sel = []
    for name in ("EventId", "Severity", "SourceName", "ConditionName", "Time"):
        op = ua.SimpleAttributeOperand()
        op.TypeDefinitionId = ua.NodeId(ua.ObjectIds.BaseEventType)
        op.BrowsePath = [ua.QualifiedName(name, 0)]
        op.AttributeId = ua.AttributeIds.Value
        sel.append(op)
    d.Filter.SelectClauses = sel
    d.Filter.WhereClause.Elements = where
    return d


def _of_type(type_id: int) -> ua.ContentFilterElement:
    el = ua.ContentFilterElement()
    el.FilterOperator = ua.FilterOperator.OfType
    el.FilterOperands = [ua.LiteralOperand(Value=ua.Variant(ua.NodeId(type_id)))]
    return el


def _severity_at_least(n: int) -> ua.ContentFilterElement:
    el = ua.ContentFilterElement()
    el.FilterOperator = ua.FilterOperator.GreaterThanOrEqual
    sev = ua.SimpleAttributeOperand()
    sev.TypeDefinitionId = ua.NodeId(ua.ObjectIds.BaseEventType)
    sev.BrowsePath = [ua.QualifiedName("Severity", 0)]
    sev.AttributeId = ua.AttributeIds.Value
    el.FilterOperands = [sev, ua.LiteralOperand(Value=ua.Variant(n, ua.VariantType.UInt16))]
    return el


def _and(a: int, b: int) -> ua.ContentFilterElement:
    el = ua.ContentFilterElement()
    el.FilterOperator = ua.FilterOperator.And
    el.FilterOperands = [ua.ElementOperand(Index=a), ua.ElementOperand(Index=b)]
    return el


def test_events_with_a_where_clause(backend) -> None:
    store = backend.open()
    level_alarm, audit = "i=9482", "i=2052"  # ExclusiveLevelAlarmType, AuditEventType
    store.append_events(
        [
            _event(0, T0 + S, level_alarm, 700, "PLC.T1.Level"),
            _event(1, T0 + 2 * S, level_alarm, 300, "PLC.T1.Level"),
            _event(2, T0 + 3 * S, audit, 900, "Supervisor"),
            _event(3, T0 + 4 * S, "i=9341", 800, "PLC.T2.Level"),  # ExclusiveLimitAlarmType
        ]
    )
    subtypes = {"i=9341": {"i=9341", "i=9482"}}  # the limit alarm and its level subtype
    svc = HistoryReadService(
        store, site_tag_mapper(store, NS), event_subtypes=lambda t: subtypes.get(t, {t}), max_values=1
    )
    server = ua.NodeId(ua.ObjectIds.Server)

    def read(where: list[ua.ContentFilterElement], node: ua.NodeId = server) -> list[list[object]]:
        out, cp = [], None
        while True:
            (r,) = svc.read(params(_event_details(where), node, cps=[cp]))
            assert r.StatusCode.is_good(), hex(r.StatusCode.value)
            out += [[f.Value for f in e.EventFields] for e in r.HistoryData.Events]
            cp = r.ContinuationPoint
            if not cp:
                return out

    everything = read([])
    assert [e[0] for e in everything] == [b"ev-0", b"ev-1", b"ev-2", b"ev-3"]
    assert everything[0][1:4] == [700, "PLC.T1.Level", "C0"] and everything[0][4] == dt(T0 + S)
    # OfType with subtypes, And Severity >= 500
    assert [e[0] for e in read([_and(1, 2), _of_type(9341), _severity_at_least(500)])] == [b"ev-0", b"ev-3"]
    assert [e[0] for e in read([_severity_at_least(800)])] == [b"ev-2", b"ev-3"]
    like = ua.ContentFilterElement()
    like.FilterOperator = ua.FilterOperator.Like
    (r,) = svc.read(params(_event_details([like]), server))
    assert r.StatusCode.value == 0x80C2_0000  # BadFilterOperatorUnsupported
    (r,) = svc.read(params(_event_details([]), ua.NodeId("PLC.NOPE", NS)))
    assert r.StatusCode.value == 0x8034_0000
    # an object's events (its SourceName and below), NumValuesPerNode 1 with both times: pages of 1
    by_source = HistoryReadService(
        store, site_tag_mapper(store, NS), source_for_nodeid=site_source_mapper(NS)
    )
    d = _event_details([])
    d.NumValuesPerNode = 1
    (r,) = by_source.read(params(d, ua.NodeId("PLC.T1", NS)))
    assert [e.EventFields[0].Value for e in r.HistoryData.Events] == [b"ev-0"] and r.ContinuationPoint
    (r,) = by_source.read(params(d, ua.NodeId("PLC.T1", NS), cps=[r.ContinuationPoint]))
    assert [e.EventFields[0].Value for e in r.HistoryData.Events] == [b"ev-1"]
    (r,) = by_source.read(params(d, ua.NodeId("PLC.T1", NS), cps=[r.ContinuationPoint]))
    assert r.HistoryData.Events == [] and not r.ContinuationPoint
    (r,) = by_source.read(params(d, ua.NodeId("PLC.T1", NS + 1)))
    assert r.StatusCode.value == 0x8034_0000


keys = st.lists(st.integers(0, 60), unique=True, min_size=1, max_size=25)  # min 1: a known tag


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ks=keys, a=st.integers(-2, 62), w=st.integers(0, 64), page=st.integers(1, 7))
def test_paging_and_reverse_properties(backend, ks: list[int], a: int, w: int, page: int) -> None:
    store = backend.open()
    try:
        store.append_samples({TAG: [Sample(T0 + k * S, float(k), BAD if k % 5 == 0 else 0) for k in ks]})
        whole = HistoryReadService(store, site_tag_mapper(store, NS))
        paged = HistoryReadService(store, site_tag_mapper(store, NS), max_values=page)
        lo, hi = T0 + a * S, T0 + (a + w) * S
        single, calls = read_all(whole, raw(lo, hi, bounds=True))
        assert calls == 1
        assert read_all(paged, raw(lo, hi, bounds=True))[0] == single
        if w > 0:
            # reverse from hi to lo covers (lo, hi]: the forward read of [lo + 1 us, hi + 1 us) reversed
            forward, _ = read_all(whole, raw(lo + 1, hi + 1))
            assert read_all(paged, raw(hi, lo))[0] == forward[::-1]
    finally:
        store.close()


def _items(r: ua.HistoryReadResult) -> tuple[list[object], int]:
    """A result's values or events and their encoded size [bytes], as a server sends them (its
    HistoryData pre-encoded: the ExtensionObject's body; events through asyncua's encoder)."""
    data = r.HistoryData
    if isinstance(data, ua.ExtensionObject):
        decoded = extensionobject_from_binary(Buffer(extensionobject_to_binary(data)))
        return list(decoded.DataValues), len(data.Body)
    if isinstance(data, ua.HistoryEvent):
        return list(data.Events), len(struct_to_binary(data))
    return [], 0


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 120), text=st.integers(0, 40), budget=st.integers(60, 900), nodes=st.integers(1, 3))
def test_pages_fit_the_response_budget(backend, n: int, text: int, budget: int, nodes: int) -> None:
    """Pages of raw values (Doubles and Strings of varied length), aggregates and events stop
    where the next item would pass the node's share of max_response_bytes (a page holds at
    least one item, and a start bound stays with its first value), and together they hold
    exactly what one unbounded read gives (issue 21: an event page of 327 kB was refused by the
    tiers' 262 kB message limit)."""
    store = backend.open()
    try:
        strings = "PLC.Status.PlantLink.LastError"
        store.append_samples(
            {
                TAG: [Sample(T0 + k * S, float(k), BAD if k % 7 == 0 else 0) for k in range(n)],
                strings: [Sample(T0 + k * S, "x" * ((k * 13) % (text + 1))) for k in range(n)],
            }
        )
        store.append_events([_event(k, T0 + k * S, "i=2052", 500, "PLC.T1") for k in range(n)])
        mapper = site_tag_mapper(store, NS)
        whole = HistoryReadService(store, mapper, binary=True)
        bounded = HistoryReadService(store, mapper, binary=True, max_response_bytes=budget * nodes)
        cases: list[tuple[object, list[ua.NodeId]]] = [
            (raw(T0 - S, T0 + n * S, bounds=True), [ua.NodeId(t, NS) for t in [TAG, strings, TAG][:nodes]]),
            (raw(T0 + n * S, T0 - S), [ua.NodeId(t, NS) for t in [strings, TAG, strings][:nodes]]),
            (processed("Average", T0, T0 + n * S, 3.0), [NODE] * nodes),
            (_event_details([]), [ua.NodeId(ua.ObjectIds.Server)] * nodes),
        ]
        for details, ids in cases:
            expect = [_items(r)[0] for r in whole.read(params(details, *ids))]
            got: list[list[object]] = [[] for _ in ids]
            pending: dict[int, bytes | None] = dict.fromkeys(range(len(ids)))
            while pending:
                open_ = list(pending)
                share = budget * nodes // len(open_)
                request = params(details, *[ids[i] for i in open_], cps=[pending[i] for i in open_])
                results = bounded.read(request)
                for i, r in zip(open_, results, strict=True):
                    assert r.StatusCode.value in (0, 0x00A5_0000), hex(r.StatusCode.value)
                    items, size = _items(r)
                    assert size <= share or len(items) <= 2, (details, len(items), size, share)
                    got[i] += items
                    if r.ContinuationPoint:
                        assert items, "a continuation point after an empty page makes no progress"
                        pending[i] = r.ContinuationPoint
                    else:
                        del pending[i]
            assert got == expect
    finally:
        store.close()
