"""Shared test helpers: free loopback ports and the one bounded wait for real processes."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import yaml
from asyncua import Client

if str(Path(__file__).resolve().parents[1]) not in sys.path:  # benchmarks/ lives at the root
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.procs import free_base_port as _free_base_port
from benchmarks.procs import tankctl_pids

from tanklab.tags import Role
from tanklab_io.home import SecurityHome
from tanklab_io.ua import new_client
from tanklab_io.ua_security import ClientIdentity, ServerSecurity, secure_client
from tanklab_io.users import Credentials

TEST_ROLES = {"observer": Role.OBSERVER, "operator": Role.OPERATOR, "engineer": Role.ENGINEER}
"""The login users of the test security home (see conftest.security_home)."""
TEST_PASSWORDS = {name: f"{name}-test-password" for name in TEST_ROLES}


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def free_base_port() -> int:
    """N such that N .. N+3 are free on 127.0.0.1 (``--base-port N``: plant, PLC, supervisor and
    the historian's place), below the ephemeral port range so that no client socket of another
    test takes one of them meanwhile. Drawn at random and never handed out twice in a process
    (``benchmarks.procs.free_base_port``, the one implementation): a fixed scan order made
    concurrent runs on one machine pick the same ports and collide at bind."""
    return _free_base_port(4)


def stop_process(proc: subprocess.Popen[str], deadline_s: float = 20.0) -> None:
    """SIGTERM a process this test started, SIGKILL after ``deadline_s`` (bounded), and reap it."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=deadline_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


async def wait_until(
    condition: Callable[[], Awaitable[bool] | bool],
    deadline_s: float,
    *,
    what: str = "condition",
    poll_s: float = 0.05,
) -> None:
    """Wait until ``condition()`` is true, at most ``deadline_s`` seconds of wall time.

    The only way tests wait for real processes: bounded, polling, failing with a message that
    names what did not happen. Assertions are on model time, never on how long this took.
    """
    end = time.monotonic() + deadline_s
    while True:
        result = condition()
        if not isinstance(result, bool):
            result = await result
        if result:
            return
        if time.monotonic() >= end:
            raise AssertionError(f"timed out after {deadline_s} s waiting for {what}")
        await asyncio.sleep(poll_s)


def wait_until_sync(
    condition: Callable[[], bool], deadline_s: float, *, what: str = "condition", poll_s: float = 0.5
) -> None:
    """:func:`wait_until` for code with no event loop (a synchronous fixture): the same bound
    and the same message."""
    end = time.monotonic() + deadline_s
    while not condition():
        if time.monotonic() >= end:
            raise AssertionError(f"timed out after {deadline_s} s waiting for {what}")
        time.sleep(poll_s)


ROOT = Path(__file__).resolve().parents[1]


class TierProcess:
    """A tier started as ``python -m tankctl ...`` in its own process group.

    ``start`` waits (bounded) for the banner line the tier prints once it serves; ``stop``
    sends SIGTERM and waits, ``kill`` sends SIGKILL. Only processes this object started are
    ever signalled.
    """

    def __init__(self, *args: str, env: dict[str, str] | None = None) -> None:
        self.args = args
        self.env = env
        self.proc: asyncio.subprocess.Process | None = None
        self.banner = ""

    async def start(self, deadline_s: float = 30.0) -> TierProcess:
        import os
        import sys

        env = dict(os.environ, **(self.env or {}))
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "tankctl",
            *self.args,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.DEVNULL,
            env=env,
            cwd=ROOT,
            start_new_session=True,
        )
        assert self.proc.stdout is not None
        line = await asyncio.wait_for(self.proc.stdout.readline(), deadline_s)
        self.banner = line.decode().strip()
        if not self.banner:
            raise AssertionError(f"tankctl {' '.join(self.args)} exited before serving")
        return self

    async def stop(self, deadline_s: float = 20.0) -> int | None:
        import signal

        if self.proc is None or self.proc.returncode is not None:
            return self.proc.returncode if self.proc else None
        self.proc.send_signal(signal.SIGTERM)
        try:
            return await asyncio.wait_for(self.proc.wait(), deadline_s)
        except TimeoutError:
            self.proc.kill()
            return await self.proc.wait()

    async def kill(self) -> None:
        if self.proc is not None and self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()


def session_home() -> SecurityHome:
    """The session's security home (``TANKLAB_HOME``, set by conftest.security_home)."""
    return SecurityHome(Path(os.environ["TANKLAB_HOME"]))


def server_security() -> ServerSecurity:
    """What an in-process tier server of a test is secured with."""
    return ServerSecurity(session_home())


def identity(
    user: str = "engineer", *, tier: str | None = None, policy: str = "Basic256Sha256"
) -> ClientIdentity:
    """A test user's login (``user``), or a tier's certificate identity (``tier``)."""
    if tier is not None:
        return ClientIdentity(session_home(), tier, policy=policy)
    return ClientIdentity(session_home(), "cli", Credentials(user, TEST_PASSWORDS[user]), policy=policy)


async def secure(
    url: str, user: str = "engineer", *, tier: str | None = None, timeout_s: float = 4.0
) -> Client:
    """A client of ``url`` set up (not connected) to connect as a test user or a tier:
    ``async with await secure(url, "operator") as client: ...``."""
    client = new_client(url, timeout_s)
    await secure_client(client, identity(user, tier=tier))
    return client


def _site_name(config: Path) -> str:
    """A site config's run-directory name (its ``name``, as ``tankctl up`` names it)."""
    return str(yaml.safe_load(config.read_text(encoding="utf-8"))["name"])


def tanklab_pids(base: int) -> list[int]:
    """Live tankctl processes bound (by their arguments) to the ports base..base+2
    (``benchmarks.procs.tankctl_pids``, which the restart benchmark counts with too)."""
    return sorted({p for ps in tankctl_pids([base + k for k in range(3)]).values() for p in ps})


class UpProcess:
    """`tankctl up` as a subprocess (own session, output piped, so in line mode); every line it
    prints is kept. ``start`` waits (bounded) for its ``started:`` line, ``stop`` sends SIGTERM and
    returns the exit code, ``cleanup`` (on every path) kills whatever of the run is left."""

    def __init__(
        self,
        base: int,
        log_dir: Path,
        *extra: str,
        config: Path | None = None,
        env: dict[str, str] | None = None,
    ) -> None:
        config = config or ROOT / "configs/three_tank_energies_sim.yaml"
        self.base = base
        self.log_dir = log_dir
        self.env = env
        self.run_dir = log_dir / _site_name(config)
        self.args = ["up", "--config", str(config), "--base-port", str(base), "--log-dir", str(log_dir)]
        self.args += list(extra)
        self.proc: asyncio.subprocess.Process | None = None
        self.lines: list[str] = []
        self._reader: asyncio.Task[None] | None = None

    async def launch(self) -> UpProcess:
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "tankctl",
            *self.args,
            cwd=ROOT,
            start_new_session=True,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT,
            env=self.env,
        )
        self._reader = asyncio.create_task(self._read())
        return self

    async def _read(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        while line := await self.proc.stdout.readline():
            self.lines.append(line.decode().rstrip("\n"))

    def said(self, start: str) -> bool:
        return any(line.startswith(start) for line in self.lines)

    async def wait_line(self, start: str, deadline_s: float = 120) -> None:
        def seen() -> bool:
            if self.said(start):
                return True
            ended = self.proc is not None and self.proc.returncode is not None
            if ended and self._reader is not None and self._reader.done():
                raise AssertionError(f"tankctl up exited early: {self.lines}")
            return False

        await wait_until(seen, deadline_s, what=f"a line {start!r} from tankctl up")

    async def started(self) -> UpProcess:
        await self.launch()
        await self.wait_line("started: ")
        return self

    async def terminate(
        self, deadline_s: float = 30, sig: signal.Signals = signal.SIGTERM
    ) -> tuple[int, float]:
        """``sig``; the exit code and the seconds it took (information, not asserted)."""
        assert self.proc is not None
        t0 = time.monotonic()
        with_signal = self.proc.returncode is None
        if with_signal:
            self.proc.send_signal(sig)
        code = await asyncio.wait_for(self.proc.wait(), deadline_s)
        if self._reader is not None:
            await asyncio.wait_for(self._reader, 10)
        return code, time.monotonic() - t0

    async def cleanup(self) -> None:
        """On every path: nothing of this run stays (SIGKILL to what is left, then assert)."""
        if self.proc is not None and self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()
        if self._reader is not None and not self._reader.done():
            self._reader.cancel()
        for pid in tanklab_pids(self.base):
            os.kill(pid, signal.SIGKILL)

    async def start(self) -> UpProcess:
        """Launch and wait for the ``started:`` line (every endpoint serves)."""
        return await self.started()

    async def stop(self, deadline_s: float = 60) -> int:
        """SIGTERM (if still running); the exit code."""
        code, _ = await self.terminate(deadline_s)
        return code

    def pid(self, tier: str) -> int:
        """The pid in a tier's pid file."""
        return int((self.run_dir / f"{tier}.pid").read_text())

    def pid_files(self) -> list[Path]:
        return sorted(self.run_dir.glob("*.pid"))
