"""The client side of ``tankctl up``'s command relay: find its socket, ask it one thing.

Standard library only (no asyncua, no cryptography): an operator command that finds a relay
pays neither their imports nor a secure-channel handshake (decision 0048).

**Where.** ``tankctl up`` serves the relay on ``<run dir>/relay/relay.sock`` (the directory 0700,
the socket 0600) and points to it from one symbolic link per tier endpoint in the owner's
runtime directory (:func:`pointer_dir`): ``relay-<host>-<port>`` for each tier's
``opc.tcp://host:port``. A command looks up the link of the endpoint it would connect to.

**Protocol** (version :data:`PROTOCOL`): one JSON object per line each way, UTF-8. A request is
``{"v": 1, "user": NAME|null, "password": SECRET|null, "tier": TIER, "url": URL, "op": "read",
"paths": [...]}`` or ``..."op": "write", "path": P, "value": V, "type": DATATYPE}``. The answer
is ``{"v": 1, "ok": true, "values": {path: value|null}}`` (null: a Bad status), ``{"v": 1,
"ok": true, "status": NAME}`` for a write, or ``{"v": 1, "ok": false, "error": KIND, ...}`` with
KIND ``login`` (``status``), ``unreachable`` (``reason``) or ``request`` (``reason``: the relay
cannot serve this request, e.g. another stack's URL; the command then connects directly).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

__all__ = ["PROTOCOL", "RelayUnavailableError", "ask", "pointer", "pointer_dir", "unix_address"]

PROTOCOL = 1
"""The relay protocol's version; a relay answering another version is not used."""
MAX_LINE_BYTES = 4 * 1024 * 1024
"""Longest request or answer line the relay and the client accept [bytes]."""


SUN_PATH_BYTES = 107
"""Longest socket path ``AF_UNIX`` takes (``sun_path`` is 108 bytes on Linux, NUL included)."""


@contextlib.contextmanager
def unix_address(path: Path) -> Iterator[str]:
    """An address for binding or connecting to the socket ``path``, however deep it lies.

    ``path`` itself when it fits ``sun_path``; else ``/proc/self/fd/N/<name>``, N a descriptor
    of its directory held open meanwhile (Linux resolves it to the same directory), so a run
    directory under a long temp path still gets its relay. Symbolic links are followed either way.
    """
    if len(os.fsencode(str(path))) <= SUN_PATH_BYTES:
        yield str(path)
        return
    fd = os.open(path.parent, os.O_PATH | os.O_DIRECTORY)
    try:
        yield f"/proc/self/fd/{fd}/{path.name}"
    finally:
        os.close(fd)


class RelayUnavailableError(Exception):
    """No relay answered (none, a stale socket, another protocol version, a timeout): the
    command takes the direct path."""


def pointer_dir(environ: Mapping[str, str] | None = None) -> Path:
    """The owner's directory of relay links: ``$XDG_RUNTIME_DIR/tanklab``, else
    ``<tmp>/tanklab-<uid>`` (made 0700 by the relay, which refuses one it does not own)."""
    env = os.environ if environ is None else environ
    runtime = env.get("XDG_RUNTIME_DIR")
    if runtime and Path(runtime).is_absolute():
        return Path(runtime) / "tanklab"
    return Path(tempfile.gettempdir()) / f"tanklab-{os.getuid()}"


def pointer(url: str, environ: Mapping[str, str] | None = None) -> Path | None:
    """The relay link for the tier endpoint ``url`` (None for a URL without host and port)."""
    try:
        parts = urlsplit(url.strip())
        host, port = parts.hostname, parts.port
    except ValueError:
        return None
    if not host or port is None:
        return None
    return pointer_dir(environ) / f"relay-{host}-{port}"


async def ask(socket_path: Path, request: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    """Send ``request`` (the version added) to the relay at ``socket_path``; its answer.

    Raises
    ------
    RelayUnavailableError
        Nothing listens there, it did not answer within ``timeout_s`` [s], or the answer is not
        a version-:data:`PROTOCOL` JSON object.
    """
    line = json.dumps({"v": PROTOCOL, **request}).encode() + b"\n"
    try:
        async with asyncio.timeout(timeout_s):
            with unix_address(socket_path) as address:
                reader, writer = await asyncio.open_unix_connection(address, limit=MAX_LINE_BYTES)
            try:
                writer.write(line)
                await writer.drain()
                answer = await reader.readline()
            finally:
                writer.close()
    except (OSError, TimeoutError, ValueError, asyncio.IncompleteReadError) as e:
        raise RelayUnavailableError(f"relay at {socket_path}: {type(e).__name__}: {e}") from None
    try:
        doc = json.loads(answer)
    except ValueError:
        raise RelayUnavailableError(f"relay at {socket_path}: not a JSON answer") from None
    if not isinstance(doc, dict) or doc.get("v") != PROTOCOL:
        raise RelayUnavailableError(f"relay at {socket_path}: another protocol version")
    return doc
