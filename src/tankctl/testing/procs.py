"""Tier processes of tests and benchmarks: free ports, one process wrapper, and the /proc scans.

Shipped (the ``tanklab_stack`` fixture of :mod:`tankctl.pytest_plugin` runs on it from an
installed wheel); :mod:`tanklab_testing.procs` re-exports it for the repository's tests and
benchmarks and adds ``tankctl up``'s wrapper (decisions 0032, 0056).

:class:`TankctlProcess` is the one wrapper of a ``python -m tankctl ...`` process, for a tier
(``plant``, ``plc``, ``supervisor``) and for ``tankctl up`` alike. It starts the process in its own
session (in ``cwd``: the repository root for the repository's tests), keeps every line it prints on
stdout (``lines``; with a ``log`` file, also there, with stderr), waits (bounded) for the line that
says it serves, and stops it with SIGCONT + SIGTERM, a bounded wait and SIGKILL. ``tankctl up``
starts children of its own: :meth:`TankctlProcess.cleanup`, which its callers run on every path,
kills by id whatever of them (and whatever ``tankctl`` process bound to ``ports``) is left. Only
processes this module started, or their children, are ever signalled.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import signal
import socket
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO

from tankctl.testing.waits import wait_until

STOP_TIMEOUT_S = 20.0
"""How long a process may take to exit after SIGTERM before it gets SIGKILL [s]."""
READY_TIMEOUT_S = 60.0
"""How long a process may take to print the line that says it serves [s]."""

_taken: set[int] = set()


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (the kernel's pick)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_base_port(count: int = 4, low: int = 20000, high: int = 30000) -> int:
    """A port N in [low, high) with N .. N + count - 1 free now and never handed out before in
    this process. The default 4 is ``--base-port N``'s block: plant, PLC, supervisor and the
    historian's place.

    Below the ephemeral port range, so that no client socket of another test takes one of them
    meanwhile, and drawn at random: a fixed scan order made concurrent runs on one machine pick
    the same ports and collide at bind."""
    rng = random.Random()
    for _ in range(500):
        base = rng.randrange(low, high - count)
        ports = range(base, base + count)
        if any(p in _taken for p in ports):
            continue
        if all(_port_free(p) for p in ports):
            _taken.update(ports)
            return base
    raise RuntimeError(f"no {count} consecutive free ports in {low}..{high}")


def descendants(pid: int) -> list[int]:
    """PIDs of every live descendant of ``pid`` (Linux /proc), children first."""
    out: list[int] = []
    todo = [pid]
    while todo:
        parent = todo.pop()
        for task in Path(f"/proc/{parent}/task").glob("*"):
            try:
                kids = [int(k) for k in (task / "children").read_text().split()]
            except (OSError, ValueError):
                continue
            for kid in kids:
                if kid not in out:
                    out.append(kid)
                    todo.append(kid)
    return out


def alive(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def tankctl_pids(
    ports: Sequence[int], flags: tuple[str, ...] = ("--port", "--base-port")
) -> dict[int, list[int]]:
    """Live ``tankctl`` processes (Linux /proc, zombies excluded) bound by their arguments to one
    of ``ports``: per port, the pids whose ``flags`` option names it. ``tankctl up`` names its base
    port with ``--base-port``, each tier its own with ``--port``."""
    wanted = {str(p): p for p in ports}
    found: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = [a.decode() for a in (entry / "cmdline").read_bytes().split(b"\0") if a]
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        if state == "Z" or "tankctl" not in argv:
            continue
        named = {argv[i + 1] for i, a in enumerate(argv[:-1]) if a in flags}
        for port in sorted(named & wanted.keys()):
            found.setdefault(wanted[port], []).append(int(entry.name))
    return found


def tankctl_pids_on(base: int, count: int = 4) -> list[int]:
    """Live tankctl processes bound (by their arguments) to the ports base .. base + count - 1."""
    return sorted({p for ps in tankctl_pids([base + k for k in range(count)]).values() for p in ps})


class TankctlProcess:
    """One ``python -m tankctl ARGS`` process in its own session, started in ``cwd``.

    The variations are parameters:

    ``ready``
        The start of the line that says the process serves: ``""`` (the default) is a tier's
        banner, its first line on stdout (so a tier keeps stderr out of ``lines``);
        ``"started: "`` is ``tankctl up``'s; None does not wait.
    ``log``
        A file that gets stderr and every stdout line (the benchmarks keep them); without one,
        stderr is dropped, or with ``merge_stderr`` kept in ``lines`` (``tankctl up`` in tests).
    ``env``
        The whole environment of the process (None: this process's).
    ``reap_children``
        Whether :meth:`stop` also waits for the children the process had (``tankctl up``'s
        tiers) and SIGKILLs, by id, any left (recorded in ``stray``). Tests that assert that
        nothing is left after a stop leave it off and kill what is left in :meth:`cleanup`.
    ``ready_timeout_s``, ``stop_timeout_s``
        The bounds of the wait for ``ready`` and of the wait after SIGTERM.
    ``cwd``
        The working directory of the process (None: this process's).
    ``ports``
        Ports whose ``tankctl`` processes :meth:`cleanup` kills too (the run of a ``tankctl up``
        killed with SIGKILL leaves its tiers).
    """

    def __init__(
        self,
        *args: str,
        name: str | None = None,
        ready: str | None = "",
        log: Path | None = None,
        merge_stderr: bool = False,
        env: Mapping[str, str] | None = None,
        reap_children: bool = False,
        ports: Sequence[int] = (),
        cwd: Path | None = None,
        ready_timeout_s: float = READY_TIMEOUT_S,
        stop_timeout_s: float = STOP_TIMEOUT_S,
    ) -> None:
        self.args = args
        self.name = name or (args[0] if args else "tankctl")
        self.ready = ready
        self.log_path = log
        self.merge_stderr = merge_stderr
        self.env = env
        self.reap_children = reap_children
        self.ports = tuple(ports)
        self.cwd = cwd
        self.ready_timeout_s = ready_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.proc: asyncio.subprocess.Process | None = None
        self.lines: list[str] = []
        """Every line printed on stdout so far (and stderr, with ``merge_stderr``)."""
        self.children: list[int] = []
        self.stray: list[int] = []
        """Children still alive after the process exited, killed by :meth:`stop`."""
        self._log: IO[bytes] | None = None
        self._reader: asyncio.Task[None] | None = None

    def __repr__(self) -> str:
        return f"TankctlProcess({self.name}, pid={self.main_pid})"

    # ---- starting ----------------------------------------------------------------------------

    async def launch(self) -> TankctlProcess:
        """Start the process (no wait); its stdout is read into ``lines`` from now on."""
        stderr: int | IO[bytes] = asyncio.subprocess.DEVNULL
        if self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._log = self.log_path.open("ab")
            stderr = self._log
        elif self.merge_stderr:
            stderr = asyncio.subprocess.STDOUT
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "tankctl",
            *self.args,
            stdout=asyncio.subprocess.PIPE,
            stderr=stderr,
            env=dict(self.env) if self.env is not None else None,
            cwd=self.cwd,
            start_new_session=True,
        )
        self._reader = asyncio.create_task(self._read())
        return self

    async def _read(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        while line := await self.proc.stdout.readline():
            text = line.decode(errors="replace").rstrip("\n")
            self.lines.append(text)
            if self._log is not None:
                self._log.write(line)
                self._log.flush()

    async def start(self) -> TankctlProcess:
        """Launch and, with ``ready``, wait (bounded) for the line that says it serves; a process
        that exits first or does not serve in time is stopped and the start fails."""
        await self.launch()
        if self.ready is not None:
            try:
                await self.wait_line(self.ready, self.ready_timeout_s)
            except (AssertionError, RuntimeError):
                await self.stop()
                raise
        return self

    def said(self, start: str) -> bool:
        """Whether a line so far starts with ``start``."""
        return any(line.startswith(start) for line in self.lines)

    async def wait_line(self, start: str, deadline_s: float = 120.0) -> None:
        """Wait (bounded) for a line starting with ``start``; RuntimeError if the process ends
        first (with what it printed)."""

        def seen() -> bool:
            if self.said(start):
                return True
            if self._reader is not None and self._reader.done() and not self.said(start):
                raise RuntimeError(f"tankctl {self.name} exited before serving: {self.lines[-20:]}")
            return False

        await wait_until(seen, deadline_s, what=f"a line {start!r} from tankctl {self.name}")

    @property
    def banner(self) -> str:
        """The first line printed (a tier's banner: what it serves, where)."""
        return self.lines[0].strip() if self.lines else ""

    # ---- looking at it -----------------------------------------------------------------------

    @property
    def main_pid(self) -> int | None:
        """The process's id (None before the start)."""
        return self.proc.pid if self.proc is not None else None

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.returncode is None

    def tree(self) -> list[int]:
        """This process and its live descendants."""
        if self.proc is None or self.proc.returncode is not None:
            return []
        return [self.proc.pid, *descendants(self.proc.pid)]

    def log_text(self) -> str:
        """The log file's text ('' without one)."""
        if self.log_path is None:
            return ""
        try:
            return self.log_path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""

    # ---- stopping ----------------------------------------------------------------------------

    async def terminate(
        self, deadline_s: float = 30.0, sig: signal.Signals = signal.SIGTERM
    ) -> tuple[int, float]:
        """Send ``sig`` (if still running) and wait at most ``deadline_s`` for the exit (no
        SIGKILL: a process that does not exit fails the caller, :meth:`cleanup` kills it);
        the exit code and the seconds it took (information, never asserted)."""
        assert self.proc is not None, f"tankctl {self.name} was never started"
        t0 = time.monotonic()
        if self.proc.returncode is None:
            self.proc.send_signal(sig)
        code = await asyncio.wait_for(self.proc.wait(), deadline_s)
        if self._reader is not None:
            await asyncio.wait_for(self._reader, 10)
        return code, time.monotonic() - t0

    async def stop(self, deadline_s: float | None = None) -> int | None:
        """SIGCONT (a frozen process must hear SIGTERM) and SIGTERM, a bounded wait, SIGKILL;
        the exit code (None if never started). With ``reap_children``, its children that
        outlive it are waited for (bounded) and killed."""
        if self.proc is None:
            return None
        if self.proc.returncode is None:
            self.children = descendants(self.proc.pid)
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signal.SIGCONT)
                self.proc.send_signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(self.proc.wait(), deadline_s or self.stop_timeout_s)
            except TimeoutError:
                self.proc.kill()
                await self.proc.wait()
        if self.reap_children:
            with contextlib.suppress(AssertionError):
                await wait_until(lambda: not any(alive(p) for p in self.children), STOP_TIMEOUT_S, poll_s=0.1)
            for pid in self.children:
                if alive(pid):
                    self.stray.append(pid)
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGKILL)
        await self._close()
        return self.proc.returncode

    async def kill(self) -> None:
        """SIGKILL (a crash) and reap it; its children, if any, are left to :meth:`cleanup`."""
        if self.proc is not None and self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()
        await self._close()

    async def cleanup(self) -> None:
        """On every path: nothing of this run stays (SIGKILL to the process, its children and
        the tankctl processes bound to ``ports``, by id)."""
        left = set(self.tree()[1:]) | {p for p in self.children if alive(p)}
        if self.ports:
            left |= {p for ps in tankctl_pids(self.ports).values() for p in ps}
        await self.kill()
        for pid in sorted(left):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        await self._close()

    async def _close(self) -> None:
        if self._reader is not None and not self._reader.done():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(self._reader), 2.0)
            if not self._reader.done():
                self._reader.cancel()
        if self._log is not None:
            self._log.close()
            self._log = None
