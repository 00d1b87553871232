"""Logins of a security home, authenticated sessions, and a probe that survives its tier's restarts.

:class:`Logins`, :func:`provision` and :func:`session` are :mod:`tankctl.testing.logins`'s
(shipped with the pytest plugin, decision 0056); what is here is test support only: the role a
fuzz session acts in, and :class:`Probe`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from typing import Any

from asyncua import Client, ua

from tankctl.testing.logins import Logins, provision, provision_users, quiet_disconnect, session
from tanklab.tags import Role
from tanklab_io.ua_client import namespace_index, new_client
from tanklab_io.ua_security import secure_client

__all__ = ["ROLE_OF", "Logins", "Probe", "provision", "provision_users", "quiet_disconnect", "session"]

ROLE_OF = {"engineer": Role.ENGINEER, "operator": Role.OPERATOR, "supervisor": Role.SUPERVISOR}
"""The role a fuzz session acts in on the PLC."""


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
