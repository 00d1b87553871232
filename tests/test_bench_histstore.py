"""benchmarks.histstore's section and goal from hand-made results (no measurement runs here)."""

from __future__ import annotations

import math

from benchmarks.common import REFERENCE_SPEED_MS
from benchmarks.histstore import BackendResult, HistStoreResults, goals, markdown


def sample(cpu_s: list[float], speed_ms: float = REFERENCE_SPEED_MS) -> HistStoreResults:
    sq = BackendResult("SQLite", [4.0, 5.0, 6.0], cpu_s, 200_000, 27.5, [0.3, 0.4, 0.5], [0.1], [0.6], 29.0)
    pg = BackendResult("PostgreSQL", [10.0], [2.0], 200_000, 86.0, [0.6], [0.2], [0.7], 85.0)
    return HistStoreResults([sq, pg], speed_ms)


def test_per_core_is_values_over_the_median_cpu_time() -> None:
    res = sample([1.0, 4.0, 2.0])
    assert res.backends[0].per_core == 100_000.0  # 200,000 values / 2.0 s (the median)
    assert res.backends[0].per_wall == 40_000.0  # / 5.0 s
    text = markdown(res)
    assert text.startswith("## 11. Historian storage\n")
    assert "| SQLite | 100,000 | 40,000 | 0.400 | 0.100 | 0.600 | 27.5 | 29 |" in text
    assert "| PostgreSQL | 100,000 | 20,000 | 0.600 | 0.200 | 0.700 | 86 | 85 |" in text


def test_the_ingest_goal_is_judged_at_the_reference_speed() -> None:
    (met,) = goals(sample([10.0]))  # 20,000 values/s per core at the reference speed
    assert met.met is True and "20,000 values/s per core" in met.measured
    # 8,000 values/s measured on a machine twice as slow as the reference: 16,000 at it
    (scaled,) = goals(sample([25.0], speed_ms=2 * REFERENCE_SPEED_MS))
    assert scaled.met is True and "16,000" in scaled.measured
    (missed,) = goals(sample([25.0]))
    assert missed.met is False
    empty = HistStoreResults([BackendResult("SQLite"), BackendResult("PostgreSQL")], math.nan)
    (none,) = goals(empty)
    assert none.met is None and none.measured == "n/a"
