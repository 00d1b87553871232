"""Logins of a security home, authenticated sessions, and a probe that survives its tier's restarts.

:class:`Logins` is a home and its users' passwords: the tests use the session's home
(``conftest.security_home``), the benchmarks one provisioned for the run (:func:`provision`).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Client, ua

from tanklab.tags import Role
from tanklab_io.home import SecurityHome
from tanklab_io.home import provision as provision_home
from tanklab_io.ua_client import namespace_index, new_client
from tanklab_io.ua_client import quiet_disconnect as ua_quiet_disconnect
from tanklab_io.ua_security import ClientIdentity, secure_client
from tanklab_io.users import Credentials, load_credentials


@dataclass(frozen=True)
class Logins:
    """A security home and the passwords of its login users (user name -> credentials)."""

    home: SecurityHome
    credentials: dict[str, Credentials]

    def identity(self, who: str) -> ClientIdentity:
        """A login user's identity, or a tier's (``plc``, ``supervisor``) certificate identity."""
        if who in ("plc", "supervisor"):
            return ClientIdentity(self.home, who)
        return ClientIdentity(self.home, "cli", self.credentials[who])


ROLE_OF = {"engineer": Role.ENGINEER, "operator": Role.OPERATOR, "supervisor": Role.SUPERVISOR}
"""The role a fuzz session acts in on the PLC."""


def provision(root: Path) -> Logins:
    """A fresh security home at ``root``: the PKI and one engineer with a random password
    (what ``tankctl up`` provisions on first run)."""
    home = SecurityHome(root)
    provision_home(home)
    creds = load_credentials(home.credentials_file, {})
    assert creds is not None, f"{home.credentials_file}: not written by provision"
    return Logins(home, {creds.username: creds})


@contextlib.asynccontextmanager
async def session(url: str, logins: Logins, who: str, timeout_s: float = 10.0) -> AsyncIterator[Client]:
    """A connected, encrypted and authenticated client of ``url`` acting as ``who``."""
    client = new_client(url, timeout_s)
    await secure_client(client, logins.identity(who))
    async with client:
        yield client


class Probe:
    """A session on one tier that reconnects on demand: :meth:`read` answers the values of
    ``paths`` (one Read), or None (dropping the session) while the tier is away or frozen.

    One login per connection, not per read: a password login costs the server one scrypt.
    """

    def __init__(self, url: str, paths: Sequence[str], logins: Logins, who: str = "engineer") -> None:
        self.url = url
        self.paths = list(paths)
        self.logins = logins
        self.who = who
        self.client: Client | None = None
        self.nodes: list[Any] = []

    async def read(self) -> dict[str, Any] | None:
        if self.client is None:
            client = new_client(self.url, 2.0)
            try:
                await asyncio.wait_for(secure_client(client, self.logins.identity(self.who)), 4.0)
                await asyncio.wait_for(client.connect(), 4.0)
                idx = await namespace_index(client)
            except Exception:
                await quiet_disconnect(client)
                return None
            self.client = client
            self.nodes = [client.get_node(ua.NodeId(p, idx)) for p in self.paths]
        try:
            values = await asyncio.wait_for(self.client.read_values(self.nodes), 2.0)
        except Exception:
            await self.close()
            return None
        return dict(zip(self.paths, values, strict=True))

    async def value(self, path: str) -> Any:
        """One value, or None while the tier is away."""
        got = await self.read()
        return None if got is None else got[path]

    async def close(self) -> None:
        client, self.client = self.client, None
        if client is not None:
            await quiet_disconnect(client)


async def quiet_disconnect(client: Client) -> None:
    """:func:`tanklab_io.ua_client.quiet_disconnect` with the probes' 2 s bound (the tier may be gone)."""
    await ua_quiet_disconnect(client, 2.0)
