"""One condition's OPC UA Part 9 state machine, on model time (pure: no clock, no transport).

A :class:`Condition` holds the state of one configured alarm (:class:`~tanklab.alarms.model.
AlarmDefinition`) and changes it on two kinds of input:

* **process** updates from the alarm manager, after deadband, delays and latching:
  :meth:`Condition.update_process` (active or not, and the active limit of a level alarm),
  :meth:`Condition.set_quality`, :meth:`Condition.set_suppressed`, :meth:`Condition.tick`
  (timed shelving expiry);
* **calls** from clients: :meth:`Condition.call` (Acknowledge, Confirm, AddComment, Enable,
  Disable, OneShotShelve, TimedShelve, Unshelve), answered with a :class:`CallStatus`.

Every accepted call and every state change returns a :class:`ConditionEvent` with a fresh EventId
(:class:`EventIds`: a per-process prefix and a counter). The rules (Part 9, docs/alarms.md):

* a new activation, or a change of the active limit, sets Acked false (and Confirmed false when
  the definition asks for confirmation); Severity is the priority of the active limit, and the
  definition's priority while inactive (Part 5 allows 1..1000 only, so never 0); LastSeverity is
  the Severity before the last change of Severity;
* Retain = Enabled and (Active or not Acked or (confirm and not Confirmed));
* Acknowledge needs the condition's latest EventId (BadEventIdUnknown otherwise) and an unacked
  condition (BadConditionBranchAlreadyAcked); Confirm needs a definition with ``confirm``, the
  latest EventId and an acked, unconfirmed condition;
* Disable raises its own event and no other until Enable; while disabled, Retain is false and the
  process state is recorded but not applied; Enable evaluates the condition afresh: active now
  is a new activation (unacked), inactive now is normal (acked, confirmed);
* shelving: OneShotShelve lasts until the alarm next returns to normal (shelved while normal: the
  next activation's return), TimedShelve(d) until ``t + d`` with ``0 < d <= max``, and any
  shelving ends after the configured maximum at the latest; OneShot <-> Timed transitions are
  allowed (Part 9 has both), the same kind again is BadConditionAlreadyShelved (the timer is not
  restarted); Unshelve of an unshelved condition is BadConditionNotShelved. Shelving does not stop
  the events (the state still changes); it stops the annunciation (:attr:`Condition.annunciating`).

Times are model seconds [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tanklab.alarms.model import (
    AlarmDefinition,
    CallStatus,
    ConditionCall,
    ConditionEvent,
    ConditionKind,
    ConditionSnapshot,
    LimitState,
    Method,
    ShelvingState,
)

__all__ = [
    "ACTIVE",
    "AT_LIMIT",
    "LIMIT_ORDER",
    "NORMAL",
    "Condition",
    "EventIds",
    "ProcessState",
    "process_state",
]

LIMIT_ORDER = (LimitState.HIGH_HIGH, LimitState.HIGH, LimitState.LOW, LimitState.LOW_LOW)
"""The order of ``AlarmDefinition.limits_m`` and ``limit_priorities``."""


class EventIds:
    """EventIds unique per process: ``prefix + counter`` (8 bytes, big-endian, from 1).

    The shell passes a prefix unique to the process (e.g. random or start-time bytes); tests pass a
    fixed one and get deterministic ids.
    """

    __slots__ = ("_count", "prefix")

    def __init__(self, prefix: bytes = b"") -> None:
        self.prefix = bytes(prefix)
        self._count = 0

    @property
    def count(self) -> int:
        """How many ids were handed out."""
        return self._count

    def next(self) -> bytes:
        """A new EventId."""
        self._count += 1
        return self.prefix + self._count.to_bytes(8, "big")


@dataclass(frozen=True, slots=True)
class ProcessState:
    """What the process says after the manager's deadband, delays and latching.

    ``limit`` is the active limit of a level alarm (None for the other kinds, and when inactive).
    """

    active: bool
    limit: LimitState | None = None


NORMAL = ProcessState(False, None)
ACTIVE = ProcessState(True, None)
"""A discrete alarm active."""
AT_LIMIT = {limit: ProcessState(True, limit) for limit in LimitState}
"""A level alarm active at each limit."""


def process_state(active: bool, limit: LimitState | None = None) -> ProcessState:
    """The shared instance of a state (the manager compares states by identity)."""
    if not active:
        return NORMAL
    return ACTIVE if limit is None else AT_LIMIT[limit]


class Condition:
    """The Part 9 state of one condition (see the module docstring for the rules).

    Parameters
    ----------
    definition : the alarm.
    ids : the tier's EventId source (shared by all its conditions).
    max_shelving_time_s : the longest any shelving may last [s] (> 0).
    """

    def __init__(self, definition: AlarmDefinition, ids: EventIds, *, max_shelving_time_s: float) -> None:
        if not (math.isfinite(max_shelving_time_s) and max_shelving_time_s > 0):
            raise ValueError(f"max_shelving_time_s {max_shelving_time_s!r} must be finite and > 0")
        self.definition = definition
        self.ids = ids
        self.max_shelving_time_s = float(max_shelving_time_s)
        self.enabled = definition.enabled
        self.active = False
        self.limit: LimitState | None = None
        self.acked = True
        self.confirmed = True
        self.severity = int(definition.priority)
        self.last_severity = int(definition.priority)
        self.comment = ""
        self.comment_user = ""
        self.quality_good = True
        self.time_s = 0.0
        self.shelving = ShelvingState.UNSHELVED
        self.shelved_until_s = math.inf
        """Model time the current shelving ends at the latest [s] (inf when unshelved)."""
        self.activations = 0
        """New activations and limit changes so far (the manager's alarm rate counts them)."""
        self.suppressed = False
        self.process = NORMAL
        """The latest process state (applied unless disabled)."""
        self.latest: ConditionEvent | None = None
        self.now_s = 0.0
        """The latest model time seen (a call, an update or a tick) [s]."""

    # ---- views ---------------------------------------------------------------------------

    @property
    def name(self) -> str:
        return self.definition.name

    @property
    def retain(self) -> bool:
        """Enabled and (active or unacked or (confirm and unconfirmed))."""
        return self.enabled and (self.active or not self.acked or not self.confirmed)

    @property
    def annunciating(self) -> bool:
        """Shown to the operator now: enabled, active, neither shelved nor suppressed."""
        return (
            self.enabled and self.active and self.shelving is ShelvingState.UNSHELVED and not self.suppressed
        )

    @property
    def latest_event_id(self) -> bytes | None:
        """The EventId an Acknowledge / Confirm / AddComment must name (None before any event)."""
        return None if self.latest is None else self.latest.event_id

    def message(self) -> str:
        """The Message text: the definition's, with the active limit or ``normal``."""
        base = self.definition.message
        if not self.active:
            return f"{base}: normal"
        if self.limit is not None:
            return f"{base}: {self.limit.value}"
        return f"{base}: active"

    def snapshot(self, t_s: float | None = None) -> ConditionSnapshot:
        """The state now (``t_s``: the time the shelving time left is counted at; default the
        latest time seen)."""
        t = self.now_s if t_s is None else t_s
        left = max(0.0, self.shelved_until_s - t) if self.shelving is ShelvingState.TIMED else 0.0
        return ConditionSnapshot(
            name=self.definition.name,
            enabled=self.enabled,
            active=self.active,
            acked=self.acked,
            confirmed=self.confirmed,
            retain=self.retain,
            severity=self.severity,
            last_severity=self.last_severity,
            message=self.message(),
            comment=self.comment,
            comment_user=self.comment_user,
            quality_good=self.quality_good,
            time_s=self.time_s,
            shelving=self.shelving,
            unshelve_time_s=left,
            suppressed=self.suppressed,
            limit_state=self.limit if self.definition.kind is ConditionKind.EXCLUSIVE_LEVEL else None,
        )

    # ---- internals -----------------------------------------------------------------------

    def _event(self, reason: str, t_s: float) -> list[ConditionEvent]:
        self.time_s = t_s
        ev = ConditionEvent(event_id=self.ids.next(), condition=self.snapshot(t_s), reason=reason, t_s=t_s)
        self.latest = ev
        return [ev]

    def _severity_of(self, state: ProcessState) -> int:
        d = self.definition
        if state.active and state.limit is not None and d.limit_priorities is not None:
            return int(d.limit_priorities[LIMIT_ORDER.index(state.limit)])
        return int(d.priority)

    def _set_severity(self, severity: int) -> None:
        if severity != self.severity:
            self.last_severity = self.severity
            self.severity = severity

    def _unshelve(self) -> None:
        self.shelving = ShelvingState.UNSHELVED
        self.shelved_until_s = math.inf

    def _transition(self, state: ProcessState) -> str | None:
        """Move to ``state``; return what changed (None: nothing)."""
        if state.active == self.active and state.limit == self.limit:
            return None
        was_active = self.active
        self.active, self.limit = state.active, state.limit
        self._set_severity(self._severity_of(state))
        if state.active:  # a new activation or a new limit: to be acknowledged (and confirmed)
            self.acked = False
            self.confirmed = not self.definition.confirm
            self.activations += 1
            if state.limit is None:
                return "active"
            return f"limit changed to {state.limit.value}" if was_active else f"active {state.limit.value}"
        if self.shelving is ShelvingState.ONE_SHOT:  # one-shot shelving ends with the return
            self._unshelve()
            return "returned to normal; one-shot shelving ended"
        return "returned to normal"

    def _apply(self, state: ProcessState, t_s: float) -> list[ConditionEvent]:
        reason = self._transition(state)
        return [] if reason is None else self._event(reason, t_s)

    # ---- process -------------------------------------------------------------------------

    def update_process(self, state: ProcessState, t_s: float) -> list[ConditionEvent]:
        """The process state after deadband, delays and latching; events if the state changed."""
        self.now_s = t_s
        self.process = state
        if not self.enabled:
            return []
        return self._apply(state, t_s)

    def set_quality(self, good: bool, t_s: float) -> list[ConditionEvent]:
        """The quality of the alarm's input (an event when it changes, while enabled)."""
        self.now_s = t_s
        if good == self.quality_good:
            return []
        self.quality_good = good
        return self._event("quality good" if good else "quality bad", t_s) if self.enabled else []

    def set_suppressed(self, suppressed: bool, t_s: float) -> list[ConditionEvent]:
        """SuppressedState (e.g. its loop in MANUAL); an event when it changes, while enabled."""
        self.now_s = t_s
        if suppressed == self.suppressed:
            return []
        self.suppressed = suppressed
        return self._event("suppressed" if suppressed else "unsuppressed", t_s) if self.enabled else []

    def tick(self, t_s: float) -> list[ConditionEvent]:
        """Model time passes: a shelving whose time is up ends (an event, while enabled)."""
        self.now_s = t_s
        if self.shelving is ShelvingState.UNSHELVED or t_s < self.shelved_until_s:
            return []
        kind = self.shelving
        self._unshelve()
        if not self.enabled:
            return []
        what = "timed shelving" if kind is ShelvingState.TIMED else "one-shot shelving (maximum time)"
        return self._event(f"{what} expired", t_s)

    def restore(
        self,
        state: ProcessState,
        *,
        enabled: bool,
        acked: bool,
        confirmed: bool,
        comment: str,
        comment_user: str,
        shelving: ShelvingState,
        shelved_until_s: float,
    ) -> None:
        """Warm restart: take retained state as it was (no event; the caller checked it)."""
        self.process = state
        self.enabled = enabled
        self.active, self.limit = state.active, state.limit
        self.acked, self.confirmed = acked, confirmed or not self.definition.confirm
        self.comment, self.comment_user = comment, comment_user
        self.shelving = shelving
        self.shelved_until_s = shelved_until_s if shelving is not ShelvingState.UNSHELVED else math.inf
        self.severity = self.last_severity = self._severity_of(state)

    def restored_event(self, t_s: float) -> list[ConditionEvent]:
        """The event that re-announces a restored condition at model time ``t_s`` [s]
        (:meth:`AlarmManager.restart_events`)."""
        return self._event("restored at warm restart", t_s)

    # ---- calls ---------------------------------------------------------------------------

    def call(self, call: ConditionCall, t_s: float) -> tuple[CallStatus, list[ConditionEvent]]:
        """Answer a client's call at model time ``t_s``; a refused call changes nothing.

        Shelving that expired by ``t_s`` ends first (its event comes before the call's).
        """
        expired = self.tick(t_s)
        status, events = self._call(call, t_s)
        return status, expired + events

    def _call(self, c: ConditionCall, t_s: float) -> tuple[CallStatus, list[ConditionEvent]]:
        m = c.method
        if m is Method.ENABLE:
            if self.enabled:
                return CallStatus.ALREADY_ENABLED, []
            # Evaluated afresh: what happened while disabled is not to be acknowledged.
            self.enabled = True
            self.acked = self.confirmed = True
            self.active, self.limit = False, None
            self._set_severity(self._severity_of(NORMAL))
            change = self._transition(self.process)
            reason = f"enabled by {c.user}" + ("" if change is None else f"; {change}")
            return CallStatus.GOOD, self._event(reason, t_s)
        if m is Method.DISABLE:
            if not self.enabled:
                return CallStatus.ALREADY_DISABLED, []
            self.enabled = False
            return CallStatus.GOOD, self._event(f"disabled by {c.user}", t_s)
        if not self.enabled:
            return CallStatus.DISABLED, []
        if m is Method.ACKNOWLEDGE:
            if c.event_id is None or c.event_id != self.latest_event_id:
                return CallStatus.EVENT_ID_UNKNOWN, []
            if self.acked:
                return CallStatus.ALREADY_ACKED, []
            self.acked = True
            self._take_comment(c)
            return CallStatus.GOOD, self._event(f"acknowledged by {c.user}", t_s)
        if m is Method.CONFIRM:
            if not self.definition.confirm:
                return CallStatus.NOT_CONFIRMABLE, []
            if c.event_id is None or c.event_id != self.latest_event_id:
                return CallStatus.EVENT_ID_UNKNOWN, []
            if self.confirmed:
                return CallStatus.ALREADY_CONFIRMED, []
            if not self.acked:
                return CallStatus.NOT_CONFIRMABLE, []
            self.confirmed = True
            self._take_comment(c)
            return CallStatus.GOOD, self._event(f"confirmed by {c.user}", t_s)
        if m is Method.ADD_COMMENT:
            if c.event_id is None or c.event_id != self.latest_event_id:
                return CallStatus.EVENT_ID_UNKNOWN, []
            self.comment, self.comment_user = c.comment, c.user
            return CallStatus.GOOD, self._event(f"comment by {c.user}", t_s)
        if m is Method.ONE_SHOT_SHELVE:
            if self.shelving is ShelvingState.ONE_SHOT:
                return CallStatus.ALREADY_SHELVED, []
            self.shelving = ShelvingState.ONE_SHOT
            self.shelved_until_s = t_s + self.max_shelving_time_s
            return CallStatus.GOOD, self._event(f"shelved (one shot) by {c.user}", t_s)
        if m is Method.TIMED_SHELVE:
            d = c.shelving_time_s
            if self.shelving is ShelvingState.TIMED:
                return CallStatus.ALREADY_SHELVED, []
            if not (math.isfinite(d) and 0.0 < d <= self.max_shelving_time_s):
                return CallStatus.SHELVING_TIME_OUT_OF_RANGE, []
            self.shelving = ShelvingState.TIMED
            self.shelved_until_s = t_s + d
            return CallStatus.GOOD, self._event(f"shelved for {d:g} s by {c.user}", t_s)
        if m is Method.UNSHELVE:
            if self.shelving is ShelvingState.UNSHELVED:
                return CallStatus.NOT_SHELVED, []
            self._unshelve()
            return CallStatus.GOOD, self._event(f"unshelved by {c.user}", t_s)
        raise ValueError(f"unknown method {m!r}")  # pragma: no cover - Method is closed

    def _take_comment(self, c: ConditionCall) -> None:
        # Part 9: an empty comment on Acknowledge / Confirm leaves the Comment as it is.
        if c.comment:
            self.comment, self.comment_user = c.comment, c.user
