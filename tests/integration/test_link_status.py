"""The tiers' links, seen on their status nodes while the tier below goes away and comes back.

A real plant and a real PLC (processes, speed 5). The plant is stopped under the running PLC:
``PLC.Status.PlantLink.Attempts`` counts the failed connection attempts and ``.LastError`` names
the cause (the refused TCP connection); ``PLC.Status.IoHealthy`` is False. The plant is started
again on the same port (same state file): the link recovers by itself, ``Attempts`` is back to
0, ``Connects`` counts the second connection, and level readings flow again (good quality,
read in scans after the recovery). The same for the supervisor's link to a PLC stopped and
restarted under it (``Supervisor.PlcLink.*``, ``Supervisor.PlcConnected``). Waits are bounded
(``wait_until``); assertions are on node values, not on how long anything took.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from helpers import ROOT, TierProcess, free_base_port, secure, wait_until
from tanklab.tags import link_status_paths
from tanklab_io.ua_client import resolve

pytestmark = pytest.mark.process

CONFIG = str(ROOT / "configs/three_tank_energies_sim.yaml")
SPEED = "5"
LINK = link_status_paths("PLC.Status.PlantLink")
PATHS = [
    *LINK.values(),
    "PLC.Status.IoHealthy",
    "PLC.Status.Scan",
    "PLC.IO.LT1.PV",
    "PLC.IO.LT1.Good",
    "PLC.Alarms.IoFault",
]


class Plc:
    """An engineer's client of the PLC reading the link's nodes in one Read."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.client: Any = None
        self.nodes: dict[str, Any] = {}

    async def __aenter__(self) -> Plc:
        self.client = await secure(self.url)
        await self.client.connect()
        self.nodes = await resolve(self.client, PATHS)
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.client.disconnect()

    async def read(self) -> dict[str, Any]:
        values = await self.client.read_values([self.nodes[p] for p in PATHS])
        return dict(zip(PATHS, values, strict=True))


@pytest.fixture
async def plant_args(tmp_path: Path) -> AsyncIterator[tuple[int, tuple[str, ...]]]:
    base = free_base_port()
    yield (
        base,
        (
            "plant",
            "--config",
            CONFIG,
            "--speed",
            SPEED,
            "--port",
            str(base),
            "--state-file",
            str(tmp_path / "plant.json"),
        ),
    )


async def test_plant_stopped_and_restarted_under_the_plc_shows_on_its_link_nodes(
    plant_args: tuple[int, tuple[str, ...]],
) -> None:
    base, plant_cmd = plant_args
    plant_url = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"
    plant = await TierProcess(*plant_cmd).start()
    plc_proc = await TierProcess(
        "plc", "--config", CONFIG, "--speed", SPEED, "--port", str(base + 1), "--plant-url", plant_url
    ).start()
    try:
        async with Plc(f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc") as plc:

            async def healthy() -> bool:
                v = await plc.read()
                return bool(v["PLC.Status.IoHealthy"]) and v[LINK["Connects"]] >= 1

            await wait_until(healthy, 30, what="the PLC's field link up")
            first = await plc.read()
            assert first[LINK["Attempts"]] == 0
            assert first[LINK["Connects"]] == 1
            assert first[LINK["RetryDelay"]] == 0.0
            assert first["PLC.IO.LT1.Good"]

            await plant.stop()

            async def failing() -> bool:
                v = await plc.read()
                return v[LINK["Attempts"]] >= 3

            await wait_until(failing, 60, what="three failed attempts counted")
            down = await plc.read()
            assert not down["PLC.Status.IoHealthy"]
            assert down["PLC.Alarms.IoFault"]
            assert not down["PLC.IO.LT1.Good"]
            # The cause, named: nothing listens on the plant's port any more.
            assert down[LINK["LastError"]].startswith("ConnectionRefusedError: ")
            assert str(base) in down[LINK["LastError"]]
            assert 0 < down[LINK["RetryDelay"]] <= 5.0
            assert down[LINK["Connects"]] == 1

            plant = await TierProcess(*plant_cmd).start()

            async def recovered() -> bool:
                v = await plc.read()
                return bool(v["PLC.Status.IoHealthy"]) and v[LINK["Connects"]] == 2

            await wait_until(recovered, 60, what="the PLC's field link recovered")
            up = await plc.read()
            assert up[LINK["Attempts"]] == 0
            assert up[LINK["RetryDelay"]] == 0.0
            # Why it was down: refused while nothing listened, or, if the last attempt met the
            # plant still starting on a loaded machine, that attempt's timeout.
            assert up[LINK["LastError"]].startswith(("ConnectionRefusedError: ", "TimeoutError"))
            # Readings flow again: good quality on scans after the recovery.
            scan = up["PLC.Status.Scan"]

            async def reading() -> bool:
                v = await plc.read()
                return v["PLC.Status.Scan"] >= scan + 3 and bool(v["PLC.IO.LT1.Good"])

            await wait_until(reading, 30, what="good level readings after the recovery")
            again = await plc.read()
            assert 0.0 < again["PLC.IO.LT1.PV"] < 1.0
            assert not again["PLC.Alarms.IoFault"]
    finally:
        await plc_proc.stop()
        await plant.stop()


async def test_plc_stopped_and_restarted_under_the_supervisor_shows_on_its_link_nodes() -> None:
    base = free_base_port()
    plc_url = f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc"
    nowhere = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"  # no plant: the PLC scans with bad I/O
    plc_cmd = ("plc", "--config", CONFIG, "--speed", SPEED, "--port", str(base + 1), "--plant-url", nowhere)
    plc = await TierProcess(*plc_cmd).start()
    sup = await TierProcess(
        "supervisor", "--config", CONFIG, "--speed", SPEED, "--port", str(base + 2), "--plc-url", plc_url
    ).start()
    link = link_status_paths("Supervisor.PlcLink")
    paths = [*link.values(), "Supervisor.PlcConnected"]
    try:
        client = await secure(f"opc.tcp://127.0.0.1:{base + 2}/tanklab/supervisor")
        async with client:
            nodes = await resolve(client, paths)

            async def read() -> dict[str, Any]:
                return dict(zip(paths, await client.read_values([nodes[p] for p in paths]), strict=True))

            async def connected(n: int) -> bool:
                v = await read()
                return v[link["Connects"]] == n and v[link["Attempts"]] == 0 and v["Supervisor.PlcConnected"]

            await wait_until(lambda: connected(1), 30, what="the supervisor's PLC link up")
            await plc.stop()

            async def failing() -> bool:
                return (await read())[link["Attempts"]] >= 2

            await wait_until(failing, 60, what="two failed attempts counted")
            down = await read()
            assert not down["Supervisor.PlcConnected"]
            assert down[link["LastError"]].startswith("ConnectionRefusedError: ")
            assert 0 < down[link["RetryDelay"]] <= 5.0

            plc = await TierProcess(*plc_cmd).start()
            await wait_until(lambda: connected(2), 60, what="the supervisor's PLC link recovered")
            assert (await read())[link["RetryDelay"]] == 0.0
    finally:
        await sup.stop()
        await plc.stop()
