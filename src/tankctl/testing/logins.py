"""Logins of a security home and authenticated sessions: who the clients of a test stack are.

:class:`Logins` is a home and its users' passwords: the repository's tests use the session's
home (``conftest.security_home``), the benchmarks one provisioned for the run (:func:`provision`),
the pytest plugin's ``tanklab_stack`` a throw-away one with one user per login role
(:func:`provision_users`). Shipped, so that the plugin works from a wheel (decision 0056).
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

from asyncua import Client

from tanklab.tags import Role
from tanklab_io.home import SecurityHome
from tanklab_io.home import provision as provision_home
from tanklab_io.ua_client import new_client
from tanklab_io.ua_client import quiet_disconnect as ua_quiet_disconnect
from tanklab_io.ua_security import ClientIdentity, secure_client
from tanklab_io.users import Credentials, UsersFile, generate_password, load_credentials


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


def provision(root: Path) -> Logins:
    """A fresh security home at ``root``: the PKI and one engineer with a random password
    (what ``tankctl up`` provisions on first run)."""
    home = SecurityHome(root)
    provision_home(home)
    creds = load_credentials(home.credentials_file, {})
    assert creds is not None, f"{home.credentials_file}: not written by provision"
    return Logins(home, {creds.username: creds})


LOGIN_ROLES = {"observer": Role.OBSERVER, "operator": Role.OPERATOR, "engineer": Role.ENGINEER}
"""The login users of a throw-away home, by name: one per role a person logs in with."""


def provision_users(root: Path) -> Logins:
    """A throw-away security home at ``root``: a fresh PKI (the tiers' and the CLI's
    certificates) and one user per login role (:data:`LOGIN_ROLES`), each with a random
    password; the CLI's credentials file logs in as ``engineer``."""
    home = SecurityHome(root)
    provision_home(home)  # the PKI, and ``engineer`` with a random password
    engineer = load_credentials(home.credentials_file, {})
    assert engineer is not None, f"{home.credentials_file}: not written by provision"
    creds = {engineer.username: engineer}
    users = UsersFile.load(home.users_file)
    for name, role in LOGIN_ROLES.items():
        if name not in creds:
            creds[name] = Credentials(name, generate_password())
            users.add(name, role, creds[name].password)
    users.save()
    return Logins(home, creds)


@contextlib.asynccontextmanager
async def session(url: str, logins: Logins, who: str, timeout_s: float = 10.0) -> AsyncIterator[Client]:
    """A connected, encrypted and authenticated client of ``url`` acting as ``who``."""
    client = new_client(url, timeout_s)
    await secure_client(client, logins.identity(who))
    async with client:
        yield client


async def quiet_disconnect(client: Client) -> None:
    """:func:`tanklab_io.ua_client.quiet_disconnect` with the probes' 2 s bound (the tier may be gone)."""
    await ua_quiet_disconnect(client, 2.0)
