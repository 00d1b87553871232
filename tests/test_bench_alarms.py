"""The alarm-flood benchmark's pure parts (benchmarks.alarms, benchmarks.report.alarms_section).

The measurement runs real plant and PLC processes (``python -m benchmarks.run --only alarms``);
here: the generated site raises its whole flood in one scan of the PLC program, and the goals and
the section are judged and rendered from hand-made rounds with hand-computed oracles (the
reference-speed scaling of decision 0036 included). No wall-clock measurement.
"""

from __future__ import annotations

import math

import numpy as np
from benchmarks import run
from benchmarks.alarms import (
    BIAS_M,
    N_CONDITIONS,
    ONE_CALL,
    READY_M,
    SEPARATE,
    AlarmsResult,
    Round,
    flood_conditions,
    flood_site,
)
from benchmarks.report.alarms_section import goals, markdown, overruns, rate, summary_goal
from benchmarks.stack import Lateness

from plc_emulator.program import PlcProgram, ScanInputs
from tanklab.alarms.definitions import plc_alarms
from tanklab.config import SiteConfig

SITE = SiteConfig.model_validate(flood_site())


def test_the_flood_site_is_25_energies_loops_at_equilibrium() -> None:
    assert SITE.tank_names == [f"T{i}" for i in range(1, 26)]
    assert SITE.supervisor is None and SITE.plc is not None
    assert [il.tank for il in SITE.plc.interlocks] == SITE.tank_names
    # 25 levels, 25 PvBad, IoFault, SupervisorLost, 25 trips
    assert len(plc_alarms(SITE)) == 77
    # equilibrium through the outlet: Q = mu a sqrt(2 g h) = 0.5 * 5e-5 * sqrt(2 * 9.81 * 0.4)
    q = 0.5 * 5e-5 * math.sqrt(2 * 9.81 * 0.4)
    for pump in SITE.plant.pumps:
        assert abs(pump.initial_command - q) < 1e-9
    assert sorted(flood_conditions()) == sorted(
        [f"T{i}Level" for i in range(1, 26)] + [f"T{i}Trip" for i in range(1, 26)]
    )


def test_the_bias_raises_the_whole_flood_in_one_scan_and_it_clears_with_the_reset() -> None:
    p = PlcProgram(SITE, alarm_event_prefix=b"bench")
    good = np.ones(25, dtype=bool)

    def scan(level_m: float) -> list[tuple[str, str]]:
        p.scan(ScanInputs(p.next_scan_t_s, np.full(25, level_m), good))
        return sorted((e.condition.name, e.reason) for e in p.alarms.events)

    assert scan(0.4) == [] and scan(0.4) == []
    # the lowest level a round starts from, plus the bias (the range's top is 0.62 m)
    assert READY_M + BIAS_M < 0.62
    flood = scan(READY_M + BIAS_M)
    assert len(flood) == N_CONDITIONS == 50
    assert {n for n, _ in flood} == set(flood_conditions())
    assert {r for n, r in flood if n.endswith("Level")} == {"active HighHigh"}
    assert {r for n, r in flood if n.endswith("Trip")} == {"active"}
    # fault cleared: the levels return; the latched trips only after the reset
    back = scan(0.38)
    assert back == sorted((f"T{i}Level", "returned to normal") for i in range(1, 26))
    p.reset_interlocks()
    assert scan(0.38) == sorted((f"T{i}Trip", "returned to normal") for i in range(1, 26))


def _round(index: int, mode: str, activation_s: float, ack_s: float, **kw: float | int | str) -> Round:
    r = Round(
        index,
        mode,
        activation_events=50,
        activation_times=1,
        activation_latency_s=activation_s,
        activation_scan_s=0.040,
        activation_scan_alarms=25,
        activation_cpu_s=0.020,
        baseline_scan_s=0.030,
        ack_call_s=ack_s / 2,
        ack_good=50,
        ack_events=50,
        ack_latency_s=ack_s,
        ack_scan_s=0.030,
        ack_cpu_s=0.030,
        return_events=50,
        confirm_events=25,
        overruns_before=3,
        overruns_after=3,
        summary_rate=50 * index,
        summary_flood=True,
        summary_unacked_after_ack=0,
    )
    for k, v in kw.items():
        setattr(r, k, v)
    return r


def _result(speed_ms: float = 22.4, **kw: object) -> AlarmsResult:
    res = AlarmsResult(
        rounds=[
            _round(1, ONE_CALL, 0.100, 0.150),
            _round(2, SEPARATE, 0.300, 0.400),
            _round(3, ONE_CALL, 0.300, 0.250, activation_scan_s=0.060),
            _round(4, SEPARATE, 0.200, 1.600),
        ],
        site_conditions=77,
        speed_ms=speed_ms,
        overruns_start=3,
        overruns_end=3,
        plc=Lateness("PLC", 1.0, math.nan, scans=80, overruns=0, p50_ms=1.5, p99_ms=30.0),
        startup_s=30.0,
        wall_s=90.0,
    )
    for k, v in kw.items():
        setattr(res, k, v)
    return res


def _by_name(res: AlarmsResult) -> dict[str, tuple[str, bool | None]]:
    return {g.name: (g.measured, g.met) for g in goals(res)}


def test_goals_at_the_reference_speed() -> None:
    g = _by_name(_result())  # speed reference 22.4 ms = twice the 11.2 ms reference: times x 0.5
    assert g["alarm flood at a 1 s scan: PLC overruns"] == ("0 in 4 rounds", True)
    # activation scans 40, 40, 60, 40 ms: median 40; the longest, 60 ms, is 30 ms at the reference speed
    (note,) = [x.note for x in goals(_result()) if x.name.endswith("PLC overruns")]
    assert note.endswith(
        "activation scan 40 ms median, 60 ms max as measured, 30 ms max at the reference speed"
    )
    assert g["50 alarms raised in one scan"] == ("50 or more in one scan in 4 / 4 rounds", True)
    assert g["every activation and acknowledged event received"] == (
        "200 / 200 activations, 200 / 200 acknowledged",
        True,
    )
    # worst activation 300 ms -> 150 ms at the reference speed
    assert g["activation burst: last event after its scan"] == (
        "150 ms at the reference speed (measured 300 ms; speed reference 22.4 ms)",
        True,
    )
    assert g["acknowledge all (one Call): last acknowledged event"][1] is True  # 250 -> 125 ms
    # separate Calls: worst 1.6 s -> 0.8 s at the reference speed, under the 1 s scan
    assert g["acknowledge all (separate Calls): last acknowledged event"] == (
        "800 ms at the reference speed (measured 1,600 ms; speed reference 22.4 ms)",
        True,
    )
    # at 11.2 ms itself 1.6 s is 1.6 s: over the scan period
    slow = _by_name(_result(speed_ms=11.2))
    assert slow["acknowledge all (separate Calls): last acknowledged event"][1] is False
    # no speed reference: the measured number, not scaled
    unknown = _by_name(_result(speed_ms=math.nan))
    assert (
        unknown["activation burst: last event after its scan"][0] == "300 ms (no speed reference: not scaled)"
    )


def test_an_overrun_a_lost_event_or_a_failed_round_is_not_met() -> None:
    assert overruns(_result(overruns_end=5)) == 2
    assert _by_name(_result(overruns_end=5))["alarm flood at a 1 s scan: PLC overruns"] == (
        "2 in 4 rounds",
        False,
    )
    lost = _result()
    lost.rounds[1].ack_events = 49
    assert _by_name(lost)["every activation and acknowledged event received"] == (
        "200 / 200 activations, 199 / 200 acknowledged",
        False,
    )
    failed = _result()
    failed.rounds.append(Round(5, ONE_CALL, error="RuntimeError: timed out"))
    g = _by_name(failed)
    # 0 overruns over 4 good rounds, but a fifth failed: not met; its events are missing
    assert g["alarm flood at a 1 s scan: PLC overruns"] == ("0 in 4 rounds", False)
    assert g["every activation and acknowledged event received"][1] is False
    assert _by_name(_result(overruns_end=None))["alarm flood at a 1 s scan: PLC overruns"] == ("n/a", None)


def test_the_flood_goal_needs_all_50_from_one_scan_in_every_round() -> None:
    goal = "50 alarms raised in one scan"
    split = _result()
    split.rounds[2].activation_times = 2  # the 50 came from two scans
    assert _by_name(split)[goal] == ("50 or more in one scan in 3 / 4 rounds", False)
    short = _result()
    short.rounds[0].activation_events = 49
    assert _by_name(short)[goal] == ("49 or more in one scan in 3 / 4 rounds", False)
    failed = _result()
    failed.rounds.append(Round(5, ONE_CALL, error="RuntimeError: timed out"))
    assert _by_name(failed)[goal] == ("50 or more in one scan in 4 / 5 rounds", False)


def test_the_section_states_medians_and_maxima_per_acknowledgement_mode() -> None:
    text = markdown(_result())
    assert text.startswith("## 13. Alarm flood: 50 conditions raised in one scan")
    assert "a generated 25-tank one" in text and "77 conditions on its PLC" in text
    rows = [line for line in text.splitlines() if line.startswith(("| one Call |", "| separate Calls |"))]
    # (benchmarks.common.fmt: whole numbers plain, else 3 significant digits)
    # one Call: activation 100, 300 ms -> median 200, max 300; 50 / 0.1 = 500 and 50 / 0.3 = 167
    # events/s -> median 333, max 500; scans 40, 60 ms -> 50 / 60; acks 150, 250 -> 200 / 250 ms,
    # 333 and 200 events/s -> 267 / 333
    assert rows[0] == (
        "| one Call | 2 | 200 / 300 | 333 / 500 | 50 / 60 | 30 / 30 | 20 / 20 | 100 / 125 "
        "| 200 / 250 | 267 / 333 | 30 / 30 | 30 / 30 |"
    )
    # separate: activation 300, 200 -> 250 / 300; 167 and 250 events/s -> 208 / 250; acks 400,
    # 1600 -> 1,000 / 1,600; 125 and 31.25 events/s -> 78.1 / 125
    assert rows[1].startswith("| separate Calls | 2 | 250 / 300 | 208 / 250 |")
    assert "| 1,000 / 1,600 | 78.1 / 125 |" in rows[1]
    assert (
        "| 4 | separate Calls | 50 / 50 | 1 | 25 | 200 | 40 | 50 / 50 | 50 / 50 | 1,600 | 50 | 25 | 0 |  |"
        in text
    )
    assert "80 scans, 0 overruns, start lateness p50 1.50 ms, p99 30 ms" in text
    assert "tankctl processes left on the stack's ports after the stop: 0." in text
    assert math.isnan(rate(50, 0.0))  # a burst without a duration has no rate


def test_make_bench_runs_the_section() -> None:
    assert "alarms" in run.SECTIONS
    assert run.FULL.alarm_rounds == 10 and run.QUICK.alarm_rounds == 4


def test_the_summary_goal_needs_flood_and_a_cleared_count_in_every_round() -> None:
    summary = "alarm summary: Flood at the activation, Unacknowledged 0 after acknowledge-all"
    # hand-made rounds 1..4: rates 50, 100, 150, 200 (each round's 50 plus the earlier ones in 600 s)
    assert _by_name(_result())[summary] == (
        "Flood 4 / 4, Unacknowledged 0 in 4 / 4, RatePer10Min 50..200",
        True,
    )
    late = _result()
    late.rounds[2].summary_unacked_after_ack = 3
    late.rounds[3].summary_flood = False
    assert _by_name(late)[summary] == ("Flood 3 / 4, Unacknowledged 0 in 3 / 4, RatePer10Min 50..200", False)
    unread = _result()
    unread.rounds[0].summary_flood = None  # never read: not counted as a flood
    assert _by_name(unread)[summary][1] is False
    assert summary_goal([]).met is None
