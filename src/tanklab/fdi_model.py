"""The fault hypotheses a site can have, and the FDI enums (shared by the supervisor's diagnosis,
:mod:`supervisor.fdi`, and the tag contract, which must not import the supervisor)."""

from __future__ import annotations

from enum import IntEnum

from tanklab.config import SiteConfig


class FaultKind(IntEnum):
    """The fault classes FDI isolates (published as integers)."""

    NONE = 0
    LEAK = 1
    CLOG = 2
    PUMP = 3
    BIAS = 4
    DRIFT = 5
    STUCK = 6


class FdiState(IntEnum):
    """The diagnosis state: warming up, no fault, a fault detected but not isolated, isolated."""

    WARMUP = 0
    NORMAL = 1
    DETECTED = 2
    ISOLATED = 3


def transmitter_of(tank: str) -> str:
    """The level transmitter of a tank (``T1`` -> ``LT1``)."""
    return "LT" + tank[1:]


def site_hypotheses(site: SiteConfig) -> list[tuple[FaultKind, str]]:
    """(class, element) of every fault the site can have, in the diagnosis' order: leaks of the
    tanks with a leak valve, clogs of the valves that pass water, pumps, then per transmitter
    bias, drift and stuck. A fault the site cannot have (no V32 on two tanks) is absent."""
    plant = site.plant
    out: list[tuple[FaultKind, str]] = [
        (FaultKind.LEAK, t.name) for t in plant.tanks if t.leak_conductance > 0.0
    ]
    out += [(FaultKind.CLOG, v.name) for v in plant.valves if v.conductance > 0.0 and v.initial_opening > 0.0]
    out += [(FaultKind.PUMP, p.name) for p in plant.pumps]
    for kind in (FaultKind.BIAS, FaultKind.DRIFT, FaultKind.STUCK):
        out += [(kind, transmitter_of(t.name)) for t in plant.tanks]
    return out


def hypothesis_name(kind: FaultKind, element: str) -> str:
    """``Leak_T1``, ``Clog_V13``, ``Pump_P1``, ``Bias_LT1``, ``Drift_LT1``, ``Stuck_LT1``."""
    return f"{kind.name.capitalize()}_{element}"
