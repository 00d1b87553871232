"""The names of a tier's alarms (condition names, unique per tier), built in one place.

The config checks its per-alarm overrides against these names and ``tanklab.alarms.definitions``
builds the definitions with them, so this module imports nothing of either.
"""

from __future__ import annotations

__all__ = [
    "ADAPTATION_UNHEALTHY",
    "IO_FAULT",
    "MPC_FAILING",
    "PLC_LINK_LOST",
    "SUPERVISOR_LOST",
    "level",
    "pv_bad",
    "trip",
]

IO_FAULT = "IoFault"
"""The PLC's field link failed (every reading bad)."""
SUPERVISOR_LOST = "SupervisorLost"
"""The supervisor's heartbeat stopped after it had been alive."""

# The supervisor's own alarms (tier "supervisor").
MPC_FAILING = "MpcFailing"
"""The supervisor's MPC held (its solver failed) at its last step."""
ADAPTATION_UNHEALTHY = "AdaptationUnhealthy"
"""The gain adapter's last candidate gain set was rejected (by a guard or by the PLC)."""
PLC_LINK_LOST = "PlcLinkLost"
"""The supervisor's link to the PLC is down (no snapshot, or the PLC's scan counter stale)."""


def level(tank: str) -> str:
    """The exclusive level alarm of tank ``tank`` (``T1Level``)."""
    return f"{tank}Level"


def pv_bad(loop: str) -> str:
    """The bad-PV alarm of loop ``loop`` (``LIC1PvBad``)."""
    return f"{loop}PvBad"


def trip(tank: str) -> str:
    """The high-high interlock trip of tank ``tank`` (``T1Trip``)."""
    return f"{tank}Trip"
