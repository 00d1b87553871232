"""Site configs: every shipped file validates; bad files give one line naming file, field, rule."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from tankctl.cli import app
from tanklab.config import ConfigError, PumpSpec, load_site, parse_endpoint_url, site_from_mapping

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))
REQUIRED = {
    "three_tank_energies_sim.yaml",
    "three_tank_energies_rig.yaml",
    "three_tank_kortela.yaml",
    "single_tank_short_sim.yaml",
    "single_tank_short_rig.yaml",
    "two_tank_interacting.yaml",
}
runner = CliRunner()


def test_every_parameter_set_of_the_digest_ships() -> None:
    assert {p.name for p in CONFIGS} >= REQUIRED


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_shipped_config_validates(path: Path) -> None:
    site = load_site(path)
    assert site.name == path.stem
    result = runner.invoke(app, ["config", "check", str(path)])
    assert result.exit_code == 0, result.output
    assert "ok" in result.output


def _energies() -> dict:
    return yaml.safe_load((ROOT / "configs/three_tank_energies_sim.yaml").read_text())


@pytest.mark.parametrize(
    ("mutate", "field", "rule"),
    [
        (lambda d: d["plant"]["tanks"][0].update(area_m2=-1), "plant.tanks[0].area_m2", "greater than 0"),
        (lambda d: d["plant"]["tanks"][1].update(colour="red"), "plant.tanks[1].colour", "Extra inputs"),
        (lambda d: d["plant"]["valves"][0].update(name="V12"), "plant.valves[0]", "name must be V13"),
        (lambda d: d["plc"]["loops"][0].update(setpoint_m=0.9), "plc.loops[0]", "setpoint_m must lie"),
        (lambda d: d["plant"]["pumps"][0].update(command_max="lots"), "plant.pumps[0].command_max", "number"),
        (lambda d: d["plant"]["tanks"][0].update(leak_mu=float("nan")), "plant.tanks[0].leak_mu", "finite"),
        (lambda d: d["supervisor"]["mpc"].update(qz=[1.0]), "(top level)", "one weight per controlled"),
        # HH 0.615 m + one 1 s scan at 1.2e-4 m^3/s into 0.0154 m^2 (7.8 mm) passes the 0.62 m top.
        (
            lambda d: d["plc"]["interlocks"][0].update(high_high_m=0.615, reset_below_m=0.6),
            "(top level)",
            "plus one scan at full pump flow (0.00779 m) reaches height_max_m 0.62 m",
        ),
        # The supervisor samples on the PLC's scan grid: 2.5 s is not a whole number of 1 s scans.
        (
            lambda d: d["supervisor"].update(sample_time_s=2.5),
            "(top level)",
            "supervisor.sample_time_s 2.5 s must be a whole multiple of plc.scan_period_s 1 s",
        ),
        (
            lambda d: d["supervisor"].update(sample_time_s=2.0, mode="ADAPTIVE_PID"),
            "(top level)",
            "supervisor.mode ADAPTIVE_PID needs supervisor.sample_time_s equal to plc.scan_period_s",
        ),
        # The cadence is a time now, not a count of scans.
        (lambda d: d["supervisor"].update(cycle_scans=2), "supervisor.cycle_scans", "xtra"),
    ],
)
def test_bad_config_is_one_line_naming_file_field_and_rule(
    tmp_path: Path, mutate, field: str, rule: str
) -> None:
    data = _energies()
    mutate(data)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_site(bad)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"{bad}: {field}"), msg
    assert rule in msg
    result = runner.invoke(app, ["config", "check", str(bad)])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and "Traceback" not in result.output


def test_unreadable_and_invalid_yaml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_site(tmp_path / "missing.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("plant: [unclosed\n")
    with pytest.raises(ConfigError, match=r"broken.yaml: line \d+: invalid YAML"):
        load_site(broken)
    with pytest.raises(ConfigError, match="expected a mapping"):
        site_from_mapping([1, 2], "list.yaml")


YAML_FILES = sorted((ROOT / "configs").rglob("*.yaml"))


@pytest.mark.skipif(not hasattr(yaml, "CSafeLoader"), reason="PyYAML built without libyaml")
@pytest.mark.parametrize("path", YAML_FILES, ids=lambda p: str(p.relative_to(ROOT / "configs")))
def test_libyaml_reads_every_shipped_file_as_the_pure_python_loader_does(path: Path) -> None:
    """read_yaml parses with libyaml when it can (decision 0039): the same objects as
    ``yaml.safe_load`` for every site and scenario file, types included."""
    from tanklab.config import read_yaml

    fast, pure = read_yaml(path), yaml.safe_load(path.read_text(encoding="utf-8"))
    assert fast == pure
    assert json.dumps(fast, sort_keys=True, default=repr) == json.dumps(pure, sort_keys=True, default=repr)


@pytest.mark.parametrize(
    "text",
    ["plant: [unclosed\n", "a: 1\n  b: 2\n", "key: 'open\n", "- a\nb: 1\n", "x: !!python/name:os.system\n"],
)
def test_a_yaml_error_names_the_line_and_problem_the_pure_python_loader_names(
    tmp_path: Path, text: str
) -> None:
    """A document libyaml refuses is parsed again by the pure-Python loader: the one-line
    error is the one it gave before (line and problem), and nothing unsafe is constructed."""
    from tanklab.config import read_yaml

    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(yaml.YAMLError) as pure:
        yaml.safe_load(text)
    mark = getattr(pure.value, "problem_mark", None)
    where = f"line {mark.line + 1}" if mark is not None else "(parse)"
    problem = getattr(pure.value, "problem", None) or str(pure.value).splitlines()[0]
    with pytest.raises(ConfigError) as got:
        read_yaml(path)
    assert str(got.value) == f"{path}: {where}: invalid YAML: {problem}"


def test_environment_overrides_endpoints() -> None:
    site = load_site(
        ROOT / "configs/three_tank_energies_sim.yaml",
        env={"TANKLAB_PLANT_URL": "opc.tcp://plant:5000/tanklab/plant", "TANKLAB_PLC_URL": ""},
    )
    assert site.endpoints.plant.host == "plant" and site.endpoints.plant.port == 5000
    assert site.endpoints.plc.port == 4841
    with pytest.raises(ConfigError, match="TANKLAB_SUPERVISOR_URL"):
        load_site(ROOT / "configs/three_tank_energies_sim.yaml", env={"TANKLAB_SUPERVISOR_URL": "http://x"})
    with pytest.raises(ValueError):
        parse_endpoint_url("opc.tcp://host:99999")


def test_speed_pump_map_has_a_dead_zone_and_inverts() -> None:
    pump = PumpSpec(
        name="P1",
        feeds="T1",
        command_kind="speed",
        command_max=1350,
        slope=2e-7,
        offset_m3_s=-1e-4,
        max_flow_m3_s=1.7e-4,
    )
    assert pump.unit == "rpm"
    assert pump.flow_of(400) == 0.0  # below the 500 rpm dead zone
    assert pump.flow_of(875) == pytest.approx(7.5e-5)  # the rig's printed operating speed
    assert pump.flow_of(5000) == pytest.approx(1.7e-4)  # saturated
    assert pump.command_of(1.143e-5) == pytest.approx(557.15, abs=0.01)


def test_schema_is_checked_in_and_current() -> None:
    result = runner.invoke(app, ["config", "schema"])
    assert result.exit_code == 0
    checked_in = (ROOT / "docs/config-schema.json").read_text()
    assert json.loads(result.output) == json.loads(checked_in), (
        "run `make docs` to refresh docs/config-schema.json"
    )


def test_every_field_is_documented() -> None:
    schema = json.loads(runner.invoke(app, ["config", "schema"]).output)
    missing = [
        f"{name}.{field}"
        for name, model in schema["$defs"].items()
        for field, spec in model.get("properties", {}).items()
        if not spec.get("description")
    ]
    missing += [f"SiteConfig.{f}" for f, s in schema["properties"].items() if not s.get("description")]
    assert missing == []


def test_supervisor_sample_time_is_a_whole_number_of_plc_scans() -> None:
    data = _energies()
    data["plc"]["scan_period_s"] = 0.5
    data["supervisor"]["sample_time_s"] = 2.5
    site = site_from_mapping(data)
    assert site.supervisor_sample_scans == 5
    assert site.supervisor_sample_time_s == 2.5
    del data["supervisor"]["sample_time_s"]
    assert site_from_mapping(data).supervisor_sample_scans == 1  # default: every scan
