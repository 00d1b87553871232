"""A write flood against the PLC while it scans (real plant and PLC processes at speed 5).

Four engineer sessions write as fast as they can (one request in flight each) a mix of valid and
invalid values to both loops' SP, ManualMV and Mode for 5 s of wall time (25 scans). The PLC
must keep its deadlines (``PLC.Status.Overruns`` unchanged over the flood) and keep its model
rate: it runs as much model time as the plant, whose clock is independent of the PLC's (a PLC
that skipped deadlines would fall behind), one scan period of model time per scan. No invalid
write is accepted. The flood driver is ``benchmarks.security.watched_flood`` (``make bench``
runs it for 60 s); its "before" reading is taken once all four sessions are logged in.

The last test is the regression of a defect the flood work found: a password login cost the
server one scrypt (~70 ms) inside its event loop, so a burst of failed logins (user names that
do not exist, which the per-name lockout does not stop) delayed the scan past its deadline. The
check now runs in a worker thread before asyncua's synchronous user lookup
(``tanklab.ua_security.TankUserManager.preverify``), and more than ten failures a minute suspend
password checks altogether.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
from asyncua import Client

from helpers import ROOT, TEST_PASSWORDS, TierProcess, secure, session_home
from tanklab.ua_security import ClientIdentity, secure_client
from tanklab.users import Credentials

if str(ROOT) not in sys.path:  # the benchmarks package (shared flood driver) lives at the root
    sys.path.insert(0, str(ROOT))
from benchmarks import security
from benchmarks.procs import free_base_port  # random bases: parallel sessions do not collide

pytestmark = pytest.mark.process

SPEED = 5.0
TS = security.SITE.plc.scan_period_s if security.SITE.plc else 1.0
FLOOD_S = 5.0
CLIENTS = 4


def logins() -> security.Logins:
    return security.Logins(session_home(), {"engineer": Credentials("engineer", TEST_PASSWORDS["engineer"])})


@pytest.fixture
async def plant_and_plc(tmp_path: Path) -> AsyncIterator[tuple[str, str]]:
    config = security.site_config(tmp_path / "site.yaml", at_operating_point=True)
    base = free_base_port(3)
    plant_url = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"
    common = ("--config", str(config), "--speed", f"{SPEED:g}")
    plant = await TierProcess(
        "plant", *common, "--port", str(base), "--state-file", str(tmp_path / "plant.json")
    ).start()
    plc = await TierProcess("plc", *common, "--port", str(base + 1), "--plant-url", plant_url).start()
    try:
        yield plant_url, f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc"
    finally:
        await plc.stop()
        await plant.stop()


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
    # Deadlines kept.
    assert watch.after["Overruns"] == watch.before["Overruns"]
    # Model rate: one Ts of model time per scan, and as much model time as the plant ran
    # (the two readings are separate round trips: allow a scan either side).
    scans = int(watch.after["Scan"]) - int(watch.before["Scan"])
    advanced = float(watch.after["ModelTime"]) - float(watch.before["ModelTime"])
    assert advanced == pytest.approx(scans * TS)
    assert scans >= 0.5 * FLOOD_S * SPEED / TS  # the flood did run alongside the scans
    assert abs(watch.model_lag_s) <= 2 * TS


async def test_failed_logins_do_not_delay_the_scan(plant_and_plc: tuple[str, str]) -> None:
    _, plc_url = plant_and_plc
    home = session_home()

    async def failed_login(k: int) -> None:
        client = Client(plc_url, timeout=10)
        await secure_client(
            client, ClientIdentity(home, "cli", Credentials(f"nobody{k}", "not-the-password"))
        )
        with contextlib.suppress(Exception):
            await client.connect()
        with contextlib.suppress(Exception):
            await client.disconnect()

    async with await secure(plc_url) as watcher:
        before = await security.status_after_scans(watcher, 2)
        for burst in range(3):  # 3 bursts of 8 concurrent logins (~0.5 s of scrypt each)
            await asyncio.gather(*(failed_login(8 * burst + k) for k in range(8)))
        after = await security.status_after_scans(watcher, 2)
    assert after["Overruns"] == before["Overruns"]
