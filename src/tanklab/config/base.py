"""What every config model shares: the base model (unknown keys are errors), value types, name rules."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

GRAVITY_M_S2 = 9.81
"""Standard gravity used by every Torricelli flow [m/s^2] (the papers' value)."""

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]

TANK_NAME = r"^T[1-9]$"
PUMP_NAME = r"^P[1-9]$"
LOOP_NAME = r"^LIC[1-9]$"
VALVE_NAME = r"^V[0-9][0-9]$"


class Model(BaseModel):
    """Base of every config model: unknown keys are errors, values are checked on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False)
