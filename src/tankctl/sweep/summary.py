"""The sweep's summary: per variant, the median and 95th percentile of each kept metric, and
the number of failed cases (pure: rows in, numbers and text out).

For one variant and metric, let x_1 <= ... <= x_n be the metric's values over the cases that
ran (status "ok") and have it (a settling time not reached is null and not counted; ``n`` says
how many did). Percentiles interpolate linearly between order statistics (numpy's default):

    q(p) = x_(floor(h)) + (h - floor(h)) (x_(floor(h)+1) - x_(floor(h))),  h = 1 + (n - 1) p

so the median is q(0.5) and p95 is q(0.95). With n = 0 both are null.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["MetricSummary", "VariantSummary", "summarize", "summary_json", "summary_markdown"]


@dataclass(frozen=True)
class MetricSummary:
    """One metric of one variant: values counted, median, p95 (None with no values)."""

    n: int
    median: float | None
    p95: float | None


@dataclass
class VariantSummary:
    """One variant: cases recorded, failed cases (status "error"), each metric's summary."""

    cases: int
    failures: int
    metrics: dict[str, MetricSummary] = field(default_factory=dict)


def _metric(values: Sequence[float | None]) -> MetricSummary:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    if not finite:
        return MetricSummary(0, None, None)
    a = np.asarray(finite, dtype=float)
    return MetricSummary(a.size, float(np.percentile(a, 50.0)), float(np.percentile(a, 95.0)))


def summarize(
    rows: Sequence[dict[str, Any]], variants: Sequence[str], metrics: Sequence[str]
) -> dict[str, VariantSummary]:
    """Per variant (in the given order): cases, failures and each metric's median and p95."""
    out: dict[str, VariantSummary] = {}
    for v in variants:
        mine = [r for r in rows if r["variant"] == v]
        ok = [r for r in mine if r["status"] == "ok"]
        s = VariantSummary(cases=len(mine), failures=len(mine) - len(ok))
        for m in metrics:
            s.metrics[m] = _metric([r.get(m) for r in ok])
        out[v] = s
    return out


def summary_json(name: str, total_cases: int, summary: dict[str, VariantSummary]) -> dict[str, Any]:
    """The ``summary.json`` document."""
    return {
        "sweep": name,
        "cases": total_cases,
        "variants": {
            v: {
                "cases": s.cases,
                "failures": s.failures,
                "metrics": {
                    m: {"n": ms.n, "median": ms.median, "p95": ms.p95} for m, ms in s.metrics.items()
                },
            }
            for v, s in summary.items()
        },
    }


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.4g}"


def summary_markdown(
    name: str,
    description: str,
    total_cases: int,
    summary: dict[str, VariantSummary],
    errors: Sequence[str] = (),
) -> str:
    """The ``summary.md`` document: a table per variant, metric rows, n / median / p95 columns."""
    lines = [f"# Sweep {name}", ""]
    if description:
        lines += [description.strip(), ""]
    lines += [f"{total_cases} cases per variant.", ""]
    for v, s in summary.items():
        lines += [f"## {v}", "", f"{s.cases} cases recorded, {s.failures} failed.", ""]
        lines += ["| metric | n | median | p95 |", "|---|---:|---:|---:|"]
        lines += [f"| {m} | {ms.n} | {_fmt(ms.median)} | {_fmt(ms.p95)} |" for m, ms in s.metrics.items()]
        lines.append("")
    if errors:
        lines += ["## Errors (first of each kind)", ""]
        lines += [f"- {e}" for e in errors]
        lines.append("")
    return "\n".join(lines)
