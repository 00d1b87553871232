"""End to end through real processes: `tankctl up`, the operator CLI, failures and recovery.

Lock-step runs are as fast as the machine allows and deterministic; assertions are on model
time (``PLC.Status.ModelTime``, ``Plant.Sim.Time``) and published values. Waiting for processes
goes through ``wait_until`` only.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
from pathlib import Path

import pytest
import yaml
from asyncua import Client

from helpers import ROOT, TierProcess, UpProcess, free_base_port, secure, tankctl_at, wait_until
from tanklab.enums import GainSource, LoopMode
from tanklab_io.ua_client import resolve

CONFIG = ROOT / "configs/three_tank_energies_sim.yaml"
pytestmark = pytest.mark.process


async def tankctl(
    *args: str, base: int, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """An operator command against the stack at ``base`` (:func:`helpers.tankctl_at`)."""
    return await tankctl_at(base, *args, env=env)


async def value(client: Client, path: str):
    return await (await resolve(client, [path]))[path].read_value()


async def model_time(client: Client) -> float:
    return await value(client, "PLC.Status.ModelTime")


@pytest.fixture
async def lockstep_stack(tmp_path: Path):
    base = free_base_port()
    up = await UpProcess(base, tmp_path / "var", "--no-board", "--clock", "lockstep", config=CONFIG).start()
    async with await secure(f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc") as plc:
        yield base, plc, up
    assert await up.stop() == 0


async def test_cli_setpoint_leak_and_mode_through_the_lockstep_stack(lockstep_stack) -> None:
    base, plc, _ = lockstep_stack
    near = lambda sp, tol=0.01: _near(plc, "PLC.LIC1.PV", sp, tol)  # noqa: E731

    await wait_until(lambda: near(0.4), 120, what="T1 filled to its 0.4 m setpoint")
    # A setpoint changed with the CLI is reached.
    r = await tankctl("setpoint", "LIC1", "0.45", base=base)
    assert r.returncode == 0, r.stdout + r.stderr
    await wait_until(lambda: near(0.45), 120, what="T1 at the new 0.45 m setpoint")
    # A leak opened with the CLI is rejected by control: back within 1 cm of SP within 600 s.
    r = await tankctl("leak", "T1", "1.0", base=base)
    assert r.returncode == 0, r.stdout + r.stderr
    t_leak = await model_time(plc)

    async def dipped() -> bool:
        return await value(plc, "PLC.LIC1.PV") < 0.45 - 0.01 or await model_time(plc) - t_leak > 60

    await wait_until(dipped, 60, what="the leak to pull T1 down")
    await wait_until(lambda: near(0.45), 120, what="T1 back within 1 cm despite the leak")
    assert await model_time(plc) - t_leak < 600
    assert (await tankctl("leak", "T1", "off", base=base)).returncode == 0
    # `tankctl mode mpc` puts the loops in REMOTE, and the MPC tracks a setpoint step.
    r = await tankctl("mode", "mpc", base=base)
    assert r.returncode == 0, r.stdout + r.stderr

    async def remote() -> bool:
        return [await value(plc, f"PLC.LIC{j}.Mode") for j in (1, 2)] == [int(LoopMode.REMOTE)] * 2

    await wait_until(remote, 60, what="both loops in REMOTE")
    assert (await tankctl("setpoint", "LIC1", "0.40", base=base)).returncode == 0
    await wait_until(lambda: near(0.40), 120, what="T1 tracks 0.40 m under the MPC")
    status = await tankctl("status", "--json", base=base)
    assert status.returncode == 0 and "Traceback" not in status.stdout + status.stderr


async def test_first_run_provisions_a_secured_stack_and_the_tour_works(tmp_path: Path) -> None:
    """README: `make run` on a fresh machine, then the tour's commands in a second terminal.

    A fresh security home: `tankctl up` creates the PKI and the engineer account, and the
    operator commands log in from the credentials file it wrote."""
    home = tmp_path / "home"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TANKLAB_")}
    env["TANKLAB_HOME"] = str(home)
    base = free_base_port()
    up = await UpProcess(base, tmp_path / "var", "--no-board", "--speed", "5", config=CONFIG, env=env).start()
    try:
        assert any("first run: created the PKI" in line for line in up.lines), up.lines
        creds = home / "credentials"
        assert creds.stat().st_mode & 0o777 == 0o600
        assert "password=" not in "".join(up.lines)  # the password is never printed
        r = await tankctl("setpoint", "LIC1", "0.45", base=base, env=env)
        assert r.returncode == 0 and r.stdout.startswith("PLC.LIC1.SP = 0.45 m (was 0.4 m)"), r.stderr
        r = await tankctl("leak", "T1", "0.3", base=base, env=env)
        assert r.returncode == 0 and r.stdout.startswith("Plant.T1.Leak = 0.3 (was 0)"), r.stderr
        r = await tankctl("mode", "mpc", base=base, env=env)
        assert r.returncode == 0 and r.stdout.startswith("Supervisor.Mode = MPC"), r.stderr
        r = await tankctl("setpoint", "LIC1", "0.7", base=base, env=env)
        assert r.returncode == 1 and r.stderr.strip() == "tankctl: PLC.LIC1.SP = 0.7 refused: BadOutOfRange"
        r = await tankctl("gains", "LIC1", base=base, env=env)
        assert r.returncode == 0, r.stderr
    finally:
        assert await up.stop() == 0


async def _near(client: Client, path: str, sp: float, tol: float) -> bool:
    return abs(await value(client, path) - sp) < tol


async def test_up_exits_nonzero_when_a_tier_dies_and_stops_the_others(tmp_path: Path) -> None:
    base = free_base_port()
    up = await UpProcess(base, tmp_path / "var", "--no-board", config=CONFIG).start()
    pids = {t: up.pid(t) for t in ("plant", "plc", "supervisor")}
    os.kill(pids["plc"], signal.SIGKILL)
    assert up.proc is not None
    code = await asyncio.wait_for(up.proc.wait(), 60)
    assert code == 1

    def gone(pid: int) -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return False

    await wait_until(
        lambda: gone(pids["plant"]) and gone(pids["supervisor"]), 30, what="the other tiers stopped"
    )


async def test_plant_killed_and_restarted_by_up_everything_recovers(tmp_path: Path) -> None:
    data = yaml.safe_load(CONFIG.read_text())
    data["stack"] = {"restart": True, "max_restarts": 2}
    config = tmp_path / "restart.yaml"
    config.write_text(yaml.safe_dump(data))
    base = free_base_port()
    up = await UpProcess(base, tmp_path / "var", "--no-board", "--speed", "20", config=config).start()
    try:
        async with await secure(f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc") as plc:
            await wait_until(lambda: _near(plc, "PLC.LIC1.PV", 0.4, 0.02), 90, what="T1 near 0.4 m")
            plc_pid = up.pid("plc")
            os.kill(up.pid("plant"), signal.SIGKILL)

            async def io_lost() -> bool:
                return await value(plc, "PLC.Status.IoHealthy") is False

            await wait_until(io_lost, 30, what="the PLC to report the lost plant")

            async def recovered() -> bool:
                return await value(plc, "PLC.Status.IoHealthy") is True

            await wait_until(recovered, 60, what="the restarted plant reconnected")
            t_back = await model_time(plc)

            async def regulating() -> bool:
                return await model_time(plc) - t_back > 60 and await _near(plc, "PLC.LIC1.PV", 0.4, 0.02)

            await wait_until(regulating, 60, what="T1 regulated again")
            assert up.pid("plc") == plc_pid, "the PLC must not have been restarted"
            assert up.proc is not None and up.proc.returncode is None
    finally:
        assert await up.stop() == 0


async def test_supervisor_killed_plc_falls_back_and_holds_the_level(tmp_path: Path) -> None:
    """Lock-step tiers started one by one, so the test may kill the supervisor alone.

    Lock-step runs hundreds of scans per wall second once the supervisor is gone, so the
    fallback's model time is read from the PLC's per-scan trace, not by polling.
    """
    base = free_base_port()
    urls = [
        f"opc.tcp://127.0.0.1:{base + k}/tanklab/{t}" for k, t in enumerate(("plant", "plc", "supervisor"))
    ]
    common = ("--config", str(CONFIG), "--lockstep")
    trace = tmp_path / "plc.csv"
    plant = await TierProcess(
        "plant", *common, "--port", str(base), "--state-file", str(tmp_path / "s.json")
    ).start()
    plc_p = await TierProcess(
        "plc", *common, "--port", str(base + 1), "--plant-url", urls[0], "--trace", str(trace)
    ).start()
    sup = await TierProcess("supervisor", *common, "--port", str(base + 2), "--plc-url", urls[1]).start()
    try:
        async with await secure(urls[1]) as plc:
            await wait_until(lambda: _near(plc, "PLC.LIC1.PV", 0.4, 0.01), 120, what="T1 at 0.4 m")
            # Put the loops on supervisor gains, then kill the supervisor.
            assert (await tankctl("mode", "adaptive-pid", base=base)).returncode == 0

            async def on_supervisor_gains() -> bool:
                return await value(plc, "PLC.LIC1.GainSource") == int(GainSource.SUPERVISOR)

            await wait_until(on_supervisor_gains, 120, what="supervisor gains applied")
            await sup.kill()
            t_kill = await model_time(plc)  # no scan completes without the dead supervisor's ack

            async def long_after() -> bool:
                return await model_time(plc) - t_kill > 400

            await wait_until(long_after, 120, what="400 s of model time after the kill")
            assert await value(plc, "PLC.Supervisor.Alive") is False
    finally:
        for p in (sup, plc_p, plant):
            await p.stop()
    rows = [line.split(",") for line in trace.read_text().splitlines()]
    head, data = rows[0], [[float(x) for x in r] for r in rows[1:]]
    t, lt1, src = head.index("t_s"), head.index("LT1"), head.index("LIC1_GainSource")
    t_fb = next(r[t] for r in data if r[t] >= t_kill and r[src] == int(GainSource.FALLBACK))
    # Timeout 3 s of model time (lock-step has no wall floor) plus one 1 s scan.
    assert t_fb - t_kill <= 3.0 + 1.0
    after = [r[lt1] for r in data if t_fb <= r[t] <= t_fb + 300]
    assert len(after) >= 300
    assert max(abs(x - 0.4) for x in after) < 0.02


async def _run_lockstep_trace(tmp_path: Path, name: str, config: Path = CONFIG) -> list[str]:
    base = free_base_port()
    urls = [
        f"opc.tcp://127.0.0.1:{base + k}/tanklab/{t}" for k, t in enumerate(("plant", "plc", "supervisor"))
    ]
    common = ("--config", str(config), "--lockstep")
    trace = tmp_path / f"{name}.csv"
    procs = [
        await TierProcess("plant", *common, "--port", str(base)).start(),
        await TierProcess(
            "plc", *common, "--port", str(base + 1), "--plant-url", urls[0], "--trace", str(trace)
        ).start(),
        await TierProcess("supervisor", *common, "--port", str(base + 2), "--plc-url", urls[1]).start(),
    ]
    try:
        await wait_until(
            lambda: trace.exists() and len(trace.read_text().splitlines()) > 301,
            120,
            what="300 lock-step scans traced",
        )
    finally:
        for p in reversed(procs):
            await p.stop()
    return trace.read_text().splitlines()[:301]


async def test_two_lockstep_runs_give_identical_traces(tmp_path: Path) -> None:
    a = await _run_lockstep_trace(tmp_path, "a")
    b = await _run_lockstep_trace(tmp_path, "b")
    assert a[0].startswith("scan,t_s,LT1")
    assert a == b
    last = a[-1].split(",")
    assert float(last[1]) == pytest.approx(299.0)  # 300 scans of 1 s of model time


async def test_two_lockstep_runs_with_the_mpc_writing_every_scan_give_identical_traces(
    tmp_path: Path,
) -> None:
    """The supervisor's writes (RemoteMV and Mode with the heartbeat) reach the PLC while the
    plant integrates, at a wall time that varies from run to run: the trace must not show it."""
    data = yaml.safe_load(CONFIG.read_text())
    data["supervisor"]["mode"] = "MPC"
    config = tmp_path / "mpc.yaml"
    config.write_text(yaml.safe_dump(data))
    a = await _run_lockstep_trace(tmp_path, "a", config)
    b = await _run_lockstep_trace(tmp_path, "b", config)
    assert a == b
    head, rows = a[0].split(","), [r.split(",") for r in a[1:]]
    modes = {float(r[head.index("LIC1_Mode")]) for r in rows}
    assert float(LoopMode.REMOTE) in modes  # the MPC drove the pumps through RemoteMV


async def test_realtime_speed_20_smoke(tmp_path: Path) -> None:
    base = free_base_port()
    up = await UpProcess(base, tmp_path / "var", "--no-board", "--speed", "20", config=CONFIG).start()
    try:
        async with await secure(f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc") as plc:
            await wait_until(
                lambda: _near(plc, "PLC.LIC1.PV", 0.4, 0.02), 90, what="T1 near 0.4 m at speed 20"
            )
            assert (await tankctl("setpoint", "LIC1", "0.43", base=base)).returncode == 0
            await wait_until(lambda: _near(plc, "PLC.LIC1.PV", 0.43, 0.01), 90, what="T1 at 0.43 m")
            assert (await tankctl("mode", "mpc", base=base)).returncode == 0

            async def remote() -> bool:
                return await value(plc, "PLC.LIC1.Mode") == int(LoopMode.REMOTE)

            await wait_until(remote, 30, what="LIC1 in REMOTE at speed 20")
    finally:
        assert await up.stop() == 0
