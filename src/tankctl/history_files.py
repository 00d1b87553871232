"""The files ``tankctl history`` writes (issue 16): a Parquet file and a PNG trend, from the
rows of :mod:`tankctl.ops.history_read`. Outside :mod:`tankctl.ops` because they load pyarrow
and matplotlib, which operator commands never import (the import-linter contract); each is
imported only by the command that writes its file, and missing is a one-line error naming the
extra to install.

- Parquet (pyarrow, the ``parquet`` extra): columns ``tag`` (string), ``time`` (timestamp[us, UTC]),
  ``value`` (float64; null where the value is not a number), ``text`` (string: the value of a
  non-numeric tag), ``status_code`` (uint32), ``status`` (string).
- PNG (matplotlib, the ``plots`` extra): one panel per tag sharing the time axis; values whose
  status is Bad are gaps, not points, and a thin red line marks each, so a gap the historian
  marked shows as a break.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from tankctl.ops.errors import UsageError
from tankctl.ops.history_output import Histories
from tanklab.history.model import is_bad


def _number(value: Any) -> float | None:
    if isinstance(value, bool | int | float):
        return float(value)
    return None


def write_parquet(histories: Histories, path: Path) -> int:
    """Write the rows to ``path`` (module docstring's columns); the number of rows written."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise UsageError("--parquet needs pyarrow: pip install 'tanklab[parquet]'") from None
    tags, times, values, texts, codes, names = [], [], [], [], [], []
    for tag, rows in histories.items():
        for row in rows:
            number = _number(row.value)
            tags.append(tag)
            times.append(row.time)
            values.append(number)
            texts.append(None if number is not None or row.value is None else str(row.value))
            codes.append(row.status_code)
            names.append(row.status)
    table = pa.table(
        {
            "tag": pa.array(tags, pa.string()),
            "time": pa.array(times, pa.timestamp("us", tz="UTC")),
            "value": pa.array(values, pa.float64()),
            "text": pa.array(texts, pa.string()),
            "status_code": pa.array(codes, pa.uint32()),
            "status": pa.array(names, pa.string()),
        }
    )
    pq.write_table(table, path)
    return table.num_rows


def plot_history(histories: Histories, path: Path, title: str) -> None:
    """A PNG trend at ``path``: one panel per tag, Bad values as gaps (module docstring)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise UsageError("plot needs matplotlib: pip install 'tanklab[plots]'") from None
    n = max(len(histories), 1)
    fig = Figure(figsize=(10, 2.2 * n + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for ax, (tag, rows) in zip(axes, histories.items(), strict=False):
        ys = [math.nan if is_bad(r.status_code) else _number(r.value) for r in rows]
        ys = [math.nan if y is None else y for y in ys]
        ax.plot([r.time for r in rows], ys, drawstyle="steps-post", linewidth=1.2)
        bad = [r.time for r in rows if is_bad(r.status_code)]
        for t in bad:
            ax.axvline(t, color="tab:red", linewidth=0.6, alpha=0.5)
        ax.set_ylabel(tag, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0].set_title(title, fontsize=9)
    axes[-1].set_xlabel("time (UTC)")
    fig.savefig(path, dpi=100)
