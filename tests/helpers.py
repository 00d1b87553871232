"""Shared test helpers: free loopback ports and the one bounded wait for real processes."""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Awaitable, Callable


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def wait_until(
    condition: Callable[[], Awaitable[bool] | bool],
    deadline_s: float,
    *,
    what: str = "condition",
    poll_s: float = 0.05,
) -> None:
    """Wait until ``condition()`` is true, at most ``deadline_s`` seconds of wall time.

    The only way tests wait for real processes: bounded, polling, failing with a message that
    names what did not happen. Assertions are on model time, never on how long this took.
    """
    end = time.monotonic() + deadline_s
    while True:
        result = condition()
        if not isinstance(result, bool):
            result = await result
        if result:
            return
        if time.monotonic() >= end:
            raise AssertionError(f"timed out after {deadline_s} s waiting for {what}")
        await asyncio.sleep(poll_s)
