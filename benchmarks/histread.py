"""A day of one tag read back through OPC UA HistoryRead from a real server (issue 16's goals).

On each back end (SQLite file; a throw-away PostgreSQL 15 of :mod:`tanklab_testing.postgres`) a
store holds one analog tag at 1 s for a day (:data:`DAY_VALUES` = 86,400 values, every 97th Bad).
An asyncua server in its own process (:mod:`benchmarks.histread_server`) on a loopback port
serves it with :func:`historian.history_read.install_history_read` (at most 100,000 values per
response), and an asyncua client in this process reads:

- **raw**: ``Node.read_raw_history(start, end)`` of the whole day (the client follows the
  continuation points; 1 response at the default page of 100,000) -- goal <= 1 s;
- **aggregate**: one ``ReadProcessedDetails`` Average over 60 s intervals (1,440 values) -- goal
  <= 0.5 s.

Wall time from the request to the decoded values, median of :data:`REPEATS` (after one warm-up
read), so it includes the store's query, the aggregate, the server's encoding, the transfer and
the client's decoding (asyncua's, pure Python: most of the time).
The goals are stated at the reference machine speed (decision 0036).
"""

from __future__ import annotations

import asyncio
import math
import select
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

from asyncua import Client, ua

from benchmarks.common import ROOT, Goal, at_reference_text, fmt, seconds_at_reference, speed_reference
from historian.store.postgres import PostgresStore
from historian.store.sqlite import SQLiteStore
from tanklab.history.model import Sample
from tanklab_testing.postgres import PostgresServer
from tanklab_testing.procs import free_port

DAY_VALUES = 86_400
REPEATS = 5
TAG = "PLC.LIC1.PV"
T0 = 1_764_633_600_000_000  # 2025-12-02 00:00 UTC [us]
S = 1_000_000
GOAL_RAW_S = 1.0
GOAL_AGGREGATE_S = 0.5
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def _dt(t_us: int) -> datetime:
    return _EPOCH + timedelta(microseconds=t_us)


@dataclass
class ReadResult:
    """One back end's times [s] (one entry per repetition) and what came back."""

    name: str
    raw_s: list[float] = field(default_factory=list)
    aggregate_s: list[float] = field(default_factory=list)
    raw_values: int = 0
    aggregate_values: int = 0

    @property
    def raw_median_s(self) -> float:
        return statistics.median(self.raw_s) if self.raw_s else math.nan

    @property
    def aggregate_median_s(self) -> float:
        return statistics.median(self.aggregate_s) if self.aggregate_s else math.nan


@dataclass
class HistReadResults:
    backends: list[ReadResult]
    speed_reference_ms: float
    errors: list[str] = field(default_factory=list)


def day() -> list[Sample]:
    """One analog tag at 1 s for a day, a slow sine, every 97th value Bad."""
    return [
        Sample(T0 + k * S, 50.0 + 10.0 * math.sin(k / 600.0), 0x8000_0000 if k % 97 == 0 else 0)
        for k in range(DAY_VALUES)
    ]


def _start_server(args: list[str]) -> tuple[subprocess.Popen[str], int, int]:
    """The server process, its port and the site namespace index (bounded wait for ``ready``)."""
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "benchmarks.histread_server", str(port), *args],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 60.0)
    line = proc.stdout.readline() if ready else ""
    if not line.startswith("ready "):
        _stop(proc)
        raise RuntimeError(f"the HistoryRead server did not start (said {line!r})")
    return proc, port, int(line.split()[1])


def _stop(proc: subprocess.Popen[str]) -> None:
    """Close its stdin (it stops), kill it if it has not after 10 s."""
    if proc.stdin is not None:
        proc.stdin.close()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=10)


async def _measure(port: int, ns: int, res: ReadResult) -> None:
    url = f"opc.tcp://127.0.0.1:{port}/tanklab/historian"
    async with Client(url, timeout=60) as client:
        node = client.get_node(ua.NodeId(TAG, ns))
        details = ua.ReadProcessedDetails()
        details.StartTime, details.EndTime = _dt(T0), _dt(T0 + DAY_VALUES * S)
        details.ProcessingInterval = 60_000.0
        details.AggregateType = [ua.NodeId(ua.ObjectIds.AggregateFunction_Average)]
        params = ua.HistoryReadParameters()
        params.HistoryReadDetails = details
        params.TimestampsToReturn = ua.TimestampsToReturn.Source
        params.ReleaseContinuationPoints = False
        rv = ua.HistoryReadValueId()
        rv.NodeId = node.nodeid
        params.NodesToRead = [rv]
        for i in range(REPEATS + 1):
            t = time.perf_counter()
            got = await node.read_raw_history(_dt(T0), _dt(T0 + DAY_VALUES * S), return_bounds=False)
            raw_s = time.perf_counter() - t
            t = time.perf_counter()
            (r,) = await client.uaclient.history_read(params)
            agg_s = time.perf_counter() - t
            r.StatusCode.check()
            res.raw_values, res.aggregate_values = len(got), len(r.HistoryData.DataValues)
            if i:  # the first is a warm-up (page cache, the client's first decode)
                res.raw_s.append(raw_s)
                res.aggregate_s.append(agg_s)


def _served(args: list[str], res: ReadResult) -> None:
    proc, port, ns = _start_server(args)
    try:
        asyncio.run(_measure(port, ns, res))
    finally:
        _stop(proc)


def run(log: Callable[[str], None]) -> HistReadResults:
    """Both back ends, one after the other."""
    speed = speed_reference()
    out = HistReadResults([], speed)
    samples = day()
    with tempfile.TemporaryDirectory(prefix="tanklab-histread-") as tmp:
        sq = ReadResult("SQLite")
        path = Path(tmp) / "history.db"
        try:
            store = SQLiteStore(path)
            try:
                store.append_samples({TAG: samples})
            finally:
                store.close()
            _served(["sqlite", str(path)], sq)
        except Exception as e:  # the document reports it; the other back end still runs
            out.errors.append(f"SQLite: {type(e).__name__}: {e}")
        out.backends.append(sq)
        log(f"  SQLite: raw {fmt(sq.raw_median_s)} s, Average 60 s {fmt(sq.aggregate_median_s)} s")
        pg = ReadResult("PostgreSQL")
        try:
            server = PostgresServer.start()
        except Exception as e:
            out.errors.append(f"PostgreSQL: {type(e).__name__}: {e}")
        else:
            try:
                pstore = PostgresStore(server.url, schema="histread")
                try:
                    pstore.append_samples({TAG: samples})
                finally:
                    pstore.close()
                _served(["postgres", server.url, "histread"], pg)
            except Exception as e:
                out.errors.append(f"PostgreSQL: {type(e).__name__}: {e}")
            finally:
                server.stop()
        out.backends.append(pg)
        log(f"  PostgreSQL: raw {fmt(pg.raw_median_s)} s, Average 60 s {fmt(pg.aggregate_median_s)} s")
    return out


def goals(res: HistReadResults) -> list[Goal]:
    """The two read goals on SQLite (the default back end), at the reference speed."""
    sq = res.backends[0] if res.backends else ReadResult("SQLite")
    out = []
    for name, target, measured in (
        ("HistoryRead of a day of one tag at 1 s (86,400 values)", GOAL_RAW_S, sq.raw_median_s),
        ("HistoryRead Average over that day, 60 s intervals", GOAL_AGGREGATE_S, sq.aggregate_median_s),
    ):
        if not math.isfinite(measured):
            out.append(Goal(name, f"<= {target} s", "n/a", None))
            continue
        at_ref = seconds_at_reference(measured, res.speed_reference_ms)
        text = at_reference_text(f"{fmt(at_ref)} s", f"{fmt(measured)} s", res.speed_reference_ms)
        out.append(Goal(name, f"<= {target} s", text, at_ref <= target, "section 12, SQLite, asyncua client"))
    return out


def markdown(res: HistReadResults) -> str:
    """Section 12 of the benchmark document."""
    lines = [
        "## 12. Historian reads through HistoryRead",
        "",
        "`benchmarks/histread.py`: one analog tag at 1 s for a day (86,400 values) in each store, "
        "served by an asyncua server process on loopback with `install_history_read` (at most "
        "100,000 values per response) and read by an asyncua client in the bench's process: "
        "the raw day (`read_raw_history`) and one Average over 60 s intervals (1,440 values). "
        f"Wall time request to decoded values, median of {REPEATS} after a warm-up. Machine speed "
        f"reference {fmt(res.speed_reference_ms)} ms.",
        "",
        "| back end | raw day [s] | values | Average 60 s [s] | values |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for b in res.backends:
        lines.append(
            f"| {b.name} | {fmt(b.raw_median_s)} | {b.raw_values:,} | {fmt(b.aggregate_median_s)} | "
            f"{b.aggregate_values:,} |"
        )
    if res.errors:
        lines += ["", *[f"- error: {e}" for e in res.errors]]
    return "\n".join(lines) + "\n"
