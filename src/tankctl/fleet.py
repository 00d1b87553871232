"""``tankctl fleet up | status | down``: many independent sites, many sites per process.

``fleet up`` runs in the foreground as ``tankctl up`` does (decision 0018): Ctrl-C or SIGTERM
stops the fleet; it also writes pid files (``fleet.pid`` and one per hosting process), so
``fleet status`` and ``fleet down`` work from any other shell. Lifecycle (decision 0057):

1. **Preflight**, before anything is started or written: the options (``--sites`` >= 1, ports
   within 1..65535), no ``fleet up`` already running from the fleet directory, every one of the
   fleet's ``3 N`` ports free (bound as the servers will bind them), the PKI and the CLI's
   login complete (created on first run, :func:`tanklab_io.home.provision`): one PKI for the
   whole fleet. A failure is one line (:class:`FleetError`); nothing was started.
2. **Start** ``ceil(N / K)`` hosting processes (``python -m tankctl fleet host``, each in its
   own session, pid file ``hosts/host-<j>.pid``, log ``hosts/host-<j>.log``), all at once; each
   starts its sites bottom-up (:mod:`tankctl.fleet_host`). ``up`` waits until every site says
   ``up`` in its process's status file. A site that fails, or a process that dies, during
   start-up stops the fleet (exit 1) with the reason.
3. **Run**: one line per event (a site failed, a process died). A process that dies stops the
   fleet (exit 1); a failed site is reported and the others go on.
4. **Stop**, the one path for a signal, a death, a start-up failure and an exception: SIGTERM to
   every process (each stops its sites PLC first, and the plants checkpoint), SIGKILL to the
   process groups still there after :data:`STOP_GRACE_S`; pid files are removed.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tankctl.fleet_layout import FLEET_TIERS, FleetError, FleetLayout
from tankctl.ports import unbindable
from tankctl.up_process import Tier, running_pid, terminate
from tanklab.errors import TanklabError
from tanklab_io.home import SecurityHome, provision

READY_TIMEOUT_S = 120.0
"""Bound of the start-up of one hosting process's sites, plus :data:`READY_PER_SITE_S` each
(a site's three servers build their address spaces one after the other: 5 to 15 s of a loaded
core each)."""
READY_PER_SITE_S = 20.0
STOP_GRACE_S = 60.0
"""From SIGTERM to SIGKILL of the hosting processes [s] (a process stops its sites in parallel)."""
REAP_S = 5.0
DOWN_TIMEOUT_S = STOP_GRACE_S + REAP_S + 10.0
"""How long ``fleet down`` waits for ``fleet up`` to have stopped everything [s]."""


def check_ports(host: str, ports: Sequence[int]) -> None:
    """Bind every port as the servers will (SO_REUSEADDR); FleetError naming the first busy one."""
    for port in ports:
        try:
            what = unbindable(host, port)
        except socket.gaierror as e:
            raise FleetError(f"--host {host}: {e.strerror or e}") from None
        if what:
            raise FleetError(f"port {port} on {host} {what}; nothing started (--base-port picks other ports)")


def host_pids(layout: FleetLayout) -> dict[int, int]:
    """The running hosting processes of ``layout`` by their pid files: process index -> pid."""
    out = {}
    for j in range(layout.processes):
        pid = running_pid(layout.host_pid_file(j))
        if pid is not None:
            out[j] = pid
    return out


@dataclass
class Fleet:
    """The hosting processes ``fleet up`` runs for ``layout``."""

    layout: FleetLayout
    home: SecurityHome
    say: Callable[[str], None] = print
    procs: dict[int, Tier] = field(default_factory=dict)

    def __post_init__(self) -> None:
        fleet_dir = str(self.layout.fleet_dir)
        for j in range(self.layout.processes):
            # The base port names the fleet in the command line (as ``up``'s does its stack).
            args = ["fleet", "host", "--fleet-dir", fleet_dir, "--index", str(j)]
            args += ["--base-port", str(self.layout.base_port)]
            first = self.layout.hosted(j)[0]
            self.procs[j] = Tier(
                f"host-{j}",
                args,
                self.layout.url(first, "plc"),
                self.layout.port(first, "plant"),
                self.layout.host_log(j),
            )

    # ---- preflight ------------------------------------------------------------------------

    def preflight(self, hosts: Sequence[str]) -> list[str]:
        """Check everything before anything starts; lines to print. FleetError (one line)."""
        pid = running_pid(self.layout.pid_path)
        if pid is not None:
            raise FleetError(
                f"{self.layout.pid_path}: pid {pid} is running: a fleet already runs from "
                f"{self.layout.fleet_dir}; `tankctl fleet down` first or use another --fleet-dir"
            )
        for j in range(self.layout.processes):
            pid = running_pid(self.layout.host_pid_file(j))
            if pid is not None:
                raise FleetError(
                    f"{self.layout.host_pid_file(j)}: pid {pid} is running; `tankctl fleet down` first"
                )
        check_ports(self.layout.host, self.layout.ports)
        lines = []
        try:
            created = provision(self.home, hosts=hosts)
        except (OSError, TanklabError) as e:
            raise FleetError(f"{self.home.root}: cannot set up the PKI and users: {e}") from None
        if created is not None:
            lines.append(
                f"first run: created the PKI in {self.home.pki.root} and user 'engineer' (role Engineer); "
                f"its password is in {self.home.credentials_file} (0600)"
            )
        return lines

    def claim(self) -> None:
        """Write ``fleet.pid`` and ``fleet.json``; remove stale pid and status files."""
        try:
            self.layout.hosts_dir.mkdir(parents=True, exist_ok=True)
            for stale in [
                *self.layout.hosts_dir.glob("host-*.pid"),
                *self.layout.hosts_dir.glob("host-*.json"),
            ]:
                stale.unlink()
            self.layout.save()
            self.layout.pid_path.write_text(f"{os.getpid()}\n", encoding="utf-8")
        except OSError as e:
            raise FleetError(
                f"{self.layout.fleet_dir}: cannot write the fleet directory: {e.strerror or e}"
            ) from None

    def release(self) -> None:
        if running_pid(self.layout.pid_path) in (None, os.getpid()):
            with contextlib.suppress(FileNotFoundError):
                self.layout.pid_path.unlink()

    # ---- start, run, stop ---------------------------------------------------------------------

    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        for var in ("TANKLAB_PLANT_URL", "TANKLAB_PLC_URL", "TANKLAB_SUPERVISOR_URL", "TANKLAB_PORT"):
            env.pop(var, None)
        return env

    def states(self, j: int) -> dict[str, dict[str, Any]]:
        """Site states from process ``j``'s status file (empty until it wrote one)."""
        return read_status(self.layout, j).get("sites", {})

    async def start(self, stop: asyncio.Event) -> bool:
        """Start every hosting process and wait until each of their sites serves.

        False when ``stop`` was set first; FleetError (one line) when a process dies or a site
        fails or does not come up in time."""
        for proc in self.procs.values():
            if stop.is_set():
                return False
            await proc.start(self.env())
        pending = set(self.procs)
        deadline = time.monotonic() + READY_TIMEOUT_S + READY_PER_SITE_S * self.layout.per_process
        while pending:
            for j in sorted(pending):
                proc = self.procs[j]
                if not proc.running:
                    await proc.wait(1.0)
                    raise FleetError(
                        f"{proc.name} exited during start-up (exit {proc.exit_code}): "
                        f"{proc.reason()}; log {proc.log_path}"
                    )
                states = self.states(j)
                failed = [(i, s) for i, s in states.items() if s.get("state") == "failed"]
                if failed:
                    i, s = failed[0]
                    raise FleetError(
                        f"site {i} ({s.get('name')}) failed during start-up: {s.get('error')}; "
                        f"log {self.layout.site_dir(int(i)) / 'site.log'}"
                    )
                if len(states) == len(self.layout.hosted(j)) and all(
                    s.get("state") == "up" for s in states.values()
                ):
                    pending.discard(j)
                    sites = self.layout.hosted(j)
                    low, high = self.layout.port(sites[0], "plant"), self.layout.port(sites[-1], "supervisor")
                    pid = proc.proc.pid if proc.proc else "?"
                    self.say(
                        f"{proc.name:8s} pid {pid}: sites {sites[0]}..{sites[-1]} up "
                        f"(ports {low}..{high}; log {proc.log_path})"
                    )
            if not pending:
                break
            if time.monotonic() > deadline:
                raise FleetError(
                    f"sites of {', '.join(self.procs[j].name for j in sorted(pending))} not up in time"
                )
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), 0.5)
            if stop.is_set():
                return False
        return True

    def dead(self) -> list[Tier]:
        out = []
        for proc in self.procs.values():
            if proc.proc is not None and proc.proc.returncode is not None:
                proc.exit_code = proc.proc.returncode
                out.append(proc)
        return out

    async def stop(self) -> tuple[float, list[str]]:
        """SIGTERM to every process started, SIGKILL after STOP_GRACE_S; seconds and the killed."""
        t0 = time.monotonic()
        started = [p for p in self.procs.values() if p.proc is not None]
        killed = await terminate(started, STOP_GRACE_S, REAP_S)
        return time.monotonic() - t0, killed


async def run_fleet(fleet: Fleet, stop: asyncio.Event, cause: Callable[[], str]) -> int:
    """Start the fleet, run until ``stop`` or a process's death, stop it; the exit code."""
    say = fleet.say
    code, why = 0, "exception"
    try:
        try:
            started = await fleet.start(stop)
        except FleetError as e:
            say(f"tankctl: {e}")
            why, code = "start-up failed", 1
            return code
        if not started:
            why = f"{cause()} during start-up"
            return code
        lay = fleet.layout
        pids = ", ".join(str(p.proc.pid) for p in fleet.procs.values() if p.proc is not None)
        say(
            f"started: fleet of {lay.sites} sites in {lay.processes} processes (pids {pids}), "
            f"ports {lay.base_port}..{lay.ports[-1]}; Ctrl-C or SIGTERM stops the fleet"
        )
        reported: set[str] = set()
        while not stop.is_set():
            dead = fleet.dead()
            if dead:
                for p in dead:
                    say(f"{p.name} died (exit {p.exit_code}): {p.reason()}; log {p.log_path}")
                why, code = f"{', '.join(p.name for p in dead)} died", 1
                break
            for j in fleet.procs:
                for i, s in fleet.states(j).items():
                    if s.get("state") == "failed" and i not in reported:
                        reported.add(i)
                        say(f"site {i} ({s.get('name')}) failed: {s.get('error')}; the other sites go on")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), 1.0)
        else:
            why = cause()
        return code
    finally:
        say(f"stopping ({why})")
        seconds, killed = await asyncio.shield(fleet.stop())
        extra = f"; killed after {STOP_GRACE_S:g} s: {', '.join(killed)}" if killed else ""
        say(f"stopped in {seconds:.1f} s{extra}")
        fleet.release()


# ---- status -----------------------------------------------------------------------------------


def read_status(layout: FleetLayout, j: int) -> dict[str, Any]:
    """Process ``j``'s status file, or {} (none yet, or being replaced)."""
    try:
        data = json.loads(layout.host_status_file(j).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def proc_rss_bytes(pid: int) -> int | None:
    """Resident set size of ``pid`` [bytes] (Linux /proc), None when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


@dataclass
class SiteReach:
    """What ``fleet status`` read from one site: per tier whether it answered, and the PLC's
    overrun counter."""

    index: int
    answered: dict[str, bool]
    overruns: int | None

    @property
    def reachable(self) -> bool:
        return all(self.answered.values())


async def probe_site(layout: FleetLayout, i: int, home: SecurityHome, timeout_s: float) -> SiteReach:
    """Read each tier's probe node (and the PLC's overrun counter) of site ``i`` over OPC UA."""
    from tanklab import paths
    from tanklab.config import load_site
    from tanklab.tags import plant_tags, plc_tags, supervisor_tags, tags_by_path
    from tanklab_io.ua_client import Link
    from tanklab_io.ua_client_security import cli_identity, client_setup

    site = load_site(layout.config_path)
    identity = cli_identity(home)
    builders = {"plant": plant_tags, "plc": plc_tags, "supervisor": supervisor_tags}
    answered: dict[str, bool] = {}
    overruns: int | None = None
    for tier in FLEET_TIERS:
        if tier == "supervisor" and site.supervisor is None:
            continue
        by_path = tags_by_path(builders[tier](site))
        wanted = [paths.PROBE_PATHS[tier]] + ([paths.plc.overruns] if tier == "plc" else [])
        link = Link(
            layout.url(i, tier),
            {p: by_path[p] for p in wanted},
            name=f"site {i} {tier}",
            setup=client_setup(identity),
            timeout_s=timeout_s,
        )
        try:
            if not await link.ensure():
                raise ConnectionError(f"{layout.url(i, tier)} does not answer")
            values = await link.read(wanted)
            answered[tier] = True
            if tier == "plc":
                overruns = int(values[1].Value.Value)
        except Exception:
            answered[tier] = False
        finally:
            with contextlib.suppress(Exception):
                await link.close()
    return SiteReach(i, answered, overruns)


async def probe_fleet(
    layout: FleetLayout, home: SecurityHome, timeout_s: float = 5.0, parallel: int = 8
) -> list[SiteReach]:
    """:func:`probe_site` for every site, ``parallel`` at a time."""
    gate = asyncio.Semaphore(parallel)

    async def one(i: int) -> SiteReach:
        async with gate:
            return await probe_site(layout, i, home, timeout_s)

    return list(await asyncio.gather(*(one(i) for i in range(layout.sites))))


def status_lines(
    layout: FleetLayout, reach: list[SiteReach] | None, each: bool = False
) -> tuple[list[str], bool]:
    """``fleet status``'s lines and whether every site is up and reachable."""
    lines = [
        f"fleet {layout.fleet_dir}: {layout.sites} sites of {layout.config_path} "
        f"in {layout.processes} processes "
        f"({layout.per_process} sites per process), ports {layout.base_port}..{layout.ports[-1]}"
    ]
    up_pid = running_pid(layout.pid_path)
    pids = host_pids(layout)
    lines.append(f"fleet up: pid {up_pid}" if up_pid is not None else "fleet up: not running")
    states: dict[int, dict[str, Any]] = {}
    total_rss = 0
    for j in range(layout.processes):
        status = read_status(layout, j)
        sites = layout.hosted(j)
        for i, s in status.get("sites", {}).items():
            states[int(i)] = s
        pid = pids.get(j)
        rss = proc_rss_bytes(pid) if pid is not None else None
        if pid is None or rss is None:
            lines.append(f"host-{j}: not running (sites {sites[0]}..{sites[-1]})")
            continue
        total_rss += rss
        lines.append(
            f"host-{j}: pid {pid}, sites {sites[0]}..{sites[-1]}, RSS {rss / 2**20:.0f} MiB "
            f"({rss / 2**20 / len(sites):.1f} MiB per site), "
            f"CPU {status.get('cpu_percent', 0.0):.0f} % of a core"
        )
    up = sum(1 for s in states.values() if s.get("state") == "up")
    failed = sorted(i for i, s in states.items() if s.get("state") == "failed")
    counted = sum(int(s.get("overruns", 0)) for s in states.values())
    line = f"sites: {up} of {layout.sites} up, {len(failed)} failed"
    ok = up == layout.sites and len(pids) == layout.processes
    if reach is not None:
        reachable = [r for r in reach if r.reachable]
        line += f", {len(reachable)} reachable (plant, PLC and supervisor answered a read)"
        ok = ok and len(reachable) == layout.sites
        read_overruns = [r.overruns for r in reach if r.overruns is not None]
        counted = sum(read_overruns) if len(read_overruns) == layout.sites else counted
    lines.append(line)
    worst = max(states.items(), key=lambda kv: int(kv[1].get("overruns", 0)), default=None)
    lines.append(
        f"PLC overruns: {counted} in all"
        + (f" (most: site {worst[0]}, {worst[1].get('overruns')})" if worst and counted else "")
    )
    if total_rss:
        lines.append(
            f"RSS: {total_rss / 2**20:.0f} MiB in all, {total_rss / 2**20 / layout.sites:.1f} MiB per site"
        )
    by_index = {r.index: r for r in reach or []}
    for i in range(layout.sites):
        s = states.get(i, {})
        r = by_index.get(i)
        bad = s.get("state") != "up" or (r is not None and not r.reachable)
        if each or bad:
            tiers = " ".join(f"{t} {'ok' if a else 'no answer'}" for t, a in r.answered.items()) if r else ""
            err = f" ({s.get('error')})" if s.get("error") else ""
            lines.append(
                f"site {i} {layout.site_name(i)}: {s.get('state', 'unknown')}{err}, "
                f"scans {s.get('scans', 0)}, "
                f"overruns {s.get('overruns', 0)}{', ' + tiers if tiers else ''}"
            )
    return lines, ok


# ---- down -------------------------------------------------------------------------------------


async def fleet_down(layout: FleetLayout, say: Callable[[str], None] = print) -> int:
    """Stop the fleet of ``layout``: SIGTERM to ``fleet up`` (which stops its processes) and
    wait; then SIGTERM, and after STOP_GRACE_S SIGKILL, to any hosting process left (a ``fleet
    up`` killed with SIGKILL leaves them). Returns how many processes are left (0)."""
    t0 = time.monotonic()
    up_pid = running_pid(layout.pid_path)
    if up_pid is not None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(up_pid, signal.SIGTERM)
        say(f"sent SIGTERM to fleet up (pid {up_pid})")
        while running_pid(layout.pid_path) == up_pid and time.monotonic() - t0 < DOWN_TIMEOUT_S:
            await asyncio.sleep(0.2)
    left = host_pids(layout)
    if left:
        say(f"stopping {len(left)} hosting processes left: pids {', '.join(map(str, left.values()))}")
        for pid in left.values():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pid, signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        while host_pids(layout) and time.monotonic() < deadline:
            await asyncio.sleep(0.2)
        for pid in host_pids(layout).values():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pid, signal.SIGKILL)
        await asyncio.sleep(0.5)
        for j in range(layout.processes):
            if running_pid(layout.host_pid_file(j)) is None:
                with contextlib.suppress(FileNotFoundError):
                    layout.host_pid_file(j).unlink()
    remaining = len(host_pids(layout)) + (1 if running_pid(layout.pid_path) is not None else 0)
    if up_pid is None and not left:
        say(f"no fleet runs from {layout.fleet_dir}")
    else:
        say(f"stopped in {time.monotonic() - t0:.1f} s; {remaining} processes left")
    return remaining


def hosts_for_pki(host: str) -> list[str]:
    return sorted({"localhost", "127.0.0.1", host, socket.gethostname()})
