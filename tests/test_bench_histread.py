"""benchmarks.histread's section and goals from hand-made results (no measurement runs here)."""

from __future__ import annotations

import math

from benchmarks.common import REFERENCE_SPEED_MS
from benchmarks.histread import HistReadResults, ReadResult, goals, markdown


def test_goals_are_judged_on_sqlite_at_the_reference_speed() -> None:
    sq = ReadResult("SQLite", [0.9, 1.2, 1.0], [0.3, 0.2, 0.4], 86_400, 1_440)
    pg = ReadResult("PostgreSQL", [2.0], [1.0], 86_400, 1_440)
    raw, agg = goals(HistReadResults([sq, pg], REFERENCE_SPEED_MS))
    assert raw.met is True and raw.measured.startswith("1 s at the reference speed")  # median 1.0
    assert agg.met is True and agg.measured.startswith("0.300 s")
    # measured on a machine twice as slow: 1.0 s there is 0.5 s at the reference speed
    raw2, _ = goals(HistReadResults([ReadResult("SQLite", [2.4], [0.9])], 2 * REFERENCE_SPEED_MS))
    assert raw2.met is False and "1.20 s at the reference speed" in raw2.measured
    text = markdown(HistReadResults([sq, pg], REFERENCE_SPEED_MS))
    assert text.startswith("## 12. Historian reads through HistoryRead\n")
    assert "| SQLite | 1 | 86,400 | 0.300 | 1,440 |" in text


def test_nothing_measured_is_not_measured() -> None:
    none = goals(HistReadResults([ReadResult("SQLite")], math.nan, ["SQLite: boom"]))
    assert [g.met for g in none] == [None, None]
    assert "- error: SQLite: boom" in markdown(
        HistReadResults([ReadResult("SQLite")], math.nan, ["SQLite: boom"])
    )
