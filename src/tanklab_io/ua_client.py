"""OPC UA client side of the contract: resolve, read and write nodes, and the one client wrapper.

:func:`resolve` looks the namespace index of ``urn:tanklab`` up and returns the nodes of the given
paths; :func:`read_values` reads many values in one Read; :func:`write_value` writes one value as
its tag's type. :func:`new_client` makes every client of the system (its keep-alive probe runs every
half session timeout). :class:`Link` is the one client wrapper, used by the tiers' links to the tier
below and by the operator commands: bounded requests, reconnection with capped exponential backoff
and jitter (:func:`backoff_delay`, a pure function of the attempt number and a random source), one
log line per failed attempt, and its attempts and last error for status nodes.
:func:`quiet_disconnect` ends a session without ever raising.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import random
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping, Sequence
from typing import Any

from asyncua import Client, Node, ua

from tanklab.clock import Clock, MonotonicClock
from tanklab.errors import LOGIN_REFUSALS, LinkError
from tanklab.tags import NAMESPACE_URI, Tag, link_status_paths
from tanklab_io.ua_values import variant

log = logging.getLogger(__name__)


NAMESPACE_ARRAY = ua.NodeId(ua.ObjectIds.Server_NamespaceArray)
"""The server's NamespaceArray (namespace URIs by index)."""

TANKLAB_INDEX = 2
"""Where every tanklab tier has ``urn:tanklab``: after OPC UA's own namespace and the server's
application URI (``register_namespace`` when its nodes are built)."""


async def namespace_index(client: Client) -> int:
    """Index of ``urn:tanklab`` on the server the client is connected to."""
    return int(await client.get_namespace_index(NAMESPACE_URI))


async def resolve(client: Client, paths: Sequence[str]) -> dict[str, Node]:
    """Nodes of the given paths (the namespace index looked up from the URI)."""
    idx = await namespace_index(client)
    return {p: client.get_node(ua.NodeId(p, idx)) for p in paths}


async def read_values(client: Client, nodes: Sequence[Node]) -> list[Any]:
    """Read many values in one Read service call (values of the same instant)."""
    return list(await client.read_values(list(nodes)))


async def write_value(node: Node, tag: Tag, value: Any) -> ua.StatusCode:
    """Write one value of the tag's type; return the server's status (no exception)."""
    dv = ua.DataValue(variant(tag, value))
    params = ua.WriteParameters()
    wv = ua.WriteValue()
    wv.NodeId = node.nodeid
    wv.AttributeId = ua.AttributeIds.Value
    wv.Value = dv
    params.NodesToWrite = [wv]
    result = await node.session.write(params)
    return result[0]


ClientSetup = Callable[[Client], Awaitable[None]]
"""Prepares a new client before it connects (security policy, certificate, identity):
:func:`tanklab_io.ua_security.client_setup`."""

SESSION_TIMEOUT_MS = 30_000
"""Session timeout a link asks for [ms]: a dead client's session is dropped within 30 s."""


@contextlib.asynccontextmanager
async def request_deadline(timeout_s: float) -> AsyncIterator[None]:
    """``asyncio.timeout(timeout_s)`` around one asyncua request, raising TimeoutError when it expires.

    asyncua bounds each request with its own ``wait_for`` (the wait_for2 package) on the same
    timeout. When both timers fire in one loop iteration, or the answer arrives in the iteration
    our deadline cancels the task, that ``wait_for`` raises ``CancelledWithResultError``, a
    *subclass* of CancelledError, and ``asyncio.timeout`` turns only CancelledError itself into
    TimeoutError: the subclass escaped as a cancellation and ended the PLC's scan task (a
    fresh-clone CI run on a loaded machine, tests/integration/test_restarts.py). Here it becomes
    a plain CancelledError inside the timeout, which then says TimeoutError when the
    cancellation was its own and stays a cancellation when it came from outside (a stop).
    """
    async with asyncio.timeout(timeout_s):
        try:
            yield
        except asyncio.CancelledError as e:
            if type(e) is asyncio.CancelledError:
                raise
            raise asyncio.CancelledError(*e.args) from e


def new_client(url: str, timeout_s: float) -> Client:
    """An asyncua client of ``url`` whose requests wait ``timeout_s`` and whose probe is patient.

    asyncua 2.1 probes the server every ``watchdog_intervall`` (1 s by default) and waits at
    most that long for the answer; a probe that overruns marks the client disconnected for
    good (no auto-reconnect). On a loaded two-core machine, or after the client's event loop
    was busy for a second, a healthy server then looked dead (a CI run lost its test client so).
    Here the probe runs every half session timeout and waits as long (asyncua caps its wait at
    half the session timeout): a server that stops answering is still found before its session
    would expire, and a slow answer is not a lost link. Tier links find a lost peer sooner by
    their own requests (each waits ``timeout_s``).
    """
    half_session_s = max(timeout_s, SESSION_TIMEOUT_MS / 1000.0 / 2.0)
    client = Client(url, timeout=timeout_s, watchdog_intervall=half_session_s)
    client.connection_lost_callback = _lost_logger(url)
    return client


def _lost_logger(url: str) -> Callable[[Exception], Awaitable[None]]:
    """asyncua's ``connection_lost_callback`` for a client of ``url``: one warning saying which
    side ended the connection (asyncua's own line is INFO, below what a tier logs).

    asyncua's supervisor calls it when the socket closed under the client (the server or the
    network ended it: ``ConnectionError('transport lost')``; requests in flight then fail with
    "Connection is closed") or when its keep-alive probe failed (the client gives up on a server
    that did not answer in time; requests then fail with "client is disconnected").
    """

    async def lost(e: Exception) -> None:
        side = "the socket closed" if isinstance(e, ConnectionError) else "the keep-alive probe failed"
        log.warning("client of %s: connection lost, %s (%s)", url, side, describe_error(e))

    return lost


BACKOFF_BASE_S = 0.2
"""Retry delay after a link's first failed connection attempt, before jitter [s]."""
BACKOFF_FACTOR = 2.0
"""Growth of the retry delay per further consecutive failure."""
BACKOFF_CAP_S = 5.0
"""Largest retry delay, before jitter [s]: a tier that comes back is found within 5 s."""
BACKOFF_JITTER = 0.5
"""Fraction of the delay that is random ("equal jitter": half fixed, half uniform)."""


def backoff_delay(
    attempt: int,
    rng: random.Random,
    *,
    base_s: float = BACKOFF_BASE_S,
    factor: float = BACKOFF_FACTOR,
    cap_s: float = BACKOFF_CAP_S,
    jitter: float = BACKOFF_JITTER,
) -> float:
    """Wait before the next connection attempt after ``attempt + 1`` consecutive failures [s].

    Capped exponential backoff with equal jitter::

        d_k = min(cap_s, base_s * factor**k)
        delay = d_k * (1 - jitter * u),    u = rng.random() in [0, 1)

    so ``delay`` lies in ``(d_k * (1 - jitter), d_k]``. With the defaults (0.2 s, x2, 5 s, 0.5)
    the first retries come after 0.1-0.2 s, 0.2-0.4 s, 0.4-0.8 s, ..., then 2.5-5 s for ever.
    Equal rather than full jitter (``jitter = 1``): a full-jitter delay can be ~0, and a link
    that retries at once against a tier that is still starting only adds to its load; half of
    the delay random is enough to spread the links of many clients that lost the same server.

    Parameters
    ----------
    attempt : k >= 0, consecutive failures so far minus one.
    rng : the source of ``u`` (a seeded ``random.Random`` in tests).
    base_s, factor, cap_s : d_0 [s] > 0, growth >= 1, cap [s] >= base_s.
    jitter : 0 (none) .. 1 (full jitter).
    """
    if attempt < 0:
        raise ValueError(f"attempt must be >= 0, got {attempt}")
    if not (base_s > 0 and math.isfinite(base_s) and factor >= 1 and math.isfinite(factor)):
        raise ValueError(f"need base_s > 0 and factor >= 1, got {base_s}, {factor}")
    if not (cap_s >= base_s and math.isfinite(cap_s)):
        raise ValueError(f"cap_s must be >= base_s and finite, got {cap_s}")
    if not 0 <= jitter <= 1:
        raise ValueError(f"jitter must be in [0, 1], got {jitter}")
    # factor**k overflows a float near k = 1024: past the cap, the cap it is.
    if factor > 1 and attempt > math.log(cap_s / base_s) / math.log(factor):
        d = cap_s
    else:
        d = min(cap_s, base_s * factor**attempt)
    return d * (1.0 - jitter * rng.random())


def describe_error(e: BaseException) -> str:
    """``Class: message`` of an exception (just the class when the message is empty: a
    TimeoutError says nothing else)."""
    text = str(e).strip()
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


class ConnectError(LinkError):
    """A connection attempt that failed, at ``stage`` (``setup``: the secure channel and identity;
    ``connect``: the session; ``namespace``: looking ``urn:tanklab`` up), because of ``cause``
    (also the exception's ``__cause__``)."""

    def __init__(self, name: str, url: str, stage: str, cause: BaseException) -> None:
        super().__init__(f"{name} link to {url}: {stage} failed: {describe_error(cause)}")
        self.stage = stage
        self.cause = cause


def refused_login(e: ConnectError) -> str | None:
    """The status code's name when the server refused the session's identity (a wrong password,
    an unknown or locked user: :data:`tanklab.errors.LOGIN_REFUSALS`), else None (the server
    was not reached, or failed otherwise)."""
    cause = e.cause
    if isinstance(cause, ua.UaStatusCodeError):
        name = str(ua.StatusCode(cause.code).name)
        if name in LOGIN_REFUSALS:
            return name
    return None


class Link:
    """An OPC UA client link to the tier below that never crashes its owner.

    Each new client is prepared by ``setup`` (the secure channel and the identity). Every
    request is bounded by ``timeout_s``; any failure marks the link unhealthy, drops the
    connection and raises :class:`~tanklab.errors.LinkError` once. :meth:`ensure` reconnects
    when an attempt is due and resolves the nodes again, so the owner calls it every cycle and
    carries on with its last good values while the tier below is away.

    Retries follow :func:`backoff_delay` on the injected ``clock`` (``now()`` only: the link
    never sleeps, an attempt is simply not made before it is due): after the k-th consecutive
    failure the next attempt waits ``backoff_delay(k - 1, rng)``; a lost connection is retried
    at once (the first attempt), a successful connection resets the count. Every failed attempt
    is one log line at ``failure_level`` naming the link, the attempt number, the endpoint, the
    exception's class and message, and the retry delay (a failed request that drops the link
    one line naming the request): the tiers' links (``PlcLink``,
    ``FieldLink``) pass WARNING; the default INFO keeps a command-line client's probes (``tankctl
    up`` waiting for a tier it is starting, its board) out of an unconfigured terminal, where
    Python prints warnings by itself.

    The operator commands' client (:class:`tankctl.ops.client.TierClient`) is this link too: it
    calls :meth:`connect` (one attempt now, raising :class:`ConnectError`) instead of
    :meth:`ensure`, and maps the failures to its one-line messages.

    Diagnostics (:meth:`status`, published by the tiers on ``<prefix>.Attempts`` etc., see
    :func:`tanklab.tags.link_status_paths`): ``attempts`` failed connection attempts since the
    link was last up (consecutive failures; 0 while up), ``connects`` successful connections,
    ``last_error`` why the last attempt or request failed (kept after a recovery),
    ``retry_delay_s`` the wait scheduled after the last failure.
    """

    def __init__(
        self,
        url: str,
        tags: dict[str, Tag],
        *,
        name: str,
        setup: ClientSetup,
        timeout_s: float = 2.0,
        clock: Clock | None = None,
        rng: random.Random | None = None,
        backoff: Callable[[int, random.Random], float] = backoff_delay,
        failure_level: int = logging.INFO,
        client_name: str | None = None,
        namespace_index: int | None = None,
    ) -> None:
        self.url = url
        self.assumed_idx = namespace_index
        """The index of ``urn:tanklab`` to take at connect instead of looking it up (a Read of
        the server's NamespaceArray), for an owner that checks it in its own first Read
        (:meth:`read_nodes` with :data:`NAMESPACE_ARRAY`); None: looked up."""
        self.client_name = client_name
        """The client's application name shown to the server (None: asyncua's default)."""
        self.setup = setup
        self.tags = tags
        self.name = name
        self.timeout_s = timeout_s
        self.clock: Clock = clock or MonotonicClock()
        self.rng = rng or random.Random()
        self.backoff = backoff
        self.failure_level = failure_level
        self.client: Client | None = None
        self.nodes: dict[str, Node] = {}
        self.idx: int | None = None
        self.healthy = False
        self.failures = 0
        """Requests (read, write, call) that failed and dropped the link."""
        self.connects = 0
        self.attempts = 0
        """Connection attempts that failed since the link was last up (0 while up)."""
        self.last_error = ""
        self.retry_delay_s = 0.0
        self._next_attempt = -math.inf

    def status(self, prefix: str) -> dict[str, Any]:
        """The link's diagnostics as tag values under ``prefix`` (e.g. ``PLC.Status.PlantLink``)."""
        paths = link_status_paths(prefix)
        return {
            paths["Attempts"]: self.attempts,
            paths["Connects"]: self.connects,
            paths["LastError"]: self.last_error,
            paths["RetryDelay"]: self.retry_delay_s,
        }

    async def ensure(self) -> bool:
        """Connect if not connected and an attempt is due; return whether the link is up."""
        if self.healthy:
            return True
        if self.clock.now() < self._next_attempt:
            return False
        try:
            await self.connect()
        except ConnectError:
            return False
        return True

    async def connect(self) -> None:
        """One connection attempt now, due or not (a no-op while up); a failure is counted and
        logged as by :meth:`ensure` and raised as :class:`ConnectError` naming its stage."""
        if self.healthy:
            return
        client = new_client(self.url, self.timeout_s)
        client.session_timeout = SESSION_TIMEOUT_MS
        if self.client_name is not None:
            client.name = self.client_name
        stage = "setup"
        try:
            await asyncio.wait_for(self.setup(client), self.timeout_s)
            stage = "connect"
            await asyncio.wait_for(client.connect(), self.timeout_s)
            stage = "namespace"
            if self.assumed_idx is None:
                self.idx = await asyncio.wait_for(namespace_index(client), self.timeout_s)
            else:
                self.idx = self.assumed_idx
        except Exception as e:
            # asyncua unwinds a failed connect itself; what a timeout cut short is the socket.
            # (A full disconnect of a client that never connected logs its own warning.)
            with contextlib.suppress(Exception):
                client.disconnect_socket()
            self._attempt_failed(e)
            raise ConnectError(self.name, self.url, stage, e) from e
        self.client = client
        self.nodes = {p: client.get_node(ua.NodeId(p, self.idx)) for p in self.tags}
        self.healthy = True
        self.connects += 1
        after = f" after {self.attempts} failed attempts" if self.attempts else ""
        self.attempts = 0
        self.retry_delay_s = 0.0
        log.info("%s link: connected to %s%s", self.name, self.url, after)

    def node(self, path: str) -> Node:
        """The node of a tag path (string NodeId in ``urn:tanklab``), made once per connection:
        the link's own tags are made at connect, any other path on first use."""
        node = self.nodes.get(path)
        if node is None:
            if self.client is None or self.idx is None:
                raise LinkError(f"{self.name} link to {self.url} is down")
            node = self.nodes[path] = self.client.get_node(ua.NodeId(path, self.idx))
        return node

    def _attempt_failed(self, e: BaseException) -> None:
        self.attempts += 1
        self.last_error = describe_error(e)
        self.retry_delay_s = self.backoff(self.attempts - 1, self.rng)
        self._next_attempt = self.clock.now() + self.retry_delay_s
        log.log(
            self.failure_level,
            "%s link: connection attempt %d to %s failed: %s; next attempt in %.2f s",
            self.name,
            self.attempts,
            self.url,
            self.last_error,
            self.retry_delay_s,
        )

    async def _fail(self, what: str, e: BaseException) -> LinkError:
        self.failures += 1
        reason = describe_error(e)
        self.last_error = f"{what}: {reason}"
        if self.healthy:
            log.log(
                self.failure_level,
                "%s link: %s on %s failed (%s); reconnecting",
                self.name,
                what,
                self.url,
                reason,
            )
        self.healthy = False
        client, self.client = self.client, None
        if client is not None:
            await quiet_disconnect(client)
        # The first reconnection attempt is due at once: most losses are one timed-out request.
        self._next_attempt = -math.inf
        return LinkError(f"{self.name} link to {self.url}: {what} failed: {reason}")

    async def read(self, paths: Sequence[str]) -> list[ua.DataValue]:
        """Read the values of ``paths`` in one Read; DataValues with their status codes."""
        if not self.healthy or self.client is None:
            raise LinkError(f"{self.name} link to {self.url} is down")
        return await self.read_nodes([self.node(p) for p in paths])

    async def read_nodes(self, nodes: Sequence[Node]) -> list[ua.DataValue]:
        """Read the values of any ``nodes`` (of this link's client) in one Read, as :meth:`read`."""
        if not self.healthy or self.client is None:
            raise LinkError(f"{self.name} link to {self.url} is down")
        try:
            # a deadline, not wait_for: no extra task per request (a few us, every scan).
            async with request_deadline(self.timeout_s):
                return list(await self.client.read_attributes(list(nodes)))
        except Exception as e:
            raise await self._fail("read", e) from e

    async def write(
        self, values: Mapping[str, Any], tags: Mapping[str, Tag] | None = None
    ) -> list[ua.StatusCode]:
        """Write many values in one Write, each with its tag's exact type (``tags``, default the
        link's own); returns each item's status (no exception for Bad)."""
        types = self.tags if tags is None else tags
        return await self.write_variants({p: variant(types[p], v) for p, v in values.items()})

    async def write_variants(self, values: Mapping[str, ua.Variant]) -> list[ua.StatusCode]:
        """Write many ready-typed Variants in one Write, as :meth:`write`."""
        if not self.healthy or self.client is None:
            raise LinkError(f"{self.name} link to {self.url} is down")
        paths = list(values)
        try:
            async with request_deadline(self.timeout_s):
                return list(
                    await self.client.uaclient.write_attributes(
                        [self.node(p).nodeid for p in paths],
                        [ua.DataValue(values[p]) for p in paths],
                        ua.AttributeIds.Value,
                    )
                )
        except Exception as e:
            raise await self._fail("write", e) from e

    async def call(self, method_path: str, *args: ua.Variant) -> list[Any]:
        """Call a method (its object is the path's parent); raises LinkError, or UaStatusCodeError
        when the server answers the call with a Bad status (the link stays up)."""
        if not self.healthy or self.client is None or self.idx is None:
            raise LinkError(f"{self.name} link to {self.url} is down")
        parent = self.client.get_node(ua.NodeId(method_path.rsplit(".", 1)[0], self.idx))
        try:
            async with request_deadline(self.timeout_s):
                result = await parent.call_method(ua.NodeId(method_path, self.idx), *args)
        except ua.UaStatusCodeError:
            raise
        except Exception as e:
            raise await self._fail(f"call {method_path}", e) from e
        return result if isinstance(result, list) else [result]

    async def close(self) -> None:
        """Disconnect (idempotent)."""
        self.healthy = False
        client, self.client = self.client, None
        if client is not None:
            await quiet_disconnect(client)


async def quiet_disconnect(client: Client, timeout_s: float = 1.0) -> None:
    """Disconnect ``client``, waiting at most ``timeout_s`` [s], never raising: the peer may
    already be gone, and a failed goodbye has nothing to tell anyone."""
    with contextlib.suppress(Exception):
        await asyncio.wait_for(client.disconnect(), timeout_s)
