"""benchmarks.sweep's section and goal from hand-made results (no measurement runs here)."""

from __future__ import annotations

import pytest
from benchmarks.sweep import SweepBench, Throughput, goals, markdown


def sample() -> SweepBench:
    # 1 worker: 10 runs in 20 s, the cases 1.8 s each (busy 0.9); 2 workers: 10 runs in 8 s,
    # cases 1.5 s each (a quieter machine: busy 15 / 16 = 0.9375)
    one = Throughput(1, 10, 5.0, 20.0, [1.8] * 10, [170.0], 0)
    two = Throughput(2, 10, 9.0, 8.0, [1.5] * 10, [171.0, 172.0], 0)
    return SweepBench(12.0, 1, [one, two], None)


def test_rates_overhead_and_busy_fraction() -> None:
    one, two = sample().throughput
    assert (one.rate, two.rate) == (0.5, 1.25)
    assert one.overhead_ms == pytest.approx(200.0)  # (1 x 20 - 18) / 10 runs
    assert two.overhead_ms == pytest.approx(100.0)  # (2 x 8 - 15) / 10 runs
    assert two.busy == pytest.approx(0.9375)


def test_the_speed_up_goal_and_its_equal_cost_figure() -> None:
    (goal,) = goals(sample())
    assert goal.met is True and goal.measured.startswith("2.50x")  # 1.25 / 0.5
    assert "at equal case cost (workers x busy fraction) 2.08x" in goal.note  # 2 x 0.9375 / 0.9
    text = markdown(sample())
    assert text.startswith("## 14. Scenario sweeps on Dask\n")
    assert "| 2 | 10 | 9 | 8 | 1.25 | 2.50x | 1.50 | 0.938 | 100 | 171, 172 | 0 |" in text
