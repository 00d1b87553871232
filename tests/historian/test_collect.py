"""The collection core: staleness, gap markers, the bounded buffer, retention steps (pure).

Oracles are hand-computed; the buffer's invariants are Hypothesis properties.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from historian.collect import (
    BAD_NO_COMMUNICATION,
    CLOCK_PATHS,
    Backlog,
    RetentionPlan,
    TierWatch,
    recorded_tags,
    restart_markers,
    source_tiers,
    stale_after_s,
    tier_period_s,
)
from tanklab import paths
from tanklab.history.model import EventRecord, Sample
from tanklab_testing.sites import SITE

BAD_OUT_OF_RANGE = 0x803C_0000


def watch(stale: float = 2.0) -> TierWatch:
    return TierWatch("plc", ("PLC.LIC1.PV", "PLC.Status.Scan"), "PLC.Status.Scan", stale)


def test_stale_after_takes_the_longer_interval_and_the_one_second_floor() -> None:
    # 8 intervals of max(0.25 s, 1 s / 20) = 2 s
    assert stale_after_s(0.25, 8, 1.0, 20.0) == 2.0
    # at speed 1 the scan is the longer: 8 * 1 s
    assert stale_after_s(0.25, 8, 1.0, 1.0) == 8.0
    # 2 * max(0.1, 1/100) = 0.2 s, floored to 1 s
    assert stale_after_s(0.1, 2, 1.0, 100.0) == 1.0
    # the supervisor's 5 s sample at speed 10: 3 * 0.5 s = 1.5 s
    assert stale_after_s(0.2, 3, 5.0, 10.0) == 1.5


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_stale_after_refuses_a_bad_interval(bad: float) -> None:
    with pytest.raises(ValueError, match="publishing_interval_s"):
        stale_after_s(bad, 8, 1.0, 1.0)
    with pytest.raises(ValueError, match="speed"):
        stale_after_s(0.25, 8, 1.0, bad)


def test_a_tier_whose_clock_stops_is_stale_after_the_timeout_and_marked_once() -> None:
    w = watch(stale=2.0)
    w.connect(10.0)
    w.receive("PLC.Status.Scan", 5, 0, 1_000_000, 10.1)
    w.receive("PLC.LIC1.PV", 0.4, 0, 1_000_000, 10.1)
    w.receive("PLC.Status.Scan", 6, 0, 2_000_000, 11.0)
    assert not w.stale(13.0)  # 2.0 s after the last advance: not yet (strictly more)
    # a value that changes is no proof of life, only the clock is
    w.receive("PLC.LIC1.PV", 0.5, 0, 2_500_000, 12.5)
    assert w.stale(13.01)
    gap = w.lost()
    marker = Sample(2_500_001, None, BAD_NO_COMMUNICATION)
    assert gap == {"PLC.LIC1.PV": [marker], "PLC.Status.Scan": [marker]}
    assert (w.connected, w.gaps, w.samples) == (False, 1, 4)
    # lost again (the reconnection failed): no second marker
    assert w.lost() == {}
    assert w.gaps == 1


def test_a_gap_closes_when_the_clock_advances_again() -> None:
    w = watch()
    w.connect(0.0)
    w.receive("PLC.Status.Scan", 1, 0, 1_000_000, 0.1)
    assert w.lost()
    # the restarted PLC: subscribed again, its first value sets the clock, the second advances it
    w.connect(5.0)
    w.receive("PLC.Status.Scan", 0, 0, 9_000_000, 5.1)
    assert w.gap_open  # one value is not an advance
    w.receive("PLC.Status.Scan", 1, 0, 9_050_000, 5.2)
    assert not w.gap_open
    assert w.lost()["PLC.LIC1.PV"] == [Sample(9_050_001, None, BAD_NO_COMMUNICATION)]
    assert w.gaps == 2


def test_a_bad_clock_value_is_no_advance() -> None:
    w = watch(stale=1.0)
    w.connect(0.0)
    w.receive("PLC.Status.Scan", 3, BAD_OUT_OF_RANGE, 1, 0.5)
    assert w.stale(1.01)


def test_nothing_received_marks_nothing() -> None:
    w = watch()
    w.connect(0.0)
    assert w.lost() == {}
    assert w.gaps == 0


def test_restart_markers_follow_each_good_newest_sample() -> None:
    last = {
        "A": Sample(100, 1.0, 0),
        "B": Sample(200, None, BAD_NO_COMMUNICATION),
        "C": Sample(300, 2.0, 0x4000_0000),  # Uncertain: still recorded data, so marked
    }
    assert restart_markers(last) == {
        "A": [Sample(101, None, BAD_NO_COMMUNICATION)],
        "C": [Sample(301, None, BAD_NO_COMMUNICATION)],
    }


def test_recorded_tags_are_the_scalar_variables_without_identity() -> None:
    plc = {t.path for t in recorded_tags(SITE, "plc")}
    assert {paths.plc.loop("LIC1").pv, paths.plc.scan, paths.plc.loop("LIC1").mode, paths.plc.io_fault} <= plc
    assert paths.plc.loop("LIC1").set_gains not in plc
    assert not plc & set(paths.identity_paths("plc").values())
    sup = {t.path for t in recorded_tags(SITE, "supervisor")}
    assert paths.supervisor.mpc_planned_mv not in sup  # an array
    assert paths.supervisor.mode in sup
    assert source_tiers(SITE) == ["plant", "plc", "supervisor"]
    for tier in source_tiers(SITE):
        assert CLOCK_PATHS[tier] in {t.path for t in recorded_tags(SITE, tier)}
    assert tier_period_s(SITE, "plc") == SITE.plc.scan_period_s  # type: ignore[union-attr]


def event(n: int) -> EventRecord:
    return EventRecord(n, bytes([n % 256]), "i=2041", "PLC", 100, "m", {})


def test_backlog_drops_the_oldest_and_gives_back_in_order() -> None:
    b = Backlog(capacity=3)
    assert b.add_samples({"A": [Sample(1, 1.0), Sample(2, 2.0)]}) == 0
    assert b.add_events([event(3)]) == 0
    assert b.add_samples({"B": [Sample(4, 4.0)]}) == 1  # A@1 goes
    batch = b.take(2)
    assert batch.samples == {"A": [Sample(2, 2.0)]}
    assert batch.events == [event(3)]
    assert len(b) == 1
    b.add_samples({"C": [Sample(5, 5.0)]})
    # the store refused: back at the front; one over capacity, the batch's oldest (A@2) goes
    assert b.give_back(batch) == 1
    assert b.take(10).items == [event(3), ("B", Sample(4, 4.0)), ("C", Sample(5, 5.0))]
    assert b.dropped == 2


def test_backlog_needs_room() -> None:
    with pytest.raises(ValueError, match="capacity"):
        Backlog(capacity=0)


@given(
    capacity=st.integers(1, 20),
    adds=st.lists(st.integers(0, 15), max_size=20),
    takes=st.lists(st.integers(0, 10), max_size=20),
)
def test_backlog_keeps_the_newest_in_order_and_counts_every_drop(
    capacity: int, adds: list[int], takes: list[int]
) -> None:
    b = Backlog(capacity)
    n = 0
    taken: list[int] = []
    for i, k in enumerate(adds):
        b.add_samples({"T": [Sample(n + j, float(n + j)) for j in range(k)]})
        n += k
        assert len(b) <= capacity
        if i < len(takes):
            taken += [item[1].t_us for item in b.take(takes[i]).items if isinstance(item, tuple)]
    rest = [item[1].t_us for item in b.take(10**6).items if isinstance(item, tuple)]
    # every record added was taken or dropped, once; what came out came out in order
    assert len(taken) + len(rest) + b.dropped == n
    out = taken + rest
    assert out == sorted(out) and len(set(out)) == len(out)
    # what remained at the end is the newest
    if rest:
        assert rest[-1] == n - 1


def test_retention_steps_until_done_then_waits_a_pass() -> None:
    plan = RetentionPlan(days=2.0, every_s=60.0)
    assert plan.cutoff_us(10 * 86_400_000_000) == 8 * 86_400_000_000
    assert plan.due(0.0)
    plan.stepped(done=False, now_s=0.0)
    assert plan.due(0.5)  # a pass under way goes on between the next batches
    plan.stepped(done=True, now_s=1.0)
    assert not plan.due(60.9)
    assert plan.due(61.0)
