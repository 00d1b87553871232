"""Operator commands of ``tankctl`` against a running stack.

::

    tankctl status [--json]                      one Read per tier: levels, loops, alarms, health
    tankctl setpoint LIC1 0.45                   PLC.LIC1.SP [m]
    tankctl leak T1 0.3 | tankctl leak T1 off    Plant.T1.Leak, opening 0..1
    tankctl valve V13 0.5                        Plant.V13.Opening, 0..1
    tankctl loop LIC1 manual 40                  PLC.LIC1.Mode = MANUAL, then ManualMV = 40 % of its EURange
    tankctl loop LIC1 auto                       PLC.LIC1.Mode = AUTO
    tankctl mode adaptive-pid|mpc|advisory|off   Supervisor.Mode
    tankctl gains LIC1 [--json]                  applied gains, GainSource, the supervisor's RLS state
    tankctl gains LIC1 --kp K --ki K --kd K      PLC.LIC1.SetGains as an engineer (GainSource ENGINEER)
    tankctl gains LIC1 --release                 PLC.LIC1.ReleaseGains: back under adaptation
    tankctl gains LIC1 --reset                   PLC.LIC1.ResetGains: the configured gains again
    tankctl browse [plant|plc|supervisor] [--json]   the servers' node trees, browsed
    tankctl watch [--interval 1] [--duration S]  live trend of levels against setpoints
    tankctl scenario run FILE                    a scenario's timed events, on the plant's model time

Endpoints (every command): ``--plant-url`` / ``--plc-url`` / ``--supervisor-url``, else
``TANKLAB_PLANT_URL`` / ``TANKLAB_PLC_URL`` / ``TANKLAB_SUPERVISOR_URL``, else ``--base-port N``
(or ``TANKLAB_BASE_PORT``) giving N, N+1, N+2 on ``--host`` (default 127.0.0.1), else the given
site config's endpoints, else 4840, 4841, 4842, with ``--host`` replacing their host when given.

The site (which tanks, valves, loops and ranges exist, so names are checked before anything is
sent) is ``--config``, else ``TANKLAB_CONFIG``, else the stack's own: each tier publishes its
site name, config digest and config (``<Tier>.Identity.*``, :mod:`tanklab.identity`). Every
connection compares them with the site and refuses another site or config in one line, exit 2
(:class:`SiteMismatchError`, decision 0020).

Units at the command line: levels in m, openings 0..1, flows in m^3/s, a manual output in
percent of the ManualMV's EURange (read from the PLC itself).

Exit codes: 0 done; 1 a write or a method call refused by a server (one line with the status
code's name, e.g. ``tankctl: PLC.LIC1.SP = 0.7 refused: BadOutOfRange``,
``tankctl: PLC.LIC1.ResetGains() refused: BadInvalidState (...)``); 2 bad usage, an unknown name, a bad
config or scenario, an unreachable endpoint (``tankctl: cannot reach plc at URL: REASON``), or a
refused login (``tankctl: login as 'alice' refused: wrong user name or password, or the account is
locked (plc at URL)``; never reported as unreachable). The login is ``TANKLAB_USER`` +
``TANKLAB_PASSWORD``, else the security home's credentials file; only one of the two variables
set is an error before anything connects (:func:`tanklab.ua_security.cli_identity`).
Nothing prints a traceback: asyncua's and tanklab's loggers are held at ERROR while these
commands run, and every failure at the OPC UA boundary becomes one line.

:func:`register` mounts the commands (and the ``scenario`` group) on the main typer app.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import signal
import socket
from collections import deque
from collections.abc import Awaitable, Callable, Coroutine, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from asyncua import Client, Node, ua
from rich import box
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from tankctl.usage import OneLineUsage
from tanklab.clock import Deadlines, MonotonicClock, sleep_or_stop
from tanklab.config import (
    ENV_ENDPOINT_VARS,
    Endpoints,
    SiteConfig,
    load_site,
    parse_endpoint_url,
)
from tanklab.enums import LoopMode, SensorFault, SupervisorMode
from tanklab.errors import SecurityError, TanklabError
from tanklab.identity import SiteIdentity, site_from_json
from tanklab.scenario import (
    DisturbanceEvent,
    Event,
    FaultEvent,
    LeakEvent,
    LoopModeEvent,
    Scenario,
    SetpointEvent,
    SupervisorModeEvent,
    ValveEvent,
    check_against_site,
    live_unappliable,
    load_scenario,
)
from tanklab.tags import (
    NAMESPACE_URI,
    TIER_ROOTS,
    Tag,
    Tier,
    identity_paths,
    plant_tags,
    plc_tags,
    supervisor_tags,
    tags_by_path,
)
from tanklab.ua import new_client, write_value
from tanklab.ua_security import ClientIdentity, cli_identity, secure_client

__all__ = [
    "DEFAULT_TIMEOUT_S",
    "CallRefusedError",
    "LoginRefusedError",
    "RefusedError",
    "SiteMismatchError",
    "Stack",
    "TierClient",
    "UnreachableError",
    "UsageError",
    "register",
    "resolve_endpoints",
    "scenario_app",
]

TIERS: tuple[Tier, ...] = ("plant", "plc", "supervisor")
"""The tiers in port order: ``--base-port N`` puts them at N, N+1, N+2."""

DEFAULT_TIMEOUT_S = 3.0
"""Wall-time bound of connecting and of every request [s]."""

DEFAULT_POLL_S = 0.05
"""Wall time between two reads of ``Plant.Sim.Time`` in ``scenario run`` [s] (the plant's tick)."""

TREND_SAMPLES = 60
"""Samples of each level kept for the sparkline of ``watch`` (at most this many are drawn)."""

_T = TypeVar("_T")


# --------------------------------------------------------------------------------------------
# Errors (each becomes one line and an exit code in _run)
# --------------------------------------------------------------------------------------------


class UnreachableError(TanklabError):
    """A tier did not answer: refused, timed out, unknown host, no tanklab namespace (exit 2)."""

    def __init__(self, tier: str, url: str, reason: str) -> None:
        super().__init__(f"cannot reach {tier} at {url}: {reason}")
        self.tier = tier
        self.url = url
        self.reason = reason


class LoginRefusedError(TanklabError):
    """A tier refused the session's login (exit 2): wrong password, unknown user, a locked
    account, or an identity the server does not take. Never reported as unreachable: the tier
    answered, it said no."""

    def __init__(self, user: str | None, tier: str, url: str, status: str) -> None:
        who = f"login as {user!r}" if user is not None else "login"
        if status == "BadUserAccessDenied":
            why = "wrong user name or password, or the account is locked"
        else:  # BadIdentityTokenRejected, BadIdentityTokenInvalid
            why = f"the {tier} does not accept this identity ({status})"
        super().__init__(f"{who} refused: {why} ({tier} at {url})")
        self.user = user
        self.tier = tier
        self.url = url
        self.status = status


LOGIN_REFUSALS = frozenset({"BadUserAccessDenied", "BadIdentityTokenRejected", "BadIdentityTokenInvalid"})
"""What a server answers a refused ActivateSession with (asyncua raises them as
``UaStatusCodeError`` subclasses from ``Client.connect``): tanklab's user manager answers
BadUserAccessDenied to a wrong password, an unknown name and a locked account alike (so that
a refusal tells an attacker nothing), BadIdentityTokenRejected to an anonymous session."""


class SiteMismatchError(TanklabError):
    """A tier runs another site, or the same site with another config, than the command was
    given (``--config`` or the tier asked first), or publishes no identity (exit 2)."""


class RefusedError(TanklabError):
    """A server answered a write with a Bad status code (exit 1)."""

    def __init__(self, path: str, shown: str, status: str) -> None:
        super().__init__(f"{path} = {shown} refused: {status}")
        self.path = path
        self.status = status


class CallRefusedError(RefusedError):
    """A server answered a method call with a Bad status code (exit 1)."""

    def __init__(self, path: str, args: str, status: str, hint: str = "") -> None:
        TanklabError.__init__(self, f"{path}({args}) refused: {status}" + (f" ({hint})" if hint else ""))
        self.path = path
        self.status = status


class UsageError(TanklabError, ValueError):
    """An argument failed the local checks: unknown name, bad number, bad option (exit 2)."""


class StoppedError(TanklabError):
    """Ctrl-C (SIGINT) or SIGTERM stopped a command that was applying changes (exit 130)."""


def _describe(e: BaseException, timeout_s: float) -> str:
    """One short reason for a failed connection or request."""
    if isinstance(e, TimeoutError):
        return f"no answer within {timeout_s:g} s"
    if isinstance(e, ConnectionRefusedError):
        return "connection refused"
    if isinstance(e, socket.gaierror):
        return f"unknown host ({e.strerror or e})"
    if isinstance(e, ua.UaStatusCodeError):
        return ua.StatusCode(e.code).name
    if isinstance(e, OSError):
        return str(e.strerror or e) or type(e).__name__
    text = str(e)
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


# --------------------------------------------------------------------------------------------
# Endpoints and the site
# --------------------------------------------------------------------------------------------

_URL_FLAGS = {"plant": "--plant-url", "plc": "--plc-url", "supervisor": "--supervisor-url"}


def _parse_base_port(text: str, source: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise UsageError(f"{source} must be a port number, got {text!r}") from None


def resolve_endpoints(
    site: SiteConfig | None,
    *,
    urls: Mapping[str, str | None],
    env: Mapping[str, str],
    base_port: int | None = None,
    host: str | None = None,
) -> dict[Tier, str]:
    """Endpoint URL of each tier, by precedence.

    For each tier: its URL flag (``urls[tier]``), else ``TANKLAB_<TIER>_URL`` in ``env``, else
    ``base_port`` (or ``TANKLAB_BASE_PORT``) + 0, 1, 2 for plant, plc, supervisor on ``host``
    (default 127.0.0.1), else the site's endpoint (``None``: the default endpoints, 4840..4842 on
    127.0.0.1) with ``host`` replacing its host when given. Empty strings count as unset.

    Raises
    ------
    UsageError
        A URL that is not ``opc.tcp://HOST:PORT[/path]``, or a base port outside 1..65533.
    """
    base = base_port
    source = "--base-port"
    if base is None and env.get("TANKLAB_BASE_PORT"):
        source = "TANKLAB_BASE_PORT"
        base = _parse_base_port(env["TANKLAB_BASE_PORT"], source)
    if base is not None and not 1 <= base <= 65533:
        raise UsageError(f"{source} must be 1..65533 (three consecutive ports), got {base}")
    out: dict[Tier, str] = {}
    for k, tier in enumerate(TIERS):
        flag, var = urls.get(tier), ENV_ENDPOINT_VARS[tier]
        url = flag or env.get(var) or None
        if url:
            try:
                parse_endpoint_url(url)
            except ValueError as e:
                raise UsageError(f"{_URL_FLAGS[tier] if flag else var}: {e}") from None
            out[tier] = url.strip()
        elif base is not None:
            out[tier] = f"opc.tcp://{host or '127.0.0.1'}:{base + k}/tanklab/{tier}"
        else:
            ep = getattr(site.endpoints if site is not None else Endpoints(), tier)
            out[tier] = f"opc.tcp://{host or ep.host}:{ep.port}/tanklab/{tier}"
    return out


@dataclass
class Stack:
    """What an operator command talks to: the tiers' URLs and the site (names, ranges).

    The site is the one given (``--config`` or ``TANKLAB_CONFIG``, ``given``), or, when none
    was, the one the first tier to answer publishes (:meth:`resolve`). Every connection reads
    the tier's ``<Tier>.Identity`` nodes and refuses (:class:`SiteMismatchError`) a tier whose
    site name or config digest differs from that site's, so a command never writes into a
    stack with the names and ranges of another site (decision 0020).
    """

    given: SiteConfig | None
    urls: dict[Tier, str]
    timeout_s: float = DEFAULT_TIMEOUT_S
    identity: ClientIdentity | None = None
    source: str = "--config"
    """How the given site was given, for messages (``--config FILE``, ``TANKLAB_CONFIG=FILE``)."""
    _site: SiteConfig | None = field(default=None, repr=False)
    _expected: SiteIdentity | None = field(default=None, repr=False)
    _origin: str = field(default="", repr=False)
    _tags: dict[Tier, dict[str, Tag]] = field(default_factory=dict, repr=False)
    _clients: dict[Tier, TierClient] = field(default_factory=dict, repr=False)
    unreached: dict[Tier, UnreachableError] = field(default_factory=dict, repr=False)
    """Why each tier :meth:`resolve` tried did not answer."""

    def __post_init__(self) -> None:
        if self.given is not None:
            self._site = self.given
            self._expected = SiteIdentity.of(self.given)
            self._origin = self.source

    @property
    def resolved(self) -> bool:
        """Whether the site is known (given, or read from a tier)."""
        return self._site is not None

    @property
    def site(self) -> SiteConfig:
        """The site; only after :meth:`resolve` when none was given."""
        if self._site is None:
            raise RuntimeError("the site is not known before Stack.resolve()")
        return self._site

    @property
    def site_identity(self) -> SiteIdentity:
        """Name and config digest of :attr:`site`."""
        if self._expected is None:
            raise RuntimeError("the site is not known before Stack.resolve()")
        return self._expected

    @property
    def origin(self) -> str:
        """Where the site came from: ``--config FILE``, ``TANKLAB_CONFIG=FILE`` or ``plc at URL``."""
        return self._origin

    async def resolve(self, *prefer: Tier) -> None:
        """Know the site: nothing to do when one was given; else connect to the ``prefer``
        tiers, then the others, until one answers, and take the site it publishes.

        The connected client is kept for :meth:`client`. A refused login or a tier publishing
        no identity stops the search; if no tier answers, the first one's UnreachableError
        (every tier's is in ``unreached``).
        """
        if self.resolved:
            return
        order = [*prefer, *(t for t in TIERS if t not in prefer)]
        for tier in order:
            try:
                await self.client(tier).connect()
                return
            except UnreachableError as e:
                self.unreached[tier] = e
        raise self.unreached[order[0]]

    def accept(self, tier: Tier, url: str, values: Mapping[str, Any]) -> None:
        """Check (or, before the site is known, take) what a tier says it runs.

        ``values`` are the tier's identity nodes by item (SiteName, ConfigDigest, Config).

        Raises
        ------
        SiteMismatchError
            No identity published, a Config that is not the digest's, or another site/config.
        """
        name, digest = values.get("SiteName"), values.get("ConfigDigest")
        where = f"{tier} at {url}"
        if not (isinstance(name, str) and name and isinstance(digest, str) and len(digest) == 64):
            raise SiteMismatchError(
                f"{where} publishes no site identity ({TIER_ROOTS[tier]}.Identity): cannot check which "
                "site it runs"
            )
        seen = SiteIdentity(name, digest)
        if self._expected is None:
            text = values.get("Config")
            site = site_from_json(text if isinstance(text, str) else "", f"{where}: Identity.Config")
            if SiteIdentity.of(site) != seen:
                raise SiteMismatchError(f"{where}: its Identity.Config is not the config of its ConfigDigest")
            self._site, self._expected, self._origin = site, seen, where
            return
        if seen != self._expected:
            given = self._origin if self._origin.startswith(("--config", "TANKLAB_CONFIG")) else ""
            if given:
                hint = "; give the stack's config, or no --config to take the site from the stack"
                raise SiteMismatchError(
                    f"site mismatch: {where} runs {seen}; {given} is {self._expected}{hint}"
                )
            raise SiteMismatchError(
                f"site mismatch: {where} runs {seen}, but {self._origin} runs {self._expected}: "
                "the stack's tiers run different sites"
            )

    def has(self, tier: Tier) -> bool:
        """Whether the site has this tier (every site has a plant)."""
        if tier == "plc":
            return self.site.plc is not None
        if tier == "supervisor":
            return self.site.supervisor is not None
        return True

    def tags(self, tier: Tier) -> dict[str, Tag]:
        """The contract's tags of ``tier`` for this site, by path."""
        if tier not in self._tags:
            build = {"plant": plant_tags, "plc": plc_tags, "supervisor": supervisor_tags}[tier]
            self._tags[tier] = tags_by_path(build(self.site))
        return self._tags[tier]

    def client(self, tier: Tier) -> TierClient:
        """The client of ``tier`` (one per tier; connected by :meth:`TierClient.connect`)."""
        if tier not in self._clients:
            self._clients[tier] = TierClient(tier, self.urls[tier], self)
        return self._clients[tier]

    # ---- local checks of names ------------------------------------------------------------

    def require(self, tier: Tier) -> None:
        """Raise UsageError if the site has no such tier."""
        if not self.has(tier):
            raise UsageError(f"the site {self.site.name} has no {tier}")

    def loop(self, name: str) -> str:
        """A loop name of the site (LIC1, ...), else UsageError."""
        return self._known(name, self.site.loop_names, "loop")

    def tank(self, name: str) -> str:
        """A tank name of the site (T1, ...), else UsageError."""
        return self._known(name, self.site.tank_names, "tank")

    def valve(self, name: str) -> str:
        """A valve name of the site (V13, ...), else UsageError."""
        return self._known(name, self.site.valve_names, "valve")

    def _known(self, name: str, known: list[str], what: str) -> str:
        if name.upper() in known:
            return name.upper()
        have = ", ".join(known) if known else "none"
        raise UsageError(f"unknown {what} {name!r} (the site {self.site.name} has {have})")


def _env(name: str) -> str | None:
    value = os.environ.get(name)
    return value if value else None


def make_stack(
    config: Path | None,
    host: str | None,
    base_port: int | None,
    plant_url: str | None,
    plc_url: str | None,
    supervisor_url: str | None,
    timeout: float,
    *,
    endpoints_of: SiteConfig | None = None,
) -> Stack:
    """The :class:`Stack` from the common options; every failure is a :class:`TanklabError`.

    The site is ``--config``, else ``TANKLAB_CONFIG``, else none: the stack's own, read at the
    first connection. The endpoints' last fallback is the given site's, else ``endpoints_of``'s
    (a scenario's site file), else the default endpoints.
    """
    if not (timeout > 0 and math.isfinite(timeout)):
        raise UsageError(f"--timeout must be a positive number of seconds, got {timeout}")
    given, source = None, ""
    if config is not None:
        given, source = load_site(config), f"--config {config}"
    elif e := _env("TANKLAB_CONFIG"):
        given, source = load_site(e), f"TANKLAB_CONFIG={e}"
    urls = resolve_endpoints(
        given or endpoints_of,
        urls={"plant": plant_url, "plc": plc_url, "supervisor": supervisor_url},
        env=os.environ,
        base_port=base_port,
        host=host,
    )
    return Stack(given, urls, timeout, cli_identity(), source)


# --------------------------------------------------------------------------------------------
# One connected tier
# --------------------------------------------------------------------------------------------


@dataclass
class BrowsedNode:
    """A node as the server's Browse and Read services showed it."""

    name: str
    path: str
    node_class: str
    description: str = ""
    children: list[BrowsedNode] = field(default_factory=list)
    value: Any = None
    status: str | None = None
    data_type: str | None = None
    unit: str | None = None
    eu_range: tuple[float, float] | None = None
    enum_strings: list[str] | None = None
    writable: bool | None = None
    inputs: list[str] | None = None
    outputs: list[str] | None = None

    def walk(self, depth: int = 0) -> Iterator[tuple[int, BrowsedNode]]:
        """This node and its descendants, depth first, with their depth."""
        yield depth, self
        for child in self.children:
            yield from child.walk(depth + 1)

    @property
    def enum_name(self) -> str | None:
        """The EnumStrings entry of an enumerated value."""
        if self.enum_strings is None or not isinstance(self.value, int) or isinstance(self.value, bool):
            return None
        return self.enum_strings[self.value] if 0 <= self.value < len(self.enum_strings) else None

    def as_json(self) -> dict[str, Any]:
        """Nested plain structure (see docs/cli.md, ``browse --json``)."""
        out: dict[str, Any] = {"name": self.name, "path": self.path, "class": self.node_class}
        if self.description:
            out["description"] = self.description
        if self.node_class == "Variable":
            out.update(
                value=_plain(self.value),
                data_type=self.data_type,
                unit=self.unit,
                eu_range=list(self.eu_range) if self.eu_range else None,
                writable=self.writable,
            )
            if self.enum_strings is not None:
                out["enum"] = self.enum_name
                out["enum_strings"] = self.enum_strings
            if self.status:
                out["status"] = self.status
        if self.node_class == "Method":
            out.update(inputs=self.inputs or [], outputs=self.outputs or [])
        if self.children:
            out["children"] = [c.as_json() for c in self.children]
        return out


class TierClient:
    """An OPC UA client of one tier: connect (bounded), Read, Write, Browse.

    Every request is bounded by ``timeout_s``; any failure to connect or to get an answer
    raises :class:`UnreachableError` naming the tier and its URL. A Bad status on a write raises
    :class:`RefusedError`. Node ids come from the namespace index of ``urn:tanklab``, looked up.
    """

    def __init__(self, tier: Tier, url: str, stack: Stack) -> None:
        self.tier = tier
        self.url = url
        self.stack = stack
        self.timeout_s = stack.timeout_s
        self.identity = stack.identity or cli_identity()
        self._client: Client | None = None
        self.idx = 0

    @property
    def tags(self) -> dict[str, Tag]:
        """The contract's tags of this tier for the stack's site, by path."""
        return self.stack.tags(self.tier)

    @property
    def client(self) -> Client:
        if self._client is None:
            raise UnreachableError(self.tier, self.url, "not connected")
        return self._client

    async def connect(self) -> TierClient:
        """Connect, look the namespace index up and check the tier's site identity with
        :meth:`Stack.accept` (each within the timeout); a no-op when connected."""
        if self._client is not None:
            return self
        client = new_client(self.url, self.timeout_s)
        client.name = "tankctl"
        try:
            await asyncio.wait_for(secure_client(client, self.identity), self.timeout_s)
            await asyncio.wait_for(client.connect(), self.timeout_s)
        except SecurityError:
            await _quiet_disconnect(client)
            raise
        except ua.UaStatusCodeError as e:
            await _quiet_disconnect(client)
            status = ua.StatusCode(e.code).name
            if status in LOGIN_REFUSALS:
                creds = self.identity.credentials
                user = creds.username if creds is not None else None
                raise LoginRefusedError(user, self.tier, self.url, status) from None
            raise UnreachableError(self.tier, self.url, status) from None
        except Exception as e:
            await _quiet_disconnect(client)
            raise UnreachableError(self.tier, self.url, _describe(e, self.timeout_s)) from None
        try:
            idx = await asyncio.wait_for(client.get_namespace_index(NAMESPACE_URI), self.timeout_s)
        except Exception as e:
            await _quiet_disconnect(client)
            # asyncua answers a missing namespace URI with list.index's ValueError.
            missing = f"no {NAMESPACE_URI} namespace" if isinstance(e, ValueError) else None
            raise UnreachableError(self.tier, self.url, missing or _describe(e, self.timeout_s)) from None
        self._client, self.idx = client, int(idx)
        paths = identity_paths(self.tier)
        if self.stack.resolved:  # the Config text is only needed to learn the site
            del paths["Config"]
        try:
            values = await self.read(list(paths.values()))
            self.stack.accept(self.tier, self.url, {item: values[p] for item, p in paths.items()})
        except TanklabError:
            await self.close()
            raise
        return self

    async def close(self) -> None:
        """Disconnect (idempotent, never raises)."""
        client, self._client = self._client, None
        if client is not None:
            await _quiet_disconnect(client)

    async def __aenter__(self) -> TierClient:
        return await self.connect()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def _bounded(self, aw: Awaitable[_T]) -> _T:
        """Await a request within the timeout; lost links and timeouts become UnreachableError."""
        try:
            return await asyncio.wait_for(aw, self.timeout_s)
        except Exception as e:
            await self.close()
            raise UnreachableError(self.tier, self.url, _describe(e, self.timeout_s)) from None

    def node(self, path: str) -> Node:
        """The node of a tag path (string NodeId in the tanklab namespace)."""
        return self.client.get_node(ua.NodeId(path, self.idx))

    async def read(self, paths: Sequence[str]) -> dict[str, Any]:
        """Values of ``paths`` in one Read; a node answering a Bad status reads as None."""
        if not paths:
            return {}
        dvs = await self._bounded(self.client.read_attributes([self.node(p) for p in paths]))
        out: dict[str, Any] = {}
        for path, dv in zip(paths, dvs, strict=True):
            bad = dv.StatusCode is not None and dv.StatusCode.is_bad()
            out[path] = None if bad or dv.Value is None else dv.Value.Value
        return out

    async def write(self, path: str, value: Any) -> None:
        """Write one value with the tag's exact type; a Bad status raises :class:`RefusedError`."""
        tag = self.tags[path]
        status = await self._bounded(write_value(self.node(path), tag, value))
        if not status.is_good():
            raise RefusedError(path, _show(tag, value), status.name)

    async def call(self, path: str, *args: float, hints: Mapping[str, str] | None = None) -> None:
        """Call the method ``path`` with Double arguments; a Bad status raises
        :class:`CallRefusedError` (with ``hints[status]`` as its reason, when given)."""
        tag = self.tags[path]
        parent = self.node(tag.parent)
        variants = [ua.Variant(float(a), ua.VariantType.Double) for a in args]

        async def call() -> str | None:
            try:
                await parent.call_method(ua.NodeId(path, self.idx), *variants)
            except ua.UaStatusCodeError as e:
                return str(ua.StatusCode(e.code).name)
            return None

        status = await self._bounded(call())
        if status is not None:
            shown = ", ".join(f"{a:g}" for a in args)
            raise CallRefusedError(path, shown, status, (hints or {}).get(status, ""))

    async def eu_range(self, path: str) -> tuple[float, float] | None:
        """The EURange property of a node as the server has it (None if it has none)."""
        params = ua.BrowseParameters()
        params.NodesToBrowse = [_browse_description(self.node(path).nodeid, ua.ObjectIds.HasProperty)]
        (refs,) = await self._browse_all(params)
        for ref in refs:
            if ref.BrowseName.Name == "EURange":
                rng = (await self.read_ids([(ref.NodeId, ua.AttributeIds.Value)]))[0]
                if rng is not None:
                    return (float(rng.Low), float(rng.High))
        return None

    async def read_ids(self, items: Sequence[tuple[ua.NodeId, ua.AttributeIds]]) -> list[Any]:
        """Attribute values of arbitrary nodes, in Reads of at most 500 items; Bad -> None."""
        out: list[Any] = []
        for start in range(0, len(items), 500):
            params = ua.ReadParameters()
            for nid, attr in items[start : start + 500]:
                rv = ua.ReadValueId()
                rv.NodeId = nid
                rv.AttributeId = attr
                params.NodesToRead.append(rv)
            dvs = await self._bounded(self.client.uaclient.read(params))
            for dv in dvs:
                bad = dv.StatusCode is not None and dv.StatusCode.is_bad()
                out.append(None if bad or dv.Value is None else dv.Value.Value)
        return out

    async def _browse_all(self, params: ua.BrowseParameters) -> list[list[ua.ReferenceDescription]]:
        """Browse, following continuation points to the end."""
        results = await self._bounded(self.client.uaclient.browse(params))
        out: list[list[ua.ReferenceDescription]] = []
        for result in results:
            refs = list(result.References or [])
            cp = result.ContinuationPoint
            while cp:
                nxt = ua.BrowseNextParameters()
                nxt.ReleaseContinuationPoints = False
                nxt.ContinuationPoints = [cp]
                (more,) = await self._bounded(self.client.uaclient.browse_next(nxt))
                refs += list(more.References or [])
                cp = more.ContinuationPoint
            out.append(refs)
        return out

    async def browse_tree(self, max_depth: int = 12) -> list[BrowsedNode]:
        """The tanklab nodes under the Objects folder, browsed level by level (one Browse per
        depth) and then read (Value, DataType, UserAccessLevel, Description and the properties
        EngineeringUnits, EURange, EnumStrings, Input/OutputArguments) in one Read."""
        roots: list[BrowsedNode] = []
        frontier: list[tuple[ua.NodeId, BrowsedNode | None]] = [(ua.NodeId(ua.ObjectIds.ObjectsFolder), None)]
        seen: set[ua.NodeId] = set()
        found: list[tuple[ua.NodeId, BrowsedNode]] = []
        props: list[tuple[BrowsedNode, str, ua.NodeId]] = []
        for _ in range(max_depth):
            if not frontier:
                break
            params = ua.BrowseParameters()
            params.NodesToBrowse = [
                _browse_description(nid, ua.ObjectIds.HierarchicalReferences) for nid, _ in frontier
            ]
            results = await self._browse_all(params)
            nxt: list[tuple[ua.NodeId, BrowsedNode | None]] = []
            for (_, parent), refs in zip(frontier, results, strict=True):
                for ref in refs:
                    nid = ref.NodeId
                    if nid.NamespaceIndex != self.idx or nid in seen:
                        continue
                    seen.add(nid)
                    if parent is not None and ref.ReferenceTypeId == ua.NodeId(ua.ObjectIds.HasProperty):
                        props.append((parent, ref.BrowseName.Name, nid))
                        continue
                    ident = nid.Identifier if isinstance(nid.Identifier, str) else nid.to_string()
                    node = BrowsedNode(ref.BrowseName.Name, ident, ua.NodeClass(ref.NodeClass).name)
                    (roots if parent is None else parent.children).append(node)
                    found.append((nid, node))
                    nxt.append((nid, node))
            frontier = nxt
        attrs = (
            ua.AttributeIds.Value,
            ua.AttributeIds.DataType,
            ua.AttributeIds.UserAccessLevel,
            ua.AttributeIds.Description,
        )
        items: list[tuple[ua.NodeId, ua.AttributeIds]] = []
        for nid, node in found:
            for attr in attrs if node.node_class == "Variable" else (ua.AttributeIds.Description,):
                items.append((nid, attr))
        items += [(nid, ua.AttributeIds.Value) for _, _, nid in props]
        values = iter(await self.read_ids(items))
        for _, node in found:
            if node.node_class == "Variable":
                node.value = next(values)
                dtype = next(values)
                access = next(values)
                node.writable = (
                    bool(access & ua.AccessLevel.CurrentWrite.mask) if access is not None else None
                )
                if node.value is None:
                    node.status = "Bad"
                node.data_type = _type_name(dtype, node.value)
            desc = next(values)
            node.description = desc.Text if isinstance(desc, ua.LocalizedText) and desc.Text else ""
        for parent, name, _ in props:
            value = next(values)
            if name == "EngineeringUnits" and value is not None:
                parent.unit = value.DisplayName.Text
            elif name == "EURange" and value is not None:
                parent.eu_range = (float(value.Low), float(value.High))
            elif name == "EnumStrings" and value is not None:
                parent.enum_strings = [v.Text if isinstance(v, ua.LocalizedText) else str(v) for v in value]
            elif name in ("InputArguments", "OutputArguments") and value is not None:
                args = [a.Name for a in value]
                if name == "InputArguments":
                    parent.inputs = args
                else:
                    parent.outputs = args
        return roots


def _browse_description(nid: ua.NodeId, reference_type: int) -> ua.BrowseDescription:
    d = ua.BrowseDescription()
    d.NodeId = nid
    d.BrowseDirection = ua.BrowseDirection.Forward
    d.ReferenceTypeId = ua.NodeId(reference_type)
    d.IncludeSubtypes = True
    d.NodeClassMask = 0
    d.ResultMask = ua.BrowseResultMask.All
    return d


def _type_name(dtype: Any, value: Any) -> str | None:
    if not isinstance(dtype, ua.NodeId):
        return None
    name = ua.ObjectIdNames.get(dtype.Identifier) if dtype.NamespaceIndex == 0 else None
    name = name or dtype.to_string()
    return f"{name}[]" if isinstance(value, list) else name


async def _quiet_disconnect(client: Client) -> None:
    # The peer may be gone already: a failed goodbye has nothing to tell the operator.
    with contextlib.suppress(Exception):
        await asyncio.wait_for(client.disconnect(), 1.0)


# --------------------------------------------------------------------------------------------
# Formatting
# --------------------------------------------------------------------------------------------


def _show(tag: Tag, value: Any) -> str:
    """A value as the operator typed or reads it: enum names, %g numbers."""
    if value is None:
        return "-"
    if tag.enum is not None and not isinstance(value, bool):
        try:
            return tag.enum(int(value)).name
        except ValueError:
            return str(value)
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return "[" + ", ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in value) + "]"
    return str(value)


def _with_unit(tag: Tag, value: Any) -> str:
    text = _show(tag, value)
    return f"{text} {tag.unit}" if tag.unit and tag.unit != "1" and value is not None else text


def _num(value: Any, unit: str | None = None) -> str:
    """A number for a table cell: 4 decimals for metres, 4 significant digits otherwise."""
    if value is None or isinstance(value, bool) or not isinstance(value, int | float):
        return "-" if value is None else str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if unit == "m":
        return f"{value:.4f}"
    if isinstance(value, float) and 1e3 <= abs(value) < 1e9:  # model times, scan counts: no exponent
        return f"{value:.1f}"
    return f"{value:.4g}"


def _secs(value: Any) -> str:
    """A model time for display: seconds with one decimal."""
    return f"{value:.1f}" if isinstance(value, float) else _num(value)


def _sci(value: Any) -> str:
    """A gain for a table cell: scientific notation, 3 decimals."""
    if isinstance(value, float) and math.isfinite(value):
        return f"{value:.3e}"
    return _num(value)


def _enum_name(enum: Any, value: Any) -> Any:
    if value is None or isinstance(value, bool):
        return value
    try:
        return enum(int(value)).name
    except (ValueError, TypeError):
        return value


def _plain(value: Any) -> Any:
    """A JSON-safe value: non-finite floats as null, OPC UA structures as plain data."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, ua.LocalizedText):
        return value.Text
    if isinstance(value, ua.Range):
        return [float(value.Low), float(value.High)]
    if isinstance(value, ua.EUInformation):
        return value.DisplayName.Text
    if isinstance(value, ua.NodeId):
        return value.to_string()
    if isinstance(value, bytes):
        return value.hex()
    return str(value)


def _console() -> Console:
    """stdout console; 120 columns when not a terminal (pipes, tests) unless COLUMNS says."""
    console = Console(markup=False, highlight=False, emoji=False)
    if not console.is_terminal and not _env("COLUMNS"):
        console.width = 120
    return console


def _percent_of(value: Any, rng: tuple[float, float] | None) -> float | None:
    if not isinstance(value, int | float) or rng is None or rng[1] <= rng[0]:
        return None
    return 100.0 * (float(value) - rng[0]) / (rng[1] - rng[0])


# --------------------------------------------------------------------------------------------
# Running a command: asyncio.run, quiet logging, one-line failures
# --------------------------------------------------------------------------------------------


def _fail(message: str, code: int) -> typer.Exit:
    typer.echo(f"tankctl: {message}", err=True)
    return typer.Exit(code)


def _quiet_logging() -> None:
    """asyncua (and tanklab's links) log below ERROR only to debug a session: not here."""
    for name in ("asyncua", "tanklab"):
        logging.getLogger(name).setLevel(logging.ERROR)


def _run(main: Callable[[], Coroutine[Any, Any, int]]) -> None:
    """Run ``main()`` under asyncio; its result is the exit code, its errors one line each."""
    _quiet_logging()
    try:
        code = asyncio.run(main())
    except RefusedError as e:
        raise _fail(str(e), 1) from None
    except StoppedError as e:
        raise _fail(str(e), 130) from None
    except TanklabError as e:  # UnreachableError, UsageError, ConfigError
        raise _fail(str(e), 2) from None
    except Exception as e:  # the CLI's boundary: a bug still gets one line, not a traceback
        raise _fail(f"internal error: {type(e).__name__}: {e}", 1) from None
    if code:
        raise typer.Exit(code)


def _stack_or_exit(
    config: Path | None,
    host: str | None,
    base_port: int | None,
    plant_url: str | None,
    plc_url: str | None,
    supervisor_url: str | None,
    timeout: float,
    endpoints_of: SiteConfig | None = None,
) -> Stack:
    try:
        return make_stack(
            config,
            host,
            base_port,
            plant_url,
            plc_url,
            supervisor_url,
            timeout,
            endpoints_of=endpoints_of,
        )
    except TanklabError as e:
        raise _fail(str(e), 2) from None


def _check(check: Callable[[], _T]) -> _T:
    """Run a local argument check; its UsageError is one line and exit code 2."""
    try:
        return check()
    except UsageError as e:
        raise _fail(str(e), 2) from None


class _StopOnSignal:
    """An event set by SIGINT/SIGTERM while the block runs (where signals can be handled)."""

    def __init__(self) -> None:
        self.event = asyncio.Event()
        self._installed: list[signal.Signals] = []

    def __enter__(self) -> asyncio.Event:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, self.event.set)
                self._installed.append(sig)
            except (NotImplementedError, RuntimeError, ValueError):
                pass  # not the main thread (or no signal support): Ctrl-C keeps its default
        return self.event

    def __exit__(self, *exc: object) -> None:
        loop = asyncio.get_running_loop()
        for sig in self._installed:
            loop.remove_signal_handler(sig)


# --------------------------------------------------------------------------------------------
# Common options
# --------------------------------------------------------------------------------------------

ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        "-c",
        help="Site YAML the stack must run: checked against every tier's identity (env "
        "TANKLAB_CONFIG; default: the site the stack publishes).",
    ),
]
HostOpt = Annotated[
    str | None,
    typer.Option(help="Host of the tiers for --base-port or the config's ports (default 127.0.0.1)."),
]
BasePortOpt = Annotated[
    int | None,
    typer.Option(
        help="Plant at N, PLC at N+1, supervisor at N+2 (env TANKLAB_BASE_PORT; default: the config's "
        "endpoints, 4840..4842)."
    ),
]
PlantUrlOpt = Annotated[str | None, typer.Option(help="Plant endpoint (env TANKLAB_PLANT_URL).")]
PlcUrlOpt = Annotated[str | None, typer.Option(help="PLC endpoint (env TANKLAB_PLC_URL).")]
SupervisorUrlOpt = Annotated[
    str | None, typer.Option(help="Supervisor endpoint (env TANKLAB_SUPERVISOR_URL).")
]
TimeoutOpt = Annotated[float, typer.Option(help="Seconds to wait for a tier to connect or answer.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON (shape in docs/cli.md).")]


# --------------------------------------------------------------------------------------------
# Writes: setpoint, leak, valve, loop, mode
# --------------------------------------------------------------------------------------------


async def _write_and_tell(client: TierClient, path: str, value: Any, note: str = "") -> str:
    """Read the old value, write the new one, return ``PATH = NEW unit (was OLD unit)``."""
    tag = client.tags[path]
    old = (await client.read([path]))[path]
    await client.write(path, value)
    extra = f" ({note})" if note else f" (was {_with_unit(tag, old)})"
    return f"{path} = {_with_unit(tag, value)}{extra}"


def setpoint(
    loop: Annotated[str, typer.Argument(help="Loop, e.g. LIC1.")],
    value: Annotated[float, typer.Argument(help="New setpoint, in m.")],
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Write a loop's setpoint, in m, to the PLC (PLC.LIC{j}.SP; the PLC range-checks it)."""
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)

    async def main() -> int:
        await stack.resolve("plc")
        name = stack.loop(loop)
        async with stack.client("plc") as plc:
            typer.echo(await _write_and_tell(plc, f"PLC.{name}.SP", value))
        return 0

    _run(main)


def _opening(text: str, what: str, words: Mapping[str, float]) -> float:
    key = text.strip().lower()
    if key in words:
        return words[key]
    try:
        value = float(key)
    except ValueError:
        raise UsageError(
            f"{what} must be a number 0..1 or {' / '.join(repr(w) for w in words)}, got {text!r}"
        ) from None
    if not math.isfinite(value):
        raise UsageError(f"{what} must be a finite number, got {text!r}")
    return value


def leak(
    tank: Annotated[str, typer.Argument(help="Tank, e.g. T1.")],
    opening: Annotated[str, typer.Argument(help="Leak valve opening 0..1, or 'off' (= 0).")],
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Open a tank's leak valve to the drain (Plant.T{i}.Leak, 0..1); 'off' closes it."""
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)
    value = _check(lambda: _opening(opening, "the leak opening", {"off": 0.0}))

    async def main() -> int:
        await stack.resolve("plant")
        name = stack.tank(tank)
        async with stack.client("plant") as plant:
            typer.echo(await _write_and_tell(plant, f"Plant.{name}.Leak", value))
        return 0

    _run(main)


def valve(
    name: Annotated[str, typer.Argument(help="Valve, e.g. V13.")],
    opening: Annotated[
        str, typer.Argument(help="Opening 0 (clogged) .. 1 (free); 'open' = 1, 'closed' = 0.")
    ],
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Set a connecting or outlet valve's opening (Plant.V{mn}.Opening, 0..1): a clog."""
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)
    value = _check(lambda: _opening(opening, "the valve opening", {"open": 1.0, "closed": 0.0}))

    async def main() -> int:
        await stack.resolve("plant")
        vname = stack.valve(name)
        async with stack.client("plant") as plant:
            typer.echo(await _write_and_tell(plant, f"Plant.{vname}.Opening", value))
        return 0

    _run(main)


def _loop_mode(text: str) -> LoopMode:
    try:
        return LoopMode[text.strip().upper()]
    except KeyError:
        raise UsageError(f"loop mode must be manual, auto or remote, got {text!r}") from None


def _check_percent(percent: float | None, mode: LoopMode) -> None:
    if percent is None:
        return
    if mode is not LoopMode.MANUAL:
        raise UsageError(f"an output percentage goes with manual only, not {mode.name.lower()}")
    if not (math.isfinite(percent) and 0.0 <= percent <= 100.0):
        raise UsageError(f"the manual output must be 0..100 % of the MV range, got {percent:g}")


async def _apply_loop_mode(plc: TierClient, loop: str, mode: LoopMode, percent: float | None) -> list[str]:
    """Switch a loop's mode; for MANUAL with a percentage, then move ManualMV to it.

    Mode first, then the output: the PLC's MANUAL switch is bumpless (it starts ManualMV from
    the applied MV, overwriting any preset), so a ManualMV written before the switch would be
    lost; written after it, it steps the output from where the loop was.
    """
    lines: list[str] = []
    mode_path, mv_path = f"PLC.{loop}.Mode", f"PLC.{loop}.ManualMV"
    lines.append(await _write_and_tell(plc, mode_path, int(mode)))
    if percent is not None:
        rng = await plc.eu_range(mv_path) or plc.tags[mv_path].eu_range
        assert rng is not None  # every ManualMV tag has a range
        value = rng[0] + percent / 100.0 * (rng[1] - rng[0])
        tag = plc.tags[mv_path]
        unit = f" {tag.unit}" if tag.unit and tag.unit != "1" else ""
        note = f"{percent:g} % of {rng[0]:g} .. {rng[1]:g}{unit}"
        lines.append(await _write_and_tell(plc, mv_path, value, note))
    return lines


def loop_command(
    loop: Annotated[str, typer.Argument(help="Loop, e.g. LIC1.")],
    mode: Annotated[str, typer.Argument(help="manual, auto or remote.")],
    percent: Annotated[
        float | None, typer.Argument(help="Manual output in percent of the ManualMV's EURange (0..100).")
    ] = None,
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Switch a loop: 'manual [PERCENT]' (bumpless, then the output to PERCENT), 'auto', 'remote'."""
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)
    new_mode = _check(lambda: _loop_mode(mode))
    _check(lambda: _check_percent(percent, new_mode))

    async def main() -> int:
        await stack.resolve("plc")
        name = stack.loop(loop)
        async with stack.client("plc") as plc:
            for line in await _apply_loop_mode(plc, name, new_mode, percent):
                typer.echo(line)
        return 0

    _run(main)


def _supervisor_mode(text: str) -> SupervisorMode:
    try:
        return SupervisorMode[text.strip().upper().replace("-", "_")]
    except KeyError:
        raise UsageError(f"mode must be adaptive-pid, mpc, advisory or off, got {text!r}") from None


def mode(
    name: Annotated[str, typer.Argument(help="adaptive-pid, mpc, advisory or off.")],
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Switch the supervisor's mode (Supervisor.Mode); it takes effect at its next cycle."""
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)
    new = _check(lambda: _supervisor_mode(name))

    async def main() -> int:
        await stack.resolve("supervisor")
        stack.require("supervisor")
        async with stack.client("supervisor") as sup:
            typer.echo(await _write_and_tell(sup, "Supervisor.Mode", int(new)))
        return 0

    _run(main)


# --------------------------------------------------------------------------------------------
# gains
# --------------------------------------------------------------------------------------------


async def _try_connect(client: TierClient) -> TierClient | UnreachableError:
    try:
        return await client.connect()
    except UnreachableError as e:
        return e


_GAIN_HINTS = {
    "BadUserAccessDenied": "your role may not do this",
    "BadOutOfRange": "a gain is not finite or lies outside the loop's gain box",
}
_RESET_HINTS = {
    **_GAIN_HINTS,
    "BadInvalidState": "a mode change of the loop is pending (retry after the next scan), or its "
    "block has no PID gains",
}
_SET_HINTS = {**_GAIN_HINTS, "BadInvalidState": "the loop's block has no PID gains"}


def _change_gains(
    stack: Stack,
    loop: str,
    new: tuple[float | None, float | None, float | None],
    reset: bool,
    release: bool,
) -> None:
    """``tankctl gains LOOP --kp/--ki/--kd | --reset | --release``: one call, one line."""
    if sum((reset, release, any(g is not None for g in new))) > 1:
        raise _fail("give one of --kp/--ki/--kd, --reset and --release", 2)
    for label, g in zip(("--kp", "--ki", "--kd"), new, strict=True):
        if g is not None and not math.isfinite(g):
            raise _fail(f"{label} must be a finite number, got {g}", 2)

    async def main() -> int:
        await stack.resolve("plc")
        name = stack.loop(loop)
        tags = stack.tags("plc")
        p = f"PLC.{name}"
        async with stack.client("plc") as plc:
            paths = [f"{p}.{g}" for g in ("Kp", "Ki", "Kd", "GainSource")]
            before = await plc.read(paths)
            source = _show(tags[f"{p}.GainSource"], before[f"{p}.GainSource"])
            applied = " ".join(f"{g} = {_sci(before[f'{p}.{g}'])}" for g in ("Kp", "Ki", "Kd"))
            if reset:
                await plc.call(f"{p}.ResetGains", hints=_RESET_HINTS)
                typer.echo(
                    f"{name}: ResetGains: the configured gains from the next scan on, GainSource FIXED "
                    f"(was {source}: {applied})"
                )
            elif release:
                await plc.call(f"{p}.ReleaseGains", hints=_SET_HINTS)
                if source == "ENGINEER":
                    typer.echo(
                        f"{name}: ReleaseGains: back under adaptation, gains kept ({applied}), "
                        "GainSource FIXED until the supervisor pushes"
                    )
                else:
                    typer.echo(
                        f"{name}: ReleaseGains: not held by an engineer (GainSource {source}), no change"
                    )
            else:
                # An omitted gain keeps its applied value: SetGains always sends all three.
                current = (before[f"{p}.Kp"], before[f"{p}.Ki"], before[f"{p}.Kd"])
                kp, ki, kd = (float(c) if g is None else g for g, c in zip(new, current, strict=True))
                await plc.call(f"{p}.SetGains", kp, ki, kd, hints=_SET_HINTS)
                typer.echo(
                    f"{name}: SetGains(Kp = {_sci(kp)}, Ki = {_sci(ki)}, Kd = {_sci(kd)}) from the next scan "
                    f"on, GainSource ENGINEER (was {source}); the supervisor is kept off until "
                    f"`tankctl gains {name} --release` or `--reset`"
                )
        return 0

    _run(main)


def gains(
    loop: Annotated[str, typer.Argument(help="Loop, e.g. LIC1.")],
    kp: Annotated[
        float | None, typer.Option("--kp", help="Set Kp (SetGains as an engineer: GainSource ENGINEER).")
    ] = None,
    ki: Annotated[
        float | None, typer.Option("--ki", help="Set Ki [per s] (omitted: the applied Ki).")
    ] = None,
    kd: Annotated[float | None, typer.Option("--kd", help="Set Kd [s] (omitted: the applied Kd).")] = None,
    reset: Annotated[
        bool, typer.Option("--reset", help="ResetGains: the configured (FIXED) gains at the next scan.")
    ] = False,
    release: Annotated[
        bool, typer.Option("--release", help="ReleaseGains: hand an ENGINEER loop back to adaptation.")
    ] = False,
    as_json: JsonOpt = False,
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """A loop's applied Kp, Ki, Kd and GainSource, and the supervisor's RLS state for it; with
    --kp/--ki/--kd, --reset or --release, change them (one call, one line)."""
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)
    if reset or release or kp is not None or ki is not None or kd is not None:
        _change_gains(stack, loop, (kp, ki, kd), reset, release)
        return

    async def main() -> int:
        await stack.resolve("plc")
        name = stack.loop(loop)
        p = f"PLC.{name}"
        plc_paths = [f"{p}.{g}" for g in ("Kp", "Ki", "Kd", "GainSource", "Block", "Mode")]
        s = f"Supervisor.RLS.{name}"
        sup_paths = ["Supervisor.Mode"] + [
            f"{s}.{x}" for x in ("Theta", "CovarianceTrace", "Accepted", "Rejected", "LastReason")
        ]
        async with stack.client("plc") as plc:
            pv = await plc.read(plc_paths)
        sup_json: dict[str, Any] | None = None
        if stack.has("supervisor"):
            sup = await _try_connect(stack.client("supervisor"))
            if isinstance(sup, UnreachableError):
                sup_json = {"reachable": False, "url": sup.url, "error": sup.reason}
            else:
                try:
                    sv = await sup.read(sup_paths)
                finally:
                    await sup.close()
                sup_json = {
                    "reachable": True,
                    "url": sup.url,
                    "mode": _enum_name(SupervisorMode, sv["Supervisor.Mode"]),
                    "theta": _plain(sv[f"{s}.Theta"]),
                    "covariance_trace": _plain(sv[f"{s}.CovarianceTrace"]),
                    "accepted": sv[f"{s}.Accepted"],
                    "rejected": sv[f"{s}.Rejected"],
                    "last_reason": sv[f"{s}.LastReason"],
                }
        tags = stack.tags("plc")
        out = {
            "loop": name,
            "url": stack.urls["plc"],
            "block": pv[f"{p}.Block"],
            "mode": _show(tags[f"{p}.Mode"], pv[f"{p}.Mode"]),
            "kp": _plain(pv[f"{p}.Kp"]),
            "ki": _plain(pv[f"{p}.Ki"]),
            "kd": _plain(pv[f"{p}.Kd"]),
            "gain_source": _show(tags[f"{p}.GainSource"], pv[f"{p}.GainSource"]),
            "supervisor": sup_json,
        }
        if as_json:
            typer.echo(json.dumps(out, indent=2))
            return 0
        typer.echo(
            f"{name} ({out['block']}, {out['mode']}): Kp = {_sci(out['kp'])}  Ki = {_sci(out['ki'])}"
            f"  Kd = {_sci(out['kd'])}  from {out['gain_source']}"
        )
        if sup_json is None:
            typer.echo("supervisor: not in this site")
        elif not sup_json["reachable"]:
            typer.echo(f"supervisor: unreachable at {sup_json['url']}: {sup_json['error']}")
        else:
            theta = sup_json["theta"] or []
            shown = "[" + ", ".join(_sci(v) for v in theta) + "]" if theta else "[] (not estimated yet)"
            reason = sup_json["last_reason"] or "-"
            typer.echo(
                f"supervisor ({sup_json['mode']}): RLS theta {shown}, covariance trace "
                f"{_num(sup_json['covariance_trace'])}, accepted {sup_json['accepted']}, "
                f"rejected {sup_json['rejected']}, last reason: {reason}"
            )
        return 0

    _run(main)


# --------------------------------------------------------------------------------------------
# status
# --------------------------------------------------------------------------------------------


async def _read_tier(stack: Stack, tier: Tier) -> dict[str, Any] | UnreachableError:
    """Every contract variable of a tier in one Read, or why the tier did not answer."""
    client = stack.client(tier)
    paths = [t.path for t in client.tags.values() if t.kind == "variable"]
    try:
        async with client:
            return await client.read(paths)
    except UnreachableError as e:
        return e


def _plant_json(stack: Stack, v: dict[str, Any]) -> dict[str, Any]:
    site = stack.site
    tags = stack.tags("plant")
    tanks = {}
    for t in site.tank_names:
        i = t[1:]
        tanks[t] = {
            "level_m": _plain(v[f"Plant.{t}.Level"]),
            "lt_pv_m": _plain(v[f"Plant.LT{i}.PV"]),
            "lt_fault": _show(tags[f"Plant.LT{i}.Fault"], v[f"Plant.LT{i}.Fault"]),
            "lt_fault_value": _plain(v[f"Plant.LT{i}.FaultValue"]),
            "leak": _plain(v[f"Plant.{t}.Leak"]),
            "disturbance_m3_s": _plain(v[f"Plant.{t}.Disturbance"]),
            "lsh": v[f"Plant.{t}.LSH"],
            "lsl": v[f"Plant.{t}.LSL"],
        }
    return {
        "model_time_s": _plain(v["Plant.Sim.Time"]),
        "speed": _plain(v["Plant.Sim.Speed"]),
        "watchdog": v["Plant.Sim.Watchdog"],
        "tanks": tanks,
        "valves": {n: {"opening": _plain(v[f"Plant.{n}.Opening"])} for n in site.valve_names},
        "pumps": {
            p.name: {
                "command": _plain(v[f"Plant.{p.name}.Command"]),
                "unit": p.unit,
                "flow_m3_s": _plain(v[f"Plant.{p.name}.Flow"]),
            }
            for p in site.plant.pumps
        },
        "balance_error_m3": _plain(v["Plant.Balance.Error"]),
    }


def _plc_json(stack: Stack, v: dict[str, Any]) -> dict[str, Any]:
    site = stack.site
    tags = stack.tags("plc")
    loops = {}
    for name in site.loop_names:
        p = f"PLC.{name}"
        mv_tag = tags[f"{p}.MV"]
        loops[name] = {
            "block": v[f"{p}.Block"],
            "mode": _show(tags[f"{p}.Mode"], v[f"{p}.Mode"]),
            "sp_m": _plain(v[f"{p}.SP"]),
            "pv_m": _plain(v[f"{p}.PV"]),
            "mv": _plain(v[f"{p}.MV"]),
            "mv_unit": mv_tag.unit,
            "mv_percent": _plain(_percent_of(v[f"{p}.MV"], mv_tag.eu_range)),
            "manual_mv": _plain(v[f"{p}.ManualMV"]),
            "kp": _plain(v[f"{p}.Kp"]),
            "ki": _plain(v[f"{p}.Ki"]),
            "kd": _plain(v[f"{p}.Kd"]),
            "gain_source": _show(tags[f"{p}.GainSource"], v[f"{p}.GainSource"]),
        }
    variables = [path for path, tag in tags.items() if tag.kind == "variable"]
    alarms = {path.split(".", 2)[2]: v[path] for path in variables if path.startswith("PLC.Alarms.")}
    interlocks = {path.split(".", 2)[2]: v[path] for path in variables if path.startswith("PLC.Interlock.")}
    return {
        "scan": v["PLC.Status.Scan"],
        "model_time_s": _plain(v["PLC.Status.ModelTime"]),
        "io_healthy": v["PLC.Status.IoHealthy"],
        "overruns": v["PLC.Status.Overruns"],
        "last_scan_duration_s": _plain(v["PLC.Status.LastScanDuration"]),
        "supervisor_alive": v["PLC.Supervisor.Alive"],
        "loops": loops,
        "io": {
            f"LT{t[1:]}": {"pv_m": _plain(v[f"PLC.IO.LT{t[1:]}.PV"]), "good": v[f"PLC.IO.LT{t[1:]}.Good"]}
            for t in site.tank_names
        },
        "alarms": alarms,
        "active_alarms": [k for k, on in alarms.items() if on],
        "interlocks": interlocks,
        "tripped": [k for k, on in interlocks.items() if on],
    }


def _supervisor_json(stack: Stack, v: dict[str, Any]) -> dict[str, Any]:
    tags = stack.tags("supervisor")
    return {
        "mode": _show(tags["Supervisor.Mode"], v["Supervisor.Mode"]),
        "cycle": v["Supervisor.Cycle"],
        "plc_connected": v["Supervisor.PlcConnected"],
        "mpc": {
            "status": _show(tags["Supervisor.MPC.Status"], v["Supervisor.MPC.Status"]),
            "solve_time_s": _plain(v["Supervisor.MPC.SolveTime"]),
            "iterations": v["Supervisor.MPC.Iterations"],
            "failures": v["Supervisor.MPC.Failures"],
            "horizon": v["Supervisor.MPC.Horizon"],
        },
    }


async def collect_status(stack: Stack) -> dict[str, Any]:
    """The status document (``status --json``): one Read per tier, the tiers concurrently."""
    tiers = [t for t in TIERS if stack.has(t)]
    results = await asyncio.gather(*(_read_tier(stack, t) for t in tiers))
    shape = {"plant": _plant_json, "plc": _plc_json, "supervisor": _supervisor_json}
    doc: dict[str, Any] = {
        "site": stack.site.name,
        "config_digest": stack.site_identity.digest,
        "plant": None,
        "plc": None,
        "supervisor": None,
    }
    for tier, res in zip(tiers, results, strict=True):
        if isinstance(res, UnreachableError):
            doc[tier] = {"reachable": False, "url": stack.urls[tier], "error": res.reason}
        else:
            doc[tier] = {"reachable": True, "url": stack.urls[tier], **shape[tier](stack, res)}
    return doc


def _tier_state(tier: str, d: dict[str, Any]) -> str:
    if not d["reachable"]:
        return f"UNREACHABLE: {d['error']}"
    if tier == "plant":
        text = f"model time {_secs(d['model_time_s'])} s, speed {_num(d['speed'])}"
        return text + (", pump watchdog TRIPPED" if d["watchdog"] else "")
    if tier == "plc":
        io = "IO healthy" if d["io_healthy"] else "IO FAULT"
        sup = "supervisor alive" if d["supervisor_alive"] else "no supervisor heartbeat"
        t = _secs(d["model_time_s"])
        return f"scan {d['scan']}, model time {t} s, {io}, {sup}, overruns {d['overruns']}"
    mpc = d["mpc"]
    solve = f" {1e3 * mpc['solve_time_s']:.1f} ms" if isinstance(mpc["solve_time_s"], float) else ""
    plc = "PLC connected" if d["plc_connected"] else "PLC NOT connected"
    return f"mode {d['mode']}, cycle {d['cycle']}, MPC {mpc['status']}{solve}, {plc}"


def render_status(stack: Stack, doc: dict[str, Any]) -> Group:
    """The human form of the status document: tiers, tanks, loops, alarms."""
    site = stack.site
    shown = [t for t in TIERS if doc[t] is not None]
    url_width = max(len(doc[t]["url"]) for t in shown)
    title = Text(f"{site.name}", style="bold") + Text(
        f"  config {stack.site_identity.short} (from {stack.origin})"
    )
    title.no_wrap, title.overflow = True, "ignore"  # one line, however narrow the terminal
    lines = [title]
    for tier in shown:
        d = doc[tier]
        state = Text(_tier_state(tier, d), style="" if d["reachable"] else "bold red")
        line = Text(f"{tier:<11}{d['url']:<{url_width}}  ", no_wrap=True, overflow="ignore") + state
        line.no_wrap, line.overflow = True, "ignore"  # one line per tier, however wide
        lines.append(line)
    header = Group(*lines)

    plant = doc["plant"] if doc["plant"] and doc["plant"]["reachable"] else None
    plc = doc["plc"] if doc["plc"] and doc["plc"]["reachable"] else None
    loop_of = {"T" + lp.pv[2:]: lp.name for lp in (site.plc.loops if site.plc else [])}
    tanks = Table(title="tanks", title_justify="left")
    for col in ("tank", "level [m]", "PLC PV [m]", "SP [m]", "loop", "leak", "LT fault", "switches"):
        tanks.add_column(col, justify="left" if col in ("tank", "loop", "LT fault", "switches") else "right")
    for t in site.tank_names:
        pt = plant["tanks"][t] if plant else {}
        lt = f"LT{t[1:]}"
        io = plc["io"][lt] if plc else {}
        pv = _num(io.get("pv_m"), "m") + ("" if io.get("good", True) else " BAD")
        loop = loop_of.get(t)
        sp = _num(plc["loops"][loop]["sp_m"], "m") if plc and loop else ""
        switches = ", ".join(k.upper() for k in ("lsh", "lsl") if pt.get(k)) or ("-" if pt else "")
        fault = pt.get("lt_fault", "-")
        if fault not in ("NONE", "-"):
            fault = f"{fault} {pt.get('lt_fault_value', 0):g}"
        tanks.add_row(
            t, _num(pt.get("level_m"), "m"), pv, sp, loop or "", _num(pt.get("leak")), fault, switches
        )

    parts: list[Any] = [header]
    if plant is not None or plc is not None:
        parts += [Text(""), tanks]
    if plc is not None:
        loops = Table(title="loops", title_justify="left")
        for col in ("loop", "block", "mode", "SP [m]", "PV [m]", "MV", "MV %", "Kp", "Ki", "Kd", "gains"):
            loops.add_column(col, justify="left" if col in ("loop", "block", "mode", "gains") else "right")
        for name in site.loop_names:
            d = plc["loops"][name]
            mv = _num(d["mv"]) + (f" {d['mv_unit']}" if d["mv_unit"] not in (None, "1") else "")
            pct = d["mv_percent"]
            loops.add_row(
                name,
                d["block"] or "-",
                d["mode"],
                _num(d["sp_m"], "m"),
                _num(d["pv_m"], "m"),
                mv,
                f"{pct:.1f}" if isinstance(pct, float) else "-",
                _sci(d["kp"]),
                _sci(d["ki"]),
                _sci(d["kd"]),
                d["gain_source"],
            )
        parts += [Text(""), loops]
        alarms = ", ".join(plc["active_alarms"]) or "none"
        trips = ", ".join(plc["tripped"]) or "none"
        parts.append(Text(f"alarms: {alarms}; interlocks tripped: {trips}"))
    elif site.plc is not None:
        parts.append(Text("alarms: unknown (PLC unreachable)"))
    return Group(*parts)


def _print_unresolved(stack: Stack, as_json: bool) -> None:
    """status when no tier answered and no site was given: each tier and why, no site."""
    if as_json:
        doc: dict[str, Any] = {"site": None, "config_digest": None}
        for tier in TIERS:
            e = stack.unreached[tier]
            doc[tier] = {"reachable": False, "url": e.url, "error": e.reason}
        typer.echo(json.dumps(doc, indent=2))
        return
    width = max(len(e.url) for e in stack.unreached.values())
    typer.echo("site unknown: no tier answered")
    for tier in TIERS:
        e = stack.unreached[tier]
        typer.echo(f"{tier:<11}{e.url:<{width}}  UNREACHABLE: {e.reason}")


def status(
    as_json: JsonOpt = False,
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Levels, setpoints, MVs, modes, gains, alarms and health of every tier (one Read each).

    Exit 0 when the PLC answers (the plant, for a site without a PLC), even if another tier is
    down (shown as unreachable); exit 2, after printing what did answer, when it does not.
    """
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)

    async def main() -> int:
        try:
            await stack.resolve("plc", "plant")
        except UnreachableError as e:
            _print_unresolved(stack, as_json)
            raise e from None
        doc = await collect_status(stack)
        if as_json:
            typer.echo(json.dumps(doc, indent=2))
        else:
            _console().print(render_status(stack, doc), crop=False)
        key: Tier = "plc" if stack.has("plc") else "plant"
        if not doc[key]["reachable"]:
            typer.echo(f"tankctl: cannot reach {key} at {doc[key]['url']}: {doc[key]['error']}", err=True)
            return 2
        return 0

    _run(main)


# --------------------------------------------------------------------------------------------
# browse
# --------------------------------------------------------------------------------------------


def _value_cell(node: BrowsedNode) -> str:
    if node.node_class == "Method":
        ins = ", ".join(node.inputs or [])
        outs = ", ".join(node.outputs or [])
        return f"method ({ins})" + (f" -> ({outs})" if outs else "")
    if node.node_class != "Variable":
        return ""
    if node.status:
        return node.status
    if node.enum_name is not None:
        return f"{node.enum_name} ({node.value})"
    v = node.value
    if isinstance(v, list):
        text = "[" + ", ".join(_num(x) for x in v[:4]) + (", ..." if len(v) > 4 else "") + "]"
        return f"{text} ({len(v)})"
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return _num(v, node.unit)
    if isinstance(v, str):
        return repr(v)
    return str(_plain(v))


def render_tree(tier: str, url: str, roots: list[BrowsedNode]) -> Table:
    """One table per tier: the node tree (indented), value, unit, EURange, access."""
    table = Table(title=f"{tier}  {url}", title_justify="left")
    for col in ("node", "value", "unit", "EURange", "access"):
        table.add_column(col)
    for root in roots:
        for depth, node in root.walk():
            name = node.name + ("()" if node.node_class == "Method" else "")
            if node.node_class == "Variable":
                access = "rw" if node.writable else "r"
            else:
                access = "call" if node.node_class == "Method" else ""
            rng = f"{node.eu_range[0]:g} .. {node.eu_range[1]:g}" if node.eu_range else ""
            table.add_row("  " * depth + name, _value_cell(node), node.unit or "", rng, access)
    return table


async def _browse_tier(stack: Stack, tier: Tier) -> list[BrowsedNode] | UnreachableError:
    try:
        async with stack.client(tier) as client:
            return await client.browse_tree()
    except UnreachableError as e:
        return e


def browse(
    tier: Annotated[
        str | None, typer.Argument(help="plant, plc or supervisor (default: every tier).")
    ] = None,
    as_json: JsonOpt = False,
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Browse the servers' tanklab nodes under Objects: tree, values, units, EURange, access.

    Exit 2 (after printing the tiers that answered) if a tier asked for does not answer.
    """
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)
    key = tier.strip().lower() if tier is not None else None
    if key is not None and key not in TIERS:
        raise _fail(f"tier must be plant, plc or supervisor, got {tier!r}", 2)

    asked: list[Tier] = [t for t in TIERS if t == key]

    def which() -> list[Tier]:
        for t in asked:
            stack.require(t)
        return asked or [t for t in TIERS if stack.has(t)]

    async def main() -> int:
        await stack.resolve(*asked)
        tiers = which()
        results = await asyncio.gather(*(_browse_tier(stack, t) for t in tiers))
        doc: dict[str, Any] = {}
        console = _console()
        failures: list[UnreachableError] = []
        for t, res in zip(tiers, results, strict=True):
            if isinstance(res, UnreachableError):
                failures.append(res)
                doc[t] = {"reachable": False, "url": stack.urls[t], "error": res.reason}
                continue
            doc[t] = {"reachable": True, "url": stack.urls[t], "nodes": [n.as_json() for n in res]}
            if not as_json:
                console.print(render_tree(t, stack.urls[t], res))
        if as_json:
            typer.echo(json.dumps(doc, indent=2))
        for e in failures:
            typer.echo(f"tankctl: {e}", err=True)
        return 2 if failures else 0

    _run(main)


# --------------------------------------------------------------------------------------------
# watch
# --------------------------------------------------------------------------------------------

_SPARK = "▁▂▃▄▅▆▇█"


def sparkline(values: Sequence[float], lo: float, hi: float) -> str:
    """One block character per value, scaled on [lo, hi]."""
    span = hi - lo
    out = []
    for v in values:
        k = 0 if span <= 0 else round((min(max(v, lo), hi) - lo) / span * (len(_SPARK) - 1))
        out.append(_SPARK[k])
    return "".join(out)


def level_bar(level: float | None, sp: float | None, hmax: float, width: int = 24) -> Text:
    """A bar from 0 to Hmax filled to the level, with ``|`` at the setpoint."""
    text = Text()
    filled = 0 if level is None else round(min(max(level / hmax, 0.0), 1.0) * width)
    mark = None if sp is None else min(round(sp / hmax * width), width - 1)
    for i in range(width):
        if i == mark:
            text.append("|", style="bold red")
        elif i < filled:
            text.append("█", style="blue")
        else:
            text.append("·", style="dim")
    return text


@dataclass
class _Sample:
    model_time_s: float | None
    levels: dict[str, float | None]
    loops: dict[str, dict[str, Any]]
    notes: list[str]


class _Trend:
    """Recent samples of each tank's level, and how to draw them."""

    def __init__(self, stack: Stack) -> None:
        self.stack = stack
        site = stack.site
        self.tanks = site.tank_names
        self.hmax = {t.name: t.height_max_m for t in site.plant.tanks}
        self.loop_of = {"T" + lp.pv[2:]: lp.name for lp in (site.plc.loops if site.plc else [])}
        self.history: dict[str, deque[float]] = {t: deque(maxlen=TREND_SAMPLES) for t in self.tanks}
        self.last: _Sample | None = None

    def add(self, sample: _Sample) -> None:
        self.last = sample
        for t in self.tanks:
            v = sample.levels.get(t)
            if v is not None:
                self.history[t].append(v)

    def _loop(self, tank: str) -> dict[str, Any]:
        loop = self.loop_of.get(tank)
        return self.last.loops.get(loop, {}) if self.last and loop else {}

    def table(self, width: int) -> Table:
        """The live table for a terminal ``width`` columns wide (trend and bar take the rest)."""
        s = self.last
        t_text = f"{s.model_time_s:.1f} s" if s and s.model_time_s is not None else "-"
        spare = max(width - 63, 14)  # the other columns, their padding and the edges take 63
        n_trend = min(max(int(spare * 0.6), 8), TREND_SAMPLES)
        n_bar = min(max(spare - n_trend, 6), 40)
        notes = ["levels in m, | in the bar marks the setpoint", *(s.notes if s else [])]
        table = Table(
            title=f"tanklab watch: {self.stack.site.name}   model time {t_text}   (Ctrl-C to stop)",
            title_justify="left",
            caption="; ".join(notes),
            caption_justify="left",
            box=box.SIMPLE_HEAD,
        )
        right = ("level", "SP", "error", "MV %")
        for col in ("tank", "level", "SP", "error", "trend", "0..Hmax", "mode", "MV %"):
            table.add_column(col, justify="right" if col in right else "left", no_wrap=True)
        for t in self.tanks:
            level = s.levels.get(t) if s else None
            d = self._loop(t)
            sp = d.get("sp")
            err = round(sp - level, 4) + 0.0 if isinstance(sp, float) and isinstance(level, float) else None
            hist = list(self.history[t])[-n_trend:]
            # Autoscale on the window (and the setpoint), at least 2 cm tall so noise stays flat.
            pts = hist + ([sp] if isinstance(sp, float) else [])
            lo, hi = (min(pts), max(pts)) if pts else (0.0, self.hmax[t])
            if hi - lo < 0.02:
                mid = (hi + lo) / 2
                lo, hi = mid - 0.01, mid + 0.01
            pct = d.get("mv_percent")
            loop = self.loop_of.get(t)
            table.add_row(
                t,
                _num(level, "m"),
                _num(sp, "m") if sp is not None else "",
                _num(err, "m") if err is not None else "",
                sparkline(hist, lo, hi).ljust(n_trend),
                level_bar(level, sp if isinstance(sp, float) else None, self.hmax[t], n_bar),
                f"{loop} {d.get('mode', '')}" if loop else "",
                f"{pct:.1f}" if isinstance(pct, float) else "",
            )
        return table

    def line(self) -> str:
        """The plain form of the last sample (one line per sample when not on a terminal)."""
        s = self.last
        assert s is not None
        t_text = f"{s.model_time_s:9.1f}" if s.model_time_s is not None else "        -"
        parts = [f"t={t_text} s"]
        for t in self.tanks:
            level = s.levels.get(t)
            sp = self._loop(t).get("sp")
            part = f"{t} {_num(level, 'm')}"
            if sp is not None:
                part += f"/{_num(sp, 'm')}"
            parts.append(part + " m")
        return "  ".join(parts + s.notes)


class _Source:
    """A tier the watch reads every interval, reconnecting (one attempt per interval) if lost."""

    def __init__(self, client: TierClient, paths: list[str]) -> None:
        self.client = client
        self.paths = paths
        self.up = False
        self.reason = ""

    async def read(self) -> dict[str, Any] | None:
        try:
            if not self.up:
                await self.client.connect()
                self.up = True
            return await self.client.read(self.paths)
        except UnreachableError as e:
            self.up = False
            self.reason = e.reason
            await self.client.close()
            return None


async def _sample(trend: _Trend, plant: _Source, plc: _Source | None) -> _Sample:
    stack = trend.stack
    pv, cv = await asyncio.gather(plant.read(), plc.read() if plc else _none())
    notes = []
    levels: dict[str, float | None] = dict.fromkeys(trend.tanks)
    model_time = None
    if pv is None:
        notes.append(f"plant unreachable ({plant.reason}), retrying")
    else:
        levels = {t: pv[f"Plant.{t}.Level"] for t in trend.tanks}
        model_time = pv["Plant.Sim.Time"]
    loops: dict[str, dict[str, Any]] = {}
    if plc is not None and cv is None:
        notes.append(f"plc unreachable ({plc.reason}), retrying")
    elif cv is not None:
        tags = stack.tags("plc")
        for name in stack.site.loop_names:
            p = f"PLC.{name}"
            loops[name] = {
                "sp": cv[f"{p}.SP"],
                "mode": _show(tags[f"{p}.Mode"], cv[f"{p}.Mode"]),
                "mv_percent": _percent_of(cv[f"{p}.MV"], tags[f"{p}.MV"].eu_range),
            }
        if pv is None:  # the plant is away: show the levels the PLC last read
            levels = {t: cv.get(f"PLC.IO.LT{t[1:]}.PV") for t in trend.tanks}
    return _Sample(model_time, levels, loops, notes)


async def _none() -> None:
    return None


def watch(
    interval: Annotated[float, typer.Option(help="Wall seconds between refreshes.")] = 1.0,
    duration: Annotated[float | None, typer.Option(help="Stop after this many wall seconds.")] = None,
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Live trend of the levels against their setpoints until Ctrl-C (exit 0) or --duration.

    On a terminal: a table redrawn in place (sparkline of the recent levels, a bar from 0 to
    Hmax with the setpoint marked, the numbers). Otherwise: one line per refresh.
    """
    stack = _stack_or_exit(config, host, base_port, plant_url, plc_url, supervisor_url, timeout)

    def check() -> None:
        if not (math.isfinite(interval) and interval > 0):
            raise UsageError(f"--interval must be a positive number of seconds, got {interval:g}")
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            raise UsageError(f"--duration must be a positive number of seconds, got {duration:g}")

    _check(check)

    async def main() -> int:
        await stack.resolve("plant", "plc")
        site = stack.site
        plant = _Source(
            stack.client("plant"), ["Plant.Sim.Time"] + [f"Plant.{t}.Level" for t in site.tank_names]
        )
        plc = None
        if stack.has("plc"):
            paths = [f"PLC.{n}.{x}" for n in site.loop_names for x in ("SP", "MV", "Mode")]
            plc = _Source(stack.client("plc"), paths + [f"PLC.IO.LT{t[1:]}.PV" for t in site.tank_names])
        # Both tiers must answer at the start; later losses are shown and retried.
        for src in (plant, plc):
            if src is not None:
                await src.client.connect()
                src.up = True
        trend = _Trend(stack)
        console = _console()
        clock = MonotonicClock()
        start = clock.now()
        end = start + duration if duration is not None else math.inf
        deadlines = Deadlines(period_s=interval, next_deadline=start)
        try:
            with _StopOnSignal() as stop:
                live = Live(console=console, auto_refresh=False) if console.is_terminal else None
                with live or contextlib.nullcontext():
                    while not stop.is_set():
                        trend.add(await _sample(trend, plant, plc))
                        if live is not None:
                            live.update(trend.table(console.width), refresh=True)
                        else:
                            console.print(Text(trend.line()))
                        now = clock.now()
                        if now >= end:
                            break
                        await sleep_or_stop(clock, min(deadlines.finished(now), end), stop)
        finally:
            for src in (plant, plc):
                if src is not None:
                    await src.client.close()
        return 0

    _run(main)


# --------------------------------------------------------------------------------------------
# scenario run
# --------------------------------------------------------------------------------------------


def _event_tiers(scenario: Scenario) -> set[Tier]:
    tiers: set[Tier] = {"plant"}
    init = scenario.initial
    if init.setpoints_m or init.modes:
        tiers.add("plc")
    for ev in scenario.events:
        if isinstance(ev, SetpointEvent | LoopModeEvent):
            tiers.add("plc")
        elif isinstance(ev, SupervisorModeEvent):
            tiers.add("supervisor")
    return tiers


def _describe_event(ev: Event) -> str:
    if isinstance(ev, SetpointEvent):
        return f"setpoint {ev.loop} {ev.value_m:g} m"
    if isinstance(ev, LeakEvent):
        return f"leak {ev.tank} {ev.opening:g}"
    if isinstance(ev, ValveEvent):
        return f"valve {ev.valve} {ev.opening:g}"
    if isinstance(ev, FaultEvent):
        return f"fault {ev.transmitter} {ev.fault} {ev.value:g}"
    if isinstance(ev, DisturbanceEvent):
        return f"disturbance {ev.tank} {ev.flow_m3_s:g} m^3/s"
    if isinstance(ev, LoopModeEvent):
        pct = f" {ev.mv_percent:g} %" if ev.mv_percent is not None else ""
        return f"loop {ev.loop} {ev.mode.lower()}{pct}"
    return f"supervisor mode {ev.mode}"


async def _apply_event(clients: Mapping[Tier, TierClient], ev: Event) -> list[str]:
    """Write one event to the tier that owns its nodes; the lines say what was written."""
    plant = clients.get("plant")
    if isinstance(ev, SetpointEvent):
        return [await _write_and_tell(clients["plc"], f"PLC.{ev.loop}.SP", ev.value_m)]
    if isinstance(ev, LoopModeEvent):
        return await _apply_loop_mode(clients["plc"], ev.loop, LoopMode[ev.mode], ev.mv_percent)
    if isinstance(ev, SupervisorModeEvent):
        return [await _write_and_tell(clients["supervisor"], "Supervisor.Mode", int(SupervisorMode[ev.mode]))]
    assert plant is not None
    if isinstance(ev, LeakEvent):
        return [await _write_and_tell(plant, f"Plant.{ev.tank}.Leak", ev.opening)]
    if isinstance(ev, ValveEvent):
        return [await _write_and_tell(plant, f"Plant.{ev.valve}.Opening", ev.opening)]
    if isinstance(ev, DisturbanceEvent):
        return [await _write_and_tell(plant, f"Plant.{ev.tank}.Disturbance", ev.flow_m3_s)]
    # A fault: its size first, then its kind, so the fault starts with the right value.
    i = ev.transmitter[2:]
    return [
        await _write_and_tell(plant, f"Plant.LT{i}.FaultValue", ev.value),
        await _write_and_tell(plant, f"Plant.LT{i}.Fault", int(SensorFault[ev.fault])),
    ]


def _initial_events(scenario: Scenario) -> list[Event]:
    """The parts of ``initial`` a running stack can take, as events at 0 s (the rest is in
    :func:`tanklab.scenario.live_unappliable`)."""
    init = scenario.initial
    events: list[Event] = []
    for name, opening in init.valves.items():
        events.append(ValveEvent(at_s=0, kind="valve", valve=name, opening=opening))
    for name, opening in init.leaks.items():
        events.append(LeakEvent(at_s=0, kind="leak", tank=name, opening=opening))
    for name, sp in init.setpoints_m.items():
        events.append(SetpointEvent(at_s=0, kind="setpoint", loop=name, value_m=sp))
    for name, m in init.modes.items():
        events.append(LoopModeEvent(at_s=0, kind="loop_mode", loop=name, mode=m))
    return events


def scenario_run(
    file: Annotated[Path, typer.Argument(help="Scenario YAML file.")],
    speed_from_plant: Annotated[
        bool,
        typer.Option(
            "--speed-from-plant",
            help="Sleep between time polls for the model time left / Plant.Sim.Speed (max 1 s) "
            "instead of polling every 50 ms.",
        ),
    ] = False,
    until_end: Annotated[
        bool, typer.Option("--until-end", help="After the last event, wait until the scenario's duration_s.")
    ] = False,
    ignore_unappliable: Annotated[
        bool,
        typer.Option(
            "--ignore-unappliable",
            help="Run the events even though some of the scenario's fields cannot be applied to a "
            "running stack (initial levels, variant settings, another config of the site); each is "
            "printed as 'not applied:'.",
        ),
    ] = False,
    config: ConfigOpt = None,
    host: HostOpt = None,
    base_port: BasePortOpt = None,
    plant_url: PlantUrlOpt = None,
    plc_url: PlcUrlOpt = None,
    supervisor_url: SupervisorUrlOpt = None,
    timeout: TimeoutOpt = DEFAULT_TIMEOUT_S,
) -> None:
    """Apply a scenario's initial settings and timed events to the running stack.

    Times are the plant's model time (Plant.Sim.Time) since the command started. The stack must
    run the scenario's site (its name; another config of it is a field not applied). Fields a
    running stack cannot take are refused in one line unless --ignore-unappliable.
    """
    try:
        scenario, site_path = load_scenario(file)
        scenario_site = load_site(site_path)
    except TanklabError as e:
        raise _fail(str(e), 2) from None
    stack = _stack_or_exit(
        config, host, base_port, plant_url, plc_url, supervisor_url, timeout, endpoints_of=scenario_site
    )

    async def main() -> int:
        needed = [t for t in TIERS if t in _event_tiers(scenario)]
        await stack.resolve(*needed)
        for tier in needed:
            stack.require(tier)
        clients = {t: stack.client(t) for t in needed}
        try:
            for c in clients.values():  # every tier the scenario writes must answer (and match) first
                await c.connect()
            skipped = _check_scenario(scenario, SiteIdentity.of(scenario_site), stack)
            if skipped and not ignore_unappliable:
                raise UsageError(
                    f"scenario {scenario.name}: {len(skipped)} field{'s' if len(skipped) > 1 else ''} cannot "
                    f"be applied to a running stack: {'; '.join(skipped)}; --ignore-unappliable runs its "
                    "events without them"
                )
            return await _play(
                scenario, clients, skipped, speed_from_plant=speed_from_plant, until_end=until_end
            )
        finally:
            for c in clients.values():
                await c.close()

    _run(main)


def _check_scenario(scenario: Scenario, written_for: SiteIdentity, stack: Stack) -> list[str]:
    """Refuse a scenario for another site; return the fields the running stack cannot take.

    The scenario's site file must name the stack's site (else :class:`SiteMismatchError`); a
    different config of that site (another digest) is listed first among the fields not
    applied, since the scenario's author meant other parameters than the stack runs.
    """
    runs = stack.site_identity
    if written_for.name != runs.name:
        raise SiteMismatchError(
            f"scenario {scenario.name} is written for {written_for} (site: {scenario.site}), but the "
            f"stack runs {runs} ({stack.origin})"
        )
    check_against_site(scenario, stack.site)
    skipped = live_unappliable(scenario)
    if written_for.digest != runs.digest:
        skipped.insert(
            0, f"site (its {scenario.site} is config {written_for.short}, the stack runs {runs.short})"
        )
    return skipped


async def _play(
    scenario: Scenario,
    clients: Mapping[Tier, TierClient],
    skipped: Sequence[str],
    *,
    speed_from_plant: bool,
    until_end: bool,
) -> int:
    plant = clients["plant"]

    async def now() -> float:
        t = (await plant.read(["Plant.Sim.Time"]))["Plant.Sim.Time"]
        if not isinstance(t, float):
            raise UnreachableError("plant", plant.url, "Plant.Sim.Time did not read Good")
        return t

    t0 = await now()
    initial = _initial_events(scenario)
    events = scenario.sorted_events()
    typer.echo(
        f"scenario {scenario.name}: {len(events)} events over {scenario.duration_s:g} s of model time, "
        f"starting at plant time {t0:.1f} s"
    )
    for field_ in skipped:
        typer.echo(f"not applied: {field_}")
    applied = 0

    def say(t: float, label: str, lines: list[str]) -> None:
        typer.echo(f"t={t:8.1f} s  {label}: " + "; ".join(lines))

    with _StopOnSignal() as stop:

        async def wait_for_model_time(at_s: float) -> float:
            while True:
                t = await now() - t0
                if t >= at_s:
                    return t
                if stop.is_set():
                    raise StoppedError(
                        f"scenario {scenario.name} interrupted at t={t:.1f} s "
                        f"({applied} of {len(events)} events applied)"
                    )
                wait = DEFAULT_POLL_S
                if speed_from_plant:
                    speed = (await plant.read(["Plant.Sim.Speed"]))["Plant.Sim.Speed"]
                    if isinstance(speed, float) and speed > 0:  # 0 in lock-step: keep polling
                        wait = min(max((at_s - t) / speed, DEFAULT_POLL_S), 1.0)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), wait)

        for ev in initial:
            say(await now() - t0, f"initial {_describe_event(ev)}", await _apply_event(clients, ev))
        for ev in events:
            if until_end and ev.at_s > scenario.duration_s:
                break
            t = await wait_for_model_time(ev.at_s)
            say(t, f"@{ev.at_s:g} s {_describe_event(ev)}", await _apply_event(clients, ev))
            applied += 1
        if until_end:
            t = await wait_for_model_time(scenario.duration_s)
            typer.echo(f"t={t:8.1f} s  end of scenario (duration {scenario.duration_s:g} s)")
    typer.echo(f"done: {applied} of {len(events)} events applied")
    return 0


# --------------------------------------------------------------------------------------------
# Mounting
# --------------------------------------------------------------------------------------------

scenario_app = typer.Typer(
    help="Scenarios against a running stack.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


def add_scenario_commands(group: typer.Typer) -> None:
    """Add ``run`` to a ``scenario`` command group (this module's or an existing one)."""
    group.command("run", cls=OneLineUsage)(scenario_run)


add_scenario_commands(scenario_app)


def register(app: typer.Typer) -> None:
    """Add the operator commands and the ``scenario`` group to the main ``tankctl`` app."""
    for name, func in (
        ("status", status),
        ("setpoint", setpoint),
        ("leak", leak),
        ("valve", valve),
        ("loop", loop_command),
        ("mode", mode),
        ("gains", gains),
        ("browse", browse),
        ("watch", watch),
    ):
        app.command(name, cls=OneLineUsage)(func)
    app.add_typer(scenario_app, name="scenario")
