"""The alarm-flood section (:mod:`benchmarks.alarms`): issue 15's scan goal judged, and its Markdown.

Pure: an :class:`~benchmarks.alarms.AlarmsResult` in, :class:`~benchmarks.common.Goal` s and text
out. Wall-time figures are stated at the reference machine speed (decision 0036) with the
section's own speed reference.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

from benchmarks.alarms import BIAS_M, N_TANKS, ONE_CALL, POLL_S, QUIET_SCANS, SEPARATE, AlarmsResult, Round
from benchmarks.common import Goal, at_reference_text, fmt, seconds_at_reference
from benchmarks.report.base import table

ISSUE_ALARMS = 50
"""The issue's flood: 50 alarms raised in one scan."""


def ms(x: float) -> str:
    return fmt(1e3 * x)


def rate(events: int, seconds: float) -> float:
    """Events per second of a burst: its events over the time from its cause to its last arrival."""
    return events / seconds if seconds > 0 and math.isfinite(seconds) else math.nan


def ok_rounds(res: AlarmsResult) -> list[Round]:
    return [r for r in res.rounds if not r.error]


def overruns(res: AlarmsResult) -> int | None:
    """Overruns over the rounds: ``PLC.Overruns`` after the last round minus before the first."""
    if res.overruns_start is None or res.overruns_end is None:
        return None
    return res.overruns_end - res.overruns_start


def _worst(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return max(finite) if finite else math.nan


def goals(res: AlarmsResult) -> list[Goal]:
    """Issue 15's "no regression of the scan": 50 conditions raised in one scan on the flood site
    (:mod:`benchmarks.alarms`) and acknowledged by one client, 0 overruns."""
    rounds = ok_rounds(res)
    n = rounds[0].conditions if rounds else 0
    period = res.scan_period_s
    out: list[Goal] = []
    over = overruns(res)
    scans = [r.activation_scan_s for r in rounds]
    measured_over = "n/a" if over is None else f"{over} in {len(rounds)} rounds"
    out.append(
        Goal(
            f"alarm flood at a {fmt(period)} s scan: PLC overruns",
            "0",
            measured_over,
            None if over is None or not rounds else over == 0 and len(rounds) == len(res.rounds),
            f"{n} conditions raised in one scan and acknowledged by one client per round "
            f"(section 13); activation scan {ms(statistics.median(scans)) if scans else 'n/a'} ms "
            f"median, {ms(_worst(scans))} ms max as measured, "
            f"{ms(seconds_at_reference(_worst(scans), res.speed_ms))} ms max at the reference speed",
        )
    )
    out.append(raised_goal(res))
    want = n * len(res.rounds)
    got_a = sum(r.activation_events for r in rounds)
    got_k = sum(r.ack_events for r in rounds)
    out.append(
        Goal(
            "every activation and acknowledged event received",
            f"{n} + {n} per round",
            f"{got_a} / {want} activations, {got_k} / {want} acknowledged",
            (got_a == want and got_k == want) if want else None,
            "one asyncua client subscribed to the Server object",
        )
    )

    out.append(summary_goal(rounds))

    def within(name: str, values: list[float], what: str) -> Goal:
        worst = _worst(values)
        scaled = seconds_at_reference(worst, res.speed_ms)
        return Goal(
            name,
            f"< {fmt(period)} s at reference speed (the scan period)",
            at_reference_text(f"{ms(scaled)} ms", f"{ms(worst)} ms", res.speed_ms),
            scaled < period if math.isfinite(scaled) else None,
            f"worst of {len(values)} rounds, {what}",
        )

    out.append(
        within(
            "activation burst: last event after its scan",
            [r.activation_latency_s for r in rounds],
            "from the raising scan's wall stamp to the last event's arrival",
        )
    )
    for mode in (ONE_CALL, SEPARATE):
        of_mode = [r.ack_latency_s for r in rounds if r.mode == mode]
        if of_mode:
            out.append(
                within(
                    f"acknowledge all ({mode}): last acknowledged event",
                    of_mode,
                    "from the first Call request sent",
                )
            )
    return out


def raised_goal(res: AlarmsResult) -> Goal:
    """The issue's flood itself: in every round all :data:`ISSUE_ALARMS` activation events came
    from one scan (one distinct ``Time``)."""
    rounds = ok_rounds(res)
    whole = [r for r in rounds if r.activation_events >= ISSUE_ALARMS and r.activation_times == 1]
    fewest = min((r.activation_events for r in rounds), default=0)
    return Goal(
        f"{ISSUE_ALARMS} alarms raised in one scan",
        f"{ISSUE_ALARMS} in one scan, every round",
        f"{fewest} or more in one scan in {len(whole)} / {len(res.rounds)} rounds",
        len(whole) == len(res.rounds) if res.rounds else None,
        f"a {N_TANKS}-tank site (names up to 99, decision 0045): each tank's level alarm (HighHigh) "
        "and its trip, from one common-mode transmitter fault",
    )


def summary_goal(rounds: Sequence[Round]) -> Goal:
    """The PLC's alarm summary through the flood: ``Flood`` true once a round's activations are
    counted (each round raises more than 10 in one scan) and ``Unacknowledged`` 0 after its
    acknowledge-all."""
    read = [r for r in rounds if r.summary_flood is not None]
    flooded = sum(bool(r.summary_flood) for r in read)
    cleared = sum(r.summary_unacked_after_ack == 0 for r in read)
    rates = [r.summary_rate for r in read]
    span = f", RatePer10Min {min(rates)}..{max(rates)}" if rates else ""
    return Goal(
        "alarm summary: Flood at the activation, Unacknowledged 0 after acknowledge-all",
        f"{len(rounds)} / {len(rounds)} rounds each",
        f"Flood {flooded} / {len(rounds)}, Unacknowledged 0 in {cleared} / {len(rounds)}{span}",
        (flooded == cleared == len(rounds)) if rounds else None,
        "PLC.AlarmSummary.* read by the acknowledging client; the rate counts the earlier rounds' "
        "activations still in the 600 s model-time window",
    )


def _summary_rows(rounds: Sequence[Round], mode: str) -> list[list[str]]:
    rs = [r for r in rounds if r.mode == mode]
    if not rs:
        return []

    def cell(values: list[float], scale: float = 1e3) -> str:
        finite = [v for v in values if math.isfinite(v)]
        if not finite:
            return "n/a"
        return f"{fmt(scale * statistics.median(finite))} / {fmt(scale * max(finite))}"

    return [
        [
            mode,
            str(len(rs)),
            cell([r.activation_latency_s for r in rs]),
            cell([rate(r.activation_events, r.activation_latency_s) for r in rs], 1.0),
            cell([r.activation_scan_s for r in rs]),
            cell([r.baseline_scan_s for r in rs]),
            cell([r.activation_cpu_s for r in rs]),
            cell([r.ack_call_s for r in rs]),
            cell([r.ack_latency_s for r in rs]),
            cell([rate(r.ack_events, r.ack_latency_s) for r in rs], 1.0),
            cell([r.ack_scan_s for r in rs]),
            cell([r.ack_cpu_s for r in rs]),
        ]
    ]


def markdown(res: AlarmsResult) -> str:
    rounds = ok_rounds(res)
    n = rounds[0].conditions if rounds else 2 * N_TANKS
    period = res.scan_period_s
    lines = [
        f"## 13. Alarm flood: {n} conditions raised in one scan, one client acknowledging all "
        f"({fmt(period)} s scan, speed 1)",
        "",
        "`benchmarks.alarms` (`python -m benchmarks.run --only alarms`), issue 15's \"no regression of "
        f"the scan: raising {ISSUE_ALARMS} alarms in one scan and a client acknowledging them all "
        f'cause 0 overruns at a 1 s scan". Tank, pump and loop numbers go to 99 (decision 0045), so '
        f"the site is a generated {N_TANKS}-tank one (`benchmarks.alarms.flood_site`: {N_TANKS} copies "
        "of the Energies T1 loop, pump into tank, outlet valve to the drain, LIC1's PID and T1's "
        "0.58 m high-high interlock on every tank, at the 0.4 m equilibrium, no supervisor; "
        f"{res.site_conditions} conditions on its PLC), and one plant event, a common-mode "
        f"transmitter fault (one Write request setting `Fault = BIAS` on all {N_TANKS} transmitters, "
        f"`FaultValue` {fmt(BIAS_M)} m written beforehand), puts every reading above the trip in "
        f"the same scan: {N_TANKS} level alarms (HighHigh) and {N_TANKS} trips, {n} conditions "
        "active at once.",
        "",
        "Real plant and PLC processes on loopback (`tanklab_testing.stack.Stack`, the benchmark's "
        "own security home, every session Basic256Sha256 SignAndEncrypt as the engineer), PLC at "
        f"speed 1. Each round: {QUIET_SCANS} quiet scans; the fault Write; the activation events counted at "
        "an asyncua client subscribed to the Server object (100 ms publishing interval), each "
        "timed from the `Time` of its event (the raising scan's wall stamp) to its arrival; one "
        f"client acknowledging all {n} with the EventIds received, alternately in **one Call** "
        f"request of {n} method calls and in **{n} separate Calls** one after the other, timed "
        "from the first request sent to the last acknowledged event; then the fault cleared (the "
        "levels return), `PLC.Interlock.Reset` (the trips return) and the trips confirmed in one "
        f"Call. A third session reads `PLC.Status.Scan`, `LastScanDuration`, `Overruns` and the HH "
        f"booleans every {fmt(POLL_S)} s: the activation scan is the first after the Write that "
        "published the HH booleans, its duration the PLC's own (the scan's work, field I/O and "
        "publishing included); *scan during ack* is the longest scan first seen from the call to "
        "one scan period after the last acknowledged event. *PLC CPU* is the PLC process's CPU "
        "time (all threads, /proc schedstat) from the Write to the last activation event and from "
        "the first Call to the last acknowledged event (it includes the ordinary scans in those "
        "windows). *events/s* is a burst's events over the time from its cause to its last "
        "arrival. Medians / max of the rounds; times as measured (the goals state them at the "
        f"reference speed); machine speed reference at the section's start {fmt(res.speed_ms)} ms.",
        "",
    ]
    header = [
        "acknowledged in",
        "rounds",
        "last activation event [ms]",
        "activation events/s",
        "activation scan [ms]",
        "quiet scan [ms]",
        "PLC CPU, activation [ms]",
        "ack call(s) [ms]",
        "last ack event [ms]",
        "ack events/s",
        "scan during ack [ms]",
        "PLC CPU, ack [ms]",
    ]
    rows = _summary_rows(rounds, ONE_CALL) + _summary_rows(rounds, SEPARATE)
    if rows:
        lines += table(header, rows, "l" + "r" * (len(header) - 1))
    per_round = [
        [
            str(r.index),
            r.mode,
            f"{r.activation_events} / {r.conditions}",
            str(r.activation_times),
            f"{r.activation_scan_alarms}",
            ms(r.activation_latency_s),
            ms(r.activation_scan_s),
            f"{r.ack_good} / {r.conditions}",
            f"{r.ack_events} / {r.conditions}",
            ms(r.ack_latency_s),
            str(r.return_events),
            str(r.confirm_events),
            str(r.overruns_after - r.overruns_before) if not r.error else "n/a",
            r.error or "",
        ]
        for r in res.rounds
    ]
    if per_round:
        lines += ["Per round:", ""]
        lines += table(
            [
                "round",
                "acknowledged in",
                "active events",
                "raising scans",
                "HH booleans in that scan",
                "last activation event [ms]",
                "activation scan [ms]",
                "acks Good",
                "acked events",
                "last ack event [ms]",
                "returns",
                "confirms",
                "overruns",
                "error",
            ],
            per_round,
            "rlrrrrrrrrrrrl",
        )
    over = overruns(res)
    plc = res.plc
    stop = (
        f"its stop line: {plc.scans} scans, {plc.overruns} overruns, start lateness p50 "
        f"{fmt(plc.p50_ms)} ms, p99 {fmt(plc.p99_ms)} ms"
        if plc is not None and not plc.error
        else f"no stop line ({plc.error if plc is not None else 'not run'})"
    )
    lines += [
        f"PLC overruns over the rounds (`PLC.Status.Overruns` after the last round minus before "
        f"the first): **{'n/a' if over is None else over}**; {stop}. Start-up of plant and PLC "
        f"{fmt(res.startup_s, 2)} s; the section took {fmt(res.wall_s, 2)} s. tankctl processes left on "
        f"the stack's ports after the stop: {len(res.left)}.",
        "",
    ]
    if res.errors:
        lines += ["Errors: " + "; ".join(res.errors), ""]
    return "\n".join(lines)
