"""Site identity: the config digest is stable under formatting and changes with the site."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from tanklab.config import ConfigError, load_site, site_from_mapping
from tanklab.identity import SiteIdentity, canonical_json, config_digest, site_from_json
from tanklab.scenario import live_unappliable, load_scenario
from tanklab.tags import identity_paths, plant_tags, plc_tags, supervisor_tags, tags_by_path

ROOT = Path(__file__).resolve().parents[2]
ENERGIES = ROOT / "configs/three_tank_energies_sim.yaml"
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


def _data() -> dict[str, Any]:
    data = yaml.safe_load(ENERGIES.read_text())
    assert isinstance(data, dict)
    return data


def _reordered(value: Any) -> Any:
    """The same data with every mapping's keys in reverse order."""
    if isinstance(value, dict):
        return {k: _reordered(value[k]) for k in reversed(list(value))}
    if isinstance(value, list):
        return [_reordered(v) for v in value]
    return value


def test_the_digest_is_sha256_hex_and_known_for_the_energies_site() -> None:
    site = load_site(ENERGIES)
    ident = SiteIdentity.of(site)
    assert ident.name == "three_tank_energies_sim"
    assert len(ident.digest) == 64 and int(ident.digest, 16) >= 0
    assert ident.short == ident.digest[:16]
    assert str(ident) == f"three_tank_energies_sim (config {ident.digest[:16]})"


def test_key_order_formatting_and_written_out_defaults_keep_the_digest(tmp_path: Path) -> None:
    reference = config_digest(load_site(ENERGIES))
    # Key order reversed everywhere, flow style, no comments: another file, the same site.
    other = tmp_path / "reordered.yaml"
    other.write_text(yaml.safe_dump(_reordered(_data()), sort_keys=False, default_flow_style=True))
    assert other.read_text() != ENERGIES.read_text()
    assert config_digest(load_site(other)) == reference
    # A number written another way (1e-4 vs 0.0001, an int for a float) is the same number.
    data = _data()
    data["plant"]["pumps"][0]["max_flow_m3_s"] = float(data["plant"]["pumps"][0]["max_flow_m3_s"])
    text = yaml.safe_dump(data).replace(repr(data["plant"]["pumps"][0]["max_flow_m3_s"]), "1.2e-4")
    assert "1.2e-4" in text
    assert config_digest(site_from_mapping(yaml.safe_load(text))) == reference
    # A default written out explicitly changes nothing either.
    data = _data()
    data["stack"] = {"restart": False}
    data["plant"].setdefault("description", "")
    assert config_digest(site_from_mapping(data)) == reference


@pytest.mark.parametrize(
    ("path", "value"),
    [
        (("plant", "tanks", 0, "area_m2"), None),
        (("plc", "loops", 0, "setpoint_m"), 0.41),
        (("plc", "scan_period_s"), 0.5),
        (("name",), "three_tank_energies_copy"),
    ],
)
def test_a_changed_parameter_changes_the_digest(path: tuple[Any, ...], value: Any) -> None:
    reference = config_digest(load_site(ENERGIES))
    data = _data()
    node: Any = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value if value is not None else node[path[-1]] * 1.001
    assert config_digest(site_from_mapping(data)) != reference


def test_where_and_how_it_runs_is_not_in_the_digest() -> None:
    reference = config_digest(load_site(ENERGIES))
    data = _data()
    data["endpoints"] = {"plant": {"host": "0.0.0.0", "port": 5840}, "plc": {"port": 5841}}
    data["stack"] = {"restart": True, "max_restarts": 9}
    data["plant"]["state_file"] = "/var/lib/tanklab/plant.json"
    data["plc"]["retain_file"] = "/var/lib/tanklab/plc-retain.json"
    assert config_digest(site_from_mapping(data)) == reference
    assert '"endpoints"' not in canonical_json(site_from_mapping(data))


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_the_published_config_gives_back_the_same_site(path: Path) -> None:
    site = load_site(path)
    text = canonical_json(site)
    assert json.loads(text) == json.loads(canonical_json(site_from_json(text, "x")))
    assert SiteIdentity.of(site_from_json(text, "x")) == SiteIdentity.of(site)
    assert site_from_json(text, "x").tank_names == site.tank_names


def test_a_published_config_that_is_not_a_site_is_one_line() -> None:
    with pytest.raises(ConfigError, match=r"^plc at U: Identity.Config: not a JSON site config"):
        site_from_json("{not json", "plc at U: Identity.Config")
    with pytest.raises(ConfigError, match=r"^src: plant: Field required"):
        site_from_json('{"name": "x"}', "src")


def test_every_tier_publishes_its_identity_as_constant_nodes() -> None:
    site = load_site(ENERGIES)
    ident = SiteIdentity.of(site)
    for tier, build in (("plant", plant_tags), ("plc", plc_tags), ("supervisor", supervisor_tags)):
        tags = tags_by_path(build(site))
        paths = identity_paths(tier)  # type: ignore[arg-type]
        assert tags[paths["SiteName"]].initial == ident.name
        assert tags[paths["ConfigDigest"]].initial == ident.digest
        assert tags[paths["Config"]].initial == canonical_json(site)
        assert not any(tags[p].writable for p in paths.values())
    assert identity_paths("plc")["ConfigDigest"] == "PLC.Identity.ConfigDigest"


def test_live_unappliable_names_initial_states_and_explicit_variant_settings(tmp_path: Path) -> None:
    scenario, _ = load_scenario(ROOT / "configs/scenarios/kortela_mpc_vs_pi.yaml")
    skipped = live_unappliable(scenario)
    assert any(s.startswith("variants[") and ".set plc.scan_period_s" in s for s in skipped)
    assert all(
        any(s.startswith(f"variants[{v.name}].supervisor_mode {v.supervisor_mode} ") for s in skipped)
        for v in scenario.variants
    )
    plain = tmp_path / "plain.yaml"
    plain.write_text(f"name: plain\nsite: {ENERGIES}\nduration_s: 5\nevents: []\n")
    assert live_unappliable(load_scenario(plain)[0]) == []
    levels = tmp_path / "levels.yaml"
    levels.write_text(
        f"name: levels\nsite: {ENERGIES}\nduration_s: 5\n"
        "initial: {levels_m: [0, 0, 0], pump_commands: [0, 0]}\n"
        "variants: [{name: a, scan_period_s: 0.5}]\n"
    )
    assert live_unappliable(load_scenario(levels)[0]) == [
        "initial.levels_m (a running plant's levels are not writable)",
        "initial.pump_commands (the PLC owns the pump commands)",
        "variants[a].scan_period_s (the PLC's scan period is fixed at its start)",
    ]
