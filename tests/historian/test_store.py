"""The historian's stores: one suite, run on SQLite and on a real PostgreSQL 15 (``backend``).

Oracles are the samples and events written: what reads back equals them exactly (value and its
type, status, time to the microsecond), in Part 11 order, page by page; duplicates are ignored
with the first write kept; retention removes exactly what is older than its limit.
"""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path

import psycopg
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from historian.store import HistoryStore, open_store, store_location
from historian.store.base import DAY_US, same_value
from historian.store.postgres import PostgresStore
from historian.store.sqlite import SQLiteStore
from tanklab.history.model import EventRecord, Sample

T0 = 1_764_633_600_000_000  # 2025-12-02 00:00:00 UTC [us]
S = 1_000_000  # one second [us]
BAD_NO_DATA = 0x809B_0000  # BadNoData
UNCERTAIN = 0x4000_0000

EVERY_TYPE = [
    Sample(T0 + 1, 0.0),
    Sample(T0 + 2, -0.0),
    Sample(T0 + 3, 1.0),  # an integral float stays a float
    Sample(T0 + 4, 1.5e-300),
    Sample(T0 + 5, -2.2250738585072014e-308),
    Sample(T0 + 6, math.inf, UNCERTAIN),
    Sample(T0 + 7, -math.inf),
    Sample(T0 + 8, 0),
    Sample(T0 + 9, 1),  # an int 1 stays an int, not a bool
    Sample(T0 + 10, -1),
    Sample(T0 + 11, 2**63 - 1),
    Sample(T0 + 12, -(2**63)),
    Sample(T0 + 13, True),
    Sample(T0 + 14, False),
    Sample(T0 + 15, ""),
    Sample(T0 + 16, "Füllstand ≥ 0.5 m ✓"),
    Sample(T0 + 17, None, BAD_NO_DATA),
    Sample(T0 + 18, 3.25, 0xFFFF_FFFF),
    Sample(T0 + 19, 7, 0x8000_0000),
    Sample(T0 + 999_999, 2.0),  # microseconds, not milliseconds
]


def assert_same(got: list[Sample], want: list[Sample]) -> None:
    """Equal, sample by sample, value types included (1.0 is not 1, True is not 1)."""
    assert [(s.t_us, s.status) for s in got] == [(s.t_us, s.status) for s in want]
    for g, w in zip(got, want, strict=True):
        assert same_value(g.value, w.value), (g, w)


def read_all(store: HistoryStore, tag: str, start: int, end: int, page: int) -> tuple[list[Sample], int]:
    """Every sample of a raw read, page by page through the cursors; and the number of pages."""
    out: list[Sample] = []
    cursor = None
    pages = 0
    while True:
        p = store.read_raw(tag, start, end, limit=page, after_us=cursor)
        pages += 1
        assert len(p.samples) <= page
        out += p.samples
        if p.cursor is None:
            return out, pages
        assert p.cursor == p.samples[-1].t_us
        cursor = p.cursor


def event(i: int, t_us: int, *, type_: str = "i=9482", severity: int = 500) -> EventRecord:
    return EventRecord(
        t_us,
        f"ev-{i:04d}".encode(),
        type_,
        f"PLC.T{i % 3}.Level",
        severity,
        f"event {i}",
        {"ActiveState/Id": i % 2 == 0, "ConditionName": f"HI{i}", "Value": i * 0.5},
    )


def test_every_type_status_and_microsecond_round_trips(backend) -> None:
    store = backend.open()
    assert store.append_samples({"PLC.LIC1.PV": EVERY_TYPE}) == len(EVERY_TYPE)
    page = store.read_raw("PLC.LIC1.PV", T0, T0 + S, limit=100)
    assert page.cursor is None
    assert_same(page.samples, EVERY_TYPE)


def test_nan_round_trips_as_nan(backend) -> None:
    store = backend.open()
    store.append_samples({"A": [Sample(T0, math.nan, UNCERTAIN)]})
    (s,) = store.read_raw("A", T0, T0 + 1, limit=5).samples
    assert isinstance(s.value, float)
    assert math.isnan(s.value)
    assert s.status == UNCERTAIN


def test_times_before_1970_and_far_ahead(backend) -> None:
    store = backend.open()
    samples = [Sample(-86_400 * S - 1, 1.0), Sample(0, 2.0), Sample(4_102_444_800 * S + 7, 3.0)]  # 2100
    store.append_samples({"A": samples})
    assert_same(store.read_raw("A", -(10**17), 10**17, limit=10).samples, samples)


def test_ordering_of_batches_written_out_of_order(backend) -> None:
    store = backend.open()
    times = [T0 + k * S for k in (5, 1, 9, 3, 7, 2, 8, 0, 6, 4)]
    for i in range(0, 10, 3):
        store.append_samples({"A": [Sample(t, float(t - T0)) for t in times[i : i + 3]]})
    got = store.read_raw("A", T0, T0 + 10 * S, limit=100).samples
    assert [s.t_us for s in got] == sorted(times)
    assert [s.value for s in got] == [float(t - T0) for t in sorted(times)]


def test_a_day_at_one_second_reads_back_in_pages_forward_and_reverse(backend) -> None:
    store = backend.open()
    day = [Sample(T0 + k * S, math.sin(k / 600.0), UNCERTAIN if k % 1000 == 0 else 0) for k in range(86_400)]
    for i in range(0, len(day), 10_000):  # batches as a collector would write them
        store.append_samples({"PLC.LIC1.PV": day[i : i + 10_000], "PLC.LIC1.MV": day[i : i + 10_000]})
    forward, pages = read_all(store, "PLC.LIC1.PV", T0, T0 + DAY_US, 1000)
    assert pages == 87  # 86 full pages and the last 400
    assert_same(forward, day)
    reverse, _ = read_all(store, "PLC.LIC1.PV", T0 + DAY_US - 1, T0 - 1, 7_000)
    assert_same(reverse, day[::-1])


def test_a_range_of_exactly_limit_samples_ends_without_a_cursor(backend) -> None:
    store = backend.open()
    store.append_samples({"A": [Sample(T0 + k, float(k)) for k in range(10)]})
    page = store.read_raw("A", T0, T0 + 10, limit=10)
    assert len(page.samples) == 10
    assert page.cursor is None
    page = store.read_raw("A", T0, T0 + 10, limit=9)
    assert page.cursor == T0 + 8
    rest = store.read_raw("A", T0, T0 + 10, limit=9, after_us=page.cursor)
    assert [s.t_us for s in rest.samples] == [T0 + 9]
    assert rest.cursor is None


def test_part11_range_bounds_forward_reverse_and_equal(backend) -> None:
    store = backend.open()
    store.append_samples({"A": [Sample(T0 + k * S, k) for k in range(10)]})

    def ks(start: int, end: int) -> list[int]:
        return [int(s.value) for s in store.read_raw("A", T0 + start * S, T0 + end * S, limit=100).samples]  # type: ignore[arg-type]

    assert ks(2, 5) == [2, 3, 4]  # start inclusive, end exclusive
    assert ks(5, 2) == [5, 4, 3]  # reverse: start inclusive, end exclusive
    assert ks(4, 4) == [4]  # the one sample at that time
    assert store.read_raw("A", T0 + 4 * S + 1, T0 + 4 * S + 1, limit=5).samples == []
    assert ks(-5, 0) == []
    assert ks(9, 100) == [9]


def test_unknown_tag_reads_empty_and_bad_limits_are_refused(backend) -> None:
    store = backend.open()
    assert store.read_raw("Nobody", T0, T0 + S, limit=5) == ([], None)
    assert store.bounds("Nobody", T0) == (None, None)
    with pytest.raises(ValueError, match="limit"):
        store.read_raw("A", T0, T0 + S, limit=0)
    with pytest.raises(TypeError, match="limit"):
        store.read_raw("A", T0, T0 + S, limit=2.5)  # type: ignore[arg-type]


def test_bounds_for_interpolation(backend) -> None:
    store = backend.open()
    store.append_samples(
        {
            "A": [Sample(T0, 1.0), Sample(T0 + 10 * S, 2.0, BAD_NO_DATA), Sample(T0 + 20 * S, 3.0)],
            "B": [Sample(T0, 9.0)],
        }
    )
    before, after = store.bounds("A", T0 + 5 * S)
    assert before == Sample(T0, 1.0) and after == Sample(T0 + 10 * S, 2.0, BAD_NO_DATA)
    assert store.bounds("A", T0 + 10 * S) == (Sample(T0 + 10 * S, 2.0, BAD_NO_DATA),) * 2  # exact
    assert store.bounds("A", T0 - 1) == (None, Sample(T0, 1.0))
    assert store.bounds("A", T0 + 21 * S) == (Sample(T0 + 20 * S, 3.0), None)
    assert store.bounds("A", T0 + 10 * S, good_only=True) == (Sample(T0, 1.0), Sample(T0 + 20 * S, 3.0))


def test_duplicates_are_ignored_and_the_first_write_wins(backend) -> None:
    store = backend.open()
    assert store.append_samples({"A": [Sample(T0, 1.0), Sample(T0 + 1, 2.0)], "B": [Sample(T0, True)]}) == 3
    # a restart re-records the last scan, once with another value: nothing is stored twice
    assert (
        store.append_samples({"A": [Sample(T0 + 1, 99.0), Sample(T0 + 2, 3.0)], "B": [Sample(T0, False)]})
        == 1
    )
    assert store.append_samples({"A": [Sample(T0 + 5, 5.0), Sample(T0 + 5, 6.0)]}) == 1  # within a batch
    assert_same(
        store.read_raw("A", T0, T0 + S, limit=10).samples,
        [Sample(T0, 1.0), Sample(T0 + 1, 2.0), Sample(T0 + 2, 3.0), Sample(T0 + 5, 5.0)],
    )
    assert_same(store.read_raw("B", T0, T0 + S, limit=10).samples, [Sample(T0, True)])
    assert store.stats().samples == 5


def test_a_bad_value_fails_the_whole_batch(backend) -> None:
    store = backend.open()
    store.append_samples({"A": [Sample(T0, 1.0)]})
    with pytest.raises(TypeError, match="value"):
        store.append_samples({"A": [Sample(T0 + 1, 2.0)], "New": [Sample(T0, [1, 2])]})  # type: ignore[list-item]
    with pytest.raises(ValueError, match="64 bits"):
        store.append_samples({"A": [Sample(T0 + 1, 2**64)]})
    with pytest.raises(ValueError, match="NUL"):
        store.append_samples({"A": [Sample(T0 + 1, "a\x00b")]})
    assert_same(store.read_raw("A", T0, T0 + S, limit=10).samples, [Sample(T0, 1.0)])
    assert [t.tag for t in store.tags()] == ["A"]
    # and the store still works after the rollback
    assert store.append_samples({"New": [Sample(T0, 4)]}) == 1
    assert [t.tag for t in store.tags()] == ["A", "New"]


def test_tags_with_first_and_last_time(backend) -> None:
    store = backend.open()
    store.append_samples(
        {"Plant.LT1.PV": [Sample(T0 + 5, 1.0), Sample(T0 + 9, 1.0)], "PLC.LIC1.SP": [Sample(T0, 0.5)]}
    )
    store.append_samples({"Plant.LT1.PV": [Sample(T0 + 2 * DAY_US, 1.0)]})
    assert store.tags() == [("PLC.LIC1.SP", T0, T0), ("Plant.LT1.PV", T0 + 5, T0 + 2 * DAY_US)]


def test_events_round_trip_idempotent_by_event_id(backend) -> None:
    store = backend.open()
    events = [event(i, T0 + (i // 2) * S) for i in range(10)]  # two events per time
    assert store.append_events(events) == 10
    assert store.append_events([event(3, T0 + 99 * S), event(10, T0 + 5 * S)]) == 1  # ev-0003 known
    assert store.append_events([]) == 0
    page = store.read_events(T0, T0 + 10 * S, limit=100)
    assert page.cursor is None
    assert page.events == sorted([*events, event(10, T0 + 5 * S)], key=lambda e: (e.t_us, e.event_id))


def test_events_filtered_by_type_and_severity_paged_both_ways(backend) -> None:
    store = backend.open()
    kinds = ["i=9482", "i=9341", "i=2052"]  # level alarm, exclusive limit alarm, audit
    events = [event(i, T0 + (i // 3) * S, type_=kinds[i % 3], severity=100 * (1 + i % 10)) for i in range(60)]
    store.append_events(events)

    def read(start: int, end: int, page: int, **kw) -> list[EventRecord]:
        out: list[EventRecord] = []
        cursor = None
        while True:
            p = store.read_events(start, end, limit=page, after=cursor, **kw)
            out += p.events
            if p.cursor is None:
                return out
            cursor = p.cursor

    want = sorted(
        (e for e in events if e.event_type in {"i=9482", "i=9341"} and e.severity >= 700),
        key=lambda e: (e.t_us, e.event_id),
    )
    assert len(want) == 16
    assert read(T0, T0 + 60 * S, 3, event_types=["i=9482", "i=9341"], min_severity=700) == want
    assert read(T0 + 60 * S, T0 - 1, 4, event_types=("i=9482", "i=9341"), min_severity=700) == want[::-1]
    in_window = [e for e in events if T0 + 5 * S <= e.t_us < T0 + 8 * S]
    assert read(T0 + 5 * S, T0 + 8 * S, 2) == in_window
    assert read(T0, T0 + 60 * S, 5, event_types=[]) == []
    assert read(T0, T0 + 60 * S, 5, event_types=["i=0"]) == []


def test_retention_in_bounded_steps(backend) -> None:
    store = backend.open()
    days = [T0 - DAY_US, T0, T0 + DAY_US]
    store.append_samples(
        {tag: [Sample(d + k * 60 * S, float(k)) for d in days for k in range(1440)] for tag in "ABC"}
    )
    store.append_events([event(i, days[i % 3] + i * S) for i in range(30)])
    cut = T0 + 12 * 3600 * S  # noon of the middle day: a whole day and a half go
    steps = []
    while True:
        step = store.retention_step(cut, max_rows=1000)
        steps.append(step)
        if step.done:
            break
        assert len(steps) < 100
    assert len(steps) > 2  # bounded: it took several short transactions
    assert sum(s.samples_deleted for s in steps) == 3 * (1440 + 720)
    assert sum(s.events_deleted for s in steps) == 20  # day 1 and the morning of day 2
    for tag in "ABC":
        kept = store.read_raw(tag, T0 - 2 * DAY_US, T0 + 2 * DAY_US, limit=10_000).samples
        assert kept[0].t_us == cut
        assert len(kept) == 720 + 1440
    assert all(e.t_us >= cut for e in store.read_events(T0 - 2 * DAY_US, T0 + 2 * DAY_US, limit=100).events)
    assert store.retention_step(cut).done  # nothing left to do
    assert store.stats().samples == 3 * (720 + 1440)


def test_reopen_after_a_restart_keeps_everything_and_duplicates_nothing(backend) -> None:
    location = backend.location()
    first = backend.open(location)
    samples = [Sample(T0 + k * S, float(k), 0 if k % 7 else BAD_NO_DATA) for k in range(500)]
    first.append_samples({"A": samples, "B": EVERY_TYPE})
    first.append_events([event(i, T0 + i) for i in range(5)])
    first.close()
    second = backend.open(location)
    assert_same(second.read_raw("A", T0, T0 + DAY_US, limit=1000).samples, samples)
    assert_same(second.read_raw("B", T0, T0 + DAY_US, limit=1000).samples, EVERY_TYPE)
    # the restarted historian records the last batch again: nothing new
    assert second.append_samples({"A": samples[-100:], "B": EVERY_TYPE[-3:]}) == 0
    assert second.append_events([event(4, T0 + 4)]) == 0
    assert second.append_samples({"A": [Sample(T0 + 500 * S, 500.0)], "C": [Sample(T0, 1)]}) == 2
    assert second.stats()[:3] == (501 + len(EVERY_TYPE) + 1, 5, 3)
    assert second.stats().bytes > 0


batches = st.lists(
    st.lists(
        st.tuples(
            st.sampled_from(["A", "B", "C"]),
            st.integers(min_value=0, max_value=40),  # few times: many duplicates
            st.one_of(
                st.floats(allow_nan=False),
                st.integers(-(2**63), 2**63 - 1),
                st.booleans(),
                st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=5),
            ),
            st.sampled_from([0, UNCERTAIN, BAD_NO_DATA]),
        ),
        max_size=30,
    ),
    max_size=6,
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batches=batches)
def test_any_batch_sequence_reads_back_as_the_sorted_unique_set(backend, batches) -> None:
    store = backend.open()
    try:
        check_batches(store, batches)
    finally:
        store.close()


def check_batches(store: HistoryStore, batches: list[list[tuple[str, int, object, int]]]) -> None:
    expected: dict[str, dict[int, Sample]] = {}
    for batch in batches:
        grouped: dict[str, list[Sample]] = {}
        new = 0
        for tag, k, value, status in batch:
            t_us = T0 + k * 1_000
            grouped.setdefault(tag, []).append(Sample(t_us, value, status))
            if t_us not in expected.setdefault(tag, {}):
                expected[tag][t_us] = Sample(t_us, value, status)  # the first write wins
                new += 1
        assert store.append_samples(grouped) == new
    for tag, by_time in expected.items():
        got, _ = read_all(store, tag, T0, T0 + S, 7)
        assert_same(got, [by_time[t] for t in sorted(by_time)])


# -- the two back ends' own structure --------------------------------------------------------


def test_sqlite_file_is_wal_with_a_without_rowid_sample_table(tmp_path: Path) -> None:
    path = tmp_path / "var" / "history.db"
    store = SQLiteStore(path)
    store.append_samples({"A": [Sample(T0, 1.0)]})
    store.close()
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA journal_mode").fetchone() == ("wal",)
    (sql,) = db.execute("SELECT sql FROM sqlite_master WHERE name = 'samples'").fetchone()
    assert "WITHOUT ROWID" in sql and "PRIMARY KEY (tag_id, t_us)" in sql
    assert db.execute("SELECT name FROM tags").fetchall() == [("A",)]
    db.close()


def test_postgres_partitions_per_day_brin_and_retention_by_dropping(pg_server, tmp_path: Path) -> None:
    backend_schema = "tpart_" + tmp_path.name.lower().replace("-", "_")[-20:]
    store = PostgresStore(pg_server.url, schema=backend_schema)
    try:
        store.append_samples({"A": [Sample(T0 + d * DAY_US + k, 1.0) for d in range(4) for k in range(3)]})
        with psycopg.connect(pg_server.url) as conn:

            def partitions() -> list[str]:
                rows = conn.execute(
                    "SELECT c.relname FROM pg_inherits i JOIN pg_class c ON c.oid = i.inhrelid "
                    "WHERE i.inhparent = %s::regclass ORDER BY 1",
                    (f"{backend_schema}.samples",),
                ).fetchall()
                return [r[0] for r in rows]

            assert partitions() == [
                "samples_p20251202",
                "samples_p20251203",
                "samples_p20251204",
                "samples_p20251205",
            ]
            (am,) = conn.execute(
                "SELECT am.amname FROM pg_class c JOIN pg_am am ON am.oid = c.relam "
                "WHERE c.oid = %s::regclass",
                (f"{backend_schema}.samples_t_brin",),
            ).fetchone()
            assert am == "brin"
            step = store.retention_step(T0 + 2 * DAY_US + 1, max_rows=1)
            assert step == (3, 0, False)  # one whole day dropped, more than max_rows at once
            assert partitions()[0] == "samples_p20251203"
            while not store.retention_step(T0 + 2 * DAY_US + 1, max_rows=1).done:
                pass
            assert partitions() == ["samples_p20251204", "samples_p20251205"]
            assert [s.t_us for s in store.read_raw("A", T0, T0 + 4 * DAY_US, limit=20).samples] == [
                T0 + 2 * DAY_US + 1,
                T0 + 2 * DAY_US + 2,
                *(T0 + d * DAY_US + k for d in (3,) for k in range(3)),
            ]
            conn.execute(f"DROP SCHEMA {backend_schema} CASCADE")  # type: ignore[call-overload]
            conn.commit()
    finally:
        store.close()


def test_open_store_picks_the_back_end_by_location(tmp_path: Path, pg_server) -> None:
    sqlite_store = open_store(tmp_path / "h.db")
    assert isinstance(sqlite_store, SQLiteStore)
    sqlite_store.close()
    uri_store = open_store(f"sqlite://{tmp_path / 'u.db'}")
    assert isinstance(uri_store, SQLiteStore) and uri_store.path == tmp_path / "u.db"
    uri_store.close()
    pg_store = open_store(pg_server.url)
    assert isinstance(pg_store, PostgresStore) and pg_store.schema == "tanklab"
    pg_store.close()
    assert store_location(tmp_path / "d.db", {}) == str(tmp_path / "d.db")
    assert store_location(tmp_path / "d.db", {"TANKLAB_HISTORIAN_URL": pg_server.url}) == pg_server.url
    with pytest.raises(ValueError, match="schema name"):
        PostgresStore(pg_server.url, schema="x; DROP TABLE y")


def test_a_reader_sees_tags_another_connection_interned_after_it_opened(backend) -> None:
    """The historian writes on one connection and serves reads on another: a tag first recorded
    after the reader opened is readable there, and listed."""
    where = backend.location()
    reader = backend.open(where)
    writer = backend.open(where)
    writer.append_samples({"PLC.LIC9.PV": [Sample(10, 0.5), Sample(20, 0.6)]})
    assert reader.read_raw("PLC.LIC9.PV", 0, 100, limit=10).samples == [Sample(10, 0.5), Sample(20, 0.6)]
    assert reader.bounds("PLC.LIC9.PV", 15) == (Sample(10, 0.5), Sample(20, 0.6))
    assert [(r.tag, r.first_us, r.last_us) for r in reader.tags()] == [("PLC.LIC9.PV", 10, 20)]
