"""Plant, PLC and supervisor processes on consecutive loopback ports: the one test and bench Stack.

A :class:`Stack` is a site config, a base port (plant on ``base``, PLC on ``base + 1``,
supervisor on ``base + 2``, each pointed at the one below; a historian, started by name, on
``base + 3`` pointed at all three) and the :class:`TankctlProcess` of
every tier it started. The variations between tests and benchmarks are fields: the speed, the
plant's state file, a ``--home`` and a log directory (the benchmarks' own security home and
per-process logs), extra arguments per tier (a retentive-memory file, a trace). Tiers start
and restart one by one (:meth:`Stack.start`), crash (:meth:`Stack.kill`), and :meth:`Stack.down`
stops all of them on every path. :meth:`Stack.serving` runs one for synchronous code (a
module-scoped fixture) in an event loop of its own thread.

Shipped: the pytest plugin's ``tanklab_stack`` (:mod:`tankctl.testing.fixture`) is a Stack, and
:mod:`tanklab_testing.stack` is this one started from the repository root (decision 0056).
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
import tempfile
import threading
from collections import Counter
from collections.abc import Coroutine, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from tankctl.testing.logins import Logins
from tankctl.testing.procs import TankctlProcess

HOST = "127.0.0.1"
"""Every test and benchmark process serves on loopback."""
TIERS = ("plant", "plc", "supervisor")
"""The control tiers in port order: ``--base-port N`` puts tier k on N + k."""
PORT_ORDER = (*TIERS, "historian")
"""Every process of a stack in port order (the historian on N + 3)."""

T = TypeVar("T")

UP_TIMEOUT_S = 180.0
"""Bound of :meth:`Stack.serving`'s start and stop of all tiers from another thread [s]."""


def tier_url(base: int, tier: str, host: str = HOST) -> str:
    """The endpoint of ``tier`` in a stack on ``base`` (plant on base, PLC on base + 1, ...)."""
    return f"opc.tcp://{host}:{base + PORT_ORDER.index(tier)}/tanklab/{tier}"


@dataclass
class Stack:
    """Tier processes of one test or measurement on ``base`` .. ``base + 2``.

    ``speed`` is ``--speed`` (None: the config's); ``state_file`` the plant's ``--state-file``;
    ``home`` the tiers' ``--home`` (None: ``TANKLAB_HOME`` of ``env``); ``log_dir`` gets one log
    per process run (``plc-0.log``, ``plc-1.log`` after a restart; None: stderr is dropped) and
    ``--host`` is passed with it; ``tier_args`` are appended to a tier's arguments; ``logins``
    are what clients of the stack log in with (the stack itself does not use them); ``cwd`` is
    the processes' working directory (None: this process's).
    """

    config: Path
    base: int
    speed: float | None = None
    state_file: Path | None = None
    home: Path | None = None
    log_dir: Path | None = None
    env: Mapping[str, str] | None = None
    tier_args: dict[str, tuple[str, ...]] = field(default_factory=dict)
    logins: Logins | None = None
    cwd: Path | None = None
    procs: dict[str, TankctlProcess] = field(default_factory=dict)
    runs: Counter[str] = field(default_factory=Counter)
    """Starts per tier so far (a restart counts)."""
    logs: dict[str, str] = field(default_factory=dict)
    """Log text of every process, by log file name, kept at :meth:`down` (the log directory
    may be temporary)."""
    exited: dict[str, int] = field(default_factory=dict)
    """Tiers that exited by themselves (not stopped or killed by the stack), with their exit
    codes, as :meth:`down` found them."""
    _scratch: tempfile.TemporaryDirectory[str] | None = field(default=None, repr=False)
    _ended: set[str] = field(default_factory=set, repr=False)
    _loop: asyncio.AbstractEventLoop | None = field(default=None, repr=False)

    # ---- where ---------------------------------------------------------------------------------

    def url(self, tier: str) -> str:
        return tier_url(self.base, tier)

    @property
    def urls(self) -> list[str]:
        """Plant, PLC and supervisor endpoints, in port order."""
        return [self.url(t) for t in TIERS]

    @property
    def plant_url(self) -> str:
        return self.url("plant")

    @property
    def plc_url(self) -> str:
        return self.url("plc")

    @property
    def supervisor_url(self) -> str:
        return self.url("supervisor")

    # ---- processes -----------------------------------------------------------------------------

    def args(self, tier: str, *extra: str) -> tuple[str, ...]:
        """``tankctl`` arguments of ``tier``: the config, the stack's options, its port, the
        tier below it, then ``tier_args`` and ``extra``."""
        common: list[str] = ["--config", str(self.config)]
        if self.log_dir is not None:
            common += ["--host", HOST]
        if self.speed is not None:
            common += ["--speed", f"{self.speed:g}"]
        if self.home is not None:
            common += ["--home", str(self.home)]
        own = ["--port", str(self.base + PORT_ORDER.index(tier))]
        if tier == "plant" and self.state_file is not None:
            own += ["--state-file", str(self.state_file)]
        elif tier == "plc":
            own += ["--plant-url", self.plant_url]
        elif tier == "supervisor":
            own += ["--plc-url", self.plc_url]
        elif tier == "historian":
            own += ["--plant-url", self.plant_url, "--plc-url", self.plc_url]
            own += ["--supervisor-url", self.supervisor_url]
        return (tier, *common, *own, *self.tier_args.get(tier, ()), *extra)

    async def start(self, tier: str, *extra: str) -> TankctlProcess:
        """Start (or restart, once stopped or killed) ``tier``; returns once it serves (its
        banner, bounded)."""
        old = self.procs.get(tier)
        if old is not None and old.running:
            raise RuntimeError(f"{tier} of the stack on {self.base} is still running ({old.main_pid})")
        log = self._logs_dir() / f"{tier}-{self.runs[tier]}.log"
        self.runs[tier] += 1
        self._ended.discard(tier)
        proc = TankctlProcess(*self.args(tier, *extra), log=log, env=self.env, cwd=self.cwd)
        self.procs[tier] = proc
        return await proc.start()

    async def up(self, tiers: Sequence[str] = TIERS) -> Stack:
        """Start ``tiers`` bottom-up (each serves before the next one starts)."""
        for tier in tiers:
            await self.start(tier)
        return self

    def pid(self, tier: str) -> int:
        """The id of ``tier``'s running process."""
        proc = self.procs[tier]
        assert proc.running and proc.main_pid is not None, f"{tier} is not running"
        return proc.main_pid

    async def kill(self, tier: str) -> None:
        """SIGKILL ``tier`` (a crash)."""
        self._ended.add(tier)
        await self.procs[tier].kill()

    async def stop(self, tier: str) -> int | None:
        """SIGTERM ``tier`` (SIGKILL after the bounded wait); its exit code."""
        self._ended.add(tier)
        return await self.procs[tier].stop()

    async def down(self) -> None:
        """Stop every tier started, top-down (frozen ones too), and keep the logs.

        A tier that had exited by itself is recorded in :attr:`exited` and the end of its log
        goes to stderr (pytest shows it with the failing test: why a server went away).
        """
        for tier in reversed(PORT_ORDER):
            proc = self.procs.get(tier)
            if proc is None:
                continue
            if proc.proc is not None and proc.proc.returncode is not None and tier not in self._ended:
                self.exited[tier] = proc.proc.returncode
            await proc.stop()
        for log in sorted(self._logs_dir().glob("*.log")):
            self.logs[log.name] = log.read_text(encoding="utf-8", errors="replace")
        for tier, code in self.exited.items():
            name = f"{tier}-{self.runs[tier] - 1}.log"
            tail = "\n".join(self.logs.get(name, "").splitlines()[-40:])
            head = f"stack on {self.base}: {tier} exited by itself (code {code}); its log ends:"
            print(f"{head}\n{tail}", file=sys.stderr)
        if self._scratch is not None:
            self._scratch.cleanup()
            self._scratch = None

    def _logs_dir(self) -> Path:
        """Where the processes' logs go: ``log_dir``, or a scratch directory removed by
        :meth:`down` (the logs stay in :attr:`logs`)."""
        if self.log_dir is not None:
            return self.log_dir
        if self._scratch is None:
            self._scratch = tempfile.TemporaryDirectory(prefix=f"tanklab-stack-{self.base}-")
        return Path(self._scratch.name)

    @contextlib.contextmanager
    def serving(self, tiers: Sequence[str] = TIERS, deadline_s: float = UP_TIMEOUT_S) -> Iterator[Stack]:
        """The stack up for synchronous code: its processes live in an event loop of a thread of
        their own; the start and the stop are bounded by ``deadline_s``, and the stop runs on
        every path."""
        loop = asyncio.new_event_loop()
        thread = threading.Thread(target=loop.run_forever, name=f"stack-{self.base}", daemon=True)
        thread.start()
        self._loop = loop
        try:
            self.run_sync(self.up(tiers), deadline_s)
            yield self
        finally:
            try:
                self.run_sync(self.down(), deadline_s)
            finally:
                self._loop = None
                loop.call_soon_threadsafe(loop.stop)
                thread.join(deadline_s)
                loop.close()

    def run_sync(self, coro: Coroutine[Any, Any, T], deadline_s: float = UP_TIMEOUT_S) -> T:
        """Run ``coro`` in the event loop of :meth:`serving` from synchronous code and return its
        result (bounded by ``deadline_s``): how a synchronous client of the stack talks to it."""
        if self._loop is None:
            coro.close()
            raise RuntimeError(f"the stack on {self.base} is not serving")
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(deadline_s)
