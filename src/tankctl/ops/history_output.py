"""What ``tankctl history`` prints or writes (issue 16): a text table, CSV, JSON, a Parquet file
and a PNG trend, all from the rows of :mod:`tankctl.ops.history_read`.

- Text: one line per value, ``time  tag  value  status`` (time in UTC, ISO 8601 to the
  millisecond), the status name only where it is not plain Good.
- CSV: the header ``tag,time,value,status,status_code``, one row per value.
- JSON: a list of ``{"tag", "time", "value", "status", "status_code"}`` objects.
- Parquet (pyarrow, the ``parquet`` extra): columns ``tag`` (string), ``time`` (timestamp[us, UTC]),
  ``value`` (float64; null where the value is not a number), ``text`` (string: the value of a
  non-numeric tag), ``status_code`` (uint32), ``status`` (string).
- PNG (matplotlib, the ``plots`` extra): one panel per tag sharing the time axis; values whose
  status is Bad are gaps, not points, so a gap the historian marked shows as a break.

pyarrow and matplotlib are imported where they are used, so the other formats and every other
command never load them; missing, they are a one-line error naming the extra to install.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tankctl.ops.errors import UsageError
from tankctl.ops.history_read import EventRow, HistoryRow

Histories = Mapping[str, Sequence[HistoryRow]]
"""Rows per tag, in the order the tags were asked for."""

_BAD = 0x8000_0000
_SEVERITY = 0xC000_0000


def _is_bad(code: int) -> bool:
    return code & _SEVERITY == _BAD


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float):
        return float(value)
    return None


def _stamp(row: HistoryRow) -> str:
    return row.time.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def render_text(histories: Histories) -> str:
    """The text table (module docstring); ``(no values)`` when every history is empty."""
    lines = []
    width = max((len(tag) for tag in histories), default=0)
    for tag, rows in histories.items():
        for row in rows:
            status = "" if row.status == "Good" else row.status
            lines.append(f"{_stamp(row)}  {tag:<{width}}  {row.value!s:>12}  {status}".rstrip())
    return "\n".join(lines) if lines else "(no values)"


def render_csv(histories: Histories) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["tag", "time", "value", "status", "status_code"])
    for tag, rows in histories.items():
        for row in rows:
            writer.writerow(
                [tag, _stamp(row), "" if row.value is None else row.value, row.status, row.status_code]
            )
    return out.getvalue()


def render_json(histories: Histories) -> str:
    return json.dumps([row.as_json(tag) for tag, rows in histories.items() for row in rows], indent=1)


def render_events(rows: Sequence[EventRow], as_json: bool) -> str:
    """``alarms --history``: one line per event (time, severity, source, message), or JSON."""
    if as_json:
        return json.dumps([row.as_json() for row in rows], indent=1)
    if not rows:
        return "(no events)"
    width = max(len(row.source) for row in rows)
    return "\n".join(
        f"{row.time.isoformat(timespec='milliseconds').replace('+00:00', 'Z')}  {row.severity:>4}  "
        f"{row.source:<{width}}  {row.message}"
        for row in rows
    )


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
    """A PNG trend: one panel per tag, Bad values as gaps (module docstring)."""
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
        ys = [math.nan if _is_bad(r.status_code) else _number(r.value) for r in rows]
        ys = [math.nan if y is None else y for y in ys]
        ax.plot([r.time for r in rows], ys, drawstyle="steps-post", linewidth=1.2)
        bad = [r.time for r in rows if _is_bad(r.status_code)]
        for t in bad:
            ax.axvline(t, color="tab:red", linewidth=0.6, alpha=0.5)
        ax.set_ylabel(tag, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0].set_title(title, fontsize=9)
    axes[-1].set_xlabel("time (UTC)")
    fig.savefig(path, dpi=100)
