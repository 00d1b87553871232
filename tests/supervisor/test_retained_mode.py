"""The supervisor's retentive memory (``supervisor.runtime.RetainedMode``): the mode a restarted
supervisor requests at its first cycle, and its conditions' states (acked, shelving, comments)."""

from __future__ import annotations

import json
from pathlib import Path

from supervisor.alarms import SupervisorAlarms
from supervisor.cycle import SupervisorCore
from supervisor.runtime import RetainedMode
from tanklab.alarms import CallStatus, ConditionCall, Method, ShelvingState, names
from tanklab.config import load_site
from tanklab.enums import SupervisorMode

ROOT = Path(__file__).resolve().parents[2]
ENERGIES = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
KORTELA = load_site(ROOT / "configs/three_tank_kortela.yaml")


def test_the_requested_mode_is_written_on_change_and_requested_again_on_restart(tmp_path: Path) -> None:
    path = tmp_path / "supervisor-retain.json"
    core = SupervisorCore(ENERGIES)
    memory = RetainedMode(path, ENERGIES)
    assert memory.restore(core) is None  # no file yet: the config's mode
    assert core.requested is SupervisorMode[ENERGIES.supervisor.mode]
    memory.save_if_changed(core)
    assert json.loads(path.read_text())["mode"] == ENERGIES.supervisor.mode
    core.request_mode(SupervisorMode.MPC)
    memory.save_if_changed(core)
    assert json.loads(path.read_text()) == {"version": 1, "site": ENERGIES.name, "mode": "MPC"}
    # A restart: a new core and memory on the same file request MPC before any cycle.
    again = SupervisorCore(ENERGIES)
    assert RetainedMode(path, ENERGIES).restore(again) is SupervisorMode.MPC
    assert again.requested is SupervisorMode.MPC


def test_unchanged_modes_are_not_rewritten(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    core = SupervisorCore(ENERGIES)
    memory = RetainedMode(path, ENERGIES)
    memory.save_if_changed(core)
    path.write_text("sentinel")  # would be replaced by a second write
    memory.save_if_changed(core)
    assert path.read_text() == "sentinel"


def test_another_sites_or_a_broken_file_is_not_restored(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"version": 1, "site": KORTELA.name, "mode": "MPC"}))
    core = SupervisorCore(ENERGIES)
    assert RetainedMode(path, ENERGIES).restore(core) is None
    assert core.requested is SupervisorMode[ENERGIES.supervisor.mode]
    for text in ("{not json", json.dumps({"version": 1, "site": ENERGIES.name, "mode": "FAST"}), "[]"):
        path.write_text(text)
        core = SupervisorCore(ENERGIES)
        assert RetainedMode(path, ENERGIES).restore(core) is None, text
        assert core.requested is SupervisorMode[ENERGIES.supervisor.mode]


# ---- the supervisor's conditions in the same file (issue 15) -----------------------------------


def _call(alarms: SupervisorAlarms, name: str, method: Method, **kw: object) -> None:
    status, events = alarms.manager.call(ConditionCall(name, method, "alice", **kw), alarms.t_s)  # type: ignore[arg-type]
    assert status is CallStatus.GOOD and events, (name, method, status)


def test_the_conditions_are_kept_and_announced_again_after_a_restart(tmp_path: Path) -> None:
    path = tmp_path / "supervisor-retain.json"
    core = SupervisorCore(ENERGIES)
    alarms = SupervisorAlarms(ENERGIES, adaptation=core.adapter is not None, event_prefix=b"A")
    memory = RetainedMode(path, ENERGIES, alarms)
    memory.restore(core)
    memory.save_if_changed(core)
    alarms.feed(None, True, 10.0)  # the link came up
    alarms.feed(None, False, 12.0)  # and went down: PlcLinkLost active, unacked
    lost = alarms.manager.condition(names.PLC_LINK_LOST)
    assert lost.active and not lost.acked
    assert lost.latest is not None
    _call(alarms, names.PLC_LINK_LOST, Method.ACKNOWLEDGE, event_id=lost.latest.event_id, comment="seen")
    _call(alarms, names.MPC_FAILING, Method.TIMED_SHELVE, shelving_time_s=600.0)
    memory.save_if_changed(core)
    saved = json.loads(path.read_text())
    assert saved["t_s"] == 12.0
    assert saved["alarms"]["conditions"][names.PLC_LINK_LOST]["acked"] is True

    # A restart: a new process (another EventId prefix) on the same file.
    again = SupervisorCore(ENERGIES)
    fresh = SupervisorAlarms(ENERGIES, adaptation=again.adapter is not None, event_prefix=b"B")
    RetainedMode(path, ENERGIES, fresh).restore(again)
    assert fresh.t_s == 12.0
    restored = fresh.manager.condition(names.PLC_LINK_LOST)
    assert (restored.active, restored.acked, restored.comment, restored.comment_user) == (
        True,
        True,
        "seen",
        "alice",
    )
    mpc_failing = fresh.manager.condition(names.MPC_FAILING)
    assert mpc_failing.shelving is ShelvingState.TIMED and mpc_failing.shelved_until_s == 612.0
    events = fresh.manager.restart_events(fresh.t_s)
    assert [(e.condition.name, e.reason) for e in events] == [
        (names.PLC_LINK_LOST, "restored at warm restart")
    ]
    assert events[0].event_id.startswith(b"B") and events[0].condition.acked
    # The link comes back: the restored condition returns to normal (acked: no longer retained).
    back = fresh.feed(None, True, 20.0)
    assert [(e.condition.name, e.condition.active, e.condition.retain) for e in back] == [
        (names.PLC_LINK_LOST, False, False)
    ]
    # Shelving runs on, on the restored model time: it ends at 612 s.
    assert fresh.feed(None, True, 611.0) == []
    assert [e.reason for e in fresh.feed(None, True, 612.0)] == ["timed shelving expired"]


def test_a_file_without_conditions_restores_the_mode_and_the_conditions_cold(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"version": 1, "site": ENERGIES.name, "mode": "MPC"}))
    core = SupervisorCore(ENERGIES)
    alarms = SupervisorAlarms(ENERGIES, adaptation=core.adapter is not None)
    memory = RetainedMode(path, ENERGIES, alarms)
    assert memory.restore(core) is SupervisorMode.MPC
    assert alarms.manager.restart_events(0.0) == []
    memory.save_if_changed(core)  # the conditions are written from now on
    assert set(json.loads(path.read_text())) == {"version", "site", "mode", "t_s", "alarms"}


def test_only_a_change_of_a_condition_rewrites_the_file(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    core = SupervisorCore(ENERGIES)
    alarms = SupervisorAlarms(ENERGIES, adaptation=core.adapter is not None)
    memory = RetainedMode(path, ENERGIES, alarms)
    memory.save_if_changed(core)
    path.write_text("sentinel")
    alarms.feed(None, True, 30.0)  # model time moves on, no condition changes
    memory.save_if_changed(core)
    assert path.read_text() == "sentinel"
    alarms.feed(None, False, 31.0)  # PlcLinkLost active
    memory.save_if_changed(core)
    assert json.loads(path.read_text())["alarms"]["conditions"][names.PLC_LINK_LOST]["active"] is True


def test_a_bad_condition_entry_leaves_that_condition_cold(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    core = SupervisorCore(ENERGIES)
    alarms = SupervisorAlarms(ENERGIES, adaptation=core.adapter is not None)
    alarms.feed(None, True, 1.0)
    alarms.feed(None, False, 2.0)
    RetainedMode(path, ENERGIES, alarms).save_if_changed(core)
    data = json.loads(path.read_text())
    data["alarms"]["conditions"][names.PLC_LINK_LOST]["acked"] = "yes"
    data["t_s"] = "later"
    path.write_text(json.dumps(data))
    fresh = SupervisorAlarms(ENERGIES, adaptation=core.adapter is not None)
    assert RetainedMode(path, ENERGIES, fresh).restore(SupervisorCore(ENERGIES)) is not None
    assert not fresh.manager.condition(names.PLC_LINK_LOST).active and fresh.t_s == 0.0
