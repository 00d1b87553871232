"""The bounded waits: the only way tests and benchmarks wait for real processes.

Both poll, stop after ``deadline_s`` seconds of wall time and fail with a message that names
what did not happen. What is asserted is on model time, never on how long a wait took.

A bound is a hang bound, not a speed target: it says "this has surely failed", which on a
shared machine depends on how busy it is. So every bound stretches with the load
(:func:`load_stretch`: the 1-minute load average per core, at least 1): a 20 s bound is 20 s
on an idle machine and 80 s while 8 runnable processes share 2 cores. The stretch is read
again whenever the bound is reached, so load that rises during a wait lengthens it too.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Awaitable, Callable

__all__ = ["hang_bound", "load_stretch", "wait_until", "wait_until_sync"]


def load_stretch() -> float:
    """How many times longer a wall-time wait may take now than on an idle machine: the
    1-minute load average per usable core, at least 1 (1 where the OS has no load average)."""
    try:
        load = os.getloadavg()[0]
    except OSError:
        return 1.0
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1.0, load / (cores or 1))


def hang_bound(deadline_s: float) -> float:
    """``deadline_s`` [s] stretched by the load now (for subprocess and wait_for timeouts)."""
    return deadline_s * load_stretch()


class _Bound:
    """``deadline_s`` of idle-machine wall time, stretched by the load when it is reached."""

    def __init__(self, deadline_s: float) -> None:
        self.deadline_s = deadline_s
        self._start = time.monotonic()
        self.stretch = 1.0

    def passed(self) -> bool:
        elapsed = time.monotonic() - self._start
        if elapsed < self.deadline_s:
            return False
        self.stretch = load_stretch()
        return elapsed >= self.deadline_s * self.stretch

    def failure(self, what: str) -> AssertionError:
        note = f" (a {self.deadline_s} s bound x {self.stretch:.1f} for the load)" if self.stretch > 1 else ""
        waited_s = self.deadline_s * self.stretch
        return AssertionError(f"timed out after {waited_s:.0f} s{note} waiting for {what}")


async def wait_until(
    condition: Callable[[], Awaitable[bool] | bool],
    deadline_s: float,
    *,
    what: str = "condition",
    poll_s: float = 0.05,
) -> None:
    """Wait until ``condition()`` (plain or awaitable) is true, at most ``deadline_s`` seconds
    of wall time on an idle machine (stretched by the load, see the module docstring), polling
    every ``poll_s`` seconds; AssertionError naming ``what`` after that."""
    bound = _Bound(deadline_s)
    while True:
        result = condition()
        if not isinstance(result, bool):
            result = await result
        if result:
            return
        if bound.passed():
            raise bound.failure(what)
        await asyncio.sleep(poll_s)


def wait_until_sync(
    condition: Callable[[], bool], deadline_s: float, *, what: str = "condition", poll_s: float = 0.5
) -> None:
    """:func:`wait_until` for code with no event loop (a synchronous fixture): the same bound
    and the same message."""
    bound = _Bound(deadline_s)
    while not condition():
        if bound.passed():
            raise bound.failure(what)
        time.sleep(poll_s)
