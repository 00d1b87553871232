"""The HMI's OPC UA side: per logged-in user, that user's own sessions to every tier (issue 17).

A :class:`UserHub` holds, for one user, one :class:`~tanklab_io.ua_client.Link` to each tier
(plant, plc, supervisor, historian), opened with that user's name and password over the CLI's
certificate (:func:`tanklab_io.ua_client_security.client_setup`): the tiers check the password,
enforce the role and audit the real user. The HMI checks nothing of a login itself; a refused
login (:func:`tanklab_io.ua_client.refused_login`) is :class:`LoginRefusedError`, a tier that does not
answer :class:`UnreachableError`.

**Polling** (decision 0005: polling, not subscriptions). While at least one browser of the user
has a WebSocket open, one poller reads, every :data:`POLL_S` wall seconds, the live set
(:class:`hmi.site.SiteModel`) plus the paths the clients subscribed to plus the alarm conditions'
state fields, with **one Read per tier** (the tiers at once), and pushes to each client the
values that changed since the last push (value or status; the first message carries every
value) and the alarm list when it changed. A tier whose Read fails is one ``link`` message
(``up: false``); its link reconnects with the Link's backoff (decision 0017) and a ``link``
message with ``up: true`` says it is back. Nothing here ever raises into the web server for a
lost tier.

Commands (writes, method calls, the alarm methods, history reads) go through the same sessions;
the tier's status code is the answer (:class:`CommandResult`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from asyncua import ua

from hmi.site import SiteModel, json_value, parse_value
from tanklab import paths
from tanklab.alarms.model import AlarmDefinition, ShelvingState
from tanklab.errors import LinkError
from tanklab.tags import Tier
from tanklab_io.home import SecurityHome
from tanklab_io.ua_alarms import child, condition_row, fields_of, text_of
from tanklab_io.ua_client import ConnectError, Link, describe_error, refused_login
from tanklab_io.ua_client_security import ClientIdentity, client_setup
from tanklab_io.ua_history import HistoryReadError, read_event_history, read_tag_history
from tanklab_io.ua_values import stored_variant
from tanklab_io.users import Credentials

__all__ = [
    "POLL_S",
    "TIERS",
    "Client",
    "CommandResult",
    "LoginRefusedError",
    "UnreachableError",
    "UserHub",
]

log = logging.getLogger(__name__)

TIERS: tuple[str, ...] = ("plant", "plc", "supervisor", "historian")
POLL_S = 0.1
"""Wall time between two polls of the live set [s] (contract: at least every 0.5 s; 0.1 s keeps
a value's way to the page within issue 17's p99 goal of 250 ms, decision 0047)."""
TIMEOUT_S = 3.0
"""Bound of connecting a session and of every request to a tier [s]."""
REQUIRED: tuple[str, ...] = ("plant", "plc")
"""Tiers a login needs to reach (the others may be away and are reconnected)."""
QUEUE_MAX = 200
"""Messages a client may have waiting before the server drops it (a stalled browser)."""
_ALARM_EXTRA = ("Comment", "SourceName")


class LoginRefusedError(Exception):
    """A tier refused the user's login (``status``: BadUserAccessDenied, ...)."""

    def __init__(self, user: str, tier: str, status: str) -> None:
        if status == "BadUserAccessDenied":
            why = "wrong user name or password, or the account is locked"
        else:
            why = f"the {tier} does not accept this identity ({status})"
        super().__init__(f"login as {user!r} refused: {why}")
        self.status = status


class UnreachableError(Exception):
    """A tier did not answer."""

    def __init__(self, tier: str, url: str, reason: str) -> None:
        super().__init__(f"cannot reach {tier} at {url}: {reason}")
        self.tier = tier
        self.reason = reason


@dataclass(frozen=True)
class CommandResult:
    """A command's outcome: the tier's status code name, and one line when it is not Good."""

    ok: bool
    status: str
    error: str = ""

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"ok": self.ok, "status": self.status}
        if not self.ok:
            out["error"] = self.error
        return out


@dataclass(eq=False)
class Client:
    """One WebSocket of a user: its queue of messages and the paths it subscribed to."""

    queue: asyncio.Queue[dict[str, Any]] = field(default_factory=lambda: asyncio.Queue(QUEUE_MAX))
    extra: set[str] = field(default_factory=set)
    dropped: bool = False

    def push(self, message: dict[str, Any]) -> None:
        if self.dropped:
            return
        try:
            self.queue.put_nowait(message)
        except asyncio.QueueFull:
            self.dropped = True  # the socket's writer sees it and closes


def epoch_s(when: Any) -> float | None:
    """A datetime (naive = UTC, as asyncua gives them) as epoch seconds; None for anything else."""
    if not isinstance(when, datetime):
        return None
    return (when if when.tzinfo is not None else when.replace(tzinfo=UTC)).timestamp()


def _status_name(dv: ua.DataValue) -> str:
    code = dv.StatusCode if dv.StatusCode is not None else ua.StatusCode(ua.StatusCodes.Good)
    return "Good" if code.is_good() else str(code.name)


class UserHub:
    """One user's sessions to the tiers, the poller of its browsers, its commands."""

    def __init__(
        self,
        model: SiteModel,
        urls: Mapping[str, str],
        home: SecurityHome,
        credentials: Credentials,
        *,
        poll_s: float = POLL_S,
    ) -> None:
        self.model = model
        self.urls = {t: u for t, u in urls.items() if t in TIERS}
        self.user = credentials.username
        self.credentials = credentials
        self.poll_s = poll_s
        setup = client_setup(ClientIdentity(home, "cli", credentials))
        self.links: dict[str, Link] = {
            tier: Link(
                url,
                {},
                name=f"hmi {tier} {self.user}",
                setup=setup,
                timeout_s=TIMEOUT_S,
                client_name="tanklab-hmi",
            )
            for tier, url in self.urls.items()
        }
        self.clients: set[Client] = set()
        self.values: dict[str, dict[str, Any]] = {}
        """The last polled value of every path, as the browser gets it."""
        self.alarms: list[dict[str, Any]] | None = None
        self.up: dict[str, bool] = {}
        self.reasons: dict[str, str] = {}
        self._poller: asyncio.Task[None] | None = None
        self._connecting: dict[str, asyncio.Task[bool]] = {}
        """A tier's reconnection in progress (one at a time per link; the poll never waits on it)."""
        self._polled = asyncio.Event()
        self._lock = asyncio.Lock()

    # ---- sessions -------------------------------------------------------------------------

    async def open(self) -> None:
        """Open every tier's session at once. Raises :class:`LoginRefusedError` when any tier refused
        the login (then nothing stays open), :class:`UnreachableError` when a tier of
        :data:`REQUIRED` did not answer; other tiers that did not answer are reconnected later."""
        tiers = list(self.links)
        results = await asyncio.gather(*(self.links[t].connect() for t in tiers), return_exceptions=True)
        refused: LoginRefusedError | None = None
        unreachable: UnreachableError | None = None
        for tier, result in zip(tiers, results, strict=True):
            self.up[tier] = result is None
            if isinstance(result, ConnectError):
                status = refused_login(result)
                if status is not None and refused is None:
                    refused = LoginRefusedError(self.user, tier, status)
                self.reasons[tier] = describe_error(result.cause)
                if tier in REQUIRED and unreachable is None:
                    unreachable = UnreachableError(tier, self.urls[tier], self.reasons[tier])
            elif isinstance(result, BaseException):
                raise result
        if refused is not None or unreachable is not None:
            await self.close()
            raise refused or unreachable  # type: ignore[misc]

    async def close(self) -> None:
        """Stop the poller and close every session (idempotent)."""
        task, self._poller = self._poller, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        connecting, self._connecting = list(self._connecting.values()), {}
        for t in connecting:
            t.cancel()
        for t in connecting:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        for link in self.links.values():
            with contextlib.suppress(Exception):
                await asyncio.wait_for(link.close(), 2.0)

    def _reconnect(self, tier: str) -> asyncio.Task[bool]:
        """The tier's reconnection: the one in progress, else a new attempt (``Link.ensure``:
        made only when its backoff says it is due)."""
        task = self._connecting.get(tier)
        if task is None or task.done():
            task = self._connecting[tier] = asyncio.get_running_loop().create_task(self.links[tier].ensure())
        return task

    async def _link(self, tier: str, *, wait: bool = False) -> Link | None:
        """The tier's link; None while it is away. A link that is down is reconnected in the
        background (a poll never waits on a tier that does not answer: the other tiers' values
        keep coming), or, with ``wait`` (a command), awaited (bounded by the link's timeout)."""
        link = self.links.get(tier)
        if link is None:
            return None
        if not link.healthy:
            task = self._reconnect(tier)
            if wait:
                with contextlib.suppress(Exception):
                    await asyncio.shield(task)
        if link.healthy:
            self._mark(tier, True, "")
            return link
        self._mark(tier, False, link.last_error)
        return None

    def _mark(self, tier: str, up: bool, reason: str) -> None:
        if self.up.get(tier) != up:
            self.up[tier] = up
            self.reasons[tier] = reason
            msg: dict[str, Any] = {"type": "link", "tier": tier, "up": up}
            if not up:
                msg["reason"] = reason or "no session"
            for c in self.clients:
                c.push(msg)

    # ---- polling --------------------------------------------------------------------------

    def attach(self) -> Client:
        """A new WebSocket client; starts the poller with the first one."""
        c = Client()
        self.clients.add(c)
        if self._poller is None or self._poller.done():
            self._polled.clear()
            self._poller = asyncio.get_running_loop().create_task(self._poll_forever())
        return c

    def detach(self, c: Client) -> None:
        """A client went away; the poller stops with the last one."""
        self.clients.discard(c)
        if not self.clients and self._poller is not None:
            self._poller.cancel()
            self._poller = None
            self.values = {}
            self.alarms = None

    def snapshot(self, c: Client) -> dict[str, dict[str, Any]]:
        """Every value the client gets, as last polled."""
        wanted = set(self.model.live) | c.extra
        return {p: v for p, v in self.values.items() if p in wanted}

    async def first_poll(self) -> None:
        """Wait (bounded by the requests' own timeouts) until the poller has read once."""
        await self._polled.wait()

    def subscribe(self, c: Client, wanted: Sequence[str]) -> list[str]:
        """Add contract paths to the client's set; the unknown ones are returned."""
        unknown = []
        for p in wanted:
            tag = self.model.tags.get(p)
            if tag is None or tag.kind != "variable" or tag.tier not in self.links:
                unknown.append(p)
            else:
                c.extra.add(p)
        return unknown

    async def _poll_forever(self) -> None:
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        while True:
            try:
                await self.poll_once()
            except Exception:  # never let one bad poll end the user's screen
                log.exception("hmi: poll of %s failed", self.user)
            self._polled.set()
            next_at += self.poll_s
            now = loop.time()
            if next_at < now:  # overran: skip ahead rather than burst
                next_at = now + self.poll_s
            await asyncio.sleep(next_at - now)

    def _alarm_fields(self, tier: Tier, d: AlarmDefinition) -> list[str]:
        extra = (*_ALARM_EXTRA, "ConfirmedState/Id") if d.confirm else _ALARM_EXTRA
        return [child(d.name, f, tier) for f in (*fields_of(d), *extra)]

    async def poll_once(self) -> None:
        """One Read per tier of everything the clients show; push what changed."""
        wanted = set(self.model.live).union(*(c.extra for c in self.clients))
        by_tier: dict[str, list[str]] = {}
        for p in self.model.live + tuple(sorted(wanted - set(self.model.live))):
            by_tier.setdefault(self.model.tier_of(p), []).append(p)
        alarm_paths: dict[str, list[str]] = {
            tier: [p for d in defs for p in self._alarm_fields(tier, d)]
            for tier, defs in self.model.alarms.items()
        }
        tiers = [t for t in self.links if t in by_tier or t in alarm_paths]
        results = await asyncio.gather(
            *(self._read_tier(t, by_tier.get(t, []), alarm_paths.get(t, [])) for t in tiers)
        )
        changed: dict[str, dict[str, Any]] = {}
        conditions: dict[str, Any] = {}
        alarms_known = True
        for tier, result in zip(tiers, results, strict=True):
            if result is None:
                alarms_known = alarms_known and tier not in alarm_paths
                continue
            values, cond = result
            for p, item in values.items():
                old = self.values.get(p)
                if old is None or old["v"] != item["v"] or old["q"] != item["q"]:
                    changed[p] = item
                self.values[p] = item
            conditions.update(cond)
        for c in self.clients:
            mine = {p: v for p, v in changed.items() if p in self.model.live or p in c.extra}
            if mine:
                c.push({"type": "values", "values": mine})
        if alarms_known or self.alarms is None:
            alarms = self._alarm_list(conditions)
            if alarms != self.alarms:
                self.alarms = alarms
                for c in self.clients:
                    c.push({"type": "alarms", "alarms": alarms})

    async def _read_tier(
        self, tier: str, value_paths: list[str], alarm_paths: list[str]
    ) -> tuple[dict[str, dict[str, Any]], dict[str, Any]] | None:
        link = await self._link(tier)
        if link is None:
            return None
        try:
            dvs = await link.read([*value_paths, *alarm_paths])
        except LinkError as e:
            self._mark(tier, False, str(e))
            return None
        values: dict[str, dict[str, Any]] = {}
        for p, dv in zip(value_paths, dvs, strict=False):
            raw = dv.Value.Value if dv.Value is not None else None
            values[p] = {
                "v": json_value(self.model.tags.get(p), raw),
                "q": _status_name(dv),
                "t": epoch_s(dv.SourceTimestamp or dv.ServerTimestamp),
            }
        cond: dict[str, Any] = {}
        for p, dv in zip(alarm_paths, dvs[len(value_paths) :], strict=True):
            bad = dv.StatusCode is not None and dv.StatusCode.is_bad()
            cond[p] = None if bad or dv.Value is None else dv.Value.Value
        return values, cond

    def _alarm_list(self, values: Mapping[str, Any]) -> list[dict[str, Any]]:
        out = []
        for tier, defs in self.model.alarms.items():
            for d in defs:
                row = condition_row(d, values, tier)
                shelved = row.shelved or ShelvingState.UNSHELVED.value
                if not (row.standing or shelved != ShelvingState.UNSHELVED.value or row.enabled is False):
                    continue
                if row.active is None and row.acked is None:
                    continue  # not read (tier away): not shown as a normal alarm
                confirmed = values.get(child(d.name, "ConfirmedState/Id", tier)) if d.confirm else True
                out.append(
                    {
                        "id": f"{tier}:{d.name}",
                        "tier": tier,
                        "condition": d.name,
                        "source": text_of(values.get(child(d.name, "SourceName", tier))) or d.source,
                        "message": row.message,
                        "severity": row.severity,
                        "priority": row.priority,
                        "active": bool(row.active),
                        "acked": bool(row.acked),
                        "confirmed": bool(confirmed) if confirmed is not None else True,
                        "shelved": shelved,
                        "enabled": row.enabled is not False,
                        "time": epoch_s(values.get(child(d.name, "Time", tier))),
                        "comment": text_of(values.get(child(d.name, "Comment", tier))) or "",
                    }
                )
        return out

    # ---- commands -------------------------------------------------------------------------

    async def _require(self, tier: str) -> Link:
        if tier not in self.links:
            raise UnreachableError(tier, "-", "no endpoint for it (--no-historian)")
        link = await self._link(tier, wait=True)
        if link is None:
            raise UnreachableError(tier, self.urls.get(tier, "?"), self.reasons.get(tier) or "no session")
        return link

    async def write(self, path: str, value: Any) -> CommandResult:
        """Write one contract variable (``value`` converted by its type: ValueError if it cannot
        be); the tier's status code is the answer. Raises UnreachableError when the tier is away."""
        tag = self.model.variable(path)
        if not tag.writable or tag.data_type is None:
            raise ValueError(f"{path} is not writable")
        v = stored_variant(tag.data_type, parse_value(tag, value))
        link = await self._require(tag.tier)
        try:
            (status,) = await link.write_variants({path: v})
        except LinkError as e:
            raise UnreachableError(tag.tier, link.url, str(e)) from e
        return _result(status, f"{path} = {value!r}")

    async def call(self, tier: str, method: str, *args: ua.Variant) -> CommandResult:
        """Call a method (a contract path or a condition's child); the tier's status is the answer."""
        link = await self._require(tier)
        try:
            await link.call(method, *args)
        except ua.UaStatusCodeError as e:
            return _result(ua.StatusCode(e.code), f"{method}()")
        except LinkError as e:
            raise UnreachableError(tier, link.url, str(e)) from e
        return CommandResult(True, "Good")

    async def manual_percent(self, loop: str, percent: Any) -> CommandResult:
        """ManualMV of ``loop`` as ``percent`` of its EURange (ValueError for a bad number)."""
        tag = self.model.variable(paths.plc.loop(loop).manual_mv)
        if isinstance(percent, bool) or not isinstance(percent, int | float) or not math.isfinite(percent):
            raise ValueError("percent: a finite number is wanted")
        if tag.eu_range is None:
            raise ValueError(f"{tag.path} has no EURange")
        low, high = tag.eu_range
        return await self.write(tag.path, low + (high - low) * float(percent) / 100.0)

    def condition(self, alarm_id: Any) -> tuple[Tier, AlarmDefinition]:
        """The condition of an alarm id ``tier:name`` (ValueError for an unknown one)."""
        if not isinstance(alarm_id, str) or ":" not in alarm_id:
            raise ValueError("id: 'tier:condition' is wanted")
        tier, name = alarm_id.split(":", 1)
        for d in self.model.alarms.get(tier, ()):  # type: ignore[call-overload]
            if d.name == name:
                return tier, d  # type: ignore[return-value]
        raise ValueError(f"unknown alarm {alarm_id}")

    async def alarm_method(self, alarm_id: Any, method: str, comment: str = "") -> CommandResult:
        """Acknowledge / Confirm / AddComment (EventId, Comment) of an alarm, with the EventId
        the condition has now (one Read), as ``tankctl ack`` does."""
        tier, d = self.condition(alarm_id)
        link = await self._require(tier)
        try:
            (dv,) = await link.read([child(d.name, "EventId", tier)])
        except LinkError as e:
            raise UnreachableError(tier, link.url, str(e)) from e
        event_id = dv.Value.Value if dv.Value is not None and isinstance(dv.Value.Value, bytes) else b""
        return await self.call(
            tier,
            child(d.name, method, tier),
            ua.Variant(event_id, ua.VariantType.ByteString),
            ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
        )

    async def shelve(self, alarm_id: Any, kind: Any, duration_s: Any) -> CommandResult:
        """One-shot, timed (``duration_s`` > 0 of model time) or un-shelve an alarm."""
        tier, d = self.condition(alarm_id)
        if kind == "oneshot":
            return await self.call(tier, child(d.name, "ShelvingState/OneShotShelve", tier))
        if kind == "unshelve":
            return await self.call(tier, child(d.name, "ShelvingState/Unshelve", tier))
        if kind == "timed":
            if isinstance(duration_s, bool) or not isinstance(duration_s, int | float):
                raise ValueError("duration_s: a number of seconds is wanted")
            if not (math.isfinite(duration_s) and duration_s > 0):
                raise ValueError("duration_s must be > 0")
            ms = ua.Variant(float(duration_s) * 1000.0, ua.VariantType.Double)
            return await self.call(tier, child(d.name, "ShelvingState/TimedShelve", tier), ms)
        raise ValueError("kind: one of oneshot, timed, unshelve")

    # ---- history --------------------------------------------------------------------------

    async def trend(
        self, tags: Sequence[str], start_s: float, end_s: float, points: int
    ) -> tuple[dict[str, dict[str, Any]], str | None]:
        """Each tag's history in [start_s, end_s] (epoch s) from the historian: raw when every
        series fits in ``points``, else the Average over ``(end_s - start_s) / points``."""
        link = await self._require("historian")
        start = datetime.fromtimestamp(start_s, UTC)
        end = datetime.fromtimestamp(end_s, UTC)
        client, ns = link.client, link.idx
        assert client is not None and ns is not None
        try:
            raw = {t: await read_tag_history(client, ns, t, start, end) for t in tags}
            aggregate = None
            if any(len(rows) > points for rows in raw.values()):
                aggregate = "Average"
                node = ua.NodeId(ua.ObjectIds.AggregateFunction_Average)
                interval = (end_s - start_s) / points
                raw = {
                    t: await read_tag_history(client, ns, t, start, end, aggregate=node, interval_s=interval)
                    for t in tags
                }
        except HistoryReadError:
            raise
        except Exception as e:
            await link.close()  # reconnected on the next request
            raise UnreachableError("historian", link.url, describe_error(e)) from e
        series = {
            t: {
                "t": [r.time.timestamp() for r in rows],
                "v": [json_value(None, r.value) if r.status_code >> 30 != 2 else None for r in rows],
            }
            for t, rows in raw.items()
        }
        return series, aggregate

    async def alarm_history(self, start_s: float, end_s: float, limit: int) -> list[dict[str, Any]]:
        """The events the historian recorded in [start_s, end_s], newest first, at most ``limit``."""
        link = await self._require("historian")
        client = link.client
        assert client is not None
        try:
            rows = await read_event_history(
                client, datetime.fromtimestamp(start_s, UTC), datetime.fromtimestamp(end_s, UTC)
            )
        except HistoryReadError:
            raise
        except Exception as e:
            await link.close()
            raise UnreachableError("historian", link.url, describe_error(e)) from e
        rows.sort(key=lambda r: r.time, reverse=True)
        return [_event_json(r) for r in rows[:limit]]


def _tier_of_source(source: str) -> str:
    head = source.split(".", 1)[0]
    return {"Plant": "plant", "PLC": "plc", "Supervisor": "supervisor", "Historian": "historian"}.get(
        head, head.lower()
    )


def _event_json(r: Any) -> dict[str, Any]:
    condition = ""
    if ".Conditions." in r.source:
        condition = r.source.rsplit(".", 1)[1]
    return {
        "time": r.time.timestamp(),
        "tier": _tier_of_source(r.source),
        "source": r.source,
        "condition": condition,
        "message": r.message,
        "severity": r.severity,
        "event": r.event_type,
    }


def _result(status: ua.StatusCode, what: str) -> CommandResult:
    if status.is_good():
        return CommandResult(True, "Good")
    name = str(status.name)
    return CommandResult(False, name, f"{what} refused: {name}")


Factory = Callable[[Credentials], UserHub]
