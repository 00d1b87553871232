"""Part 11 read rules, as pure functions: the time domain of a raw, processed or at-time read.

Times are UTC microseconds (``*_us``); ``None`` is an unspecified time (the client sent
DateTime.MinValue). **Raw reads** (Part 11, 6.5.3.1-6.5.3.2: "two of the three parameters,
numValuesPerNode, startTime and endTime shall be specified")::

    start, end given     start <= end: forward  [start, end)   (start == end: the value at start)
                         start >  end: reverse  (end, start], newest first
    start, n given       forward from start, at most n values
    end, n given         reverse from end (end inclusive, as a reverse read's start), at most n
    fewer than two       Bad_InvalidTimestampArgument

``n = numValuesPerNode`` (0: no limit). The start is always the inclusive bound: "the startTime
is included" in either direction. **Bounds** (``returnBounds``): the start bound is the value at
or before the start (forward) or at or after it (reverse) and the end bound the value at or after
the end (forward) or at or before it (reverse); a bound not found is returned as a value with
Bad_BoundNotFound stamped with that time (Part 11, 6.5.3.2 and 3.1.6). A bound that is a value
the range holds already is not repeated. Bounds are not counted in ``n``.

**Processed reads** (6.5.4): start and end both given and different (start > end: reverse
intervals), else Bad_InvalidTimestampArgument; a negative or non-finite processing interval is
Bad_InvalidArgument. **At-time reads** (6.5.5): each requested time gets its interpolated bounding
value (:func:`tanklab.history.aggregates.interpolated_value`).
"""

from __future__ import annotations

from typing import NamedTuple

from tanklab.history.model import EPOCH_OFFSET_TICKS
from tanklab.history.status import BAD_INVALID_ARGUMENT, BAD_INVALID_TIMESTAMP_ARGUMENT

__all__ = [
    "TIME_MAX_US",
    "TIME_MIN_US",
    "HistoryArgumentError",
    "RawPlan",
    "plan_processed",
    "plan_raw",
    "ticks_to_us",
    "us_to_ticks",
]

TIME_MIN_US = -EPOCH_OFFSET_TICKS // 10
"""1601-01-01 UTC [us]: OPC UA's DateTime.MinValue, "unspecified"."""
TIME_MAX_US = 253_402_300_799_999_999
"""9999-12-31T23:59:59.999999 UTC [us]: the end of time a read can name."""


class HistoryArgumentError(ValueError):
    """A read's arguments break a Part 11 rule; ``status`` is the code the operation returns."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def ticks_to_us(ticks: int) -> int:
    """OPC UA DateTime (100 ns since 1601) to UTC us since 1970 (floor)."""
    return (ticks - EPOCH_OFFSET_TICKS) // 10


def us_to_ticks(t_us: int) -> int:
    """UTC us since 1970 to OPC UA DateTime (exact)."""
    return t_us * 10 + EPOCH_OFFSET_TICKS


class RawPlan(NamedTuple):
    """What a raw read asks the store: ``read_raw(tag, start_us, end_us)`` semantics
    (:func:`historian.store.base.in_range`), a limit (``None``: all) and the bounds wanted."""

    start_us: int
    end_us: int
    limit: int | None
    start_bound: bool
    end_bound: bool

    @property
    def reverse(self) -> bool:
        return self.start_us > self.end_us


def plan_raw(start_us: int | None, end_us: int | None, num_values: int, return_bounds: bool) -> RawPlan:
    """The store read of a ReadRawModifiedDetails (module docstring); raises
    :class:`HistoryArgumentError` (Bad_InvalidTimestampArgument) when fewer than two of start,
    end and ``num_values`` are given."""
    if num_values < 0:
        raise HistoryArgumentError(BAD_INVALID_TIMESTAMP_ARGUMENT, "numValuesPerNode < 0")
    limit = num_values or None
    given = (start_us is not None) + (end_us is not None) + (limit is not None)
    if given < 2:
        raise HistoryArgumentError(
            BAD_INVALID_TIMESTAMP_ARGUMENT,
            "two of startTime, endTime and numValuesPerNode must be specified (Part 11, 6.5.3.1)",
        )
    if start_us is not None and end_us is not None:
        return RawPlan(start_us, end_us, limit, return_bounds, return_bounds)
    if start_us is not None:
        return RawPlan(start_us, TIME_MAX_US, limit, return_bounds, False)
    assert end_us is not None
    return RawPlan(end_us, TIME_MIN_US, limit, return_bounds, False)


def plan_processed(start_us: int | None, end_us: int | None, processing_ms: float) -> tuple[int, int, int]:
    """``(start_us, end_us, processing_us)`` of a ReadProcessedDetails; raises
    :class:`HistoryArgumentError`: Bad_InvalidTimestampArgument when a time is unspecified or
    start == end, Bad_InvalidArgument for a negative or non-finite processing interval [ms]."""
    if start_us is None or end_us is None or start_us == end_us:
        raise HistoryArgumentError(
            BAD_INVALID_TIMESTAMP_ARGUMENT, "a processed read needs startTime != endTime, both specified"
        )
    if not processing_ms >= 0 or processing_ms == float("inf"):
        raise HistoryArgumentError(BAD_INVALID_ARGUMENT, f"processing interval {processing_ms} ms")
    return start_us, end_us, round(processing_ms * 1000)
