"""ISA-18.2 / IEC 62682 alarm management over a tier's conditions, run on model time (pure).

Each scan (:meth:`AlarmManager.scan`) takes per alarm its input (a level [m] or a discrete
value, and the input's quality) and, per alarm, in order:

1. **Raw state with deadband** (level alarms, exclusive limits): each configured limit has a
   flag, set by its own comparison of the reading ``x`` [m] with deadband ``d`` [m] while the
   flag was set last scan (hysteresis):

   * HighHigh: ``x >= HH`` (``x >= HH - d`` while set), on any finite reading, good or not
     (fail-safe, like the interlock);
   * with a good reading only: High ``x >= H`` (``H - d``), Low ``x <= L`` (``L + d``),
     LowLow ``x <= LL`` (``LL + d``); a bad reading sets none of these (the PvBad alarm says the
     reading is bad).

   The limit state is the most severe flag set: HighHigh, High, LowLow, Low; none set is normal.
   So a level oscillating inside ``[H - d, H)`` after an activation never returns to normal and
   never re-activates: no chatter. Discrete alarms are active while their input is true.
2. **Delays** on model time: a new raw state must hold ``on_delay_s`` (an activation or a new
   limit) or ``off_delay_s`` (a return to normal) before it becomes the ActiveState; a raw state
   that goes back to the ActiveState before cancels the pending change.
3. **Latching**: a latched alarm (interlock trips) stays active when its input returns to normal,
   until :meth:`AlarmManager.reset`.
4. **Suppression**: SuppressedState while the loop named by ``suppress_when_manual`` is in MANUAL.
5. **Shelving expiry** (``tick``).

Alarm rate (ISA-18.2, per operator position: one position per tier): the annunciated activations
(new activations and new limits, not shelved, suppressed or disabled; an Enable that finds the
process off normal is one too) at model times ``t_k`` [s]; at model time ``t`` [s]

    rate(t) = #{k : t - W < t_k <= t},   W = ``rate_window_s`` (600 s),
    peak(t) = max(rate(t_k) for t_k <= t),   flood(t) = rate(t) > ``flood_threshold`` (10),

so the activation at ``t_k`` leaves the window at exactly ``t_k + W`` (:meth:`AlarmManager.
rate_expiring`), and the counts are those of :func:`summarize`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from tanklab.alarms.condition import (
    ACTIVE,
    AT_LIMIT,
    LIMIT_ORDER,
    NORMAL,
    Condition,
    EventIds,
    ProcessState,
    process_state,
)
from tanklab.alarms.model import (
    AlarmDefinition,
    AlarmSummary,
    CallStatus,
    ConditionCall,
    ConditionEvent,
    ConditionKind,
    ConditionSnapshot,
    LimitState,
    ShelvingState,
)

__all__ = [
    "DEFAULT_MAX_SHELVING_TIME_S",
    "FLOOD_THRESHOLD",
    "RATE_WINDOW_S",
    "AlarmInput",
    "AlarmManager",
    "classify_level",
    "summarize",
]

DEFAULT_MAX_SHELVING_TIME_S = 8 * 3600.0
"""The longest shelving allowed unless configured [s] (one shift)."""
RATE_WINDOW_S = 600.0
"""ISA-18.2's alarm-rate window [s]."""
FLOOD_THRESHOLD = 10
"""ISA-18.2: more than this many annunciated alarms per window per operator position is a flood."""

_HH, _H, _L, _LL = LIMIT_ORDER
_HIGH_SIDE = (_HH, _H)
_LOW_SIDE = (_L, _LL)


def summarize(
    conditions: Iterable[Condition], rate_per_10min: int, peak_rate_per_10min: int, flood_threshold: int
) -> AlarmSummary:
    """The summary of ``conditions`` (pure): per enabled condition whether it is active, not
    acknowledged, shelved, suppressed, the count of disabled ones, and the rate figures as
    given (``flood``: ``rate_per_10min > flood_threshold``)."""
    active = unacked = shelved = suppressed = disabled = 0
    unshelved = ShelvingState.UNSHELVED
    for c in conditions:
        if not c.enabled:
            disabled += 1
            continue
        active += c.active
        unacked += not c.acked
        shelved += c.shelving is not unshelved
        suppressed += c.suppressed
    return AlarmSummary(
        active=active,
        unacked=unacked,
        shelved=shelved,
        suppressed=suppressed,
        disabled=disabled,
        rate_per_10min=rate_per_10min,
        peak_rate_per_10min=max(peak_rate_per_10min, rate_per_10min),
        flood=rate_per_10min > flood_threshold,
    )


@dataclass(frozen=True, slots=True)
class AlarmInput:
    """One alarm's input in a scan: a level [m] (NaN: nothing delivered) or a discrete value
    (true: off normal), and the input's quality."""

    value: float | bool
    good: bool = True


Flags = tuple[bool, bool, bool, bool]
"""Per limit (HighHigh, High, Low, LowLow): whether the reading is beyond it (with deadband)."""

_OFF: Flags = (False, False, False, False)


def classify_level(
    x_m: float,
    good: bool,
    limits_m: tuple[float | None, float | None, float | None, float | None],
    deadband_m: float,
    last: Flags = _OFF,
) -> tuple[ProcessState, Flags]:
    """The raw exclusive limit state of reading ``x_m`` (see the module docstring, step 1).

    Parameters
    ----------
    x_m : the reading [m] (NaN: none).
    good : its quality.
    limits_m : (HighHigh, High, Low, LowLow) [m], None where not configured.
    deadband_m : the return-to-normal deadband [m].
    last : the flags of the previous scan.

    Returns
    -------
    The state (the most severe limit whose flag is set: HighHigh, High, LowLow, Low) and the
    flags: each limit's own comparison, with the deadband while its flag was set last scan.
    """
    hh, h, lo, ll = limits_m
    finite = math.isfinite(x_m)
    usable = finite and good
    d = deadband_m
    f_hh = finite and hh is not None and x_m >= (hh - d if last[0] else hh)
    f_h = usable and h is not None and x_m >= (h - d if last[1] else h)
    f_l = usable and lo is not None and x_m <= (lo + d if last[2] else lo)
    f_ll = usable and ll is not None and x_m <= (ll + d if last[3] else ll)
    flags = (f_hh, f_h, f_l, f_ll)
    for on, limit in ((f_hh, _HH), (f_h, _H), (f_ll, _LL), (f_l, _L)):
        if on:
            return AT_LIMIT[limit], flags
    return NORMAL, flags


def _quiet(d: AlarmDefinition) -> tuple[float, float]:
    """The open interval of readings that set no limit flag of a level alarm at normal (an empty
    one for the other kinds: NaN compares false)."""
    if d.limits_m is None:
        return (math.nan, math.nan)
    hh, h, lo, ll = d.limits_m
    highs = [v for v in (hh, h) if v is not None]
    lows = [v for v in (lo, ll) if v is not None]
    return (max(lows, default=-math.inf), min(highs, default=math.inf))


@dataclass(slots=True)
class _Track:
    """The manager's per-alarm memory between scans."""

    raw: ProcessState = NORMAL
    """The raw state of the last scan (after deadband, before delays)."""
    raw_flags: Flags = _OFF
    state: ProcessState = NORMAL
    """After delays and latching: the ActiveState the condition follows."""
    flags: Flags = _OFF
    """Level alarms: the flags ``state`` was evaluated with (the booleans show them)."""
    pending: ProcessState | None = None
    since_s: float = 0.0
    """Model time ``pending`` was first seen [s]."""
    good: bool = True
    """The input's quality in the last scan."""
    last: float | bool | None = None
    """The input of the last scan (None before the first)."""
    primed: bool = False
    """``state`` was set by :meth:`AlarmManager.prime`: the first input replaces it at once."""


class AlarmManager:
    """The alarms of one tier: conditions, deadband, delays, latching, suppression, rates.

    Parameters
    ----------
    definitions : the tier's alarms (names unique).
    event_prefix : the EventId prefix, unique per process (the shell's; tests pass a fixed one).
    max_shelving_time_s : the longest shelving allowed [s] (> 0).
    rate_window_s, flood_threshold : the alarm-rate window [s] and the flood threshold.

    Raises
    ------
    ValueError
        Two definitions share a name; a level definition without limits.
    """

    def __init__(
        self,
        definitions: tuple[AlarmDefinition, ...],
        *,
        event_prefix: bytes = b"",
        max_shelving_time_s: float = DEFAULT_MAX_SHELVING_TIME_S,
        rate_window_s: float = RATE_WINDOW_S,
        flood_threshold: int = FLOOD_THRESHOLD,
    ) -> None:
        names = [d.name for d in definitions]
        if len(set(names)) != len(names):
            raise ValueError(f"alarm names must be unique: {names}")
        for d in definitions:
            if d.kind is ConditionKind.EXCLUSIVE_LEVEL and d.limits_m is None:
                raise ValueError(f"level alarm {d.name} needs limits_m")
        self.definitions = tuple(definitions)
        self.ids = EventIds(event_prefix)
        self.max_shelving_time_s = float(max_shelving_time_s)
        self.rate_window_s = float(rate_window_s)
        self.flood_threshold = int(flood_threshold)
        self._conditions = {
            d.name: Condition(d, self.ids, max_shelving_time_s=max_shelving_time_s) for d in definitions
        }
        self._tracks = {d.name: _Track() for d in definitions}
        self._rows = [(d, self._conditions[d.name], self._tracks[d.name], *_quiet(d)) for d in definitions]
        self._annunciated: deque[float] = deque()
        self._peak_rate = 0
        """The largest count of annunciated activations in one window so far."""
        self._booleans: dict[str, bool] | None = None
        """:meth:`booleans` as last built (None: to be rebuilt; most scans change none)."""
        self.t_s = 0.0

    # ---- access --------------------------------------------------------------------------

    def condition(self, name: str) -> Condition:
        """The condition called ``name`` (KeyError if none)."""
        return self._conditions[name]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._conditions)

    # ---- the scan ------------------------------------------------------------------------

    def scan(
        self, inputs: Mapping[str, AlarmInput], t_s: float, *, manual: Collection[str] = ()
    ) -> list[ConditionEvent]:
        """One scan at model time ``t_s`` [s]; return the events it raised, in alarm order.

        ``inputs`` maps alarm names to their inputs (an alarm left out keeps its state and only
        ticks); ``manual`` names the loops in MANUAL (for suppression).

        Raises
        ------
        KeyError
            ``inputs`` names an unknown alarm (checked before anything changes).
        """
        unknown = set(inputs) - self._conditions.keys()
        if unknown:
            raise KeyError(f"unknown alarms {sorted(unknown)}")
        got = [inputs.get(d.name) for d in self.definitions]
        values = [None if i is None else i.value for i in got]
        good = [True if i is None else bool(i.good) for i in got]
        return self.scan_values(values, good, t_s, manual=manual)

    def scan_values(
        self,
        values: Sequence[float | bool | None],
        good: Sequence[bool],
        t_s: float,
        *,
        manual: Collection[str] = (),
    ) -> list[ConditionEvent]:
        """:meth:`scan` with the inputs as two sequences in definition order (the tier's scan
        fills them in place: no mapping, no objects); a value None leaves that alarm's input out.

        Raises
        ------
        ValueError
            A sequence does not have one entry per definition.
        """
        n = len(self._rows)
        if len(values) != n or len(good) != n:
            raise ValueError(f"scan_values needs {n} values and qualities, got {len(values)} and {len(good)}")
        self.t_s = t_s
        events: list[ConditionEvent] = []
        unshelved = ShelvingState.UNSHELVED
        # Each step is skipped when it cannot change anything (a steady scan is mostly that).
        for (d, cond, tr, q_lo, q_hi), x, ok in zip(self._rows, values, good, strict=True):
            if x is not None and ok != cond.quality_good:
                events += cond.set_quality(ok, t_s)
            suppressed = d.suppress_when_manual is not None and d.suppress_when_manual in manual
            if suppressed != cond.suppressed:
                events += cond.set_suppressed(suppressed, t_s)
            # Skip the filter where it cannot change anything: nothing pending and the same input
            # again (the deadband flags are idempotent for a constant reading), or a level alarm
            # at normal with a good reading strictly between its limits.
            if x is None:
                pass
            elif (
                tr.pending is None
                and not tr.primed
                and ok == tr.good
                and (x == tr.last or (ok and q_lo < x < q_hi and tr.state is NORMAL))
            ):
                tr.last = x
            else:
                tr.good, tr.last = ok, x
                shown = (tr.state, tr.flags)
                state = self._filter(d, tr, x, t_s)
                if self._booleans is not None and (tr.state, tr.flags) != shown:
                    self._booleans = None
                if state is not cond.process:
                    before = cond.activations
                    events += cond.update_process(state, t_s)
                    if cond.activations != before and cond.annunciating:
                        self._annunciate(t_s)
            if cond.shelving is not unshelved:
                events += cond.tick(t_s)
        return events

    def _annunciate(self, t_s: float) -> None:
        """Count an annunciated activation; forget those out of the rate window (bounded memory
        whether or not anyone asks for the summary)."""
        q = self._annunciated
        q.append(t_s)
        while q[0] <= t_s - self.rate_window_s:
            q.popleft()
        self._peak_rate = max(self._peak_rate, sum(1 for t in q if t <= t_s))

    def _filter(self, d: AlarmDefinition, tr: _Track, x: float | bool, t_s: float) -> ProcessState:
        """Steps 1-3 of the module docstring: the new ActiveState of ``d`` for input ``x``."""
        if d.kind is ConditionKind.EXCLUSIVE_LEVEL:
            assert d.limits_m is not None
            raw, flags = classify_level(float(x), tr.good, d.limits_m, d.deadband_m, tr.raw_flags)
        else:
            raw, flags = (ACTIVE if x else NORMAL), _OFF
        tr.raw, tr.raw_flags = raw, flags
        if tr.primed:
            tr.primed = False
            tr.state, tr.flags, tr.pending = raw, flags, None
            return raw
        if raw is tr.state:
            tr.pending = None
            tr.flags = flags
            return tr.state
        if tr.pending is not raw:
            tr.pending, tr.since_s = raw, t_s
        delay = d.on_delay_s if raw.active else d.off_delay_s
        if t_s - tr.since_s < delay:
            return tr.state
        if d.latched and tr.state.active and not raw.active:
            return tr.state  # held until reset
        tr.pending = None
        tr.state, tr.flags = raw, flags
        return raw

    def prime(self, name: str, active: bool) -> None:
        """Before the first scan: the state a discrete alarm's boolean shows (a tier's initial node
        value, e.g. the PLC's IoFault before it has read anything). The condition is left as it
        is, and the first input replaces the primed state at once (no delay, no event from it)."""
        tr = self._tracks[name]
        tr.state, tr.primed = (ACTIVE if active else NORMAL), True
        self._booleans = None

    def reset(self, name: str, t_s: float) -> list[ConditionEvent]:
        """Reset a latched alarm whose input is back to normal (its events; [] if nothing to
        reset). KeyError for an unknown name."""
        cond = self._conditions[name]
        tr = self._tracks[name]
        if not (cond.definition.latched and tr.state.active and not tr.raw.active):
            return []
        tr.state, tr.flags, tr.pending = tr.raw, tr.raw_flags, None
        self._booleans = None
        return cond.update_process(tr.raw, t_s)

    # ---- calls ---------------------------------------------------------------------------

    def call(self, call: ConditionCall, t_s: float) -> tuple[CallStatus, list[ConditionEvent]]:
        """A client's method call at model time ``t_s`` [s] (UNKNOWN_CONDITION for a name not
        configured); shelving that expired by ``t_s`` ends first."""
        cond = self._conditions.get(call.condition)
        if cond is None:
            return CallStatus.UNKNOWN_CONDITION, []
        before = cond.activations
        status, events = cond.call(call, t_s)
        if cond.activations != before and cond.annunciating:  # Enable found it off normal
            self._annunciate(t_s)
        return status, events

    def restart_events(self, t_s: float) -> list[ConditionEvent]:
        """After a warm restart (:meth:`from_retain`), one event per retained condition at model
        time ``t_s`` [s] ("restored at warm restart"): it gives the condition a fresh EventId of
        this process, so a client can acknowledge or confirm it and ConditionRefresh reports it
        (a restored condition has no event of its own otherwise). Its Time is ``t_s``: the
        retentive memory does not keep when the alarm started."""
        events: list[ConditionEvent] = []
        for c in self._conditions.values():
            if c.retain and c.latest is None:
                events += c.restored_event(t_s)
        return events

    # ---- views ---------------------------------------------------------------------------

    def snapshots(self) -> tuple[ConditionSnapshot, ...]:
        """Every condition's state now, in definition order."""
        return tuple(c.snapshot(self.t_s) for c in self._conditions.values())

    def retained(self) -> tuple[ConditionEvent, ...]:
        """For ConditionRefresh: each retained condition's latest event (its EventId, so a
        client may acknowledge from the refresh) carrying the condition's state now."""
        out = []
        for c in self._conditions.values():
            if c.retain and c.latest is not None:
                out.append(replace(c.latest, condition=c.snapshot(self.t_s)))
        return tuple(out)

    def summary(self, t_s: float) -> AlarmSummary:
        """Counts and the alarm rate in the ``rate_window_s`` ending at ``t_s`` [s]
        (:func:`summarize` of the conditions; activations that left the window are forgotten)."""
        q = self._annunciated
        while q and q[0] <= t_s - self.rate_window_s:
            q.popleft()
        return summarize(
            self._conditions.values(),
            sum(1 for t in q if t <= t_s),
            self._peak_rate,
            self.flood_threshold,
        )

    def rate_expiring(self) -> float | None:
        """The model time [s] at which the oldest activation still counted in the rate leaves
        the window (``t_k + rate_window_s``: from that instant on it is not counted), or None
        when none is counted. A tier republishes its summary when its model time reaches it
        (the summary after that forgets it, and this moves on to the next one)."""
        q = self._annunciated
        return q[0] + self.rate_window_s if q else None

    def booleans(self) -> dict[str, bool]:
        """The ``PLC.Alarms.*`` booleans: each follows its alarm's ActiveState (after deadband,
        delays and latching; while a condition is disabled it keeps following the process).

        Level alarms: each limit's boolean is that limit's flag as the ActiveState was evaluated
        (:func:`classify_level`): High and Low only with a good reading, HighHigh on any finite
        reading. With no deadband and no delays these are today's ``level >= high``,
        ``level <= low`` (good reading) and ``reading >= high_high``, whatever the order of the
        limits (a site may put its trip below its high switch).
        """
        if self._booleans is not None:
            return dict(self._booleans)
        out: dict[str, bool] = {}
        for d in self.definitions:
            tr = self._tracks[d.name]
            if d.boolean_path is not None:
                out[d.boolean_path] = tr.state.active
            if d.limit_boolean_paths is not None:
                for path, on in zip(d.limit_boolean_paths, tr.flags, strict=True):
                    if path is not None:
                        out[path] = on
        self._booleans = out
        return dict(out)

    # ---- retentive memory ----------------------------------------------------------------

    def to_retain(self) -> dict[str, Any]:
        """What a warm restart keeps (JSON-able): per alarm Enabled, Active and its limit, Acked,
        Confirmed, Comment and its user, shelving and when it ends [model s], and the latch."""
        out: dict[str, Any] = {}
        for name, c in self._conditions.items():
            tr = self._tracks[name]
            out[name] = {
                "enabled": c.enabled,
                "active": tr.state.active,
                "limit": None if tr.state.limit is None else tr.state.limit.value,
                "acked": c.acked,
                "confirmed": c.confirmed,
                "comment": c.comment,
                "comment_user": c.comment_user,
                "shelving": c.shelving.value,
                "shelved_until_s": None if c.shelving is ShelvingState.UNSHELVED else c.shelved_until_s,
            }
        return {"conditions": out}

    def from_retain(self, data: Mapping[str, Any]) -> list[str]:
        """Warm restart from :meth:`to_retain` output, before the first scan; return what could
        not be restored (an alarm whose entry fails any check keeps its cold state, never half).

        No events are raised: the projection reads :meth:`snapshots` when it starts.
        """
        skipped: list[str] = []
        entries = data.get("conditions", {})
        if not isinstance(entries, Mapping):
            return ["alarms: conditions is not a mapping"]
        for name, entry in entries.items():
            if name not in self._conditions:
                skipped.append(f"alarm {name}: not configured")
                continue
            try:
                self._restore(name, entry)
            except (KeyError, TypeError, ValueError) as e:
                skipped.append(f"alarm {name}: {e}")
        return skipped

    def _restore(self, name: str, e: Mapping[str, Any]) -> None:
        c = self._conditions[name]
        d = c.definition
        flags = {k: e[k] for k in ("enabled", "active", "acked", "confirmed")}
        for k, v in flags.items():
            if type(v) is not bool:
                raise TypeError(f"{k} {v!r} is not a boolean")
        texts = {k: e[k] for k in ("comment", "comment_user")}
        for k, v in texts.items():
            if not isinstance(v, str):
                raise TypeError(f"{k} {v!r} is not a string")
        limit = None if e["limit"] is None else LimitState(e["limit"])
        is_level = d.kind is ConditionKind.EXCLUSIVE_LEVEL
        if flags["active"] and is_level != (limit is not None):
            raise ValueError(f"limit {e['limit']!r} does not fit a {d.kind.value} that is active")
        if not flags["active"] and limit is not None:
            raise ValueError("an inactive alarm has no limit")
        if is_level and limit is not None:
            assert d.limits_m is not None
            if d.limits_m[LIMIT_ORDER.index(limit)] is None:
                raise ValueError(f"limit {limit.value} is not configured")
        if not d.confirm and not flags["confirmed"]:
            raise ValueError("unconfirmed, but the alarm asks for no confirmation")
        shelving = ShelvingState(e["shelving"])
        until = e["shelved_until_s"]
        if shelving is ShelvingState.UNSHELVED:
            until_s = math.inf
        elif isinstance(until, int | float) and not isinstance(until, bool) and math.isfinite(until):
            until_s = float(until)
        else:
            raise ValueError(f"shelved_until_s {until!r} is not a finite time")
        # Every check passed: apply all of it.
        state = process_state(flags["active"], limit)
        tr = self._tracks[name]
        tr.state = tr.raw = state
        tr.flags = tr.raw_flags = (limit is _HH, limit is _H, limit is _L, limit is _LL)
        tr.pending, tr.last = None, None
        self._booleans = None
        c.restore(
            state,
            enabled=flags["enabled"],
            acked=flags["acked"],
            confirmed=flags["confirmed"],
            comment=texts["comment"],
            comment_user=texts["comment_user"],
            shelving=shelving,
            shelved_until_s=until_s,
        )
