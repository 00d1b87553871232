"""The supervisor's retentive mode (``supervisor.runtime.RetainedMode``): what a restarted
supervisor requests at its first cycle."""

from __future__ import annotations

import json
from pathlib import Path

from supervisor.cycle import SupervisorCore
from supervisor.runtime import RetainedMode
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
