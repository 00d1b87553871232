"""The historian's storage interface: one Protocol, the value types its reads return.

Every store keeps **samples** (a tag's value, OPC UA status and source time) and **events**
(conditions' state changes, audit events) and answers the reads OPC UA Part 11 needs:

* raw samples of one tag in a time range, ordered, a page at a time (``ReadRawModifiedDetails``
  with continuation points): forward when ``start_us <= end_us`` (``start_us <= t < end_us``),
  **reverse** when ``start_us > end_us`` (``end_us < t <= start_us``, newest first): the start is
  always the inclusive bound (Part 11, 6.4.3.2). ``start_us == end_us`` reads the one sample at
  that time, if any;
* the bounding samples of a time (last at or before, first at or after: interpolation, Part 13);
* events in a range with filters on event type and minimum severity (``ReadEventDetails``);
* the tags with their first and last times.

Writes are **idempotent**: a sample whose ``(tag, t_us)`` is stored already is ignored, and so is
an event whose EventId is (the first write wins), so a historian that restarts and records again
what it had recorded duplicates nothing. Retention deletes what is older than a time in bounded
steps, one short transaction each, so a collector writing between the steps is never held up for
long. The stores are synchronous (sqlite3, psycopg): the historian calls them from one worker
thread, never from its event loop.

Times are UTC microseconds since 1970 (``*_us``), as in :mod:`tanklab.history.model`.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from typing import NamedTuple, Protocol, runtime_checkable

from tanklab.history.model import EventRecord, Sample, Value

__all__ = [
    "DAY_US",
    "Bounds",
    "EventCursor",
    "EventPage",
    "HistoryStore",
    "RawPage",
    "RetentionStep",
    "StoreStats",
    "TagRange",
    "check_limit",
    "check_value",
    "in_range",
]

DAY_US = 86_400_000_000
"""One day [us]: the PostgreSQL store's partition width."""

INT64_MIN = -(2**63)
INT64_MAX = 2**63 - 1


class RawPage(NamedTuple):
    """One page of a raw read: the samples, and where the next page starts.

    ``cursor`` is the time [us] of the last sample returned when more remain in the range (pass
    it back as ``after_us`` for the next page: a continuation point), ``None`` when the range is
    exhausted.
    """

    samples: list[Sample]
    cursor: int | None


class Bounds(NamedTuple):
    """The samples bounding a time: ``before`` is the last at or before it, ``after`` the first at
    or after it (both are the same sample when one is stored at exactly that time)."""

    before: Sample | None
    after: Sample | None


EventCursor = tuple[int, bytes]
"""Where an event read stopped: the last event's ``(t_us, event_id)`` (events are ordered by time,
then EventId, since several can share a time)."""


class EventPage(NamedTuple):
    """One page of an event read; ``cursor`` as in :class:`RawPage`."""

    events: list[EventRecord]
    cursor: EventCursor | None


class TagRange(NamedTuple):
    """A recorded tag and the times [us] of its first and last sample."""

    tag: str
    first_us: int
    last_us: int


class StoreStats(NamedTuple):
    """What a store holds: rows and the bytes they take on disk (tables, indexes, the WAL)."""

    samples: int
    events: int
    tags: int
    bytes: int


class RetentionStep(NamedTuple):
    """One bounded step of retention: the rows it deleted, and whether older rows remain."""

    samples_deleted: int
    events_deleted: int
    done: bool


@runtime_checkable
class HistoryStore(Protocol):
    """The historian's storage (SQLite and PostgreSQL implement it; one test suite runs on both)."""

    def append_samples(self, batch: Mapping[str, Iterable[Sample]]) -> int:
        """Store the samples of many tags in one transaction; return how many were new (a sample
        whose ``(tag, t_us)`` is stored already is ignored)."""
        ...

    def append_events(self, events: Iterable[EventRecord]) -> int:
        """Store events in one transaction; return how many were new (by EventId)."""
        ...

    def read_raw(
        self, tag: str, start_us: int, end_us: int, *, limit: int, after_us: int | None = None
    ) -> RawPage:
        """At most ``limit`` (>= 1) samples of ``tag`` in the range, ordered (reverse when
        ``start_us > end_us``), continuing after ``after_us`` (a page's ``cursor``). An unknown
        tag reads as empty."""
        ...

    def bounds(self, tag: str, t_us: int, *, good_only: bool = False) -> Bounds:
        """The samples bounding ``t_us``; ``good_only`` skips samples whose status is not Good."""
        ...

    def read_events(
        self,
        start_us: int,
        end_us: int,
        *,
        limit: int,
        event_types: Collection[str] | None = None,
        min_severity: int = 0,
        after: EventCursor | None = None,
    ) -> EventPage:
        """At most ``limit`` events in the range (same order and bounds as :meth:`read_raw`)
        whose type is one of ``event_types`` (``None``: any; the type NodeIds exactly as stored,
        subtypes are the caller's to expand) and whose severity is >= ``min_severity``."""
        ...

    def tags(self) -> list[TagRange]:
        """Every tag with samples, by name."""
        ...

    def retention_step(self, before_us: int, *, max_rows: int = 50_000) -> RetentionStep:
        """Delete samples and events older than ``before_us`` (``t < before_us``), at most about
        ``max_rows`` of each (or one whole partition) in one short transaction. Call again until
        ``done``."""
        ...

    def stats(self) -> StoreStats:
        """Rows and bytes on disk (counts every row: a scan, not for the collection path)."""
        ...

    def close(self) -> None:
        """Commit nothing pending (every write commits itself) and release the connection."""
        ...


def check_limit(limit: int) -> None:
    """A read's page size must be a positive int."""
    if isinstance(limit, bool) or not isinstance(limit, int):
        raise TypeError(f"limit must be an int, not {type(limit).__name__}")
    if limit < 1:
        raise ValueError(f"limit must be >= 1, got {limit}")


def check_value(value: Value) -> None:
    """What a store can hold: a float, an int in int64, a bool, a str without NUL characters
    (PostgreSQL's text cannot hold them; both stores refuse them alike) or None."""
    if isinstance(value, str):
        if "\x00" in value:
            raise ValueError("a text value may not contain NUL characters")
        return
    if value is None or isinstance(value, bool | float):
        return
    if isinstance(value, int):
        if not INT64_MIN <= value <= INT64_MAX:
            raise ValueError(f"integer value {value} does not fit in 64 bits")
        return
    raise TypeError(f"a sample's value must be float, int, bool, str or None, not {type(value).__name__}")


def in_range(start_us: int, end_us: int, after: int | None) -> tuple[int, int, bool]:
    """The half-open read window ``[lo, hi)`` in time order and whether the read is reverse.

    Forward (``start <= end``): ``lo = start`` (or just after ``after``), ``hi = end``; a read with
    ``start == end`` covers that one microsecond. Reverse: ``(end, start]``, i.e. ``lo = end + 1``,
    ``hi = start + 1`` (or ``after``, exclusive).
    """
    if start_us == end_us:
        lo, hi, reverse = start_us, start_us + 1, False
    elif start_us < end_us:
        lo, hi, reverse = start_us, end_us, False
    else:
        lo, hi, reverse = end_us + 1, start_us + 1, True
    if after is not None:
        if reverse:
            hi = min(hi, after)
        else:
            lo = max(lo, after + 1)
    return lo, hi, reverse


def same_value(a: Value, b: Value) -> bool:
    """Equality of two values as stores round-trip them (NaN equals NaN, bool is not int)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        return math.isnan(b)
    return a == b


def events_sorted(events: Sequence[EventRecord]) -> list[EventRecord]:
    """Events in the stores' order: by time, then EventId."""
    return sorted(events, key=lambda e: (e.t_us, e.event_id))
