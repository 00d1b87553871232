"""Enumerations of the address-space contract.

Every enumerated node (loop ``Mode``, ``GainSource``, ``Supervisor.Mode``, ``MPC.Status``,
``LT.Fault``) is an Int32 variable with an ``EnumStrings`` property; the integer values are
defined here, once, and nowhere else. The member names are the EnumStrings, in order.
"""

from __future__ import annotations

from enum import IntEnum


class LoopMode(IntEnum):
    """Operating mode of a PLC control loop ``PLC.LIC{j}.Mode``.

    MANUAL: the operator's ``ManualMV`` drives the actuator.
    AUTO: the loop's block computes the MV from SP and PV.
    REMOTE: the supervisor's ``RemoteMV`` drives the actuator (the MPC-direct architecture).
    """

    MANUAL = 0
    AUTO = 1
    REMOTE = 2


class RemoteSource(IntEnum):
    """Who drives a loop in REMOTE: ``PLC.LIC{j}.RemoteSource`` (engineer, retentive).

    SUPERVISOR: the supervisor's identity writes ``RemoteMV`` (and switches AUTO <-> REMOTE); the
    supervisor's heartbeat watchdog sheds the loop.
    EXTERNAL: a certificate identity in role External does, and the external heartbeat's
    watchdog (``PLC.External.*``) sheds it; the supervisor's writes to the loop are refused.
    """

    SUPERVISOR = 0
    EXTERNAL = 1


class GainSource(IntEnum):
    """Where the gains a PID loop applies came from (``PLC.LIC{j}.GainSource``).

    FIXED: the configured gains (at start and after ``ResetGains``), or gains an engineer handed
    back with ``ReleaseGains`` (kept until the supervisor pushes again).
    SUPERVISOR: the supervisor's last accepted ``SetGains``.
    FALLBACK: the supervisor was lost; the fixed or its last accepted gains.
    ENGINEER: an engineer's own ``SetGains``; the supervisor's ``SetGains`` is refused on the loop
    and the watchdog leaves it alone until ``ReleaseGains`` or ``ResetGains``.
    """

    FIXED = 0
    SUPERVISOR = 1
    FALLBACK = 2
    ENGINEER = 3


class SupervisorMode(IntEnum):
    """Operating mode of the supervisor (``Supervisor.Mode``)."""

    OFF = 0
    ADVISORY = 1
    ADAPTIVE_PID = 2
    MPC = 3


class MpcStatus(IntEnum):
    """Outcome of the last MPC step (``Supervisor.MPC.Status``).

    SOLVED: the QP solved to tolerance. INACCURATE: solved to a looser tolerance (plan used).
    HELD: the solver failed and the previous safe plan, shifted one step, was used.
    """

    NOT_RUN = 0
    SOLVED = 1
    INACCURATE = 2
    HELD = 3


class SensorFault(IntEnum):
    """Injectable fault of a level transmitter (``Plant.LT{i}.Fault``).

    BIAS adds ``FaultValue`` [m]; STUCK freezes the reading at the value it had when the fault
    was set; DRIFT adds ``FaultValue`` [m/s] times the time since the fault was set.
    """

    NONE = 0
    BIAS = 1
    STUCK = 2
    DRIFT = 3
