"""Whether a TCP port can be bound as the tier servers bind it: the preflight of `up` and `fleet up`."""

from __future__ import annotations

import errno
import socket


def unbindable(host: str, port: int) -> str | None:
    """Why ``port`` on ``host`` cannot be bound the way the servers bind it (every address the
    host resolves to, SO_REUSEADDR as asyncio sets it): ``"is already in use"`` or ``"cannot be
    bound: REASON"``; None when it can. Raises socket.gaierror for a host that does not resolve."""
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(addr)
            except OSError as e:
                return (
                    "is already in use"
                    if e.errno == errno.EADDRINUSE
                    else f"cannot be bound: {e.strerror or e}"
                )
    return None
