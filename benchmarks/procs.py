"""Tier processes for the benchmarks: free ports, start with a bounded wait, stop, leave nothing.

Every process is started by this module as ``python -m tankctl ...`` in its own session, its
output going to a log file; ``stop`` sends SIGTERM, waits (bounded), then SIGKILL. ``tankctl up``
starts its own children: :func:`descendants` lists them (from /proc) before the stop so that
:meth:`Proc.stop` can check they are gone and kill, by id, any that is not. Only processes this
module started, or their children, are ever signalled.
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
from pathlib import Path
from typing import IO

from benchmarks.common import ROOT, bench_home

STOP_TIMEOUT_S = 20.0
BANNER_TIMEOUT_S = 60.0

_taken: set[int] = set()


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_base_port(count: int = 3, low: int = 20000, high: int = 30000) -> int:
    """A port N in [low, high) with N .. N + count - 1 free now and not handed out before."""
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


_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def _busy_s() -> float:
    """CPU time the whole machine has spent busy since boot [s] (all cores; /proc/stat)."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    except (OSError, IndexError):
        return float("nan")
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(f) for f in fields[:8])
    return (user + nice + system + irq + softirq + steal) * _TICK_S


def _cpu_s(pid: int) -> float:
    """CPU time (user + system) of one live process [s]; 0 if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return 0.0
    return (int(fields[11]) + int(fields[12])) * _TICK_S


class CpuMeter:
    """CPU used by everything else on the machine while a measurement runs.

    ``start`` and ``stop`` take the PIDs of the measurement's own processes (this one is always
    added); the result is the machine's busy time minus theirs, divided by the wall time: the
    average number of cores other work (other users, other sessions) kept busy meanwhile.
    """

    def __init__(self) -> None:
        self._t0 = self._busy0 = self._ours0 = float("nan")
        self.other_cores = float("nan")

    @staticmethod
    def _ours(pids: list[int]) -> float:
        return sum(_cpu_s(p) for p in {os.getpid(), *pids})

    def start(self, pids: list[int]) -> None:
        self._t0, self._busy0, self._ours0 = time.monotonic(), _busy_s(), self._ours(pids)

    def stop(self, pids: list[int]) -> float:
        wall = time.monotonic() - self._t0
        other = (_busy_s() - self._busy0) - (self._ours(pids) - self._ours0)
        self.other_cores = max(0.0, other) / wall if wall > 0 else float("nan")
        return self.other_cores


class Proc:
    """One ``python -m tankctl ...`` process with its log file."""

    def __init__(self, name: str, args: list[str], log_path: Path, *, banner: bool = True) -> None:
        self.name = name
        self.args = args
        self.log_path = log_path
        self.banner = banner
        self.proc: asyncio.subprocess.Process | None = None
        self.banner_line = ""
        self.children: list[int] = []
        self.stray: list[int] = []
        self._log: IO[bytes] | None = None

    async def start(self) -> Proc:
        """Start; with ``banner``, wait (bounded) for the line a tier prints once it serves."""
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("wb")
        env = {k: v for k, v in os.environ.items() if not k.startswith("TANKLAB_")}
        env["TANKLAB_HOME"] = str(bench_home())
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "tankctl",
            *self.args,
            stdout=asyncio.subprocess.PIPE if self.banner else self._log,
            stderr=self._log,
            env=env,
            cwd=ROOT,
            start_new_session=True,
        )
        if self.banner:
            assert self.proc.stdout is not None
            try:
                line = await asyncio.wait_for(self.proc.stdout.readline(), BANNER_TIMEOUT_S)
            except TimeoutError:
                await self.stop()
                raise RuntimeError(f"{self.name} did not serve within {BANNER_TIMEOUT_S:.0f} s") from None
            self.banner_line = line.decode().strip()
            if not self.banner_line:
                await self.stop()
                raise RuntimeError(f"{self.name} exited before serving (see {self.log_path})")
        return self

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    def tree(self) -> list[int]:
        """This process and its live descendants."""
        if self.proc is None or self.proc.returncode is not None:
            return []
        return [self.proc.pid, *descendants(self.proc.pid)]

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.returncode is None

    async def stop(self) -> int | None:
        """SIGTERM, bounded wait, SIGKILL; then make sure its children are gone too."""
        if self.proc is None:
            return None
        if self.proc.returncode is None:
            self.children = descendants(self.proc.pid)
            self.proc.send_signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(self.proc.wait(), STOP_TIMEOUT_S)
            except TimeoutError:
                self.proc.kill()
                await self.proc.wait()
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while any(alive(p) for p in self.children) and time.monotonic() < deadline:
            await asyncio.sleep(0.1)
        for pid in self.children:
            if alive(pid):
                self.stray.append(pid)
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        if self._log is not None:
            self._log.close()
            self._log = None
        return self.proc.returncode

    def log_text(self) -> str:
        try:
            return self.log_path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""


def tankctl_pids(
    ports: list[int], flags: tuple[str, ...] = ("--port", "--base-port")
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
