"""The supervisor's ``supervisor.alarms`` overrides (priority, delays, enabled, shelving maximum),
the shared ``enabled`` override, and the errors naming the file, the field and the rule."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

from tanklab.alarms import names
from tanklab.alarms.definitions import (
    SUPERVISOR_PRIORITIES,
    plc_manager,
    supervisor_alarms,
    supervisor_manager,
)
from tanklab.alarms.manager import DEFAULT_MAX_SHELVING_TIME_S
from tanklab.alarms.model import Priority
from tanklab.config import ConfigError, load_site, site_from_mapping

ROOT = Path(__file__).resolve().parents[3]


def energies(**alarms: Any) -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((ROOT / "configs/three_tank_energies_sim.yaml").read_text())
    data = copy.deepcopy(data)
    data["supervisor"]["alarms"] = alarms
    return data


def test_without_overrides_the_supervisor_alarms_keep_their_defaults() -> None:
    site = site_from_mapping(energies())
    defs = supervisor_alarms(site)
    assert [d.name for d in defs] == [names.MPC_FAILING, names.ADAPTATION_UNHEALTHY, names.PLC_LINK_LOST]
    for d in defs:
        assert (d.priority, d.on_delay_s, d.off_delay_s, d.enabled) == (
            SUPERVISOR_PRIORITIES[d.name],
            0,
            0,
            True,
        )
    assert site.plc is not None
    assert supervisor_manager(site).max_shelving_time_s == site.plc.alarms.max_shelving_time_s


def test_overrides_set_priority_delays_enabled_and_the_shelving_maximum() -> None:
    site = site_from_mapping(
        energies(
            max_shelving_time_s=1200,
            overrides={
                "PlcLinkLost": {"priority": "URGENT", "on_delay_s": 4, "off_delay_s": 6},
                "AdaptationUnhealthy": {"enabled": False},
            },
        )
    )
    d = {a.name: a for a in supervisor_alarms(site)}
    lost = d[names.PLC_LINK_LOST]
    assert (lost.priority, lost.on_delay_s, lost.off_delay_s, lost.enabled) == (
        Priority.URGENT,
        4.0,
        6.0,
        True,
    )
    assert d[names.ADAPTATION_UNHEALTHY].enabled is False
    assert d[names.MPC_FAILING].priority is SUPERVISOR_PRIORITIES[names.MPC_FAILING]
    manager = supervisor_manager(site)
    assert manager.max_shelving_time_s == 1200.0
    # A condition configured disabled starts disabled (not retained, no events), the others enabled.
    adapt = manager.condition(names.ADAPTATION_UNHEALTHY)
    assert (adapt.enabled, adapt.retain) == (False, False)
    assert manager.condition(names.PLC_LINK_LOST).enabled
    # The delays act on model time: the link lost at 10 s is annunciated at 14 s.
    values: list[float | bool | None] = [None, None, True]
    good = [True] * 3
    assert manager.scan_values(values, good, 10.0) == []
    assert manager.scan_values(values, good, 13.9) == []
    (event,) = manager.scan_values(values, good, 14.0)
    assert event.condition.active and event.condition.severity == int(Priority.URGENT)


def test_the_shared_enabled_override_disables_a_plc_alarm_at_a_cold_start() -> None:
    data = energies()
    data["plc"]["alarms"] = {"overrides": {"IoFault": {"enabled": False}}}
    manager = plc_manager(site_from_mapping(data))
    assert manager.condition(names.IO_FAULT).enabled is False
    assert manager.condition("T1Level").enabled is True


def test_without_either_shelving_maximum_the_supervisor_has_the_cores_default() -> None:
    site = site_from_mapping(energies(overrides={}))
    assert site.plc is not None and "max_shelving_time_s" not in site.plc.alarms.model_fields_set
    assert supervisor_manager(site).max_shelving_time_s == DEFAULT_MAX_SHELVING_TIME_S


@pytest.mark.parametrize(
    ("alarms", "field", "rule"),
    [
        (
            {"overrides": {"MpcLost": {}}},
            "(top level)",
            "supervisor.alarms.overrides.MpcLost: unknown alarm (the supervisor's: MpcFailing, "
            "AdaptationUnhealthy, PlcLinkLost)",
        ),
        (
            {"overrides": {"PlcLinkLost": {"deadband_m": 0.1}}},
            "(top level)",
            "supervisor.alarms.overrides.PlcLinkLost: deadband_m apply to the PLC's level alarms only",
        ),
        (
            {"overrides": {"MpcFailing": {"limit_priorities": {"High": "LOW"}}}},
            "(top level)",
            "limit_priorities apply to the PLC's level alarms only",
        ),
        (
            {"overrides": {"MpcFailing": {"suppress_when_manual": True}}},
            "(top level)",
            "suppress_when_manual applies to the PLC's level and PvBad alarms only",
        ),
        (
            {"overrides": {"MpcFailing": {"priority": "SEVERE"}}},
            "supervisor.alarms.overrides.MpcFailing.priority",
            "LOW",
        ),
        (
            {"overrides": {"PlcLinkLost": {"off_delay_s": -1}}},
            "supervisor.alarms.overrides.PlcLinkLost.off_delay_s",
            "greater than or equal to 0",
        ),
        ({"max_shelving_time_s": 0}, "supervisor.alarms.max_shelving_time_s", "greater than 0"),
        (
            {"overrides": {"PlcLinkLost": {"enabled": "maybe"}}},
            "supervisor.alarms.overrides.PlcLinkLost.enabled",
            "bool",
        ),
        ({"colour": 1}, "supervisor.alarms.colour", "Extra inputs"),
    ],
)
def test_bad_supervisor_alarm_config_names_file_field_and_rule(
    tmp_path: Path, alarms: dict[str, Any], field: str, rule: str
) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(energies(**alarms)))
    with pytest.raises(ConfigError) as err:
        load_site(bad)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{bad}: {field}"), msg
    assert rule in msg, msg


def test_adaptation_unhealthy_is_unknown_on_a_site_without_a_gain_adapter(tmp_path: Path) -> None:
    data = energies()
    loop = data["plc"]["loops"][0]
    loop.update(block="nlpi", nlpi={"b": 1e-3, "a_prime": 0.01, "wn_rad_s": 0.05})
    loop.pop("gain_box", None)
    site = site_from_mapping(data)
    assert not site.supervisor_adapts_gains
    assert [d.name for d in supervisor_alarms(site)] == [names.MPC_FAILING, names.PLC_LINK_LOST]
    data["supervisor"]["alarms"] = {"overrides": {"AdaptationUnhealthy": {"priority": "HIGH"}}}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="AdaptationUnhealthy needs a gain adapter"):
        load_site(bad)
