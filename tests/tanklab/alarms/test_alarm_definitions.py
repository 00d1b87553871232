"""The PLC's alarm definitions from the site config, its ``plc.alarms`` overrides and their errors."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

from tanklab import paths
from tanklab.alarms.definitions import plc_alarms, plc_manager
from tanklab.alarms.model import ConditionKind, Priority
from tanklab.config import ConfigError, load_site, site_from_mapping
from tanklab.tags import plc_tags

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))
U, M, HI = Priority.URGENT, Priority.MEDIUM, Priority.HIGH


def energies(overrides: dict[str, Any] | None = None, **alarms: Any) -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((ROOT / "configs/three_tank_energies_sim.yaml").read_text())
    data = copy.deepcopy(data)
    data["plc"]["alarms"] = {"overrides": overrides or {}, **alarms}
    return data


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_every_shipped_site_has_its_alarms_on_contract_nodes(path: Path) -> None:
    site = load_site(path)
    if site.plc is None:
        pytest.skip("no plc section")
    defs = plc_alarms(site)
    tags = {t.path for t in plc_tags(site)}
    expect = [f"{t}Level" for t in site.tank_names] + [f"{lp}PvBad" for lp in site.loop_names]
    expect += ["IoFault", "SupervisorLost", *dict.fromkeys(f"{il.tank}Trip" for il in site.plc.interlocks)]
    assert [d.name for d in defs] == expect
    for d in defs:
        assert d.input_path in tags
        booleans = [d.boolean_path, *(d.limit_boolean_paths or ())]
        assert all(b in tags for b in booleans if b is not None)
        assert d.source.startswith(paths.TIER_ROOTS["plc"] + ".")
    m = plc_manager(site, event_prefix=b"x")
    assert set(m.booleans()) <= tags
    assert set(m.booleans()) == {p for p in tags if p.startswith(paths.plc.alarms_prefix)}


def test_energies_defaults_by_hand() -> None:
    site = site_from_mapping(energies())
    d = {a.name: a for a in plc_alarms(site)}
    t1 = d["T1Level"]
    # HH = the interlock's 0.58 m; switches LSH 0.9 * 0.62, LSL 0.05 * 0.62; range 0..0.62 m
    assert t1.kind is ConditionKind.EXCLUSIVE_LEVEL
    assert t1.limits_m == pytest.approx((0.58, 0.558, 0.031, None))  # type: ignore[arg-type]
    assert t1.deadband_m == pytest.approx(0.0124)
    assert t1.limit_priorities == (U, M, M, HI) and t1.priority is M
    assert t1.source == paths.plc.io("T1").root and t1.input_path == paths.plc.io("T1").pv
    assert d["T3Level"].limits_m is not None and d["T3Level"].limits_m[0] is None  # no interlock on T3
    assert d["LIC1PvBad"].kind is ConditionKind.DISCRETE and d["LIC1PvBad"].priority is HI
    trip = d["T1Trip"]
    assert (trip.kind, trip.latched, trip.confirm, trip.priority) == (ConditionKind.OFF_NORMAL, True, True, U)
    assert trip.boolean_path is None  # PLC.Interlock.T1HH is the interlock's own latch
    assert plc_manager(site).max_shelving_time_s == 8 * 3600.0


def test_overrides_apply() -> None:
    site = site_from_mapping(
        energies(
            {
                "T1Level": {
                    "priority": "LOW",
                    "limit_priorities": {"HighHigh": "URGENT"},
                    "deadband_m": 0.005,
                    "on_delay_s": 2,
                    "off_delay_s": 3,
                    "low_low_m": 0.01,
                    "suppress_when_manual": True,
                },
                "LIC2PvBad": {"priority": "URGENT", "suppress_when_manual": True},
                "SupervisorLost": {"on_delay_s": 5},
            },
            max_shelving_time_s=1800,
        )
    )
    d = {a.name: a for a in plc_alarms(site)}
    t1 = d["T1Level"]
    assert t1.limit_priorities == (U, Priority.LOW, Priority.LOW, Priority.LOW)
    assert t1.priority is Priority.LOW
    assert (t1.deadband_m, t1.on_delay_s, t1.off_delay_s) == (0.005, 2.0, 3.0)
    assert t1.limits_m is not None and t1.limits_m[3] == 0.01
    assert t1.suppress_when_manual == "LIC1"
    assert (d["LIC2PvBad"].priority, d["LIC2PvBad"].suppress_when_manual) == (U, "LIC2")
    assert d["SupervisorLost"].on_delay_s == 5.0
    assert plc_manager(site).max_shelving_time_s == 1800.0


@pytest.mark.parametrize(
    ("alarms", "field", "rule"),
    [
        ({"overrides": {"T9Level": {}}}, "(top level)", "plc.alarms.overrides.T9Level: unknown alarm"),
        (
            {"overrides": {"IoFault": {"deadband_m": 0.1}}},
            "(top level)",
            "deadband_m apply to level alarms only",
        ),
        (
            {"overrides": {"IoFault": {"suppress_when_manual": True}}},
            "(top level)",
            "suppress_when_manual applies to level and PvBad alarms only",
        ),
        (
            {"overrides": {"T1Level": {"low_low_m": 0.05}}},
            "(top level)",
            "low_low_m 0.05 m must be below the low switch 0.031 m",
        ),
        ({"overrides": {"T1Level": {"deadband_m": 0.6}}}, "(top level)", "must be below the band"),
        ({"overrides": {"T1Level": {"priority": "SEVERE"}}}, "plc.alarms.overrides.T1Level.priority", "LOW"),
        (
            {"overrides": {"T1Level": {"on_delay_s": -1}}},
            "plc.alarms.overrides.T1Level.on_delay_s",
            "greater than or equal to 0",
        ),
        ({"max_shelving_time_s": 0}, "plc.alarms.max_shelving_time_s", "greater than 0"),
        ({"overrides": {"T1Level": {"colour": 1}}}, "plc.alarms.overrides.T1Level.colour", "Extra inputs"),
    ],
)
def test_bad_alarm_config_names_file_field_and_rule(
    tmp_path: Path, alarms: dict[str, Any], field: str, rule: str
) -> None:
    data = energies()
    data["plc"]["alarms"] = alarms
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_site(bad)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{bad}: {field}"), msg
    assert rule in msg, msg
