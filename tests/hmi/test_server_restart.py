"""The HMI survives a tier restarting: the browser is told the tier is away and back, the other
tiers' values keep coming, and commands to the tier answer again once it is back (real processes)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection, connect

from helpers import ROOT, TEST_PASSWORDS, free_base_port, free_port
from tanklab import paths
from tanklab_testing.procs import TankctlProcess
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

CONFIG = ROOT / "configs/three_tank_energies_sim.yaml"


async def next_of(ws: ClientConnection, kind: str, **match: Any) -> dict[str, Any]:
    """The next message of type ``kind`` whose fields equal ``match`` (within 60 s in all: the
    values keep coming, so a bound per message would never end the wait)."""

    async def wanted() -> dict[str, Any]:
        while True:
            m = json.loads(await ws.recv())
            if m["type"] == kind and all(m.get(k) == v for k, v in match.items()):
                return m

    return await asyncio.wait_for(wanted(), 60.0)


async def test_a_supervisor_restart_is_a_link_down_and_up_and_the_screen_keeps_going(tmp_path: Path) -> None:
    stack = Stack(CONFIG, free_base_port(), speed=5.0, state_file=tmp_path / "plant.json")
    port = free_port()
    hmi = TankctlProcess(
        *("hmi", "--config", str(CONFIG), "--base-port", str(stack.base), "--port", str(port)),
        "--no-historian",
        log=tmp_path / "hmi.log",
    )
    try:
        await stack.up()
        await hmi.start()
        assert hmi.said("hmi: three_tank_energies_sim at http://127.0.0.1:")
        url = f"http://127.0.0.1:{port}"
        async with httpx.AsyncClient(base_url=url, timeout=15.0) as b:
            r = await b.post("/api/login", json={"user": "engineer", "password": TEST_PASSWORDS["engineer"]})
            assert r.status_code == 200
            b.headers["X-CSRF-Token"] = r.json()["csrf"]
            # Without a historian: the site says so, and a trend is 503 saying why.
            assert (await b.get("/api/site")).json()["historian"] is False
            span = {"path": [paths.plc.loop("LIC1").pv], "start": 1, "end": 2}
            trend = await b.get("/api/trend", params=span)
            assert trend.status_code == 503 and "--no-historian" in trend.json()["error"]
            cookie = f"tanklab_hmi={b.cookies['tanklab_hmi']}"
            async with connect(
                url.replace("http", "ws") + "/ws", additional_headers={"Cookie": cookie}
            ) as ws:
                await next_of(ws, "values")
                await stack.kill("supervisor")
                down = await next_of(ws, "link", tier="supervisor")
                assert down["up"] is False and down["reason"]
                # The plant's and the PLC's values keep coming meanwhile.
                later = await next_of(ws, "values")
                while "Plant.Sim.Time" not in later["values"]:
                    later = await next_of(ws, "values")
                away = await b.post("/api/write", json={"path": paths.supervisor.mode, "value": "MPC"})
                assert away.status_code == 503 and "supervisor" in away.json()["error"]
                health = (await b.get("/healthz")).json()["tiers"]
                assert health["supervisor"] is False and health["plc"] is True
                await stack.start("supervisor")
                back = await next_of(ws, "link", tier="supervisor")
                assert back["up"] is True
                r = await b.post("/api/write", json={"path": paths.supervisor.mode, "value": "MPC"})
                assert r.json() == {"ok": True, "status": "Good"}
                mode = await next_of(ws, "values")
                while paths.supervisor.mode not in mode["values"]:
                    mode = await next_of(ws, "values")
                assert mode["values"][paths.supervisor.mode]["v"] == "MPC"
        assert hmi.running  # nothing crashed
        assert await hmi.stop() == 0
    finally:
        await hmi.stop()
        await stack.down()


async def test_a_plant_plc_or_historian_restart_is_a_link_down_and_up_and_the_rest_keeps_going(
    tmp_path: Path,
) -> None:
    """Each of the other tiers (the supervisor's restart is the test above) killed and restarted in
    turn under one WebSocket: a ``link`` down naming it, /healthz saying so, the other tiers'
    values still arriving (the PLC's scan counter while the plant is away, the model time while
    another tier is), a ``link`` up once it serves again; the HMI never exits."""
    stack = Stack(
        CONFIG,
        free_base_port(),
        speed=5.0,
        state_file=tmp_path / "plant.json",
        tier_args={"historian": ("--store", str(tmp_path / "history.db"))},
    )
    port = free_port()
    hmi = TankctlProcess(
        *("hmi", "--config", str(CONFIG), "--base-port", str(stack.base), "--port", str(port)),
        log=tmp_path / "hmi.log",
    )
    try:
        await stack.up(("plant", "plc", "supervisor", "historian"))
        await hmi.start()
        url = f"http://127.0.0.1:{port}"
        async with httpx.AsyncClient(base_url=url, timeout=15.0) as b:
            r = await b.post("/api/login", json={"user": "engineer", "password": TEST_PASSWORDS["engineer"]})
            assert r.status_code == 200
            cookie = f"tanklab_hmi={b.cookies['tanklab_hmi']}"
            async with connect(
                url.replace("http", "ws") + "/ws", additional_headers={"Cookie": cookie}
            ) as ws:
                await next_of(ws, "values")
                for tier, alive in (
                    ("historian", "Plant.Sim.Time"),
                    ("plc", "Plant.Sim.Time"),
                    ("plant", paths.plc.scan),
                ):
                    await stack.kill(tier)
                    down = await next_of(ws, "link", tier=tier)
                    assert down["up"] is False and down["reason"], down
                    later = await next_of(ws, "values")
                    while alive not in later["values"]:
                        later = await next_of(ws, "values")
                    health = (await b.get("/healthz")).json()["tiers"]
                    assert health[tier] is False and sum(health.values()) == 3, health
                    await stack.start(tier)
                    back = await next_of(ws, "link", tier=tier)
                    assert back["up"] is True, back
        assert hmi.running  # nothing crashed
        assert await hmi.stop() == 0
    finally:
        await hmi.stop()
        await stack.down()
