"""Operator commands through ``tankctl up``'s command relay (decision 0048), real processes only.

One ``up`` (line mode, its own runtime directory for the relay's links) serves every check in
order: a setpoint through the relay reaches the PLC and is audited under the user's name, without
asyncua imported in the command; a wrong password is one line and exit 2; an out-of-range
setpoint is the direct path's Bad code with the old value kept; the relay survives a PLC restart;
the socket and its links are gone after ``up`` stopped.
"""

from __future__ import annotations

import asyncio
import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import ROOT, TEST_PASSWORDS, UpProcess, free_base_port, secure, session_home, wait_until
from tankctl.relay_client import pointer
from tanklab import paths
from tanklab_io.audit import read_audit
from tanklab_io.ua_client import resolve

pytestmark = pytest.mark.process


async def command(
    base: int, env: dict[str, str], *args: str, importtime: bool = False
) -> subprocess.CompletedProcess[str]:
    """``python [-X importtime] -m tankctl ARGS --base-port BASE`` in a thread (bounded hang only)."""
    flags = ["-X", "importtime"] if importtime else []
    return await asyncio.to_thread(
        subprocess.run,
        [sys.executable, *flags, "-m", "tankctl", *args, "--base-port", str(base)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
        check=False,
        env=env,
    )


def imported(stderr: str) -> set[str]:
    """Top-level packages named in ``-X importtime`` lines."""
    out = set()
    for line in stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            out.add(line.rsplit("|", 1)[1].strip().split(".")[0])
    return out


async def plc_sp(url: str) -> float:
    async with await secure(url, "engineer") as client:
        (node,) = (await resolve(client, [paths.plc.loop("LIC1").sp])).values()
        return float(await node.read_value())


async def test_relay_serves_setpoint_status_and_refusals_and_survives_a_plc_restart(tmp_path: Path) -> None:
    runtime = tmp_path / "rt"
    runtime.mkdir(mode=0o700)
    env = {**os.environ, "XDG_RUNTIME_DIR": str(runtime)}
    env.pop("TANKLAB_USER", None)
    env.pop("TANKLAB_PASSWORD", None)
    config = tmp_path / "site.yaml"  # the Energies site, its tiers restarted when they die
    config.write_text(
        (ROOT / "configs/three_tank_energies_sim.yaml").read_text() + "\nstack:\n  restart: true\n"
    )
    base = free_base_port()
    up = await UpProcess(
        base, tmp_path / "var", "--no-board", "--speed", "5", config=config, env=env
    ).started()
    try:
        await up.wait_line("command relay: ")
        sock = up.run_dir / "relay" / "relay.sock"
        assert stat.S_IMODE(sock.stat().st_mode) == 0o600
        assert stat.S_IMODE(sock.parent.stat().st_mode) == 0o700
        plc_url = f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc"
        link = pointer(plc_url, env)
        assert link is not None and link.is_symlink() and Path(os.readlink(link)) == sock

        # A setpoint as the operator: through the relay, seen by the PLC, audited as "operator".
        op_env = {**env, "TANKLAB_USER": "operator", "TANKLAB_PASSWORD": TEST_PASSWORDS["operator"]}
        audit = session_home().audit_dir / "plc.log"
        mark = len(read_audit(audit))
        r = await command(base, op_env, "setpoint", "LIC1", "0.42", importtime=True)
        assert r.returncode == 0, r.stdout + r.stderr
        assert r.stdout.startswith("PLC.LIC1.SP = 0.42 m (was "), r.stdout
        loaded = imported(r.stderr)
        assert "tankctl" in loaded and "asyncua" not in loaded and "cryptography" not in loaded, sorted(
            loaded
        )
        assert await plc_sp(plc_url) == pytest.approx(0.42)
        writes = [x for x in read_audit(audit)[mark:] if x.get("node") == "PLC.LIC1.SP"]
        assert [(x["action"], x["user"]) for x in writes] == [("write", "operator")], writes

        # The status through the relay, no asyncua either.
        r = await command(base, env, "status", "--json", importtime=True)
        assert r.returncode == 0, r.stderr[-2000:]
        assert "asyncua" not in imported(r.stderr)
        assert '"reachable": true' in r.stdout

        # A plant write (leak) goes the same way.
        r = await command(base, op_env, "leak", "T1", "off", importtime=True)
        assert r.returncode == 0 and r.stdout.startswith("Plant.T1.Leak = 0"), r.stdout + r.stderr[-2000:]
        assert "asyncua" not in imported(r.stderr)

        # A wrong password: the tier refuses, one line, exit 2 (and nothing is cached).
        bad_env = {**env, "TANKLAB_USER": "operator", "TANKLAB_PASSWORD": "not-the-password"}
        r = await command(base, bad_env, "setpoint", "LIC1", "0.3")
        assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
        assert r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith("tankctl: login as 'operator' refused: wrong user name or password"), (
            r.stderr
        )
        assert await plc_sp(plc_url) == pytest.approx(0.42)

        # Out of range: the direct path's Bad code, the old value kept.
        # The same command on the direct path (a runtime directory without relay links) says the same.
        r = await command(base, op_env, "setpoint", "LIC1", "99")
        assert r.returncode == 1, r.stdout + r.stderr
        assert r.stderr == "tankctl: PLC.LIC1.SP = 99 refused: BadOutOfRange\n", r.stderr
        assert await plc_sp(plc_url) == pytest.approx(0.42)
        (tmp_path / "no-relay").mkdir(mode=0o700)
        direct = await command(
            base, {**op_env, "XDG_RUNTIME_DIR": str(tmp_path / "no-relay")}, "setpoint", "LIC1", "99"
        )
        assert (direct.returncode, direct.stdout, direct.stderr) == (r.returncode, r.stdout, r.stderr)
        # A stale link (a relay that does not answer): the command connects directly.
        stale = tmp_path / "stale"
        stale.mkdir(mode=0o700)
        stale_link = pointer(plc_url, {"XDG_RUNTIME_DIR": str(stale)})
        assert stale_link is not None
        stale_link.parent.mkdir(mode=0o700)
        stale_link.symlink_to(tmp_path / "no-such.sock")
        r = await command(base, {**op_env, "XDG_RUNTIME_DIR": str(stale)}, "setpoint", "LIC1", "0.42")
        assert r.returncode == 0 and r.stdout.startswith("PLC.LIC1.SP = 0.42 m (was 0.42 m)"), (
            r.stdout + r.stderr
        )

        # The PLC restarts (up restarts it); the relay opens its session again.
        old_pid = up.pid("plc")
        os.kill(old_pid, signal.SIGKILL)
        await up.wait_line("plc restarted")
        done: list[subprocess.CompletedProcess[str]] = []

        async def written() -> bool:  # the restarted PLC may take a moment to serve
            done.append(await command(base, op_env, "setpoint", "LIC1", "0.4"))
            return done[-1].returncode == 0

        await wait_until(written, 60, what="a setpoint through the relay after the PLC restart", poll_s=0.5)
        assert await plc_sp(plc_url) == pytest.approx(0.4)
        assert any("relay: plc session of 'operator' lost" in line for line in up.lines), up.lines

        code, _ = await up.terminate()
        assert code == 0, up.lines
        await wait_until(lambda: not sock.exists(), 10, what="relay socket removed")
        assert not link.is_symlink() and not link.exists()
    finally:
        await up.cleanup()
