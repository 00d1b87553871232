"""``tankctl up`` starts the HMI after the historian, prints its URL, preflights its port and stops it."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from helpers import ROOT, TEST_PASSWORDS, UpProcess, free_base_port, free_port

pytestmark = pytest.mark.process


async def test_up_serves_the_hmi_and_stops_it(tmp_path: Path) -> None:
    base, port = free_base_port(), free_port()
    up = UpProcess(base, tmp_path / "var", "--no-board", "--speed", "5", "--hmi-port", str(port))
    try:
        await up.started()
        lines = [line.split() for line in up.lines]
        assert ["hmi", f"http://127.0.0.1:{port}", "(log"] == lines[[w[:1] for w in lines].index(["hmi"])][:3]
        names = [w[0] for w in lines if w and w[0] in ("plant", "plc", "supervisor", "historian", "hmi")]
        assert names[-1] == "hmi" and names.index("historian") < names.index("hmi")
        assert (up.run_dir / "hmi.pid").exists()
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=15.0) as b:
            health = (await b.get("/healthz")).json()
            assert health == {
                "ok": True,
                "tiers": dict.fromkeys(("plant", "plc", "supervisor", "historian"), True),
            }
            r = await b.post("/api/login", json={"user": "operator", "password": TEST_PASSWORDS["operator"]})
            assert r.status_code == 200
        hmi_pid = up.pid("hmi")
        assert await up.stop() == 0
        assert not (up.run_dir / "hmi.pid").exists()
        with pytest.raises(ProcessLookupError):
            os.kill(hmi_pid, 0)
    finally:
        await up.cleanup()


def run_up(base: int, hmi_port: int, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    args = ["up", "--no-board", "--base-port", str(base), "--hmi-port", str(hmi_port)]
    return subprocess.run(
        [sys.executable, "-m", "tankctl", *args, "--log-dir", str(tmp_path / "var")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
        check=False,
    )


def test_up_preflight_refuses_a_taken_hmi_port(tmp_path: Path) -> None:
    base = free_base_port()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = run_up(base, port, tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.startswith(f"tankctl: port {port} (hmi) on 127.0.0.1 is already in use"), r.stderr
    assert r.stderr.count("\n") == 1
    bad = run_up(base, base + 1, tmp_path)
    assert bad.returncode == 2 and "is one of the tiers' ports" in bad.stderr, bad.stderr
    assert not (tmp_path / "var").exists()  # nothing started, nothing written


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["--port", "0"], "tankctl: --port must be 1..65535, got 0"),
        (["--poll-interval", "5"], "tankctl: --poll-interval must be 0.05 .. 0.5 s, got 5.0"),
        (["--idle-timeout", "0"], "tankctl: --idle-timeout must be > 0, got 0.0"),
        (["--plc-url", "http://x"], "tankctl: --plc-url: "),
    ],
)
def test_hmi_bad_options_are_one_line_and_exit_2(args: list[str], line: str) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "tankctl", "hmi", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
        check=False,
    )
    assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
    assert r.stderr.startswith(line) and r.stderr.count("\n") == 1, r.stderr
