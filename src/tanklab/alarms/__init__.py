"""Alarms: the seam types (``model``) shared by the pure alarm core and the OPC UA projection, and
the core: one condition's Part 9 state machine (``condition``) and ISA-18.2 management over a tier's
conditions (``manager``). The PLC's definitions from a site config are in ``definitions`` (not
imported here: it imports the config, which imports ``names``). docs/alarms.md describes them."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tanklab.alarms.condition import Condition, EventIds, ProcessState
    from tanklab.alarms.manager import AlarmInput, AlarmManager
    from tanklab.alarms.model import (
        AlarmDefinition,
        AlarmSummary,
        CallStatus,
        ConditionCall,
        ConditionEvent,
        ConditionKind,
        ConditionSnapshot,
        LimitState,
        Method,
        Priority,
        ShelvingState,
    )

_HOME = {
    **dict.fromkeys(("Condition", "EventIds", "ProcessState"), "condition"),
    **dict.fromkeys(("AlarmInput", "AlarmManager"), "manager"),
    **dict.fromkeys(
        (
            "AlarmDefinition",
            "AlarmSummary",
            "CallStatus",
            "ConditionCall",
            "ConditionEvent",
            "ConditionKind",
            "ConditionSnapshot",
            "LimitState",
            "Method",
            "Priority",
            "ShelvingState",
        ),
        "model",
    ),
}
"""Where each exported name is defined: the package imports it on first use (PEP 562), so a
module that needs only ``tanklab.alarms.model`` (the config, an operator command) does not load
the state machine and the manager (decision 0044)."""


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


__all__ = [
    "AlarmDefinition",
    "AlarmInput",
    "AlarmManager",
    "AlarmSummary",
    "CallStatus",
    "Condition",
    "ConditionCall",
    "ConditionEvent",
    "ConditionKind",
    "ConditionSnapshot",
    "EventIds",
    "LimitState",
    "Method",
    "Priority",
    "ProcessState",
    "ShelvingState",
]
