"""Each tier SIGKILLed and restarted by ``tankctl up`` under a running stack (issue 21): the driver.

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

What a run records, how it is judged and how section 10 renders it are in
:mod:`benchmarks.restarts_report` (pure); this module runs the stack and measures.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import os
import signal
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml
from asyncua import ua

from benchmarks.common import cli_setup
from benchmarks.procs import bench_process
from benchmarks.restarts_report import (
    POST_S,
    QUIET_S,
    RESTARTS,
    TIERS,
    Restart,
    RestartsResult,
    box_change,
    describe,
    markdown,
    plc_phases,
    settings_paths,
)
from tanklab.enums import GainSource, SensorFault, SupervisorMode
from tanklab.errors import LinkError
from tanklab.tags import Tag, plant_tags, plc_tags, supervisor_tags, tags_by_path
from tanklab_io.ua_client import Link
from tanklab_testing.procs import alive, free_base_port, tankctl_pids
from tanklab_testing.sites import site_config

SPEED = 1.0
HEALTHY_TIMEOUT_S = 120.0
SETTLE_TIMEOUT_S = 300.0
SETTLE_BAND_M = 0.002
"""Both controlled levels within this of their setpoints before the first kill [m]."""
STILL_S = 30.0
STILL_BAND_M = 0.001
"""Steady before the first kill: each level moved less than this over STILL_S [m]."""
RECOVER_BAND_M = 0.002
"""Before the next kill both levels are back within this of their pre-kill values (bounded) [m]."""
RECOVER_TIMEOUT_S = 30.0
SAMPLE_S = 0.2

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
                *("up", "--config", str(self.config), "--speed", f"{SPEED:g}", "--no-board", "--no-hmi"),
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


if __name__ == "__main__":
    import sys

    n = int(sys.argv[1]) if len(sys.argv) > 1 else RESTARTS
    res = asyncio.run(run(Path("var/bench-restarts"), lambda m: print(m, file=sys.stderr, flush=True), n))
    print(markdown(res))
