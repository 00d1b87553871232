"""What ``tankctl history`` prints (issue 16): a text table, CSV or JSON, from the rows of
:mod:`tankctl.ops.history_read` (the Parquet file and the PNG trend: :mod:`tankctl.history_files`).

- Text: one line per value, ``time  tag  value  status`` (time in UTC, ISO 8601 to the
  millisecond), the status name only where it is not plain Good.
- CSV: the header ``tag,time,value,status,status_code``, one row per value.
- JSON: a list of ``{"tag", "time", "value", "status", "status_code"}`` objects.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence

from tankctl.ops.history_read import EventRow, HistoryRow

Histories = Mapping[str, Sequence[HistoryRow]]
"""Rows per tag, in the order the tags were asked for."""


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
