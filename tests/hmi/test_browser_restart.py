"""The screen survives any tier's restart: the tier is shown unreachable meanwhile, then back.

The tiers run as separate processes (:class:`tanklab_testing.stack.Stack`: ``tankctl up`` stops
the whole stack when one tier dies), the real HMI server against them, and an Operator's
headless Chromium. Each tier in turn (supervisor, historian, PLC, plant) is killed (SIGKILL, a
crash): the header marks it unreachable while the other tiers' values keep arriving (the model
time still advances on the screen; with the plant away, the PLC's scan counter in the page's
store); restarted, it is shown reachable again, and the page never logged a script error.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from helpers import TEST_PASSWORDS
from hmi_browser import LoopThread, browser, http_json
from tanklab import paths
from tanklab_testing.procs import TankctlProcess, free_base_port, free_port
from tanklab_testing.sites import PORT_ORDER, site_config
from tanklab_testing.stack import Stack
from tanklab_testing.waits import wait_until

pytestmark = pytest.mark.process


def test_every_tier_restart_is_shown_and_survived(tmp_path: Path) -> None:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True, pumps_hold_on_watchdog=True)
    loop = LoopThread()
    stack = Stack(config, free_base_port(), speed=5.0, log_dir=tmp_path / "logs")
    port = free_port()
    hmi = TankctlProcess(
        "hmi",
        "--config",
        str(config),
        "--base-port",
        str(stack.base),
        "--port",
        str(port),
        name="hmi",
        ready=None,
        log=tmp_path / "hmi.log",
        ports=[port],
    )
    url = f"http://127.0.0.1:{port}"
    try:
        loop.run(stack.up(PORT_ORDER))
        loop.run(hmi.start())

        async def healthy() -> bool:
            status, body = await asyncio.to_thread(http_json, f"{url}/healthz")
            return status == 200 and all(body["tiers"].values())

        loop.run(wait_until(healthy, 120, what="the HMI's /healthz", poll_s=0.5))
        with browser(tmp_path / "downloads") as page:
            page.open(url)
            page.login("operator", TEST_PASSWORDS["operator"])

            def model_time() -> float:
                text = page.css("#model-time").text.split()
                return float(text[2]) if len(text) > 2 else -1.0

            def scan() -> float:
                value = page.js(f"return window.tanklabHmi.store.value('{paths.plc.scan}')")
                return float(value) if isinstance(value, int | float) else -1.0

            for tier in ("supervisor", "historian", "plc", "plant"):
                badge = f"#links [data-link={tier}]"
                loop.run(stack.kill(tier))
                page.wait(
                    lambda b=badge: page.all(b) and page.css(b).get_attribute("data-up") == "false",
                    60,
                    f"the {tier} shown unreachable",
                )
                assert f"{tier} unreachable" in page.css(badge).text
                alive = scan if tier == "plant" else model_time
                t0 = alive()
                page.wait(
                    lambda a=alive, t=t0: a() > t + 5, 60, f"the other tiers' values arriving ({tier} away)"
                )
                if tier == "supervisor":
                    page.screenshot("tier-down")
                loop.run(stack.start(tier))
                page.wait(
                    lambda b=badge: page.css(b).get_attribute("data-up") == "true", 120, f"the {tier} back"
                )
                assert page.css(badge).text == tier
            assert page.errors() == [], "the front end logged errors"
    finally:
        try:
            loop.run(hmi.stop(), 120)
            loop.run(hmi.cleanup(), 60)
            loop.run(stack.down(), 180)
        finally:
            loop.close()
