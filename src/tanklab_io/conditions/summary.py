"""A tier's alarm summary nodes kept current (the thin shell over :meth:`AlarmManager.summary`).

The summary (``<Tier>.AlarmSummary.*``, :mod:`tanklab.alarms.summary`) changes only when a
condition changes or when an annunciated activation leaves the 600 s rate window, so it is
published at exactly those moments, never every scan:

* after every batch of condition events the projection raised (its ``after_publish`` hook:
  scan events, a client's call, the warm-restart announcements);
* when the tier's model time reaches :meth:`AlarmManager.rate_expiring` (the tier calls
  :meth:`SummaryPublisher.expire` once per scan or cycle; it costs a comparison).

Model time is the tier's (``now_s``: the last scan's or feed's), so the rate window runs on model
time like every other alarm time.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

from tanklab.alarms.manager import AlarmManager
from tanklab.alarms.model import AlarmSummary
from tanklab.alarms.summary import summary_values
from tanklab.paths import Tier

__all__ = ["SummaryPublisher"]


class SummaryPublisher:
    """Publishes ``manager``'s summary of ``tier`` through ``publish`` (the tier's value publisher,
    which stores only the values that changed) at model time ``now_s()`` [s]."""

    def __init__(
        self,
        tier: Tier,
        manager: AlarmManager,
        publish: Callable[[dict[str, Any]], Awaitable[None]],
        now_s: Callable[[], float],
    ) -> None:
        self.tier: Tier = tier
        self.manager = manager
        self._publish = publish
        self._now_s = now_s
        self.last: AlarmSummary | None = None
        """The summary last published (None before the first)."""
        self.publications = 0

    async def publish(self) -> None:
        """Compute the summary now and publish it."""
        summary = self.manager.summary(self._now_s())
        self.last = summary
        self.publications += 1
        await self._publish(summary_values(self.tier, summary))

    async def expire(self) -> bool:
        """Publish if an activation left the rate window by now; return whether it did."""
        due = self.manager.rate_expiring()
        if due is None or due > self._now_s():
            return False
        await self.publish()
        return True
