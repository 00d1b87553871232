"""The historian's stores: ingest per core, a day read back in pages, bytes per value (section 11).

Three measurements on each back end (:class:`historian.store.sqlite.SQLiteStore` on a file under
a temporary directory; :class:`historian.store.postgres.PostgresStore` on a throw-away PostgreSQL
15 cluster of :mod:`tanklab_testing.postgres` with PostgreSQL's **default, durable** settings:
fsync and synchronous commit on):

- **ingest**: :data:`INGEST_TAGS` tags scanned every 100 ms, written as a collector would, one
  batch (one transaction) per :data:`SCANS_PER_BATCH` scans, :data:`INGEST_SCANS` scans in all.
  *Values/s per core* is values / CPU seconds: this process's ``time.process_time`` and, for
  PostgreSQL, also the CPU time of the connection's backend process (``/proc/PID/stat``); wall
  time is reported beside it. The back ends run alternately, :data:`REPEATS` times each, fresh
  stores each time; medians.
- **a day read back**: one tag at 1 s (86,400 values) read in pages of :data:`PAGE` through the
  continuation cursors (``read_raw``'s ``after_us``), and in one page; wall and client CPU,
  median of :data:`READ_REPEATS`. This is the store alone; HistoryRead adds the OPC UA encoding.
- **bytes per value**: the store's on-disk size (tables and indexes; SQLite's file after a WAL
  checkpoint) over the values stored, for the ingest mix and for the day of one analog tag.
"""

from __future__ import annotations

import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.common import Goal, at_reference_text, fmt, rate_at_reference, speed_reference
from historian.store import HistoryStore
from historian.store.postgres import PostgresStore
from historian.store.sqlite import SQLiteStore
from tanklab.history.model import Sample
from tanklab_testing.postgres import PostgresServer

INGEST_TAGS = 50
"""Tags per scan: 40 analog (float), 5 enumerations (int), 5 flags (bool)."""
INGEST_SCANS = 4_000
SCANS_PER_BATCH = 10
"""Scans per batch: one transaction per second of a 100 ms scan."""
SCAN_US = 100_000
REPEATS = 3
READ_REPEATS = 5
PAGE = 1_000
DAY_VALUES = 86_400
GOAL_SQLITE_PER_CORE = 10_000.0
"""The issue's target: values per second per core into SQLite."""
T0 = 1_764_633_600_000_000  # 2025-12-02 00:00 UTC [us]
_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


@dataclass
class BackendResult:
    """One back end's numbers (lists: one entry per repetition)."""

    name: str
    ingest_wall_s: list[float] = field(default_factory=list)
    ingest_cpu_s: list[float] = field(default_factory=list)
    values: int = 0
    bytes_per_value_mix: float = math.nan
    read_paged_wall_s: list[float] = field(default_factory=list)
    read_paged_cpu_s: list[float] = field(default_factory=list)
    read_one_wall_s: list[float] = field(default_factory=list)
    bytes_per_value_day: float = math.nan

    @property
    def per_core(self) -> float:
        """Values per CPU second (median run) [1/s]."""
        return self.values / statistics.median(self.ingest_cpu_s) if self.ingest_cpu_s else math.nan

    @property
    def per_wall(self) -> float:
        return self.values / statistics.median(self.ingest_wall_s) if self.ingest_wall_s else math.nan


@dataclass
class HistStoreResults:
    backends: list[BackendResult]
    speed_reference_ms: float
    errors: list[str] = field(default_factory=list)


def scan_batches() -> list[dict[str, list[Sample]]]:
    """The ingest workload: :data:`INGEST_SCANS` scans of :data:`INGEST_TAGS` tags in batches."""
    names = (
        [f"PLC.LIC{i}.PV" for i in range(40)]
        + [f"PLC.LIC{i}.Mode" for i in range(5)]
        + [f"PLC.Alarms.HI{i}" for i in range(5)]
    )
    batches = []
    for b in range(INGEST_SCANS // SCANS_PER_BATCH):
        batch: dict[str, list[Sample]] = {n: [] for n in names}
        for k in range(b * SCANS_PER_BATCH, (b + 1) * SCANS_PER_BATCH):
            t = T0 + k * SCAN_US
            for i, n in enumerate(names):
                if i < 40:
                    v: float | int | bool = 0.5 + 0.1 * math.sin(k / 50.0 + i)
                elif i < 45:
                    v = (k // 100) % 4
                else:
                    v = (k // 300 + i) % 2 == 0
                batch[n].append(Sample(t, v))
        batches.append(batch)
    return batches


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) * _TICK_S  # utime, stime


def _ingest(store: HistoryStore, batches: list[dict[str, list[Sample]]]) -> tuple[float, float, int]:
    pid = store.server_pid() if isinstance(store, PostgresStore) else None
    server0 = _proc_cpu_s(pid) if pid else 0.0
    cpu0, wall0 = time.process_time(), time.perf_counter()
    n = sum(store.append_samples(b) for b in batches)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    if pid:
        cpu += _proc_cpu_s(pid) - server0
    return wall, cpu, n


def _bytes_per_value(store: HistoryStore) -> float:
    if isinstance(store, SQLiteStore):
        store.checkpoint()
    stats = store.stats()
    return stats.bytes / stats.samples if stats.samples else math.nan


def run(log: Callable[[str], None]) -> HistStoreResults:
    speed = speed_reference()
    batches = scan_batches()
    sqlite_res, pg_res = (
        BackendResult("SQLite (WAL, synchronous=NORMAL)"),
        BackendResult("PostgreSQL 15 (defaults)"),
    )
    errors: list[str] = []
    with (
        tempfile.TemporaryDirectory(prefix="tanklab-histbench-") as tmp,
        PostgresServer.start(settings={}) as pg,
    ):
        counter = iter(range(10_000))

        def fresh(kind: str) -> HistoryStore:
            n = next(counter)
            if kind == "sqlite":
                return SQLiteStore(Path(tmp) / f"h{n}.db")
            return PostgresStore(pg.url, schema=f"bench{n}")

        for rep in range(REPEATS):
            for kind, res in (("sqlite", sqlite_res), ("postgres", pg_res)):
                store = fresh(kind)
                try:
                    wall, cpu, n = _ingest(store, batches)
                    res.ingest_wall_s.append(wall)
                    res.ingest_cpu_s.append(cpu)
                    res.values = n
                    if n != INGEST_TAGS * INGEST_SCANS:
                        errors.append(f"{kind}: ingest stored {n} of {INGEST_TAGS * INGEST_SCANS} values")
                    if rep == REPEATS - 1:
                        res.bytes_per_value_mix = _bytes_per_value(store)
                    log(
                        f"  {kind} ingest {rep + 1}/{REPEATS}: {n / cpu:,.0f} values/s per core, "
                        f"{wall:.2f} s wall"
                    )
                finally:
                    store.close()
        day = {
            "PLC.LIC1.PV": [
                Sample(T0 + k * 1_000_000, 0.5 + 0.1 * math.sin(k / 600.0)) for k in range(DAY_VALUES)
            ]
        }
        stores = {"sqlite": fresh("sqlite"), "postgres": fresh("postgres")}
        try:
            for store in stores.values():
                store.append_samples(day)
            end = T0 + DAY_VALUES * 1_000_000
            for _ in range(READ_REPEATS):
                for kind, res in (("sqlite", sqlite_res), ("postgres", pg_res)):
                    store = stores[kind]
                    cpu0, wall0 = time.process_time(), time.perf_counter()
                    got, cursor = 0, None
                    while True:
                        page = store.read_raw("PLC.LIC1.PV", T0, end, limit=PAGE, after_us=cursor)
                        got += len(page.samples)
                        if page.cursor is None:
                            break
                        cursor = page.cursor
                    res.read_paged_wall_s.append(time.perf_counter() - wall0)
                    res.read_paged_cpu_s.append(time.process_time() - cpu0)
                    wall0 = time.perf_counter()
                    one = store.read_raw("PLC.LIC1.PV", T0, end, limit=DAY_VALUES + 1)
                    res.read_one_wall_s.append(time.perf_counter() - wall0)
                    if got != DAY_VALUES or len(one.samples) != DAY_VALUES:
                        errors.append(f"{kind}: read {got} / {len(one.samples)} of {DAY_VALUES} values")
            for kind, res in (("sqlite", sqlite_res), ("postgres", pg_res)):
                res.bytes_per_value_day = _bytes_per_value(stores[kind])
                log(
                    f"  {kind} day read in pages of {PAGE}: "
                    f"{statistics.median(res.read_paged_wall_s):.3f} s; "
                    f"{res.bytes_per_value_day:.1f} bytes/value"
                )
        finally:
            for store in stores.values():
                store.close()
    return HistStoreResults([sqlite_res, pg_res], speed, errors)


def goals(res: HistStoreResults) -> list[Goal]:
    """The issue's ingest target on SQLite, stated at the reference machine speed (decision 0036)."""
    sq = res.backends[0]
    rate = sq.per_core
    if not math.isfinite(rate):
        return [Goal("historian ingest into SQLite", ">= 10,000 values/s per core", "n/a", None)]
    at_ref = rate_at_reference(rate, res.speed_reference_ms)
    measured = at_reference_text(
        f"{fmt(at_ref)} values/s per core", f"{fmt(rate)} values/s per core", res.speed_reference_ms
    )
    note = (
        f"section 11: {INGEST_TAGS} tags, one transaction per {SCANS_PER_BATCH} scans, median of "
        f"{len(sq.ingest_cpu_s)} runs, CPU time"
    )
    return [
        Goal(
            "historian ingest into SQLite",
            f">= {GOAL_SQLITE_PER_CORE:,.0f} values/s per core",
            measured,
            at_ref >= GOAL_SQLITE_PER_CORE,
            note,
        )
    ]


def markdown(res: HistStoreResults) -> str:
    """Section 11 of the benchmark document."""

    def med(xs: list[float]) -> float:
        return statistics.median(xs) if xs else math.nan

    lines = [
        "## 11. Historian storage",
        "",
        "`benchmarks/histstore.py`: the historian's two stores, each fresh per run, the back ends "
        f"alternated, {REPEATS} runs each. Ingest: {INGEST_TAGS} tags (40 floats, 5 ints, 5 bools) "
        f"every 100 ms for {INGEST_SCANS:,} scans, one batch (one transaction) per {SCANS_PER_BATCH} "
        "scans; *per core* divides by CPU time: this process's and, for PostgreSQL, its backend "
        "process's (`/proc`). SQLite runs in WAL mode with `synchronous=NORMAL` (no fsync per "
        "commit); PostgreSQL with its durable defaults (fsync and synchronous commit on; a "
        "throw-away cluster on loopback). The day read: one tag at 1 s (86,400 values) through the "
        f"store's cursors in pages of {PAGE:,}, and in one page (medians of {READ_REPEATS}; the store "
        "alone, without OPC UA). Bytes per value: tables and indexes on disk over values stored "
        f"(SQLite after a WAL checkpoint). Machine speed reference {fmt(res.speed_reference_ms)} ms.",
        "",
        "| back end | ingest [values/s per core] | ingest [values/s wall] | day read, pages [s] "
        "| day read, pages, CPU [s] | day read, one page [s] | bytes/value (ingest mix) "
        "| bytes/value (day, one analog tag) |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for b in res.backends:
        lines.append(
            f"| {b.name} | {fmt(b.per_core)} | {fmt(b.per_wall)} | {fmt(med(b.read_paged_wall_s))} | "
            f"{fmt(med(b.read_paged_cpu_s))} | {fmt(med(b.read_one_wall_s))} | "
            f"{fmt(b.bytes_per_value_mix)} | {fmt(b.bytes_per_value_day)} |"
        )
    if res.errors:
        lines += ["", *[f"- error: {e}" for e in res.errors]]
    return "\n".join(lines) + "\n"
