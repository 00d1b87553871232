"""One condition's Part 9 state machine: each transition and every CallStatus, hand-computed."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from alarm_definitions import LEVEL, TRIP
from tanklab.alarms.condition import Condition, EventIds, ProcessState
from tanklab.alarms.model import (
    AlarmDefinition,
    CallStatus,
    ConditionCall,
    LimitState,
    Method,
    ShelvingState,
)

HH, H, L, LL = LimitState.HIGH_HIGH, LimitState.HIGH, LimitState.LOW, LimitState.LOW_LOW
MAX_S = 3600.0


def make(d: AlarmDefinition = LEVEL) -> Condition:
    return Condition(d, EventIds(b"P"), max_shelving_time_s=MAX_S)


def call(c: Condition, method: Method, t_s: float = 0.0, **kw: object) -> tuple[CallStatus, int]:
    status, events = c.call(ConditionCall(condition=c.name, method=method, user="alice", **kw), t_s)  # type: ignore[arg-type]
    return status, len(events)


def ack(c: Condition, t_s: float = 0.0, event_id: bytes | None = None, comment: str = "") -> CallStatus:
    eid = c.latest_event_id if event_id is None else event_id
    return call(c, Method.ACKNOWLEDGE, t_s, event_id=eid, comment=comment)[0]


def test_initial_state_is_normal_acked_not_retained() -> None:
    s = make().snapshot()
    assert (s.enabled, s.active, s.acked, s.confirmed, s.retain) == (True, False, True, True, False)
    assert (s.severity, s.last_severity) == (500, 500)
    assert s.message == "T1 level: normal"
    assert s.shelving is ShelvingState.UNSHELVED and s.limit_state is None


def test_activation_limit_change_and_return() -> None:
    c = make()
    (ev,) = c.update_process(ProcessState(True, H), 10.0)
    s = ev.condition
    assert (s.active, s.acked, s.retain, s.limit_state) == (True, False, True, H)
    assert (s.severity, s.last_severity, s.time_s) == (500, 500, 10.0)
    assert s.message == "T1 level: High" and ev.reason == "active High"
    assert ev.event_id == b"P" + (1).to_bytes(8, "big")
    assert ack(c, 11.0) is CallStatus.GOOD and c.acked
    (ev,) = c.update_process(ProcessState(True, HH), 12.0)  # a new limit: unacked again
    assert (ev.condition.acked, ev.condition.severity, ev.condition.last_severity) == (False, 900, 500)
    assert ev.reason == "limit changed to HighHigh"
    (ev,) = c.update_process(ProcessState(False), 13.0)
    s = ev.condition
    assert (s.active, s.acked, s.retain, s.severity, s.last_severity) == (False, False, True, 500, 900)
    assert ack(c, 14.0) is CallStatus.GOOD
    assert not c.retain
    assert c.update_process(ProcessState(False), 15.0) == []  # no change, no event


def test_acknowledge_refusals() -> None:
    c = make()
    assert ack(c, event_id=b"nothing yet") is CallStatus.EVENT_ID_UNKNOWN
    (first,) = c.update_process(ProcessState(True, L), 1.0)
    c.set_quality(False, 2.0)  # a later event: the activation's id is stale now
    assert ack(c, event_id=first.event_id) is CallStatus.EVENT_ID_UNKNOWN
    assert call(c, Method.ACKNOWLEDGE, event_id=None)[0] is CallStatus.EVENT_ID_UNKNOWN
    assert not c.acked
    assert ack(c, comment="seen") is CallStatus.GOOD
    assert (c.comment, c.comment_user) == ("seen", "alice")
    assert ack(c) is CallStatus.ALREADY_ACKED
    assert ack(c, comment="") is CallStatus.ALREADY_ACKED and c.comment == "seen"


def test_confirm_after_ack_only_and_retain_until_confirmed() -> None:
    c = make(TRIP)
    c.update_process(ProcessState(True), 1.0)
    assert (c.acked, c.confirmed) == (False, False)
    eid = c.latest_event_id
    assert call(c, Method.CONFIRM, event_id=eid)[0] is CallStatus.NOT_CONFIRMABLE  # not acked yet
    assert call(c, Method.CONFIRM, event_id=b"x")[0] is CallStatus.EVENT_ID_UNKNOWN
    assert ack(c) is CallStatus.GOOD
    c.update_process(ProcessState(False), 2.0)
    assert c.retain and not c.active  # acked, inactive, still to be confirmed
    status, n = call(c, Method.CONFIRM, 3.0, event_id=c.latest_event_id, comment="ok")
    assert (status, n) == (CallStatus.GOOD, 1)
    assert c.confirmed and not c.retain and c.comment == "ok"
    assert call(c, Method.CONFIRM, event_id=c.latest_event_id)[0] is CallStatus.ALREADY_CONFIRMED


def test_confirm_of_a_definition_without_confirmation_is_invalid() -> None:
    c = make()
    c.update_process(ProcessState(True, H), 1.0)
    ack(c)
    assert call(c, Method.CONFIRM, event_id=c.latest_event_id) == (CallStatus.NOT_CONFIRMABLE, 0)


def test_add_comment_needs_the_latest_event_id() -> None:
    c = make()
    c.update_process(ProcessState(True, H), 1.0)
    assert call(c, Method.ADD_COMMENT, event_id=b"old", comment="x")[0] is CallStatus.EVENT_ID_UNKNOWN
    status, n = call(c, Method.ADD_COMMENT, 2.0, event_id=c.latest_event_id, comment="checking")
    assert (status, n) == (CallStatus.GOOD, 1)
    assert (c.comment, c.comment_user, c.acked) == ("checking", "alice", False)


def test_disable_raises_only_its_own_event_and_enable_reevaluates() -> None:
    c = make()
    c.update_process(ProcessState(True, H), 1.0)
    assert call(c, Method.DISABLE, 2.0) == (CallStatus.GOOD, 1)
    assert not c.retain and c.latest is not None and c.latest.reason == "disabled by alice"
    assert call(c, Method.DISABLE) == (CallStatus.ALREADY_DISABLED, 0)
    assert c.update_process(ProcessState(True, HH), 3.0) == []
    assert c.set_quality(False, 3.0) == [] and c.set_suppressed(True, 3.0) == []
    for m in (
        Method.ACKNOWLEDGE,
        Method.CONFIRM,
        Method.ADD_COMMENT,
        Method.ONE_SHOT_SHELVE,
        Method.UNSHELVE,
    ):
        assert call(c, m, event_id=c.latest_event_id) == (CallStatus.DISABLED, 0)
    assert call(c, Method.TIMED_SHELVE, shelving_time_s=10.0) == (CallStatus.DISABLED, 0)
    status, events = c.call(ConditionCall("T1Level", Method.ENABLE, "bob"), 4.0)
    assert status is CallStatus.GOOD and len(events) == 1
    s = events[0].condition
    assert events[0].reason == "enabled by bob; active HighHigh"
    assert (s.enabled, s.active, s.limit_state, s.acked, s.retain) == (True, True, HH, False, True)
    assert call(c, Method.ENABLE) == (CallStatus.ALREADY_ENABLED, 0)


def test_enable_while_normal_is_normal_and_acked() -> None:
    c = make()
    c.update_process(ProcessState(True, H), 1.0)  # unacked ...
    call(c, Method.DISABLE, 2.0)
    c.update_process(ProcessState(False), 3.0)  # ... gone while disabled
    call(c, Method.ENABLE, 4.0)
    assert (c.active, c.acked, c.retain) == (False, True, False)


def test_one_shot_shelving_ends_when_the_alarm_returns_to_normal() -> None:
    c = make()
    c.update_process(ProcessState(True, H), 1.0)
    assert call(c, Method.ONE_SHOT_SHELVE, 2.0) == (CallStatus.GOOD, 1)
    assert c.shelving is ShelvingState.ONE_SHOT and not c.annunciating
    assert call(c, Method.ONE_SHOT_SHELVE) == (CallStatus.ALREADY_SHELVED, 0)
    (ev,) = c.update_process(ProcessState(False), 3.0)
    assert ev.condition.shelving is ShelvingState.UNSHELVED
    assert ev.reason == "returned to normal; one-shot shelving ended"


def test_one_shot_shelved_while_normal_lasts_through_the_next_activation() -> None:
    c = make()
    call(c, Method.ONE_SHOT_SHELVE, 0.0)
    c.update_process(ProcessState(True, L), 1.0)
    assert c.active and c.shelving is ShelvingState.ONE_SHOT and not c.annunciating
    c.update_process(ProcessState(False), 2.0)
    assert c.shelving is ShelvingState.UNSHELVED


def test_timed_shelving_range_and_expiry_on_model_time() -> None:
    c = make()
    for bad in (0.0, -1.0, MAX_S + 0.001, math.inf, math.nan):
        assert call(c, Method.TIMED_SHELVE, shelving_time_s=bad) == (CallStatus.SHELVING_TIME_OUT_OF_RANGE, 0)
    assert call(c, Method.TIMED_SHELVE, 100.0, shelving_time_s=MAX_S) == (CallStatus.GOOD, 1)
    c.tick(100.0 + MAX_S / 2)
    assert c.snapshot().unshelve_time_s == pytest.approx(MAX_S / 2)
    assert call(c, Method.TIMED_SHELVE, shelving_time_s=10.0) == (CallStatus.ALREADY_SHELVED, 0)
    assert c.tick(100.0 + MAX_S - 0.5) == []
    (ev,) = c.tick(100.0 + MAX_S)
    assert ev.reason == "timed shelving expired" and ev.condition.shelving is ShelvingState.UNSHELVED


def test_shelving_kinds_switch_both_ways_and_unshelve() -> None:
    c = make()
    assert call(c, Method.UNSHELVE) == (CallStatus.NOT_SHELVED, 0)
    call(c, Method.ONE_SHOT_SHELVE, 0.0)
    assert call(c, Method.TIMED_SHELVE, 1.0, shelving_time_s=60.0) == (CallStatus.GOOD, 1)
    assert c.shelving is ShelvingState.TIMED and c.shelved_until_s == 61.0
    assert call(c, Method.ONE_SHOT_SHELVE, 2.0) == (CallStatus.GOOD, 1)
    assert c.shelving is ShelvingState.ONE_SHOT and c.snapshot().unshelve_time_s == 0.0
    assert call(c, Method.UNSHELVE, 3.0) == (CallStatus.GOOD, 1)
    assert c.shelving is ShelvingState.UNSHELVED


def test_one_shot_shelving_ends_after_the_maximum_time() -> None:
    c = make()
    c.update_process(ProcessState(True, H), 0.0)
    call(c, Method.ONE_SHOT_SHELVE, 10.0)
    status, n = call(c, Method.ACKNOWLEDGE, 10.0 + MAX_S, event_id=c.latest_event_id)
    # the expiry comes first (its event), so the id the client holds is stale by then
    assert (status, n) == (CallStatus.EVENT_ID_UNKNOWN, 1)
    assert c.shelving is ShelvingState.UNSHELVED


def test_shelving_neither_blocks_acknowledge_nor_events() -> None:
    c = make()
    call(c, Method.TIMED_SHELVE, 0.0, shelving_time_s=60.0)
    (ev,) = c.update_process(ProcessState(True, H), 1.0)
    assert ev.condition.shelving is ShelvingState.TIMED and not c.annunciating
    assert ack(c, 2.0) is CallStatus.GOOD


def test_quality_and_suppression_raise_events() -> None:
    c = make()
    (ev,) = c.set_quality(False, 1.0)
    assert not ev.condition.quality_good and ev.reason == "quality bad"
    (ev,) = c.set_suppressed(True, 2.0)
    assert ev.condition.suppressed
    c.update_process(ProcessState(True, H), 3.0)
    assert c.active and not c.annunciating


def test_restore_takes_the_state_without_an_event() -> None:
    c = make(TRIP)
    c.restore(
        ProcessState(True),
        enabled=True,
        acked=True,
        confirmed=False,
        comment="c",
        comment_user="u",
        shelving=ShelvingState.TIMED,
        shelved_until_s=50.0,
    )
    assert c.latest is None and c.retain and c.severity == 900
    assert c.tick(50.0)[0].condition.shelving is ShelvingState.UNSHELVED


# ---- properties ------------------------------------------------------------------------

_STATES = st.sampled_from(
    [ProcessState(False), ProcessState(True, H), ProcessState(True, HH), ProcessState(True, L)]
)
_STEP = st.one_of(
    st.tuples(st.just("process"), _STATES),
    st.tuples(st.just("quality"), st.booleans()),
    st.tuples(st.just("suppress"), st.booleans()),
    st.tuples(st.just("call"), st.sampled_from(list(Method))),
    st.tuples(st.just("stale"), st.sampled_from([Method.ACKNOWLEDGE, Method.CONFIRM, Method.ADD_COMMENT])),
)


@settings(max_examples=150, deadline=None)
@given(steps=st.lists(_STEP, max_size=40), confirm=st.booleans())
def test_properties_of_any_sequence(steps: list[tuple[str, object]], confirm: bool) -> None:
    """Retain is false iff (inactive, acked, confirmed-or-not-required) or disabled; EventIds
    unique; every event carries the latest id; refused calls change nothing."""
    d = TRIP if confirm else LEVEL
    c = make(d)
    seen: set[bytes] = set()
    t = 0.0
    for kind, arg in steps:
        t += 7.0
        if kind == "process":
            assert isinstance(arg, ProcessState)
            state = arg if d is LEVEL else ProcessState(arg.active)
            events = c.update_process(state, t)
        elif kind == "quality":
            events = c.set_quality(bool(arg), t)
        elif kind == "suppress":
            events = c.set_suppressed(bool(arg), t)
        else:
            assert isinstance(arg, Method)
            eid = b"stale" if kind == "stale" else c.latest_event_id
            before = c.snapshot(t)
            status, events = c.call(ConditionCall(d.name, arg, "u", eid, "x", 600.0), t)
            if status is not CallStatus.GOOD:
                assert events == [] and c.snapshot(t) == before
            if kind == "stale":
                assert status in (
                    CallStatus.EVENT_ID_UNKNOWN,
                    CallStatus.DISABLED,
                    CallStatus.NOT_CONFIRMABLE,
                )
        for ev in events:
            assert ev.event_id not in seen
            seen.add(ev.event_id)
        if events:
            assert c.latest_event_id == events[-1].event_id
        expect_retain = c.enabled and not (c.acked and (c.confirmed or not d.confirm) and not c.active)
        assert c.retain == expect_retain == c.snapshot(t).retain
        if not d.confirm:
            assert c.confirmed
        assert 1 <= c.severity <= 1000 and 1 <= c.last_severity <= 1000
        if c.shelving is not ShelvingState.UNSHELVED or c.suppressed:
            assert not c.annunciating
