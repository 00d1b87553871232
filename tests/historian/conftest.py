"""The historian's store tests run on both back ends: SQLite files and a real PostgreSQL 15.

:func:`pg_server` is one throw-away PostgreSQL cluster per test session (per xdist worker),
stopped after the last test whatever happened (:class:`tanklab_testing.postgres.PostgresServer`);
the PostgreSQL binaries missing fails the PostgreSQL tests, naming ``make tools``.
:func:`backend` is parametrised over ``sqlite`` and ``postgres``: each test asks it for stores
(:meth:`Backend.open`), a fresh location each time unless it reopens one (a restart).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import psycopg
import pytest

from historian.store import HistoryStore
from historian.store.postgres import PostgresStore
from historian.store.sqlite import SQLiteStore
from tanklab_testing.postgres import PostgresServer

_names = itertools.count()


@pytest.fixture(scope="session")
def pg_server() -> Iterator[PostgresServer]:
    """One PostgreSQL cluster for the session, on a free loopback port, stopped on every path."""
    server = PostgresServer.start()
    try:
        yield server
    finally:
        server.stop()


@dataclass
class Backend:
    """Where one test's stores live, and the stores it opened (closed after the test)."""

    name: str
    tmp: Path
    pg_url: str | None = None
    opened: list[HistoryStore] = field(default_factory=list)
    schemas: list[str] = field(default_factory=list)

    def location(self) -> str:
        """A new, empty location: a file path, or a PostgreSQL schema name."""
        n = next(_names)
        if self.pg_url is None:
            return str(self.tmp / f"history-{n}.db")
        schema = f"t{n}_{self.tmp.name.lower()[-12:]}".replace("-", "_")
        schema = "".join(c if c.isalnum() or c == "_" else "_" for c in schema)
        self.schemas.append(schema)
        return schema

    def open(self, location: str | None = None) -> HistoryStore:
        """The store at ``location`` (a new one when ``None``)."""
        loc = self.location() if location is None else location
        store: HistoryStore
        if self.pg_url is None:
            store = SQLiteStore(Path(loc))
        else:
            store = PostgresStore(self.pg_url, schema=loc)
        self.opened.append(store)
        return store

    def cleanup(self) -> None:
        for store in self.opened:
            store.close()
        if self.pg_url is not None and self.schemas:
            with psycopg.connect(self.pg_url, autocommit=True) as conn:
                for schema in self.schemas:
                    conn.execute(f"DROP SCHEMA IF EXISTS {schema} CASCADE")  # type: ignore[call-overload]


@pytest.fixture(params=["sqlite", "postgres"])
def backend(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Backend]:
    """Stores of one back end for one test."""
    url = request.getfixturevalue("pg_server").url if request.param == "postgres" else None
    b = Backend(request.param, tmp_path, url)
    try:
        yield b
    finally:
        b.cleanup()
