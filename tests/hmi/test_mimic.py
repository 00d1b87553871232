"""The P&ID mimic (``hmi.mimic``) of every shipped site and of generated chains of 1 to 9 tanks.

The oracles are the site config and the address-space contract: one element per tank, valve,
pump, loop and interlock, each bound to a tag the tier really publishes and to an alarm the site
really has; the drawing itself well-formed, its ids unique, its elements inside the view box and
its tanks and valve symbols apart.
"""

from __future__ import annotations

import copy
import itertools
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from helpers import ROOT
from hmi.mimic import TANK_H, TANK_TOP, mimic
from tanklab.alarms import names as alarm_names
from tanklab.config import SiteConfig, load_site, site_from_mapping
from tanklab.tags import all_tags

SVG = "{http://www.w3.org/2000/svg}"
SITES = sorted((ROOT / "configs").glob("*.yaml"))


def elements(site: SiteConfig) -> tuple[ET.Element, list[ET.Element]]:
    root = ET.fromstring(mimic(site).svg)
    return root, list(root.iter())


def site_alarms(site: SiteConfig) -> set[str]:
    names = {alarm_names.level(t.name) for t in site.plant.tanks}
    if site.plc is not None:
        names |= {alarm_names.pv_bad(lp.name) for lp in site.plc.loops}
        names |= {alarm_names.trip(il.tank) for il in site.plc.interlocks}
    return names


def check(site: SiteConfig) -> None:
    """Every property the module docstring promises, for ``site``."""
    drawing = mimic(site)
    root, els = elements(site)
    assert root.tag == f"{SVG}svg" and root.get("data-site") == site.name
    ids = [e.get("id") for e in els if e.get("id")]
    assert len(ids) == len(set(ids)), "element ids are unique"

    # bound to the contract: every tag is a node of the site, every alarm one of its conditions
    contract = {t.path for t in all_tags(site)}
    bound = {b.tag for b in drawing.bindings} | {e.get("data-tag") for e in els if e.get("data-tag")}
    assert bound <= contract, bound - contract
    assert {b.element_id for b in drawing.bindings} <= set(ids)
    alarms = {e.get("data-alarm") for e in els if e.get("data-alarm")}
    assert alarms <= site_alarms(site), alarms - site_alarms(site)

    # one element per thing, each opening the right faceplate
    def faceplates(kind: str) -> list[str]:
        return sorted(e.get("data-faceplate", "") for e in els if e.get("data-kind") == kind)

    tanks = site.plant.tanks
    assert faceplates("level") == sorted(f"tank:{t.name}" for t in tanks)
    assert faceplates("opening") == sorted(f"valve:{v.name}" for v in site.plant.valves)
    assert faceplates("pump") == sorted(f"pump:{p.name}" for p in site.plant.pumps)
    assert faceplates("leak") == faceplates("fault") == faceplates("level")
    loops = site.plc.loops if site.plc else []
    interlocks = site.plc.interlocks if site.plc else []
    assert faceplates("mode") == sorted(f"loop:{lp.name}" for lp in loops)
    assert faceplates("trip") == sorted(f"tank:{il.tank}" for il in interlocks)

    # the water fills from the tank's bottom to its full height at height_max
    for t in tanks:
        water = next(e for e in els if e.get("id") == f"{t.name}-water")
        assert float(water.get("data-full", "nan")) == pytest.approx(t.height_max_m)
        bottom, span = float(water.get("data-bottom", "nan")), float(water.get("data-span", "nan"))
        assert TANK_TOP < bottom - span < bottom < TANK_TOP + TANK_H

    # geometry: inside the view box; tanks and valve symbols do not overlap
    width, height = drawing.width_px, drawing.height_px
    for e in els:
        for attr, limit in (("x", width), ("cx", width), ("y", height), ("cy", height)):
            if e.get(attr) is not None:
                assert 0.0 <= float(e.get(attr, "nan")) <= limit, (e.get("id"), attr, e.get(attr))
        if e.get("points"):
            for p in e.get("points", "").split():
                x, y = map(float, p.split(","))
                assert 0.0 <= x <= width and 0.0 <= y <= height, (e.get("id"), p)
    vessels = sorted(float(e.get("x", "nan")) for e in els if e.get("class") == "vessel")
    widths = {float(e.get("width", "nan")) for e in els if e.get("class") == "vessel"}
    assert all(b - a > max(widths) for a, b in itertools.pairwise(vessels))
    boxes = [_box(e.get("points", "")) for e in els if e.get("data-kind") == "opening"]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert a[2] < b[0] or b[2] < a[0] or a[3] < b[1] or b[3] < a[1], (a, b)


def _box(points: str) -> tuple[float, float, float, float]:
    xy = [tuple(map(float, p.split(","))) for p in points.split()]
    xs, ys = [p[0] for p in xy], [p[1] for p in xy]
    return min(xs), min(ys), max(xs), max(ys)


@pytest.mark.parametrize("config", SITES, ids=lambda p: p.stem)
def test_every_shipped_site_is_drawn_bound_to_its_contract(config: Path) -> None:
    check(load_site(config))


def chain_site(n: int, skips: list[tuple[int, int]], outlets: list[int]) -> SiteConfig:
    """``n`` tanks of the Energies site in a chain T1 - T2 - ... - Tn, plus the connecting valves
    ``skips`` (non-adjacent pairs, each drawn on its own lane) and outlets of ``outlets``; pumps
    into T1 and (n > 1) T2, a PID loop and an interlock for each pumped tank."""
    base: dict[str, Any] = yaml.safe_load((ROOT / "configs" / "three_tank_energies_sim.yaml").read_text())
    data = copy.deepcopy(base)
    plant = data["plant"]
    tank, valve, pump = plant["tanks"][0], plant["valves"][0], plant["pumps"][0]
    ids = range(1, n + 1)

    def v(m: int, k: int) -> dict[str, Any]:
        spec = {"name": f"V{m}{k}", "upstream": f"T{m}", "mu": valve["mu"], "area_m2": valve["area_m2"]}
        return spec | ({"downstream": f"T{k}"} if k else {})

    pumped = [i for i in (1, 2) if i <= n]
    plant["tanks"] = [{**tank, "name": f"T{i}"} for i in ids]
    plant["valves"] = (
        [v(i, i + 1) for i in ids if i < n] + [v(m, k) for m, k in skips] + [v(i, 0) for i in outlets]
    )
    plant["pumps"] = [{**pump, "name": f"P{i}", "feeds": f"T{i}"} for i in pumped]
    plant["operating_point"] = {"levels_m": [0.3] * n, "flows_m3_s": None}
    loop, interlock = data["plc"]["loops"][0], data["plc"]["interlocks"][0]
    data["plc"]["loops"] = [{**loop, "name": f"LIC{i}", "pv": f"LT{i}", "actuator": f"P{i}"} for i in pumped]
    data["plc"]["interlocks"] = [{**interlock, "tank": f"T{i}"} for i in pumped]
    data.pop("supervisor", None)
    data["name"] = f"chain_{n}"
    return site_from_mapping(data)


Chain = tuple[int, list[tuple[int, int]], list[int]]
"""Tanks, non-adjacent connecting valves, outlets (:func:`chain_site`)."""


@st.composite
def chains(draw: st.DrawFn) -> Chain:
    n = draw(st.integers(1, 9))
    pairs = [(m, k) for m in range(1, n + 1) for k in range(m + 2, n + 1)]
    skips = draw(st.lists(st.sampled_from(pairs), unique=True, max_size=4)) if pairs else []
    outlets = draw(st.lists(st.integers(1, n), unique=True, min_size=1, max_size=n))
    return n, skips, outlets


@settings(max_examples=40, deadline=None)
@given(chains())
def test_generated_chains_are_drawn_bound_and_apart(
    chain: tuple[int, list[tuple[int, int]], list[int]],
) -> None:
    check(chain_site(*chain))


def test_a_lane_valve_sits_between_its_tanks_and_off_the_straight_pipes() -> None:
    # T1 - T2 - T3 with T1 -> T3 below: V13 on the lane, V12 and V23 straight, V30 to the drain
    site = chain_site(3, [(1, 3)], [3])
    _, els = elements(site)
    valve = {e.get("id"): _box(e.get("points", "")) for e in els if e.get("data-kind") == "opening"}
    t1 = next(float(e.get("x", "nan")) for e in els if e.get("id") == "T1-vessel")
    t2 = next(float(e.get("x", "nan")) for e in els if e.get("id") == "T2-vessel")
    lane, straight = valve["V13-valve"], valve["V12-valve"]
    assert lane[1] > TANK_TOP + TANK_H > straight[1]  # the lane runs below the tanks
    assert t1 < lane[0] < lane[2] < t2 + 1e-9  # ... its valve in the gap right of T1
    assert valve["V30-valve"][1] > lane[1]  # the outlet's valve is lower still, by the drain
