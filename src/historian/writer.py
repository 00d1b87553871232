"""The historian's store writer: the bounded buffer and the one worker thread that owns the store.

The stores are synchronous (sqlite3, psycopg), so the event loop never calls them: the collectors
hand their samples and events to :meth:`StoreWriter.put_samples` / :meth:`put_events` (a lock
and a notify, microseconds), and the worker thread takes batches of at most ``batch_max`` records
from the :class:`historian.collect.Backlog`, writes each in one transaction, and between two
batches runs one bounded retention step when one is due (:class:`historian.collect.RetentionPlan`).

No data lost:

* a write that fails (PostgreSQL down, a locked or full disk) gives its batch back to the front of
  the backlog, closes the store, and the worker reopens it every ``retry_s`` until it works; the
  backlog keeps at most ``capacity`` records meanwhile, the oldest dropped and counted;
* the stores are idempotent (a sample by tag and source time, an event by EventId), so a batch
  written twice (a failure after the commit) and a historian restarted on its own store duplicate
  nothing;
* when the store is first opened, the historian's own downtime is marked: each recorded tag whose
  newest stored sample is Good or Uncertain gets a BadNoCommunication marker 1 us after it
  (:func:`historian.collect.restart_markers`), before any new sample is written.

On :meth:`stop` the worker writes what is buffered (one attempt per batch while the store works),
closes the store and ends; what it could not write is logged and counted as dropped.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from datetime import UTC, datetime, timedelta

from historian.collect import Backlog, RetentionPlan, restart_markers
from historian.store import HistoryStore, open_store
from tanklab.history.model import EventRecord, Sample
from tanklab_io.ua_client import describe_error

log = logging.getLogger(__name__)

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def store_kind(location: str) -> str:
    """``postgresql`` for a PostgreSQL URL, else ``sqlite``."""
    return "postgresql" if location.startswith(("postgresql://", "postgres://")) else "sqlite"


def _utc_now_us() -> int:
    return (datetime.now(UTC) - _EPOCH) // timedelta(microseconds=1)


class StoreWriter:
    """Owns the store on a worker thread (module docstring)."""

    def __init__(
        self,
        location: str,
        *,
        capacity: int,
        batch_max: int,
        retry_s: float,
        retention: RetentionPlan,
        retention_rows: int,
        recorded: Collection[str] = (),
        opener: Callable[[str], HistoryStore] = open_store,
        utc_now_us: Callable[[], int] | None = None,
    ) -> None:
        self.location = location
        self.kind = store_kind(location)
        self.batch_max = batch_max
        self.retry_s = retry_s
        self.retention = retention
        self.retention_rows = retention_rows
        self.recorded = frozenset(recorded)
        self.opener = opener
        self.utc_now_us = utc_now_us or _utc_now_us
        self._backlog = Backlog(capacity)
        self._cond = threading.Condition()
        self._stopping = False
        self._thread: threading.Thread | None = None
        self.store: HistoryStore | None = None
        self.available = False
        self.last_error = ""
        self.stored = 0
        self.events = 0
        self.retention_deleted = 0
        self.markers = 0
        self.opened = threading.Event()
        """Set once the store was opened and the restart markers written."""

    # ---- the collectors' side (event loop) ------------------------------------------------------

    def put_samples(self, batch: Mapping[str, Sequence[Sample]]) -> None:
        with self._cond:
            self._backlog.add_samples(batch)
            self._cond.notify()

    def put_events(self, events: Sequence[EventRecord]) -> None:
        with self._cond:
            self._backlog.add_events(events)
            self._cond.notify()

    @property
    def buffered(self) -> int:
        with self._cond:
            return len(self._backlog)

    @property
    def dropped(self) -> int:
        with self._cond:
            return self._backlog.dropped

    # ---- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="historian-store", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        """Write what is buffered (bounded by ``timeout_s``), close the store, end the thread."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("historian store writer did not finish within %.0f s", timeout_s)

    # ---- the worker -----------------------------------------------------------------------------

    def _open(self) -> bool:
        try:
            store = self.opener(self.location)
        except Exception as e:
            self._failed("open", e)
            return False
        try:
            self._mark_restart(store)
        except Exception as e:
            store.close()
            self._failed("restart markers", e)
            return False
        self.store = store
        self.available = True
        self.opened.set()
        return True

    def _mark_restart(self, store: HistoryStore) -> None:
        if self.opened.is_set():
            return  # markers are for the process's start only: a reopened store lost nothing
        last: dict[str, Sample] = {}
        for rng in store.tags():
            if self.recorded and rng.tag not in self.recorded:
                continue
            page = store.read_raw(rng.tag, rng.last_us, rng.last_us, limit=1)
            if page.samples:
                last[rng.tag] = page.samples[0]
        markers = restart_markers(last)
        if markers:
            store.append_samples(markers)
            self.markers = len(markers)
            log.info("historian: marked the gap since the last run in %d tags", len(markers))

    def _failed(self, what: str, e: BaseException) -> None:
        reason = f"{what}: {describe_error(e)}"
        if self.available or reason != self.last_error:
            log.warning("historian store %s: %s; retrying every %.1f s", self.kind, reason, self.retry_s)
        self.available = False
        self.last_error = reason

    def _close(self) -> None:
        store, self.store = self.store, None
        if store is not None:
            try:
                store.close()
            except Exception as e:
                log.info("closing the store: %s", describe_error(e))

    def _wait(self, seconds: float) -> None:
        with self._cond:
            if not self._stopping:
                self._cond.wait(seconds)

    def _run(self) -> None:
        failures_at_stop = 0
        while True:
            if self.store is None:
                if self._open():
                    continue
                with self._cond:
                    if self._stopping and (failures_at_stop := failures_at_stop + 1) > 1:
                        break
                self._wait(self.retry_s)
                continue
            with self._cond:
                while not self._backlog and not self._stopping and not self.retention.due(time.monotonic()):
                    self._cond.wait(1.0)
                if self._stopping and not self._backlog:
                    break
                batch = self._backlog.take(self.batch_max)
            if batch.items:
                try:
                    samples, events = batch.samples, batch.events
                    new = self.store.append_samples(samples) if samples else 0
                    new_events = self.store.append_events(events) if events else 0
                except Exception as e:
                    with self._cond:
                        self._backlog.give_back(batch)
                    self._failed("write", e)
                    self._close()
                    if not self._stopping:
                        self._wait(self.retry_s)
                    continue
                self.stored += new
                self.events += new_events
                self.available = True
            if self.retention.due(time.monotonic()):
                self._retention_step()
        left = self.buffered
        if left:
            log.error("historian: %d records not stored at stop (store %s unavailable)", left, self.kind)
            with self._cond:
                self._backlog.dropped += left
                self._backlog.take(left)
        self._close()

    def _retention_step(self) -> None:
        assert self.store is not None
        try:
            step = self.store.retention_step(
                self.retention.cutoff_us(self.utc_now_us()), max_rows=self.retention_rows
            )
        except Exception as e:
            log.warning("historian retention step failed: %s", describe_error(e))
            self.retention.stepped(True, time.monotonic())
            return
        self.retention_deleted += step.samples_deleted + step.events_deleted
        self.retention.stepped(step.done, time.monotonic())
