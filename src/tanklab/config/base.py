"""What every config model shares: the base model (unknown keys are errors), value types, name rules."""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

GRAVITY_M_S2 = 9.81
"""Standard gravity used by every Torricelli flow [m/s^2] (the papers' value)."""

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]

NUMBER = r"[1-9][0-9]?"
"""A tank, pump, loop or transmitter number: 1..99, no leading zero (decision 0045)."""

TANK_NAME = rf"^T{NUMBER}$"
PUMP_NAME = rf"^P{NUMBER}$"
LOOP_NAME = rf"^LIC{NUMBER}$"
TRANSMITTER_NAME = rf"^LT{NUMBER}$"
VALVE_NAME = r"^V[1-9][0-9]{1,3}$"
"""``V{m}{n}``: upstream tank number m (1..99), downstream n (1..99, 0 = the drain).

The shape alone cannot tell V123 (T1 -> T23) from V123 (T12 -> T3): the plant's validation
derives the name from the valve's tanks and refuses two valves that get the same one."""


def numeric_key(name: str) -> tuple[str | int, ...]:
    """Sort key that reads the numbers in a name as numbers: T2 before T10, LIC2PvBad before
    LIC10PvBad (plain string order puts "T10" first). Text and number parts alternate, text first,
    so two keys always compare like with like."""
    return tuple(int(part) if k % 2 else part for k, part in enumerate(re.split(r"(\d+)", name)))


class Model(BaseModel):
    """Base of every config model: unknown keys are errors, values are checked on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False)
