"""The embedded store: one SQLite file in WAL mode (the historian's default).

Schema (``SCHEMA_VERSION`` 1)::

    tags    (id INTEGER PRIMARY KEY, name TEXT UNIQUE)                 -- tags interned once
    samples (tag_id, t_us, status, value, kind,
             PRIMARY KEY (tag_id, t_us)) WITHOUT ROWID                 -- one B-tree, no rowid
    events  (event_id BLOB PRIMARY KEY, t_us, event_type, source, severity, message, fields)
             + INDEX events_t (t_us, event_id)

**One value column with SQLite's own typing, and a kind** (decision 0040): ``value`` has no
declared type, so SQLite stores each value in its smallest record form: a float as an 8-byte
REAL, an int in 0 to 8 bytes by magnitude (0 and 1 in none), text as UTF-8, None as NULL. What
SQLite cannot tell apart is carried by ``kind``: 0 for the value as stored, 1 for a bool (stored
as the integer 0 or 1), 2 for a float NaN (SQLite binds NaN as NULL). ``kind`` is 0 for almost
every row and so is ``status`` (Good), and SQLite stores the integers 0 and 1 in the record header
alone: an analog sample costs its key (tag_id 1-2 bytes, t_us 6-8 bytes), 8 bytes of value and a
5-byte header. Four typed columns (real, int, bool, text) would cost a header byte more each.

Durability: WAL with ``synchronous=NORMAL``: a committed batch survives the historian's crash; a
power loss may lose the last batches (not corrupt the file). One connection, used by one thread
at a time (the historian's storage worker).
"""

from __future__ import annotations

import json
import math
import sqlite3
from collections.abc import Collection, Iterable, Iterator, Mapping
from pathlib import Path

from historian.store.base import (
    Bounds,
    EventCursor,
    EventPage,
    RawPage,
    RetentionStep,
    StoreStats,
    TagRange,
    check_limit,
    check_value,
    in_range,
)
from tanklab.history.model import EventRecord, Sample, Value

__all__ = ["SCHEMA_VERSION", "SQLiteStore"]

SCHEMA_VERSION = 1

_KIND_PLAIN = 0
_KIND_BOOL = 1
_KIND_NAN = 2

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS tags (id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE);
CREATE TABLE IF NOT EXISTS samples (
    tag_id INTEGER NOT NULL,
    t_us   INTEGER NOT NULL,
    status INTEGER NOT NULL,
    value,
    kind   INTEGER NOT NULL,
    PRIMARY KEY (tag_id, t_us)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS events (
    event_id   BLOB PRIMARY KEY,
    t_us       INTEGER NOT NULL,
    event_type TEXT NOT NULL,
    source     TEXT NOT NULL,
    severity   INTEGER NOT NULL,
    message    TEXT NOT NULL,
    fields     TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS events_t ON events (t_us, event_id);
"""


def _encode(value: Value) -> tuple[Value, int]:
    check_value(value)
    if isinstance(value, bool):
        return int(value), _KIND_BOOL
    if isinstance(value, float) and math.isnan(value):
        return None, _KIND_NAN
    return value, _KIND_PLAIN


def _decode(value: Value, kind: int) -> Value:
    if kind == _KIND_PLAIN:
        return value
    if kind == _KIND_BOOL:
        return bool(value)
    return math.nan


def _rows(tag_id: int, samples: Iterable[Sample]) -> Iterator[tuple[int, int, int, Value, int]]:
    for t_us, value, status in samples:
        v, kind = _encode(value)
        yield tag_id, t_us, status, v, kind


class SQLiteStore:
    """:class:`historian.store.base.HistoryStore` on one SQLite file (created if missing)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # autocommit mode: every write opens its own BEGIN ... COMMIT (one batch, one transaction)
        self._db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(_SCHEMA)
        row = self._db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        if row is None:
            self._db.execute("INSERT INTO meta VALUES ('schema_version', ?)", (SCHEMA_VERSION,))
        elif row[0] != SCHEMA_VERSION:
            self._db.close()
            raise ValueError(f"{self.path}: schema version {row[0]}, this historian reads {SCHEMA_VERSION}")
        self._tag_ids: dict[str, int] = dict(self._db.execute("SELECT name, id FROM tags"))

    def _read_id(self, tag: str) -> int | None:
        """The tag's id for a read: the cache, else the database (another connection, the
        historian's writer, may have interned it since this one opened)."""
        tag_id = self._tag_ids.get(tag)
        if tag_id is None:
            row = self._db.execute("SELECT id FROM tags WHERE name = ?", (tag,)).fetchone()
            if row is not None:
                tag_id = self._tag_ids[tag] = int(row[0])
        return tag_id

    # -- writes ---------------------------------------------------------------------------------

    def _tag_id(self, tag: str) -> tuple[int, int]:
        """The tag's id, interned if new, and the rows that interning wrote (0 or 1)."""
        tag_id = self._tag_ids.get(tag)
        if tag_id is not None:
            return tag_id, 0
        written = self._db.execute("INSERT OR IGNORE INTO tags (name) VALUES (?)", (tag,)).rowcount
        (tag_id,) = self._db.execute("SELECT id FROM tags WHERE name = ?", (tag,)).fetchone()
        self._tag_ids[tag] = tag_id
        return tag_id, written

    def append_samples(self, batch: Mapping[str, Iterable[Sample]]) -> int:
        """Store the batch in one transaction (``INSERT OR IGNORE``: the first write wins)."""
        db = self._db
        before = db.total_changes
        interned = 0
        db.execute("BEGIN IMMEDIATE")
        try:
            for tag, samples in batch.items():
                tag_id, written = self._tag_id(tag)
                interned += written
                db.executemany("INSERT OR IGNORE INTO samples VALUES (?, ?, ?, ?, ?)", _rows(tag_id, samples))
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            # a tag interned inside the rolled-back transaction is gone again
            self._tag_ids = dict(db.execute("SELECT name, id FROM tags"))
            raise
        # total_changes counts the interned tags' rows too
        return db.total_changes - before - interned

    def append_events(self, events: Iterable[EventRecord]) -> int:
        """Store the events in one transaction (``INSERT OR IGNORE`` by EventId)."""
        db = self._db
        before = db.total_changes
        rows = (
            (
                bytes(e.event_id),
                e.t_us,
                e.event_type,
                e.source,
                e.severity,
                e.message,
                json.dumps(e.fields, sort_keys=True, separators=(",", ":")),
            )
            for e in events
        )
        db.execute("BEGIN IMMEDIATE")
        try:
            db.executemany("INSERT OR IGNORE INTO events VALUES (?, ?, ?, ?, ?, ?, ?)", rows)
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        return db.total_changes - before

    # -- reads ----------------------------------------------------------------------------------

    def read_raw(
        self, tag: str, start_us: int, end_us: int, *, limit: int, after_us: int | None = None
    ) -> RawPage:
        check_limit(limit)
        tag_id = self._read_id(tag)
        if tag_id is None:
            return RawPage([], None)
        lo, hi, reverse = in_range(start_us, end_us, after_us)
        order = "DESC" if reverse else "ASC"
        rows = self._db.execute(
            "SELECT t_us, value, kind, status FROM samples WHERE tag_id = ? AND t_us >= ? AND t_us < ? "
            f"ORDER BY t_us {order} LIMIT ?",
            (tag_id, lo, hi, limit + 1),
        ).fetchall()
        more = len(rows) > limit
        samples = [Sample(t, _decode(v, k), s) for t, v, k, s in rows[:limit]]
        return RawPage(samples, samples[-1].t_us if more else None)

    def bounds(self, tag: str, t_us: int, *, good_only: bool = False) -> Bounds:
        tag_id = self._read_id(tag)
        if tag_id is None:
            return Bounds(None, None)
        good = " AND (status & 3221225472) = 0" if good_only else ""
        q = (
            "SELECT t_us, value, kind, status FROM samples "
            "WHERE tag_id = ? AND t_us {op} ?{good} ORDER BY t_us {o} LIMIT 1"
        )
        out: list[Sample | None] = []
        for op, o in (("<=", "DESC"), (">=", "ASC")):
            row = self._db.execute(q.format(op=op, good=good, o=o), (tag_id, t_us)).fetchone()
            out.append(None if row is None else Sample(row[0], _decode(row[1], row[2]), row[3]))
        return Bounds(out[0], out[1])

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
        check_limit(limit)
        lo, hi, reverse = in_range(start_us, end_us, None)
        where = ["t_us >= ?", "t_us < ?", "severity >= ?"]
        args: list[object] = [lo, hi, min_severity]
        if event_types is not None:
            types = list(event_types)
            if not types:
                return EventPage([], None)
            where.append(f"event_type IN ({','.join('?' * len(types))})")
            args += types
        if after is not None:
            where.append("(t_us, event_id) < (?, ?)" if reverse else "(t_us, event_id) > (?, ?)")
            args += [after[0], bytes(after[1])]
        order = "DESC" if reverse else "ASC"
        rows = self._db.execute(
            "SELECT t_us, event_id, event_type, source, severity, message, fields FROM events "
            f"WHERE {' AND '.join(where)} ORDER BY t_us {order}, event_id {order} LIMIT ?",
            (*args, limit + 1),
        ).fetchall()
        more = len(rows) > limit
        events = [
            EventRecord(t, bytes(i), ty, src, sev, msg, json.loads(f))
            for t, i, ty, src, sev, msg, f in rows[:limit]
        ]
        return EventPage(events, (events[-1].t_us, events[-1].event_id) if more else None)

    def tags(self) -> list[TagRange]:
        self._tag_ids = dict(self._db.execute("SELECT name, id FROM tags"))
        out = []
        for name, tag_id in sorted(self._tag_ids.items()):
            first = self._db.execute(
                "SELECT t_us FROM samples WHERE tag_id = ? ORDER BY t_us ASC LIMIT 1", (tag_id,)
            ).fetchone()
            if first is None:
                continue
            (last,) = self._db.execute(
                "SELECT t_us FROM samples WHERE tag_id = ? ORDER BY t_us DESC LIMIT 1", (tag_id,)
            ).fetchone()
            out.append(TagRange(name, first[0], last))
        return out

    # -- maintenance ----------------------------------------------------------------------------

    def retention_step(self, before_us: int, *, max_rows: int = 50_000) -> RetentionStep:
        """Delete at most ``max_rows`` samples (tag by tag, on the primary key) and as many events
        older than ``before_us``, in one transaction."""
        check_limit(max_rows)
        db = self._db
        budget = max_rows
        samples_deleted = 0
        db.execute("BEGIN IMMEDIATE")
        try:
            for tag_id in sorted(self._tag_ids.values()):
                if budget == 0:
                    break
                n = db.execute(
                    "DELETE FROM samples WHERE tag_id = ?1 AND t_us IN "
                    "(SELECT t_us FROM samples WHERE tag_id = ?1 AND t_us < ?2 ORDER BY t_us LIMIT ?3)",
                    (tag_id, before_us, budget),
                ).rowcount
                samples_deleted += n
                budget -= n
            events_deleted = db.execute(
                "DELETE FROM events WHERE event_id IN "
                "(SELECT event_id FROM events WHERE t_us < ? ORDER BY t_us LIMIT ?)",
                (before_us, max_rows),
            ).rowcount
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        done = budget > 0 and events_deleted < max_rows
        return RetentionStep(samples_deleted, events_deleted, done)

    def stats(self) -> StoreStats:
        (samples,) = self._db.execute("SELECT count(*) FROM samples").fetchone()
        (events,) = self._db.execute("SELECT count(*) FROM events").fetchone()
        (tags,) = self._db.execute("SELECT count(DISTINCT tag_id) FROM samples").fetchone()
        size = sum(p.stat().st_size for p in (self.path, Path(f"{self.path}-wal")) if p.exists())
        return StoreStats(samples, events, tags, size)

    def checkpoint(self) -> None:
        """Copy the WAL into the database file and truncate it (SQLite only: what bytes per value
        measures is then the one file)."""
        self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")

    def close(self) -> None:
        self._db.close()
