"""The historian's collection decisions: what to record, when a tier is stale, how a gap is marked,
the bounded buffer in front of the store, and when retention runs (pure, clock-injected).

Every function and method takes the wall time ``now_s`` [s] (monotonic, from the shell) and UTC
times as microseconds (``*_us``, :mod:`tanklab.history.model`); nothing here reads a clock,
sleeps or does I/O. :mod:`historian.collector` (the OPC UA subscriptions), :mod:`historian.writer`
(the store's worker thread) and :mod:`historian.runtime` are the shells around it
(decision 0043).

Staleness. A tier's **clock node** (``Plant.Sim.Time``, ``PLC.Status.Scan``,
``Supervisor.Cycle``) advances once per period ``T`` of model time, i.e. every ``T / speed`` s of
wall time. With publishing interval ``P`` [s wall] and ``N`` intervals of patience::

    stale_after_s = max(N * max(P, T / speed), 1 s)

(the architecture's wall-clock floor of 1 s for model-time timeouts: at a large speed, scheduling
noise is never a gap). A subscribed tier whose clock node has not changed for longer than
``stale_after_s`` is **stale**: it is marked and resubscribed.

Gap marking. When a tier is lost (stale, or its link dropped), every recorded tag of that tier
gets one sample ``(t_gap_us, None, BadNoCommunication)`` with ``t_gap_us = t_last_us + 1``, where
``t_last_us`` is the newest source time the historian received from that tier: after every value
it recorded (the store is idempotent by ``(tag, t_us)``, first write wins, so a marker must not
share a time with a real sample), before anything it missed. A raw read then shows the tag Bad
from the gap's start until the tier's next sample; Part 13 aggregates treat the interval as Bad.
One gap is marked per loss: a tier that stays away is not marked again until it has sent data.
The same marker covers the historian's own downtime: at start, each tag whose newest stored
sample is not Bad gets a marker 1 us after it (:func:`restart_markers`).

Buffer. :class:`Backlog` holds at most ``capacity`` records (samples and events) on their way to
the store, oldest first; a record added to a full backlog evicts the oldest, counted in
``dropped`` (the store was unavailable that long: the historian reports it on
``Historian.Status.Dropped``). A batch the store refused is given back at the front, in order.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

from tanklab import paths
from tanklab.config import SiteConfig
from tanklab.history.model import EventRecord, Sample, Value, is_bad
from tanklab.paths import SOURCE_TIERS, SourceTier
from tanklab.tags import DataType, Tag, plant_tags, plc_tags, supervisor_tags

__all__ = [
    "BAD_NO_COMMUNICATION",
    "CLOCK_PATHS",
    "FLOOR_S",
    "Backlog",
    "Batch",
    "RetentionPlan",
    "TierWatch",
    "recorded_tags",
    "restart_markers",
    "source_tiers",
    "stale_after_s",
    "tier_period_s",
]

BAD_NO_COMMUNICATION = 0x8031_0000
"""OPC UA BadNoCommunication: the historian's gap marker (decision 0043)."""

FLOOR_S = 1.0
"""Wall-clock floor of the staleness timeout [s] (architecture, "Speed")."""

CLOCK_PATHS: dict[SourceTier, str] = {
    "plant": paths.plant.sim_time,
    "plc": paths.plc.scan,
    "supervisor": paths.supervisor.cycle,
}
"""The node whose change proves that a tier is alive and publishing."""

_RECORDED_TYPES = frozenset(
    {DataType.DOUBLE, DataType.INT32, DataType.UINT32, DataType.BOOLEAN, DataType.STRING}
)


def source_tiers(site: SiteConfig) -> list[SourceTier]:
    """The tiers of ``site`` the historian records (the plant always; the PLC and the supervisor
    when the site has them)."""
    out: list[SourceTier] = []
    for tier in SOURCE_TIERS:
        if (tier == "plc" and site.plc is None) or (tier == "supervisor" and site.supervisor is None):
            continue
        out.append(tier)
    return out


def recorded_tags(site: SiteConfig, tier: SourceTier) -> list[Tag]:
    """The nodes of ``tier`` the historian records: every scalar variable (analog, enumeration,
    flag, counter, status text) but the constant identity nodes; methods and arrays
    (``Supervisor.MPC.PlannedMV``...) are not samples of one value."""
    builder = {"plant": plant_tags, "plc": plc_tags, "supervisor": supervisor_tags}[tier]
    identity = set(paths.identity_paths(tier).values())
    return [
        t
        for t in builder(site)
        if t.kind == "variable" and t.data_type in _RECORDED_TYPES and t.path not in identity
    ]


def tier_period_s(site: SiteConfig, tier: SourceTier) -> float:
    """Model time between two advances of ``tier``'s clock node [s]: the PLC's scan for the plant
    and the PLC (the plant publishes at least once per scan), the supervisor's sample time."""
    if tier == "supervisor" and site.supervisor is not None and site.plc is not None:
        return site.supervisor_sample_time_s
    return site.plc.scan_period_s if site.plc is not None else 1.0


def stale_after_s(publishing_interval_s: float, intervals: int, period_s: float, speed: float) -> float:
    """``max(N * max(P, T / speed), 1 s)`` [s wall] (module docstring)."""
    for name, v in (
        ("publishing_interval_s", publishing_interval_s),
        ("period_s", period_s),
        ("speed", speed),
    ):
        if not (v > 0 and math.isfinite(v)):
            raise ValueError(f"{name} must be positive and finite, got {v}")
    if intervals < 1:
        raise ValueError(f"intervals must be >= 1, got {intervals}")
    return max(intervals * max(publishing_interval_s, period_s / speed), FLOOR_S)


@dataclass
class TierWatch:
    """What the historian knows of one tier's collection: connected, alive, the newest source
    time, the counts its status nodes publish.

    ``tags`` are the recorded paths (gap markers go to each); ``clock_path`` is the node whose
    change proves the tier alive.
    """

    tier: SourceTier
    tags: tuple[str, ...]
    clock_path: str
    stale_after_s: float
    connected: bool = False
    advanced_s: float = -math.inf
    """Wall time [s] of the clock node's last change (or of the connection)."""
    clock_value: Value = None
    last_source_us: int | None = None
    """The newest source time received from the tier [us] (None before the first sample)."""
    gap_open: bool = False
    """A gap is marked and no new data has come since."""
    samples: int = 0
    gaps: int = 0

    def connect(self, now_s: float) -> None:
        """The tier is subscribed (again): its staleness counts from now; the clock's last value is
        forgotten (a restarted tier's counter may start anywhere)."""
        self.connected = True
        self.advanced_s = now_s
        self.clock_value = None

    def receive(self, path: str, value: Value, status: int, source_us: int, now_s: float) -> Sample:
        """A data change of ``path`` (value, StatusCode, source time): the sample to store."""
        self.samples += 1
        if self.last_source_us is None or source_us > self.last_source_us:
            self.last_source_us = source_us
        if path == self.clock_path and not is_bad(status) and value != self.clock_value:
            if self.clock_value is not None:
                self.gap_open = False  # the tier advanced: a new loss is a new gap
            self.clock_value = value
            self.advanced_s = now_s
        return Sample(source_us, value, status)

    def stale(self, now_s: float) -> bool:
        """Connected, and the clock node has not changed for more than ``stale_after_s``."""
        return self.connected and now_s - self.advanced_s > self.stale_after_s

    def lost(self) -> dict[str, list[Sample]]:
        """The tier is lost (stale, or its link dropped): disconnected, and the gap markers to
        store (none when a gap is already open or nothing was ever received)."""
        self.connected = False
        if self.gap_open or self.last_source_us is None:
            return {}
        self.gap_open = True
        self.gaps += 1
        marker = Sample(self.last_source_us + 1, None, BAD_NO_COMMUNICATION)
        self.last_source_us += 1
        return {tag: [marker] for tag in self.tags}


def restart_markers(last: Mapping[str, Sample]) -> dict[str, list[Sample]]:
    """Gap markers for the historian's own downtime: one 1 us after each tag's newest stored
    sample, unless that sample is Bad already (a gap marked, or the tag was Bad)."""
    return {
        tag: [Sample(s.t_us + 1, None, BAD_NO_COMMUNICATION)]
        for tag, s in last.items()
        if not is_bad(s.status)
    }


class Batch(NamedTuple):
    """Records taken from the backlog for one store transaction, in arrival order."""

    items: list[tuple[str, Sample] | EventRecord]

    @property
    def samples(self) -> dict[str, list[Sample]]:
        out: dict[str, list[Sample]] = {}
        for item in self.items:
            if isinstance(item, tuple) and not isinstance(item, EventRecord):
                out.setdefault(item[0], []).append(item[1])
        return out

    @property
    def events(self) -> list[EventRecord]:
        return [item for item in self.items if isinstance(item, EventRecord)]


@dataclass
class Backlog:
    """The bounded buffer between the collector and the store (module docstring)."""

    capacity: int
    dropped: int = 0
    _items: deque[tuple[str, Sample] | EventRecord] = field(default_factory=deque)

    def __post_init__(self) -> None:
        if self.capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {self.capacity}")

    def __len__(self) -> int:
        return len(self._items)

    def _trim(self) -> int:
        over = len(self._items) - self.capacity
        for _ in range(max(over, 0)):
            self._items.popleft()
        self.dropped += max(over, 0)
        return max(over, 0)

    def add_samples(self, batch: Mapping[str, Iterable[Sample]]) -> int:
        """Append samples (by tag); return how many old records were dropped to make room."""
        for tag, samples in batch.items():
            self._items.extend((tag, s) for s in samples)
        return self._trim()

    def add_events(self, events: Iterable[EventRecord]) -> int:
        """Append events; return how many old records were dropped."""
        self._items.extend(events)
        return self._trim()

    def take(self, limit: int) -> Batch:
        """The oldest ``limit`` records (fewer when fewer wait), removed."""
        n = min(limit, len(self._items))
        return Batch([self._items.popleft() for _ in range(n)])

    def give_back(self, batch: Batch) -> int:
        """Put a batch the store refused back at the front, in order; records beyond the capacity
        (the oldest, i.e. the batch's first) are dropped and counted."""
        self._items.extendleft(reversed(batch.items))
        return self._trim()


@dataclass
class RetentionPlan:
    """When retention runs and what it deletes: passes every ``every_s`` [s wall]; a pass is a
    sequence of bounded steps, one between two batches, until the store reports ``done``."""

    days: float
    every_s: float
    next_s: float = -math.inf
    running: bool = False

    def cutoff_us(self, now_utc_us: int) -> int:
        """Delete what is older than this: ``now - days`` [us]."""
        return now_utc_us - round(self.days * 86_400_000_000)

    def due(self, now_s: float) -> bool:
        """Whether a step should run now (a pass is under way, or the next one is due)."""
        return self.running or now_s >= self.next_s

    def stepped(self, done: bool, now_s: float) -> None:
        """A step ran: the pass goes on unless ``done``, then the next is due ``every_s`` later."""
        self.running = not done
        if done:
            self.next_s = now_s + self.every_s
