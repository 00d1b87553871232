"""The historian's section: where it stores, how long it keeps, how it watches the tiers.

Collection (docs/historian.md, decision 0043): the historian subscribes to every recorded node of
each tier with a publishing interval ``publishing_interval_s`` [s wall] and watches the tier's
clock node; a tier whose clock has not advanced for

    stale_after_s = max(stale_intervals * max(publishing_interval_s, T_tier / speed), 1 s)

of wall time (``T_tier``: the tier's own period in model time, the architecture's wall-clock floor
of 1 s) is marked as a gap and resubscribed.
"""

from __future__ import annotations

from pydantic import Field

from tanklab.config.base import Model


class RetentionConfig(Model):
    """How long each back end keeps samples and events [days] (older rows are deleted in short
    bounded steps between the collector's batches)."""

    sqlite_days: float = Field(
        30.0, gt=0, allow_inf_nan=False, description="Days a SQLite store keeps (one file, embedded)."
    )
    postgresql_days: float = Field(
        365.0, gt=0, allow_inf_nan=False, description="Days a PostgreSQL store keeps (partitions dropped)."
    )
    step_rows: int = Field(
        10_000, ge=100, le=1_000_000, description="Rows deleted at most per retention step (one transaction)."
    )
    every_s: float = Field(
        60.0, gt=0, allow_inf_nan=False, description="Wall time between retention passes [s]."
    )


class HistorianConfig(Model):
    """The historian tier (every field has a default: a site without this section records too)."""

    store: str | None = Field(
        None,
        description="Store location: a postgresql:// URL or a SQLite file path (env TANKLAB_HISTORIAN_URL "
        "wins; default: history.db in the run's var directory, var/<site name>/history.db).",
    )
    retention: RetentionConfig = Field(default_factory=RetentionConfig, description="Retention per back end.")
    publishing_interval_s: float = Field(
        0.25,
        gt=0,
        le=10,
        allow_inf_nan=False,
        description="Publishing interval of the historian's subscriptions [s wall].",
    )
    stale_intervals: int = Field(
        8,
        ge=2,
        le=1000,
        description="A tier's clock node not advancing for this many intervals (publishing interval or "
        "the tier's period, whichever is longer; at least 1 s wall) marks a gap.",
    )
    queue_size: int = Field(
        1000,
        ge=10,
        le=100_000,
        description="Monitored items' queue size: changes of one node kept between two publishes.",
    )
    buffer_capacity: int = Field(
        200_000,
        ge=100,
        le=10_000_000,
        description="Samples and events buffered while the store is unavailable; beyond, the oldest are "
        "dropped and counted (Historian.Status.Dropped).",
    )
    batch_max: int = Field(5_000, ge=1, le=1_000_000, description="Records written per store transaction.")
    store_retry_s: float = Field(
        1.0, gt=0, le=60, allow_inf_nan=False, description="Wait before retrying a failed store write [s]."
    )
