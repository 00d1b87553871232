"""A write flood against the PLC while it scans (real plant and PLC processes at speed 5).

Four engineer sessions write as fast as they can (one request in flight each) a mix of valid and
invalid values to both loops' SP, ManualMV and Mode for 5 s of wall time. No invalid write is
accepted, and the PLC keeps its model rate: one scan period of model time per scan, the scan
going on through the flood. The flood driver is ``tanklab_testing.security.watched_flood``; its
"before" reading is taken once all four sessions are logged in.

A burst of failed logins (user names that do not exist, which the per-name lockout does not stop)
is refused, login by login, while the PLC scans on, and the watching session keeps working. (A
password login costs the server one scrypt, ~70 ms; it runs in a worker thread before asyncua's
synchronous user lookup, ``tanklab_io.ua_security.TankUserManager.preverify``, and more than ten
failures a minute suspend password checks altogether.)

Timing properties, deadlines kept (``PLC.Status.Overruns`` unchanged) during the flood and the
login storms and the PLC's model time keeping up with the plant's, depend on how busy the machine
is, so they are measured in ``make bench`` (the security section: 60 s floods, login storms),
never asserted here: tests assert on model time and events only.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from helpers import engineer_logins, secure, session_home
from tanklab_io.ua_client import new_client
from tanklab_io.ua_security import ClientIdentity, secure_client
from tanklab_io.users import Credentials
from tanklab_testing import security
from tanklab_testing.procs import free_base_port  # random bases: parallel sessions do not collide
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

SPEED = 5.0
TS = security.SITE.plc.scan_period_s if security.SITE.plc else 1.0
FLOOD_S = 5.0
CLIENTS = 4


def logins() -> security.Logins:
    return engineer_logins()


@pytest.fixture
async def plant_and_plc(tmp_path: Path) -> AsyncIterator[tuple[str, str]]:
    config = security.site_config(tmp_path / "site.yaml", at_operating_point=True)
    stack = Stack(config, free_base_port(3), speed=SPEED, state_file=tmp_path / "plant.json")
    try:
        await stack.up(("plant", "plc"))
        yield stack.plant_url, stack.plc_url
    finally:
        await stack.down()


async def test_write_flood_keeps_the_scan_on_its_deadlines_and_model_rate(
    plant_and_plc: tuple[str, str],
) -> None:
    plant_url, plc_url = plant_and_plc
    counts, watch = await security.watched_flood(
        plc_url, plant_url, logins(), seconds=FLOOD_S, clients=CLIENTS, seed=3
    )
    assert counts.errors == []
    assert counts.violations == [], "invalid writes accepted"
    assert counts.accepted > 0 and counts.sent - counts.accepted > 0
    # Model rate: one Ts of model time per scan, and the scan went on alongside the flood.
    scans = int(watch.after["Scan"]) - int(watch.before["Scan"])
    advanced = float(watch.after["ModelTime"]) - float(watch.before["ModelTime"])
    assert advanced == pytest.approx(scans * TS)
    assert scans > 0


async def test_failed_logins_are_refused_while_the_plc_scans_on(plant_and_plc: tuple[str, str]) -> None:
    _, plc_url = plant_and_plc
    home = session_home()
    refused: list[bool] = []

    async def failed_login(k: int) -> None:
        client = new_client(plc_url, 10)
        await secure_client(
            client, ClientIdentity(home, "cli", Credentials(f"nobody{k}", "not-the-password"))
        )
        try:
            await client.connect()
        except Exception:  # refused: the session is not activated
            refused.append(True)
        else:
            refused.append(False)
        with contextlib.suppress(Exception):
            await client.disconnect()

    async with await secure(plc_url) as watcher:
        before = await security.status_after_scans(watcher, 2)
        for burst in range(3):  # 3 bursts of 8 concurrent logins (~0.5 s of scrypt each)
            await asyncio.gather(*(failed_login(8 * burst + k) for k in range(8)))
        after = await security.status_after_scans(watcher, 2)
    assert refused == [True] * 24
    assert int(after["Scan"]) >= int(before["Scan"]) + 2  # scanning went on; the watcher still reads
    assert float(after["ModelTime"]) - float(before["ModelTime"]) == pytest.approx(
        (int(after["Scan"]) - int(before["Scan"])) * TS
    )
