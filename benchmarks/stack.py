"""Benchmarks through the real processes: OPC UA round trip, setpoint-to-action, scan lateness,
lock-step speed.

Every tier runs as ``python -m tankctl plant|plc`` or the whole stack as ``tankctl up`` on
free loopback ports in 20000-30000, each with its own log and plant state file under the run's
log directory (so no checkpoint of an earlier run is resumed).

- Round trip: an OPC UA client (:class:`tanklab_io.ua_client.Link`, the tiers' own client) reads one node
  of a running PLC, and the supervisor's snapshot paths (``PlcSnapshot.read_paths``, one Read),
  back to back; each Read is timed with ``time.perf_counter``.
- Setpoint-to-action: a client writes ``PLC.LIC1.SP`` alternately to 0.6 m and 0 m (its range
  ends: the PID's MV swings across most of its range in one scan, far beyond noise) after a
  random wait of up to one scan period (so the write lands at a random phase of the scan), and
  two other clients poll ``PLC.LIC1.MV`` and the plant's ``Plant.P1.Command`` back to back until
  each has moved by a quarter of the pump's range in the expected direction. Latency = time of
  the reply showing the change - time the write was sent (resolution: one read, ~1 ms).
- PLC scan lateness: plant + PLC run idle for a fixed wall time; on SIGTERM the PLC logs
  ``lateness p50 ... p99 ...`` (start of each scan minus its deadline, ``run_plc``), parsed here.
- Lock-step: ``tankctl up --clock lockstep --no-board``; the benchmark scenario's setpoint step is
  written by a client when ``Plant.Sim.Time`` reaches 10 s; ``Plant.Sim.Time`` is polled back
  to back until then and every 50 ms of wall time after (light load on the plant); speed =
  model seconds / wall seconds over 1000 s of model time.
- Realtime stack at speed 20: ``tankctl up --speed 20 --no-board`` (all three tiers, supervisor
  in its configured mode) for a fixed wall time; the PLC's lateness from its log.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import re
import shutil
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarks.common import (
    ENERGIES,
    SCENARIO_DURATION_S,
    SCENARIO_STEP_AT_S,
    SCENARIO_STEP_M,
    cli_setup,
    load,
)
from benchmarks.procs import CpuMeter, bench_process
from supervisor.cycle import PlcSnapshot
from tanklab.tags import plant_tags, plc_tags, tags_by_path
from tanklab_io.ua_client import Link
from tanklab_testing.procs import TankctlProcess, free_base_port

LATENESS_RE = re.compile(
    r"PLC stopped after (\d+) scans: (\d+) overruns, lateness p50 ([\d.]+) ms p99 ([\d.]+) ms"
)
CONNECT_TIMEOUT_S = 30.0
LOCKSTEP_TIMEOUT_S = 180.0

SITE = load(ENERGIES)
PLANT_TAGS = tags_by_path(plant_tags(SITE))
PLC_TAGS = tags_by_path(plc_tags(SITE))


@dataclass
class Lateness:
    """Start lateness of the PLC's scans from its stop line."""

    label: str
    speed: float
    wall_s: float
    scans: int = 0
    overruns: int = 0
    p50_ms: float = float("nan")
    p99_ms: float = float("nan")
    error: str = ""
    stray: list[int] = field(default_factory=list)
    other_cores: float = float("nan")
    """Cores other work on the machine kept busy meanwhile (:class:`CpuMeter`)."""


@dataclass
class RoundTrip:
    label: str
    nodes: int
    samples_s: list[float]


@dataclass
class Action:
    """Setpoint-to-action latencies at one speed."""

    speed: float
    scan_period_wall_s: float
    write_s: list[float] = field(default_factory=list)
    mv_s: list[float] = field(default_factory=list)
    command_s: list[float] = field(default_factory=list)
    missed: int = 0
    refused: int = 0


@dataclass
class LockstepRun:
    model_s: float = float("nan")
    wall_s: float = float("nan")
    startup_s: float = float("nan")
    step_model_s: tuple[float, float] = (float("nan"), float("nan"))
    sp_after: float = float("nan")
    exit_code: int | None = None
    stray: list[int] = field(default_factory=list)
    error: str = ""
    other_cores: float = float("nan")
    """Cores other work on the machine kept busy during the timed window (:class:`CpuMeter`)."""

    @property
    def speed(self) -> float:
        return self.model_s / self.wall_s


@dataclass
class StackResults:
    round_trips: list[RoundTrip] = field(default_factory=list)
    actions: list[Action] = field(default_factory=list)
    lateness: list[Lateness] = field(default_factory=list)
    lockstep: list[LockstepRun] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)


def parse_lateness(text: str, into: Lateness) -> None:
    """Fill ``into`` from the PLC's stop line (the last one in ``text``)."""
    found = LATENESS_RE.findall(text)
    if not found:
        into.error = "no 'PLC stopped after ...' line in the PLC log"
        return
    scans, overruns, p50, p99 = found[-1]
    into.scans, into.overruns, into.p50_ms, into.p99_ms = int(scans), int(overruns), float(p50), float(p99)


async def connect(url: str, tags: dict[str, Any], name: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Link:
    """A connected :class:`Link`, retrying every 20 ms (a fresh Link skips the backoff)."""
    deadline = time.monotonic() + timeout_s
    while True:
        link = Link(url, tags, name=name, setup=cli_setup(), timeout_s=2.0)
        if await link.ensure():
            return link
        if time.monotonic() > deadline:
            raise RuntimeError(f"could not connect to {url} within {timeout_s:.0f} s")
        await asyncio.sleep(0.02)


@dataclass
class Pair:
    plant: TankctlProcess
    plc: TankctlProcess
    plant_url: str
    plc_url: str


@contextlib.asynccontextmanager
async def plant_and_plc(speed: float, log_dir: Path, tag: str) -> AsyncIterator[Pair]:
    """Plant and PLC processes at ``speed`` (realtime), stopped (PLC first) on exit."""
    base = free_base_port(2)
    plant_url = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"
    plc_url = f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc"
    cfg = str(ENERGIES)
    state = log_dir / f"{tag}-plant-state.json"
    state.unlink(missing_ok=True)
    common = ["--config", cfg, "--host", "127.0.0.1", "--speed", f"{speed:g}"]
    plant = bench_process(
        "plant",
        ["plant", *common, "--port", str(base), "--state-file", str(state)],
        log_dir / f"{tag}-plant.log",
    )
    plc = bench_process(
        "plc", ["plc", *common, "--port", str(base + 1), "--plant-url", plant_url], log_dir / f"{tag}-plc.log"
    )
    pair = Pair(plant, plc, plant_url, plc_url)
    try:
        await plant.start()
        await plc.start()
        yield pair
    finally:
        await plc.stop()
        await plant.stop()


async def lateness_idle(speed: float, wall_s: float, log_dir: Path) -> Lateness:
    """Plant + PLC at ``speed`` with no client for ``wall_s``; the PLC's lateness."""
    out = Lateness(f"plant + PLC processes, speed {speed:g}", speed, wall_s)
    meter = CpuMeter()
    async with plant_and_plc(speed, log_dir, f"lateness-x{speed:g}") as pair:
        ours = pair.plant.tree() + pair.plc.tree()
        meter.start(ours)
        await asyncio.sleep(wall_s)
        out.other_cores = meter.stop(ours)
    parse_lateness(pair.plc.log_text(), out)
    out.stray = pair.plc.stray + pair.plant.stray
    return out


async def round_trips(plc_url: str, n: int) -> list[RoundTrip]:
    """Reads of one node and of the supervisor's snapshot, ``n`` each (after 20 warm-up reads)."""
    snap = PlcSnapshot.read_paths(SITE.loop_names, SITE.tank_names)
    one = ["PLC.LIC1.PV"]
    link = await connect(plc_url, {p: PLC_TAGS[p] for p in {*snap, *one}}, "bench-read")
    out = []
    try:
        for label, paths in (
            ("Read of 1 node (PLC.LIC1.PV)", one),
            ("Read of the supervisor's snapshot", snap),
        ):
            for _ in range(20):
                await link.read(paths)
            samples = []
            for _ in range(n):
                t0 = time.perf_counter()
                await link.read(paths)
                samples.append(time.perf_counter() - t0)
            out.append(RoundTrip(label, len(paths), samples))
    finally:
        await link.close()
    return out


async def _wait_move(
    link: Link, path: str, before: float, direction: float, threshold: float, t0: float, deadline: float
) -> float | None:
    """Poll ``path`` until it moved by ``threshold`` in ``direction``; seconds since ``t0``."""
    while time.perf_counter() < deadline:
        value = float((await link.read([path]))[0].Value.Value)
        if direction * (value - before) >= threshold:
            return time.perf_counter() - t0
    return None


async def setpoint_to_action(pair: Pair, speed: float, n: int, seed: int = 7) -> Action:
    """``n`` setpoint writes alternating 0.6 m / 0 m; latency to MV and to the plant's command."""
    assert SITE.plc is not None
    period = SITE.plc.scan_period_s / speed
    pump = SITE.plant.pump("P1")
    threshold = 0.25 * (pump.command_max - pump.command_min)
    out = Action(speed, period)
    writer = await connect(pair.plc_url, {"PLC.LIC1.SP": PLC_TAGS["PLC.LIC1.SP"]}, "bench-sp")
    mv_link = await connect(pair.plc_url, {"PLC.LIC1.MV": PLC_TAGS["PLC.LIC1.MV"]}, "bench-mv")
    cmd_link = await connect(
        pair.plant_url, {"Plant.P1.Command": PLANT_TAGS["Plant.P1.Command"]}, "bench-cmd"
    )
    rng = random.Random(seed)
    lo, hi = 0.0, 0.6
    try:
        await writer.write({"PLC.LIC1.SP": lo})
        await asyncio.sleep(3 * period + 0.2)
        for i in range(n):
            await asyncio.sleep(rng.uniform(0.0, period))
            target, direction = (hi, 1.0) if i % 2 == 0 else (lo, -1.0)
            mv0 = float((await mv_link.read(["PLC.LIC1.MV"]))[0].Value.Value)
            cmd0 = float((await cmd_link.read(["Plant.P1.Command"]))[0].Value.Value)
            t0 = time.perf_counter()
            deadline = t0 + 3 * period + 2.0
            mv_task = asyncio.create_task(
                _wait_move(mv_link, "PLC.LIC1.MV", mv0, direction, threshold, t0, deadline)
            )
            cmd_task = asyncio.create_task(
                _wait_move(cmd_link, "Plant.P1.Command", cmd0, direction, threshold, t0, deadline)
            )
            status = (await writer.write({"PLC.LIC1.SP": target}))[0]
            out.write_s.append(time.perf_counter() - t0)
            mv_t, cmd_t = await asyncio.gather(mv_task, cmd_task)
            if not status.is_good():
                out.refused += 1
            if mv_t is None or cmd_t is None:
                out.missed += 1
            if mv_t is not None:
                out.mv_s.append(mv_t)
            if cmd_t is not None:
                out.command_s.append(cmd_t)
            # let the loop settle at the new saturation before the next write
            await asyncio.sleep(period)
    finally:
        for link in (writer, mv_link, cmd_link):
            await link.close()
    return out


async def lockstep_run(log_dir: Path, duration_s: float = SCENARIO_DURATION_S) -> LockstepRun:
    """One lock-step run of the benchmark scenario through ``tankctl up``."""
    run_dir = log_dir / f"lockstep-{time.time_ns()}"
    base = free_base_port(3)
    plant_url = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"
    plc_url = f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc"
    up = bench_process(
        "up",
        [
            "up",
            "--config",
            str(ENERGIES),
            "--clock",
            "lockstep",
            "--no-board",
            "--no-hmi",
            "--base-port",
            str(base),
            "--log-dir",
            str(run_dir),
        ],
        run_dir / "up.out",
        banner=False,
    )
    out = LockstepRun()
    t_launch = time.perf_counter()
    await up.start()
    links: list[Link] = []
    try:
        plant = await connect(plant_url, {"Plant.Sim.Time": PLANT_TAGS["Plant.Sim.Time"]}, "bench-time")
        links.append(plant)
        plc = await connect(plc_url, {"PLC.LIC1.SP": PLC_TAGS["PLC.LIC1.SP"]}, "bench-sp")
        links.append(plc)
        first: tuple[float, float] | None = None
        stepped = False
        meter = CpuMeter()
        bound = time.perf_counter() + LOCKSTEP_TIMEOUT_S
        while True:
            t_model = float((await plant.read(["Plant.Sim.Time"]))[0].Value.Value)
            now = time.perf_counter()
            if first is None and t_model > 0.0:
                first = (now, t_model)
                out.startup_s = now - t_launch
                meter.start(up.tree())
            if not stepped and t_model >= SCENARIO_STEP_AT_S:
                sp = float((await plc.read(["PLC.LIC1.SP"]))[0].Value.Value)
                status = (await plc.write({"PLC.LIC1.SP": sp + SCENARIO_STEP_M}))[0]
                if not status.is_good():
                    raise RuntimeError(f"setpoint write refused: {status}")
                after = float((await plant.read(["Plant.Sim.Time"]))[0].Value.Value)
                out.step_model_s = (t_model, after)
                stepped = True
            if first is not None and t_model >= first[1] + duration_s:
                out.model_s = t_model - first[1]
                out.wall_s = now - first[0]
                out.other_cores = meter.stop(up.tree())
                break
            if now > bound:
                raise RuntimeError(
                    f"lock-step run reached only t = {t_model:.0f} s "
                    f"in {LOCKSTEP_TIMEOUT_S:.0f} s of wall time"
                )
            if stepped:
                await asyncio.sleep(0.05)
        out.sp_after = float((await plc.read(["PLC.LIC1.SP"]))[0].Value.Value)
    except Exception as e:
        out.error = f"{type(e).__name__}: {e}"
    finally:
        for link in links:
            await link.close()
        out.exit_code = await up.stop()
        out.stray = up.stray
    return out


async def realtime_stack(speed: float, wall_s: float, log_dir: Path) -> Lateness:
    """``tankctl up --speed`` (all three tiers) for ``wall_s``; the PLC's lateness from its log."""
    out = Lateness(f"tankctl up (plant + PLC + supervisor), speed {speed:g}", speed, wall_s)
    run_dir = log_dir / f"realtime-x{speed:g}-{time.time_ns()}"
    base = free_base_port(3)
    up = bench_process(
        "up",
        [
            "up",
            "--config",
            str(ENERGIES),
            "--speed",
            f"{speed:g}",
            "--no-board",
            "--no-hmi",
            "--base-port",
            str(base),
            "--log-dir",
            str(run_dir),
        ],
        run_dir / "up.out",
        banner=False,
    )
    await up.start()
    meter = CpuMeter()
    end = time.monotonic() + wall_s
    try:
        # the CPU meter starts once all three tiers exist (`up` starts them one after the other)
        while len(up.tree()) < 4 and time.monotonic() < end:
            await asyncio.sleep(0.1)
        meter.start(up.tree())
        await asyncio.sleep(max(0.0, end - time.monotonic()))
        out.other_cores = meter.stop(up.tree())
    finally:
        await up.stop()
    out.stray = up.stray
    plc_log = run_dir / SITE.name / "plc.log"
    try:
        parse_lateness(plc_log.read_text(encoding="utf-8", errors="replace"), out)
    except OSError as e:
        out.error = f"cannot read {plc_log}: {e}"
    return out


async def run_all(
    log_dir: Path,
    *,
    reads: int,
    actions_x1: int,
    actions_x20: int,
    lateness_x1_s: float,
    lateness_x20_s: float,
    lockstep_runs: int,
    realtime_x20_s: float,
    log: Callable[[str], None],
) -> StackResults:
    """Every process benchmark in turn (each on its own processes and ports)."""
    if log_dir.exists():
        shutil.rmtree(log_dir)
    log_dir.mkdir(parents=True)
    res = StackResults()

    async def attempt(what: str, coro: Any) -> Any:
        try:
            return await coro
        except Exception as e:
            res.errors.append(f"{what}: {type(e).__name__}: {e}")
            log(f"  {what} FAILED: {type(e).__name__}: {e}")
            return None

    for speed, wall in ((1.0, lateness_x1_s), (20.0, lateness_x20_s)):
        lat = await attempt(f"lateness at speed {speed:g}", lateness_idle(speed, wall, log_dir))
        if lat is not None:
            res.lateness.append(lat)
            log(
                f"  PLC lateness, speed {speed:g}: p50 {lat.p50_ms} ms, p99 {lat.p99_ms} ms, "
                f"{lat.scans} scans"
            )

    async def speed_one() -> None:
        async with plant_and_plc(1.0, log_dir, "client-x1") as pair:
            res.round_trips.extend(await round_trips(pair.plc_url, reads))
            res.actions.append(await setpoint_to_action(pair, 1.0, actions_x1))

    await attempt("round trip and setpoint-to-action at speed 1", speed_one())

    async def speed_twenty() -> None:
        async with plant_and_plc(20.0, log_dir, "client-x20") as pair:
            res.actions.append(await setpoint_to_action(pair, 20.0, actions_x20))

    await attempt("setpoint-to-action at speed 20", speed_twenty())
    for rt in res.round_trips:
        log(f"  {rt.label}: median {1e3 * sorted(rt.samples_s)[len(rt.samples_s) // 2]:.3f} ms")
    for act in res.actions:
        log(f"  setpoint-to-action at speed {act.speed:g}: {len(act.command_s)} trials, {act.missed} missed")

    lat20 = await attempt("realtime stack at speed 20", realtime_stack(20.0, realtime_x20_s, log_dir))
    if lat20 is not None:
        res.lateness.append(lat20)
        log(f"  tankctl up speed 20: PLC lateness p50 {lat20.p50_ms} ms, p99 {lat20.p99_ms} ms")

    for i in range(lockstep_runs):
        run = await lockstep_run(log_dir)
        res.lockstep.append(run)
        if run.error:
            log(f"  lock-step run {i + 1} FAILED: {run.error}")
        else:
            log(f"  lock-step run {i + 1}: {run.model_s:.0f} s of model time in {run.wall_s:.2f} s")
    return res
