"""Scenario events: what each kind means, written once, applied through one interface.

:func:`apply_event` is the one table from an event kind of :mod:`tanklab.scenario` to a verb of
:class:`EventTarget`. Two targets implement the verbs: the co-simulation in process
(:class:`tankctl.cosim.CoSimEvents`: ``tankctl simulate``, ``tankctl compare`` and the
randomized scenarios) and the running stack over OPC UA (:class:`tankctl.ops.scenario.LiveEvents`:
``tankctl scenario run``). So the paths cannot differ in what an event does, nor in the order of
the writes an event makes.

=================  ======================================  =========================================
kind               verb                                    meaning (the nodes an OPC UA client writes)
=================  ======================================  =========================================
setpoint           ``setpoint(loop, value_m)``             ``PLC.<loop>.SP`` [m]
leak               ``leak(tank, opening)``                 ``Plant.<tank>.Leak``, opening 0..1
valve              ``valve(valve, opening)``               ``Plant.<valve>.Opening``, 0..1
disturbance        ``disturbance(tank, flow_m3_s)``        ``Plant.<tank>.Disturbance`` [m^3/s]
fault              ``fault(transmitter, fault, value)``    ``Plant.LT<i>.FaultValue``, then ``.Fault``
                                                           (the size first: the fault starts with it)
loop_mode          ``loop_mode(loop, mode, mv_percent)``   ``PLC.<loop>.Mode``, then, with a
                                                           percentage, ``ManualMV`` = that percent of
                                                           its range (the MANUAL switch is bumpless
                                                           and starts ManualMV from the MV, so a
                                                           preset written before it would be lost)
supervisor_mode    ``supervisor_mode(mode)``               ``Supervisor.Mode``
=================  ======================================  =========================================

A target's verbs return what the caller needs back: nothing in process, the lines saying what
was written (as coroutines) over OPC UA; :func:`apply_event` returns the verb's result as is.
This module imports no numerics: the operator commands use it.
"""

from __future__ import annotations

from typing import Protocol, TypeVar

from tanklab.enums import LoopMode, SensorFault, SupervisorMode
from tanklab.scenario import (
    DisturbanceEvent,
    Event,
    FaultEvent,
    LeakEvent,
    LoopModeEvent,
    SetpointEvent,
    ValveEvent,
)

__all__ = ["EventTarget", "apply_event"]

R_co = TypeVar("R_co", covariant=True)
R = TypeVar("R")


class EventTarget(Protocol[R_co]):
    """What a scenario event can do to a stack: one verb per kind (units as in the scenario)."""

    def setpoint(self, loop: str, value_m: float) -> R_co:
        """A loop's setpoint [m]."""
        ...

    def leak(self, tank: str, opening: float) -> R_co:
        """A tank's leak valve to the drain, opening 0..1."""
        ...

    def valve(self, valve: str, opening: float) -> R_co:
        """A connecting or outlet valve's opening 0 (clogged) .. 1."""
        ...

    def disturbance(self, tank: str, flow_m3_s: float) -> R_co:
        """An extra inflow into a tank [m^3/s] (negative: an outflow)."""
        ...

    def fault(self, transmitter: str, fault: SensorFault, value: float) -> R_co:
        """A level transmitter's fault and its size (in the fault's unit: m, m/s, ...)."""
        ...

    def loop_mode(self, loop: str, mode: LoopMode, mv_percent: float | None) -> R_co:
        """A loop's mode; for MANUAL with a percentage, then its output to that percent of the MV range."""
        ...

    def supervisor_mode(self, mode: SupervisorMode) -> R_co:
        """The supervisor's mode (taking effect at its next cycle)."""
        ...


def apply_event(target: EventTarget[R], ev: Event) -> R:
    """Apply one scenario event to ``target``: the table of event kinds (module docstring)."""
    if isinstance(ev, SetpointEvent):
        return target.setpoint(ev.loop, ev.value_m)
    if isinstance(ev, LeakEvent):
        return target.leak(ev.tank, ev.opening)
    if isinstance(ev, ValveEvent):
        return target.valve(ev.valve, ev.opening)
    if isinstance(ev, DisturbanceEvent):
        return target.disturbance(ev.tank, ev.flow_m3_s)
    if isinstance(ev, FaultEvent):
        return target.fault(ev.transmitter, SensorFault[ev.fault], ev.value)
    if isinstance(ev, LoopModeEvent):
        return target.loop_mode(ev.loop, LoopMode[ev.mode], ev.mv_percent)
    return target.supervisor_mode(SupervisorMode[ev.mode])
