"""What the HMI serves of a site (pure): the live set, the site description, value conversions."""

from __future__ import annotations

from pathlib import Path

import pytest

from helpers import ROOT
from hmi.site import SiteModel, json_value, parse_value
from tanklab import paths
from tanklab.config import load_site

SITES = sorted((ROOT / "configs").glob("*.yaml"))


@pytest.fixture(scope="module")
def energies() -> SiteModel:
    return SiteModel.of(load_site(ROOT / "configs/three_tank_energies_sim.yaml"))


@pytest.mark.parametrize("config", SITES, ids=lambda p: p.stem)
def test_every_shipped_site_has_a_live_set_of_its_own_variables(config: Path) -> None:
    model = SiteModel.of(load_site(config))
    site = model.site
    assert len(model.live) == len(set(model.live))
    assert all(model.tags[p].kind == "variable" for p in model.live)
    binding_tags = {b["tag"] for b in model.description["mimic"]["bindings"]}
    assert binding_tags <= set(model.live)
    for tank in site.plant.tanks:
        assert paths.plant.tank(tank.name).level in model.live
        assert paths.plant.lt(tank.name).fault in model.live
    if site.plc is None:  # a plant-only site (tankctl hmi refuses it): no loops, no alarms
        assert model.alarms == {} and model.description["loops"] == []
        return
    for loop in site.plc.loops:
        lp = paths.plc.loop(loop.name)
        assert {lp.sp, lp.pv, lp.mv, lp.mode, lp.manual_mv, lp.gain_source} <= set(model.live)
    assert any(p.startswith("PLC.AlarmSummary.") for p in model.live)
    # every tier is in every poll, the historian too: its silence is a link message (down)
    assert {model.tier_of(p) for p in model.live} >= {"plant", "plc", "historian"}
    has_supervisor = site.supervisor is not None
    assert (paths.supervisor.mode in model.live) == has_supervisor
    assert all(model.tags[p].tier != "supervisor" for p in model.live) or has_supervisor
    assert set(model.alarms) == ({"plc", "supervisor"} if has_supervisor else {"plc"})
    assert model.description["supervisor"] is has_supervisor
    assert [t["name"] for t in model.description["tanks"]] == [t.name for t in site.plant.tanks]


def test_description_of_the_energies_site(energies: SiteModel) -> None:
    d = energies.description
    lic1 = next(lp for lp in d["loops"] if lp["name"] == "LIC1")
    assert lic1 == {
        "name": "LIC1",
        "pv_tank": "T1",
        "pump": "P1",
        "sp_range_m": [energies.site.plc.loops[0].sp_min_m, energies.site.plc.loops[0].sp_max_m],  # type: ignore[union-attr]
        "mv_range": [0.0, 1.2e-4],
        "mv_unit": "m^3/s",
        "has_gains": True,
    }
    p1 = next(p for p in d["pumps"] if p["name"] == "P1")
    assert p1 == {"name": "P1", "unit": "m^3/s", "range": [0.0, 1.2e-4], "tank": "T1"}
    assert len(d["digest"]) == 64


def test_json_values(energies: SiteModel) -> None:
    mode = energies.tags[paths.plc.loop("LIC1").mode]
    assert json_value(mode, 1) in ("AUTO", "MANUAL", "REMOTE")
    assert json_value(mode, 99) == 99  # not a member: the number as read
    assert json_value(None, float("nan")) is None
    assert json_value(None, [1.0, float("inf")]) == [1.0, None]
    assert json_value(None, True) is True and json_value(None, "x") == "x" and json_value(None, None) is None


def test_parse_value_by_the_tags_type(energies: SiteModel) -> None:
    lp = paths.plc.loop("LIC1")
    sp, mode = energies.tags[lp.sp], energies.tags[lp.mode]
    assert parse_value(sp, 0.3) == 0.3 and parse_value(sp, 1) == 1.0
    assert parse_value(mode, "auto") == parse_value(mode, "AUTO")
    assert isinstance(parse_value(mode, 1), int)
    for bad in ("0.3", True, None, [0.3]):
        with pytest.raises(ValueError, match="number"):
            parse_value(sp, bad)
    with pytest.raises(ValueError, match="not one of"):
        parse_value(mode, "BANANA")
    with pytest.raises(ValueError, match="integer"):
        parse_value(mode, 1.5)
    with pytest.raises(KeyError, match="unknown path"):
        energies.variable("PLC.LIC1.Nope")
    with pytest.raises(KeyError):
        energies.variable(lp.set_gains)  # a method, not a variable
