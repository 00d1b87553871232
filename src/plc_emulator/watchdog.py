"""The PLC's supervisor watchdog: is the supervisor's heartbeat still changing?

Pure: model time in, Alive out. The heartbeat must change within ``timeout_s`` of model time,
counted from the scan that saw the last change (the first timeout after start is a grace period
counted from the first scan); supervisor gains are accepted again only after the heartbeat has
been good for ``good_scans_needed`` scans (``PlcProgram.supervisor_trusted``).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["TIME_EPS_SCANS", "Watchdog"]

TIME_EPS_SCANS = 1e-6
"""Tolerance on model-time comparisons, in scan periods: model time accumulated as a sum of Ts
(0.01 s 300 times is not exactly 3.0) must not delay a timeout by a whole scan."""


@dataclass
class Watchdog:
    """The watchdog's state (times in model seconds)."""

    timeout_s: float
    good_scans_needed: int
    last_value: int | None = None
    last_change_s: float | None = None  # None until the first scan (grace period starts there)
    alive: bool = False
    ever_alive: bool = False
    good_scans: int = 0
    expired: bool = False

    def update(self, t_s: float, value: int | None, ts_s: float) -> bool:
        """One scan at model time ``t_s`` [s] with the heartbeat written since the last scan
        (None: none), scan period ``ts_s`` [s]; returns whether the timeout has expired."""
        if self.last_change_s is None:
            self.last_change_s = t_s  # grace period: the first timeout counts from the first scan
        if value is not None and value != self.last_value:
            self.last_value = value
            self.last_change_s = t_s
        expired = t_s - self.last_change_s >= self.timeout_s - TIME_EPS_SCANS * ts_s
        alive = self.last_value is not None and not expired
        if alive:
            self.good_scans += 1
            self.ever_alive = True
        else:
            self.good_scans = 0
        self.alive = alive
        self.expired = expired
        return expired
