"""A tier's alarm summary as contract values: :class:`~tanklab.alarms.model.AlarmSummary` ->
``<Tier>.AlarmSummary.*`` (pure; the tier's shell publishes the mapping).

The nodes (:func:`tanklab.paths.alarm_summary_paths`, declared in :mod:`tanklab.tags`): the counts
``Active``, ``Unacknowledged``, ``Shelved``, ``Suppressed``, ``Disabled`` (UInt32), the ISA-18.2
figures ``RatePer10Min`` and ``PeakRatePer10Min`` (UInt32, annunciated alarms per 600 s of model
time, one operator position per tier) and ``Flood`` (Boolean, ``RatePer10Min > 10``). The
manager computes them (:meth:`AlarmManager.summary`); docs/alarms.md section "Alarm summary".
"""

from __future__ import annotations

from tanklab.alarms.model import AlarmSummary
from tanklab.paths import Tier, alarm_summary_paths

__all__ = ["summary_values"]


def summary_values(tier: Tier, summary: AlarmSummary) -> dict[str, int | bool]:
    """The value of each of ``tier``'s summary nodes, keyed by path."""
    p = alarm_summary_paths(tier)
    return {
        p["Active"]: summary.active,
        p["Unacknowledged"]: summary.unacked,
        p["Shelved"]: summary.shelved,
        p["Suppressed"]: summary.suppressed,
        p["Disabled"]: summary.disabled,
        p["RatePer10Min"]: summary.rate_per_10min,
        p["PeakRatePer10Min"]: summary.peak_rate_per_10min,
        p["Flood"]: summary.flood,
    }
