"""One child process of ``tankctl up`` (:class:`Tier`: start, readiness, log, pid file, stop)
and the pid-file and log helpers ``up`` and its tests use."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any


def pid_alive(pid: int) -> bool:
    """True when a process ``pid`` exists (``kill(pid, 0)``)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def running_pid(path: Path) -> int | None:
    """The pid in the pid file ``path`` when it names a live tanklab process, else None.

    None for a missing or unreadable file, a pid that is gone, and (where ``/proc`` exists) a
    pid now used by a process that is not ``tankctl``: such a file is stale.
    """
    try:
        pid = int(path.read_text(encoding="utf-8").split()[0])
    except (OSError, ValueError, IndexError):
        return None
    if pid <= 0 or not pid_alive(pid):
        return None
    if not Path("/proc/self").exists():
        return pid
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except FileNotFoundError:
        return None
    except OSError:
        return pid
    return pid if any(b"tankctl" in a for a in argv) else None


def last_error_line(text: str, limit: int = 300) -> str:
    """The line of a tier's log that says why it stopped.

    The tier's own one-line error (``tankctl: ...``) if there is one, else the last line naming
    an error or exception (a traceback's last line), else the last line.
    """
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not lines:
        return "nothing in its log"
    pick = next((ln for ln in reversed(lines) if ln.startswith("tankctl:")), None)
    if pick is None:
        keys = ("ERROR", "CRITICAL", "Error", "Exception")
        pick = next((ln for ln in reversed(lines) if any(k in ln for k in keys)), lines[-1])
    return pick if len(pick) <= limit else pick[: limit - 3] + "..."


@dataclass
class Tier:
    """One child process of the stack."""

    name: str
    args: list[str]
    url: str
    port: int
    log_path: Path
    proc: asyncio.subprocess.Process | None = None
    restarts: int = 0
    exit_code: int | None = None
    log_file: Any = None
    log_offset: int = 0
    killed: bool = False
    exited_at: float | None = None

    async def start(self, env: dict[str, str]) -> None:
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        if self.log_file is None:
            self.log_file = self.log_path.open("ab")
        # The reason of a death is looked for in what this run wrote, not in older runs.
        self.log_offset = self.log_path.stat().st_size
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "tankctl",
            *self.args,
            stdout=asyncio.subprocess.DEVNULL,
            stderr=self.log_file,
            env=env,
            # Its own process group: Ctrl-C on the terminal reaches ``up`` only, which stops
            # the tiers in its order, and SIGKILL can take the tier's whole group.
            start_new_session=True,
        )
        self.exit_code = None
        self.killed = False
        self.exited_at = None
        # The pid file lets an operator (or a test) signal exactly this tier.
        self.pid_path.write_text(f"{self.proc.pid}\n", encoding="utf-8")

    @property
    def pid_path(self) -> Path:
        """``<log dir>/<tier>.pid`` while the tier runs."""
        return self.log_path.with_suffix(".pid")

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.returncode is None

    def signal(self, sig: signal.Signals) -> None:
        """Send ``sig`` to the tier's process group (it leads its own session)."""
        if self.proc is None or self.proc.returncode is not None:
            return
        if sig == signal.SIGKILL:
            self.killed = True
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, sig)

    async def wait(self, timeout_s: float) -> bool:
        """Wait at most ``timeout_s`` for the process to exit; True when it has."""
        if self.proc is None:
            return True
        try:
            await asyncio.wait_for(asyncio.shield(self.proc.wait()), max(0.0, timeout_s))
        except TimeoutError:
            return False
        self.exit_code = self.proc.returncode
        if self.exited_at is None:
            self.exited_at = time.monotonic()
        return True

    def reason(self) -> str:
        """Why the tier stopped: the signal that killed it, else the last error line its log got
        since it was started."""
        if self.exit_code is not None and self.exit_code < 0:
            with contextlib.suppress(ValueError):
                return f"killed by {signal.Signals(-self.exit_code).name}"
        try:
            with self.log_path.open("rb") as f:
                f.seek(self.log_offset)
                data = f.read()
        except OSError as e:
            return f"its log {self.log_path} is unreadable: {e.strerror or e}"
        return last_error_line(data[-65536:].decode("utf-8", "replace"))

    def release(self) -> None:
        """After the process is gone: close the log, remove the pid file if it still is ours."""
        if self.log_file is not None:
            self.log_file.close()
            self.log_file = None
        if self.proc is not None and running_pid(self.pid_path) in (None, self.proc.pid):
            with contextlib.suppress(FileNotFoundError):
                self.pid_path.unlink()


async def terminate(started: list[Tier], grace_s: float, reap_s: float) -> list[str]:
    """SIGTERM to every process of ``started``, SIGKILL to those still there after ``grace_s``,
    ``reap_s`` to reap them, then :meth:`Tier.release` of each: the names of the killed (the end
    of `up`'s and `fleet up`'s one stop path)."""
    for proc in started:
        proc.signal(signal.SIGTERM)
    await asyncio.gather(*(p.wait(grace_s) for p in started))
    killed = [p.name for p in started if p.running]
    for proc in started:
        proc.signal(signal.SIGKILL)
    await asyncio.gather(*(p.wait(reap_s) for p in started))
    for proc in started:
        proc.release()
    return killed
