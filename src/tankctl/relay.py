"""``tankctl up``'s command relay: operator commands' OPC UA sessions, kept open (decision 0048).

A Unix socket (``<run dir>/relay/relay.sock``: the directory 0700, the socket 0600) that answers
the requests of :mod:`tankctl.relay_client` (its docstring has the protocol). For each (user,
tier) the relay holds one OPC UA session of the CLI's certificate, logged in with that user's
own name and password as the request carried them: the tier checks the password, enforces the
role and audits the real user's name; the relay checks nothing of the login itself. A refused
login is answered and forgotten (no session is kept); a request with another password for a
user closes that user's session first, so a password is never checked against a session opened
with another one. A session whose tier went away (a restart) is opened again on the next
request, once, and the reason is logged. Only a peer of the relay's own uid (``SO_PEERCRED``)
is served.

Per command this saves the imports of asyncua and cryptography and the secure channel's
handshake (RSA, and scrypt on the server): see decision 0048 for the measurements.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import os
import socket
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import ua

from tankctl.ops.errors import describe_failure
from tankctl.relay_client import MAX_LINE_BYTES, PROTOCOL, pointer, unix_address
from tanklab.errors import LinkError
from tanklab.tags import DataType
from tanklab_io.home import SecurityHome
from tanklab_io.ua_client import ConnectError, Link, refused_login
from tanklab_io.ua_client_security import ClientIdentity, client_setup
from tanklab_io.ua_values import python_value, stored_variant
from tanklab_io.users import Credentials

__all__ = ["SOCKET_NAME", "Relay"]

SOCKET_NAME = "relay.sock"
TIMEOUT_S = 3.0
"""Bound of connecting a session and of every request to a tier [s]."""


@dataclass
class _Session:
    link: Link
    password: str | None


class _RefusedError(Exception):
    def __init__(self, answer: dict[str, Any]) -> None:
        super().__init__(answer)
        self.answer = answer


class Relay:
    """The relay of one stack: ``urls`` by tier, the CLI certificate of ``home``."""

    def __init__(
        self, urls: Mapping[str, str], home: SecurityHome, run_dir: Path, say: Callable[[str], None]
    ) -> None:
        self.urls = dict(urls)
        self.home = home
        self.dir = run_dir.absolute() / "relay"  # the links name it from another directory
        self.path = self.dir / SOCKET_NAME
        self.say = say
        self.sessions: dict[tuple[str | None, str], _Session] = {}
        self.pointers: list[Path] = []
        self._server: asyncio.Server | None = None
        self._lock = asyncio.Lock()

    # ---- lifecycle ------------------------------------------------------------------------

    async def start(self) -> None:
        """Serve the socket (0600 in a 0700 directory) and point each tier's endpoint at it."""
        self.dir.mkdir(mode=0o700, parents=True, exist_ok=True)
        os.chmod(self.dir, 0o700)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()  # a stale socket of a killed up (the pid-file preflight passed)
        old = os.umask(0o177)  # the socket is born 0600: no moment of a wider mode
        try:
            with unix_address(self.path) as address:  # a deep run directory too
                self._server = await asyncio.start_unix_server(self._serve, address, limit=MAX_LINE_BYTES)
        finally:
            os.umask(old)
        os.chmod(self.path, 0o600)
        for url in self.urls.values():
            link = pointer(url)
            if link is None:
                continue
            _private_dir(link.parent)
            tmp = link.with_name(f".{link.name}.{os.getpid()}")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.path)
            tmp.replace(link)
            self.pointers.append(link)

    async def stop(self) -> None:
        """Stop serving, close every session, remove the socket and the links (idempotent)."""
        if self._server is not None:
            self._server.close()
            self._server = None
        for link in self.pointers:
            with contextlib.suppress(OSError):
                if os.readlink(link) == str(self.path):  # not another stack's, started since
                    link.unlink()
        self.pointers = []
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        sessions, self.sessions = list(self.sessions.values()), {}
        for s in sessions:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(s.link.close(), 2.0)

    # ---- serving --------------------------------------------------------------------------

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            uid = _peer_uid(writer)
            if uid != os.getuid():
                self.say(f"relay: refused a connection of uid {uid} (only uid {os.getuid()} is served)")
                return  # not the owner: no answer at all
            line = await reader.readline()
            try:
                answer = await self.answer(json.loads(line))
            except (ValueError, KeyError, TypeError) as e:
                answer = {"ok": False, "error": "request", "reason": f"bad request: {e}"}
            writer.write(json.dumps({"v": PROTOCOL, **answer}).encode() + b"\n")
            await writer.drain()
        except Exception as e:  # one client's broken pipe never stops the relay
            self.say(f"relay: request failed: {type(e).__name__}: {e}")
        finally:
            with contextlib.suppress(Exception):
                writer.close()

    async def answer(self, req: dict[str, Any]) -> dict[str, Any]:
        """The answer to one request (protocol in :mod:`tankctl.relay_client`)."""
        if req.get("v") != PROTOCOL:
            return {"ok": False, "error": "request", "reason": f"protocol {req.get('v')!r}, not {PROTOCOL}"}
        tier, url = str(req["tier"]), str(req["url"])
        if self.urls.get(tier) != url:
            return {"ok": False, "error": "request", "reason": f"this relay does not serve {tier} at {url}"}
        user, password = req.get("user"), req.get("password")
        op = req["op"]
        if op not in ("read", "write"):
            return {"ok": False, "error": "request", "reason": f"unknown operation {op!r}"}
        async with self._lock:  # one request at a time per relay: sessions are opened once
            try:
                return await self._do(tier, user, password, req)
            except _RefusedError as r:
                return r.answer

    async def _do(
        self, tier: str, user: str | None, password: str | None, req: dict[str, Any]
    ) -> dict[str, Any]:
        for attempt in (1, 2):
            session = await self._session(tier, user, password)
            try:
                if req["op"] == "read":
                    paths = [str(p) for p in req["paths"]]
                    dvs = await session.link.read(paths) if paths else []
                    return {"ok": True, "values": {p: _value(dv) for p, dv in zip(paths, dvs, strict=True)}}
                data_type = DataType(req["type"])
                v = stored_variant(data_type, python_value(data_type, req["value"]))
                (status,) = await session.link.write_variants({str(req["path"]): v})
                return {"ok": True, "status": str(status.name)}
            except LinkError as e:
                # The tier went away under the session (a restart): open it again, once.
                self.sessions.pop((user, tier), None)
                reason = describe_failure(e.__cause__ or e, TIMEOUT_S)
                self.say(f"relay: {tier} session of {user!r} lost ({reason}); reconnecting")
                if attempt == 2:
                    return {"ok": False, "error": "unreachable", "reason": reason}
        raise AssertionError("unreachable")

    async def _session(self, tier: str, user: str | None, password: str | None) -> _Session:
        key = (user, tier)
        s = self.sessions.get(key)
        if s is not None and not _same(s.password, password):
            del self.sessions[key]  # another password: the tier checks it on a session of its own
            await s.link.close()
            s = None
        if s is not None and s.link.healthy:
            return s
        creds = Credentials(user, password) if user and password else None
        link = Link(
            self.urls[tier],
            {},
            name=f"relay {tier} {user or 'anonymous'}",
            setup=client_setup(ClientIdentity(self.home, "cli", creds)),
            timeout_s=TIMEOUT_S,
            client_name="tankctl",
        )
        try:
            await link.connect()
        except ConnectError as e:
            self.sessions.pop(key, None)  # a refused login is never cached
            status = refused_login(e)
            if status is not None:
                raise _RefusedError({"ok": False, "error": "login", "status": status}) from None
            raise _RefusedError({"ok": False, "error": "unreachable", "reason": _connect_reason(e)}) from None
        if s is not None:
            self.say(f"relay: {tier} session of {user!r} open again")
        s = self.sessions[key] = _Session(link, password)
        return s


def _connect_reason(e: ConnectError) -> str:
    if e.stage == "namespace" and isinstance(e.cause, ValueError):
        return "no urn:tanklab namespace"
    return describe_failure(e.cause, TIMEOUT_S)


def _value(dv: ua.DataValue) -> Any:
    bad = dv.StatusCode is not None and dv.StatusCode.is_bad()
    return None if bad or dv.Value is None else dv.Value.Value


def _same(a: str | None, b: str | None) -> bool:
    return hmac.compare_digest((a or "").encode(), (b or "").encode()) and (a is None) == (b is None)


def _peer_uid(writer: asyncio.StreamWriter) -> int:
    """The connecting process's uid (``SO_PEERCRED``: pid, uid, gid as three ints)."""
    sock = writer.get_extra_info("socket")
    creds = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    _pid, uid, _gid = struct.unpack("3i", creds)
    return int(uid)


def _private_dir(path: Path) -> None:
    """Make ``path`` 0700, refusing one owned by another user (a planted link directory)."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = path.lstat()
    if st.st_uid != os.getuid() or not path.is_dir() or path.is_symlink():
        raise PermissionError(f"{path}: not a directory of uid {os.getuid()}")
    os.chmod(path, 0o700)
