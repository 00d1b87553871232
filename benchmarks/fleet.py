"""Sites per machine: ``tankctl fleet up --sites N`` at a 1 s scan, overruns, CPU and RSS vs N.

For each N: ``fleet up`` (the shipped Energies site, speed 1, so the PLC scans every 1 s of wall
time) in its own session with the benchmarks' security home; once it says ``started:``, the
hosting processes' status files are read (every site's PLC overrun counter), then again after
the window: *overruns in the window* is the difference (the start-up's overruns, counted while
the other sites were still building their address spaces, are reported apart). Then ``fleet
status`` reads every site's plant, PLC and supervisor over OPC UA (*reachable*), and its RSS
and CPU lines are kept (CPU: % of one core over the hosting process's last status period).
``fleet down`` stops the fleet; the bench checks that no hosting process is left. The load
average of the machine (shared with other work) is recorded at each N.

Run alone: ``python -m benchmarks.fleet --sites 10,25 --window 60 --output /tmp/fleet.md``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.common import bench_home
from tankctl.fleet_layout import FleetLayout
from tanklab_testing.procs import ROOT, TankctlProcess, alive, free_base_port

CONFIG = ROOT / "configs" / "three_tank_energies_sim.yaml"
DEFAULT_NS = (10, 25, 50, 100, 200)
PER_PROCESS = 25


REACHABLE = re.compile(r"(\d+) reachable")
"""The reachable count in `fleet status`'s ``sites:`` line (its brackets hold commas too)."""


@dataclass
class FleetPoint:
    """One N: what the window showed."""

    sites: int
    per_process: int
    window_s: float
    start_s: float = 0.0
    startup_overruns: int = 0
    window_overruns: int = 0
    reachable: int = 0
    up: int = 0
    rss_mib: float = 0.0
    cpu_percent: list[float] = field(default_factory=list)
    load: str = ""
    left: int = 0
    error: str = ""


def _overruns(layout: FleetLayout) -> tuple[int, list[float], int]:
    total, cpus, up = 0, [], 0
    for j in range(layout.processes):
        try:
            data = json.loads(layout.host_status_file(j).read_text())
        except (OSError, ValueError):
            continue
        cpus.append(float(data.get("cpu_percent", 0.0)))
        for s in data.get("sites", {}).values():
            total += int(s.get("overruns", 0))
            up += s.get("state") == "up"
    return total, cpus, up


def _rss_mib(layout: FleetLayout) -> float:
    total = 0
    for j in range(layout.processes):
        try:
            pid = int(layout.host_pid_file(j).read_text().split()[0])
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except (OSError, ValueError, IndexError):
            continue
    return total / 1024


def _tankctl(*args: str, env: dict[str, str]) -> TankctlProcess:
    return TankctlProcess(*args, ready=None, merge_stderr=True, env=env)


async def measure(
    n: int, window_s: float, work: Path, log: Callable[[str], None], per_process: int = PER_PROCESS
) -> FleetPoint:
    point = FleetPoint(n, per_process, window_s)
    base = free_base_port(3 * n, low=30000, high=60000)
    fleet_dir = work / f"fleet-{n}"
    env = {**os.environ, "TANKLAB_HOME": str(bench_home())}
    up = TankctlProcess(
        "fleet",
        "up",
        "--sites",
        str(n),
        "--config",
        str(CONFIG),
        "--base-port",
        str(base),
        "--sites-per-process",
        str(per_process),
        "--fleet-dir",
        str(fleet_dir),
        name=f"fleet-{n}",
        ready="started: ",
        merge_stderr=True,
        env=env,
        ready_timeout_s=900.0,
        stop_timeout_s=120.0,
    )
    t0 = time.monotonic()
    try:
        await up.start()
        point.start_s = time.monotonic() - t0
        layout = FleetLayout.load(fleet_dir)
        await asyncio.sleep(3.0)  # one status period: every counter written after start-up
        point.startup_overruns, _, _ = _overruns(layout)
        log(f"  N={n}: up in {point.start_s:.0f} s, {point.startup_overruns} overruns at start-up")
        await asyncio.sleep(window_s)
        end, point.cpu_percent, point.up = _overruns(layout)
        point.window_overruns = end - point.startup_overruns
        point.rss_mib = _rss_mib(layout)
        point.load = " ".join(Path("/proc/loadavg").read_text().split()[:3])
        status = _tankctl("fleet", "status", "--fleet-dir", str(fleet_dir), env=env)
        await status.launch()
        assert status.proc is not None
        await asyncio.wait_for(status.proc.wait(), 600)
        await asyncio.sleep(0.5)
        for line in status.lines:
            found = REACHABLE.search(line) if line.startswith("sites: ") else None
            if found:
                point.reachable = int(found.group(1))
        log(f"  N={n}: " + " | ".join(status.lines[2:]))
        pids = [int(p.read_text().split()[0]) for p in layout.hosts_dir.glob("host-*.pid")]
        await up.stop(120.0)
        point.left = sum(alive(p) for p in pids)
    except Exception as e:  # the next N still runs
        point.error = f"{type(e).__name__}: {e}"
        log(f"  N={n}: FAILED {point.error}; last lines {up.lines[-5:]}")
    finally:
        await up.cleanup()
    return point


def markdown(points: list[FleetPoint]) -> str:
    """Section 17 of the benchmark document."""
    lines = [
        "## 17. Fleets of live sites (`tankctl fleet up`)",
        "",
        "`benchmarks/fleet.py` (`python -m benchmarks.run --only fleet`; alone: `python -m "
        "benchmarks.fleet`). The shipped Energies site at speed 1 (1 s PLC scan), "
        "K sites per hosting process (column). *Overruns (window)* are the PLC overruns counted "
        "after every site was up, summed over the sites; *start-up* those counted before; "
        "*reachable*: sites whose plant, PLC and supervisor each answered a read from `fleet status` "
        "after the window; RSS is the sum over the hosting processes; CPU is each hosting process's "
        "% of one core over its last 2 s. The machine is shared with other work: its load average "
        "(1, 5, 15 min) is recorded at each N.",
        "",
        "| N | K | processes | window [s] | start-up [s] | overruns (start-up) | overruns (window) | up | "
        "reachable | RSS total [MiB] | RSS per site [MiB] | CPU per process [%] | load avg | left |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in points:
        if p.error:
            lines.append(
                f"| {p.sites} | {p.per_process} | | {p.window_s:g} | failed: {p.error} | | | | | | | | | |"
            )
            continue
        cpu = ", ".join(f"{c:.0f}" for c in p.cpu_percent)
        lines.append(
            f"| {p.sites} | {p.per_process} | {-(-p.sites // p.per_process)} | {p.window_s:g} | "
            f"{p.start_s:.0f} | "
            f"{p.startup_overruns} | {p.window_overruns} | {p.up} | {p.reachable} | {p.rss_mib:.0f} | "
            f"{p.rss_mib / p.sites:.0f} | {cpu} | {p.load} | {p.left} |"
        )
    ok = [p.sites for p in points if not p.error and p.window_overruns == 0 and p.reachable == p.sites]
    lines += [
        "",
        f"Largest N measured with 0 overruns in the window and every site reachable: "
        f"{max(ok) if ok else 'none'}.",
        "",
    ]
    return "\n".join(lines)


def run(
    ns: tuple[int, ...],
    window_s: float,
    log: Callable[[str], None],
    work: Path | None = None,
    per_process: int = PER_PROCESS,
) -> str:
    work = work or ROOT / "var" / "bench-fleet"
    work.mkdir(parents=True, exist_ok=True)
    points = []
    for n in ns:
        log(f"fleet of {n} sites, {window_s:g} s window:")
        points.append(asyncio.run(measure(n, window_s, work, log, per_process)))
    return markdown(points)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sites", default=",".join(map(str, DEFAULT_NS)))
    parser.add_argument("--window", type=float, default=600.0)
    parser.add_argument("--output", type=Path, required=True)
    parser.add_argument("--per-process", type=int, default=PER_PROCESS)
    args = parser.parse_args(argv)
    ns = tuple(int(x) for x in args.sites.split(","))
    text = run(
        ns, args.window, lambda line: print(line, file=sys.stderr, flush=True), per_process=args.per_process
    )
    args.output.write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
