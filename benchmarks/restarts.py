"""Each tier SIGKILLed and restarted by ``tankctl up`` under a running stack (issue 21).

The stack is started the way users do: ``tankctl up`` (line mode) on a free base port, its own
run directory, speed 1, the three-tank Energies site (``configs/three_tank_energies_sim.yaml``)
with two changes written to a copy: the tanks start at the operating point with the equilibrium
pump flows (so the run does not spend minutes filling empty tanks), and ``stack.restart`` with
``max_restarts`` = the number of kills per tier (``up`` restarts a dead tier instead of stopping
the stack). The plant's watchdog keeps the shipped safe state ``off``.

Once the loops hold their setpoints, a set of operator and engineer settings is applied through
OPC UA as the engineer (a leak, a valve opening, a disturbance, a sensor fault on the untracked
LT3, both setpoints, an engineer SP limit, an engineer's gains on LIC1, the supervisor in
ADAPTIVE_PID adapting LIC2). No scenario file runs: the benchmark drives the settings itself,
the loops regulating and the supervisor adapting all the while.

Then, round by round, the PLC, the plant and the supervisor are each SIGKILLed (by the pid in
``up``'s pid file, one process at a time); the benchmark waits for ``up`` to restart the tier and
for the stack to be healthy again (the tier answers and its neighbours are linked to it again),
and compares every writable and state node it applied or that the restart could change (modes,
gain sources, interlock latches) with its value before the kill. During a PLC restart it samples
the true levels (``Plant.T1.Level``, ``Plant.T2.Level``) from the kill until ``POST_S`` after the
PLC is healthy again; the deviation is from the level just before the kill. After every restart
it counts the tankctl processes per tier port (exactly one each), and after the final SIGTERM of
``up`` it counts what is left (none) and the pid files left.

Supervisor-owned values are not settings: LIC2's gains and gain source while the supervisor
adapts them change by design when the supervisor is lost (the PLC's watchdog falls back to the
fixed gains) and whenever the supervisor pushes a new set; they are reported apart.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import math
import os
import signal
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import yaml
from asyncua import ua

from benchmarks.common import Goal, cli_setup, fmt
from benchmarks.procs import bench_process
from tanklab.enums import GainSource, SensorFault, SupervisorMode
from tanklab.errors import LinkError
from tanklab.tags import Tag, plant_tags, plc_tags, supervisor_tags, tags_by_path
from tanklab_io.ua_client import Link
from tanklab_testing.procs import alive, free_base_port, tankctl_pids
from tanklab_testing.sites import site_config

TIERS = ("plc", "plant", "supervisor")
"""The order of one round of kills."""
RESTARTS = 20
SPEED = 1.0
POST_S = 10.0
"""How long the levels are still sampled after a restarted PLC is healthy again [s wall = s model]."""
HEALTHY_TIMEOUT_S = 120.0
SETTLE_TIMEOUT_S = 300.0
SETTLE_BAND_M = 0.002
"""Both controlled levels within this of their setpoints before the first kill [m]."""
STILL_S = 30.0
STILL_BAND_M = 0.001
"""Steady before the first kill: each level moved less than this over STILL_S [m]."""
QUIET_S = 20.0
RECOVER_BAND_M = 0.002
"""Before the next kill both levels are back within this of their pre-kill values (bounded) [m]."""
RECOVER_TIMEOUT_S = 30.0
SAMPLE_S = 0.2
DEVIATION_TARGET_M = 0.005

ENGINEER_GAINS = (5.0e-4, 6.0e-6, -1.42e-4)
"""LIC1's engineer gains (near the config's fixed ones, so the loop behaves the same)."""
PLANT_WRITES: dict[str, Any] = {
    "Plant.T2.Leak": 0.1,
    "Plant.V32.Opening": 0.8,
    "Plant.T3.Disturbance": 2.0e-6,
    "Plant.LT3.Fault": int(SensorFault.BIAS),
    "Plant.LT3.FaultValue": 0.005,
}
PLC_WRITES: dict[str, Any] = {"PLC.LIC1.SP": 0.405, "PLC.LIC2.SP": 0.205, "PLC.LIC2.SPHigh": 0.5}
LEVELS = ("Plant.T1.Level", "Plant.T2.Level")
THETA = "Supervisor.RLS.LIC2.Theta"
ACCEPTED = "Supervisor.RLS.LIC2.Accepted"
REJECTED = "Supervisor.RLS.LIC2.Rejected"
SUPERVISOR_OWNED = tuple(f"PLC.LIC2.{g}" for g in ("Kp", "Ki", "Kd", "GainSource"))
"""LIC2's gains while the supervisor adapts them: the supervisor's, not a setting."""


def settings_paths(site_tags: dict[str, dict[str, Tag]]) -> dict[str, list[str]]:
    """Per tier, the nodes compared before and after every restart: every writable variable of
    the plant (pump commands aside: the PLC's), every retentive PLC node (SP, limits, mode,
    manual MV, gains and their source) and the interlock latches, and the supervisor's mode."""
    plant = [
        p
        for p, t in site_tags["plant"].items()
        if t.kind == "variable" and t.writable and not p.endswith(".Command")
    ]
    loops = sorted({p.split(".")[1] for p in site_tags["plc"] if p.startswith("PLC.LIC")})
    items = ("SP", "SPLow", "SPHigh", "Mode", "ManualMV", "Kp", "Ki", "Kd", "GainSource")
    plc = [f"PLC.{lp}.{i}" for lp in loops for i in items]
    plc += [p for p, t in site_tags["plc"].items() if p.startswith("PLC.Interlock.") and t.kind == "variable"]
    return {"plant": plant, "plc": plc, "supervisor": ["Supervisor.Mode"]}


@dataclass
class Restart:
    """One SIGKILL and what followed."""

    tier: str
    index: int
    seconds: float
    """From the SIGKILL to the stack healthy again [s wall]."""
    tier_s: float
    """From the SIGKILL to the tier itself back (the PLC: scanning with its field link) [s wall]."""
    lost: list[str]
    """Settings whose value after the restart differs from before: ``path: before -> after``."""
    owned: list[str]
    """Supervisor-owned values that changed (by design: fallback or a new push)."""
    processes: dict[str, int]
    """tankctl processes per tier port right after the stack was healthy again."""
    deviation_m: float | None = None
    """PLC restarts: largest |level - pre-kill level| of T1 and T2 over the window [m]."""
    deviation_by_tank_m: tuple[float, float] | None = None
    sp_deviation_m: float | None = None
    """PLC restarts: largest |level - setpoint| of T1 and T2 over the window [m]."""
    pumps_stopped: bool = False
    """The plant's watchdog stopped the pumps during the window."""
    theta_change: float | None = None
    """PLC restarts: largest change of LIC2's RLS estimate over the window (fraction of the gain
    box's width)."""
    theta: tuple[list[float], list[float]] | None = None
    """PLC restarts: LIC2's RLS estimate just before the kill and at the window's end."""
    pushes: int = 0
    """Gain sets the supervisor had accepted on LIC2 during the window."""
    refusals: int = 0
    """Candidate gain sets rejected (by a guard or the PLC) on LIC2 during the window."""
    killed_at: float = float("nan")
    """Wall-clock time of the SIGKILL (``time.time()``, to find the restart in the tier's log)."""
    phases_s: tuple[float, float, float] | None = None
    """PLC restarts, from its log: SIGKILL -> "warm restart from" (up's poll, the interpreter's
    start, imports, config), -> "pump commands held" (field link, the read of the plant and the
    write that refreshes its watchdog, decision 0026), -> "PLC server listening" (its OPC UA
    server, before the first scan) [s]."""


@dataclass
class RestartsResult:
    restarts: list[Restart] = field(default_factory=list)
    baseline_m: float = float("nan")
    """Largest level deviation over a quiet window as long as a PLC restart's, before any kill [m]."""
    theta_quiet_change: float | None = None
    """Largest change of LIC2's RLS estimate over the quiet window (a baseline; box fraction)."""
    settle_s: float = float("nan")
    left_after_stop: list[int] = field(default_factory=list)
    pid_files_left: list[str] = field(default_factory=list)
    up_exit: int | None = None
    up_lines: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    base: int = 0
    restarts_per_tier: int = RESTARTS
    tiers: list[str] = field(default_factory=lambda: list(TIERS))
    safe_state: str | None = None
    """Every pump's watchdog safe state in this run (None: the shipped config's, ``off``)."""
    load: tuple[float, float] = (float("nan"), float("nan"))
    """The machine's 1-minute load average at the start and at the end (2 cores here)."""


class Reader:
    """A link to one tier that is recreated after a failure and never backs off for long: the
    benchmark polls tiers that are being killed and restarted."""

    def __init__(self, url: str, tags: dict[str, Tag], name: str) -> None:
        self.url, self.tags, self.name = url, tags, name
        self.link: Link | None = None

    async def _ensure(self) -> Link | None:
        if self.link is None:
            self.link = Link(
                self.url,
                self.tags,
                name=self.name,
                setup=cli_setup(),
                timeout_s=2.0,
                backoff=lambda k, r: 0.1,
            )
        return self.link if await self.link.ensure() else None

    async def read(self, paths: Sequence[str]) -> dict[str, Any] | None:
        """Values of ``paths`` (Good status only), or None when the tier does not answer."""
        link = await self._ensure()
        if link is None:
            return None
        try:
            dvs = await link.read(paths)
        except LinkError:
            return None
        if not all(dv.StatusCode is None or dv.StatusCode.is_good() for dv in dvs):
            return None
        return {p: dv.Value.Value for p, dv in zip(paths, dvs, strict=True)}

    async def write(self, values: dict[str, Any]) -> None:
        link = await self._ensure()
        if link is None:
            raise RuntimeError(f"{self.url} does not answer")
        codes = await link.write(values)
        bad = {p: c.name for p, c in zip(values, codes, strict=True) if not c.is_good()}
        if bad:
            raise RuntimeError(f"writes refused: {bad}")

    async def call(self, method: str, *args: float) -> None:
        link = await self._ensure()
        if link is None:
            raise RuntimeError(f"{self.url} does not answer")
        await link.call(method, *(ua.Variant(a, ua.VariantType.Double) for a in args))

    async def close(self) -> None:
        if self.link is not None:
            await self.link.close()


def _differs(a: Any, b: Any) -> bool:
    if isinstance(a, list | tuple) or isinstance(b, list | tuple):
        return list(a or []) != list(b or [])
    return bool(a != b)


def box_change(a: Sequence[float] | None, b: Sequence[float] | None, widths: Sequence[float]) -> float | None:
    """max_i |b_i - a_i| / width_i: how far an estimate [Kp, Ki, Kd, ...] moved, as a fraction of
    the gain box's width of each gain (a relative change would explode on a gain near 0)."""
    if not a or not b or len(a) != len(b):
        return None
    w = [widths[i % len(widths)] for i in range(len(a))]
    return max(abs(y - x) / wi for x, y, wi in zip(a, b, w, strict=True))


class Bench:
    """The stack under test, its readers and the measurements."""

    def __init__(
        self, work: Path, restarts: int, log: Callable[[str], None], safe_state: str | None = None
    ) -> None:
        self.log = log
        self.n = restarts
        self.work = work
        self.base = free_base_port(3)
        work.mkdir(parents=True, exist_ok=True)
        self.config = site_config(work / "site.yaml", at_operating_point=True)
        data = yaml.safe_load(self.config.read_text(encoding="utf-8"))
        data["stack"] = {"restart": True, "max_restarts": restarts}
        if safe_state is not None:
            for pump in data["plant"]["pumps"]:
                pump["watchdog_safe_state"] = safe_state
        self.config.write_text(yaml.safe_dump(data), encoding="utf-8")
        self.run_dir = work / "var" / str(data["name"])
        from benchmarks.common import load

        site = load(self.config)
        self.tags = {
            "plant": tags_by_path(plant_tags(site)),
            "plc": tags_by_path(plc_tags(site)),
            "supervisor": tags_by_path(supervisor_tags(site)),
        }
        self.paths = settings_paths(self.tags)
        assert site.plc is not None
        box = next(lp.gain_box for lp in site.plc.loops if lp.name == "LIC2")
        assert box is not None
        self.box = [box.kp[1] - box.kp[0], box.ki[1] - box.ki[0], box.kd[1] - box.kd[0]]
        self.tier_up: float | None = None
        self.ports = {"plant": self.base, "plc": self.base + 1, "supervisor": self.base + 2}
        self.readers = {
            t: Reader(f"opc.tcp://127.0.0.1:{p}/tanklab/{t}", self.tags[t], f"bench-{t}")
            for t, p in self.ports.items()
        }
        self.up = bench_process(
            "up",
            [
                *("up", "--config", str(self.config), "--speed", f"{SPEED:g}", "--no-board"),
                *("--base-port", str(self.base), "--log-dir", str(work / "var")),
            ],
            work / "up.out",
            banner=False,
        )

    # ---- reading ---------------------------------------------------------------------------

    async def read(self, tier: str, paths: Sequence[str]) -> dict[str, Any] | None:
        return await self.readers[tier].read(paths)

    async def wait_for(self, what: str, cond: Callable[[], Any], timeout_s: float) -> None:
        """Poll ``cond()`` (awaitable, true when done) every SAMPLE_S, bounded."""
        end = time.monotonic() + timeout_s
        while not await cond():
            if not self.up.running:
                raise RuntimeError(f"tankctl up exited while waiting for {what} (see {self.up.log_path})")
            if time.monotonic() > end:
                raise RuntimeError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            await asyncio.sleep(SAMPLE_S)

    async def snapshot(self) -> dict[str, Any] | None:
        out: dict[str, Any] = {}
        for tier, paths in self.paths.items():
            got = await self.read(tier, paths)
            if got is None:
                return None
            out.update(got)
        sup = await self.read("supervisor", [ACCEPTED, REJECTED])
        if sup is None:
            return None
        out.update(sup)
        return out

    def pid(self, tier: str) -> int | None:
        try:
            return int((self.run_dir / f"{tier}.pid").read_text(encoding="utf-8").split()[0])
        except (OSError, ValueError, IndexError):
            return None

    def processes(self) -> dict[str, int]:
        found = tankctl_pids(list(self.ports.values()), flags=("--port",))
        return {t: len(found.get(p, [])) for t, p in self.ports.items()}

    async def healthy(self, tier: str, old_pid: int) -> bool:
        """The killed tier runs again (a new pid), answers, and its neighbours use it again.

        The first moment the tier itself is back (the plant or the supervisor answers; the PLC
        scans with a healthy field link, so it writes pump commands again) goes to ``tier_up``.
        """
        new = self.pid(tier)
        if new is None or new == old_pid or not alive(new):
            return False
        plc = await self.read("plc", ["PLC.Status.IoHealthy", "PLC.Supervisor.Alive"])
        plant = await self.read("plant", ["Plant.Sim.Time"])
        sup = await self.read("supervisor", ["Supervisor.PlcConnected"])
        own = {"plc": plc is not None and bool(plc["PLC.Status.IoHealthy"]), "plant": plant is not None}
        own["supervisor"] = sup is not None
        if own[tier] and self.tier_up is None:
            self.tier_up = time.monotonic()
        if plc is None or not plc["PLC.Status.IoHealthy"] or plant is None:
            return False
        if tier == "plant":
            return True
        return bool(plc["PLC.Supervisor.Alive"]) and sup is not None and bool(sup["Supervisor.PlcConnected"])

    # ---- the run ---------------------------------------------------------------------------

    async def settle(self, result: RestartsResult) -> None:
        t0 = time.monotonic()

        async def ready() -> bool:
            got = await self.read("plc", ["PLC.Status.IoHealthy", "PLC.LIC1.PV", "PLC.LIC2.PV"])
            sup = await self.read("supervisor", ["Supervisor.PlcConnected"])
            return bool(got and got["PLC.Status.IoHealthy"] and sup and sup["Supervisor.PlcConnected"])

        await self.wait_for("the stack serving and linked", ready, HEALTHY_TIMEOUT_S)
        self.log("  stack up; applying the settings")
        await self.readers["plant"].write(PLANT_WRITES)
        await self.readers["plc"].write(PLC_WRITES)
        await self.readers["plc"].call("PLC.LIC1.SetGains", *ENGINEER_GAINS)
        await self.readers["supervisor"].write({"Supervisor.Mode": int(SupervisorMode.ADAPTIVE_PID)})

        async def settled() -> bool:
            got = await self.read("plant", list(LEVELS))
            plc = await self.read("plc", ["PLC.LIC1.GainSource", "PLC.LIC2.GainSource"])
            if got is None or plc is None:
                return False
            return (
                abs(got["Plant.T1.Level"] - PLC_WRITES["PLC.LIC1.SP"]) < SETTLE_BAND_M
                and abs(got["Plant.T2.Level"] - PLC_WRITES["PLC.LIC2.SP"]) < SETTLE_BAND_M
                and plc["PLC.LIC1.GainSource"] == int(GainSource.ENGINEER)
            )

        await self.wait_for("T1 and T2 at their new setpoints", settled, SETTLE_TIMEOUT_S)
        # Steady: both levels stay within STILL_BAND_M over STILL_S (bounded; the run goes on
        # if not, and the quiet window below says how still it was).
        end = time.monotonic() + SETTLE_TIMEOUT_S
        while time.monotonic() < end:
            spread = await self.spread(STILL_S)
            if spread < STILL_BAND_M:
                break
        result.settle_s = time.monotonic() - t0
        # A quiet window as long as a typical PLC restart window: the deviation without a kill.
        theta0 = (await self.read("supervisor", [THETA])) or {}
        result.baseline_m = await self.spread(QUIET_S, from_start=True)
        theta1 = (await self.read("supervisor", [THETA])) or {}
        result.theta_quiet_change = box_change(theta0.get(THETA), theta1.get(THETA), self.box)
        quiet = f"quiet {QUIET_S:g} s window: {1e3 * result.baseline_m:.2f} mm"
        self.log(f"  settled in {result.settle_s:.0f} s; {quiet}")

    async def spread(self, seconds: float, *, from_start: bool = False) -> float:
        """Largest change of T1 or T2 over ``seconds`` [m]: max - min of each level, or with
        ``from_start`` the largest |level - first sample|."""
        seen: dict[str, list[float]] = {p: [] for p in LEVELS}
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            got = await self.read("plant", list(LEVELS))
            if got is not None:
                for p in LEVELS:
                    seen[p].append(float(got[p]))
            await asyncio.sleep(SAMPLE_S)
        if not all(seen.values()):
            return float("inf")
        if from_start:
            return max(abs(h - v[0]) for v in seen.values() for h in v)
        return max(max(v) - min(v) for v in seen.values())

    async def kill_one(self, tier: str, index: int) -> Restart:
        async def snap() -> dict[str, Any]:
            for _ in range(50):
                got = await self.snapshot()
                if got is not None:
                    return got
                await asyncio.sleep(SAMPLE_S)
            raise RuntimeError("the stack does not answer a snapshot")

        before = await snap()
        levels0 = await self.read("plant", list(LEVELS))
        theta0 = (await self.read("supervisor", [THETA])) or {}
        old = self.pid(tier)
        if old is None or not alive(old):
            raise RuntimeError(f"no live {tier} pid in {self.run_dir}")
        self.tier_up = None
        t_kill = time.monotonic()
        killed_at = time.time()
        os.kill(old, signal.SIGKILL)
        worst = [0.0, 0.0]
        from_sp = 0.0
        sps = (PLC_WRITES["PLC.LIC1.SP"], PLC_WRITES["PLC.LIC2.SP"])
        stopped = False

        async def sample() -> None:
            nonlocal stopped, from_sp
            if tier != "plc" or levels0 is None:
                return
            got = await self.read("plant", [*LEVELS, "Plant.Sim.Watchdog"])
            if got is not None:
                for i, p in enumerate(LEVELS):
                    worst[i] = max(worst[i], abs(got[p] - levels0[p]))
                    from_sp = max(from_sp, abs(got[p] - sps[i]))
                stopped = stopped or bool(got["Plant.Sim.Watchdog"])

        async def back() -> bool:
            await sample()
            return await self.healthy(tier, old)

        await self.wait_for(f"{tier} restarted and healthy", back, HEALTHY_TIMEOUT_S)
        seconds = time.monotonic() - t_kill
        tier_s = (self.tier_up or time.monotonic()) - t_kill
        processes = self.processes()
        after = await snap()
        if tier == "plc":
            end = time.monotonic() + POST_S
            while time.monotonic() < end:
                await sample()
                await asyncio.sleep(SAMPLE_S)
        theta1 = (await self.read("supervisor", [THETA])) or {}
        counts = (await self.read("supervisor", [ACCEPTED, REJECTED])) or {}
        lost: list[str] = []
        owned: list[str] = []
        engineer = int(GainSource.ENGINEER)
        adapted = engineer not in (before["PLC.LIC2.GainSource"], after["PLC.LIC2.GainSource"])
        for path in (p for ps in self.paths.values() for p in ps):
            if not _differs(before[path], after[path]):
                continue
            line = f"{path}: {before[path]!r} -> {after[path]!r}"
            if path in SUPERVISOR_OWNED and adapted:
                owned.append(line)
            else:
                lost.append(line)
        r = Restart(tier, index, seconds, tier_s, lost, owned, processes, killed_at=killed_at)
        if tier == "plc":
            r.deviation_m = max(worst)
            r.deviation_by_tank_m = (worst[0], worst[1])
            r.sp_deviation_m = from_sp
            r.pumps_stopped = stopped
            r.theta_change = box_change(theta0.get(THETA), theta1.get(THETA), self.box)
            r.theta = (list(theta0.get(THETA) or []), list(theta1.get(THETA) or []))
            r.pushes = int(counts.get(ACCEPTED, before[ACCEPTED])) - int(before[ACCEPTED])
            r.refusals = int(counts.get(REJECTED, before[REJECTED])) - int(before[REJECTED])
        if "Supervisor.Mode" in "".join(lost):
            # Not retained by the supervisor (reported): put it back so the next rounds adapt.
            await self.readers["supervisor"].write({"Supervisor.Mode": int(SupervisorMode.ADAPTIVE_PID)})
        await self.recover(levels0)
        return r

    async def recover(self, levels0: dict[str, Any] | None) -> None:
        """Bounded: until both levels are back near their pre-kill values (no error if not)."""
        if levels0 is None:
            return
        end = time.monotonic() + RECOVER_TIMEOUT_S
        while time.monotonic() < end:
            got = await self.read("plant", list(LEVELS))
            if got is not None and all(abs(got[p] - levels0[p]) < RECOVER_BAND_M for p in LEVELS):
                return
            await asyncio.sleep(SAMPLE_S)

    async def close(self) -> None:
        for reader in self.readers.values():
            with contextlib.suppress(Exception):
                await reader.close()


async def run(
    work: Path,
    log: Callable[[str], None],
    restarts: int = RESTARTS,
    *,
    tiers: Sequence[str] = TIERS,
    safe_state: str | None = None,
) -> RestartsResult:
    """The whole measurement; ``work`` gets the site copy, the run directory and the logs.

    ``tiers``: which tiers each round kills (in this order); ``safe_state``: every pump's
    ``watchdog_safe_state`` (None: the config's, the shipped ``off``)."""
    started = time.monotonic()
    bench = Bench(work, restarts, log, safe_state)
    result = RestartsResult(
        base=bench.base, restarts_per_tier=restarts, tiers=list(tiers), safe_state=safe_state
    )
    load0 = os.getloadavg()[0]
    log(f"restarts: tankctl up on base port {bench.base}, run directory {bench.run_dir}")
    await bench.up.start()
    try:
        await bench.settle(result)
        for k in range(1, restarts + 1):
            for tier in tiers:
                r = await bench.kill_one(tier, k)
                result.restarts.append(r)
                log(describe(r))
    except Exception as e:
        result.errors.append(f"{type(e).__name__}: {e}")
        log(f"  restarts FAILED: {e}")
    finally:
        await bench.close()
        result.up_exit = await bench.up.stop()
        result.left_after_stop = [
            p for ps in tankctl_pids([bench.base, bench.base + 1, bench.base + 2]).values() for p in ps
        ]
        for pid in result.left_after_stop:  # never leave them running (reported)
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        result.pid_files_left = sorted(p.name for p in bench.run_dir.glob("*.pid"))
        result.up_lines = bench.up.log_text().splitlines()[-12:]
        with contextlib.suppress(OSError):
            plc_phases(result, (bench.run_dir / "plc.log").read_text(encoding="utf-8", errors="replace"))
        result.wall_s = time.monotonic() - started
        result.load = (load0, os.getloadavg()[0])
        (work / "result.json").write_text(json.dumps(dataclasses.asdict(result), indent=1), encoding="utf-8")
    return result


PHASE_MARKS = ("warm restart from", "warm restart: pump commands held", "PLC server listening")


def _stamp(line: str) -> float | None:
    """The wall time of a tier's log line (``%(asctime)s``: local time, milliseconds) [s epoch]."""
    try:
        return datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
    except ValueError:
        return None


def plc_phases(result: RestartsResult, log_text: str) -> None:
    """Fill each PLC restart's ``phases_s`` from the PLC's log: the first line of each phase
    after its SIGKILL."""
    marks = [(t, line) for line in log_text.splitlines() if (t := _stamp(line)) is not None]
    for r in result.restarts:
        if r.tier != "plc" or not math.isfinite(r.killed_at):
            continue
        at: list[float] = []
        t0 = r.killed_at
        for mark in PHASE_MARKS:
            t = next((t for t, line in marks if t >= t0 and mark in line), None)
            if t is None:
                break
            at.append(t)
            t0 = t
        if len(at) == 3:
            r.phases_s = (at[0] - r.killed_at, at[1] - at[0], at[2] - at[1])


def describe(r: Restart) -> str:
    """One progress line for a restart."""
    line = f"  {r.tier} kill {r.index}: back after {r.tier_s:.1f} s, healthy after {r.seconds:.1f} s"
    line += f", lost {len(r.lost)}" + (f" ({'; '.join(r.lost)})" if r.lost else "")
    if r.deviation_by_tank_m is not None and r.sp_deviation_m is not None:
        t1, t2 = (1e3 * d for d in r.deviation_by_tank_m)
        line += f", level deviation T1 {t1:.2f} T2 {t2:.2f} mm (from SP {1e3 * r.sp_deviation_m:.2f} mm)"
        line += f", theta change {fmt(r.theta_change or 0.0)}, pushes {r.pushes}, refused {r.refusals}"
        line += ", pumps stopped by the watchdog" if r.pumps_stopped else ""
    return line + f"; processes {r.processes}"


def goals(result: RestartsResult) -> list[Goal]:
    """Issue 21's three targets for the restarts."""
    n = {t: sum(r.tier == t for r in result.restarts) for t in TIERS}
    done = ", ".join(f"{t} {k}" for t, k in n.items())
    lost = [r for r in result.restarts if r.lost]
    devs = [r.deviation_m for r in result.restarts if r.deviation_m is not None]
    complete = not result.errors and all(k == result.restarts_per_tier for k in n.values())
    worst = max(devs) if devs else float("nan")
    over = sum(d > DEVIATION_TARGET_M for d in devs)
    stopped = sum(
        r.pumps_stopped
        for r in result.restarts
        if r.deviation_m is not None and r.deviation_m > DEVIATION_TARGET_M
    )
    tiers_lost = sorted({r.tier for r in lost})
    return [
        Goal(
            f"settings lost over {result.restarts_per_tier} SIGKILL restarts per tier (speed 1)",
            "0",
            f"{sum(len(r.lost) for r in result.restarts)} (restarts: {done})",
            (not lost) if complete else None,
            f"lost on {', '.join(tiers_lost)} restarts (section 10)" if lost else "",
        ),
        Goal(
            "largest level deviation during a PLC restart",
            "<= 5 mm",
            f"{fmt(1e3 * worst)} mm ({over} of {len(devs)} over)",
            (worst <= DEVIATION_TARGET_M) if devs else None,
            f"{stopped} of the {over} over had the plant's watchdog stop the pumps (section 10)"
            if over
            else "",
        ),
        Goal(
            "tankctl processes left after the stop; one per tier after every restart",
            "0; 1",
            f"{len(result.left_after_stop)}; "
            + (
                "1 each" if all(set(r.processes.values()) == {1} for r in result.restarts) else "not always 1"
            ),
            not result.left_after_stop and all(set(r.processes.values()) == {1} for r in result.restarts),
        ),
    ]


def _summary(values: Sequence[float]) -> str:
    if not values:
        return "-"
    return f"{fmt(statistics.median(values))} / {fmt(max(values))}"


def markdown(result: RestartsResult) -> str:
    """The section of docs/benchmarks.md."""
    by_tier = {t: [r for r in result.restarts if r.tier == t] for t in result.tiers}
    plc = by_tier.get("plc", [])
    devs = [1e3 * r.deviation_m for r in plc if r.deviation_m is not None]
    if result.safe_state is not None:
        lines = [
            f"### 10b. The PLC alone, every pump's watchdog safe state `{result.safe_state}`",
            "",
            f"The same stack, settings and waits with `plant.pumps[].watchdog_safe_state: "
            f"{result.safe_state}` (decision 0019's remedy for a PLC restart gap longer than the "
            f"plant's command timeout); each round kills only the {', '.join(result.tiers)}.",
        ]
    else:
        lines = [
            "## 10. Restarts under a running stack (`tankctl up`, speed 1)",
            "",
            "`benchmarks.restarts` (`python -m benchmarks.run --only restarts`): `tankctl up --speed 1` "
            "on the three-tank Energies site (a copy of `configs/three_tank_energies_sim.yaml` starting "
            f"at the operating point, `stack.restart: true`, `max_restarts: {result.restarts_per_tier}`; "
            "the plant's watchdog keeps the shipped safe state `off`, 10 s). Settings applied through "
            "OPC UA as the engineer before the first kill: T2 leak 0.1, V32 opening 0.8, T3 disturbance "
            "2e-6 m^3/s, a 5 mm BIAS fault on LT3, setpoints 0.405 / 0.205 m, LIC2 SPHigh 0.5 m, engineer "
            "gains on LIC1, the supervisor in ADAPTIVE_PID adapting LIC2; no scenario file (the benchmark "
            "drives the settings itself). Each round SIGKILLs the PLC, the plant and the supervisor, one "
            "at a time (the pid in `up`'s pid file), waits for `up` to restart it and for the stack to be "
            "healthy (the tier answers, the PLC's IO is healthy, PLC and supervisor linked), then compares "
            "every compared node (the plant's writable nodes, the PLC's retentive nodes and interlock "
            "latches, `Supervisor.Mode`) with its value before the kill.",
        ]
    lines += [
        "",
        "| tier | restarts | settings lost | kill -> tier back, median / max [s] "
        "| kill -> stack healthy, median / max [s] | processes per tier after each restart "
        "| supervisor-owned changes |",
        "|---|---|---|---|---|---|---|",
    ]
    for tier, rs in by_tier.items():
        procs = sorted({tuple(sorted(r.processes.items())) for r in rs})
        proc_text = "; ".join(", ".join(f"{t} {n}" for t, n in p) for p in procs) or "-"
        lines.append(
            f"| {tier} | {len(rs)} | {sum(len(r.lost) for r in rs)} | {_summary([r.tier_s for r in rs])} "
            f"| {_summary([r.seconds for r in rs])} "
            f"| {proc_text} | {sum(len(r.owned) for r in rs)} |"
        )
    lost = [f"{r.tier} kill {r.index}: {x}" for r in result.restarts for x in r.lost]
    kinds: dict[str, int] = {}
    for r in result.restarts:
        for x in r.lost:
            key = f"{r.tier}: {x.split(':')[0]}"
            kinds[key] = kinds.get(key, 0) + 1
    stopped = sum(r.pumps_stopped for r in plc)
    lines += [
        "",
        f"PLC restarts: largest deviation of T1 or T2 from its level just before the kill, from the kill "
        f"until {POST_S:g} s after the PLC is healthy again, median / max **{_summary(devs)} mm** "
        f"(target <= {1e3 * DEVIATION_TARGET_M:g} mm; {sum(d > 1e3 * DEVIATION_TARGET_M for d in devs)} of "
        f"{len(devs)} over); the plant's watchdog stopped the pumps in {stopped} of {len(plc)}. A quiet "
        f"20 s window before the first kill: {1e3 * result.baseline_m:.2f} mm. Once the PLC has been "
        "away for the plant's command timeout (10 s) the watchdog puts the pumps in their safe state; "
        "with `off`, T1 then falls by its outflow alone, about 2 mm/s here (Q1 about 3.0e-5 m^3/s over "
        "0.0154 m^2), so a gap 3 s longer than the timeout already costs about 5 mm.",
        "",
        f"Settings lost: **{len(lost)}** in {len(result.restarts)} restarts"
        + (": " + ", ".join(f"{k} ({n}x)" for k, n in sorted(kinds.items())) if kinds else "")
        + ".",
        f"After the final SIGTERM of `up` (exit {result.up_exit}): **{len(result.left_after_stop)}** "
        f"tankctl processes left on the stack's ports, pid files left: "
        f"{', '.join(result.pid_files_left) or 'none'}.",
        "",
    ]
    phases = [r.phases_s for r in plc if r.phases_s is not None]
    if phases:
        start, link, serve = ([p[i] for p in phases] for i in range(3))
        held = [a + b for a, b in zip(start, link, strict=True)]
        gap = [sum(p) for p in phases]
        lines += [
            "Where a PLC restart's gap goes (its log; median / max, s): from the SIGKILL to "
            f"\"warm restart from\" (`up`'s 1 s poll, the interpreter's start, imports, config) "
            f"{_summary(start)}; the field link, the read of the plant and the write-back that "
            f'refreshes its watchdog ("pump commands held", decision 0026) {_summary(link)}; its OPC '
            f'UA server until "listening", before the first scan, {_summary(serve)}; total '
            f"{_summary(gap)}. The pumps were held {_summary(held)} after the SIGKILL "
            f"({sum(h > 10.0 for h in held)} of {len(held)} later than the plant's 10 s command timeout).",
            "",
        ]
    thetas = [r.theta_change for r in plc if r.theta_change is not None]
    if thetas:
        off = [r.theta_change for r in plc if r.theta_change is not None and r.pumps_stopped]
        on = [r.theta_change for r in plc if r.theta_change is not None and not r.pumps_stopped]
        quiet = float("nan") if result.theta_quiet_change is None else result.theta_quiet_change
        lines += [
            "RLS across a PLC restart (the supervisor stays up, ADAPTIVE_PID on LIC2): largest change "
            "of a gain in `Supervisor.RLS.LIC2.Theta` over the restart window, as a fraction of LIC2's "
            f"gain-box width, median / max {_summary(thetas)}: {_summary(off)} over the {len(off)} "
            f"restarts whose gap let the watchdog stop the pumps, {_summary(on)} over the {len(on)} "
            f"others; {fmt(quiet)} over the quiet {QUIET_S:g} s "
            f"window before the first kill. Gain sets accepted on LIC2 during the windows "
            f"{sum(r.pushes for r in plc)}, refused {sum(r.refusals for r in plc)} (a restarted PLC "
            "refuses the supervisor's SetGains until it trusts the supervisor again, "
            "`watchdog.good_scans_to_accept`). The scan counter continues across a warm restart, so "
            "the adapter (`PidGainAdapter.observe`) forms a sample whose window spans the restart "
            "when the new PLC's first scan follows the last one the supervisor read, or repeats it "
            "(a SIGKILL lost the last retentive write: the repeat is ignored as a duplicate and the "
            "next scan is consecutive); it drops the window as a gap only when two or more writes "
            "were lost. The published nodes cannot separate that one sample from the recovery's "
            "ordinary samples that follow it.",
            "",
        ]
    if any("Supervisor.Mode" in x for r in result.restarts for x in r.lost):
        lines += [
            "`Supervisor.Mode` is not retentive: a restarted supervisor starts in its config's mode "
            "(here ADVISORY), so the engineer's ADAPTIVE_PID is lost at every supervisor restart; "
            "the benchmark writes it again after counting it. LIC2's gains then fall back (the "
            "PLC's supervisor watchdog) and are the supervisor's again after its next push: those "
            "are the supervisor-owned changes, not settings.",
            "",
        ]
    if result.errors:
        lines += [f"Errors: {'; '.join(result.errors)}", ""]
    lines.append(
        f"Wall time {result.wall_s / 60:.1f} min (settling {result.settle_s:.0f} s); the machine's 1-minute "
        f"load average {result.load[0]:.1f} at the start, {result.load[1]:.1f} at the end ({os.cpu_count()} "
        "cores; other sessions' work included)."
    )
    lines.append("")
    return "\n".join(lines)


def load_result(path: Path) -> RestartsResult:
    """A run's ``result.json`` back as a :class:`RestartsResult` (to render it again)."""
    data = json.loads(path.read_text(encoding="utf-8"))
    restarts = [Restart(**r) for r in data.pop("restarts")]
    for r in restarts:
        r.deviation_by_tank_m = tuple(r.deviation_by_tank_m) if r.deviation_by_tank_m else None  # type: ignore[assignment]
        r.phases_s = tuple(r.phases_s) if r.phases_s else None  # type: ignore[assignment]
    data["load"] = tuple(data["load"])
    return RestartsResult(restarts=restarts, **data)


if __name__ == "__main__":
    import sys

    n = int(sys.argv[1]) if len(sys.argv) > 1 else RESTARTS
    res = asyncio.run(run(Path("var/bench-restarts"), lambda m: print(m, file=sys.stderr, flush=True), n))
    print(markdown(res))
