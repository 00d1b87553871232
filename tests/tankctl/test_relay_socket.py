"""The command relay's socket, links and protocol checks, in process (decision 0048).

A real :class:`tankctl.relay.Relay` on a real Unix socket, spoken to by the real client side
(:func:`tankctl.relay_client.ask`); its tier endpoints are closed loopback ports, so every request
that gets as far as a tier is answered "unreachable". The stack-level behaviour (sessions, logins,
audit, restarts) is in tests/integration/test_relay.py.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import stat
import subprocess
import tempfile
from pathlib import Path

import pytest

from helpers import free_base_port, session_home
from tankctl.relay import Relay
from tankctl.relay_client import PROTOCOL, RelayUnavailableError, ask, pointer


@pytest.fixture
def runtime(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    d = tmp_path / "rt"
    d.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(d))
    return d


def read_request(plc_url: str) -> dict[str, object]:
    """An empty read of the PLC at ``plc_url`` as the engineer (with a password no tier checks:
    the tests' endpoints are closed ports)."""
    return {"user": "engineer", "password": "x", "tier": "plc", "url": plc_url, "op": "read", "paths": []}


def test_pointer_names_the_endpoint_in_the_runtime_directory(tmp_path: Path) -> None:
    env = {"XDG_RUNTIME_DIR": str(tmp_path)}
    assert (
        pointer("opc.tcp://127.0.0.1:4841/tanklab/plc", env) == tmp_path / "tanklab" / "relay-127.0.0.1-4841"
    )
    assert pointer("opc.tcp://nohost", env) is None
    assert pointer("opc.tcp://h:4840", {"XDG_RUNTIME_DIR": "relative"}) == Path(
        f"/tmp/tanklab-{os.getuid()}/relay-h-4840"
    )


async def test_ask_without_a_relay_is_unavailable(tmp_path: Path) -> None:
    with pytest.raises(RelayUnavailableError):
        await ask(tmp_path / "none.sock", {"op": "read"}, 2.0)


async def test_relay_socket_modes_protocol_checks_and_cleanup(tmp_path: Path, runtime: Path) -> None:
    base = free_base_port()
    urls = {
        "plant": f"opc.tcp://127.0.0.1:{base}/tanklab/plant",
        "plc": f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc",
    }
    said: list[str] = []
    relay = Relay(urls, session_home(), tmp_path / "run", said.append)
    await relay.start()
    try:
        assert stat.S_IMODE(relay.path.stat().st_mode) == 0o600
        assert stat.S_IMODE(relay.dir.stat().st_mode) == 0o700
        link = pointer(urls["plc"])
        assert link is not None and Path(os.readlink(link)) == relay.path
        assert stat.S_IMODE(link.parent.stat().st_mode) == 0o700

        req = read_request(urls["plc"])
        other = await ask(link, {**req, "url": "opc.tcp://127.0.0.1:1/tanklab/plc"}, 5.0)
        assert other["ok"] is False and other["error"] == "request", other
        unknown = await ask(link, {**req, "op": "delete"}, 5.0)
        assert unknown["error"] == "request" and "unknown operation" in unknown["reason"], unknown
        down = await ask(link, req, 10.0)
        assert down == {"v": PROTOCOL, "ok": False, "error": "unreachable", "reason": "connection refused"}
        assert relay.sessions == {}  # nothing kept of a session that never opened

        # Another protocol version: refused as a request (the client would connect directly).
        async with asyncio.timeout(5.0):
            reader, writer = await asyncio.open_unix_connection(str(link))
            writer.write(b'{"v": 99, "op": "read"}\n')
            answer = (await reader.readline()).decode()
            writer.close()
        assert '"error": "request"' in answer and "protocol 99" in answer
    finally:
        await relay.stop()
    assert not relay.path.exists()
    assert not os.path.lexists(link)
    await relay.stop()  # idempotent


SYSTEM_PYTHON = Path("/usr/bin/python3")
"""An interpreter another uid may run (the venv's lives under the worktree's owner)."""


@pytest.mark.skipif(
    os.getuid() != 0 or not SYSTEM_PYTHON.exists(),
    reason="needs root and /usr/bin/python3 to run a client as another uid",
)
async def test_relay_answers_no_other_uid_even_when_the_file_modes_would_let_it(runtime: Path) -> None:
    """The second lock: with the socket's modes opened up on purpose, a process of another uid
    (nobody, 65534) connects but gets no answer (SO_PEERCRED), while the owner does."""
    run_dir = Path(tempfile.mkdtemp(prefix="relay-peer-"))  # /tmp: traversable by nobody
    try:
        os.chmod(run_dir, 0o755)
        url = f"opc.tcp://127.0.0.1:{free_base_port()}/tanklab/plc"
        said: list[str] = []
        relay = Relay({"plc": url}, session_home(), run_dir, said.append)
        await relay.start()
        try:
            os.chmod(relay.dir, 0o755)
            os.chmod(relay.path, 0o666)
            client = (
                "import socket, sys\n"
                "s = socket.socket(socket.AF_UNIX); s.settimeout(10); s.connect(sys.argv[1])\n"
                "try:\n"
                "    s.sendall(b'{}\\n')\n"
                "    print(repr(s.recv(4096)))\n"
                "except (BrokenPipeError, ConnectionResetError):\n"
                "    print('closed')\n"
            )

            def as_nobody() -> subprocess.CompletedProcess[str]:
                return subprocess.run(
                    [str(SYSTEM_PYTHON), "-c", client, str(relay.path)],
                    capture_output=True,
                    text=True,
                    timeout=60,
                    check=False,
                    preexec_fn=lambda: os.setuid(65534),
                )

            r = await asyncio.to_thread(as_nobody)
            assert r.returncode == 0, r.stderr
            assert r.stdout.strip() in ("b''", "closed"), r.stdout  # connected, no answer
            assert said == [f"relay: refused a connection of uid 65534 (only uid {os.getuid()} is served)"]
            mine = await ask(relay.path, {"tier": "plc", "url": "x", "op": "read", "paths": []}, 5.0)
            assert mine["error"] == "request", mine  # the owner is answered
        finally:
            await relay.stop()
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)


async def test_a_relay_deeper_than_sun_path_serves_through_a_deep_link(tmp_path: Path) -> None:
    # The run directory and the runtime directory both longer than AF_UNIX's 107 bytes (a CI's
    # xdist temp paths): the relay still binds its socket there and the client reaches it.
    deep = tmp_path / ("d" * 60) / ("e" * 60)
    base = free_base_port()
    urls = {"plc": f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc"}
    env = {"XDG_RUNTIME_DIR": str(deep / "rt")}
    (deep / "rt").mkdir(parents=True, mode=0o700)
    relay = Relay(urls, session_home(), deep / "run", lambda _: None)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XDG_RUNTIME_DIR", env["XDG_RUNTIME_DIR"])
        await relay.start()
    try:
        link = pointer(urls["plc"], env)
        assert link is not None and len(str(link)) > 107 and len(str(relay.path)) > 107
        assert stat.S_IMODE(relay.path.stat().st_mode) == 0o600
        req = read_request(urls["plc"])
        down = await ask(link, req, 10.0)
        assert down == {"v": PROTOCOL, "ok": False, "error": "unreachable", "reason": "connection refused"}
    finally:
        await relay.stop()
    assert not relay.path.exists() and not link.exists()
