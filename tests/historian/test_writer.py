"""The store writer's thread: buffering while the store is unavailable, restart markers, retention.

The store is a real SQLite file; "unavailable" is a real failure to open it (where its directory
should be is a file), and it becomes available when the directory is made there. Waits are bounded
(``wait_until_sync``) and assert on the writer's counts and the store's contents.
"""

from __future__ import annotations

from pathlib import Path

from historian.collect import BAD_NO_COMMUNICATION, RetentionPlan
from historian.store.sqlite import SQLiteStore
from historian.writer import StoreWriter
from tanklab.history.model import EventRecord, Sample
from tanklab_testing.waits import wait_until_sync

DAY_US = 86_400_000_000
END = 2**62


def writer(
    location: Path, *, capacity: int = 1000, now_us: int = 0, days: float = 3650.0, batch_max: int = 7
) -> StoreWriter:
    return StoreWriter(
        str(location),
        capacity=capacity,
        batch_max=batch_max,
        retry_s=0.05,
        retention=RetentionPlan(days, every_s=3600.0),
        retention_rows=100,
        utc_now_us=lambda: now_us,
    )


def raw(location: Path, tag: str) -> list[Sample]:
    store = SQLiteStore(location)
    try:
        return store.read_raw(tag, 0, END, limit=10_000).samples
    finally:
        store.close()


def test_an_unavailable_store_buffers_bounded_then_gets_everything_kept(tmp_path: Path) -> None:
    location = tmp_path / "later" / "history.db"
    location.parent.write_text("not a directory")
    w = writer(location, capacity=50)
    w.start()
    try:
        w.put_samples({"A": [Sample(t, float(t)) for t in range(30)]})
        w.put_events([EventRecord(5, b"e1", "i=2041", "PLC", 100, "m", {})])
        wait_until_sync(lambda: w.last_error.startswith("open:"), 10, what="the open's failure", poll_s=0.05)
        assert (w.available, w.buffered, w.dropped) == (False, 31, 0)
        # 30 more samples than the buffer holds with what waits: the oldest 11 go
        w.put_samples({"B": [Sample(t, float(t)) for t in range(30)]})
        assert (w.buffered, w.dropped) == (50, 11)
        location.parent.unlink()
        # the store comes back (the writer's retry may make the directory itself first)
        location.parent.mkdir(exist_ok=True)
        wait_until_sync(
            lambda: w.buffered == 0 and w.stored == 49, 10, what="the backlog stored", poll_s=0.05
        )
    finally:
        w.stop()
    # the oldest 11 records were A@0..10; the event came after A, so it was kept
    assert [s.t_us for s in raw(location, "A")] == list(range(11, 30))
    assert len(raw(location, "B")) == 30
    assert (w.stored, w.events, w.dropped, w.available) == (49, 1, 11, True)


def test_a_restarted_writer_marks_the_downtime_and_duplicates_nothing(tmp_path: Path) -> None:
    location = tmp_path / "history.db"
    first = writer(location)
    first.start()
    gap = Sample(15, None, BAD_NO_COMMUNICATION)
    first.put_samples({"A": [Sample(10, 1.0), Sample(20, 2.0)], "G": [gap]})
    first.stop()
    assert first.stored == 3
    second = writer(location)
    second.start()
    try:
        wait_until_sync(second.opened.is_set, 10, what="the store opened", poll_s=0.05)
        # what the first run stored already (a tier's unchanged value, sent again) is no new row
        second.put_samples({"A": [Sample(20, 2.0), Sample(30, 3.0)]})
        wait_until_sync(lambda: second.buffered == 0, 10, what="written", poll_s=0.05)
    finally:
        second.stop()
    assert raw(location, "A") == [
        Sample(10, 1.0),
        Sample(20, 2.0),
        Sample(21, None, BAD_NO_COMMUNICATION),  # the downtime's marker, 1 us after the last
        Sample(30, 3.0),
    ]
    assert raw(location, "G") == [gap]  # Bad already: no marker
    assert (second.markers, second.stored) == (1, 1)


def test_retention_deletes_what_is_older_than_the_days_between_batches(tmp_path: Path) -> None:
    location = tmp_path / "history.db"
    w = writer(location, now_us=10 * DAY_US, days=2.0, batch_max=100)
    w.put_samples({"A": [Sample(t * DAY_US, float(t)) for t in range(10)]})  # one batch, then a step
    w.start()
    try:
        wait_until_sync(
            lambda: w.buffered == 0 and w.retention_deleted == 8, 10, what="retention ran", poll_s=0.05
        )
    finally:
        w.stop()
    # cutoff 10 - 2 = 8 days: days 0..7 deleted, 8 and 9 kept
    assert [s.t_us // DAY_US for s in raw(location, "A")] == [8, 9]
