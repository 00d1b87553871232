"""The historian's OPC UA client of one tier: subscriptions in, samples and events out (thin shell).

Per tier, one :class:`~tanklab_io.ua_client.Link` (the historian's own certificate as X509
identity: role Observer; capped backoff with jitter, one log line per failed attempt, its
diagnostics on ``Historian.Status.<Tier>.Link.*``) and one subscription at the configured
publishing interval holding

* a data-change monitored item per recorded node (:func:`historian.collect.recorded_tags`), queue
  size ``queue_size``, sampling interval 0 (asyncua's server reports every write): each
  notification's value, StatusCode and SourceTimestamp is one sample;
* an event monitored item on the Server object (BaseEventType: the tier's conditions and its
  ``TanklabAuditEventType`` audit events) selecting :data:`EVENT_FIELDS`.

Every decision is the pure :class:`historian.collect.TierWatch`'s: a tier whose clock node has not
advanced for ``stale_after_s``, or whose connection was lost, gets its gap markers, and the
subscription is dropped and made again on a new connection. Samples and events go to ``sink``
(the store writer's buffer), never to the store from the event loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, Protocol

from asyncua import Node, ua

from historian.collect import TierWatch
from tanklab import paths
from tanklab.clock import Clock, MonotonicClock
from tanklab.history.model import EventRecord, Sample, Value
from tanklab.paths import SourceTier
from tanklab.tags import Tag
from tanklab_io.ua_client import ClientSetup, Link, describe_error

log = logging.getLogger(__name__)

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_US = timedelta(microseconds=1)

STANDARD_FIELDS = (
    "EventId",
    "EventType",
    "SourceName",
    "Time",
    "Severity",
    "Message",
    "ConditionName",
    "Retain",
    "ActiveState/Id",
    "AckedState/Id",
    "ConfirmedState/Id",
    "EnabledState/Id",
    "LimitState/CurrentState",
    "Comment",
)
"""Fields of BaseEventType and the condition types selected on every tier (namespace 0)."""

AUDIT_FIELDS = ("Action", "User", "Role", "Node", "OldValue", "NewValue", "Status")
"""Fields of the tiers' ``TanklabAuditEventType`` (namespace ``urn:tanklab``)."""


class Sink(Protocol):
    """Where the collector hands its records (:class:`historian.writer.StoreWriter`)."""

    def put_samples(self, batch: Mapping[str, Sequence[Sample]]) -> None: ...

    def put_events(self, events: Sequence[EventRecord]) -> None: ...


def utc_us(dt: datetime | None) -> int | None:
    """A DateTime as UTC microseconds since 1970 (asyncua's naive datetimes are UTC)."""
    if dt is None:
        return None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return (dt - _EPOCH) // _US


def sample_value(value: Any) -> Value:
    """A notification's value as the store holds it (None stays None)."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return str(value)


def _json(value: Any) -> Any:
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, ua.LocalizedText):
        return value.Text
    if isinstance(value, ua.NodeId):
        return value.to_string()
    if isinstance(value, ua.StatusCode):
        return value.name
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, list):
        return [_json(v) for v in value]
    return str(value)


def event_record(fields: Mapping[str, Any], received_us: int) -> EventRecord | None:
    """An event notification's fields (by browse path) as a record; None without an EventId."""
    event_id = fields.get("EventId")
    if not isinstance(event_id, bytes) or not event_id:
        return None
    etype = fields.get("EventType")
    t_us = utc_us(fields.get("Time")) if isinstance(fields.get("Time"), datetime) else None
    message = fields.get("Message")
    severity = fields.get("Severity")
    rest = {
        k: _json(v)
        for k, v in fields.items()
        if k not in ("EventId", "EventType", "SourceName", "Time", "Severity", "Message") and v is not None
    }
    return EventRecord(
        t_us=received_us if t_us is None else t_us,
        event_id=event_id,
        event_type=etype.to_string() if isinstance(etype, ua.NodeId) else str(etype),
        source=str(fields.get("SourceName") or ""),
        severity=int(severity) if isinstance(severity, int) else 0,
        message=message.Text or "" if isinstance(message, ua.LocalizedText) else str(message or ""),
        fields=rest,
    )


def event_filter(tanklab_idx: int) -> ua.EventFilter:
    """Select :data:`STANDARD_FIELDS` (ns 0) and :data:`AUDIT_FIELDS` (ns ``urn:tanklab``)."""
    f = ua.EventFilter()
    for ns, names in ((0, STANDARD_FIELDS), (tanklab_idx, AUDIT_FIELDS)):
        for path in names:
            op = ua.SimpleAttributeOperand()
            op.TypeDefinitionId = ua.NodeId(ua.ObjectIds.BaseEventType)
            op.BrowsePath = [ua.QualifiedName(p, ns) for p in path.split("/")]
            op.AttributeId = ua.AttributeIds.Value
            f.SelectClauses.append(op)
    return f


@dataclass
class _Handler:
    """asyncua's subscription handler (sync methods: nothing here awaits)."""

    collector: TierCollector

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        self.collector.on_data(node, data.monitored_item.Value)

    def event_notification(self, event: Any) -> None:
        # asyncua's fields dict holds Variants: the record takes their values
        fields = event.get_event_props_as_fields_dict()
        self.collector.on_event({k: v.Value for k, v in fields.items()})

    def status_change_notification(self, status: Any) -> None:
        log.warning("%s subscription status change: %s", self.collector.tier, status)


class TierCollector:
    """Records one tier (module docstring); :meth:`run` until ``stop``."""

    def __init__(
        self,
        tier: SourceTier,
        url: str,
        tags: Sequence[Tag],
        watch: TierWatch,
        sink: Sink,
        *,
        setup: ClientSetup,
        publishing_interval_s: float,
        queue_size: int,
        clock: Clock | None = None,
        utc_now_us: Callable[[], int] | None = None,
        timeout_s: float = 4.0,
    ) -> None:
        self.tier = tier
        self.url = url
        self.watch = watch
        self.sink = sink
        self.clock: Clock = clock or MonotonicClock()
        self.utc_now_us = utc_now_us or (lambda: utc_us(datetime.now(UTC)) or 0)
        self.publishing_interval_s = publishing_interval_s
        self.queue_size = queue_size
        self.link = Link(
            url,
            {t.path: t for t in tags},
            name=f"historian-{tier}",
            setup=setup,
            timeout_s=timeout_s,
            clock=self.clock,
            failure_level=logging.WARNING,
        )
        self._path_of: dict[ua.NodeId, str] = {}
        self._subscription: Any = None
        self._lost = False

    @property
    def subscribed(self) -> bool:
        return self._subscription is not None

    # ---- notifications ------------------------------------------------------------------------

    def on_data(self, node: Node, dv: ua.DataValue | None) -> None:
        path = self._path_of.get(node.nodeid)
        if path is None or dv is None or self._subscription is None:
            return
        value = dv.Value.Value if dv.Value is not None else None
        status = dv.StatusCode.value if dv.StatusCode is not None else 0
        t_us = utc_us(dv.SourceTimestamp) or utc_us(dv.ServerTimestamp) or self.utc_now_us()
        sample = self.watch.receive(path, sample_value(value), status, t_us, self.clock.now())
        self.sink.put_samples({path: [sample]})

    def on_event(self, fields: Mapping[str, Any]) -> None:
        record = event_record(fields, self.utc_now_us())
        if record is not None:
            self.sink.put_events([record])

    def _connection_lost(self, original: Any) -> Callable[[Exception], Any]:
        async def lost(e: Exception) -> None:
            self._lost = True
            if original is not None:
                await original(e)

        return lost

    # ---- the loop -----------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        """Subscribe, watch, mark gaps and resubscribe until ``stop`` is set."""
        tick_s = max(self.publishing_interval_s, 0.1)
        try:
            while not stop.is_set():
                await self.step()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), tick_s)
        finally:
            await self._drop()
            await self.link.close()

    async def step(self) -> None:
        """One look: connect and subscribe when due, or mark the tier lost when it is."""
        now = self.clock.now()
        if self._subscription is None:
            if not await self.link.ensure():
                return
            try:
                await self._subscribe()
            except Exception as e:
                log.warning("%s: subscription to %s failed: %s", self.tier, self.url, describe_error(e))
                self.link.last_error = f"subscribe: {describe_error(e)}"
                await self._drop()
                await self.link.close()
                return
            self.watch.connect(self.clock.now())
            log.info("historian: recording %s (%d nodes) from %s", self.tier, len(self._path_of), self.url)
            return
        if self._lost or self.watch.stale(now) or not self.link.healthy:
            why = "connection lost" if self._lost or not self.link.healthy else "its clock stopped"
            gap = self.watch.lost()
            if gap:
                t_us = next(iter(gap.values()))[0].t_us
                log.warning(
                    "historian: %s %s: gap marked at %d us in %d tags", self.tier, why, t_us, len(gap)
                )
                self.sink.put_samples(gap)
            self.link.last_error = why
            await self._drop()
            await self.link.close()

    async def _subscribe(self) -> None:
        client = self.link.client
        assert client is not None and self.link.idx is not None
        self._lost = False
        client.connection_lost_callback = self._connection_lost(client.connection_lost_callback)
        nodes = [self.link.node(p) for p in self.link.tags]
        self._path_of = {n.nodeid: p for p, n in zip(self.link.tags, nodes, strict=True)}
        sub = await client.create_subscription(self.publishing_interval_s * 1000.0, _Handler(self))
        self._subscription = sub
        results = await sub.subscribe_data_change(nodes, queuesize=self.queue_size, sampling_interval=0)
        refused = [p for p, r in zip(self.link.tags, results, strict=True) if isinstance(r, ua.StatusCode)]
        if refused:
            log.warning("%s: %d nodes refused a monitored item: %s", self.tier, len(refused), refused[:5])
        await sub.subscribe_events(
            ua.ObjectIds.Server,
            ua.ObjectIds.BaseEventType,
            evfilter=event_filter(self.link.idx),
            queuesize=self.queue_size,
        )

    async def _drop(self) -> None:
        sub, self._subscription = self._subscription, None
        if sub is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(sub.delete(), 1.0)

    def status(self) -> dict[str, Any]:
        """The tier's ``Historian.Status.<Tier>.*`` values."""
        tp = paths.historian.tier(self.tier)
        last = self.watch.last_source_us
        values: dict[str, Any] = {
            tp.connected: self.subscribed and self.watch.connected and not self.watch.gap_open,
            tp.last_sample: 0.0 if last is None else last / 1e6,
            tp.samples: min(self.watch.samples, 2**32 - 1),
            tp.gaps: min(self.watch.gaps, 2**32 - 1),
        }
        values.update(self.link.status(tp.link))
        return values
