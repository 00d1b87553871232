"""An external controller over OPC UA (issue 18, decision 0055), through real servers and processes.

The access rules run against an in-process PLC server (no scan: the address space and the write
path are what is checked); the examples run as real processes against a plant and a PLC
(:class:`tanklab_testing.stack.Stack`, speed 20, the tanks at the operating point): the asyncua
example drives LIC1 in REMOTE to its own setpoint and, SIGKILLed, leaves the PLC's watchdog to
shed the loop to AUTO; the node-opcua example drives it too and hands it back on SIGTERM.
Assertions are on the PLC's published values (mode, PV, ``External.Alive``); waits go through
``wait_until``.
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from asyncua import Client, ua

from helpers import (
    ROOT,
    TEST_EXTERNAL,
    free_base_port,
    free_port,
    identity,
    server_security,
    session_home,
    wait_until,
)
from node_client import NODE, NODE_DIR
from plc_emulator.program import PlcProgram
from plc_emulator.server import PlcServer
from tanklab.config import load_site
from tanklab.enums import LoopMode, RemoteSource
from tanklab.tags import Tag, plc_tags, tags_by_path
from tanklab_io.ua import variant
from tanklab_io.ua_security import secure_client
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
TAGS = tags_by_path(plc_tags(SITE))
WATCHDOG_S = 60.0
"""The stack's PLC heartbeat timeout [model s]."""
SP_EXAMPLE = 0.45
"""The examples' own setpoint for LIC1 [m] (the PLC's SP stays 0.4)."""


async def _connect(url: str, **who: Any) -> Client:
    client = Client(url, timeout=10)
    await secure_client(client, identity(**who))
    await client.connect()
    return client


async def _write(client: Client, path: str, value: Any) -> str:
    tag: Tag = TAGS[path]
    idx = await client.get_namespace_index("urn:tanklab")
    try:
        await client.get_node(ua.NodeId(path, idx)).write_value(ua.DataValue(variant(tag, value)))
    except ua.UaStatusCodeError as e:
        return type(e).__name__
    return "Good"


async def _read(client: Client, path: str) -> Any:
    idx = await client.get_namespace_index("urn:tanklab")
    return await client.get_node(ua.NodeId(path, idx)).read_value()


# --------------------------------------------------------------------------------------------
# Access: only the loops handed to it, only RemoteMV, Mode (AUTO <-> REMOTE) and its heartbeat
# --------------------------------------------------------------------------------------------


@pytest.fixture
async def plc_url() -> AsyncIterator[str]:
    server = PlcServer(SITE, PlcProgram(SITE), "127.0.0.1", free_port(), server_security())
    await server.start()
    try:
        yield server.url
    finally:
        await server.stop()


async def test_external_writes_only_the_loops_handed_to_it_and_old_values_stay(plc_url: str) -> None:
    ext = await _connect(plc_url, tier="external")
    eng = await _connect(plc_url, user="engineer")
    sup = await _connect(plc_url, tier="supervisor")
    try:
        # Not handed yet: every loop is the supervisor's.
        assert await _read(eng, "PLC.LIC1.RemoteSource") == int(RemoteSource.SUPERVISOR)
        assert await _write(ext, "PLC.LIC1.RemoteMV", 2e-5) == "BadUserAccessDenied"
        assert await _write(ext, "PLC.LIC1.Mode", int(LoopMode.REMOTE)) == "BadUserAccessDenied"
        assert await _read(eng, "PLC.LIC1.Mode") == int(LoopMode.AUTO)
        # Only an engineer hands a loop over (the External identity and the supervisor cannot).
        assert await _write(ext, "PLC.LIC1.RemoteSource", int(RemoteSource.EXTERNAL)) == "BadUserAccessDenied"
        assert await _write(sup, "PLC.LIC1.RemoteSource", int(RemoteSource.EXTERNAL)) == "BadUserAccessDenied"
        assert await _write(eng, "PLC.LIC1.RemoteSource", int(RemoteSource.EXTERNAL)) == "Good"
        # LIC1 is the external controller's now.
        assert await _write(ext, "PLC.External.Heartbeat", 7) == "Good"
        assert await _write(ext, "PLC.LIC1.RemoteMV", 2e-5) == "Good"
        assert await _write(ext, "PLC.LIC1.Mode", int(LoopMode.REMOTE)) == "Good"
        assert await _write(ext, "PLC.LIC1.Mode", int(LoopMode.MANUAL)) == "BadUserAccessDenied"
        # ... and no longer the supervisor's; the owner of a REMOTE loop cannot change under it.
        assert await _write(sup, "PLC.LIC1.RemoteMV", 3e-5) == "BadUserAccessDenied"
        assert await _write(sup, "PLC.LIC1.Mode", int(LoopMode.AUTO)) == "BadUserAccessDenied"
        assert await _write(eng, "PLC.LIC1.RemoteSource", int(RemoteSource.SUPERVISOR)) == "BadInvalidState"
        assert await _read(eng, "PLC.LIC1.RemoteMV") == 2e-5
        assert await _read(eng, "PLC.LIC1.Mode") == int(LoopMode.REMOTE)
        assert await _read(eng, "PLC.LIC1.RemoteSource") == int(RemoteSource.EXTERNAL)
        # Another loop, and other nodes, stay out of reach.
        lic2 = await _read(eng, "PLC.LIC2.RemoteMV")
        assert await _write(ext, "PLC.LIC2.RemoteMV", 1e-5) == "BadUserAccessDenied"
        assert await _read(eng, "PLC.LIC2.RemoteMV") == lic2
        for path, value in (
            ("PLC.LIC1.SP", 0.41),
            ("PLC.LIC1.ManualMV", 1e-5),
            ("PLC.Supervisor.Heartbeat", 9),
        ):
            old = await _read(eng, path)
            assert await _write(ext, path, value) == "BadUserAccessDenied", path
            assert await _read(eng, path) == old, path
        # Nobody else writes the external heartbeat: an Observer, an engineer, the supervisor.
        obs = await _connect(plc_url, user="observer")
        try:
            for client in (obs, eng, sup):
                assert await _write(client, "PLC.External.Heartbeat", 8) == "BadUserAccessDenied"
            assert await _read(obs, "PLC.External.Heartbeat") == 7
        finally:
            await obs.disconnect()
    finally:
        for client in (ext, eng, sup):
            await client.disconnect()


async def test_the_external_certificate_opens_no_session_on_the_plant() -> None:
    """External is a PLC identity only: the plant (and the supervisor) do not map it."""
    from plant_sim.plant import PlantSimulator
    from plant_sim.server import PlantServer

    server = PlantServer(SITE, PlantSimulator(SITE.plant), "127.0.0.1", free_port(), server_security())
    await server.start()
    try:
        with pytest.raises(ua.UaStatusCodeError) as err:
            await _connect(server.url, tier="external")
        assert type(err.value).__name__ == "BadUserAccessDenied"
    finally:
        await server.stop()


# --------------------------------------------------------------------------------------------
# The examples as real processes
# --------------------------------------------------------------------------------------------


@pytest.fixture
async def stack(tmp_path: Path) -> AsyncIterator[Stack]:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True, pumps_hold_on_watchdog=True)
    data = yaml.safe_load(config.read_text(encoding="utf-8"))
    # 60 s of model time = 3 s of wall time at speed 20: an example's heartbeat delayed by a
    # loaded machine must not shed the loop mid-test (the config's 3 s would be the 1 s wall floor).
    data["plc"]["watchdog"]["timeout_s"] = WATCHDOG_S
    config.write_text(yaml.safe_dump(data), encoding="utf-8")
    st = Stack(config=config, base=free_base_port(), speed=20)
    try:
        await st.up(("plant", "plc"))
        yield st
    finally:
        await st.down()


async def _hand_lic1(url: str) -> Client:
    """An engineer hands LIC1 to the external controller; returns the engineer's (open) client."""
    eng = await _connect(url, user="engineer")
    assert await _write(eng, "PLC.LIC1.RemoteSource", int(RemoteSource.EXTERNAL)) == "Good"
    return eng


async def _drives_lic1_to_the_example_sp(eng: Client, proc: asyncio.subprocess.Process) -> None:
    async def remote() -> bool:
        assert proc.returncode is None, f"the example exited ({proc.returncode})"
        return bool(await _read(eng, "PLC.LIC1.Mode") == int(LoopMode.REMOTE))

    await wait_until(remote, 60, what="the example puts LIC1 in REMOTE")
    assert await _read(eng, "PLC.External.Alive") is True or await wait_until_alive(eng)
    t0 = await _read(eng, "PLC.Status.ModelTime")

    async def at_sp() -> bool:
        assert proc.returncode is None, f"the example exited ({proc.returncode})"
        assert await _read(eng, "PLC.LIC1.Mode") == int(LoopMode.REMOTE)
        return bool(abs(await _read(eng, "PLC.LIC1.PV") - SP_EXAMPLE) < 0.005)

    await wait_until(at_sp, 120, what=f"LIC1's level at the example's SP {SP_EXAMPLE} m", poll_s=0.2)
    assert await _read(eng, "PLC.Status.ModelTime") > t0  # it took model time: the plant moved
    assert await _read(eng, "PLC.LIC1.SP") == pytest.approx(0.4)  # the PLC's own SP is untouched


async def wait_until_alive(eng: Client) -> bool:
    async def alive() -> bool:
        return bool(await _read(eng, "PLC.External.Alive"))

    await wait_until(alive, 30, what="PLC.External.Alive")
    return True


async def _spawn(*argv: str, log: Path, cwd: Path = ROOT) -> asyncio.subprocess.Process:
    """Start an example; its stdout and stderr go to ``log`` (printed by pytest on a failure)."""
    with log.open("wb") as out:
        return await asyncio.create_subprocess_exec(
            *argv, cwd=cwd, stdout=out, stderr=asyncio.subprocess.STDOUT
        )


def _tail(log: Path) -> None:
    print(f"--- {log.name}:\n" + "\n".join(log.read_text(errors="replace").splitlines()[-40:]))


async def _reap(proc: asyncio.subprocess.Process) -> None:
    if proc.returncode is None:
        proc.kill()
    await proc.wait()


@pytest.mark.process
async def test_the_asyncua_example_drives_lic1_and_the_watchdog_sheds_it_when_killed(
    stack: Stack, tmp_path: Path
) -> None:
    eng = await _hand_lic1(stack.plc_url)
    home = str(session_home().root)
    proc = await _spawn(
        sys.executable, "examples/external_asyncua.py", "--url", stack.plc_url, "--home", home,
        "--name", TEST_EXTERNAL, "--sp", str(SP_EXAMPLE), "--period", "0.25", log=tmp_path / "example.log",
    )  # fmt: skip
    try:
        await _drives_lic1_to_the_example_sp(eng, proc)
        proc.kill()  # a crash: no hand-back, the heartbeat just stops
        await proc.wait()
        killed_at = await _read(eng, "PLC.Status.ModelTime")

        async def shed() -> bool:
            return bool(await _read(eng, "PLC.LIC1.Mode") == int(LoopMode.AUTO))

        await wait_until(shed, 30, what="the watchdog sheds LIC1 to AUTO")
        shed_at = await _read(eng, "PLC.Status.ModelTime")
        timeout = await _read(eng, "PLC.External.Timeout")
        assert timeout == WATCHDOG_S
        assert await _read(eng, "PLC.External.Alive") is False
        # Shed within the timeout (plus a scan and the poll) of the last heartbeat, not before it.
        assert 0 < shed_at - killed_at <= timeout + 2 * SITE.plc.scan_period_s + 20 * 0.5
        assert abs(await _read(eng, "PLC.LIC1.MV") - await _read(eng, "PLC.LIC1.RemoteMV")) <= 0.01 * 1.2e-4
    finally:
        await _reap(proc)
        await eng.disconnect()
        _tail(tmp_path / "example.log")


def _node_modules_ready() -> bool:
    stamp = NODE_DIR / "node_modules" / ".package-lock.json"
    return stamp.is_file()


@pytest.mark.process
@pytest.mark.skipif(NODE is None, reason="node is not installed (the node-opcua example needs node 20+)")
async def test_the_node_opcua_example_drives_lic1_and_hands_it_back_on_sigterm(
    stack: Stack, tmp_path: Path
) -> None:
    if not _node_modules_ready():
        pytest.fail(f"{NODE_DIR}/node_modules is missing: run `make node-tools`")
    # The example with the test's pinned node-opcua (the same dependency set as its package.json).
    work = tmp_path / "external_node"
    work.mkdir()
    (work / "controller.mjs").write_bytes((ROOT / "examples/external_node/controller.mjs").read_bytes())
    os.symlink(NODE_DIR / "node_modules", work / "node_modules")
    eng = await _hand_lic1(stack.plc_url)
    home = str(session_home().root)
    assert NODE is not None
    proc = await _spawn(
        NODE, "controller.mjs", "--url", stack.plc_url, "--home", home, "--name", TEST_EXTERNAL,
        "--sp", str(SP_EXAMPLE), "--period", "0.25", "--pki", str(tmp_path / "node-pki"), cwd=work,
        log=tmp_path / "example.log",
    )  # fmt: skip
    try:
        await _drives_lic1_to_the_example_sp(eng, proc)
        proc.send_signal(signal.SIGTERM)  # a clean stop: the example hands the loop back
        assert await asyncio.wait_for(proc.wait(), 60) == 0
        assert await _read(eng, "PLC.LIC1.Mode") == int(LoopMode.AUTO)
    finally:
        await _reap(proc)
        await eng.disconnect()
        _tail(tmp_path / "example.log")
