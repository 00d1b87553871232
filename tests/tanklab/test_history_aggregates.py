"""Part 13 aggregates and Part 11 read rules of the kernel (tanklab.history): hand-computed
oracles on one small series, and Hypothesis properties.

The series (t in s, value, status): 0: 10 Good, 10: 20 Good, 20: 30 **Bad**, 30: 40 Good,
50: 60 Good; nothing after 50 s (the end of the data). Intervals of 20 s from 0 to 80 s:
I0 = [0, 20), I1 = [20, 40) (the Bad value at its start), I2 = [40, 60) (one value; the gap
30-50 s crosses its start), I3 = [60, 80) (empty, after the end of the data).
"""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tanklab.history.aggregates import AGGREGATES, aggregate, interpolated_value
from tanklab.history.intervals import MAX_INTERVALS, Interval, intervals
from tanklab.history.model import Sample, is_bad, is_good
from tanklab.history.raw import (
    TIME_MAX_US,
    TIME_MIN_US,
    HistoryArgumentError,
    plan_processed,
    plan_raw,
    ticks_to_us,
    us_to_ticks,
)
from tanklab.history.status import (
    BAD,
    BAD_AGGREGATE_INVALID_INPUTS,
    BAD_INVALID_ARGUMENT,
    BAD_INVALID_TIMESTAMP_ARGUMENT,
    BAD_NO_DATA,
    UNCERTAIN_DATA_SUB_NORMAL,
    AggregateConfig,
    status_from_shares,
)

S = 1_000_000
CALC = 0x401
INTERP = 0x402
PARTIAL = 0x404
MULTI = 0x410
UNC = UNCERTAIN_DATA_SUB_NORMAL
SERIES = [
    Sample(0, 10.0),
    Sample(10 * S, 20.0),
    Sample(20 * S, 30.0, BAD),
    Sample(30 * S, 40.0),
    Sample(50 * S, 60.0),
]
IVS = intervals(0, 80 * S, 20 * S)


def run(
    name: str, ivs: list[Interval] = IVS, cfg: AggregateConfig | None = None
) -> list[tuple[float, object, int]]:
    return [(r.t_us / S, r.value, r.status) for r in aggregate(name, SERIES, ivs, cfg)]


NO = (60.0, None, BAD_NO_DATA)

ORACLES = {
    # (10 + 20)/2; I1: the Bad 30 is left out, 1 Good of 2 -> Uncertain_DataSubNormal
    "Average": [(0.0, 15.0, CALC), (20.0, 40.0, UNC | CALC), (40.0, 60.0, CALC), NO],
    "Count": [(0.0, 2, CALC), (20.0, 1, UNC | CALC), (40.0, 1, CALC), NO],
    # raw timestamps, no Calculated bit (a raw value)
    "Minimum": [(0.0, 10.0, 0), (30.0, 40.0, UNC), (50.0, 60.0, 0), NO],
    "Maximum": [(10.0, 20.0, 0), (30.0, 40.0, UNC), (50.0, 60.0, 0), NO],
    # first/last raw value whatever its status
    "Start": [(0.0, 10.0, 0), (20.0, 30.0, BAD), (50.0, 60.0, 0), NO],
    "End": [(10.0, 20.0, 0), (30.0, 40.0, 0), (50.0, 60.0, 0), NO],
    "Delta": [(0.0, 10.0, CALC), (20.0, 0.0, UNC | CALC), (40.0, 0.0, CALC), NO],
    # at 0 the raw value; at 20 the Bad raw is skipped: 20 + (40-20)*10/20 = 30, Uncertain;
    # at 40 between 40 (30 s) and 60 (50 s): 50; at 60 past the data: 60 held, Uncertain
    "Interpolative": [
        (0.0, 10.0, 0),
        (20.0, 30.0, UNC | INTERP),
        (40.0, 50.0, INTERP),
        (60.0, 60.0, UNC | INTERP),
    ],
    # I0: (10+20)/2*10 + 20*10 (the line to the Bad 30 is not drawn: held) = 350 over 20 s;
    # I1: [20,30) Bad; [30,40) from 40 to the line's 50 at 40 s: 450 over 10 s; 50 % Bad;
    # I2: [40,50) from 50 to 60: 550 over 10 s; [50,60) after the data's end: Uncertain -> Bad
    "TimeAverage": [(0.0, 17.5, CALC), (20.0, 45.0, UNC | CALC), (40.0, 55.0, UNC | CALC), NO],
    "Total": [(0.0, 350.0, CALC), (20.0, 450.0, UNC | CALC), (40.0, 550.0, UNC | CALC), NO],
}


@pytest.mark.parametrize("name", sorted(ORACLES))
def test_aggregate_oracles(name: str) -> None:
    assert run(name) == ORACLES[name]


def test_every_aggregate_has_an_oracle() -> None:
    assert set(ORACLES) == set(AGGREGATES)


def test_stepped_interpolation_holds_the_value_before() -> None:
    cfg = AggregateConfig(stepped=True)
    assert run("Interpolative", cfg=cfg)[1:3] == [(20.0, 20.0, UNC | INTERP), (40.0, 40.0, INTERP)]
    # stepped TimeAverage of I0: 10*10 + 20*10 = 300 over 20 s
    assert run("TimeAverage", cfg=cfg)[0] == (0.0, 15.0, CALC)


def test_partial_last_interval() -> None:
    ivs = intervals(0, 50 * S, 20 * S)
    assert ivs[-1] == Interval(40 * S, 50 * S, partial=True)
    # [40, 50): the line from 50 (at 40 s) to the raw 60 at 50 s: 55, Partial; Average never
    assert run("TimeAverage", ivs)[-1] == (40.0, 55.0, CALC | PARTIAL)
    assert run("Average", ivs)[-1] == (40.0, None, BAD_NO_DATA)
    assert run("Count", ivs)[-2] == (20.0, 1, UNC | CALC)


def test_reverse_intervals_include_their_later_bound() -> None:
    ivs = intervals(60 * S, 20 * S, 20 * S)
    assert ivs == [Interval(60 * S, 40 * S), Interval(40 * S, 20 * S)]
    # (40, 60] holds 60 at 50 s; (20, 40] holds 40 at 30 s but not the Bad 30 at 20 s
    assert run("Average", ivs) == [(60.0, 60.0, CALC), (40.0, 40.0, CALC)]
    assert run("Count", ivs) == [(60.0, 1, CALC), (40.0, 1, CALC)]


def test_uncertain_counts_when_not_treated_as_bad() -> None:
    xs = [Sample(0, 1.0), Sample(S, 3.0, 0x4000_0000)]
    iv = [Interval(0, 2 * S)]
    assert aggregate("Average", xs, iv)[0] == Sample(0, 1.0, UNC | CALC)
    cfg = AggregateConfig(treat_uncertain_as_bad=False)
    assert aggregate("Average", xs, iv, cfg)[0] == Sample(0, 2.0, CALC)


def test_percent_data_thresholds() -> None:
    # 1 Bad of 4 = 25 %: with PercentDataBad 20 it is Bad, with PercentDataGood 75 Good
    assert status_from_shares(3, 1, AggregateConfig(percent_data_bad=20)) == BAD
    assert status_from_shares(3, 1, AggregateConfig(percent_data_good=75)) == 0
    assert status_from_shares(3, 1, AggregateConfig()) == UNC
    assert status_from_shares(0, 4, AggregateConfig()) == BAD
    assert status_from_shares(0, 0, AggregateConfig()) == BAD_NO_DATA
    with pytest.raises(ValueError, match="percent_data_bad"):
        AggregateConfig(percent_data_bad=101)


def test_multi_value_and_invalid_inputs() -> None:
    xs = [Sample(0, 5.0), Sample(S, 5.0), Sample(2 * S, 7.0)]
    assert aggregate("Minimum", xs, [Interval(0, 3 * S)])[0] == Sample(0, 5.0, MULTI)
    text = [Sample(0, "a"), Sample(S, "b")]
    assert aggregate("Average", text, [Interval(0, 2 * S)])[0].status == BAD_AGGREGATE_INVALID_INPUTS
    assert aggregate("Count", text, [Interval(0, 2 * S)])[0] == Sample(0, 2, CALC)


def test_enumerations_step_even_when_sloped() -> None:
    xs = [Sample(0, 1), Sample(10 * S, 3)]
    assert interpolated_value(xs, 5 * S, AggregateConfig()) == Sample(5 * S, 1, INTERP)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="increasing"):
        aggregate("Average", [Sample(S, 1.0), Sample(0, 2.0)], IVS)
    with pytest.raises(KeyError):
        aggregate("Range", SERIES, IVS)
    with pytest.raises(ValueError, match="start != end"):
        intervals(S, S, 0)
    with pytest.raises(ValueError, match="exceed"):
        intervals(0, (MAX_INTERVALS + 1) * S, S)


def test_one_interval_when_processing_interval_is_zero() -> None:
    assert intervals(0, 80 * S, 0) == [Interval(0, 80 * S)]
    assert run("Count", intervals(0, 80 * S, 0)) == [(0.0, 4, UNC | CALC)]


# --- Part 11 read rules --------------------------------------------------------------------


def test_raw_plan_follows_part11() -> None:
    assert plan_raw(0, 10, 0, False) == (0, 10, None, False, False)
    # start > end: a reverse read, not an error (Part 11, 6.5.3.2)
    assert plan_raw(10, 0, 5, True).reverse
    assert plan_raw(0, None, 5, True) == (0, TIME_MAX_US, 5, True, False)
    assert plan_raw(None, 10, 5, False) == (10, TIME_MIN_US, 5, False, False)
    for start, end, n in ((None, None, 0), (None, None, 5), (0, None, 0), (None, 10, 0)):
        with pytest.raises(HistoryArgumentError) as e:
            plan_raw(start, end, n, False)
        assert e.value.status == BAD_INVALID_TIMESTAMP_ARGUMENT


def test_processed_plan_follows_part11() -> None:
    assert plan_processed(0, 60 * S, 1000.0) == (0, 60 * S, S)
    assert plan_processed(60 * S, 0, 0.0) == (60 * S, 0, 0)
    for start, end in ((None, S), (S, None), (S, S)):
        with pytest.raises(HistoryArgumentError) as e:
            plan_processed(start, end, 1000.0)
        assert e.value.status == BAD_INVALID_TIMESTAMP_ARGUMENT
    with pytest.raises(HistoryArgumentError) as e:
        plan_processed(0, S, -1.0)
    assert e.value.status == BAD_INVALID_ARGUMENT


def test_ticks_round_trip() -> None:
    assert us_to_ticks(0) == 116_444_736_000_000_000
    assert ticks_to_us(0) == TIME_MIN_US
    assert ticks_to_us(us_to_ticks(1_764_633_600_123_456)) == 1_764_633_600_123_456


# --- properties ---------------------------------------------------------------------------

_status = st.sampled_from([0, 0, 0, BAD, 0x4000_0000, 0x80A4_0000])


@st.composite
def series(draw: st.DrawFn, constant: float | None = None) -> list[Sample]:
    times = sorted(draw(st.sets(st.integers(0, 200), min_size=0, max_size=40)))
    value = st.just(constant) if constant is not None else st.floats(-1e6, 1e6, allow_nan=False)
    return [Sample(t * S // 2, draw(value), draw(_status)) for t in times]


_ivs = st.builds(
    lambda a, w, p: intervals(a * S, (a + w) * S, p * S),
    st.integers(-10, 90),
    st.integers(1, 60),
    st.integers(0, 30),
)


@given(series(), _ivs)
def test_count_is_the_number_of_good_values(xs: list[Sample], ivs: list[Interval]) -> None:
    for iv, r in zip(ivs, aggregate("Count", xs, ivs), strict=True):
        n_in = [x for x in xs if iv.contains(x.t_us)]
        if not n_in:
            assert r.status == BAD_NO_DATA
        else:
            assert r.value == sum(1 for x in n_in if is_good(x.status))


@given(series(), _ivs)
def test_minimum_average_maximum_are_ordered(xs: list[Sample], ivs: list[Interval]) -> None:
    lo, avg, hi = (aggregate(n, xs, ivs) for n in ("Minimum", "Average", "Maximum"))
    for a, b, c in zip(lo, avg, hi, strict=True):
        assert is_bad(a.status) == is_bad(b.status) == is_bad(c.status)
        if not is_bad(b.status):
            assert isinstance(a.value, float) and isinstance(b.value, float) and isinstance(c.value, float)
            tol = 1e-9 * (1 + abs(b.value))  # the mean of n floats is rounded once
            assert a.value <= b.value + tol and b.value <= c.value + tol


@given(st.floats(-1e6, 1e6, allow_nan=False).flatmap(lambda c: st.tuples(st.just(c), series(c))), _ivs)
def test_time_average_of_a_constant_is_that_constant(
    cx: tuple[float, list[Sample]], ivs: list[Interval]
) -> None:
    c, xs = cx
    for r in aggregate("TimeAverage", xs, ivs, AggregateConfig(stepped=False)):
        if not is_bad(r.status):
            assert isinstance(r.value, float) and math.isclose(r.value, c, rel_tol=1e-12, abs_tol=1e-9)


@given(_ivs)
def test_intervals_tile_the_range(ivs: list[Interval]) -> None:
    for a, b in itertools.pairwise(ivs):
        assert a.end_us == b.start_us and not a.partial
    assert sum(iv.width_us for iv in ivs) == abs(ivs[-1].end_us - ivs[0].start_us)
