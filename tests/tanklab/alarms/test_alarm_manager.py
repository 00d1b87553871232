"""The alarm manager: deadband, delays and latching on model time, suppression, shelving expiry,
rates and flood, the booleans, ConditionRefresh's view and the retentive state."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from alarm_definitions import DB, LEVEL, LIMITS, PVBAD, TRIP
from tanklab.alarms.manager import AlarmInput, AlarmManager, classify_level
from tanklab.alarms.model import (
    AlarmDefinition,
    CallStatus,
    ConditionCall,
    ConditionEvent,
    LimitState,
    Method,
    ShelvingState,
)

HH, H, L, LL = LimitState.HIGH_HIGH, LimitState.HIGH, LimitState.LOW, LimitState.LOW_LOW


def manager(*defs: AlarmDefinition, **kw: object) -> AlarmManager:
    return AlarmManager(defs or (LEVEL, PVBAD, TRIP), event_prefix=b"M", **kw)  # type: ignore[arg-type]


def level(m: AlarmManager, x: float, t: float, good: bool = True, **kw: object) -> list[ConditionEvent]:
    return m.scan({"T1Level": AlarmInput(x, good)}, t, **kw)  # type: ignore[arg-type]


def reasons(events: list[ConditionEvent]) -> list[str]:
    return [e.reason for e in events]


# ---- step 1: the raw state with deadband ------------------------------------------------


@pytest.mark.parametrize(
    ("x", "good", "last", "expect"),
    [
        (0.5, True, (False,) * 4, None),
        (0.8, True, (False,) * 4, H),  # at the limit: active (>=, as today's booleans)
        (1.0, True, (False,) * 4, HH),
        (0.79, True, (False, True, False, False), H),  # inside the deadband: stays High
        (0.7799, True, (False, True, False, False), None),  # past H - d: normal
        (0.99, True, (True, True, False, False), HH),  # HH keeps its own deadband
        (0.97, True, (True, True, False, False), H),
        (1.2, False, (False,) * 4, HH),  # fail-safe: a bad but finite reading still trips HH
        (0.9, False, (False, True, False, False), None),  # a bad reading asserts no High
        (math.nan, True, (True,) * 4, None),
        (0.2, True, (False,) * 4, L),
        (0.21, True, (False, False, True, False), L),
        (0.1, True, (False,) * 4, LL),
        (0.115, True, (False, False, True, True), LL),
        (0.125, True, (False, False, True, True), L),
    ],
)
def test_classify_level(
    x: float, good: bool, last: tuple[bool, bool, bool, bool], expect: LimitState | None
) -> None:
    state, _ = classify_level(x, good, LIMITS, DB, last)
    assert state.limit is expect and state.active == (expect is not None)


def test_deadband_trace_by_hand() -> None:
    m = manager(LEVEL)
    trace = [(0.79, []), (0.80, ["active High"]), (0.781, []), (0.795, []), (0.779, ["returned to normal"])]
    for k, (x, expect) in enumerate(trace):
        assert reasons(level(m, x, float(k))) == expect


@settings(max_examples=100, deadline=None)
@given(xs=st.lists(st.floats(0.8 - DB + 1e-6, 0.95), min_size=1, max_size=60))
def test_no_chatter_inside_the_deadband(xs: list[float]) -> None:
    m = manager(LEVEL)
    assert reasons(level(m, 0.85, 0.0)) == ["active High"]
    for k, x in enumerate(xs, start=1):
        assert level(m, x, float(k)) == []
    assert m.condition("T1Level").active


# ---- step 2: delays on model time ------------------------------------------------------


def test_on_and_off_delay_by_hand() -> None:
    m = manager(replace(LEVEL, on_delay_s=5.0, off_delay_s=3.0))
    # t:   0    1    2    3    4    5    6    7    8    9    10   11   12
    xs = [0.5, 0.9, 0.9, 0.5, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.5, 0.5, 0.5, 0.5, 0.9, 0.5]
    got = {}
    for t, x in enumerate(xs):
        for ev in level(m, x, float(t)):
            got[t] = ev.reason
    # High from t=4 held 5 s: active at t=9; normal from t=10 held 3 s: back at t=13;
    # the dip at t=3 restarted the on-delay, the blip at t=14 never lasts.
    assert got == {9: "active High", 13: "returned to normal"}


def test_a_seeded_level_trace_with_delays_follows_the_delayed_rule() -> None:
    """A noisy level around High, scanned every 0.5 s: each activation comes after exactly
    on_delay_s of raw High, each return after off_delay_s of raw normal (raw: the deadband rule)."""
    on_s, off_s, ts = 4.0, 2.0, 0.5
    m = manager(replace(LEVEL, on_delay_s=on_s, off_delay_s=off_s))
    rng = np.random.default_rng(15)
    t = np.arange(0.0, 600.0, ts)
    xs = 0.8 + 0.05 * np.sin(2 * np.pi * t / 60.0) + rng.normal(0.0, 0.01, t.size)
    raw_high, last = [], (False,) * 4
    for x in xs:
        state, last = classify_level(float(x), True, LIMITS, DB, last)
        raw_high.append(state.active)
    events = [
        (ev.t_s, ev.condition.active) for k, x in enumerate(xs) for ev in level(m, float(x), float(t[k]))
    ]
    # the oracle: a change of the raw state that lasts the delay without going back
    expect, active, since = [], False, None
    for k, r in enumerate(raw_high):
        if r == active:
            since = None
            continue
        since = t[k] if since is None else since
        if t[k] - since >= (on_s if r else off_s):
            active, since = r, None
            expect.append((float(t[k]), r))
    assert events == expect
    assert 10 <= len(events) <= 40  # the trace does cross: about two activations a minute


# ---- steps 3-5: latching, suppression, shelving expiry -----------------------------------


def test_latched_trip_stays_until_reset_and_needs_confirmation() -> None:
    m = manager(TRIP)
    assert reasons(m.scan({"T1Trip": AlarmInput(True)}, 0.0)) == ["active"]
    assert m.reset("T1Trip", 0.5) == []  # input still off normal: nothing to reset
    assert m.scan({"T1Trip": AlarmInput(False)}, 1.0) == []
    assert m.condition("T1Trip").active
    assert reasons(m.reset("T1Trip", 2.0)) == ["returned to normal"]
    c = m.condition("T1Trip")
    assert (c.active, c.acked, c.confirmed, c.retain) == (False, False, False, True)
    status, _ = m.call(ConditionCall("T1Trip", Method.ACKNOWLEDGE, "op", c.latest_event_id), 3.0)
    assert status is CallStatus.GOOD and c.retain
    status, _ = m.call(ConditionCall("T1Trip", Method.CONFIRM, "op", c.latest_event_id), 4.0)
    assert status is CallStatus.GOOD and not c.retain


def test_suppressed_while_its_loop_is_in_manual() -> None:
    m = manager(LEVEL)
    assert reasons(level(m, 0.9, 0.0, manual={"LIC1"})) == ["suppressed", "active High"]
    assert m.summary(0.0).rate_per_10min == 0 and m.summary(0.0).suppressed == 1
    assert reasons(level(m, 0.9, 1.0)) == ["unsuppressed"]
    assert reasons(level(m, 0.9, 2.0, manual={"LIC2"})) == []


def test_timed_shelving_expires_in_the_scan() -> None:
    m = manager(LEVEL)
    status, events = m.call(ConditionCall("T1Level", Method.TIMED_SHELVE, "op", shelving_time_s=900.0), 10.0)
    assert status is CallStatus.GOOD and len(events) == 1
    assert m.scan({}, 909.0) == []
    assert reasons(m.scan({}, 910.0)) == ["timed shelving expired"]
    status, _ = m.call(ConditionCall("T1Level", Method.TIMED_SHELVE, "op", shelving_time_s=28801.0), 911.0)
    assert status is CallStatus.SHELVING_TIME_OUT_OF_RANGE


def test_unknown_names() -> None:
    m = manager()
    assert m.call(ConditionCall("Nope", Method.ENABLE, "op"), 0.0) == (CallStatus.UNKNOWN_CONDITION, [])
    with pytest.raises(KeyError):
        m.scan({"Nope": AlarmInput(True)}, 0.0)
    with pytest.raises(ValueError, match="unique"):
        AlarmManager((PVBAD, PVBAD))


# ---- summary, rate, flood -------------------------------------------------------------


def test_summary_counts_rate_and_flood() -> None:
    m = manager(LEVEL, PVBAD, TRIP)
    s = m.summary(0.0)
    assert (s.active, s.unacked, s.shelved, s.suppressed, s.rate_per_10min, s.flood) == (0, 0, 0, 0, 0, False)
    # 11 PvBad activations at t = 0, 20, ..., 200 (each a new annunciated alarm)
    for k in range(11):
        m.scan({"LIC1PvBad": AlarmInput(True)}, 20.0 * k)
        m.scan({"LIC1PvBad": AlarmInput(False)}, 20.0 * k + 10.0)
    assert m.summary(200.0).rate_per_10min == 11 and m.summary(200.0).flood
    assert m.summary(600.0).rate_per_10min == 10 and not m.summary(600.0).flood  # t=0 left the window
    m.scan({"T1Level": AlarmInput(0.9), "T1Trip": AlarmInput(True)}, 700.0)
    m.call(ConditionCall("T1Level", Method.ONE_SHOT_SHELVE, "op"), 700.0)
    s = m.summary(700.0)
    assert (s.active, s.unacked, s.shelved) == (2, 3, 1)
    assert s.rate_per_10min == 7  # in (100, 700]: PvBad at 120, 140, ..., 200 and the two new ones


@settings(max_examples=60, deadline=None)
@given(xs=st.lists(st.floats(0.0, 1.2), max_size=80))
def test_a_shelved_alarm_never_annunciates(xs: list[float]) -> None:
    m = manager(LEVEL)
    m.call(ConditionCall("T1Level", Method.TIMED_SHELVE, "op", shelving_time_s=3600.0), 0.0)
    for k, x in enumerate(xs):
        level(m, x, float(k))
        assert not m.condition("T1Level").annunciating
    assert m.summary(float(len(xs))).rate_per_10min == 0


# ---- booleans ---------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(
    steps=st.lists(st.tuples(st.one_of(st.floats(-0.1, 1.3), st.just(math.nan)), st.booleans()), max_size=40)
)
def test_booleans_without_deadband_are_todays(steps: list[tuple[float, bool]]) -> None:
    """H = good and x >= high, L = good and x <= low, HH = x >= high_high (any finite x)."""
    m = manager(replace(LEVEL, deadband_m=0.0), PVBAD)
    for k, (x, good) in enumerate(steps):
        m.scan({"T1Level": AlarmInput(x, good), "LIC1PvBad": AlarmInput(not good)}, float(k))
        assert m.booleans() == {
            "b.HH": x >= 1.0,
            "b.H": good and x >= 0.8,
            "b.L": good and x <= 0.2,
            "b.PvBad": not good,
        }


def test_booleans_follow_the_active_state_with_deadband_and_delay() -> None:
    m = manager(replace(LEVEL, on_delay_s=2.0))
    level(m, 0.85, 0.0)
    assert not m.booleans()["b.H"]  # pending
    level(m, 0.85, 2.0)
    assert m.booleans()["b.H"]
    level(m, 0.79, 3.0)
    assert m.booleans()["b.H"]  # inside the deadband


def test_booleans_do_not_depend_on_the_order_of_the_limits() -> None:
    """A site may put its trip below its high switch (single_tank_short_sim: HH 0.25, H 0.27)."""
    m = manager(replace(LEVEL, limits_m=(0.25, 0.27, 0.015, None), deadband_m=0.0))
    level(m, 0.26, 0.0)
    assert m.condition("T1Level").limit is HH
    assert (m.booleans()["b.HH"], m.booleans()["b.H"]) == (True, False)


# ---- refresh and ids -------------------------------------------------------------------


def test_retained_gives_the_latest_event_id_for_refresh() -> None:
    m = manager()
    m.scan({"T1Level": AlarmInput(0.9), "LIC1PvBad": AlarmInput(True)}, 0.0)
    m.scan({"LIC1PvBad": AlarmInput(False)}, 1.0)
    c = m.condition("LIC1PvBad")
    status, _ = m.call(ConditionCall("LIC1PvBad", Method.ACKNOWLEDGE, "op", c.latest_event_id), 2.0)
    assert status is CallStatus.GOOD
    refreshed = m.retained()
    assert [e.condition.name for e in refreshed] == ["T1Level"]
    ev = refreshed[0]
    assert ev.event_id == m.condition("T1Level").latest_event_id
    status, _ = m.call(ConditionCall("T1Level", Method.ACKNOWLEDGE, "op", ev.event_id), 3.0)
    assert status is CallStatus.GOOD
    assert [s.name for s in m.snapshots()] == ["T1Level", "LIC1PvBad", "T1Trip"]


@settings(max_examples=50, deadline=None)
@given(steps=st.lists(st.tuples(st.floats(0.0, 1.2), st.booleans(), st.booleans()), max_size=60))
def test_event_ids_are_unique_and_prefixed(steps: list[tuple[float, bool, bool]]) -> None:
    m = manager()
    ids = []
    for k, (x, bad, trip) in enumerate(steps):
        inputs = {"T1Level": AlarmInput(x), "LIC1PvBad": AlarmInput(bad), "T1Trip": AlarmInput(trip)}
        ids += [e.event_id for e in m.scan(inputs, float(k))]
        ids += [e.event_id for e in m.reset("T1Trip", float(k))]
    assert len(set(ids)) == len(ids) == m.ids.count
    assert all(i.startswith(b"M") for i in ids)


# ---- retentive memory -----------------------------------------------------------------


def test_retain_round_trip_through_json() -> None:
    m = manager()
    m.scan({"T1Level": AlarmInput(0.9), "T1Trip": AlarmInput(True)}, 0.0)
    m.scan({"T1Trip": AlarmInput(False)}, 1.0)  # latched
    lvl = m.condition("T1Level")
    m.call(ConditionCall("T1Level", Method.ACKNOWLEDGE, "op", lvl.latest_event_id, "seen"), 2.0)
    m.call(ConditionCall("T1Level", Method.TIMED_SHELVE, "op", shelving_time_s=100.0), 3.0)
    m.call(ConditionCall("LIC1PvBad", Method.DISABLE, "eng"), 4.0)
    data = json.loads(json.dumps(m.to_retain()))
    n = manager()
    assert n.from_retain(data) == []
    for a, b in zip(m.snapshots(), n.snapshots(), strict=True):
        assert replace(a, time_s=0.0, unshelve_time_s=0.0) == replace(b, time_s=0.0, unshelve_time_s=0.0)
    # the restart continues: no new activation (still acked), the trip still latched
    events = n.scan(
        {"T1Level": AlarmInput(0.9), "T1Trip": AlarmInput(False), "LIC1PvBad": AlarmInput(True)}, 5.0
    )
    assert events == []
    assert n.condition("T1Trip").active and n.condition("T1Level").acked
    assert reasons(n.scan({}, 103.0)) == ["timed shelving expired"]
    assert n.condition("T1Level").comment == "seen"


def test_restart_events_give_restored_retained_conditions_an_acknowledgeable_event_id() -> None:
    m = manager()
    m.scan({"T1Level": AlarmInput(0.9), "T1Trip": AlarmInput(True)}, 0.0)
    n = manager()
    assert n.from_retain(json.loads(json.dumps(m.to_retain()))) == []
    assert n.retained() == ()  # restored, but no event of this process yet
    events = n.restart_events(7.0)
    assert [e.condition.name for e in events] == ["T1Level", "T1Trip"]
    assert reasons(events) == ["restored at warm restart"] * 2
    assert all(e.t_s == 7.0 and e.condition.active and not e.condition.acked for e in events)
    assert [e.event_id for e in n.retained()] == [e.event_id for e in events]
    assert n.restart_events(8.0) == []  # once
    lvl = n.condition("T1Level")
    status, _ = n.call(ConditionCall("T1Level", Method.ACKNOWLEDGE, "op", events[0].event_id, ""), 9.0)
    assert status is CallStatus.GOOD and lvl.acked


def test_retain_refuses_bad_entries_whole() -> None:
    m = manager()
    good = m.to_retain()["conditions"]
    bad = {
        "T1Level": {**good["T1Level"], "active": True, "limit": None},
        "LIC1PvBad": {**good["LIC1PvBad"], "acked": "yes"},
        "T1Trip": {**good["T1Trip"], "shelving": "TimedShelved", "shelved_until_s": None},
        "Gone": good["T1Trip"],
    }
    skipped = m.from_retain({"conditions": bad})
    assert len(skipped) == 4 and any("Gone" in s for s in skipped)
    assert [s.retain for s in m.snapshots()] == [False, False, False]
    assert m.condition("T1Trip").shelving is ShelvingState.UNSHELVED


def test_a_primed_boolean_is_replaced_by_the_first_input_without_an_event() -> None:
    m = manager(replace(PVBAD, off_delay_s=10.0))
    m.prime("LIC1PvBad", True)
    assert m.booleans() == {"b.PvBad": True} and not m.condition("LIC1PvBad").active
    assert m.scan({"LIC1PvBad": AlarmInput(False)}, 0.0) == []  # no off-delay, no event
    assert m.booleans() == {"b.PvBad": False}
    m.prime("LIC1PvBad", True)
    assert reasons(m.scan({"LIC1PvBad": AlarmInput(True)}, 1.0)) == ["active"]


def test_the_rate_memory_stays_bounded_without_summaries() -> None:
    m = manager(PVBAD)
    for k in range(2000):  # one activation every 20 s for 11 h, nobody asks for the summary
        m.scan({"LIC1PvBad": AlarmInput(k % 2 == 0)}, 10.0 * k)
    assert len(m._annunciated) <= 600 / 20 + 1
    assert m.summary(19990.0).rate_per_10min == 30
