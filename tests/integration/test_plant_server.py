"""The plant's OPC UA server for real: a server on a free loopback port, a real client.

Assertions are on model time (``Plant.Sim.Time`` read in the same Read as the level); the test
waits for the processes only through ``wait_until``.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from asyncua import ua

from helpers import free_port, identity, secure, server_security, wait_until
from plant_sim.runtime import run_plant
from plc_emulator.link import FieldLink
from plc_emulator.program import PlcProgram
from plc_emulator.runtime import warm_resume
from tanklab.config import load_site
from tanklab_io.ua_client import read_values, resolve
from tanklab_io.ua_security import client_setup

ROOT = Path(__file__).resolve().parents[2]
SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
AT = 0.0154


@pytest.fixture
async def plant_url():
    port = free_port()
    stop, ready = asyncio.Event(), asyncio.Event()
    task = asyncio.create_task(
        run_plant(
            SITE, host="127.0.0.1", port=port, security=server_security(), speed=4.0, stop=stop, ready=ready
        )
    )
    await wait_until(ready.is_set, 20, what="plant server ready")
    yield f"opc.tcp://127.0.0.1:{port}/tanklab/plant"
    stop.set()
    await asyncio.wait_for(task, 20)


async def test_pump_command_raises_the_level_at_q_over_at(plant_url: str) -> None:
    q = 1.0e-4
    # Close V13 (an operator's write) so that T1 has no outflow: its level must then rise at
    # exactly Q / At.
    async with await secure(plant_url, "operator") as operator:
        v13 = (await resolve(operator, ["Plant.V13.Opening"]))["Plant.V13.Opening"]
        await v13.write_value(ua.Variant(0.0, ua.VariantType.Double))
    # Pump commands are the PLC's: this client acts with the PLC's certificate.
    async with await secure(plant_url, tier="plc") as client:
        n = await resolve(client, ["Plant.T1.Level", "Plant.Sim.Time", "Plant.P1.Command"])
        await n["Plant.P1.Command"].write_value(ua.Variant(q, ua.VariantType.Double))
        h_a, t_a = await read_values(client, [n["Plant.T1.Level"], n["Plant.Sim.Time"]])

        async def advanced() -> bool:
            # Keep commanding (the plant's watchdog stops pumps left without commands).
            await n["Plant.P1.Command"].write_value(ua.Variant(q, ua.VariantType.Double))
            t = await n["Plant.Sim.Time"].read_value()
            return t - t_a >= 20.0

        await wait_until(advanced, 30, what="20 s of model time")
        h_b, t_b = await read_values(client, [n["Plant.T1.Level"], n["Plant.Sim.Time"]])
    rate = (h_b - h_a) / (t_b - t_a)
    assert h_b < 0.5  # still low, no overflow
    assert rate == pytest.approx(q / AT, rel=0.02)


async def test_bad_writes_are_refused_and_the_old_value_stays(plant_url: str) -> None:
    async with await secure(plant_url, tier="plc") as plc:
        cmd = (await resolve(plc, ["Plant.P1.Command"]))["Plant.P1.Command"]
        before = await cmd.read_value()
        with pytest.raises(ua.UaStatusCodeError) as err:
            await cmd.write_value(ua.Variant(-1e-5, ua.VariantType.Double))
        assert type(err.value).__name__ == "BadOutOfRange"
        assert await cmd.read_value() == before
        # Advance is for lock-step only.
        idx = cmd.nodeid.NamespaceIndex
        with pytest.raises(ua.UaStatusCodeError) as err:
            await plc.get_node(ua.NodeId("Plant.Sim", idx)).call_method(
                ua.NodeId("Plant.Sim.Advance", idx), 1.0, [0.0, 0.0]
            )
        assert type(err.value).__name__ == "BadInvalidState"
    async with await secure(plant_url, "engineer") as client:
        n = await resolve(
            client,
            [
                "Plant.P1.Command",
                "Plant.T1.Leak",
                "Plant.LT1.Fault",
                "Plant.T1.Level",
                "Plant.T2.Disturbance",
            ],
        )
        await n["Plant.T1.Leak"].write_value(ua.Variant(0.25, ua.VariantType.Double))
        cases = [
            ("Plant.T1.Leak", ua.Variant(1.5, ua.VariantType.Double), "BadOutOfRange"),
            ("Plant.T1.Leak", ua.Variant(float("nan"), ua.VariantType.Double), "BadOutOfRange"),
            ("Plant.T1.Leak", ua.Variant(float("inf"), ua.VariantType.Double), "BadOutOfRange"),
            ("Plant.T1.Leak", ua.Variant(1, ua.VariantType.Int32), "BadTypeMismatch"),
            ("Plant.T1.Leak", ua.Variant("open", ua.VariantType.String), "BadTypeMismatch"),
            ("Plant.P1.Command", ua.Variant(1e-5, ua.VariantType.Double), "BadUserAccessDenied"),
            ("Plant.LT1.Fault", ua.Variant(9, ua.VariantType.Int32), "BadOutOfRange"),
            ("Plant.T2.Disturbance", ua.Variant(1.0, ua.VariantType.Double), "BadOutOfRange"),
            ("Plant.T1.Level", ua.Variant(0.3, ua.VariantType.Double), "BadNotWritable"),
        ]
        for path, value, expected in cases:
            before = await n[path].read_value()
            with pytest.raises(ua.UaStatusCodeError) as err:
                await n[path].write_value(value)
            assert type(err.value).__name__ == expected, (path, value)
            if path != "Plant.T1.Level":
                assert await n[path].read_value() == before
        assert await n["Plant.T1.Leak"].read_value() == 0.25
        # A write carrying a Bad status code is refused with BadWriteNotSupported.
        dv = ua.DataValue(
            ua.Variant(0.5, ua.VariantType.Double), StatusCode=ua.StatusCode(ua.StatusCodes.BadSensorFailure)
        )
        with pytest.raises(ua.UaStatusCodeError) as err:
            await n["Plant.T1.Leak"].write_attribute(ua.AttributeIds.Value, dv)
        assert type(err.value).__name__ == "BadWriteNotSupported"
        assert await n["Plant.T1.Leak"].read_value() == 0.25


async def test_analog_nodes_carry_eurange_and_units(plant_url: str) -> None:
    async with await secure(plant_url, "observer") as client:
        node = (await resolve(client, ["Plant.T1.Level"]))["Plant.T1.Level"]
        props = {(await c.read_browse_name()).Name: await c.read_value() for c in await node.get_properties()}
        assert props["EURange"].Low == 0.0 and props["EURange"].High == pytest.approx(0.62)
        assert props["EngineeringUnits"].DisplayName.Text == "m"
        fault = (await resolve(client, ["Plant.LT1.Fault"]))["Plant.LT1.Fault"]
        names = {
            (await c.read_browse_name()).Name: await c.read_value() for c in await fault.get_properties()
        }
        assert [t.Text for t in names["EnumStrings"]] == ["NONE", "BIAS", "STUCK", "DRIFT"]


async def test_tankctl_plant_prints_its_endpoint_and_stops_on_sigterm(tmp_path: Path) -> None:
    port = free_port()
    env = dict(os.environ, TANKLAB_SPEED="5")
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "tankctl",
        "plant",
        "--config",
        str(ROOT / "configs/three_tank_energies_sim.yaml"),
        "--port",
        str(port),
        "--state-file",
        str(tmp_path / "plant.json"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        cwd=ROOT,
    )
    try:
        assert proc.stdout is not None
        line = await asyncio.wait_for(proc.stdout.readline(), 30)
        assert f"opc.tcp://127.0.0.1:{port}/tanklab/plant" in line.decode()
        async with await secure(f"opc.tcp://127.0.0.1:{port}/tanklab/plant", "operator") as client:
            leak = (await resolve(client, ["Plant.T1.Leak"]))["Plant.T1.Leak"]
            await leak.write_value(ua.Variant(0.4, ua.VariantType.Double))
        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), 20) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    # The checkpoint written on SIGTERM carries the leak opening: a restart resumes from it.
    import json

    snap = json.loads((tmp_path / "plant.json").read_text())
    assert snap["leak_openings"][0] == 0.4


async def test_a_warm_restart_holds_the_pumps_before_the_plc_serves(plant_url: str) -> None:
    """The PLC's warm restart writes the plant's own commands back before its server starts
    (``warm_resume(hold_outputs=True)``): flows unchanged, the plant's command watchdog reset.
    Lock-step (``hold_outputs=False``) leaves the plant alone."""
    q = 2.0e-5
    async with await secure(plant_url, tier="plc") as client:
        n = await resolve(client, ["Plant.P1.Command", "Plant.Sim.Watchdog"])
        await n["Plant.P1.Command"].write_value(ua.Variant(q, ua.VariantType.Double))

        async def tripped() -> bool:
            return bool(await n["Plant.Sim.Watchdog"].read_value())

        # No PLC writes any more: the plant's watchdog puts the pumps in their safe state.
        await wait_until(tripped, 60, what="the plant's command watchdog")
        program = PlcProgram(SITE, watchdog_timeout_s=SITE.plc.watchdog.timeout_s)
        field = FieldLink(SITE, plant_url, setup=client_setup(identity(tier="plc")))
        try:
            await warm_resume(program, field, hold_outputs=False)
            assert await tripped()
            await warm_resume(program, field, hold_outputs=True)

            async def reset() -> bool:  # the plant publishes the flag at its next step
                return not await tripped()

            await wait_until(reset, 20, what="the plant's watchdog reset by the held commands")
            assert await n["Plant.P1.Command"].read_value() == q
            # The loop on P1 resumed from the plant's command: its MV is that command.
            lic1 = next(lp for lp in program.loops if lp.pump == 0)
            assert lic1.mv == q
        finally:
            await field.link.close()
