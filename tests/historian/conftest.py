"""The historian's store tests run on both back ends: SQLite files and a real PostgreSQL 15.

:func:`pg_server` is one throw-away PostgreSQL cluster per test session (per xdist worker),
stopped after the last test whatever happened (:class:`tanklab_testing.postgres.PostgresServer`);
the PostgreSQL binaries missing fails the PostgreSQL tests, naming ``make tools``.
:func:`backend` is parametrised over ``sqlite`` and ``postgres``: each test asks it for stores
(:meth:`Backend.open`), a fresh location each time unless it reopens one (a restart).
"""

from __future__ import annotations

import itertools
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psycopg
import pytest
from asyncua import ua

from helpers import ROOT, free_port, server_security
from historian.history_read import install_history_read, site_tag_mapper
from historian.store import HistoryStore
from historian.store.postgres import PostgresStore
from historian.store.sqlite import SQLiteStore
from history_series import BAD_CODE, EVENTS, T0, TAG, N, S, is_bad, level
from tanklab.config import load_site
from tanklab.history.model import Sample
from tanklab.tags import NAMESPACE_URI, Tag, plc_tags
from tanklab_io.ua_security import start_tier_server
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


SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")


async def _nothing(*_: Any) -> ua.StatusCode:
    return ua.StatusCode(ua.StatusCodes.Good)


def _accept(tag: Tag, value: Any) -> None:
    return None


@pytest.fixture
async def history_url(tmp_path: Path) -> AsyncIterator[str]:
    """A tier server secured like every tier (site PKI, users, roles) serving HistoryRead
    (:func:`install_history_read`) from a SQLite store holding :data:`TAG`'s series: N values
    :func:`level` (k) one second apart from T0, every 100th (k % 100 == 50) BadNoCommunication.
    and :data:`EVENTS`. Its endpoint URL; stopped after the test."""
    store: HistoryStore = SQLiteStore(tmp_path / "history.db")
    # every 100th sample Bad (a gap marker), the rest Good
    store.append_samples(
        {TAG: [Sample(T0 + k * S, level(k), BAD_CODE if is_bad(k) else 0) for k in range(N)]}
    )
    store.append_events(list(EVENTS))
    tags = plc_tags(SITE)
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/tanklab/historian"
    tier = await start_tier_server(
        "plc",
        url=endpoint,
        name="history test",
        security=server_security(tmp_path / "audit"),
        tags=tags,
        writes={t.path: _accept for t in tags if t.kind == "variable" and t.writable},
        methods={t.path: _nothing for t in tags if t.kind == "method"},
    )
    try:
        ns = await tier.server.get_namespace_index(NAMESPACE_URI)
        install_history_read(tier.server, store, site_tag_mapper(store, ns))
        yield endpoint
    finally:
        await tier.server.stop()
        store.close()
