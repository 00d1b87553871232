"""The alarm summary of a tier (issue 15): counts, the ISA-18.2 rate on model time, the peak and
the flood, with hand-computed oracles for a scripted sequence and a Hypothesis property against a
brute-force recount; :func:`summary_values` maps it to the contract's nodes."""

from __future__ import annotations

from dataclasses import astuple

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from alarm_definitions import LEVEL, PVBAD, TRIP
from helpers import ROOT
from tanklab.alarms.manager import AlarmInput, AlarmManager
from tanklab.alarms.model import (
    AlarmSummary,
    ConditionCall,
    ConditionEvent,
    Method,
    ShelvingState,
)
from tanklab.alarms.summary import summary_values
from tanklab.config import load_site
from tanklab.tags import ALARM_SUMMARY_ITEMS, DataType, plc_tags, supervisor_tags, tags_by_path

NAMES = (LEVEL.name, PVBAD.name, TRIP.name)


def manager() -> AlarmManager:
    return AlarmManager((LEVEL, PVBAD, TRIP), event_prefix=b"T")


def counts(m: AlarmManager, t_s: float) -> tuple[int, ...]:
    """(active, unacked, shelved, suppressed, disabled, rate, peak, flood) at ``t_s``."""
    return astuple(m.summary(t_s))


def ack(m: AlarmManager, name: str, t_s: float) -> None:
    event_id = m.condition(name).latest_event_id
    status, _ = m.call(ConditionCall(name, Method.ACKNOWLEDGE, "op", event_id=event_id), t_s)
    assert status.value == "Good"


def call(m: AlarmManager, name: str, method: Method, t_s: float) -> None:
    status, _ = m.call(ConditionCall(name, method, "eng"), t_s)
    assert status.value == "Good", (name, method, status)


def test_a_scripted_sequence_has_its_hand_computed_summary() -> None:
    m = manager()
    inputs = {"T1Level": AlarmInput(0.5), "LIC1PvBad": AlarmInput(False), "T1Trip": AlarmInput(False)}
    m.scan(inputs, 0.0)
    assert counts(m, 0.0) == (0, 0, 0, 0, 0, 0, 0, False)
    assert m.rate_expiring() is None
    # t = 10: T1 at 0.15 m (Low) and LIC1's PV bad: two annunciated activations.
    m.scan({"T1Level": AlarmInput(0.15), "LIC1PvBad": AlarmInput(True)}, 10.0)
    assert counts(m, 10.0) == (2, 2, 0, 0, 0, 2, 2, False)
    assert m.rate_expiring() == 610.0
    ack(m, "T1Level", 20.0)
    assert counts(m, 20.0) == (2, 1, 0, 0, 0, 2, 2, False)
    call(m, "LIC1PvBad", Method.ONE_SHOT_SHELVE, 30.0)  # shelving now does not undo the rate
    assert counts(m, 30.0) == (2, 1, 1, 0, 0, 2, 2, False)
    m.scan({}, 40.0, manual={"LIC1"})  # LIC1 out of service: T1Level suppressed
    assert counts(m, 40.0) == (2, 1, 1, 1, 0, 2, 2, False)
    call(m, "T1Trip", Method.DISABLE, 50.0)
    assert counts(m, 50.0) == (2, 1, 1, 1, 1, 2, 2, False)
    m.scan({"T1Trip": AlarmInput(True)}, 60.0, manual={"LIC1"})  # tripped while disabled: no alarm
    assert counts(m, 60.0) == (2, 1, 1, 1, 1, 2, 2, False)
    call(m, "T1Trip", Method.ENABLE, 70.0)  # evaluated afresh: a new activation, annunciated
    assert counts(m, 70.0) == (3, 2, 1, 1, 0, 3, 3, False)
    # The window is (t - 600 s, t] of model time: the two at 10 s count until just before 610 s.
    assert counts(m, 609.999)[5] == 3
    assert counts(m, 610.0)[5:] == (1, 3, False)
    assert m.rate_expiring() == 670.0
    assert counts(m, 669.999)[5] == 1
    assert counts(m, 670.0) == (3, 2, 1, 1, 0, 0, 3, False)  # counts stand, the rate is gone
    assert m.rate_expiring() is None


def test_suppressed_and_shelved_activations_are_not_annunciated() -> None:
    m = manager()
    m.scan({"T1Level": AlarmInput(0.5)}, 0.0, manual={"LIC1"})
    m.scan({"T1Level": AlarmInput(0.15)}, 1.0, manual={"LIC1"})  # active while suppressed
    call(m, "LIC1PvBad", Method.ONE_SHOT_SHELVE, 2.0)
    m.scan({"LIC1PvBad": AlarmInput(True)}, 3.0, manual={"LIC1"})  # active while shelved
    assert counts(m, 3.0) == (2, 2, 1, 1, 0, 0, 0, False)
    assert m.rate_expiring() is None


def test_flood_begins_at_the_eleventh_activation_in_600_s() -> None:
    m = manager()
    for k in range(11):  # LIC1PvBad active at 0, 50, ..., 500 s (back to normal 10 s after each)
        t = 50.0 * k
        m.scan({"LIC1PvBad": AlarmInput(True)}, t)
        s = m.summary(t)
        assert (s.rate_per_10min, s.flood) == (k + 1, k == 10), k
        m.scan({"LIC1PvBad": AlarmInput(False)}, t + 10.0)
    assert m.rate_expiring() == 600.0
    assert astuple(m.summary(599.0))[5:] == (11, 11, True)
    assert astuple(m.summary(600.0))[5:] == (10, 11, False)  # the one at 0 s left: no flood
    assert m.rate_expiring() == 650.0


def test_summary_values_name_every_summary_node_of_the_tier_with_its_type() -> None:
    site = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
    s = AlarmSummary(1, 2, 3, 4, 5, 6, 7, False)
    for tier, tags in (("plc", plc_tags(site)), ("supervisor", supervisor_tags(site))):
        values = summary_values(tier, s)  # type: ignore[arg-type]
        root = "PLC" if tier == "plc" else "Supervisor"
        assert list(values) == [f"{root}.AlarmSummary.{i}" for i in ALARM_SUMMARY_ITEMS]
        assert list(values.values()) == [1, 2, 3, 4, 5, 6, 7, False]
        by_path = tags_by_path(tags)
        for path, value in values.items():
            want = DataType.BOOLEAN if isinstance(value, bool) else DataType.UINT32
            assert by_path[path].data_type is want, path


# ---- the property: the summary is a recount of the conditions and of the activations ----

OPS = st.one_of(
    st.tuples(
        st.just("scan"),
        st.sampled_from([0.0, 1.0, 50.0, 299.0, 599.0, 600.0, 601.0]),
        st.sampled_from([0.05, 0.15, 0.5, 0.85, 1.1]),
        st.booleans(),
        st.booleans(),
        st.booleans(),
    ),
    st.tuples(
        st.sampled_from(
            [
                Method.ACKNOWLEDGE,
                Method.CONFIRM,
                Method.ONE_SHOT_SHELVE,
                Method.TIMED_SHELVE,
                Method.UNSHELVE,
                Method.DISABLE,
                Method.ENABLE,
                "reset",
            ]
        ),
        st.sampled_from(NAMES),
        st.sampled_from([10.0, 300.0, 900.0]),
    ),
)


def annunciated(ev: ConditionEvent) -> bool:
    """An event that reports a new activation or a new limit of a condition shown to the operator
    (read from the event's words and snapshot, not from the manager's memory)."""
    c = ev.condition
    news = any(part.startswith(("active", "limit changed")) for part in ev.reason.split("; "))
    shown = c.enabled and c.active and c.shelving is ShelvingState.UNSHELVED and not c.suppressed
    return news and shown


@settings(max_examples=150, deadline=None)
@given(ops=st.lists(OPS, max_size=40))
def test_the_summary_equals_a_brute_force_recount(ops: list[tuple[object, ...]]) -> None:
    m = manager()
    t = 0.0
    times: list[float] = []  # model times of the annunciated activations
    peak = 0
    for op in ops:
        events: list[ConditionEvent] = []
        if op[0] == "scan":
            _, dt, x, pv_bad, trip, manual = op
            t += float(dt)  # type: ignore[arg-type]
            inputs = {
                "T1Level": AlarmInput(float(x)),  # type: ignore[arg-type]
                "LIC1PvBad": AlarmInput(bool(pv_bad)),
                "T1Trip": AlarmInput(bool(trip)),
            }
            events = m.scan(inputs, t, manual={"LIC1"} if manual else set())
        elif op[0] == "reset":
            events = m.reset(str(op[1]), t)
        else:
            method, name, shelve_s = op
            assert isinstance(method, Method) and isinstance(name, str)
            c = m.condition(name)
            request = ConditionCall(
                name,
                method,
                "eng",
                event_id=c.latest_event_id,
                shelving_time_s=float(shelve_s),  # type: ignore[arg-type]
            )
            _, events = m.call(request, t)
        for ev in events:
            if annunciated(ev):
                times.append(ev.t_s)
                peak = max(peak, sum(1 for tk in times if ev.t_s - 600.0 < tk <= ev.t_s))
        snaps = m.snapshots()
        on = [s for s in snaps if s.enabled]
        rate = sum(1 for tk in times if t - 600.0 < tk <= t)
        expected = AlarmSummary(
            active=sum(s.active for s in on),
            unacked=sum(not s.acked for s in on),
            shelved=sum(s.shelving is not ShelvingState.UNSHELVED for s in on),
            suppressed=sum(s.suppressed for s in on),
            disabled=len(snaps) - len(on),
            rate_per_10min=rate,
            peak_rate_per_10min=peak,
            flood=rate > 10,
        )
        assert m.summary(t) == expected
        in_window = [tk for tk in times if t - 600.0 < tk <= t]
        assert m.rate_expiring() == (min(in_window) + 600.0 if in_window else None)


@pytest.mark.parametrize("threshold", [0, 3])
def test_the_flood_threshold_is_the_managers(threshold: int) -> None:
    m = AlarmManager((PVBAD,), flood_threshold=threshold)
    for k in range(threshold + 1):
        m.scan({"LIC1PvBad": AlarmInput(True)}, 2.0 * k)
        assert m.summary(2.0 * k).flood is (k == threshold)
        m.scan({"LIC1PvBad": AlarmInput(False)}, 2.0 * k + 1.0)
