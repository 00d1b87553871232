"""Tank, pump, loop and transmitter numbers 1..99 and the valve-name rule (decision 0045).

A 12-tank site (two-digit names everywhere, a two-digit valve V1112 between T11 and T12) loads,
builds its address space and runs in the co-simulation with every loop holding its own tank at its
own setpoint; a site where two valves get one name V{m}{n} is refused naming both; T0, T100 and
leading zeros are refused; names a reader sees sort numerically.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from plant_sim.linearize import operating_point
from plant_sim.models import TankNetwork, default_inputs
from tankctl.cosim import CoSimulation
from tanklab.alarms.definitions import plc_alarms
from tanklab.config import ConfigError, SiteConfig, format_validation_error, load_site, numeric_key
from tanklab.scenario import LeakEvent
from tanklab.tags import plant_tags, plc_tags

ROOT = Path(__file__).resolve().parents[2]
N = 12


def setpoint_m(i: int) -> float:
    """Tank i's setpoint [m]: distinct per tank, so a loop wired to the wrong tank shows."""
    return 0.30 + 0.005 * i


def energies() -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((ROOT / "configs/three_tank_energies_sim.yaml").read_text())
    return data


def site_data(n: int = N) -> dict[str, Any]:
    """``n`` (default twelve) copies of the Energies T1 loop, each draining to the floor (V{i}0),
    and T11 joined to T12 by V1112; every tank starts at its setpoint's equilibrium."""
    base = energies()
    tank, pump = base["plant"]["tanks"][0], base["plant"]["pumps"][0]
    loop, interlock = base["plc"]["loops"][0], base["plc"]["interlocks"][0]
    valve = base["plant"]["valves"][0]
    ids = range(1, n + 1)
    outlet = {"mu": valve["mu"], "area_m2": valve["area_m2"]}
    data = {
        "name": "twelve_tanks",
        "plant": {
            **base["plant"],
            "tanks": [{**tank, "name": f"T{i}", "initial_level_m": setpoint_m(i)} for i in ids],
            "valves": [{"name": f"V{i}0", "upstream": f"T{i}", **outlet} for i in ids]
            + [{"name": "V1112", "upstream": "T11", "downstream": "T12", "mu": 0.5, "area_m2": 1e-5}],
            "pumps": [{**pump, "name": f"P{i}", "feeds": f"T{i}"} for i in ids],
            "operating_point": {"levels_m": [setpoint_m(i) for i in ids], "flows_m3_s": None},
        },
        "plc": {
            **base["plc"],
            "loops": [
                {**loop, "name": f"LIC{i}", "pv": f"LT{i}", "actuator": f"P{i}", "setpoint_m": setpoint_m(i)}
                for i in ids
            ],
            "interlocks": [{**interlock, "tank": f"T{i}"} for i in (10, 12)],
        },
    }
    site = SiteConfig.model_validate(copy.deepcopy(data))
    net = TankNetwork.from_config(site.plant)
    op = operating_point(net, site.plant, default_inputs(net, site.plant))
    for p, command in zip(data["plant"]["pumps"], op.commands, strict=True):
        p["initial_command"] = float(command)
    return data


def test_a_twelve_tank_site_loads_with_two_digit_names_and_builds_its_address_space(tmp_path: Path) -> None:
    path = tmp_path / "twelve_tanks.yaml"
    path.write_text(yaml.safe_dump(site_data()))
    site = load_site(path)
    assert site.tank_names == [f"T{i}" for i in range(1, N + 1)]
    assert [v.name for v in site.plant.valves][-2:] == ["V120", "V1112"]
    paths = {t.path for t in plant_tags(site)} | {t.path for t in plc_tags(site)}
    for node in ("Plant.T12.Level", "Plant.LT12.PV", "Plant.P12.Command", "Plant.V1112.Opening"):
        assert node in paths, node
    assert {"PLC.LIC12.PV", "PLC.LIC10.SP", "PLC.Alarms.T12HH"} <= paths
    alarms = [d.name for d in plc_alarms(site)]
    assert {"T12Level", "LIC12PvBad", "T10Trip", "T12Trip"} <= set(alarms)


def test_a_twelve_tank_site_runs_in_the_cosimulation_each_loop_on_its_own_tank() -> None:
    cs = CoSimulation(SiteConfig.model_validate(site_data()))
    cs.run(60.0)
    # a leak on T12 only: LIC12 (pump P12) must answer it, no other pump
    cs.plant.set_leak("T12", 0.3)
    tr = cs.run(600.0)
    h, u = tr.array("levels_m"), tr.array("commands")
    for k in range(N):  # every tank back at its own setpoint (integral action), T12 included
        assert abs(h[-1, k] - setpoint_m(k + 1)) < 2e-3, (k + 1, h[-1, k])
    assert u[-1, N - 1] > u[0, N - 1] * 1.05  # P12 works harder against the leak
    assert np.allclose(u[-1, : N - 2], u[0, : N - 2], rtol=1e-3)  # T1..T10 untouched


def _error(data: dict[str, Any], tmp_path: Path) -> str:
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as e:
        load_site(path)
    return str(e.value)


def _joint(up: str, down: str) -> dict[str, Any]:
    name = f"V{up[1:]}{down[1:]}"
    return {"name": name, "upstream": up, "downstream": down, "mu": 0.5, "area_m2": 1e-5}


@pytest.mark.parametrize(
    ("tanks", "first", "second", "name"),
    [(12, ("T1", "T12"), ("T11", "T2"), "V112"), (23, ("T1", "T23"), ("T12", "T3"), "V123")],
)
def test_two_valves_with_one_name_are_refused_naming_both_and_the_rule(
    tanks: int, first: tuple[str, str], second: tuple[str, str], name: str, tmp_path: Path
) -> None:
    data = site_data(tanks)
    valves = data["plant"]["valves"]
    valves += [_joint(*first), _joint(*second)]
    j, i = len(valves) - 2, len(valves) - 1
    assert _error(data, tmp_path) == (
        f"{tmp_path / 'site.yaml'}: plant: valves[{i}].name: {name} ({second[0]} -> {second[1]}) is also "
        f"valves[{j}].name ({first[0]} -> {first[1]}): valve names V{{m}}{{n}} must be unique (renumber a "
        "tank so they differ)"
    )
    del valves[j]  # either valve alone is fine
    assert load_site_data(data, tmp_path).plant.valves[-1].name == name


def load_site_data(data: dict[str, Any], tmp_path: Path) -> SiteConfig:
    path = tmp_path / "ok.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_site(path)


def test_one_valve_listed_twice_is_refused_as_a_duplicate(tmp_path: Path) -> None:
    data = site_data()
    data["plant"]["valves"].append(dict(data["plant"]["valves"][-1]))  # V1112 again
    assert _error(data, tmp_path).endswith(
        "plant: valves[13]: V1112 (T11 -> T12) is listed twice (also valves[12])"
    )


def test_a_valve_name_is_still_derived_from_its_tanks(tmp_path: Path) -> None:
    data = site_data()
    data["plant"]["valves"][-1]["name"] = "V1211"
    assert _error(data, tmp_path).endswith("plant.valves[12]: name must be V1112 for a valve from T11 to T12")


@pytest.mark.parametrize("name", ["T0", "T100", "T01", "T1a"])
def test_tank_numbers_outside_1_to_99_are_refused(name: str, tmp_path: Path) -> None:
    data = site_data()
    data["plant"]["tanks"][0]["name"] = name
    msg = _error(data, tmp_path)
    assert "plant.tanks[0].name: String should match pattern '^T[1-9][0-9]?$'" in msg


@pytest.mark.parametrize(
    ("where", "field", "value"),
    [("pumps", "name", "P100"), ("pumps", "name", "P0")],
)
def test_pump_numbers_outside_1_to_99_are_refused(where: str, field: str, value: str, tmp_path: Path) -> None:
    data = site_data()
    data["plant"][where][0][field] = value
    assert f"plant.{where}[0].{field}: String should match pattern" in _error(data, tmp_path)


@pytest.mark.parametrize(("field", "value"), [("name", "LIC100"), ("pv", "LT0"), ("pv", "LT100")])
def test_loop_and_transmitter_numbers_outside_1_to_99_are_refused(
    field: str, value: str, tmp_path: Path
) -> None:
    data = site_data()
    data["plc"]["loops"][0][field] = value
    assert f"plc.loops[0].{field}: String should match pattern" in _error(data, tmp_path)


def test_scenario_events_take_two_digit_names_and_refuse_three() -> None:
    assert LeakEvent.model_validate({"at_s": 1, "kind": "leak", "tank": "T12", "opening": 1.0}).tank == "T12"
    with pytest.raises(ValidationError) as e:
        LeakEvent.model_validate({"at_s": 1, "kind": "leak", "tank": "T100", "opening": 1.0})
    assert "tank" in format_validation_error("s.yaml", e.value)


def test_names_a_reader_sees_sort_by_number() -> None:
    names = ["T10", "T2", "T1", "LIC10PvBad", "LIC2PvBad", "IoFault", "T12Trip", "T9Trip"]
    assert sorted(names, key=numeric_key) == [
        "IoFault",
        "LIC2PvBad",
        "LIC10PvBad",
        "T1",
        "T2",
        "T9Trip",
        "T10",
        "T12Trip",
    ]
