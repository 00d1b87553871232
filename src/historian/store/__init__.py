"""The historian's storage: one interface, two back ends (docs/historian.md, decision 0040).

* :mod:`historian.store.base`: the :class:`HistoryStore` Protocol and the types its reads return.
* :mod:`historian.store.sqlite`: :class:`SQLiteStore`, one WAL-mode file (the embedded default).
* :mod:`historian.store.postgres`: :class:`PostgresStore`, psycopg 3, day partitions, COPY.

:func:`open_store` picks the back end from a location: a ``postgresql://`` (or ``postgres://``)
URL opens PostgreSQL, anything else is a SQLite file path (``sqlite:///abs/path`` accepted too).
:func:`store_location` is the location a historian uses: ``TANKLAB_HISTORIAN_URL`` when set, else
its default file.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from historian.store.base import (
    Bounds,
    EventCursor,
    EventPage,
    HistoryStore,
    RawPage,
    RetentionStep,
    StoreStats,
    TagRange,
)

__all__ = [
    "URL_ENV",
    "Bounds",
    "EventCursor",
    "EventPage",
    "HistoryStore",
    "RawPage",
    "RetentionStep",
    "StoreStats",
    "TagRange",
    "open_store",
    "store_location",
]

URL_ENV = "TANKLAB_HISTORIAN_URL"
"""The environment variable naming the historian's store (a PostgreSQL URL or a SQLite path)."""


def store_location(default: Path, env: Mapping[str, str] | None = None) -> str:
    """``TANKLAB_HISTORIAN_URL`` if set and not empty, else ``default`` (a SQLite file)."""
    value = (os.environ if env is None else env).get(URL_ENV, "").strip()
    return value or str(default)


def open_store(location: str | Path) -> HistoryStore:
    """Open (and create if missing) the store at ``location``."""
    text = str(location)
    # each back end imported when used: a SQLite historian never loads psycopg and libpq
    if text.startswith(("postgresql://", "postgres://")):
        from historian.store.postgres import PostgresStore  # noqa: PLC0415

        return PostgresStore(text)
    from historian.store.sqlite import SQLiteStore  # noqa: PLC0415

    if text.startswith("sqlite://"):
        text = text.removeprefix("sqlite://")
        if not text:
            raise ValueError("sqlite:// needs a path: sqlite:///var/history.db")
    return SQLiteStore(Path(text))
