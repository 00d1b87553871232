"""HistoryRead through a real asyncua server on a loopback port (``install_history_read``) and an
asyncua client: raw reads (the client follows the continuation points), a processed read built by
hand, an event read with asyncua's own filter, and the bad-input codes as a client sees them.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import pytest
from asyncua import Client, Server, ua

from historian.history_read import HistoryReadService, install_history_read, site_tag_mapper
from historian.store import HistoryStore
from tankctl.ops.history_read import read_event_history
from tanklab.history.model import EventRecord, Sample
from tanklab_io.ua_security import set_transport_limits
from tanklab_testing.procs import free_port

S = 1_000_000
T0 = 1_764_633_600_000_000  # 2025-12-02 00:00 UTC [us]
TAG = "PLC.LIC1.PV"
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
N = 250


def dt(t_us: int) -> datetime:
    return EPOCH + timedelta(microseconds=t_us)


@dataclass
class Served:
    url: str
    ns: int
    service: HistoryReadService


@pytest.fixture
async def served(backend) -> AsyncIterator[Served]:
    store: HistoryStore = backend.open()
    # one value a second, every 7th Bad
    store.append_samples(
        {TAG: [Sample(T0 + k * S, float(k), 0x8000_0000 if k % 7 == 3 else 0) for k in range(N)]}
    )
    store.append_events(
        [
            EventRecord(T0 + S, b"e1", "i=9482", "PLC.T1.Level", 700, "T1 high", {}),
            EventRecord(T0 + 2 * S, b"e2", "i=2052", "Supervisor", 100, "login", {}),
        ]
    )
    port = free_port()
    url = f"opc.tcp://127.0.0.1:{port}/tanklab/historian"
    server = Server()
    await server.init()
    server.set_endpoint(url)
    ns = await server.register_namespace("urn:tanklab")
    service = install_history_read(server, store, site_tag_mapper(store, ns), max_values=100)
    async with server:
        yield Served(url, ns, service)


async def test_raw_processed_and_events_through_a_server(served: Served) -> None:
    async with Client(served.url) as client:
        node = client.get_node(ua.NodeId(TAG, served.ns))
        # 250 values in pages of 100: the client follows two continuation points
        got = await node.read_raw_history(dt(T0), dt(T0 + N * S), return_bounds=False)
        assert [v.Value.Value for v in got] == [float(k) for k in range(N)]
        assert [v.StatusCode.value for v in got[:4]] == [0, 0, 0, 0x8000_0000]
        assert got[10].SourceTimestamp == dt(T0 + 10 * S)
        assert served.service.continuation_points() == 0
        # reverse: start > end reads newest first, (end, start]
        rev = await node.read_raw_history(dt(T0 + 20 * S), dt(T0 + 10 * S), return_bounds=False)
        assert [v.Value.Value for v in rev] == [float(k) for k in range(20, 10, -1)]

        # Average over 60 s intervals, by hand (asyncua's Node has no processed read)
        d = ua.ReadProcessedDetails()
        d.StartTime, d.EndTime = dt(T0), dt(T0 + 120 * S)
        d.ProcessingInterval = 60_000.0
        d.AggregateType = [ua.NodeId(ua.ObjectIds.AggregateFunction_Average)]
        (r,) = await _read(client, d, node.nodeid)
        assert r.StatusCode.is_good()
        vals = r.HistoryData.DataValues
        # [0, 60): the good k (k % 7 != 3) of 0..59: 51 values, their mean by hand
        good = [k for k in range(60) if k % 7 != 3]
        assert len(vals) == 2 and vals[0].SourceTimestamp == dt(T0)
        assert vals[0].Value.Value == pytest.approx(sum(good) / len(good), rel=1e-12)
        assert vals[0].StatusCode.value == 0x40A4_0401  # Uncertain_DataSubNormal, Calculated

        events = await client.nodes.server.read_event_history(dt(T0), dt(T0 + 10 * S))
        assert [e.Severity for e in events] == [700, 100]
        alarms = await client.nodes.server.read_event_history(
            dt(T0), dt(T0 + 10 * S), evtypes=ua.NodeId(ua.ObjectIds.AlarmConditionType)
        )
        assert [e.SourceName for e in alarms] == ["PLC.T1.Level"]  # ExclusiveLevelAlarm is a subtype


async def test_bad_input_codes_through_a_server(served: Served) -> None:
    async with Client(served.url) as client:
        unknown = client.get_node(ua.NodeId("PLC.NOPE.PV", served.ns))
        with pytest.raises(ua.uaerrors.BadNodeIdUnknown):
            await unknown.read_raw_history(dt(T0), dt(T0 + S))
        node = client.get_node(ua.NodeId(TAG, served.ns))
        with pytest.raises(ua.uaerrors.BadInvalidTimestampArgument):
            await node.read_raw_history(None, None)  # neither time, no NumValuesPerNode
        d = ua.ReadProcessedDetails()
        d.StartTime, d.EndTime = dt(T0), dt(T0 + 60 * S)
        d.ProcessingInterval = 10_000.0
        d.AggregateType = [ua.NodeId(ua.ObjectIds.AggregateFunction_Range)]
        (r,) = await _read(client, d, node.nodeid)
        assert r.StatusCode.value == ua.StatusCodes.BadAggregateNotSupported
        d.AggregateType = [ua.NodeId(ua.ObjectIds.AggregateFunction_Average)]
        d.EndTime = d.StartTime
        (r,) = await _read(client, d, node.nodeid)
        assert r.StatusCode.value == ua.StatusCodes.BadInvalidTimestampArgument
        (r,) = await _read(client, _raw(), node.nodeid, cp=b"not a point")
        assert r.StatusCode.value == ua.StatusCodes.BadContinuationPointInvalid
        # nobody may update history: asyncua's server refuses HistoryUpdate before any history
        # manager sees it (its permission check: BadUserAccessDenied); the service would say
        # BadHistoryOperationUnsupported (tests/historian/test_history_read.py)
        with pytest.raises(ua.UaStatusCodeError) as refused:
            await node.history_update(ua.UpdateDataDetails(NodeId=node.nodeid))
        assert refused.value.code in (
            ua.StatusCodes.BadUserAccessDenied,
            ua.StatusCodes.BadServiceUnsupported,
            ua.StatusCodes.BadHistoryOperationUnsupported,
        )
        # the server still answers after every refusal
        # asyncua asks for bounds by default: [0 s, 3 s) and the end bound, the value at 3 s
        got = await node.read_raw_history(dt(T0), dt(T0 + 3 * S))
        assert [v.SourceTimestamp for v in got] == [dt(T0 + k * S) for k in range(4)]


def _raw() -> ua.ReadRawModifiedDetails:
    d = ua.ReadRawModifiedDetails()
    d.StartTime, d.EndTime = dt(T0), dt(T0 + 10 * S)
    return d


async def _read(
    client: Client, details: object, nodeid: ua.NodeId, cp: bytes | None = None
) -> list[ua.HistoryReadResult]:
    p = ua.HistoryReadParameters()
    p.HistoryReadDetails = details
    p.TimestampsToReturn = ua.TimestampsToReturn.Both
    p.ReleaseContinuationPoints = False
    rv = ua.HistoryReadValueId()
    rv.NodeId = nodeid
    rv.ContinuationPoint = cp
    p.NodesToRead = [rv]
    return await client.uaclient.history_read(p)


@pytest.mark.parametrize("budget", [None, 10**9], ids=["default budget", "unbounded pages"])
async def test_large_reads_fit_the_tiers_message_limit(backend, budget: int | None) -> None:
    """A raw read of 16,000 values (288 kB) and an event read of 1,000 events (about
    340 kB) through a server with the tiers' transport limits (262,140 bytes a message): the
    service's response budget pages both, and the client gets everything. With unbounded pages
    the same reads fail, as `tankctl alarms --history` did in a fresh-clone run (issue 21:
    "Message size: 327315 is > configured max message size: 262140")."""
    store: HistoryStore = backend.open()
    n, n_events = 16_000, 1_000
    store.append_samples({TAG: [Sample(T0 + k * S, float(k)) for k in range(n)]})
    store.append_events(
        [
            EventRecord(T0 + k * S, b"ev%06d" % k, "i=2052", "PLC", 500, f"event {k}: " + "x" * 300, {})
            for k in range(n_events)
        ]
    )
    port = free_port()
    url = f"opc.tcp://127.0.0.1:{port}/tanklab/historian"
    server = Server()
    await server.init()
    server.set_endpoint(url)
    set_transport_limits(server)
    ns = await server.register_namespace("urn:tanklab")
    options = {} if budget is None else {"max_response_bytes": budget}
    install_history_read(server, store, site_tag_mapper(store, ns), **options)
    async with server, Client(url) as client:
        node = client.get_node(ua.NodeId(TAG, ns))
        if budget is None:
            got = await node.read_raw_history(dt(T0), dt(T0 + n * S), return_bounds=False)
            assert [v.Value.Value for v in got] == [float(k) for k in range(n)]
            events = await read_event_history(client, dt(T0), dt(T0 + n_events * S))
            assert [e.message for e in events] == [f"event {k}: " + "x" * 300 for k in range(n_events)]
        else:
            with pytest.raises(ua.UaStatusCodeError):
                await read_event_history(client, dt(T0), dt(T0 + n_events * S))
