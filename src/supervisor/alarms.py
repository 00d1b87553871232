"""The supervisor's own alarms: its :class:`~tanklab.alarms.AlarmManager`, fed from the core's
status (pure, on model time; docs/alarms.md section 9).

Inputs, each a discrete value:

* ``MpcFailing``: the last MPC step HELD (its solver failed and the shifted last plan was used:
  ``MpcResult.consecutive_failures > 0``); normal again at the next step that solves. Before any
  step ran the input is left out (the condition stays as it is).
* ``AdaptationUnhealthy`` (only with a gain adapter): the adapter's last candidate gain set was
  rejected, by a guard or by the PLC (``SupervisorStatus.rejected`` rose and no accepted push
  since); normal again at the next accepted push (``LoopAdaptation.accepted`` rose).
* ``PlcLinkLost``: the runtime's link to the PLC is down (no snapshot, or the scan counter
  stale); given by the runtime, which knows it, as ``link_up``.

Model time is the PLC's (the snapshots' ``t_s``): while the link is down it does not advance, so
the link-lost events carry the model time of the last snapshot seen.
"""

from __future__ import annotations

from supervisor.cycle import SupervisorStatus
from tanklab.alarms import AlarmManager, ConditionEvent, names
from tanklab.alarms.definitions import supervisor_manager
from tanklab.config import SiteConfig
from tanklab.enums import MpcStatus

__all__ = ["SupervisorAlarms"]


class SupervisorAlarms:
    """The supervisor's alarm manager and how a cycle feeds it.

    Parameters
    ----------
    site : the site (its ``supervisor`` and ``plc`` sections).
    adaptation : the supervisor has a gain adapter (``SupervisorCore.adapter is not None``).
    event_prefix : the EventId prefix, unique per process (the runtime's; tests leave it empty).
    """

    def __init__(self, site: SiteConfig, *, adaptation: bool, event_prefix: bytes = b"") -> None:
        self.manager: AlarmManager = supervisor_manager(
            site, adaptation=adaptation, event_prefix=event_prefix
        )
        index = {name: i for i, name in enumerate(self.manager.names)}
        self._mpc = index[names.MPC_FAILING]
        self._adapt = index.get(names.ADAPTATION_UNHEALTHY)
        self._link = index[names.PLC_LINK_LOST]
        self._good = [True] * len(index)
        self._rejected: int | None = None
        self._accepted: int | None = None
        self._unhealthy = False
        self.t_s = 0.0
        """The model time [s] of the last feed (a client's call is answered at it)."""

    def feed(self, status: SupervisorStatus | None, link_up: bool, t_s: float) -> list[ConditionEvent]:
        """Feed one cycle's ``status`` (None: no cycle, only the link's state) and the PLC link's
        state at model time ``t_s`` [s]; return the events."""
        self.t_s = max(self.t_s, t_s)
        values: list[float | bool | None] = [None] * len(self._good)
        values[self._link] = not link_up
        if status is not None:
            if status.mpc is not None:
                values[self._mpc] = status.mpc.status is MpcStatus.HELD
            if self._adapt is not None and status.adaptation is not None:
                values[self._adapt] = self._adaptation_unhealthy(status)
        return self.manager.scan_values(values, self._good, self.t_s)

    def _adaptation_unhealthy(self, status: SupervisorStatus) -> bool:
        """True from a rise of the rejected count until the next rise of the accepted count."""
        assert status.adaptation is not None
        accepted = status.adaptation[0][1].accepted if status.adaptation else 0
        rejected = status.rejected
        if self._rejected is not None and self._accepted is not None:
            if accepted > self._accepted:
                self._unhealthy = False
            if rejected > self._rejected:
                self._unhealthy = True
        self._rejected, self._accepted = rejected, accepted
        return self._unhealthy
