"""The supervisor's own alarms fed from hand-made statuses (issue 15, supervisor part).

Each test feeds :class:`supervisor.alarms.SupervisorAlarms` statuses made by hand at given model
times and checks the condition events (activations, returns to normal) and their times.
"""

from __future__ import annotations

import numpy as np
import pytest

from helpers import ROOT
from supervisor.alarms import SupervisorAlarms
from supervisor.cycle import LoopAdaptation, SupervisorStatus
from supervisor.mpc.model import MpcResult
from tanklab import paths
from tanklab.alarms import ConditionEvent, ConditionKind, Priority, names
from tanklab.alarms.definitions import supervisor_alarms
from tanklab.config import load_site
from tanklab.enums import MpcStatus, SupervisorMode

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")


def mpc(status: MpcStatus, consecutive: int = 0) -> MpcResult:
    z = np.zeros(2)
    return MpcResult(
        u=z,
        status=status,
        osqp_status="x",
        iterations=1,
        solve_time_s=0.0,
        planned_u=np.zeros((1, 2)),
        predicted_z=np.zeros((1, 2)),
        disturbance=z,
        state=np.zeros(3),
        failures=consecutive,
        consecutive_failures=consecutive,
        inaccurate=0,
    )


def adaptation(accepted: int) -> tuple[tuple[str, LoopAdaptation], ...]:
    a = LoopAdaptation((1.0, 0.1, 0.0), 1.0, accepted, "", 0.0, 1.0, (0.5,), False, (1.0, 0.1, 0.0), 0.0)
    return (("LIC1", a), ("LIC2", a))


def status(
    result: MpcResult | None = None, *, accepted: int | None = None, rejected: int = 0
) -> SupervisorStatus:
    return SupervisorStatus(
        mode=SupervisorMode.ADVISORY,
        cycles=1,
        mpc=result,
        adaptation=None if accepted is None else adaptation(accepted),
        rejected=rejected,
    )


def changes(events: list[ConditionEvent], name: str) -> list[tuple[bool, float]]:
    """(ActiveState, model time [s]) of each of ``name``'s events that changed ActiveState."""
    out: list[tuple[bool, float]] = []
    for e in events:
        if e.condition.name == name and (not out or out[-1][0] != e.condition.active):
            out.append((e.condition.active, e.t_s))
    return out


def test_definitions_follow_the_config_and_the_contract() -> None:
    with_adapter = supervisor_alarms(SITE, adaptation=True)
    assert [d.name for d in with_adapter] == [
        names.MPC_FAILING,
        names.ADAPTATION_UNHEALTHY,
        names.PLC_LINK_LOST,
    ]
    by = {d.name: d for d in with_adapter}
    assert by[names.MPC_FAILING].source == paths.supervisor.mpc
    assert by[names.ADAPTATION_UNHEALTHY].source == paths.supervisor.rls_root
    assert by[names.PLC_LINK_LOST].source == paths.supervisor.plc_link
    assert all(d.kind is ConditionKind.DISCRETE for d in with_adapter)
    assert by[names.PLC_LINK_LOST].priority is Priority.HIGH
    assert by[names.MPC_FAILING].priority is Priority.MEDIUM
    assert by[names.ADAPTATION_UNHEALTHY].priority is Priority.LOW
    # Without a gain adapter there is no adaptation to be unhealthy.
    assert [d.name for d in supervisor_alarms(SITE, adaptation=False)] == [
        names.MPC_FAILING,
        names.PLC_LINK_LOST,
    ]
    with pytest.raises(KeyError):
        SupervisorAlarms(SITE, adaptation=False).manager.condition(names.ADAPTATION_UNHEALTHY)


def test_mpc_failing_follows_held_steps() -> None:
    alarms = SupervisorAlarms(SITE, adaptation=False)
    events: list[ConditionEvent] = []
    events += alarms.feed(status(), True, 0.0)  # no step yet: nothing
    events += alarms.feed(status(mpc(MpcStatus.SOLVED)), True, 1.0)
    assert events == []
    events += alarms.feed(status(mpc(MpcStatus.HELD, 1)), True, 2.0)
    events += alarms.feed(status(mpc(MpcStatus.HELD, 2)), True, 3.0)  # still held: no new activation
    events += alarms.feed(status(mpc(MpcStatus.INACCURATE)), True, 4.0)  # a plan is used again
    assert changes(events, names.MPC_FAILING) == [(True, 2.0), (False, 4.0)]
    assert events[0].condition.severity == int(Priority.MEDIUM)


def test_adaptation_unhealthy_from_a_rejection_until_the_next_accepted_push() -> None:
    alarms = SupervisorAlarms(SITE, adaptation=True)
    events: list[ConditionEvent] = []
    events += alarms.feed(status(accepted=0, rejected=0), True, 0.0)
    events += alarms.feed(status(accepted=1, rejected=0), True, 1.0)  # accepted: healthy
    assert events == []
    events += alarms.feed(status(accepted=1, rejected=1), True, 2.0)  # rejected
    events += alarms.feed(status(accepted=1, rejected=1), True, 3.0)  # nothing new: still unhealthy
    events += alarms.feed(status(accepted=1, rejected=2), True, 4.0)
    events += alarms.feed(status(accepted=2, rejected=2), True, 5.0)  # accepted again
    assert changes(events, names.ADAPTATION_UNHEALTHY) == [(True, 2.0), (False, 5.0)]


def test_plc_link_lost_follows_the_link_and_keeps_the_last_model_time() -> None:
    alarms = SupervisorAlarms(SITE, adaptation=False)
    events: list[ConditionEvent] = []
    events += alarms.feed(status(mpc(MpcStatus.SOLVED)), True, 10.0)
    events += alarms.feed(None, False, 10.0)  # lost: no snapshot, model time stands
    events += alarms.feed(None, False, 0.0)  # an older time never moves the manager back
    events += alarms.feed(None, True, 12.0)
    assert changes(events, names.PLC_LINK_LOST) == [(True, 10.0), (False, 12.0)]
    lost = next(e for e in events if e.condition.active)
    assert lost.condition.severity == int(Priority.HIGH)
    assert lost.condition.retain and not lost.condition.acked
    # Unacknowledged, it stays retained after the return to normal (for ConditionRefresh).
    assert [e.condition.name for e in alarms.manager.retained()] == [names.PLC_LINK_LOST]
    assert alarms.t_s == 12.0


def test_the_event_prefix_marks_the_event_ids() -> None:
    alarms = SupervisorAlarms(SITE, adaptation=False, event_prefix=b"\x01" * 8)
    (event,) = alarms.feed(None, False, 1.0)
    assert event.event_id.startswith(b"\x01" * 8)
