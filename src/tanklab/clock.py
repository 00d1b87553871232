"""Clocks, injected into the runtimes so that tests drive time instead of sleeping.

``runtime.py`` modules are the only places that own a clock. A :class:`MonotonicClock` reads
``time.monotonic`` and sleeps with ``asyncio.sleep``; a :class:`VirtualClock` is advanced by the
caller (co-simulation, lock-step, tests) and its ``sleep_until`` returns as soon as virtual time
has reached the deadline, so an hour of scans runs in milliseconds.

Deadline scheduling (openpilot's Ratekeeper): the next deadline is the previous deadline plus
the period, never "now + period", so scan jitter does not accumulate; a scan whose work ends
after the next deadline is an overrun.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field
from typing import Protocol


class Clock(Protocol):
    """What a runtime needs from a clock: the time now and a way to wait for a deadline."""

    def now(self) -> float:
        """Seconds on a monotonic scale."""
        ...

    async def sleep_until(self, deadline: float) -> None:
        """Return once ``now() >= deadline``."""
        ...


class MonotonicClock:
    """The wall clock: ``time.monotonic`` and ``asyncio.sleep``."""

    def now(self) -> float:
        return time.monotonic()

    async def sleep_until(self, deadline: float) -> None:
        delay = deadline - time.monotonic()
        if delay > 0:
            await asyncio.sleep(delay)
        else:
            await asyncio.sleep(0)


class VirtualClock:
    """A clock that only moves when told to; ``sleep_until`` jumps to the deadline.

    Waiting on a virtual clock advances it, so a runtime driven by it runs as fast as its work.
    """

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)

    def now(self) -> float:
        return self._now

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError(f"seconds must be >= 0, got {seconds}")
        self._now += seconds

    async def sleep_until(self, deadline: float) -> None:
        self._now = max(self._now, deadline)
        await asyncio.sleep(0)


@dataclass
class Deadlines:
    """Deadline schedule with overrun telemetry (pure: the caller passes the clock readings).

    Attributes
    ----------
    period_s : float
        Wall seconds between deadlines.
    next_deadline : float
        The next deadline on the caller's clock.
    overruns : int
        Scans whose work ended after the following deadline; the schedule then skips the missed
        deadlines instead of running a burst of late scans.
    lateness_s : list[float]
        Start lateness of recent scans (start time minus deadline), bounded to the last 10,000.
    """

    period_s: float
    next_deadline: float
    overruns: int = 0
    lateness_s: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.period_s > 0:
            raise ValueError(f"period_s must be > 0, got {self.period_s}")

    def started(self, now: float) -> None:
        """Record that the scan due at ``next_deadline`` started at ``now``."""
        self.lateness_s.append(max(0.0, now - self.next_deadline))
        if len(self.lateness_s) > 10_000:
            del self.lateness_s[:5_000]

    def finished(self, now: float) -> float:
        """Record the end of a scan at ``now``; return the deadline of the next scan."""
        self.next_deadline += self.period_s
        if now > self.next_deadline:
            missed = int((now - self.next_deadline) // self.period_s) + 1
            self.overruns += 1
            self.next_deadline += missed * self.period_s
        return self.next_deadline


async def sleep_or_stop(clock: Clock, deadline: float, stop: asyncio.Event) -> None:
    """Wait until ``deadline`` on ``clock`` or until ``stop`` is set, whichever comes first."""
    sleeper = asyncio.ensure_future(clock.sleep_until(deadline))
    stopper = asyncio.ensure_future(stop.wait())
    await asyncio.wait({sleeper, stopper}, return_when=asyncio.FIRST_COMPLETED)
    for fut in (sleeper, stopper):
        fut.cancel()
