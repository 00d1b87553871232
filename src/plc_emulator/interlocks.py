"""The PLC's high-high interlocks: latch on a reading, reset by an operator below the reset level.

Pure: readings in, forced pumps out. A delivered, finite reading at or above high-high trips its
tank (over-range and frozen readings included: fail-safe), with any mode, gains or supervisor
state; the trip latches until the level is below ``reset_below_m`` and an operator resets it.
The program then forces the tank's pumps to their lowest command and tells the loops (docs/plc.md
section 6).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Interlock", "latch", "reset_trips"]


@dataclass
class Interlock:
    """One tank's interlock (levels in m)."""

    tank: int  # tank index
    tank_name: str
    high_high_m: float
    reset_below_m: float
    tripped: bool = False


def latch(interlocks: list[Interlock], raw_m: list[float], pump_tank: list[int]) -> list[bool] | None:
    """Latch trips on this scan's delivered readings ``raw_m`` [m] (NaN where none was delivered);
    return which pumps (pump order; ``pump_tank`` their tanks) are forced, None when none is."""
    any_tripped = False
    for il in interlocks:
        if raw_m[il.tank] >= il.high_high_m:
            il.tripped = True
        any_tripped = any_tripped or il.tripped
    if not any_tripped:
        return None
    tripped = [False] * len(raw_m)
    for il in interlocks:
        tripped[il.tank] = tripped[il.tank] or il.tripped
    return [tripped[tank] for tank in pump_tank]


def reset_trips(interlocks: list[Interlock], levels_m: list[float], good: list[bool]) -> list[str]:
    """Reset latched trips whose (good) level is below the reset level; return the tanks reset."""
    reset = []
    for il in interlocks:
        if il.tripped and good[il.tank] and levels_m[il.tank] < il.reset_below_m:
            il.tripped = False
            reset.append(il.tank_name)
    return reset
