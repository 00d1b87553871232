"""The alarm summary of a tier as an operator command shows it (``tankctl status``, the
``tankctl up`` board): the ``<Tier>.AlarmSummary.*`` nodes (docs/alarms.md) read with the rest,
shaped into the status document's ``alarm_summary`` and one line of text.

Pure: values keyed by node path in, a mapping or a line out (no client, no numerics: the
operator path stays lean, decisions 0023 and 0039).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tanklab.paths import AlarmSummaryItem, Tier, alarm_summary_paths

__all__ = ["SUMMARY_TIERS", "summary_json", "summary_line", "summary_paths", "unacknowledged_line"]

SUMMARY_TIERS: tuple[Tier, ...] = ("plc", "supervisor")
"""The tiers with an alarm summary (each one operator position), in the order lines show them."""
_NAMES: dict[Tier, str] = {"plant": "plant", "plc": "PLC", "supervisor": "supervisor"}

_KEYS: dict[AlarmSummaryItem, str] = {
    "Active": "active",
    "Unacknowledged": "unacknowledged",
    "Shelved": "shelved",
    "Suppressed": "suppressed",
    "Disabled": "disabled",
    "RatePer10Min": "rate_per_10min",
    "PeakRatePer10Min": "peak_rate_per_10min",
    "Flood": "flood",
}
"""Node item -> key of the status document's ``alarm_summary``."""


def summary_paths(tier: Tier) -> list[str]:
    """The summary node paths of ``tier`` (to read them with the tier's other nodes)."""
    return list(alarm_summary_paths(tier).values())


def summary_json(tier: Tier, values: Mapping[str, Any]) -> dict[str, Any]:
    """``tier``'s ``alarm_summary`` from ``values`` keyed by path (a node missing from
    ``values`` is None: a tier that predates the summary)."""
    return {key: values.get(alarm_summary_paths(tier)[item]) for item, key in _KEYS.items()}


def summary_line(tier: Tier, s: Mapping[str, Any]) -> str:
    """``PLC alarms: 2 active, 1 unacknowledged, 0 shelved, rate 3/10 min`` (``, FLOOD`` while
    flooding; suppressed and disabled counts when not 0)."""
    if s.get("active") is None:
        return f"{_NAMES[tier]} alarms: no summary"
    counts = f"{s['active']} active, {s['unacknowledged']} unacknowledged, {s['shelved']} shelved"
    text = f"{_NAMES[tier]} alarms: {counts}"
    for key in ("suppressed", "disabled"):
        if s.get(key):
            text += f", {s[key]} {key}"
    text += f", rate {s['rate_per_10min']}/10 min (peak {s['peak_rate_per_10min']})"
    return text + (", FLOOD" if s["flood"] else "")


def unacknowledged_line(summaries: Mapping[Tier, Mapping[str, Any]]) -> str:
    """The board's line: ``unacknowledged alarms: PLC 1, supervisor 0`` (``?`` for a tier not
    read; ``FLOOD`` after a tier that floods)."""
    parts = []
    for tier, s in summaries.items():
        n = s.get("unacknowledged")
        part = f"{_NAMES[tier]} {'?' if n is None else n}"
        parts.append(part + (" FLOOD" if s.get("flood") else ""))
    return "unacknowledged alarms: " + ", ".join(parts)
