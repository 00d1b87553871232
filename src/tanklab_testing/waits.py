"""The bounded waits: the only way tests and benchmarks wait for real processes.

Both poll, stop after ``deadline_s`` seconds of wall time and fail with a message that names
what did not happen. What is asserted is on model time, never on how long a wait took.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable


async def wait_until(
    condition: Callable[[], Awaitable[bool] | bool],
    deadline_s: float,
    *,
    what: str = "condition",
    poll_s: float = 0.05,
) -> None:
    """Wait until ``condition()`` (plain or awaitable) is true, at most ``deadline_s`` seconds
    of wall time, polling every ``poll_s`` seconds; AssertionError naming ``what`` after that."""
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


def wait_until_sync(
    condition: Callable[[], bool], deadline_s: float, *, what: str = "condition", poll_s: float = 0.5
) -> None:
    """:func:`wait_until` for code with no event loop (a synchronous fixture): the same bound
    and the same message."""
    end = time.monotonic() + deadline_s
    while not condition():
        if time.monotonic() >= end:
            raise AssertionError(f"timed out after {deadline_s} s waiting for {what}")
        time.sleep(poll_s)
