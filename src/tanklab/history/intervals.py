"""Processing intervals of a processed history read (OPC UA Part 13, 5.4.2; Part 11, 6.5.4).

A read from ``start`` to ``end`` [us] with processing interval ``p`` [us] is cut into intervals
of width ``p`` laid from ``start`` towards ``end``::

    forward (start < end):  I_k = [start + k p, min(start + (k+1) p, end))      k = 0, 1, ...
    reverse (start > end):  I_k = (max(start - (k+1) p, end), start - k p]

Each interval **includes its start and excludes its end** (Part 13: the start time of each
interval is inclusive, the end exclusive); in a reverse read an interval's start is its later
bound, so it covers ``(lo, hi]``. ``p = 0`` makes one interval of the whole range. When the range
is not a multiple of ``p`` the last interval is shorter: it is **partial** (its results carry the
Partial bit where Part 13 says so). An aggregate's timestamp is its interval's start.
``start == end`` has no interval (Part 11: BadInvalidTimestampArgument for processed reads).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["MAX_INTERVALS", "Interval", "intervals"]

MAX_INTERVALS = 1_000_000
"""The most intervals one read may ask for (a day at 0.1 s); more is refused, not computed."""


class Interval(NamedTuple):
    """One processing interval: ``start_us`` is inclusive and stamps the result."""

    start_us: int
    end_us: int
    partial: bool = False

    @property
    def reverse(self) -> bool:
        """A reverse read's interval (its start is its later bound)."""
        return self.start_us > self.end_us

    @property
    def lo_us(self) -> int:
        """The earlier bound."""
        return min(self.start_us, self.end_us)

    @property
    def hi_us(self) -> int:
        """The later bound."""
        return max(self.start_us, self.end_us)

    @property
    def width_us(self) -> int:
        """Duration [us]."""
        return abs(self.end_us - self.start_us)

    def contains(self, t_us: int) -> bool:
        """Start inclusive, end exclusive, in either direction."""
        if self.reverse:
            return self.end_us < t_us <= self.start_us
        return self.start_us <= t_us < self.end_us


def intervals(start_us: int, end_us: int, processing_us: int) -> list[Interval]:
    """The intervals of a processed read (see the module docstring).

    Raises ``ValueError`` for ``start_us == end_us``, a negative ``processing_us`` or more than
    :data:`MAX_INTERVALS` intervals.
    """
    if start_us == end_us:
        raise ValueError("a processed read needs start != end")
    if processing_us < 0:
        raise ValueError(f"processing interval must be >= 0 us, got {processing_us}")
    span = abs(end_us - start_us)
    if processing_us == 0 or processing_us >= span:
        return [Interval(start_us, end_us, partial=processing_us > span)]
    n_full, rest = divmod(span, processing_us)
    if n_full + (1 if rest else 0) > MAX_INTERVALS:
        raise ValueError(f"{n_full + (1 if rest else 0)} intervals exceed the limit {MAX_INTERVALS}")
    sign = 1 if end_us > start_us else -1
    step = sign * processing_us
    out = [Interval(start_us + k * step, start_us + (k + 1) * step) for k in range(n_full)]
    if rest:
        out.append(Interval(start_us + n_full * step, end_us, partial=True))
    return out
