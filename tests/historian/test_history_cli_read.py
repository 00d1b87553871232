"""``tankctl history`` and ``alarms --history``: the argument parsing and output formats by hand,
and the HistoryRead calls (tankctl.ops.history_read) against a secured server serving a known
series (``history_url`` in conftest.py), read as an Observer."""

from __future__ import annotations

import csv
import io
import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st

from helpers import secure
from history_series import EVENTS, T0, TAG, N, S, is_bad, level
from tankctl.history_files import plot_history, write_parquet
from tankctl.ops.errors import UsageError
from tankctl.ops.history_output import render_csv, render_events, render_json, render_text
from tankctl.ops.history_read import (
    HistoryReadError,
    HistoryRow,
    parse_span_s,
    parse_time,
    read_event_history,
    read_tag_history,
)
from tanklab.tags import NAMESPACE_URI

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
NOW = datetime(2026, 12, 3, 8, 0, 0, tzinfo=UTC)


def at(t_us: int) -> datetime:
    return EPOCH + timedelta(microseconds=t_us)


def test_times_and_spans() -> None:
    assert parse_time("now", NOW, "--to") == NOW
    assert parse_time("-15m", NOW, "--from") == NOW - timedelta(minutes=15)
    assert parse_time("-1d", NOW, "--from") == NOW - timedelta(days=1)
    assert parse_time("2026-12-03T07:00:00", NOW, "--from") == datetime(2026, 12, 3, 7, tzinfo=UTC)  # UTC
    assert parse_time("2026-12-03T08:00:00+01:00", NOW, "--from") == datetime(2026, 12, 3, 7, tzinfo=UTC)
    assert parse_time("2026-12-03T07:00:00Z", NOW, "--from") == datetime(2026, 12, 3, 7, tzinfo=UTC)
    assert [parse_span_s(t, "--interval") for t in ("500ms", "60s", "5m", "2h", "1d", "1.5s")] == [
        0.5,
        60.0,
        300.0,
        7200.0,
        86400.0,
        1.5,
    ]
    for bad in ("60", "0s", "-5s", "5 parsecs", ""):
        with pytest.raises(UsageError, match="--interval"):
            parse_span_s(bad, "--interval")
    with pytest.raises(UsageError, match="--from 'yesterday'"):
        parse_time("yesterday", NOW, "--from")


@given(st.integers(min_value=1, max_value=10**9), st.sampled_from(["ms", "s", "m", "h", "d"]))
def test_relative_times_go_back_by_the_span(n: int, unit: str) -> None:
    span = parse_span_s(f"{n}{unit}", "--from")
    assert span == n * {"ms": 0.001, "s": 1, "m": 60, "h": 3600, "d": 86400}[unit]
    try:
        back = NOW - timedelta(seconds=span)
    except OverflowError:  # before the year 1: a usage error, never a crash
        with pytest.raises(UsageError, match="before the year 1"):
            parse_time(f"-{n}{unit}", NOW, "--from")
    else:
        assert parse_time(f"-{n}{unit}", NOW, "--from") == back


ROWS = {
    "PLC.LIC1.PV": [
        HistoryRow(at(T0), 0.25, "Good", 0),
        HistoryRow(at(T0 + S), None, "BadNoCommunication", 0x8031_0000),
    ],
    "PLC.LIC1.Mode": [HistoryRow(at(T0), 1, "Good", 0)],
}


def test_output_formats() -> None:
    text = render_text(ROWS).splitlines()
    assert text == [
        "2025-12-02T00:00:00.000Z  PLC.LIC1.PV            0.25",
        "2025-12-02T00:00:01.000Z  PLC.LIC1.PV            None  BadNoCommunication",
        "2025-12-02T00:00:00.000Z  PLC.LIC1.Mode             1",
    ]
    assert render_text({"PLC.LIC1.PV": []}) == "(no values)"
    rows = list(csv.reader(io.StringIO(render_csv(ROWS))))
    assert rows[0] == ["tag", "time", "value", "status", "status_code"]
    assert rows[2] == ["PLC.LIC1.PV", "2025-12-02T00:00:01.000Z", "", "BadNoCommunication", str(0x8031_0000)]
    assert len(rows) == 4
    got = json.loads(render_json(ROWS))
    assert got[0] == {
        "tag": "PLC.LIC1.PV",
        "time": "2025-12-02T00:00:00+00:00",
        "value": 0.25,
        "status": "Good",
        "status_code": 0,
    }
    assert [g["tag"] for g in got] == ["PLC.LIC1.PV", "PLC.LIC1.PV", "PLC.LIC1.Mode"]


def test_parquet_and_plot(tmp_path: Path) -> None:
    assert write_parquet(ROWS, tmp_path / "h.parquet") == 3
    table = pq.read_table(tmp_path / "h.parquet").to_pylist()
    assert table[0] == {
        "tag": "PLC.LIC1.PV",
        "time": at(T0),
        "value": 0.25,
        "text": None,
        "status_code": 0,
        "status": "Good",
    }
    assert table[1]["value"] is None and table[1]["status_code"] == 0x8031_0000
    assert table[2]["value"] == 1.0
    plot_history(ROWS, tmp_path / "h.png", "test")
    assert (tmp_path / "h.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


async def test_reads_through_a_server(history_url: str) -> None:
    async with await secure(history_url, "observer") as client:
        ns = await client.get_namespace_index(NAMESPACE_URI)
        raw = await read_tag_history(client, ns, TAG, at(T0), at(T0 + N * S))
        # every recorded value, past the server's continuation points, with its time and status
        assert len(raw) == N
        assert [r.time for r in raw[:3]] == [at(T0), at(T0 + S), at(T0 + 2 * S)]
        assert [r.value for r in raw] == pytest.approx([level(k) for k in range(N)], abs=1e-15)
        assert [r.status_code != 0 for r in raw] == [is_bad(k) for k in range(N)]
        assert raw[50].status == "BadNoCommunication"

        avg = await read_tag_history(
            client, ns, TAG, at(T0), at(T0 + 600 * S), aggregate="avg", interval_s=60.0
        )
        assert [r.time for r in avg] == [at(T0 + 60 * j * S) for j in range(10)]
        good = [k for k in range(60, 120) if not is_bad(k)]
        assert avg[1].value == pytest.approx(sum(level(k) for k in good) / len(good), rel=1e-12)
        count = await read_tag_history(
            client, ns, TAG, at(T0), at(T0 + 600 * S), aggregate="count", interval_s=60.0
        )
        assert [r.value for r in count] == [
            sum(not is_bad(k) for k in range(60 * j, 60 * j + 60)) for j in range(10)
        ]

        with pytest.raises(HistoryReadError, match=r"PLC\.NOPE\.PV: BadNodeIdUnknown"):
            await read_tag_history(client, ns, "PLC.NOPE.PV", at(T0), at(T0 + S))

        events = await read_event_history(client, at(T0), at(T0 + 60 * S))
        assert [(e.time, e.source, e.severity, e.message) for e in events] == [
            (at(ev.t_us), ev.source, ev.severity, ev.message) for ev in EVENTS
        ]
        assert events[0].event_id == EVENTS[0].event_id.hex()
        severe = await read_event_history(client, at(T0), at(T0 + 60 * S), min_severity=300)
        assert [e.message for e in severe] == ["T1 level high", "T1 level normal"]
        text = render_events(severe, as_json=False).splitlines()
        assert text[0] == "2025-12-02T00:00:10.000Z   700  PLC.T1.Level  T1 level high"
