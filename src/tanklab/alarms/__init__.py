"""Alarms: the seam types (``model``) shared by the pure alarm core and the OPC UA projection, and
the core: one condition's Part 9 state machine (``condition``) and ISA-18.2 management over a tier's
conditions (``manager``). The PLC's definitions from a site config are in ``definitions`` (not
imported here: it imports the config, which imports ``names``). docs/alarms.md describes them."""

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
