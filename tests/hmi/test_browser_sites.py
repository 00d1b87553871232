"""Every shipped kind of site renders its mimic in headless Chromium: one, two and three tanks.

Each shipped config runs as a real stack (``tankctl up`` at speed 5) with the real HMI server;
an Engineer logs in and the screen must show that site's drawing: one vessel, one animated
water column and one value label per tank of the config, a faceplate for every loop, and the
water drawn at the level the plant publishes (the oracle: ``Plant.T{i}.Level`` against the
drawn height, by the drawing's own ``data-full`` / ``data-span``).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import ROOT, TEST_PASSWORDS
from hmi_browser import Browser, HmiStack, browser
from tanklab.config import load_site

pytestmark = pytest.mark.process

SITES = {
    "1tank": ROOT / "configs/single_tank_short_sim.yaml",
    "2tank": ROOT / "configs/two_tank_interacting.yaml",
    "3tank": ROOT / "configs/three_tank_energies_sim.yaml",
}


@pytest.fixture
def page(tmp_path: Path) -> Iterator[Browser]:
    with browser(tmp_path / "downloads") as b:
        yield b


@pytest.mark.parametrize("name", sorted(SITES))
def test_the_site_renders_its_mimic(name: str, page: Browser, tmp_path: Path) -> None:
    config = SITES[name]
    site = load_site(config)
    stack = HmiStack.start(tmp_path, config, "--speed", "5", "--fresh")
    try:
        page.open(stack.url)
        page.login("engineer", TEST_PASSWORDS["engineer"])
        assert page.css("#mimic svg").get_attribute("data-site") == site.name
        assert page.css("#site-name").text == site.name
        tanks = [t.name for t in site.plant.tanks]
        assert sorted(e.get_attribute("id") for e in page.all("#mimic rect.vessel")) == sorted(
            f"{t}-vessel" for t in tanks
        )

        def drawn_as_published() -> bool:
            for t in tanks:
                level = page.js(f"return window.tanklabHmi.store.value('Plant.{t}.Level')")
                water = page.css(f"#mimic [id='{t}-water']")
                if not isinstance(level, float | int):
                    return False
                full, span = float(water.get_attribute("data-full")), float(water.get_attribute("data-span"))
                want = span * min(max(level / full, 0.0), 1.0)
                if abs(float(water.get_attribute("height")) - want) > 0.11:
                    return False
            return True

        page.wait(drawn_as_published, 60, "every tank's water drawn at its published level")
        labels = {e.get_attribute("data-value-of") for e in page.all("#mimic text.value")}
        assert {f"{t}-water" for t in tanks} <= labels
        assert site.plc is not None
        for lp in site.plc.loops:
            page.faceplate(f"loop:{lp.name}", f"{lp.name}-bubble")
            assert page.css("#faceplate h2").text == lp.name
        page.screenshot(f"mimic-{name}")
        assert page.errors() == [], "the front end logged errors"  # before the stack stops
    finally:
        stack.stop()
