"""`tankctl up`'s lifecycle through real processes: preflight, stop at any moment, pid files,
what a stop saved, ``--fresh`` and the line mode of piped output (issue #21, decision 0018).

Every ``up`` runs as a subprocess in its own session with its output piped (so it is in line
mode); assertions are on its exit code, its lines, the run directory's files and the absence of
its processes (read from /proc). Waits are bounded (``wait_until``); the product's own stop
bound is 10 s, the tests allow 30 s and print the time they saw, as information only.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import ROOT, UpProcess, free_base_port, secure, tanklab_pids, wait_until
from tankctl.up import last_error_line, running_pid
from tanklab.enums import SupervisorMode
from tanklab_io.ua_client import resolve

CONFIG = ROOT / "configs/three_tank_energies_sim.yaml"
SITE = "three_tank_energies_sim"
pytestmark = pytest.mark.process


def gone_pid() -> int:
    """The pid of a process that has exited (a stale pid file's content)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


async def assert_nothing_left(up: UpProcess) -> None:
    await wait_until(lambda: not tanklab_pids(up.base), 10, what="no tankctl process of the run")
    assert up.pid_files() == []


@pytest.mark.parametrize("moment", ["launch", "plant spawned", "plant up", "all up", "all up, SIGINT"])
async def test_sigterm_at_any_moment_stops_every_tier_and_leaves_no_pid_file(
    tmp_path: Path, moment: str
) -> None:
    up = UpProcess(free_base_port(), tmp_path / "var", "--no-board", "--speed", "5")
    try:
        await up.launch()
        if moment == "plant spawned":
            await wait_until((up.run_dir / "plant.pid").exists, 120, what="plant.pid")
        elif moment == "plant up":
            await up.wait_line("plant      opc.tcp://")
        elif moment.startswith("all up"):
            await up.wait_line("started: ")
        sig = signal.SIGINT if moment.endswith("SIGINT") else signal.SIGTERM
        code, seconds = await up.terminate(sig=sig)
        print(f"\n{sig.name} at {moment!r}: up exited {code} after {seconds:.2f} s; lines {up.lines}")
        # Right after launch the signal may come before Python has started at all: the default
        # action then ends `up` before it started anything (exit -15).
        assert code == 0 or (moment == "launch" and code == -signal.SIGTERM), up.lines
        if code == 0:
            assert up.lines[-1].startswith("stopped in "), up.lines
            assert any(line.startswith(f"stopping ({sig.name}") for line in up.lines), up.lines
        await assert_nothing_left(up)
        assert not (up.run_dir / "up.pid").exists()
    finally:
        await up.cleanup()


async def test_second_up_refuses_busy_ports_and_a_running_run_dir_and_the_first_keeps_running(
    tmp_path: Path,
) -> None:
    base = free_base_port()
    first = await UpProcess(base, tmp_path / "a", "--no-board", "--speed", "5").started()
    try:
        pids = {p.name: p.read_text() for p in first.pid_files()}
        stamps = {p.name: p.stat().st_mtime_ns for p in first.pid_files()}
        assert set(pids) == {"up.pid", "plant.pid", "plc.pid", "supervisor.pid", "historian.pid"}

        def up(*args: str) -> subprocess.CompletedProcess[str]:
            cmd = [
                sys.executable,
                "-m",
                "tankctl",
                "up",
                "--config",
                str(CONFIG),
                "--no-board",
                "--no-hmi",
                *args,
            ]
            return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=60, check=False)

        # The same ports, another run directory: one line naming the port and the tier.
        r = up("--base-port", str(base), "--log-dir", str(tmp_path / "b"))
        assert r.returncode == 2, r.stdout + r.stderr
        assert r.stdout == ""
        assert r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith(f"tankctl: port {base} (plant) on 127.0.0.1 is already in use"), r.stderr
        assert not (tmp_path / "b" / SITE).exists()
        # Other ports, the same run directory: refused, naming the running stack's pid file.
        other = free_base_port()
        while other <= base + 2 < other + 3 or base <= other + 2 < base + 3:
            other += 7
        r = up("--base-port", str(other), "--log-dir", str(tmp_path / "a"))
        assert r.returncode == 2, r.stdout + r.stderr
        assert r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith(f"tankctl: {first.run_dir / 'up.pid'}: pid "), r.stderr
        assert not tanklab_pids(other)
        # The first stack is untouched: its pid files, its processes.
        assert {p.name: p.read_text() for p in first.pid_files()} == pids
        assert {p.name: p.stat().st_mtime_ns for p in first.pid_files()} == stamps
        assert first.proc is not None and first.proc.returncode is None
        for text in pids.values():
            os.kill(int(text), 0)
        code, seconds = await first.terminate()
        print(f"\nstop of a running stack: {seconds:.2f} s")
        assert code == 0, first.lines
        await assert_nothing_left(first)
    finally:
        await first.cleanup()


async def test_stop_says_what_it_saved_and_fresh_discards_it(tmp_path: Path) -> None:
    """Piped output without --no-board gives the line mode; stale pid files are replaced."""
    base = free_base_port()
    run_dir = tmp_path / "var" / SITE
    run_dir.mkdir(parents=True)
    for name in ("up.pid", "plant.pid"):
        (run_dir / name).write_text(f"{gone_pid()}\n")
    up = UpProcess(base, tmp_path / "var", "--speed", "5")
    try:
        await up.started()
        ops = [sys.executable, "-m", "tankctl"]
        for args in (["leak", "T1", "0.3"], ["setpoint", "LIC1", "0.45"], ["mode", "off"]):
            r = subprocess.run(
                [*ops, *args, "--base-port", str(base)],
                capture_output=True,
                text=True,
                cwd=ROOT,
                timeout=60,
                check=False,
            )
            assert r.returncode == 0, r.stderr
        assert (await up.terminate())[0] == 0, up.lines
        state, retain = run_dir / "plant-state.json", run_dir / "plc-retain.json"
        assert f"saved: plant state (levels, valves, leaks, faults, volumes) to {state}" in up.lines
        assert any(
            line.startswith("saved: PLC retentive memory") and str(retain) in line for line in up.lines
        )
        mode = run_dir / "supervisor-retain.json"
        assert f"saved: supervisor mode in {mode}" in up.lines
        assert json.loads(state.read_text())["leak_openings"][0] == pytest.approx(0.3)
        assert "0.45" in retain.read_text()
        assert json.loads(mode.read_text())["mode"] == "OFF"
        await assert_nothing_left(up)
    finally:
        await up.cleanup()
    # The line mode: one line per event, in this order.
    kinds = ["plant ", "plc ", "supervisor ", "started: ", "stopping (SIGTERM)", *["saved: "] * 3]
    events = [
        next(k for k in kinds if line.startswith(k)) for line in up.lines if line.startswith(tuple(kinds))
    ]
    assert events == kinds, up.lines
    assert up.lines[-1].startswith("stopped in "), up.lines

    # A restart without --fresh: the supervisor goes back to the engineer's mode (the config's is
    # ADVISORY) at its first cycle.
    again = UpProcess(base, tmp_path / "var", "--no-board", "--speed", "5")
    try:
        await again.started()
        async with await secure(f"opc.tcp://127.0.0.1:{base + 2}/tanklab/supervisor") as client:
            node = (await resolve(client, ["Supervisor.Mode"]))["Supervisor.Mode"]

            async def off() -> bool:
                return await node.read_value() == int(SupervisorMode.OFF)

            await wait_until(off, 60, what="the restarted supervisor back in OFF")
        assert (await again.terminate())[0] == 0, again.lines
        await assert_nothing_left(again)
    finally:
        await again.cleanup()

    fresh = UpProcess(base, tmp_path / "var", "--no-board", "--speed", "5", "--fresh")
    try:
        await fresh.started()
        assert fresh.lines[0] == (
            "fresh start from the config's initial state: discarded the saved plant state "
            f"{state}, PLC retentive memory {retain} and supervisor mode {mode}"
        ), fresh.lines
        plant = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"
        plc = f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc"
        async with await secure(plant) as client:
            assert await (await resolve(client, ["Plant.T1.Leak"]))["Plant.T1.Leak"].read_value() == 0
        async with await secure(plc) as client:
            sp = await (await resolve(client, ["PLC.LIC1.SP"]))["PLC.LIC1.SP"].read_value()
            assert sp == pytest.approx(0.4)
        async with await secure(f"opc.tcp://127.0.0.1:{base + 2}/tanklab/supervisor") as client:
            node = (await resolve(client, ["Supervisor.Mode"]))["Supervisor.Mode"]

            async def advisory() -> bool:
                return await node.read_value() == int(SupervisorMode.ADVISORY)

            await wait_until(advisory, 60, what="the fresh supervisor in the config's ADVISORY")
        assert (await fresh.terminate())[0] == 0, fresh.lines
        assert json.loads(state.read_text())["leak_openings"][0] == 0
        await assert_nothing_left(fresh)
    finally:
        await fresh.cleanup()


async def test_a_tier_dying_during_start_up_is_reported_with_the_reason_from_its_log(tmp_path: Path) -> None:
    """The PLC's port is taken after the preflight (once the plant is up): the PLC cannot bind."""
    base = free_base_port()
    up = UpProcess(base, tmp_path / "var", "--no-board", "--speed", "5")
    blocker = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        await up.launch()
        await wait_until((up.run_dir / "plant.pid").exists, 120, what="plant.pid")
        blocker.bind(("127.0.0.1", base + 1))
        blocker.listen()
        assert up.proc is not None
        code = await asyncio.wait_for(up.proc.wait(), 120)
        await asyncio.wait_for(up._reader or asyncio.sleep(0), 10)
        assert code == 1, up.lines
        died = [
            line for line in up.lines if line.startswith("tankctl: plc exited during start-up (exit 2): ")
        ]
        assert len(died) == 1, up.lines
        assert "address already in use" in died[0].lower(), died
        assert up.lines[-1].startswith("stopped in "), up.lines
        await assert_nothing_left(up)
    finally:
        blocker.close()
        await up.cleanup()


async def test_a_tier_dying_later_is_reported_and_the_stack_stopped(tmp_path: Path) -> None:
    up = UpProcess(free_base_port(), tmp_path / "var", "--no-board", "--speed", "5")
    try:
        await up.started()
        os.kill(int((up.run_dir / "plc.pid").read_text()), signal.SIGKILL)
        assert up.proc is not None
        code = await asyncio.wait_for(up.proc.wait(), 60)
        await asyncio.wait_for(up._reader or asyncio.sleep(0), 10)
        assert code == 1, up.lines
        assert any(line.startswith("plc died (exit -9): killed by SIGKILL; log ") for line in up.lines), (
            up.lines
        )
        assert "stopping (plc died)" in up.lines
        assert up.lines[-1].startswith("stopped in "), up.lines
        await assert_nothing_left(up)
    finally:
        await up.cleanup()


def run_up(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "tankctl", "up", "--no-board", "--no-hmi", *args]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=60, check=False, env=env)


def test_preflight_refuses_a_broken_config_and_a_home_without_login(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(CONFIG.read_text().replace("scan_period_s:", "scan_period_sec:", 1))
    base = free_base_port()
    r = run_up("--config", str(bad), "--base-port", str(base), "--log-dir", str(tmp_path / "var"))
    assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(f"tankctl: {bad}"), r.stderr
    # A security home with its PKI and users but no credentials file: the board could not log in.
    home = tmp_path / "home"
    shutil.copytree(os.environ["TANKLAB_HOME"], home)
    (home / "credentials").unlink()
    env = {k: v for k, v in os.environ.items() if k not in ("TANKLAB_USER", "TANKLAB_PASSWORD")}
    env["TANKLAB_HOME"] = str(home)
    r = run_up("--config", str(CONFIG), "--base-port", str(base), "--log-dir", str(tmp_path / "var"), env=env)
    assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
    assert r.stderr == f"tankctl: no login for the board: {home / 'credentials'} is missing and " + (
        "TANKLAB_USER/TANKLAB_PASSWORD are not set\n"
    )
    assert not (tmp_path / "var").exists()
    assert not tanklab_pids(base)


def test_a_pid_file_is_running_only_for_a_live_tankctl_process(tmp_path: Path) -> None:
    path = tmp_path / "plant.pid"
    assert running_pid(path) is None  # no file
    path.write_text("garbage\n")
    assert running_pid(path) is None
    path.write_text(f"{gone_pid()}\n")
    assert running_pid(path) is None  # the pid is gone
    other = subprocess.Popen(["sleep", "30"])
    try:
        path.write_text(f"{other.pid}\n")
        assert running_pid(path) is None  # alive, but not tanklab's: a reused pid
    finally:
        other.kill()
        other.wait()


def test_the_reason_of_a_death_is_the_tiers_own_line_else_the_last_error() -> None:
    log = "20:00 INFO plc: serving\ntankctl: plc: cannot serve: address already in use\n"
    assert last_error_line(log) == "tankctl: plc: cannot serve: address already in use"
    log = "INFO a\nTraceback (most recent call last):\n  File x\nValueError: bad\nINFO shutting down\n"
    assert last_error_line(log) == "ValueError: bad"
    assert last_error_line("INFO a\nINFO b\n") == "INFO b"
    assert last_error_line("") == "nothing in its log"
    assert last_error_line("ERROR " + "x" * 500).endswith("...")


async def test_a_tier_that_ignores_sigterm_is_killed_and_up_says_so(tmp_path: Path) -> None:
    """A stopped (SIGSTOP) plant cannot act on SIGTERM: at the grace period its group gets
    SIGKILL, and the plant's state is reported as not saved at stop."""
    up = UpProcess(free_base_port(), tmp_path / "var", "--no-board", "--speed", "5")
    try:
        await up.started()
        os.kill(int((up.run_dir / "plant.pid").read_text()), signal.SIGSTOP)
        code, seconds = await up.terminate()
        print(f"\nstop with a frozen plant: {seconds:.2f} s; {up.lines[-1]}")
        assert code == 0, up.lines
        assert up.lines[-1].startswith("stopped in ") and up.lines[-1].endswith("; killed after 8 s: plant")
        # "not saved at stop: plant state (plant killed); its last checkpoint is in ...", or
        # "not saved: plant state (no state file ...)" when it was frozen before its first one.
        assert any(line.startswith("not saved") and "plant state" in line for line in up.lines), up.lines
        assert not any(line.startswith("saved: plant state") for line in up.lines), up.lines
        await assert_nothing_left(up)
    finally:
        await up.cleanup()
