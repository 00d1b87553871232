"""The alarm seam: what an alarm is, what its condition publishes, and what a client may ask.

These value types are shared by the pure alarm core (``tanklab.alarms``: the OPC UA Part 9
condition state machine and ISA-18.2 / IEC 62682 alarm management, run on model time inside a
tier's scan or cycle) and by the OPC UA projection (``tanklab_io.ua_conditions``: condition nodes,
events, methods, ConditionRefresh). Neither side imports the other; both speak these types.

Vocabulary (OPC UA Part 9, ISA-18.2):

* a **definition** is configuration: which condition exists, its type, its source node, its
  priority, limits, deadband and delays;
* a **snapshot** is the condition's state at one moment (the fields every event carries);
* an **event** is one state change: a new unique EventId, the snapshot after the change, and why;
* a **call** is a client's method call (Acknowledge, Confirm, AddComment, Enable, Disable,
  OneShotShelve, TimedShelve, Unshelve), answered with a :class:`CallStatus`.

Times are model seconds (``t_s``, the tier's clock); the projection converts them to UTC stamps.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum


class ConditionKind(StrEnum):
    """The OPC UA condition type a definition is instantiated as (its BrowseName)."""

    EXCLUSIVE_LEVEL = "ExclusiveLevelAlarmType"
    """A level with exclusive limits (HighHigh > High > Low > LowLow): one condition per variable."""
    OFF_NORMAL = "OffNormalAlarmType"
    """A discrete input away from its normal state (an interlock trip, an I/O fault)."""
    DISCRETE = "DiscreteAlarmType"
    """A discrete condition with no normal-state node (a supervisor's own failures)."""


class LimitState(StrEnum):
    """The active limit of an exclusive level alarm (Part 9 ExclusiveLimitStateMachineType)."""

    HIGH_HIGH = "HighHigh"
    HIGH = "High"
    LOW = "Low"
    LOW_LOW = "LowLow"


class Priority(IntEnum):
    """ISA-18.2 priority, valued as the OPC UA Severity it maps to (1..1000; docs/alarms.md)."""

    LOW = 250
    MEDIUM = 500
    HIGH = 700
    URGENT = 900


class ShelvingState(StrEnum):
    """Part 9 ShelvedStateMachineType's states."""

    UNSHELVED = "Unshelved"
    ONE_SHOT = "OneShotShelved"
    TIMED = "TimedShelved"


class Method(StrEnum):
    """The condition methods a client may call (their Part 9 BrowseNames)."""

    ACKNOWLEDGE = "Acknowledge"
    CONFIRM = "Confirm"
    ADD_COMMENT = "AddComment"
    ENABLE = "Enable"
    DISABLE = "Disable"
    ONE_SHOT_SHELVE = "OneShotShelve"
    TIMED_SHELVE = "TimedShelve"
    UNSHELVE = "Unshelve"


class CallStatus(StrEnum):
    """A call's outcome, valued as the OPC UA StatusCode name the projection answers with."""

    GOOD = "Good"
    EVENT_ID_UNKNOWN = "BadEventIdUnknown"
    """The EventId is not the condition's latest (a stale or foreign event)."""
    ALREADY_ACKED = "BadConditionBranchAlreadyAcked"
    ALREADY_CONFIRMED = "BadConditionBranchAlreadyConfirmed"
    ALREADY_ENABLED = "BadConditionAlreadyEnabled"
    ALREADY_DISABLED = "BadConditionAlreadyDisabled"
    DISABLED = "BadConditionDisabled"
    """Acknowledge, Confirm, AddComment and shelving of a disabled condition."""
    ALREADY_SHELVED = "BadConditionAlreadyShelved"
    NOT_SHELVED = "BadConditionNotShelved"
    SHELVING_TIME_OUT_OF_RANGE = "BadShelvingTimeOutOfRange"
    NOT_CONFIRMABLE = "BadMethodInvalid"
    """Confirm of a condition whose definition does not ask for confirmation, or not yet acked."""
    UNKNOWN_CONDITION = "BadNodeIdUnknown"


@dataclass(frozen=True, slots=True)
class AlarmDefinition:
    """One configured alarm: a condition instance in the address space.

    Attributes
    ----------
    name : the condition's name, unique in its tier (``T1Level``, ``LIC1PvBad``, ``T1HighHigh``).
    kind : the condition type.
    source : contract path of the source node (the tank's transmitter, the loop, the interlock)
        whose notifier chain reports the condition's events.
    message : the base text of the condition's Message (the core appends the limit state).
    priority : ISA-18.2 priority; Severity while active (per limit for level alarms, see
        ``limit_priorities``).
    input_path : contract path of the variable the alarm watches (the InputNode), or None.
    limits_m : level alarms only: the configured limits, (HighHigh, High, Low, LowLow) [m], each
        None when not configured.
    limit_priorities : level alarms only: the priority per limit, in the order of ``limits_m``.
    deadband_m : level alarms: the return-to-normal deadband [m] (EEMUA default 2 % of range).
    on_delay_s, off_delay_s : the condition must hold (on) or be gone (off) this long in model
        time before ActiveState changes [s].
    latched : stays active after its input returns to normal until reset (interlock trips).
    confirm : Acknowledge leaves it unconfirmed, to be confirmed (ConfirmedState is used).
    suppress_when_manual : a loop name: while that loop is in MANUAL (out of service) the alarm is
        suppressed (SuppressedState true; no annunciation), or None.
    boolean_path : the ``PLC.Alarms.*`` boolean that follows ActiveState (kept by the contract),
        or None.
    limit_boolean_paths : level alarms only: the ``PLC.Alarms.*`` booleans of the limits, in the
        order of ``limits_m``, each None when there is none (``T1HH``, ``T1H``, ``T1L``, None). Each
        is its limit's own comparison (with deadband) as the ActiveState was evaluated: High and
        Low only with a good reading, HighHigh on any finite one (today's meaning).
    enabled : the EnabledState at a cold start (a configured ``enabled: false``); a warm restart
        restores the retained one.
    """

    name: str
    kind: ConditionKind
    source: str
    message: str
    priority: Priority
    input_path: str | None = None
    limits_m: tuple[float | None, float | None, float | None, float | None] | None = None
    limit_priorities: tuple[Priority, Priority, Priority, Priority] | None = None
    deadband_m: float = 0.0
    on_delay_s: float = 0.0
    off_delay_s: float = 0.0
    latched: bool = False
    confirm: bool = False
    suppress_when_manual: str | None = None
    boolean_path: str | None = None
    limit_boolean_paths: tuple[str | None, str | None, str | None, str | None] | None = None
    enabled: bool = True


@dataclass(frozen=True, slots=True)
class ConditionSnapshot:
    """A condition's state: every field its events carry (Part 9 ConditionType and subtypes).

    Attributes
    ----------
    name : the definition's name.
    enabled, active, acked, confirmed : the two-state variables' Id values.
    retain : true while the condition is of interest (active, or not yet acked / confirmed).
    severity, last_severity : current and previous Severity (1..1000).
    message : the Message text.
    comment, comment_user : the last comment and who made it ("" for none).
    quality_good : whether the alarm's input is Good (Quality = Good or Bad).
    time_s : model time of the last state change [s].
    shelving : the shelving state; ``unshelve_time_s``: model time left until it unshelves
        (timed shelving; 0 otherwise) [s].
    suppressed : SuppressedState (e.g. while the loop is in MANUAL).
    limit_state : exclusive level alarms only: the active limit (None when inactive or another
        kind).
    """

    name: str
    enabled: bool
    active: bool
    acked: bool
    confirmed: bool
    retain: bool
    severity: int
    last_severity: int
    message: str
    comment: str
    comment_user: str
    quality_good: bool
    time_s: float
    shelving: ShelvingState
    unshelve_time_s: float
    suppressed: bool
    limit_state: LimitState | None = None


@dataclass(frozen=True, slots=True)
class ConditionEvent:
    """One state change of a condition, as its event reports it.

    ``event_id`` is unique among every event a tier process ever raises (the core takes a per-
    process prefix from its shell and counts); a client acknowledges with it.
    """

    event_id: bytes
    condition: ConditionSnapshot
    reason: str
    """What changed, in words for the audit log and the event's Message suffix ("active High",
    "acknowledged by alice", "shelved for 900 s", ...)."""
    t_s: float


@dataclass(frozen=True, slots=True)
class ConditionCall:
    """A client's method call on a condition.

    ``event_id`` is the EventId argument of Acknowledge / Confirm / AddComment (None for the
    others); ``shelving_time_s`` is TimedShelve's ShelvingTime converted from ms [s]; ``user`` is
    the session's user name (for ClientUserId and the audit log).
    """

    condition: str
    method: Method
    user: str
    event_id: bytes | None = None
    comment: str = ""
    shelving_time_s: float = 0.0


@dataclass(frozen=True, slots=True)
class AlarmSummary:
    """A tier's alarm summary node values and ISA-18.2 rate figures (one operator position per
    tier: the rate is the tier's own).

    Attributes
    ----------
    active, unacked, shelved, suppressed : counts of the *enabled* conditions that are active,
        not acknowledged, shelved (one-shot or timed), suppressed (e.g. their loop in MANUAL).
    disabled : count of the disabled conditions (not in the other counts: Part 9 says a disabled
        condition reports nothing).
    rate_per_10min : annunciated alarms (new activations and new limits of enabled conditions
        that were neither shelved nor suppressed) in the rate window ``(t - 600 s, t]`` of model
        time.
    peak_rate_per_10min : the largest ``rate_per_10min`` since the tier started (it can only
        rise at an activation, so it is the largest count at an activation instant).
    flood : whether ``rate_per_10min`` exceeds the flood threshold (ISA-18.2 / EEMUA 191: more
        than 10 per 10 min per operator position).
    """

    active: int
    unacked: int
    shelved: int
    suppressed: int
    disabled: int
    rate_per_10min: int
    peak_rate_per_10min: int
    flood: bool
