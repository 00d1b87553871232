"""The sweep's figures (matplotlib, the ``plots`` extra): metric distributions and, for a sweep
over exactly two grid parameters, heat maps of each metric's median over the grid.

``distributions.png``: one panel per kept metric, a step histogram per variant (cases that ran
and have the metric). ``heatmap.png`` (two grid parameters only): one panel per metric and
variant, cell (i, j) the median over the draws of grid point (first parameter's i-th value,
second's j-th), blank where no case of the cell has the metric.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["heatmap_grid", "plot_distributions", "plot_heatmaps"]


def _ok(rows: Sequence[dict[str, Any]], variant: str, metric: str) -> list[float]:
    return [
        float(r[metric])
        for r in rows
        if r["variant"] == variant
        and r["status"] == "ok"
        and r.get(metric) is not None
        and math.isfinite(float(r[metric]))
    ]


def _bins(values: Sequence[float]) -> int | np.ndarray:
    """Histogram bins: up to 30 over the values' range; two edges around a range too narrow for
    numpy to split (a metric equal in every case up to rounding, as a saturated max_du)."""
    lo, hi = min(values), max(values)
    n = min(30, max(5, len(values) // 5))
    if hi - lo > 1e-9 * max(abs(lo), abs(hi)) and hi - lo > 1e-300:
        return n
    pad = max(abs(lo) * 1e-3, 1e-12)
    return np.array([lo - pad, hi + pad])


def plot_distributions(
    rows: Sequence[dict[str, Any]], variants: Sequence[str], metrics: Sequence[str], out: Path, title: str
) -> Path:
    """Histograms of every metric, variants overlaid; written to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(metrics)
    cols = min(3, n)
    nrows = math.ceil(n / cols)
    fig, axes = plt.subplots(
        nrows, cols, figsize=(4.2 * cols, 3.2 * nrows), squeeze=False, layout="constrained"
    )
    for k, metric in enumerate(metrics):
        ax = axes[k // cols][k % cols]
        for v in variants:
            values = _ok(rows, v, metric)
            if values:
                ax.hist(values, bins=_bins(values), histtype="step", label=v)
        ax.set_title(metric, fontsize=9)
        ax.set_ylabel("cases")
    for k in range(n, nrows * cols):
        axes[k // cols][k % cols].set_visible(False)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(title)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def heatmap_grid(
    rows: Sequence[dict[str, Any]],
    variant: str,
    metric: str,
    first: tuple[str, Sequence[Any]],
    second: tuple[str, Sequence[Any]],
) -> np.ndarray:
    """(len(first values), len(second values)) medians of ``metric`` per grid cell; NaN if empty."""
    (p1, v1), (p2, v2) = first, second
    grid = np.full((len(v1), len(v2)), math.nan)
    for i, a in enumerate(v1):
        for j, b in enumerate(v2):
            cell = [
                float(r[metric])
                for r in rows
                if r["variant"] == variant
                and r["status"] == "ok"
                and r.get(metric) is not None
                and r[p1] == a
                and r[p2] == b
            ]
            if cell:
                grid[i, j] = float(np.median(cell))
    return grid


def plot_heatmaps(
    rows: Sequence[dict[str, Any]],
    variants: Sequence[str],
    metrics: Sequence[str],
    first: tuple[str, Sequence[Any]],
    second: tuple[str, Sequence[Any]],
    out: Path,
    title: str,
) -> Path:
    """A heat map per metric (rows) and variant (columns) over the two grid parameters."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        len(metrics),
        len(variants),
        figsize=(3.8 * len(variants), 3.0 * len(metrics)),
        squeeze=False,
        layout="constrained",
    )
    for i, metric in enumerate(metrics):
        for j, v in enumerate(variants):
            ax = axes[i][j]
            grid = heatmap_grid(rows, v, metric, first, second)
            im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
            ax.set_xticks(
                range(len(second[1])),
                [f"{x:.3g}" if isinstance(x, float) else str(x) for x in second[1]],
                fontsize=7,
            )
            ax.set_yticks(
                range(len(first[1])),
                [f"{x:.3g}" if isinstance(x, float) else str(x) for x in first[1]],
                fontsize=7,
            )
            ax.set_xlabel(second[0], fontsize=8)
            ax.set_ylabel(first[0], fontsize=8)
            ax.set_title(f"{v}: {metric} (median)", fontsize=8)
            fig.colorbar(im, ax=ax)
    fig.suptitle(title)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
