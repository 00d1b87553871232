"""An operator command's client of one tier through ``tankctl up``'s command relay (decision 0048).

The same reads, writes, identity check and one-line failures as
:class:`tankctl.ops.client.TierClient`, without importing asyncua: the relay
(:mod:`tankctl.relay`) holds the OPC UA session of the command's user. When the relay does not
answer (a stale link, an ``up`` being stopped, another stack), this client becomes a direct
``TierClient`` for the rest of the command.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tankctl.ops.display import show
from tankctl.ops.errors import LoginRefusedError, RefusedError, UnreachableError
from tankctl.relay_client import RelayUnavailableError, ask
from tanklab.errors import TanklabError
from tanklab.tags import Tag, Tier

if TYPE_CHECKING:
    from tankctl.ops.client import TierClient
    from tankctl.ops.stack import Stack


class RelayedClient:
    """The relay's client of ``tier`` at ``url`` for ``stack``'s user; the relay's socket is
    the target of the link ``socket``."""

    def __init__(self, tier: Tier, url: str, stack: Stack, socket: Path) -> None:
        self.tier = tier
        self.url = url
        self.stack = stack
        self.socket = socket
        self.timeout_s = stack.timeout_s
        self.direct: TierClient | None = None
        """The direct client this one became when the relay did not answer."""
        self._connected = False
        self._wanted: list[str] = []
        self._first: dict[str, Any] = {}

    @property
    def tags(self) -> dict[str, Tag]:
        """The contract's tags of this tier for the stack's site, by path."""
        return self.stack.tags(self.tier)

    def will_read(self, paths: Sequence[str]) -> RelayedClient:
        """As :meth:`TierClient.will_read`: ``paths`` come with the identity's Read."""
        self._wanted = list(paths)
        return self

    async def connect(self) -> RelayedClient:
        """Read the tier's site identity (and the :meth:`will_read` paths) through the relay
        and check it with :meth:`Stack.accept`; a direct connection if the relay does not answer."""
        if self._connected:
            return self
        if self.direct is not None:
            await self.direct.connect()
            return self
        paths, reads = self.stack.first_read(self.tier, self._wanted)
        try:
            values = await self._ask({"op": "read", "paths": reads})
        except RelayUnavailableError:
            self.direct = self.stack.direct_client(self.tier).will_read(self._wanted)
            await self.direct.connect()
            return self
        self.stack.accept(self.tier, self.url, {item: values["values"][p] for item, p in paths.items()})
        self._connected = True
        self._first = {p: values["values"][p] for p in self._wanted}
        return self

    async def close(self) -> None:
        """Nothing to close here (the relay keeps the session); a direct client disconnects."""
        self._first = {}
        self._connected = False
        if self.direct is not None:
            await self.direct.close()

    async def __aenter__(self) -> RelayedClient:
        return await self.connect()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def read(self, paths: Sequence[str]) -> dict[str, Any]:
        """Values of ``paths`` in one Read; a node answering a Bad status reads as None."""
        if self.direct is not None:
            return await self.direct.read(paths)
        if self._first and list(paths) == list(self._first):
            first, self._first = self._first, {}
            return first
        if not paths:
            return {}
        answer = await self._ask({"op": "read", "paths": list(paths)})
        values: dict[str, Any] = answer["values"]
        return {p: values[p] for p in paths}

    async def write(self, path: str, value: Any) -> None:
        """Write one value with the tag's exact type; a Bad status raises :class:`RefusedError`."""
        if self.direct is not None:
            return await self.direct.write(path, value)
        tag = self.tags[path]
        if tag.data_type is None:
            raise TanklabError(f"{path} is a method, not a variable")
        answer = await self._ask({"op": "write", "path": path, "value": value, "type": tag.data_type.value})
        if answer["status"] != "Good":
            raise RefusedError(path, show(tag, value), str(answer["status"]))
        return None

    async def _ask(self, request: dict[str, Any]) -> dict[str, Any]:
        """One request for this tier as the stack's user; the relay's refusals as the direct
        path words them. RelayUnavailableError when the relay cannot serve it at all."""
        login = self.stack.login
        try:
            answer = await ask(
                self.socket,
                {
                    "user": login.username if login else None,
                    "password": login.password if login else None,
                    "tier": self.tier,
                    "url": self.url,
                    **request,
                },
                self.timeout_s + 1.0,  # the relay bounds its own requests to the tier
            )
        except RelayUnavailableError as e:
            if not self._connected:
                raise
            # Gone between two requests of one command (``up`` stopping): say so, as a lost tier.
            raise UnreachableError(
                self.tier, self.url, f"the command relay stopped answering ({e})"
            ) from None
        if answer.get("ok"):
            return answer
        error = answer.get("error")
        if error == "login":
            user = login.username if login else None
            raise LoginRefusedError(user, self.tier, self.url, str(answer.get("status")))
        if error == "unreachable":
            raise UnreachableError(self.tier, self.url, str(answer.get("reason")))
        raise RelayUnavailableError(str(answer.get("reason")))
