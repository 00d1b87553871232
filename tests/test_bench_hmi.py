"""The HMI benchmark's pure parts (benchmarks.hmi): percentiles, /proc ticks, CPU %, goals, markdown.

The measurement itself runs a real stack, the HMI and headless Chromium for a few minutes
(``python -m benchmarks.run --only hmi``); here the arithmetic it reports, on hand-computed
oracles and properties, and the process's own /proc line.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest
from benchmarks.hmi import (
    GOAL_P99_S,
    HmiResult,
    Window,
    cpu_percent,
    goals,
    markdown,
    percentile,
    stat_ticks,
)
from hypothesis import given
from hypothesis import strategies as st


def test_nearest_rank_percentiles_by_hand() -> None:
    xs = [0.5, 0.1, 0.4, 0.2, 0.3]  # sorted: 0.1 0.2 0.3 0.4 0.5
    assert percentile(xs, 50) == 0.3  # ceil(2.5) = 3rd
    assert percentile(xs, 20) == 0.1  # ceil(1.0) = 1st
    assert percentile(xs, 21) == 0.2
    assert percentile(xs, 99) == 0.5 and percentile(xs, 100) == 0.5
    hundred = [i / 1000 for i in range(1, 101)]  # 1 ms .. 100 ms
    assert percentile(hundred, 99) == 0.099 and percentile(hundred, 50) == 0.05
    assert math.isnan(percentile([], 50))
    with pytest.raises(ValueError, match="q must be"):
        percentile(xs, 0)


@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=200), st.floats(0.01, 100))
def test_a_percentile_is_a_sample_with_q_percent_at_or_below(xs: list[float], q: float) -> None:
    p = percentile(xs, q)
    assert p in xs
    assert sum(x <= p for x in xs) >= q / 100 * len(xs) - 1e-9
    assert sum(x < p for x in xs) < q / 100 * len(xs) + 1e-9


def test_stat_ticks_count_fields_after_the_last_parenthesis() -> None:
    # pid (comm) state ppid pgrp session tty tpgid flags minflt cminflt majflt cmajflt utime stime ...
    line = "4242 (chrom (renderer) x) S 1 2 3 0 -1 4194560 10 0 0 0 123 45 6 7 20 0 1 0 99 0 0"
    assert stat_ticks(line) == 168
    own = stat_ticks(Path(f"/proc/{os.getpid()}/stat").read_text())
    assert own >= 0


def test_cpu_percent_of_a_process_tree_by_hand() -> None:
    before = {10: 100, 11: 50, 12: 7}  # 12 died in the window: its ticks are lost
    after = {10: 150, 11: 60, 13: 40}  # 13 was born in the window: counts from 0
    # (50 + 10 + 40) ticks / 100 Hz = 1.0 s of CPU over 4 s of wall: 25 % of one core
    assert cpu_percent(before, after, 4.0, 100) == pytest.approx(25.0)
    assert math.isnan(cpu_percent(before, after, 0.0, 100))


def _window(clients: int, samples: list[float]) -> Window:
    return Window(clients, 60.0, samples, browser_cpu_pct=12.5, server_cpu_pct=3.25, browser_processes=7)


def test_goals_judge_the_p99_per_client_count() -> None:
    fast = _window(1, [0.05] * 99 + [0.2])
    slow = _window(20, [0.05] * 98 + [0.3, 0.3])
    res = HmiResult(60.0, windows=[fast, slow, Window(20)])
    met, not_met, unmeasured = goals(res)
    assert met.met is True and "1 client" in met.name and met.measured.startswith("50 ms")
    assert not_met.met is False and "20 client" in not_met.name and not_met.measured.startswith("300 ms")
    assert unmeasured.met is None
    assert fast.p99_s <= GOAL_P99_S < slow.p99_s


def test_markdown_is_section_15_with_one_row_per_window() -> None:
    res = HmiResult(60.0, windows=[_window(1, [0.062, 0.113]), _window(20, [0.07])], errors=["boom"])
    text = markdown(res)
    assert text.startswith("## 15. HMI")
    rows = [line for line in text.splitlines() if line.startswith("| 1 |") or line.startswith("| 20 |")]
    assert rows[0] == "| 1 | 60 | 2 | 62 | 113 | 113 | 12.5 | 7 | 3.25 |"
    assert rows[1].startswith("| 20 | 60 | 1 | 70 |")
    assert "- error: boom" in text
