"""The PostgreSQL store (psycopg 3): for sites that outgrow one SQLite file.

Schema (in its own PostgreSQL schema, ``tanklab`` unless told; ``SCHEMA_VERSION`` 1)::

    tags    (id integer identity PRIMARY KEY, name text UNIQUE)
    samples (t timestamptz, tag_id integer, status integer,
             v_real float8, v_int int8, v_bool bool, v_text text,
             PRIMARY KEY (tag_id, t)) PARTITION BY RANGE (t)        -- one partition per UTC day
             + BRIN index on t (time-range scans across tags: retention, export)
    events  (event_id bytea PRIMARY KEY, t timestamptz, event_type, source, severity, message,
             fields jsonb) + INDEX (t, event_id)

* **Time** is ``timestamptz`` (microseconds, as the model's ``t_us``), so the tables read naturally
  in SQL; ``t_us`` converts exactly both ways: in with ``'epoch' + t_us * interval '1 us'`` (exact
  below 2**53 us, the year 2255), out with ``extract(epoch ...) * 1e6`` (numeric, exact).
* **Values** are typed columns, at most one non-NULL (NULLs cost a bit in the row's bitmap); the
  columns are ordered so an analog row packs without padding (8 + 4 + 4 + 8 bytes).
* **Status** is the OPC UA uint32 stored in an int4 as two's complement (Bad codes are >= 2**31).
* **Partitions** ``samples_pYYYYMMDD`` are created on demand, in the batch's transaction, for the
  days a batch touches. Retention drops whole partitions older than the limit (no vacuum debt),
  then deletes the partial day's rows in bounded chunks.
* **Batches** go by binary ``COPY`` into a temporary staging table, then one
  ``INSERT ... SELECT ... ON CONFLICT DO NOTHING`` (idempotent; the first write wins), in one
  transaction.

One connection, used by one thread at a time (the historian's storage worker).
"""

from __future__ import annotations

import json
import re
from collections.abc import Collection, Iterable, Mapping
from datetime import UTC, datetime, timedelta
from typing import Any

import psycopg
from psycopg.types.json import Jsonb

from historian.store.base import (
    DAY_US,
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

__all__ = ["SCHEMA_VERSION", "PostgresStore", "day_partition"]

SCHEMA_VERSION = 1

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_US = timedelta(microseconds=1)
_SCHEMA_NAME = re.compile(r"^[a-z_][a-z0-9_]{0,62}$")
_PARTITION = re.compile(r"^samples_p(\d{8})$")
_GOOD_MASK_I32 = -0x4000_0000  # 0xC000_0000 as a signed int4: the status's severity bits

_T_US = "(extract(epoch FROM t) * 1000000)::int8"


_MIN_US = (datetime(1, 1, 2, tzinfo=UTC) - EPOCH) // _US
_MAX_US = (datetime(9999, 12, 30, tzinfo=UTC) - EPOCH) // _US


def _ts(t_us: int) -> datetime:
    """``t_us`` as an aware datetime (exact: integer timedelta arithmetic), a query's bound
    clamped to the years 1..9999 that datetime holds (a read "to the end of time" works)."""
    return EPOCH + timedelta(microseconds=min(max(t_us, _MIN_US), _MAX_US))


def _to_i32(status: int) -> int:
    return status - 0x1_0000_0000 if status >= 0x8000_0000 else status


def _from_i32(status: int) -> int:
    return status & 0xFFFF_FFFF


def day_partition(day: int) -> tuple[str, str, str]:
    """The partition of UTC day ``day`` (days since 1970-01-01): its name and bounds (ISO)."""
    start = EPOCH + timedelta(days=day)
    end = start + timedelta(days=1)
    return f"samples_p{start:%Y%m%d}", start.isoformat(), end.isoformat()


def _encode(value: Value) -> tuple[float | None, int | None, bool | None, str | None]:
    check_value(value)
    if value is None:
        return None, None, None, None
    if isinstance(value, bool):
        return None, None, value, None
    if isinstance(value, float):
        return value, None, None, None
    if isinstance(value, int):
        return None, value, None, None
    return None, None, None, value


def _decode(v_real: float | None, v_int: int | None, v_bool: bool | None, v_text: str | None) -> Value:
    if v_real is not None:
        return v_real
    if v_int is not None:
        return v_int
    if v_bool is not None:
        return v_bool
    return v_text


class PostgresStore:
    """:class:`historian.store.base.HistoryStore` on PostgreSQL (schema created if missing).

    ``url`` is a libpq URL (``postgresql://user@host:port/db``: ``TANKLAB_HISTORIAN_URL``);
    ``schema`` the PostgreSQL schema the tables live in (one historian, one schema).
    """

    def __init__(self, url: str, *, schema: str = "tanklab", connect_timeout_s: float = 10.0) -> None:
        if not _SCHEMA_NAME.match(schema):
            raise ValueError(f"schema name {schema!r}: lower-case letters, digits and _ only")
        self.schema = schema
        self._conn = psycopg.connect(url, autocommit=True, connect_timeout=max(1, round(connect_timeout_s)))
        try:
            self._create_schema()
        except BaseException:
            self._conn.close()
            raise
        self._tag_ids: dict[str, int] = {}
        self._partitions: set[int] = set()
        self._reload()

    def _create_schema(self) -> None:
        s = self.schema
        with self._conn.transaction():
            # one creator at a time (two historians opening one new database)
            self._conn.execute("SELECT pg_advisory_xact_lock(hashtext(%s))", (f"tanklab-historian:{s}",))
            for stmt in (
                f"CREATE SCHEMA IF NOT EXISTS {s}",
                f"CREATE TABLE IF NOT EXISTS {s}.meta (key text PRIMARY KEY, value text NOT NULL)",
                f"CREATE TABLE IF NOT EXISTS {s}.tags "
                "(id integer GENERATED ALWAYS AS IDENTITY PRIMARY KEY, name text NOT NULL UNIQUE)",
                f"CREATE TABLE IF NOT EXISTS {s}.samples ("
                "t timestamptz NOT NULL, tag_id integer NOT NULL, status integer NOT NULL, "
                "v_real double precision, v_int bigint, v_bool boolean, v_text text, "
                "PRIMARY KEY (tag_id, t)) PARTITION BY RANGE (t)",
                f"CREATE INDEX IF NOT EXISTS samples_t_brin ON {s}.samples USING brin (t)",
                f"CREATE TABLE IF NOT EXISTS {s}.events ("
                "event_id bytea PRIMARY KEY, t timestamptz NOT NULL, event_type text NOT NULL, "
                "source text NOT NULL, severity integer NOT NULL, message text NOT NULL, "
                "fields jsonb NOT NULL)",
                f"CREATE INDEX IF NOT EXISTS events_t ON {s}.events (t, event_id)",
            ):
                self._conn.execute(stmt)
            row = self._conn.execute(f"SELECT value FROM {s}.meta WHERE key = 'schema_version'").fetchone()
            if row is None:
                self._conn.execute(
                    f"INSERT INTO {s}.meta VALUES ('schema_version', %s)",
                    (str(SCHEMA_VERSION),),
                )
            elif row[0] != str(SCHEMA_VERSION):
                raise ValueError(f"schema {s}: version {row[0]}, this historian reads {SCHEMA_VERSION}")
        self._conn.execute(
            "CREATE TEMP TABLE IF NOT EXISTS samples_stage (tag_id integer, t_us bigint, status integer, "
            "v_real double precision, v_int bigint, v_bool boolean, v_text text) ON COMMIT DELETE ROWS"
        )

    def _sql(self, query: str, args: Any = None) -> psycopg.Cursor[Any]:
        return self._conn.execute(query, args)

    def _reload(self) -> None:
        """The tag ids and the partitions as the database has them (after a rollback, too)."""
        s = self.schema
        self._tag_ids = dict(self._sql(f"SELECT name, id FROM {s}.tags").fetchall())
        rows = self._sql(
            "SELECT c.relname FROM pg_inherits i JOIN pg_class c ON c.oid = i.inhrelid "
            "WHERE i.inhparent = %s::regclass",
            (f"{s}.samples",),
        ).fetchall()
        self._partitions = set()
        for (name,) in rows:
            m = _PARTITION.match(name)
            if m:
                day = datetime.strptime(m.group(1), "%Y%m%d").replace(tzinfo=UTC)
                self._partitions.add((day - EPOCH).days)

    # -- writes ---------------------------------------------------------------------------------

    def _ensure_partition(self, day: int) -> None:
        name, lo, hi = day_partition(day)
        self._sql(
            f"CREATE TABLE IF NOT EXISTS {self.schema}.{name} PARTITION OF {self.schema}.samples "
            f"FOR VALUES FROM ('{lo}') TO ('{hi}')"
        )
        self._partitions.add(day)

    def _intern(self, tags: Iterable[str]) -> None:
        new = [t for t in tags if t not in self._tag_ids]
        if not new:
            return
        s = self.schema
        self._sql(
            f"INSERT INTO {s}.tags (name) SELECT unnest(%s::text[]) ON CONFLICT (name) DO NOTHING", (new,)
        )
        self._tag_ids.update(
            self._sql(f"SELECT name, id FROM {s}.tags WHERE name = ANY(%s)", (new,)).fetchall()
        )

    def append_samples(self, batch: Mapping[str, Iterable[Sample]]) -> int:
        """COPY the batch into the staging table, then insert what is new, in one transaction."""
        s = self.schema
        days: set[int] = set()
        try:
            with self._conn.transaction():
                self._intern(batch)
                with self._conn.cursor() as cur:
                    with cur.copy(
                        "COPY pg_temp.samples_stage (tag_id, t_us, status, v_real, v_int, v_bool, v_text) "
                        "FROM STDIN (FORMAT BINARY)"
                    ) as copy:
                        copy.set_types(["int4", "int8", "int4", "float8", "int8", "bool", "text"])
                        write = copy.write_row
                        for tag, samples in batch.items():
                            tag_id = self._tag_ids[tag]
                            for t_us, value, status in samples:
                                days.add(t_us // DAY_US)
                                write((tag_id, t_us, _to_i32(status), *_encode(value)))
                    for day in sorted(days - self._partitions):
                        self._ensure_partition(day)
                    cur.execute(
                        f"INSERT INTO {s}.samples (t, tag_id, status, v_real, v_int, v_bool, v_text) "
                        "SELECT timestamptz 'epoch' + t_us * interval '1 microsecond', tag_id, status, "
                        "v_real, v_int, v_bool, v_text FROM pg_temp.samples_stage "
                        "ON CONFLICT DO NOTHING"
                    )
                    return max(cur.rowcount, 0)
        except BaseException:
            self._reload()
            raise

    def append_events(self, events: Iterable[EventRecord]) -> int:
        rows = [
            (
                bytes(e.event_id),
                _ts(e.t_us),
                e.event_type,
                e.source,
                e.severity,
                e.message,
                Jsonb(e.fields),
            )
            for e in events
        ]
        if not rows:
            return 0
        with self._conn.transaction(), self._conn.cursor() as cur:
            cur.executemany(
                f"INSERT INTO {self.schema}.events VALUES (%s, %s, %s, %s, %s, %s, %s) "
                "ON CONFLICT (event_id) DO NOTHING",
                rows,
                returning=False,
            )
            return max(cur.rowcount, 0)

    # -- reads ----------------------------------------------------------------------------------

    def _read_id(self, tag: str) -> int | None:
        """The tag's id for a read: the cache, else the database (another connection, the
        historian's writer, may have interned it since this one opened)."""
        tag_id = self._tag_ids.get(tag)
        if tag_id is None:
            row = self._sql(f"SELECT id FROM {self.schema}.tags WHERE name = %s", (tag,)).fetchone()
            if row is not None:
                tag_id = self._tag_ids[tag] = int(row[0])
        return tag_id

    def read_raw(
        self, tag: str, start_us: int, end_us: int, *, limit: int, after_us: int | None = None
    ) -> RawPage:
        check_limit(limit)
        tag_id = self._read_id(tag)
        if tag_id is None:
            return RawPage([], None)
        lo, hi, reverse = in_range(start_us, end_us, after_us)
        order = "DESC" if reverse else "ASC"
        rows = self._sql(
            f"SELECT {_T_US}, status, v_real, v_int, v_bool, v_text FROM {self.schema}.samples "
            f"WHERE tag_id = %s AND t >= %s AND t < %s ORDER BY t {order} LIMIT %s",
            (tag_id, _ts(lo), _ts(hi), limit + 1),
        ).fetchall()
        more = len(rows) > limit
        samples = [Sample(t, _decode(r, i, b, x), _from_i32(st)) for t, st, r, i, b, x in rows[:limit]]
        return RawPage(samples, samples[-1].t_us if more else None)

    def bounds(self, tag: str, t_us: int, *, good_only: bool = False) -> Bounds:
        tag_id = self._read_id(tag)
        if tag_id is None:
            return Bounds(None, None)
        good = f" AND (status & {_GOOD_MASK_I32}) = 0" if good_only else ""
        out: list[Sample | None] = []
        for op, order in (("<=", "DESC"), (">=", "ASC")):
            row = self._sql(
                f"SELECT {_T_US}, status, v_real, v_int, v_bool, v_text FROM {self.schema}.samples "
                f"WHERE tag_id = %s AND t {op} %s{good} ORDER BY t {order} LIMIT 1",
                (tag_id, _ts(t_us)),
            ).fetchone()
            out.append(None if row is None else Sample(row[0], _decode(*row[2:]), _from_i32(row[1])))
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
        where = ["t >= %s", "t < %s", "severity >= %s"]
        args: list[object] = [_ts(lo), _ts(hi), min_severity]
        if event_types is not None:
            where.append("event_type = ANY(%s)")
            args.append(list(event_types))
        if after is not None:
            where.append("(t, event_id) < (%s, %s)" if reverse else "(t, event_id) > (%s, %s)")
            args += [_ts(after[0]), bytes(after[1])]
        order = "DESC" if reverse else "ASC"
        rows = self._sql(
            f"SELECT {_T_US}, event_id, event_type, source, severity, message, fields "
            f"FROM {self.schema}.events WHERE {' AND '.join(where)} "
            f"ORDER BY t {order}, event_id {order} LIMIT %s",
            (*args, limit + 1),
        ).fetchall()
        more = len(rows) > limit
        events = [
            EventRecord(t, bytes(i), ty, src, sev, msg, f if isinstance(f, dict) else json.loads(f))
            for t, i, ty, src, sev, msg, f in rows[:limit]
        ]
        return EventPage(events, (events[-1].t_us, events[-1].event_id) if more else None)

    def tags(self) -> list[TagRange]:
        s = self.schema
        self._tag_ids = dict(self._sql(f"SELECT name, id FROM {s}.tags").fetchall())
        out = []
        for name, tag_id in sorted(self._tag_ids.items()):
            first = self._sql(
                f"SELECT {_T_US} FROM {s}.samples WHERE tag_id = %s ORDER BY t ASC LIMIT 1", (tag_id,)
            ).fetchone()
            if first is None:
                continue
            last = self._sql(
                f"SELECT {_T_US} FROM {s}.samples WHERE tag_id = %s ORDER BY t DESC LIMIT 1", (tag_id,)
            ).fetchone()
            assert last is not None
            out.append(TagRange(name, first[0], last[0]))
        return out

    # -- maintenance ----------------------------------------------------------------------------

    def retention_step(self, before_us: int, *, max_rows: int = 50_000) -> RetentionStep:
        """Drop the oldest partition wholly older than ``before_us`` if there is one; otherwise
        delete at most ``max_rows`` older samples of the partial day; and at most ``max_rows``
        older events. One transaction."""
        check_limit(max_rows)
        s = self.schema
        whole = sorted(d for d in self._partitions if (d + 1) * DAY_US <= before_us)
        try:
            with self._conn.transaction():
                if whole:
                    name = day_partition(whole[0])[0]
                    row = self._sql(f"SELECT count(*) FROM {s}.{name}").fetchone()
                    samples_deleted = row[0] if row else 0
                    self._sql(f"DROP TABLE {s}.{name}")
                    self._partitions.discard(whole[0])
                else:
                    samples_deleted = self._sql(
                        f"DELETE FROM {s}.samples WHERE (tag_id, t) IN "
                        f"(SELECT tag_id, t FROM {s}.samples WHERE t < %s LIMIT %s)",
                        (_ts(before_us), max_rows),
                    ).rowcount
                events_deleted = self._sql(
                    f"DELETE FROM {s}.events WHERE event_id IN "
                    f"(SELECT event_id FROM {s}.events WHERE t < %s ORDER BY t LIMIT %s)",
                    (_ts(before_us), max_rows),
                ).rowcount
        except BaseException:
            self._reload()
            raise
        done = not whole and samples_deleted < max_rows and events_deleted < max_rows
        return RetentionStep(samples_deleted, events_deleted, done)

    def stats(self) -> StoreStats:
        s = self.schema

        def one(query: str) -> int:
            row = self._sql(query).fetchone()
            return int(row[0]) if row and row[0] is not None else 0

        samples = one(f"SELECT count(*) FROM {s}.samples")
        events = one(f"SELECT count(*) FROM {s}.events")
        tags = one(f"SELECT count(DISTINCT tag_id) FROM {s}.samples")
        size = one(
            f"SELECT sum(pg_total_relation_size(relid)) FROM pg_partition_tree('{s}.samples'::regclass)"
        )
        size += one(f"SELECT pg_total_relation_size('{s}.events') + pg_total_relation_size('{s}.tags')")
        return StoreStats(samples, events, tags, size)

    def server_pid(self) -> int:
        """The PID of this connection's PostgreSQL backend (the benchmark counts its CPU time)."""
        return int(self._conn.info.backend_pid)

    def close(self) -> None:
        self._conn.close()
