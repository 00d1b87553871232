"""Alarm definitions shared by the alarm condition, manager and summary tests: one exclusive
level alarm with a deadband, limit priorities and its PLC.Alarms booleans, one discrete PV-bad
alarm and one latched interlock trip that asks for confirmation."""

from __future__ import annotations

from tanklab.alarms.model import AlarmDefinition, ConditionKind, LimitState, Priority

HH, H, L, LL = LimitState.HIGH_HIGH, LimitState.HIGH, LimitState.LOW, LimitState.LOW_LOW
LIMITS = (1.0, 0.8, 0.2, 0.1)
DB = 0.02

LEVEL = AlarmDefinition(
    name="T1Level",
    kind=ConditionKind.EXCLUSIVE_LEVEL,
    source="src",
    message="T1 level",
    priority=Priority.MEDIUM,
    limits_m=LIMITS,
    limit_priorities=(Priority.URGENT, Priority.MEDIUM, Priority.MEDIUM, Priority.HIGH),
    deadband_m=DB,
    suppress_when_manual="LIC1",
    limit_boolean_paths=("b.HH", "b.H", "b.L", None),
)
PVBAD = AlarmDefinition(
    name="LIC1PvBad",
    kind=ConditionKind.DISCRETE,
    source="src",
    message="LIC1 PV bad",
    priority=Priority.HIGH,
    boolean_path="b.PvBad",
)
TRIP = AlarmDefinition(
    name="T1Trip",
    kind=ConditionKind.OFF_NORMAL,
    source="src",
    message="T1 trip",
    priority=Priority.URGENT,
    latched=True,
    confirm=True,
)
