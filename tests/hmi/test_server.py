"""The HMI server against a real stack: ``tankctl hmi`` as a process, the tiers and the historian
as processes, every request over real HTTP and WebSocket on loopback (issue 17).

One stack and one HMI serve the module (the Energies site at speed 5). Each test logs in as the
session's test users (conftest.security_home): the tiers check the passwords and the roles.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from helpers import ROOT, TEST_PASSWORDS, free_base_port, free_port, secure, session_home, wait_until
from hmi.app import WS_MAX_BYTES, HmiState, create_app
from hmi.sessions import SessionTable
from hmi.site import SiteModel
from tanklab import paths
from tanklab.config import load_site
from tanklab_io.ua_client import resolve
from tanklab_testing.stack import Stack
from tanklab_testing.waits import wait_until_sync

pytestmark = pytest.mark.process

CONFIG = ROOT / "configs/three_tank_energies_sim.yaml"
SPEED = 5.0
LIC1 = paths.plc.loop("LIC1")


@dataclass
class Hmi:
    url: str
    stack: Stack
    proc: subprocess.Popen[bytes]
    log: Path


def _healthy(url: str) -> bool:
    try:
        return httpx.get(f"{url}/healthz", timeout=2.0).status_code == 200
    except httpx.HTTPError:
        return False


@pytest.fixture(scope="module")
def hmi(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Hmi]:
    tmp = tmp_path_factory.mktemp("hmi")
    stack = Stack(
        CONFIG,
        free_base_port(),
        speed=SPEED,
        state_file=tmp / "plant.json",
        tier_args={"historian": ("--store", str(tmp / "history.db"))},
    )
    with stack.serving(("plant", "plc", "supervisor", "historian")):
        port = free_port()
        cli_ports = ["--base-port", str(stack.base), "--port", str(port)]
        log = tmp / "hmi.log"
        with log.open("wb") as out:
            proc = subprocess.Popen(
                [sys.executable, "-m", "tankctl", "hmi", "--config", str(CONFIG), *cli_ports],
                cwd=ROOT,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=os.environ.copy(),
            )
        url = f"http://127.0.0.1:{port}"
        try:
            wait_until_sync(
                lambda: proc.poll() is None and _healthy(url), 60.0, what="the HMI serves", poll_s=0.2
            )
            yield Hmi(url, stack, proc, log)
        finally:
            proc.terminate()
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)


@contextlib.asynccontextmanager
async def browser(hmi: Hmi, user: str | None = None) -> AsyncIterator[httpx.AsyncClient]:
    """An HTTP client with a cookie jar, logged in as ``user`` when given."""
    async with httpx.AsyncClient(base_url=hmi.url, timeout=15.0) as client:
        if user is not None:
            r = await client.post("/api/login", json={"user": user, "password": TEST_PASSWORDS[user]})
            assert r.status_code == 200, r.text
            client.headers["X-CSRF-Token"] = r.json()["csrf"]
        yield client


async def plc_value(hmi: Hmi, path: str) -> Any:
    async with await secure(hmi.stack.plc_url, "engineer") as client:
        (node,) = (await resolve(client, [path])).values()
        return await node.read_value()


# ---- health, login, roles ---------------------------------------------------------------------


async def test_healthz_names_every_tier_reachable(hmi: Hmi) -> None:
    async with browser(hmi) as b:
        r = await b.get("/healthz")
    assert r.status_code == 200
    assert r.json() == {
        "ok": True,
        "tiers": {"plant": True, "plc": True, "supervisor": True, "historian": True},
    }


async def test_login_session_and_cookie_flags(hmi: Hmi) -> None:
    async with browser(hmi) as b:
        assert (await b.get("/api/session")).status_code == 401
        r = await b.post("/api/login", json={"user": "operator", "password": TEST_PASSWORDS["operator"]})
        assert r.status_code == 200
        body = r.json()
        assert body["user"] == "operator" and body["role"] == "Operator" and body["idle_timeout_s"] == 900
        cookie = r.headers["set-cookie"].lower()
        assert "tanklab_hmi=" in cookie and "httponly" in cookie and "samesite=strict" in cookie
        assert "path=/" in cookie and "secure" not in cookie  # plain http on loopback
        again = (await b.get("/api/session")).json()
        assert again["csrf"] == body["csrf"] and again["user"] == "operator"


async def test_wrong_password_is_refused_by_the_tiers(hmi: Hmi) -> None:
    async with browser(hmi) as b:
        r = await b.post("/api/login", json={"user": "operator", "password": "not-the-password"})
        assert r.status_code == 401
        assert r.json() == {
            "error": "login as 'operator' refused: wrong user name or password, or the account is locked"
        }
        assert (await b.get("/api/session")).status_code == 401
        bad = await b.post("/api/login", content=b"not json")
        assert bad.status_code == 400


async def test_observer_write_reaches_the_tier_and_is_refused(hmi: Hmi) -> None:
    before = await plc_value(hmi, LIC1.sp)
    async with browser(hmi, "observer") as b:
        assert (await b.get("/api/session")).json()["role"] == "Observer"
        r = await b.post("/api/write", json={"path": LIC1.sp, "value": 0.31})
    assert r.status_code == 200
    assert r.json()["ok"] is False and r.json()["status"] == "BadUserAccessDenied"
    assert await plc_value(hmi, LIC1.sp) == before


async def test_operator_setpoint_write_and_read_back_and_out_of_range_keeps_the_old_value(hmi: Hmi) -> None:
    async with browser(hmi, "operator") as b:
        r = await b.post("/api/write", json={"path": LIC1.sp, "value": 0.33})
        assert r.json() == {"ok": True, "status": "Good"}
        assert await plc_value(hmi, LIC1.sp) == pytest.approx(0.33)
        r = await b.post("/api/write", json={"path": LIC1.sp, "value": 5.0})
        assert r.status_code == 200
        assert r.json()["ok"] is False and r.json()["status"] == "BadOutOfRange"
        assert "refused: BadOutOfRange" in r.json()["error"]
        assert await plc_value(hmi, LIC1.sp) == pytest.approx(0.33)
        # Malformed requests: 400, nothing written.
        for bad in (
            {"path": "PLC.LIC1.Nope", "value": 1.0},
            {"path": LIC1.sp, "value": "high"},
            {"path": LIC1.sp},
            {"value": 0.2},
        ):
            assert (await b.post("/api/write", json=bad)).status_code == 400, bad
        assert (await b.post("/api/write", json=[1, 2])).status_code == 400
        mode = await b.post("/api/write", json={"path": LIC1.mode, "value": "BANANA"})
        assert mode.status_code == 400
        assert await plc_value(hmi, LIC1.sp) == pytest.approx(0.33)


async def test_csrf_token_is_required_on_every_post_but_login(hmi: Hmi) -> None:
    async with browser(hmi, "operator") as b:
        token = b.headers.pop("X-CSRF-Token")
        r = await b.post("/api/write", json={"path": LIC1.sp, "value": 0.2})
        assert r.status_code == 403 and r.json() == {"error": "CSRF token missing or wrong"}
        r = await b.post("/api/write", json={"path": LIC1.sp, "value": 0.2}, headers={"X-CSRF-Token": "x"})
        assert r.status_code == 403
        assert (await b.post("/api/logout")).status_code == 403
        assert (await b.post("/api/interlock/reset", json={})).status_code == 403
        r = await b.post("/api/logout", headers={"X-CSRF-Token": token})
        assert r.status_code == 204
        assert "tanklab_hmi" not in b.cookies
        assert (await b.get("/api/session")).status_code == 401
        assert (await b.get("/api/site")).status_code == 401
    assert await plc_value(hmi, LIC1.sp) != pytest.approx(0.2)


async def test_site_description(hmi: Hmi) -> None:
    async with browser(hmi, "observer") as b:
        site = (await b.get("/api/site")).json()
    assert site["site"] == "three_tank_energies_sim"
    assert [t["name"] for t in site["tanks"]] == ["T1", "T2", "T3"]
    assert {v["name"]: v["kind"] for v in site["valves"]} == {
        "V13": "connecting",
        "V32": "connecting",
        "V20": "outlet",
    }
    loop = next(lp for lp in site["loops"] if lp["name"] == "LIC1")
    assert loop["pv_tank"] == "T1" and loop["pump"] == "P1" and loop["has_gains"] is True
    assert site["supervisor"] is True and site["historian"] is True
    assert site["mimic"]["svg"].startswith("<svg")
    assert {"element", "tag", "kind"} <= set(site["mimic"]["bindings"][0])


# ---- live data --------------------------------------------------------------------------------


async def messages(ws: ClientConnection, kind: str, n: int = 1) -> list[dict[str, Any]]:
    """The next ``n`` messages of type ``kind`` (others skipped; bounded by the socket's reads)."""
    got: list[dict[str, Any]] = []
    while len(got) < n:
        m = json.loads(await asyncio.wait_for(ws.recv(), 20.0))
        if m["type"] == kind:
            got.append(m)
    return got


def ws_url(hmi: Hmi) -> str:
    return hmi.url.replace("http://", "ws://") + "/ws"


async def test_websocket_without_login_is_closed_with_4401(hmi: Hmi) -> None:
    async with connect(ws_url(hmi)) as ws:
        with pytest.raises(ConnectionClosed) as caught:
            await asyncio.wait_for(ws.recv(), 20.0)
    assert ws.close_code == 4401, caught.value


async def test_websocket_from_another_sites_page_is_refused(hmi: Hmi) -> None:
    async with browser(hmi, "operator") as b:
        headers = {"Cookie": f"tanklab_hmi={b.cookies['tanklab_hmi']}", "Origin": "http://evil.example"}
        async with connect(ws_url(hmi), additional_headers=headers) as ws:
            with pytest.raises(ConnectionClosed):
                await asyncio.wait_for(ws.recv(), 20.0)
        assert ws.close_code == 4403
        own = {"Cookie": headers["Cookie"], "Origin": hmi.url}
        async with connect(ws_url(hmi), additional_headers=own, origin=None) as ws:
            assert json.loads(await asyncio.wait_for(ws.recv(), 20.0))["type"] == "hello"


async def test_websocket_hello_values_alarms_and_changes(hmi: Hmi) -> None:
    async with browser(hmi, "operator") as b:
        cookie = f"tanklab_hmi={b.cookies['tanklab_hmi']}"
        async with connect(ws_url(hmi), additional_headers={"Cookie": cookie}) as ws:
            hello = json.loads(await asyncio.wait_for(ws.recv(), 20.0))
            assert hello == {"type": "hello", "user": "operator", "role": "Operator"}
            (first,) = await messages(ws, "values")
            values = first["values"]
            for path in (LIC1.sp, LIC1.pv, LIC1.mode, "Plant.T1.Level", "Plant.Sim.Time", "Supervisor.Mode"):
                assert path in values, path
            assert values[LIC1.mode]["v"] in ("AUTO", "MANUAL", "REMOTE")
            assert values["Plant.T1.Level"]["q"] == "Good"
            assert isinstance(values["Plant.Sim.Time"]["t"], float)
            (alarms,) = await messages(ws, "alarms")
            assert isinstance(alarms["alarms"], list)
            # Model time moves: later messages carry only what changed, Sim.Time among it.
            (later,) = await messages(ws, "values")
            assert "Plant.Sim.Time" in later["values"]
            assert later["values"]["Plant.Sim.Time"]["v"] > values["Plant.Sim.Time"]["v"]
            assert set(later["values"]) < set(values)
            # Subscriptions: unknown paths are an error message, the socket stays.
            await ws.send(json.dumps({"type": "subscribe", "paths": ["PLC.Nope"]}))
            (err,) = await messages(ws, "error")
            assert err["error"] == "unknown path PLC.Nope"
            await ws.send("{broken")
            (err,) = await messages(ws, "error")
            assert "JSON" in err["error"]
            await ws.send(json.dumps({"type": "subscribe", "paths": [paths.plc.scan]}))
            (sub,) = await messages(ws, "values")
            while paths.plc.scan not in sub["values"]:
                (sub,) = await messages(ws, "values")


async def test_malformed_websocket_messages_are_error_frames_and_change_nothing(hmi: Hmi) -> None:
    """Not JSON, not an object, wrong types, an unknown op (a write: the socket has none), a binary
    frame: each one error frame, the socket stays and nothing is written; a message above
    WS_MAX_BYTES closes the socket with 1009 unparsed; the server serves on."""
    before = await plc_value(hmi, LIC1.sp)
    async with browser(hmi, "operator") as b:
        cookie = {"Cookie": f"tanklab_hmi={b.cookies['tanklab_hmi']}"}
        async with connect(ws_url(hmi), additional_headers=cookie) as ws:
            await messages(ws, "alarms")  # hello, the first values and the alarms are in
            for bad, error in (
                ("not json at all", "message is not JSON"),
                ("[1, 2]", "message must be a JSON object"),
                ('"subscribe"', "message must be a JSON object"),
                (
                    json.dumps({"type": "write", "path": LIC1.sp, "value": 0.77}),
                    "unknown message type 'write'",
                ),
                (json.dumps({"type": 7}), "unknown message type 7"),
                (json.dumps({"paths": [LIC1.sp]}), "unknown message type None"),
                (json.dumps({"type": "subscribe", "paths": LIC1.sp}), "paths must be a list of strings"),
                (json.dumps({"type": "subscribe", "paths": [1, None]}), "paths must be a list of strings"),
                (json.dumps({"type": "subscribe"}), "paths must be a list of strings"),
                (b"\x00\xff binary", "JSON text is wanted"),
            ):
                await ws.send(bad)
                (err,) = await messages(ws, "error")
                assert err == {"type": "error", "error": error}, bad
            # the socket still works: a good subscribe brings its value
            await ws.send(json.dumps({"type": "subscribe", "paths": [paths.plc.scan]}))
            (sub,) = await messages(ws, "values")
            while paths.plc.scan not in sub["values"]:
                (sub,) = await messages(ws, "values")
        async with connect(ws_url(hmi), additional_headers=cookie, max_size=None) as ws:
            await messages(ws, "alarms")
            huge = json.dumps({"type": "subscribe", "paths": ["PLC.LIC1.SP" + "x" * 70_000]})
            assert len(huge) > WS_MAX_BYTES
            await ws.send(huge)
            with pytest.raises(ConnectionClosed):
                while True:
                    await asyncio.wait_for(ws.recv(), 20.0)
        assert ws.close_code == 1009  # message too big
        assert (await b.get("/api/session")).status_code == 200  # the session is untouched
    assert await plc_value(hmi, LIC1.sp) == before
    assert hmi.proc.poll() is None and _healthy(hmi.url)


async def test_another_users_or_a_logged_out_session_is_refused_and_changes_nothing(hmi: Hmi) -> None:
    """User A's cookie with user B's CSRF token (and B's with A's) is 403; a logged-out session's
    cookie replayed (with its own token, or with a live session's) is 401 on every route and
    4401 on the WebSocket; the setpoint never changes."""
    before = await plc_value(hmi, LIC1.sp)
    write = {"path": LIC1.sp, "value": 0.27}
    async with browser(hmi, "operator") as a, browser(hmi, "engineer") as b, browser(hmi, "operator") as gone:
        a_cookie, b_cookie = a.cookies["tanklab_hmi"], b.cookies["tanklab_hmi"]
        a_csrf, b_csrf = a.headers["X-CSRF-Token"], b.headers["X-CSRF-Token"]
        assert a_cookie != b_cookie and a_csrf != b_csrf
        old_cookie, old_csrf = gone.cookies["tanklab_hmi"], gone.headers["X-CSRF-Token"]
        assert old_cookie != a_cookie  # the same user, another login: another session
        assert (await gone.post("/api/logout")).status_code == 204
        async with httpx.AsyncClient(base_url=hmi.url, timeout=15.0) as forger:
            for cookie, csrf, status in (
                (a_cookie, b_csrf, 403),
                (b_cookie, a_csrf, 403),
                (old_cookie, old_csrf, 401),
                (old_cookie, a_csrf, 401),
            ):
                headers = {"Cookie": f"tanklab_hmi={cookie}", "X-CSRF-Token": csrf}
                for route, body in (
                    ("/api/write", write),
                    ("/api/loop/LIC1/manual", {"percent": 50}),
                    ("/api/interlock/reset", {}),
                    ("/api/logout", {}),
                ):
                    r = await forger.post(route, json=body, headers=headers)
                    assert r.status_code == status, (route, cookie == a_cookie, r.text)
            replay = {"Cookie": f"tanklab_hmi={old_cookie}"}
            assert (await forger.get("/api/session", headers=replay)).status_code == 401
            assert (await forger.get("/api/site", headers=replay)).status_code == 401
            span = {"path": [LIC1.pv], "start": 1, "end": 2}
            assert (await forger.get("/api/trend", params=span, headers=replay)).status_code == 401
        async with connect(ws_url(hmi), additional_headers=replay) as ws:
            with pytest.raises(ConnectionClosed):
                await asyncio.wait_for(ws.recv(), 20.0)
        assert ws.close_code == 4401
        # the refusals closed nothing: both live sessions still work, each with its own token
        assert (await a.get("/api/session")).json()["user"] == "operator"
        assert (await b.get("/api/session")).json()["user"] == "engineer"
    assert await plc_value(hmi, LIC1.sp) == before


# ---- alarms and history -----------------------------------------------------------------------


async def test_alarm_appears_and_its_ack_with_comment_reaches_the_condition(hmi: Hmi) -> None:
    """A +0.5 m bias on LT1 puts the PLC's reading of T1 above its high limits at once: the
    alarm appears on the socket, the Operator acknowledges it with a comment through the HMI,
    and the PLC's condition is acknowledged with that comment."""
    lt1 = paths.plant.lt("T1")
    async with browser(hmi, "operator") as b:
        cookie = f"tanklab_hmi={b.cookies['tanklab_hmi']}"
        async with connect(ws_url(hmi), additional_headers={"Cookie": cookie}) as ws:
            assert (await b.post("/api/write", json={"path": lt1.fault_value, "value": 0.5})).json()["ok"]
            assert (await b.post("/api/write", json={"path": lt1.fault, "value": "BIAS"})).json()["ok"]
            try:
                alarm: dict[str, Any] | None = None
                while alarm is None:
                    (m,) = await messages(ws, "alarms")
                    standing = [a for a in m["alarms"] if a["active"] and not a["acked"]]
                    alarm = next((a for a in standing if a["id"] == "plc:T1Level"), None)
                assert alarm["tier"] == "plc" and alarm["priority"] in ("MEDIUM", "HIGH", "URGENT")
                assert alarm["source"] and alarm["message"] and alarm["shelved"] == "Unshelved"
                ack = {"id": "plc:T1Level", "comment": "seen by the hmi test"}
                r = await b.post("/api/alarms/ack", json=ack)
                assert r.json() == {"ok": True, "status": "Good"}
                condition = paths.condition("plc", "T1Level")
                assert await plc_value(hmi, f"{condition}.AckedState.Id") is True
                assert (await plc_value(hmi, f"{condition}.Comment")).Text == "seen by the hmi test"
                while True:
                    (m,) = await messages(ws, "alarms")
                    mine = [a for a in m["alarms"] if a["id"] == "plc:T1Level"]
                    if mine and mine[0]["acked"]:
                        assert mine[0]["comment"] == "seen by the hmi test"
                        break
                bad = await b.post("/api/alarms/ack", json={"id": "plc:NoSuchAlarm", "comment": ""})
                assert bad.status_code == 400
                assert (
                    await b.post("/api/alarms/shelve", json={"id": "plc:T1Level", "kind": "x"})
                ).status_code == 400
            finally:
                await b.post("/api/write", json={"path": lt1.fault, "value": "NONE"})
                await b.post("/api/write", json={"path": lt1.fault_value, "value": 0.0})

                async def reset() -> bool:
                    await b.post("/api/interlock/reset", json={})
                    return await plc_value(hmi, paths.plc.interlock("T1")) is False

                await wait_until(reset, 60.0, what="T1's interlock reset", poll_s=0.5)


async def test_trend_from_the_historian_returns_the_pv_series(hmi: Hmi) -> None:
    async with browser(hmi, "observer") as b:
        end = time.time() + 5.0
        start = end - 3600.0

        async def has_samples() -> bool:
            r = await b.get("/api/trend", params={"path": [LIC1.pv, LIC1.sp], "start": start, "end": end})
            return r.status_code == 200 and len(r.json()["series"][LIC1.pv]["t"]) >= 3

        await wait_until(has_samples, 60.0, what="the historian has PV samples", poll_s=0.5)
        r = await b.get("/api/trend", params={"path": [LIC1.pv], "start": start, "end": end})
        series = r.json()["series"][LIC1.pv]
        assert r.json()["aggregate"] is None
        assert len(series["t"]) == len(series["v"])
        assert series["t"] == sorted(series["t"])
        assert all(start <= t <= end for t in series["t"])
        assert all(v is None or -1.0 <= v <= 2.0 for v in series["v"])  # LT1 was biased meanwhile
        # Fewer points than samples: the Average over (end - start) / points.
        n = len(series["t"])
        r = await b.get(
            "/api/trend", params={"path": [LIC1.pv], "start": start, "end": end, "points": max(1, n // 3)}
        )
        assert r.json()["aggregate"] == "Average"
        assert len(r.json()["series"][LIC1.pv]["t"]) <= max(1, n // 3) + 1
        for bad in ({"path": ["PLC.Nope"], "start": 1, "end": 2}, {"path": [LIC1.pv], "start": 2, "end": 1}):
            assert (await b.get("/api/trend", params=bad)).status_code == 400, bad
        events = await b.get("/api/alarms/history", params={"start": start, "end": end, "limit": 50})
        assert events.status_code == 200
        times = [e["time"] for e in events.json()["events"]]
        assert times == sorted(times, reverse=True) and len(times) <= 50


# ---- the idle timeout, on an injected clock ---------------------------------------------------


async def test_idle_session_is_closed_with_its_opc_ua_sessions(hmi: Hmi) -> None:
    """The app in this process on a clock the test moves, against the real tiers."""
    now = [1000.0]
    urls = {t: hmi.stack.url(t) for t in ("plant", "plc", "supervisor", "historian")}
    state = HmiState(
        SiteModel.of(load_site(CONFIG)), urls, session_home(), SessionTable(60.0), now=lambda: now[0]
    )
    app = create_app(state)
    async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://hmi") as b:
        r = await b.post("/api/login", json={"user": "operator", "password": TEST_PASSWORDS["operator"]})
        assert r.status_code == 200
        hub = state.hubs["operator"]
        assert all(link.healthy for link in hub.links.values())
        now[0] += 59.0
        assert (await b.get("/api/session")).status_code == 200  # a request: idle from now on
        now[0] += 59.0
        assert (await b.get("/api/session")).status_code == 200
        now[0] += 60.0
        assert (await b.get("/api/session")).status_code == 401
        await state.expire()
        assert state.hubs == {} and len(state.sessions) == 0
        assert not any(link.healthy for link in hub.links.values())
        await state.close()
