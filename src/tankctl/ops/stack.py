"""The stack an operator command talks to: the tiers' endpoints (flags, environment, base
port, the site's endpoints) and the site, given or read from the first tier that answers.

A :class:`Stack` holds one :class:`~tankctl.ops.client.TierClient` per tier and checks each
tier's published site identity against the site (decision 0020).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tankctl.ops.errors import SiteMismatchError, UnreachableError, UsageError
from tanklab.config import ENV_ENDPOINT_VARS, Endpoints, SiteConfig, load_site, parse_endpoint_url
from tanklab.identity import SiteIdentity, site_from_json
from tanklab.tags import (
    TIER_ROOTS,
    Tag,
    Tier,
    historian_tags,
    identity_paths,
    plant_tags,
    plc_tags,
    supervisor_tags,
    tags_by_path,
)
from tanklab_io.users import Credentials, cli_login, default_home

if TYPE_CHECKING:
    from tankctl.ops.client import TierClient
    from tankctl.ops.relayed import RelayedClient
    from tanklab_io.ua_client_security import ClientIdentity

TIERS: tuple[Tier, ...] = ("plant", "plc", "supervisor")
"""The control tiers in port order: ``--base-port N`` puts them at N, N+1, N+2."""
ENDPOINT_TIERS: tuple[Tier, ...] = (*TIERS, "historian")
"""Every tier with an endpoint, in port order: the historian at N+3 (``tankctl history``)."""
HISTORIAN_ENDPOINT_VAR = "TANKLAB_HISTORIAN_ENDPOINT"
"""The historian's OPC UA endpoint in the environment (``TANKLAB_HISTORIAN_URL`` is its store)."""

DEFAULT_TIMEOUT_S = 3.0
"""Wall-time bound of connecting and of every request [s]."""


_URL_FLAGS = {
    "plant": "--plant-url",
    "plc": "--plc-url",
    "supervisor": "--supervisor-url",
    "historian": "--historian-url",
}
_ENV_VARS: dict[Tier, str] = {**ENV_ENDPOINT_VARS, "historian": HISTORIAN_ENDPOINT_VAR}  # type: ignore[dict-item]


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

    For each tier: its URL flag (``urls[tier]``), else ``TANKLAB_<TIER>_URL`` in ``env`` (the
    historian's: ``TANKLAB_HISTORIAN_ENDPOINT``), else ``base_port`` (or ``TANKLAB_BASE_PORT``)
    + 0, 1, 2, 3 for plant, plc, supervisor, historian on ``host`` (default 127.0.0.1), else the
    site's endpoint (``None``: the default endpoints, 4840..4843 on 127.0.0.1) with ``host``
    replacing its host when given. Empty strings count as unset.

    Raises
    ------
    UsageError
        A URL that is not ``opc.tcp://HOST:PORT[/path]``, or a base port outside 1..65532.
    """
    base = base_port
    source = "--base-port"
    if base is None and env.get("TANKLAB_BASE_PORT"):
        source = "TANKLAB_BASE_PORT"
        base = _parse_base_port(env["TANKLAB_BASE_PORT"], source)
    if base is not None and not 1 <= base <= 65532:
        raise UsageError(f"{source} must be 1..65532 (four consecutive ports), got {base}")
    out: dict[Tier, str] = {}
    for k, tier in enumerate(ENDPOINT_TIERS):
        flag, var = urls.get(tier), _ENV_VARS[tier]
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
    login: Credentials | None = None
    """The CLI's login (user and password) as the relay path sends it (:meth:`use_relay`)."""
    relay: bool = False
    """Whether :meth:`client` tries ``tankctl up``'s command relay first (:meth:`use_relay`)."""
    _clients: dict[Tier, TierClient | RelayedClient] = field(default_factory=dict, repr=False)
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
                await self.io(tier).connect()
                return
            except UnreachableError as e:
                self.unreached[tier] = e
        raise self.unreached[order[0]]

    def first_read(self, tier: Tier, wanted: list[str]) -> tuple[dict[str, str], list[str]]:
        """What a command's first Read of ``tier`` asks: the identity items :meth:`accept` checks
        (item -> path; the Config text only while the site is not yet known) and every path to
        read, the identity's first, then ``wanted``'s not among them."""
        paths = identity_paths(tier)
        if self.resolved:
            del paths["Config"]
        identity = list(paths.values())
        return paths, identity + [p for p in wanted if p not in identity]

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
            build = {
                "plant": plant_tags,
                "plc": plc_tags,
                "supervisor": supervisor_tags,
                "historian": historian_tags,
            }[tier]
            self._tags[tier] = tags_by_path(build(self.site))
        return self._tags[tier]

    def use_relay(self) -> None:
        """Let :meth:`client` go through ``tankctl up``'s command relay where one serves the
        tier's endpoint (decision 0048), for a command that only reads and writes values."""
        self.relay = True

    def io(self, tier: Tier) -> TierClient | RelayedClient:
        """The reading and writing client of ``tier`` (one per tier; connected by its
        ``connect``): the relay's when :meth:`use_relay` was called and a relay link exists for
        its endpoint (it falls back to a direct :class:`TierClient` when the relay does not
        answer), else the direct one."""
        if tier not in self._clients:
            self._clients[tier] = self._new_client(tier)
        return self._clients[tier]

    def client(self, tier: Tier) -> TierClient:
        """The direct OPC UA client of ``tier`` (browse, calls, history: more than values);
        the one :meth:`io` gives when :meth:`use_relay` was not called."""
        from tankctl.ops.client import TierClient

        client = self.io(tier)
        if not isinstance(client, TierClient):
            raise RuntimeError(f"the {tier} client is the relay's: use Stack.io() for it")
        return client

    def _new_client(self, tier: Tier) -> TierClient | RelayedClient:
        if self.relay:
            from tankctl.relay_client import pointer

            link = pointer(self.urls[tier])
            if link is not None and link.is_symlink():
                from tankctl.ops.relayed import RelayedClient

                return RelayedClient(tier, self.urls[tier], self, link)
        return self.direct_client(tier)

    def direct_client(self, tier: Tier) -> TierClient:
        """A new OPC UA client of ``tier`` (asyncua imported here, on first use)."""
        from tankctl.ops.client import TierClient

        return TierClient(tier, self.urls[tier], self)

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

    def pump(self, name: str) -> str:
        """A pump name of the site (P1, ...), else UsageError."""
        return self._known(name, self.site.pump_names, "pump")

    def _known(self, name: str, known: list[str], what: str) -> str:
        if name.upper() in known:
            return name.upper()
        have = ", ".join(known) if known else "none"
        raise UsageError(f"unknown {what} {name!r} (the site {self.site.name} has {have})")


def env(name: str) -> str | None:
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
    historian_url: str | None = None,
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
    elif e := env("TANKLAB_CONFIG"):
        given, source = load_site(e), f"TANKLAB_CONFIG={e}"
    urls = resolve_endpoints(
        given or endpoints_of,
        urls={"plant": plant_url, "plc": plc_url, "supervisor": supervisor_url, "historian": historian_url},
        env=os.environ,
        base_port=base_port,
        host=host,
    )
    # The login is checked here (half a login in the environment, a too-open credentials
    # file); the certificate is loaded by a direct client only (the relay path needs none).
    login = cli_login(default_home() / "credentials")
    return Stack(given, urls, timeout, None, source, login=login)
