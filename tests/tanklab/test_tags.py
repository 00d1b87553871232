"""The address-space contract: complete, consistent, documented, numbered per config."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from tankctl.cli import app
from tanklab.config import load_site
from tanklab.enums import GainSource, LoopMode, MpcStatus, SensorFault, SupervisorMode
from tanklab.tags import DataType, Role, all_tags, plant_tags, plc_tags, supervisor_tags, tags_by_path

ROOT = Path(__file__).resolve().parents[2]
DEFAULT = ROOT / "configs/three_tank_energies_sim.yaml"


@pytest.fixture(scope="module")
def site():
    return load_site(DEFAULT)


def test_every_node_of_the_architecture_exists(site) -> None:
    paths = set(tags_by_path(all_tags(site)))
    expected = {
        "Plant.T1.Level",
        "Plant.T3.LSH",
        "Plant.T2.LSL",
        "Plant.T1.Leak",
        "Plant.V13.Opening",
        "Plant.V32.Opening",
        "Plant.V20.Opening",
        "Plant.LT1.PV",
        "Plant.LT2.Fault",
        "Plant.LT3.FaultValue",
        "Plant.T1.Disturbance",
        "Plant.P1.Command",
        "Plant.P2.Flow",
        "Plant.Sim.Time",
        "Plant.Sim.Speed",
        "Plant.Sim.Advance",
        "Plant.Balance.In",
        "Plant.Balance.Out",
        "Plant.Balance.Leaked",
        "Plant.Balance.Spilled",
        "Plant.Balance.Stored",
        "Plant.Balance.Error",
        "PLC.LIC1.SP",
        "PLC.LIC1.PV",
        "PLC.LIC1.MV",
        "PLC.LIC1.Mode",
        "PLC.LIC1.ManualMV",
        "PLC.LIC1.RemoteMV",
        "PLC.LIC2.Kp",
        "PLC.LIC2.Ki",
        "PLC.LIC2.Kd",
        "PLC.LIC2.GainSource",
        "PLC.LIC2.SetGains",
        "PLC.Status.Scan",
        "PLC.Status.ScanPeriod",
        "PLC.Status.LastScanDuration",
        "PLC.Status.Overruns",
        "PLC.Status.IoHealthy",
        "PLC.Supervisor.Heartbeat",
        "PLC.Supervisor.Timeout",
        "PLC.Supervisor.Alive",
        "PLC.IO.LT1.PV",
        "PLC.IO.LT3.PV",
        "PLC.Interlock.T1HH",
        "PLC.Interlock.Reset",
        "PLC.Alarms.T1H",
        "PLC.Alarms.T2L",
        "PLC.Alarms.T3HH",
        "PLC.Alarms.LIC1PvBad",
        "PLC.Alarms.IoFault",
        "PLC.Alarms.SupervisorLost",
        "Supervisor.Mode",
        "Supervisor.MPC.SolveTime",
        "Supervisor.MPC.Status",
        "Supervisor.MPC.Horizon",
        "Supervisor.MPC.PlannedMV",
        "Supervisor.MPC.PredictedPV",
        "Supervisor.RLS.LIC1.Theta",
        "Supervisor.RLS.LIC2.CovarianceTrace",
        "Supervisor.RLS.LIC1.Accepted",
        "Supervisor.RLS.LIC1.Rejected",
        "Supervisor.Estimator.Disturbance",
    }
    assert expected <= paths, sorted(expected - paths)


def test_types_units_ranges_and_roles(site) -> None:
    tags = tags_by_path(all_tags(site))
    assert tags["PLC.Supervisor.Heartbeat"].data_type == DataType.UINT32
    assert tags["Supervisor.MPC.PlannedMV"].data_type == DataType.DOUBLE_ARRAY
    assert "step-major" in tags["Supervisor.MPC.PlannedMV"].description
    assert tags["Plant.T1.Level"].unit == "m" and tags["Plant.T1.Level"].eu_range == (0.0, 0.62)
    assert tags["Plant.P1.Command"].eu_range == (0.0, 1.2e-4)
    assert tags["Plant.P1.Command"].writers == {Role.PLC}
    assert Role.OPERATOR in tags["PLC.LIC1.SP"].writers and tags["PLC.LIC1.SP"].eu_range == (0.0, 0.6)
    assert Role.OPERATOR not in tags["PLC.LIC1.SetGains"].writers
    assert tags["PLC.LIC1.SetGains"].writers == {Role.ENGINEER, Role.SUPERVISOR}
    assert not tags["PLC.LIC1.Kp"].writable and not tags["Plant.T1.Level"].writable
    for path, enum in (
        ("PLC.LIC1.Mode", LoopMode),
        ("PLC.LIC1.GainSource", GainSource),
        ("Supervisor.Mode", SupervisorMode),
        ("Supervisor.MPC.Status", MpcStatus),
        ("Plant.LT1.Fault", SensorFault),
    ):
        assert tags[path].enum is enum and tags[path].data_type == DataType.INT32
    for t in tags.values():
        assert t.description
        if t.analog:
            lo, hi = t.eu_range
            assert lo < hi, t.path


def test_tags_are_numbered_per_config() -> None:
    single = load_site(ROOT / "configs/single_tank_short_sim.yaml")
    paths = {t.path for t in plant_tags(single) + plc_tags(single)}
    assert "Plant.T1.Level" in paths and "PLC.LIC1.SP" in paths and "Plant.V10.Opening" in paths
    assert not any(p.startswith(("Plant.T2", "Plant.P2", "PLC.LIC2")) for p in paths)
    rig = load_site(ROOT / "configs/three_tank_energies_rig.yaml")
    cmd = tags_by_path(plant_tags(rig))["Plant.P1.Command"]
    assert cmd.unit == "rpm" and cmd.eu_range == (0.0, 1350.0)
    with pytest.raises(ValueError, match="no supervisor section"):
        supervisor_tags(single)


def test_address_space_doc_is_current() -> None:
    result = CliRunner().invoke(app, ["docs", "address-space", "--config", str(DEFAULT)])
    assert result.exit_code == 0
    assert (ROOT / "docs/address-space.md").read_text() == result.output, (
        "docs/address-space.md is stale: run `make docs`"
    )
