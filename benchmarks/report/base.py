"""One run's results (:class:`Report`) and the Markdown helpers every section of the document uses."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from benchmarks.accuracy import GuardResult
from benchmarks.common import Goal, Summary, fmt
from benchmarks.cosim import CosimResult, HotSpot
from benchmarks.mpc import HorizonResult, Series
from benchmarks.stack import StackResults

GOAL_NP = 40
GOAL_NP_LONG = 160


@dataclass
class Report:
    """Everything one run measured."""

    date: str
    command: str
    quick: bool
    machine: dict[str, str]
    versions: dict[str, str]
    total_wall_s: float = math.nan
    mpc_alone: list[HorizonResult] = field(default_factory=list)
    mpc_side: list[HorizonResult] = field(default_factory=list)
    mpc_profile: list[HotSpot] = field(default_factory=list)
    mpc_profile_np: int = GOAL_NP
    accuracy: list[GuardResult] = field(default_factory=list)
    cosim: list[CosimResult] = field(default_factory=list)
    stack: StackResults | None = None
    settings: dict[str, str] = field(default_factory=dict)
    speed_reference_ms: tuple[float, float] = (math.nan, math.nan)
    """:func:`benchmarks.common.speed_reference` at the start and at the end of the run [ms]."""
    errors: list[str] = field(default_factory=list)
    extra: list[str] = field(default_factory=list)
    """Whole markdown sections of other benchmark modules (robustness, security, cli, restarts), in order."""
    extra_goals: list[Goal] = field(default_factory=list)
    """Goals measured by those modules (cli: operator command wall time; restarts), after the others."""


def cores_cell(cores: float) -> str:
    """Other load [cores] with two decimals."""
    return f"{cores:.2f}" if math.isfinite(cores) else "n/a"


def in_ms(s: Summary) -> Summary:
    return s.scaled(1e3)


def table(header: Sequence[str], rows: Sequence[Sequence[str]], align: str = "") -> list[str]:
    align = align or "l" + "r" * (len(header) - 1)
    sep = ["---:" if a == "r" else "---" for a in align]
    out = ["| " + " | ".join(header) + " |", "| " + " | ".join(sep) + " |"]
    out += ["| " + " | ".join(row) + " |" for row in rows]
    return [*out, ""]


def ratio(num: float, den: float) -> float:
    return num / den if den > 0 and math.isfinite(num) and math.isfinite(den) else math.nan


def status_cell(series: Series) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(series.status.items())) or "-"


def find(results: Sequence[HorizonResult], horizon: int) -> HorizonResult | None:
    return next((r for r in results if r.horizon == horizon), None)


def hotspot_table(spots: Sequence[HotSpot], top: int = 5) -> list[str]:
    rows = [
        [
            f"`{h.function}`",
            f"{h.calls:,}",
            fmt(1e3 * h.own_s),
            fmt(100 * h.share, 2),
            fmt(1e3 * h.cumulative_s),
        ]
        for h in spots[:top]
    ]
    return table(["function", "calls", "own [ms]", "own share [%]", "cumulative [ms]"], rows, "lrrrr")
