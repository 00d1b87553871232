"""Each tier's memory and CPU under ``tankctl up``: the figures behind deploy/kubernetes/'s resources.

    python -m benchmarks.k8s_resources [--settle 60] [--window 150]

Starts ``tankctl up --no-board --fresh`` of the default site (speed 1, realtime clock) on free
loopback ports with the benchmarks' own security home, lets it settle for ``--settle`` seconds,
then per tier process (pids from ``up``'s pid files):

- CPU [cores] = (utime + stime at the end - at the start of the window) / window, from
  ``/proc/PID/stat`` (clock ticks / ``SC_CLK_TCK``);
- RSS and peak RSS [MiB] at the end: ``VmRSS`` and ``VmHWM`` of ``/proc/PID/status``;

and one health probe per tier, ``python -m tankctl.health URL`` as the exec probes run it (its
peak RSS and CPU time from GNU ``/usr/bin/time``, and its wall time). Prints a
markdown table (docs/kubernetes.md "Resources") and the load average; stops the stack on every
path. Not part of ``make bench``: run it when the tiers' footprint changes.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import bench_home
from tanklab_testing.procs import ROOT, UpProcess, free_base_port

TIERS = ("plant", "plc", "supervisor", "historian")
"""The tiers ``up`` starts, in port order from the base port."""


@dataclass(frozen=True)
class Usage:
    """One process's CPU time [s] and resident memory [KiB] at one moment."""

    cpu_s: float
    rss_kib: int
    hwm_kib: int


def usage(pid: int) -> Usage:
    """CPU time and memory of ``pid`` now (``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    status = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines())
    return Usage(cpu, int(status["VmRSS"].split()[0]), int(status["VmHWM"].split()[0]))


def probe(url: str, env: dict[str, str]) -> tuple[bool, float, float, float]:
    """Run one health probe under GNU time; (Good, peak RSS [MiB], CPU [s], wall [s]).

    Through ``/usr/bin/time`` (Debian's ``time``), not ``os.wait4`` of a child of this process:
    Linux keeps a process's peak RSS across ``exec``, so a child forked from this interpreter
    would report this interpreter's RSS at the fork as the probe's peak.
    """
    t0 = time.perf_counter()
    run = subprocess.run(
        ["/usr/bin/time", "-f", "%M %U %S", sys.executable, "-m", "tankctl.health", url, "--timeout", "20"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    wall = time.perf_counter() - t0
    maxrss_kib, user_s, system_s = run.stderr.strip().splitlines()[-1].split()
    return run.returncode == 0, int(maxrss_kib) / 1024, float(user_s) + float(system_s), wall


async def measure(settle_s: float, window_s: float) -> str:
    """Run the stack, measure, stop it; the markdown table."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TANKLAB_")}
    env["TANKLAB_HOME"] = str(bench_home())
    base = free_base_port()
    with tempfile.TemporaryDirectory(prefix="tanklab-k8s-res-") as tmp:
        up = UpProcess(base, Path(tmp), "--no-board", "--fresh", env=env)
        try:
            await up.started()
            pids = {tier: up.pid(tier) for tier in TIERS}
            await asyncio.sleep(settle_s)
            start, t0 = {t: usage(p) for t, p in pids.items()}, time.monotonic()
            await asyncio.sleep(window_s)
            end, t1 = {t: usage(p) for t, p in pids.items()}, time.monotonic()
            probes = {
                t: probe(f"opc.tcp://127.0.0.1:{base + k}/tanklab/{t}", env) for k, t in enumerate(TIERS)
            }
        finally:
            await up.stop()
            await up.cleanup()
    rows = [
        "| tier | CPU [cores] | RSS [MiB] | peak RSS [MiB] | probe: Good, CPU [s], peak [MiB], wall [s] |",
        "|---|---|---|---|---|",
    ]
    for t in TIERS:
        ok, rss, cpu, wall = probes[t]
        rows.append(
            f"| {t} | {(end[t].cpu_s - start[t].cpu_s) / (t1 - t0):.3f} | {end[t].rss_kib / 1024:.1f} "
            f"| {end[t].hwm_kib / 1024:.1f} | {ok}, {cpu:.2f}, {rss:.1f}, {wall:.2f} |"
        )
    load = " / ".join(Path("/proc/loadavg").read_text().split()[:3])
    return "\n".join(
        [*rows, "", f"window {t1 - t0:.0f} s after {settle_s:g} s of settling; load average {load}"]
    )


def main() -> None:
    p = argparse.ArgumentParser(prog="python -m benchmarks.k8s_resources", description=__doc__)
    p.add_argument("--settle", type=float, default=60.0, help="Seconds after start-up before measuring.")
    p.add_argument("--window", type=float, default=150.0, help="Seconds the CPU time is measured over.")
    args = p.parse_args()
    print(asyncio.run(measure(args.settle, args.window)))


if __name__ == "__main__":
    main()
