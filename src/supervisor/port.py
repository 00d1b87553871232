"""The seam between the supervisor and the PLC: a snapshot per scan in, one ordered request out.

The co-simulation and the supervisor process run the same :class:`SupervisorDriver` on the same
snapshots and send the same :class:`PlcRequest`; only the transport differs (a
:class:`PlcPort`: in-process on a :class:`plc_emulator.program.PlcProgram`, ``tankctl.cosim``; over
OPC UA, ``supervisor.link.PlcLink``). So the two cannot differ in order or timing.

Per new PLC scan k (a snapshot whose scan counter moved):

1. the heartbeat count goes up by one (every scan is acknowledged: in lock-step the PLC waits
   for it before scan k + 1);
2. on a sample scan (the first one seen, then every ``sample_scans`` scans) the supervisory
   controller steps, through its :class:`supervisor.host.ControllerHost` (the shipped one:
   :meth:`SupervisorCore.cycle`); on the others it only tracks the applied MV
   (:meth:`SupervisorCore.track`). Scan 0, the PLC's values before its first scan, is
   acknowledged only: nothing has been measured yet. While the host is ``failing`` (its
   controller failed too many steps in a row) no heartbeat is sent, so the PLC's watchdog
   sheds the loops as for a lost supervisor;
3. the request is sent in this order: one Write of every loop's ``RemoteMV``, then every loop's
   ``Mode`` (the PLC applies a Write's items in order, so entering REMOTE never applies a stale
   RemoteMV), with the heartbeat as its last item when no gains are pushed; then one
   ``SetGains`` call per pushed loop; then, when gains were pushed, the heartbeat in a Write of its
   own. Everything is applied by the PLC from scan k + 1 on.

This module is pure: no clock, no I/O.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from supervisor.controller import ShippedController
from supervisor.cycle import Actions, PlcSnapshot, SupervisorCore
from supervisor.host import ControllerHost
from tanklab import paths

HEARTBEAT_MODULO = 2**32
"""``PLC.Supervisor.Heartbeat`` is a UInt32: the count wraps."""


@dataclass(frozen=True)
class PlcRequest:
    """What the supervisor sends the PLC after one snapshot, in order (see the module docstring).

    Attributes
    ----------
    writes : items of the first Write, (contract path, value), in the order the PLC applies them.
    gains : (loop, (Kp, Ki, Kd)) per ``SetGains`` call, after the Write.
    trailing : items of a last Write (the heartbeat when gains were pushed), possibly empty.
    actions : the cycle's actions the request was made of (None on a tracking scan).
    """

    writes: tuple[tuple[str, object], ...]
    gains: tuple[tuple[str, tuple[float, float, float]], ...] = ()
    trailing: tuple[tuple[str, object], ...] = ()
    actions: Actions | None = field(default=None, compare=False)

    @classmethod
    def of(cls, actions: Actions | None, heartbeat: int | None) -> PlcRequest:
        """The request of a cycle's ``actions`` (None: none ran) followed by ``heartbeat``."""
        writes: list[tuple[str, object]] = []
        gains: tuple[tuple[str, tuple[float, float, float]], ...] = ()
        if actions is not None:
            writes += [(paths.plc.loop(lp).remote_mv, float(mv)) for lp, mv in actions.remote_mv.items()]
            writes += [(paths.plc.loop(lp).mode, int(m)) for lp, m in actions.modes.items()]
            gains = tuple(actions.gains.items())
        beat: tuple[tuple[str, object], ...] = ()
        if heartbeat is not None:
            beat = ((paths.plc.heartbeat, heartbeat % HEARTBEAT_MODULO),)
        if not gains:
            return cls(tuple(writes) + beat, (), (), actions)
        return cls(tuple(writes), gains, beat, actions)


class PlcPort(Protocol):
    """A transport to the PLC, as the supervisor needs it (the in-process one; the OPC UA one,
    ``supervisor.link.PlcLink``, has the same two verbs as coroutines)."""

    def snapshot(self) -> PlcSnapshot | None:
        """One read of everything a cycle needs, from one scan; None when the PLC cannot be read."""
        ...

    def apply(self, request: PlcRequest) -> list[str]:
        """Send ``request`` in its order; return the loops whose SetGains the PLC refused."""
        ...


class SupervisorDriver:
    """The per-scan logic around a :class:`SupervisorCore`, shared by every transport.

    Parameters
    ----------
    core : the supervisor core.
    host : the controller host (default: the shipped controller on ``core``, process CPU time).
    """

    def __init__(self, core: SupervisorCore, host: ControllerHost | None = None) -> None:
        self.core = core
        self.host = host or ControllerHost(core.site, ShippedController(core.site, core=core), core)
        self.sample_scans = core.sample_scans
        self.heartbeat = 0
        self.last_scan: int | None = None
        self.last_sample_scan: int | None = None
        self.sampled = False
        """Whether the last request came from a cycle (a sample scan)."""

    def on_snapshot(
        self, snap: PlcSnapshot, preview: Callable[[], NDArray[np.float64] | None] | None = None
    ) -> PlcRequest | None:
        """The request for a new snapshot; None when its scan was already handled.

        ``preview``: called on a sample scan for an optional reference preview ((Np, nz) array),
        as :meth:`SupervisorCore.cycle` takes it.
        """
        if snap.scan == self.last_scan:
            return None
        self.last_scan = snap.scan
        self.sampled = False
        if snap.scan <= 0:
            return PlcRequest.of(None, self._beat())
        last = self.last_sample_scan
        if last is None or snap.scan < last or snap.scan - last >= self.sample_scans:
            self.last_sample_scan = snap.scan
            self.sampled = True
            actions = self.host.cycle(snap, preview() if preview is not None else None)
            return PlcRequest.of(actions, self._beat())
        self.host.track(snap)
        return PlcRequest.of(None, self._beat())

    def _beat(self) -> int | None:
        """The next heartbeat count, or None while the controller is failing (withheld)."""
        if self.host.failing:
            return None
        self.heartbeat += 1
        return self.heartbeat

    def refused(self, loops: list[str]) -> None:
        """The PLC refused the gain pushes of ``loops``: resynchronise the adapter."""
        if loops:
            self.core.push_refused()

    def lost(self) -> None:
        """The PLC counts as lost (its scan counter went stale): the next snapshot is handled as a
        new scan even if the counter has not moved, and the adapter reads the applied gains back
        before it pushes."""
        self.last_scan = None
        self.core.push_refused()
