"""Model time -> UTC for a tier's condition events (its ``to_utc``)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

__all__ = ["ModelUtc"]


class ModelUtc:
    """Model time [s] -> UTC, as a tier's SourceTimestamps are: the wall clock of the scan.

    The PLC stamps every value it publishes with the server's clock when the scan publishes it
    (:class:`tanklab_io.ua.Publisher`); an alarm event's Time (the core's model time) is mapped
    the same way. :meth:`anchor` ties model time ``t_s`` to the UTC now (the runtime calls it
    when it publishes a scan's alarm events, so their Time is that scan's stamp); other model
    times are the anchor's, moved by the model-time difference over ``speed`` (real time: ``speed``
    model seconds per wall second; in lock-step only a scan's own events are exact).
    """

    def __init__(self, speed: float = 1.0) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.speed = speed
        self._t_s = 0.0
        self._utc = datetime.now(UTC)

    def anchor(self, t_s: float, utc: datetime | None = None) -> None:
        """Model time ``t_s`` [s] is ``utc`` (default: now)."""
        self._t_s, self._utc = t_s, utc or datetime.now(UTC)

    def __call__(self, t_s: float) -> datetime:
        return self._utc + timedelta(seconds=(t_s - self._t_s) / self.speed)
