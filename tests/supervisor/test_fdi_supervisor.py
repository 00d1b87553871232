"""FDI in the supervisor: fed every scan through the SupervisorCore status path in the
co-simulation, published as ``Supervisor.FDI.*`` values; a restarted supervisor warms up and
raises nothing."""

from __future__ import annotations

from supervisor.cycle import SupervisorCore
from supervisor.fdi import FdiState
from supervisor.port import SupervisorDriver
from supervisor.server import status_values
from tankctl.cosim import CoSimulation
from tanklab import paths
from tanklab.tags import supervisor_tags
from tanklab_testing.sites import noisy_site


def test_clog_diagnosed_through_the_supervisor_and_published() -> None:
    cs = CoSimulation(noisy_site(), supervisor_mode="ADVISORY")
    cs.run(100.0)
    cs.plant.set_valve("V13", 0.8)
    cs.run(40.0)
    assert cs.supervisor is not None
    status = cs.supervisor.status()
    assert status.fdi is not None and status.fdi.diagnosis is not None
    assert status.fdi.diagnosis.hypothesis.name == "Clog_V13"
    values = status_values(status)
    sup = paths.supervisor
    assert values[sup.fdi_state] == int(FdiState.ISOLATED)
    assert values[sup.fdi_diagnosis] == "Clog_V13"
    assert 0.15 <= values[sup.fdi_size] <= 0.25
    assert values[sup.fdi_message].startswith("FDI clog V13 est. fraction lost 0.")
    assert values[sup.fdi_hypothesis("Clog_V13").alarm] is True
    # every published path is a declared tag of the supervisor
    declared = {t.path for t in supervisor_tags(cs.site)}
    assert {p for p in values if p.startswith("Supervisor.FDI.")} <= declared


def test_supervisor_restart_warms_up_without_false_alarm() -> None:
    cs = CoSimulation(noisy_site(), supervisor_mode="ADVISORY")
    cs.run(200.0)
    cs.plc.set_sp("LIC1", 0.45)
    # the supervisor process restarts: a new core, fresh diagnosis state
    cs.supervisor = SupervisorCore(cs.site)
    cs.driver = SupervisorDriver(cs.supervisor)
    states = []
    for _ in range(200):
        cs.step()
        rep = cs.supervisor.fdi.report
        assert rep is not None
        states.append(rep.state)
    assert states[0] is FdiState.WARMUP
    assert states[-1] is FdiState.NORMAL
    assert FdiState.DETECTED not in states and FdiState.ISOLATED not in states


def test_status_shows_the_diagnosis() -> None:
    """``tankctl status``: the supervisor's FDI values (as the server publishes them) in the JSON
    document and as one line."""
    from tankctl.ops.status import _fdi_json, fdi_line
    from tanklab.tags import tags_by_path

    cs = CoSimulation(noisy_site(), supervisor_mode="ADVISORY")
    tags = tags_by_path(supervisor_tags(cs.site))
    cs.run(60.0)
    assert cs.supervisor is not None
    quiet = _fdi_json(tags, status_values(cs.supervisor.status()))
    assert quiet["state"] == "NORMAL" and fdi_line(quiet) == "diagnosis: NORMAL"
    cs.plant.set_leak("T3", 0.2)
    cs.run(80.0)
    doc = _fdi_json(tags, status_values(cs.supervisor.status()))
    assert doc["state"] == "ISOLATED" and doc["diagnosis"] == "Leak_T3"
    assert fdi_line(doc).startswith("diagnosis: FDI leak T3 est. opening 0.")
