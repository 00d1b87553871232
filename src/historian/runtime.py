"""The historian process: collectors of every tier, the store writer, its server (the shell that
owns the clock).

``run_historian`` opens nothing on the event loop but sockets: the store belongs to the writer's
thread (:class:`historian.writer.StoreWriter`). It starts the historian's server first (so its
status is readable while the tiers are still away), then one :class:`~historian.collector.
TierCollector` per recorded tier under one TaskGroup, and publishes ``Historian.Status.*`` every
``STATUS_PERIOD_S``. On ``stop`` the collectors unsubscribe, the writer stores what is buffered and
closes the store, and the server stops.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from historian.collect import (
    CLOCK_PATHS,
    RetentionPlan,
    TierWatch,
    recorded_tags,
    source_tiers,
    stale_after_s,
    tier_period_s,
)
from historian.collector import TierCollector
from historian.server import HistorianServer
from historian.store import HistoryStore, open_store
from historian.writer import StoreWriter, store_kind
from tanklab import paths
from tanklab.clock import Clock, MonotonicClock
from tanklab.config import SiteConfig
from tanklab.paths import SourceTier
from tanklab_io.ua_security import ClientIdentity, ServerSecurity, client_setup

log = logging.getLogger(__name__)

STATUS_PERIOD_S = 0.5
"""Wall time between two publishes of the historian's status nodes [s]."""

UINT32_MAX = 2**32 - 1


def default_store(site: SiteConfig, var_dir: Path = Path("var")) -> Path:
    """The SQLite file of a site without a configured store: ``var/<site>/history.db``."""
    return var_dir / site.name / "history.db"


def retention_days(site: SiteConfig, location: str) -> float:
    """The configured retention of the back end at ``location`` [days]."""
    r = site.historian.retention
    return r.postgresql_days if store_kind(location) == "postgresql" else r.sqlite_days


async def run_historian(
    site: SiteConfig,
    *,
    host: str,
    port: int,
    urls: Mapping[SourceTier, str],
    store: str,
    security: ServerSecurity,
    stop: asyncio.Event,
    speed: float = 1.0,
    clock: Clock | None = None,
    ready: asyncio.Event | None = None,
) -> StoreWriter:
    """Record the tiers at ``urls`` into the store at ``store`` until ``stop`` is set; returns the
    writer (its counts) after the store is closed."""
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    clock = clock or MonotonicClock()
    cfg = site.historian
    tiers = [t for t in source_tiers(site) if t in urls]
    tags = {t: recorded_tags(site, t) for t in tiers}
    recorded = frozenset(tag.path for ts in tags.values() for tag in ts)
    if store_kind(store) == "sqlite":
        Path(store.removeprefix("sqlite://")).parent.mkdir(parents=True, exist_ok=True)
    writer = StoreWriter(
        store,
        capacity=cfg.buffer_capacity,
        batch_max=cfg.batch_max,
        retry_s=cfg.store_retry_s,
        retention=RetentionPlan(retention_days(site, store), cfg.retention.every_s),
        retention_rows=cfg.retention.step_rows,
        recorded=recorded,
    )
    server = HistorianServer(site, host, port, security)
    setup = client_setup(ClientIdentity(security.home, "historian"))
    collectors = [
        TierCollector(
            tier,
            urls[tier],
            tags[tier],
            TierWatch(
                tier,
                tuple(t.path for t in tags[tier]),
                CLOCK_PATHS[tier],
                stale_after_s(
                    cfg.publishing_interval_s, cfg.stale_intervals, tier_period_s(site, tier), speed
                ),
            ),
            writer,
            setup=setup,
            publishing_interval_s=cfg.publishing_interval_s,
            queue_size=cfg.queue_size,
            clock=clock,
        )
        for tier in tiers
    ]
    reads: HistoryStore | None = None
    writer.start()
    try:
        await server.start()
        # The writer's restart markers go in before HistoryRead opens its own connection.
        await asyncio.to_thread(writer.opened.wait, 10.0)
        if writer.opened.is_set():
            try:
                reads = open_store(store)
                server.install_history(reads, recorded)
            except Exception as e:
                log.warning("historian: no HistoryRead: %s", e)
        await server.publish(_status(writer, collectors))
        if ready is not None:
            ready.set()
        log.info("historian: recording %s into %s (%s)", ", ".join(tiers), store, writer.kind)
        async with asyncio.TaskGroup() as tg:
            for c in collectors:
                tg.create_task(c.run(stop))
            tg.create_task(_publish_status(server, writer, collectors, stop))
    finally:
        await asyncio.to_thread(writer.stop)
        if reads is not None:
            with contextlib.suppress(Exception):
                reads.close()
        await server.stop()
    log.info(
        "historian: stopped (%d samples and %d events stored, %d dropped)",
        writer.stored,
        writer.events,
        writer.dropped,
    )
    return writer


def _status(writer: StoreWriter, collectors: list[TierCollector]) -> dict[str, Any]:
    h = paths.historian
    values: dict[str, Any] = {
        h.buffered: min(writer.buffered, UINT32_MAX),
        h.dropped: min(writer.dropped, UINT32_MAX),
        h.stored: min(writer.stored, UINT32_MAX),
        h.events: min(writer.events, UINT32_MAX),
        h.store_kind: writer.kind,
        h.store_available: writer.available,
        h.store_error: writer.last_error,
        h.retention_deleted: min(writer.retention_deleted, UINT32_MAX),
    }
    for c in collectors:
        values.update(c.status())
    return values


async def _publish_status(
    server: HistorianServer, writer: StoreWriter, collectors: list[TierCollector], stop: asyncio.Event
) -> None:
    while not stop.is_set():
        await server.publish(_status(writer, collectors))
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), STATUS_PERIOD_S)
