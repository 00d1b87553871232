"""Plant, PLC and supervisor as real processes (speed 20): adaptation pushes, MPC mode tracks.

Assertions are on the PLC's model time and on published values; waits go through wait_until.

The waits are bounded in the PLC's model time (what 60 s of wall time is at speed 20, 1200 s):
on a busy machine the tiers overrun and skip scans, so a wall-time bound judged the machine's
speed, not the loops (issue #21). Their wall bound, 600 s, only catches a hang.
"""

from __future__ import annotations

import pytest
from asyncua import ua

from helpers import ROOT, TierProcess, free_port, secure, wait_until
from tanklab.enums import GainSource, LoopMode, SupervisorMode
from tanklab_io.ua_client import resolve

CONFIG = str(ROOT / "configs/three_tank_energies_sim.yaml")
SPEED = "20"
pytestmark = pytest.mark.process

HANG_S = 600.0
"""Wall bound of every wait: a hang, not a speed check [s]."""


async def until_model(condition, model_s: float, clock, what: str) -> None:
    """Wait until ``condition()`` holds, failing once the PLC's model time (``clock``, the
    ``PLC.Status.ModelTime`` node) has advanced ``model_s`` [model s] without it."""
    t0 = float(await clock.read_value())
    late = []

    async def done() -> bool:
        if await condition():
            return True
        if float(await clock.read_value()) - t0 > model_s:
            late.append(True)
            return True
        return False

    await wait_until(done, HANG_S, what=what)
    assert not late, f"not within {model_s:g} s of model time: {what}"


@pytest.fixture
async def stack():
    pp, cp, sp = free_port(), free_port(), free_port()
    plant_url = f"opc.tcp://127.0.0.1:{pp}/tanklab/plant"
    plc_url = f"opc.tcp://127.0.0.1:{cp}/tanklab/plc"
    procs = [
        await TierProcess("plant", "--config", CONFIG, "--port", str(pp), "--speed", SPEED).start(),
        await TierProcess(
            "plc", "--config", CONFIG, "--port", str(cp), "--plant-url", plant_url, "--speed", SPEED
        ).start(),
        await TierProcess(
            "supervisor", "--config", CONFIG, "--port", str(sp), "--plc-url", plc_url, "--speed", SPEED
        ).start(),
    ]
    yield plc_url, f"opc.tcp://127.0.0.1:{sp}/tanklab/supervisor"
    for p in reversed(procs):
        await p.stop()


async def test_adaptive_pid_pushes_gains_the_plc_accepts(stack) -> None:
    plc_url, sup_url = stack
    async with await secure(sup_url) as sup, await secure(plc_url) as plc:
        s = await resolve(sup, ["Supervisor.Mode", "Supervisor.RLS.LIC1.Accepted", "Supervisor.PlcConnected"])
        gains = [f"PLC.LIC{j}.{g}" for j in (1, 2) for g in ("Kp", "Ki", "Kd")]
        p = await resolve(
            plc, ["PLC.LIC1.GainSource", "PLC.Supervisor.Alive", "PLC.Status.ModelTime", *gains]
        )
        clock = p["PLC.Status.ModelTime"]
        await until_model(
            lambda: _is(p["PLC.Supervisor.Alive"], True), 600, clock, "PLC sees the supervisor alive"
        )
        await s["Supervisor.Mode"].write_value(
            ua.Variant(int(SupervisorMode.ADAPTIVE_PID), ua.VariantType.Int32)
        )

        async def pushed() -> bool:
            return await p["PLC.LIC1.GainSource"].read_value() == int(GainSource.SUPERVISOR)

        await until_model(pushed, 1200, clock, "supervisor gains applied in the PLC")
        assert await s["Supervisor.RLS.LIC1.Accepted"].read_value() >= 1
        fixed = [4.29e-4, 5.32e-6, -1.42e-4, 10.83e-4, 3.94e-5, -13.51e-4]
        applied = [await p[g].read_value() for g in gains]
        assert applied != pytest.approx(fixed, rel=1e-6), "the pushed set must differ from the fixed gains"
        assert await s["Supervisor.Mode"].read_value() == int(SupervisorMode.ADAPTIVE_PID)


async def test_mpc_mode_puts_loops_in_remote_and_tracks_a_step(stack) -> None:
    plc_url, sup_url = stack
    async with await secure(sup_url) as sup, await secure(plc_url) as plc:
        s = await resolve(sup, ["Supervisor.Mode"])
        p = await resolve(
            plc,
            [
                "PLC.LIC1.Mode",
                "PLC.LIC2.Mode",
                "PLC.LIC1.SP",
                "PLC.LIC1.PV",
                "PLC.Supervisor.Alive",
                "PLC.Status.ModelTime",
            ],
        )
        clock = p["PLC.Status.ModelTime"]
        await until_model(
            lambda: _is(p["PLC.Supervisor.Alive"], True), 600, clock, "PLC sees the supervisor alive"
        )

        async def near(sp: float) -> bool:
            return abs(await p["PLC.LIC1.PV"].read_value() - sp) < 0.01

        await until_model(lambda: near(0.4), 1200, clock, "T1 filled to 0.4 m by the PIDs")
        await s["Supervisor.Mode"].write_value(ua.Variant(int(SupervisorMode.MPC), ua.VariantType.Int32))

        async def remote() -> bool:
            modes = [await p["PLC.LIC1.Mode"].read_value(), await p["PLC.LIC2.Mode"].read_value()]
            return modes == [int(LoopMode.REMOTE)] * 2

        await until_model(remote, 400, clock, "loops in REMOTE")
        t0 = await p["PLC.Status.ModelTime"].read_value()
        await p["PLC.LIC1.SP"].write_value(ua.Variant(0.45, ua.VariantType.Double))
        await until_model(lambda: near(0.45), 600, clock, "T1 tracks 0.45 m under the MPC")
        assert await p["PLC.Status.ModelTime"].read_value() - t0 < 600
        assert await p["PLC.LIC1.Mode"].read_value() == int(LoopMode.REMOTE)
        # Leaving MPC mode puts the loops back in AUTO.
        await s["Supervisor.Mode"].write_value(ua.Variant(int(SupervisorMode.ADVISORY), ua.VariantType.Int32))

        async def auto() -> bool:
            return await p["PLC.LIC1.Mode"].read_value() == int(LoopMode.AUTO)

        await until_model(auto, 400, clock, "loops back in AUTO")


async def _is(node, value) -> bool:
    return await node.read_value() == value
