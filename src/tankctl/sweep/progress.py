"""The sweep's progress bar on stderr, with an estimate of the time left.

ETA = (cases left) / (cases done by this run / seconds since it started): cases found already
done in the output (a resumed sweep) count as done but not in the rate. On a terminal the bar is
one line redrawn in place (``\\r``); piped (a CI log) it prints a line each time another
``every_pct`` percent of the cases is done, and at the end.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["Progress", "format_duration", "progress_line"]


def format_duration(seconds: float) -> str:
    """``H:MM:SS`` or ``M:SS`` (``?`` for an unknown or infinite time)."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    s = round(seconds)
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def progress_line(done: int, total: int, new: int, elapsed_s: float, width: int = 24) -> str:
    """The bar: ``done``/``total`` cases, ``new`` of them by this run in ``elapsed_s`` seconds."""
    frac = done / total if total else 1.0
    filled = math.floor(frac * width)  # never more than done
    rate = new / elapsed_s if elapsed_s > 0 and new > 0 else 0.0
    eta = (total - done) / rate if rate > 0 else (0.0 if done >= total else math.inf)
    return (
        f"sweep [{'#' * filled}{'.' * (width - filled)}] {done}/{total} {100 * frac:3.0f}% "
        f"{rate:.2f} cases/s ETA {format_duration(eta)}"
    )


class Progress:
    """Shows :func:`progress_line` on ``stream`` as cases complete."""

    def __init__(
        self,
        total: int,
        already: int,
        stream: TextIO,
        *,
        tty: bool,
        every_pct: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.total, self.already, self.stream, self.tty = total, already, stream, tty
        self.every_pct, self.clock = every_pct, clock
        self.started = clock()
        self.done = already
        self._next_pct = every_pct * (math.floor(100 * already / total / every_pct) + 1) if total else 100.0

    def _line(self) -> str:
        return progress_line(self.done, self.total, self.done - self.already, self.clock() - self.started)

    def update(self, completed: int) -> None:
        """``completed`` more cases are done."""
        self.done += completed
        if self.tty:
            self.stream.write("\r" + self._line())
            self.stream.flush()
            return
        pct = 100 * self.done / self.total if self.total else 100.0
        if pct >= self._next_pct or self.done >= self.total:
            self.stream.write(self._line() + "\n")
            self.stream.flush()
            while self._next_pct <= pct:
                self._next_pct += self.every_pct

    def close(self) -> None:
        """End the bar's line (terminal)."""
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
