"""Alarms: the seam types (``model``) shared by the pure alarm core and the OPC UA projection."""

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
]
