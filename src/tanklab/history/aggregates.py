"""Part 13 aggregates over recorded samples (pure: samples and intervals in, samples out).

Input: one tag's samples in time order, covering the read's range **plus its bounds** (the last
sample at or before the range and the first at or after it, and the nearest Good ones beyond
those: the caller fetches them), and the processing intervals (:mod:`tanklab.history.intervals`).
A raw value *counts* when its status is Good, or Uncertain with ``treat_uncertain_as_bad`` false
(:func:`tanklab.history.status.counts_as_good`); the others are Bad. Statuses follow
:func:`tanklab.history.status.status_from_shares`. Results are :class:`Sample` (time, value,
StatusCode with the historian bits); a result without a value is ``None`` with a Bad code.

Per interval ``I`` (start inclusive, end exclusive; ``n_good``/``n_bad`` raw values in ``I``)::

    Average       = sum(v_i, good) / n_good                  Calculated; status by count
    Count         = n_good                                   Calculated; status by count
    Minimum       = min(v_i, good) at its raw time           Raw; MultiValue if tied; by count
    Maximum       = max(v_i, good) at its raw time           Raw; MultiValue if tied; by count
    Start / End   = the first / last raw value in I (any status), as recorded
    Delta         = v_last_good - v_first_good               Calculated; status by count
    Interpolative = x(start of I), the interpolated bounding value (below)
    TimeAverage   = A_good / T_good                          Calculated; status by duration
    Total         = A_good [value * s]                       Calculated; status by duration

**Interpolated bounding value** ``x(t)`` (Part 13, 3.1.8 and 5.3.1): a raw value at exactly ``t``
that counts is used as is (Raw). Otherwise, with ``p`` the nearest counting value before ``t``
and ``n`` the nearest after: ``x = v_p`` when the variable is stepped, or either value is not a
float (enumerations and flags step); else ``x = v_p + (v_n - v_p) (t - t_p) / (t_n - t_p)``
(sloped). Status Good + Interpolated, Uncertain_DataSubNormal + Interpolated when Bad raw values
were skipped between ``p`` and ``n``; no ``n``: ``x = v_p`` (stepped extrapolation; sloped
extrapolation is not offered) with Uncertain_DataSubNormal; no ``p``: Bad_NoData.

**Time-weighted** (TimeAverage, Total): the interval ``[a, b)`` is cut at its raw values into
regions; a region ``[t_j, t_j+1)`` has the status of the last raw value at or before ``t_j``
(none: no data, counted Bad) and is Good when that value counts; a region after the last value
of the data is extrapolated, Uncertain (so Bad by default: an interval after the end of the data
is Bad_NoData, Part 13 "After End of Data"). The value at the interval's
edges is the simple bound: the value in effect there, joined by a straight line to the next raw
value when both count and are floats and the variable is sloped. Area of a Good region::

    sloped  (y_j + y_j+1) / 2 * (t_j+1 - t_j)     (y_j+1 the value at the region's end)
    stepped  y_j * (t_j+1 - t_j)

``A_good`` sums the Good regions [value * us], ``T_good`` their durations [us]; Bad regions are
left out of both (so the TimeAverage of a constant is that constant whatever the gaps), and
``T_bad / (T_good + T_bad)`` decides the status. Partial is set on a shortened last interval for
the time-weighted results, Minimum, Maximum, Count and Delta; Average never sets it (Part 13,
Table "Average Aggregate summary").

An interval with no raw value (or, for the time-weighted ones, no Good region) gives Bad_NoData
at the interval's start; a counting value that is not a number gives Bad_AggregateInvalidInputs.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Sequence
from itertools import pairwise

from tanklab.history.intervals import Interval
from tanklab.history.model import Sample, Value
from tanklab.history.status import (
    BAD_AGGREGATE_INVALID_INPUTS,
    BAD_NO_DATA,
    GOOD,
    HISTORIAN_CALCULATED,
    HISTORIAN_INTERPOLATED,
    HISTORIAN_MULTI_VALUE,
    HISTORIAN_PARTIAL,
    UNCERTAIN_DATA_SUB_NORMAL,
    AggregateConfig,
    counts_as_good,
    status_from_shares,
)

__all__ = ["AGGREGATES", "aggregate", "interpolated_value"]


class _Series:
    """Samples in time order with their times, for bisection."""

    def __init__(self, samples: Sequence[Sample], config: AggregateConfig) -> None:
        self.s = samples
        self.t = [x.t_us for x in samples]
        self.cfg = config

    def span(self, iv: Interval) -> tuple[int, int]:
        """Indices ``[i, j)`` of the raw values inside ``iv`` (start in, end out)."""
        if iv.reverse:
            return bisect_right(self.t, iv.end_us), bisect_right(self.t, iv.start_us)
        return bisect_left(self.t, iv.start_us), bisect_left(self.t, iv.end_us)

    def ok(self, k: int) -> bool:
        return counts_as_good(self.s[k].status, self.cfg)


def _number(v: Value) -> float | None:
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, int | float):
        return float(v)
    return None


def _slopes(a: Value, b: Value, cfg: AggregateConfig) -> bool:
    return not cfg.stepped and type(a) is float and type(b) is float


def _no_data(iv: Interval) -> Sample:
    return Sample(iv.start_us, None, BAD_NO_DATA)


def _partial(iv: Interval) -> int:
    return HISTORIAN_PARTIAL if iv.partial else 0


def interpolated_value(samples: Sequence[Sample], t_us: int, config: AggregateConfig) -> Sample:
    """The interpolated bounding value at ``t_us`` (module docstring), stamped ``t_us``."""
    return _interp(_Series(samples, config), t_us)


def _interp(ser: _Series, t: int) -> Sample:
    i = bisect_left(ser.t, t)
    if i < len(ser.t) and ser.t[i] == t and ser.ok(i):
        return Sample(t, ser.s[i].value, ser.s[i].status)
    p = bisect_right(ser.t, t) - 1
    skipped = False
    while p >= 0 and not ser.ok(p):
        skipped = True
        p -= 1
    if p < 0:
        return Sample(t, None, BAD_NO_DATA)
    n = bisect_right(ser.t, t)
    while n < len(ser.t) and not ser.ok(n):
        skipped = True
        n += 1
    vp = ser.s[p].value
    if n >= len(ser.t):
        return Sample(t, vp, UNCERTAIN_DATA_SUB_NORMAL | HISTORIAN_INTERPOLATED)
    vn = ser.s[n].value
    code = (UNCERTAIN_DATA_SUB_NORMAL if skipped else GOOD) | HISTORIAN_INTERPOLATED
    if _slopes(vp, vn, ser.cfg):
        assert isinstance(vp, float) and isinstance(vn, float)
        tp, tn = ser.t[p], ser.t[n]
        return Sample(t, vp + (vn - vp) * (t - tp) / (tn - tp), code)
    return Sample(t, vp, code)


def _counted(ser: _Series, iv: Interval) -> tuple[list[int], int, int]:
    """Indices of the counting values in ``iv`` (time order), and how many raw values do not."""
    i, j = ser.span(iv)
    good = [k for k in range(i, j) if ser.ok(k)]
    return good, len(good), (j - i) - len(good)


def _average(ser: _Series, iv: Interval) -> Sample:
    good, n_good, n_bad = _counted(ser, iv)
    if n_good == 0:
        return _no_data(iv)
    nums = [_number(ser.s[k].value) for k in good]
    if any(x is None for x in nums):
        return Sample(iv.start_us, None, BAD_AGGREGATE_INVALID_INPUTS)
    mean = math.fsum(x for x in nums if x is not None) / n_good
    return Sample(iv.start_us, mean, status_from_shares(n_good, n_bad, ser.cfg) | HISTORIAN_CALCULATED)


def _count(ser: _Series, iv: Interval) -> Sample:
    _good, n_good, n_bad = _counted(ser, iv)
    if n_good + n_bad == 0:
        return _no_data(iv)
    code = status_from_shares(n_good, n_bad, ser.cfg) | HISTORIAN_CALCULATED | _partial(iv)
    return Sample(iv.start_us, n_good, code)


def _extreme(pick: Callable[[Sequence[float]], float]) -> Callable[[_Series, Interval], Sample]:
    def calc(ser: _Series, iv: Interval) -> Sample:
        good, n_good, n_bad = _counted(ser, iv)
        if n_good == 0:
            return _no_data(iv)
        nums = [_number(ser.s[k].value) for k in good]
        if any(x is None for x in nums):
            return Sample(iv.start_us, None, BAD_AGGREGATE_INVALID_INPUTS)
        vals = [x for x in nums if x is not None]
        best = pick(vals)
        at = good[vals.index(best)]
        code = status_from_shares(n_good, n_bad, ser.cfg) | _partial(iv)
        if vals.count(best) > 1:
            code |= HISTORIAN_MULTI_VALUE
        return Sample(ser.t[at], ser.s[at].value, code)

    return calc


def _edge(last: bool) -> Callable[[_Series, Interval], Sample]:
    def calc(ser: _Series, iv: Interval) -> Sample:
        i, j = ser.span(iv)
        if i == j:
            return _no_data(iv)
        return ser.s[j - 1 if last else i]

    return calc


def _delta(ser: _Series, iv: Interval) -> Sample:
    good, n_good, n_bad = _counted(ser, iv)
    if n_good == 0:
        return _no_data(iv)
    first, last = _number(ser.s[good[0]].value), _number(ser.s[good[-1]].value)
    if first is None or last is None:
        return Sample(iv.start_us, None, BAD_AGGREGATE_INVALID_INPUTS)
    code = status_from_shares(n_good, n_bad, ser.cfg) | HISTORIAN_CALCULATED | _partial(iv)
    return Sample(iv.start_us, last - first, code)


def _interpolative(ser: _Series, iv: Interval) -> Sample:
    return _interp(ser, iv.start_us)


def _simple_bound(ser: _Series, t: int) -> tuple[int, float | None]:
    """The raw value in effect at ``t`` (index, -1 if none) and the value there on the line to
    the next raw value (``None`` when it does not count or is not a number)."""
    k = bisect_right(ser.t, t) - 1
    if k < 0 or not ser.ok(k):
        return k, None
    v = ser.s[k].value
    y = _number(v)
    if y is None or ser.t[k] == t:
        return k, y
    n = k + 1
    if n < len(ser.t) and ser.ok(n) and _slopes(v, ser.s[n].value, ser.cfg):
        vn = ser.s[n].value
        assert isinstance(v, float) and isinstance(vn, float)
        return k, v + (vn - v) * (t - ser.t[k]) / (ser.t[n] - ser.t[k])
    return k, y


def _area(ser: _Series, iv: Interval) -> tuple[float, int, int, bool]:
    """``(A_good [value*us], T_good [us], T_bad [us], invalid)`` over ``iv``."""
    a, b = iv.lo_us, iv.hi_us
    k0, y0 = _simple_bound(ser, a)
    _k1, y_end = _simple_bound(ser, b)
    inner_lo, inner_hi = bisect_right(ser.t, a), bisect_left(ser.t, b)
    # points: (time, index of the raw value in effect from there, value at that time)
    pts: list[tuple[int, int, float | None]] = [(a, k0, y0)]
    for k in range(inner_lo, inner_hi):
        pts.append((ser.t[k], k, _number(ser.s[k].value) if ser.ok(k) else None))
    area, t_good, t_bad, invalid = 0.0, 0, 0, False
    last = len(ser.t) - 1  # after the last value of the data: extrapolated, so Uncertain
    for idx, (t, k, y) in enumerate(pts):
        t_next = pts[idx + 1][0] if idx + 1 < len(pts) else b
        dt = t_next - t
        if dt <= 0:
            continue
        if k < 0 or not ser.ok(k) or (k == last and ser.cfg.treat_uncertain_as_bad):
            t_bad += dt
            continue
        if y is None:
            invalid = True
            continue
        t_good += dt
        if idx + 1 < len(pts):
            y_next = pts[idx + 1][2]
            nxt = pts[idx + 1][1]
        else:
            y_next, nxt = y_end, k + 1
        sloped = (
            y_next is not None
            and 0 <= nxt < len(ser.s)
            and ser.ok(nxt)
            and _slopes(ser.s[k].value, ser.s[nxt].value, ser.cfg)
        )
        area += (y + y_next) / 2 * dt if sloped and y_next is not None else y * dt
    return area, t_good, t_bad, invalid


def _time_weighted(total: bool) -> Callable[[_Series, Interval], Sample]:
    def calc(ser: _Series, iv: Interval) -> Sample:
        area, t_good, t_bad, invalid = _area(ser, iv)
        if invalid:
            return Sample(iv.start_us, None, BAD_AGGREGATE_INVALID_INPUTS)
        if t_good == 0:
            return _no_data(iv)
        code = status_from_shares(t_good, t_bad, ser.cfg) | HISTORIAN_CALCULATED | _partial(iv)
        return Sample(iv.start_us, area / 1e6 if total else area / t_good, code)

    return calc


AGGREGATES: dict[str, Callable[[_Series, Interval], Sample]] = {
    "Average": _average,
    "TimeAverage": _time_weighted(total=False),
    "Total": _time_weighted(total=True),
    "Minimum": _extreme(min),
    "Maximum": _extreme(max),
    "Count": _count,
    "Interpolative": _interpolative,
    "Start": _edge(last=False),
    "End": _edge(last=True),
    "Delta": _delta,
}
"""The aggregates this historian computes, by their Part 13 BrowseName."""


def aggregate(
    name: str, samples: Sequence[Sample], ivs: Sequence[Interval], config: AggregateConfig | None = None
) -> list[Sample]:
    """One result per interval of aggregate ``name`` over ``samples`` (time order, with bounds).

    Raises ``KeyError`` for an aggregate not in :data:`AGGREGATES` and ``ValueError`` when the
    samples are not in strictly increasing time order.
    """
    calc = AGGREGATES[name]
    ser = _Series(samples, config or AggregateConfig())
    if any(b <= a for a, b in pairwise(ser.t)):
        raise ValueError("samples must be in strictly increasing time order")
    return [calc(ser, iv) for iv in ivs]
