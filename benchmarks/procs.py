"""Tier processes for the benchmarks: the test-support wrapper with the benchmarks' home, and CPU use.

Every process is a :class:`tanklab_testing.procs.TankctlProcess` (the one wrapper tests use
too) made by :func:`bench_process`: started as ``python -m tankctl ...`` in its own session with
the benchmarks' own security home (:func:`benchmarks.common.bench_home`, never the user's),
its output going to a log file; ``stop`` sends SIGTERM, waits (bounded), then SIGKILL, and
waits for the children ``tankctl up`` started, killing by id (and recording in ``stray``) any
that outlives it. :class:`CpuMeter` measures what other work on the machine costs meanwhile.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from benchmarks.common import bench_home
from tanklab_testing.procs import TankctlProcess


def bench_process(
    name: str,
    args: list[str],
    log_path: Path,
    *,
    banner: bool = True,
    env_extra: dict[str, str] | None = None,
) -> TankctlProcess:
    """``python -m tankctl ARGS`` logging to ``log_path``, in the benchmarks' security home (and
    ``env_extra``); with ``banner``, :meth:`~TankctlProcess.start` waits (bounded) for the line a
    tier prints once it serves."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TANKLAB_")}
    env["TANKLAB_HOME"] = str(bench_home())
    env.update(env_extra or {})
    return TankctlProcess(
        *args, name=name, ready="" if banner else None, log=log_path, env=env, reap_children=True
    )


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
