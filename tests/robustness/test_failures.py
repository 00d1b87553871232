"""Kills, freezes and crashes of real tier processes: the plant stays in band, nothing stalls silently.

The stack (plant, PLC, supervisor; speed 5, so one 1 s scan is 200 ms of wall time) starts at
the default config's operating point (T1 0.4 m, T2 0.2 m, T3 0.3 m, pumps at the equilibrium
flows; ``tanklab_testing.sites.site_config``), with the PLC's retentive memory and the plant's
state file in the test's directory, so restarts are warm.

What is judged, on model time (``Plant.Sim.Time``, ``PLC.Status.ModelTime``), from samples of
the plant taken at every poll of every wait:

* **Band.** Every tank stays strictly between its low and high level alarm limits (LSL 5 %,
  LSH 90 % of the tank height: 0.031 m and 0.558 m), the band the PLC alarms on. A loss of the
  supervisor must cost almost nothing, since the PLC takes over bumplessly within its heartbeat
  timeout: the controlled levels stay within ``SUPERVISOR_BAND_M`` of their setpoints. A lost
  PLC or plant stops the pumps for a while (the plant's pump watchdog, safe state "off"), so the
  levels sag, but they stay in the alarm band and come back within ``SETTLE_BAND_M`` of their
  setpoints within ``RECOVERY_MODEL_S`` of model time.
* **No spill.** ``Plant.Balance.Spilled`` stays 0.
* **No silent stall.** While the PLC is frozen (SIGSTOP) or dead, ``Supervisor.PlcConnected``
  goes False; after SIGCONT or a restart it goes True again, ``Supervisor.Cycle`` advances and
  the PLC sees the heartbeats (``PLC.Supervisor.Alive``).

Waiting for the processes goes through ``wait_until`` only; the freeze lasts 3 s of wall time,
measured as 15 s of the plant's model time.
"""

from __future__ import annotations

import functools
import os
import signal
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from helpers import ROOT, engineer_logins, secure, wait_until
from tanklab.config import load_site
from tanklab.enums import GainSource, LoopMode, SupervisorMode
from tanklab_io.ua_client import resolve
from tanklab_testing.logins import Probe
from tanklab_testing.procs import free_base_port  # random bases: parallel sessions do not collide
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

SPEED = 5.0
SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
TANKS = SITE.tank_names
ALARM_BAND_M = {t.name: (t.switch_levels().low_m, t.switch_levels().high_m) for t in SITE.plant.tanks}
"""(L, H) alarm limits per tank [m]: the band every level must stay strictly inside."""
SETPOINTS_M = {"T1": 0.4, "T2": 0.2}
"""Setpoints of the controlled tanks (LIC1 on T1, LIC2 on T2) in the config [m]."""
SUPERVISOR_BAND_M = 0.02
"""Largest setpoint deviation allowed after a supervisor loss [m] (2 cm: 20x the transmitter's
noise, 5 % of T1's level; the measured deviation is a few mm)."""
SETTLE_BAND_M = 0.02
"""Setpoint deviation a recovered loop must come back within [m]."""
RECOVERY_MODEL_S = 400.0
"""Model time within which the levels come back into ``SETTLE_BAND_M`` after a PLC or plant
restart [s] (the slowest mode of the plant is about 150 s)."""
WATCH_MODEL_S = 60.0
"""Model time the levels are watched after a supervisor loss, and after a recovery [s]."""
HEARTBEAT_TIMEOUT_S = max(SITE.plc.watchdog.timeout_s if SITE.plc else 3.0, SPEED)
"""The PLC's heartbeat timeout at this speed (model time, wall floor 1 s) [s]."""
FALLBACK_SLACK_S = 3.0
"""Scans a fallback may come after the heartbeat timeout, as this test sees it [model s]: the
scan that notices the timeout, the heartbeat of the scan the kill interrupted, and one scan
of polling latency (a poll is a plant and a PLC read; 200 ms of wall time is one scan)."""

PLANT_PATHS = ["Plant.Sim.Time", "Plant.Balance.Spilled", "Plant.Sim.Watchdog"] + [
    f"Plant.{t}.Level" for t in TANKS
]
PLC_PATHS = [
    "PLC.Status.ModelTime",
    "PLC.Status.Scan",
    "PLC.Status.IoHealthy",
    "PLC.Supervisor.Alive",
    "PLC.LIC1.SP",
    "PLC.LIC1.Mode",
    "PLC.LIC2.Mode",
    "PLC.LIC1.GainSource",
    "PLC.LIC2.GainSource",
]
SUPERVISOR_PATHS = ["Supervisor.PlcConnected", "Supervisor.Cycle", "Supervisor.Mode"]


Sample = tuple[float, float, dict[str, float]]
"""(plant model time [s], spilled volume [m^3], level by tank [m])."""


@dataclass
class PlantLog:
    """Samples of the plant: (model time, spilled volume, levels by tank)."""

    probe: Probe
    samples: list[Sample] = field(default_factory=list)

    async def sample(self) -> dict[str, Any] | None:
        got = await self.probe.read()
        if got is not None:
            levels = {t: float(got[f"Plant.{t}.Level"]) for t in TANKS}
            self.samples.append((float(got["Plant.Sim.Time"]), float(got["Plant.Balance.Spilled"]), levels))
        return got

    def mark(self) -> int:
        """Index of the next sample (a window starts here)."""
        return len(self.samples)

    def window(self, start: int) -> list[Sample]:
        return self.samples[start:]


def out_of_band(
    samples: Sequence[Sample], setpoints: dict[str, float], setpoint_band_m: float | None = None
) -> list[str]:
    """Samples outside the alarm band (and, when given, farther than ``setpoint_band_m`` from
    ``setpoints``), or with water spilled."""
    bad = []
    for t, spilled, levels in samples:
        if spilled != 0.0:
            bad.append(f"t={t:.1f}: spilled {spilled:.3g} m^3")
        for tank, h in levels.items():
            lo, hi = ALARM_BAND_M[tank]
            if not lo < h < hi:
                bad.append(f"t={t:.1f}: {tank} at {h:.4f} m, outside ({lo:.3f}, {hi:.3f})")
            sp = setpoints.get(tank)
            if setpoint_band_m is not None and sp is not None and abs(h - sp) > setpoint_band_m:
                bad.append(f"t={t:.1f}: {tank} at {h:.4f} m, more than {setpoint_band_m} m from {sp} m")
    return bad


def deviation(samples: Sequence[Sample], setpoints: dict[str, float]) -> dict[str, float]:
    """Largest |level - setpoint| per controlled tank over ``samples`` [m] (for messages)."""
    return {t: max((abs(s[2][t] - sp) for s in samples), default=0.0) for t, sp in setpoints.items()}


class WatchedStack(Stack):
    """The test-support :class:`Stack` (plant, PLC and, optionally, supervisor on consecutive
    ports, restartable tier by tier) with the tiers probed and the plant sampled at every poll."""

    def __init__(self, tmp_path: Path, *, supervisor: bool) -> None:
        config = site_config(
            tmp_path / "site.yaml", retain=tmp_path / "plc-retain.json", at_operating_point=True
        )
        super().__init__(config, free_base_port(3), speed=SPEED, state_file=tmp_path / "plant-state.json")
        self.tiers = ("plant", "plc", "supervisor") if supervisor else ("plant", "plc")
        self.setpoints = dict(SETPOINTS_M)
        logins = engineer_logins()
        self.plant = PlantLog(Probe(self.urls[0], PLANT_PATHS, logins))
        self.plc = Probe(self.urls[1], PLC_PATHS, logins)
        self.supervisor = Probe(self.urls[2], SUPERVISOR_PATHS, logins)

    async def up(self, tiers: Sequence[str] | None = None) -> WatchedStack:
        await super().up(tiers or self.tiers)
        await wait_until(self.regulating, 60, what="the stack scanning at its operating point")
        return self

    async def regulating(self) -> bool:
        """Sample the plant; True when the PLC scans with good I/O and the controlled levels are
        within ``SETTLE_BAND_M`` of their setpoints."""
        got = await self.plant.sample()
        plc = await self.plc.read()
        if got is None or plc is None or not plc["PLC.Status.IoHealthy"]:
            return False
        return all(abs(got[f"Plant.{t}.Level"] - sp) < SETTLE_BAND_M for t, sp in self.setpoints.items())

    async def model_time(self) -> float:
        """The plant's model time now (sampling the levels as it goes)."""
        got = await self.plant.sample()
        assert got is not None, "the plant does not answer"
        return float(got["Plant.Sim.Time"])

    async def plant_time_reaches(self, t: float) -> bool:
        got = await self.plant.sample()
        return got is not None and float(got["Plant.Sim.Time"]) >= t

    async def down(self) -> None:
        """Close the probes, then stop every tier (frozen ones too: SIGCONT before SIGTERM)."""
        for probe in (self.plant.probe, self.plc, self.supervisor):
            await probe.close()
        await super().down()


@pytest.fixture
async def full_stack(tmp_path: Path) -> AsyncIterator[WatchedStack]:
    stack = WatchedStack(tmp_path, supervisor=True)
    try:
        yield await stack.up()
    finally:
        await stack.down()


@pytest.fixture
async def plant_and_plc(tmp_path: Path) -> AsyncIterator[WatchedStack]:
    stack = WatchedStack(tmp_path, supervisor=False)
    try:
        yield await stack.up()
    finally:
        await stack.down()


async def _write(url: str, path: str, value: ua.Variant) -> None:
    """One write as the engineer (raises on a Bad status)."""
    async with await secure(url) as client:
        await (await resolve(client, [path]))[path].write_value(value)


async def _write_supervisor_mode(stack: WatchedStack, mode: SupervisorMode) -> None:
    await _write(stack.urls[2], "Supervisor.Mode", ua.Variant(int(mode), ua.VariantType.Int32))


async def _supervisor_killed(stack: WatchedStack, on_supervisor: str) -> tuple[float, float]:
    """Kill the supervisor; wait for the PLC to fall back (``on_supervisor``: the condition the
    fallback clears); return the PLC's model time of the kill and of the fallback."""
    t_kill = float(await stack.plc.value("PLC.Status.ModelTime"))
    await stack.procs["supervisor"].kill()

    async def fell_back() -> bool:
        await stack.plant.sample()
        got = await stack.plc.read()
        if got is None or got["PLC.Supervisor.Alive"]:
            return False
        if on_supervisor == "remote":
            return got["PLC.LIC1.Mode"] == got["PLC.LIC2.Mode"] == int(LoopMode.AUTO)
        sources = {got["PLC.LIC1.GainSource"], got["PLC.LIC2.GainSource"]}
        return int(GainSource.SUPERVISOR) not in sources and int(GainSource.FALLBACK) in sources

    await wait_until(fell_back, 30, what="the PLC's fallback after the supervisor died")
    t_fb = float(await stack.plc.value("PLC.Status.ModelTime"))
    return t_kill, t_fb


async def test_supervisor_killed_in_mpc_plc_takes_over_and_levels_stay_in_band(
    full_stack: WatchedStack,
) -> None:
    stack = full_stack
    await _write_supervisor_mode(stack, SupervisorMode.MPC)

    async def remote() -> bool:
        await stack.plant.sample()
        got = await stack.plc.read()
        return got is not None and got["PLC.LIC1.Mode"] == got["PLC.LIC2.Mode"] == int(LoopMode.REMOTE)

    await wait_until(remote, 30, what="both loops in REMOTE under the MPC")
    t_remote = await stack.model_time()
    await wait_until(lambda: stack.plant_time_reaches(t_remote + 20), 30, what="20 s of MPC")
    start = stack.plant.mark()
    t0 = await stack.model_time()
    t_kill, t_fb = await _supervisor_killed(stack, "remote")
    # REMOTE sheds to AUTO within the heartbeat timeout plus the scan that notices it.
    assert t_fb - t_kill <= HEARTBEAT_TIMEOUT_S + FALLBACK_SLACK_S
    await wait_until(lambda: stack.plant_time_reaches(t0 + WATCH_MODEL_S), 60, what="60 s after the kill")
    window = stack.plant.window(start)
    assert window[-1][0] - window[0][0] >= WATCH_MODEL_S
    assert out_of_band(window, stack.setpoints, SUPERVISOR_BAND_M) == [], deviation(window, stack.setpoints)


async def test_supervisor_killed_in_adaptive_pid_plc_falls_back_and_levels_stay_in_band(
    full_stack: WatchedStack,
) -> None:
    stack = full_stack
    await _write_supervisor_mode(stack, SupervisorMode.ADAPTIVE_PID)
    # The adapter learns from excitation: a 2 cm setpoint step of LIC1 and back gives it some.
    await _write(stack.urls[1], "PLC.LIC1.SP", ua.Variant(0.42, ua.VariantType.Double))

    async def pushed() -> bool:
        await stack.plant.sample()
        got = await stack.plc.read()
        return got is not None and int(GainSource.SUPERVISOR) in (
            got["PLC.LIC1.GainSource"],
            got["PLC.LIC2.GainSource"],
        )

    await wait_until(pushed, 90, what="gains pushed by the supervisor")
    await _write(stack.urls[1], "PLC.LIC1.SP", ua.Variant(0.4, ua.VariantType.Double))
    await wait_until(stack.regulating, 90, what="the levels settled on the supervisor's gains")
    start = stack.plant.mark()
    t0 = await stack.model_time()
    t_kill, t_fb = await _supervisor_killed(stack, "gains")
    assert t_fb - t_kill <= HEARTBEAT_TIMEOUT_S + FALLBACK_SLACK_S
    await wait_until(lambda: stack.plant_time_reaches(t0 + WATCH_MODEL_S), 60, what="60 s after the kill")
    window = stack.plant.window(start)
    assert window[-1][0] - window[0][0] >= WATCH_MODEL_S
    assert out_of_band(window, stack.setpoints, SUPERVISOR_BAND_M) == [], deviation(window, stack.setpoints)


async def test_plc_killed_and_restarted_levels_stay_in_band_and_recover(plant_and_plc: WatchedStack) -> None:
    stack = plant_and_plc
    await _write(stack.urls[1], "PLC.LIC1.SP", ua.Variant(0.41, ua.VariantType.Double))
    stack.setpoints["T1"] = 0.41

    async def at_new_setpoint() -> bool:
        got = await stack.plant.sample()
        return got is not None and abs(got["Plant.T1.Level"] - 0.41) < 0.005

    # Many scans later the retentive memory holds the new setpoint (it is saved after a scan).
    await wait_until(at_new_setpoint, 60, what="T1 at its new 0.41 m setpoint")
    start = stack.plant.mark()
    await stack.procs["plc"].kill()
    await stack.plc.close()

    async def pumps_safe() -> bool:
        got = await stack.plant.sample()
        return got is not None and bool(got["Plant.Sim.Watchdog"])

    # No command for the watchdog's time: the plant puts the pumps in their safe state.
    await wait_until(pumps_safe, 30, what="the plant's pump watchdog after the PLC died")
    await stack.start("plc")
    t_back = await stack.model_time()

    async def warm() -> bool:
        await stack.plant.sample()
        got = await stack.plc.read()
        return got is not None and bool(got["PLC.Status.IoHealthy"])

    await wait_until(warm, 30, what="the restarted PLC scanning")
    # Warm restart: the retentive memory gave the new PLC the operator's setpoint.
    assert await stack.plc.value("PLC.LIC1.SP") == 0.41
    await wait_until(stack.regulating, 120, what="the levels back at their setpoints")
    recovered = await stack.model_time()
    assert recovered - t_back <= RECOVERY_MODEL_S
    await wait_until(
        lambda: stack.plant_time_reaches(recovered + WATCH_MODEL_S), 60, what="60 s after the recovery"
    )
    window = stack.plant.window(start)
    assert out_of_band(window, stack.setpoints) == [], deviation(window, stack.setpoints)


async def test_plant_killed_and_restarted_resumes_its_state_and_levels_stay_in_band(
    plant_and_plc: WatchedStack,
) -> None:
    stack = plant_and_plc
    # Let the plant checkpoint (every 5 s of wall time) at the operating point.
    t0 = await stack.model_time()
    await wait_until(lambda: stack.plant_time_reaches(t0 + 6 * SPEED), 30, what="a checkpoint interval")
    start = stack.plant.mark()
    t_kill = await stack.model_time()
    await stack.procs["plant"].kill()
    await stack.plant.probe.close()

    async def io_lost() -> bool:
        got = await stack.plc.read()
        return got is not None and not got["PLC.Status.IoHealthy"]

    await wait_until(io_lost, 30, what="the PLC to report the dead plant")
    await stack.start("plant")
    t_resumed = await stack.model_time()
    # Resumed from the state file, not from zero: at most one checkpoint interval (5 s of wall
    # time) of model time was lost.
    assert t_resumed >= t_kill - 6 * SPEED
    await wait_until(stack.regulating, 120, what="the levels regulated after the plant restart")
    recovered = await stack.model_time()
    assert recovered - t_resumed <= RECOVERY_MODEL_S
    await wait_until(
        lambda: stack.plant_time_reaches(recovered + WATCH_MODEL_S), 60, what="60 s after the recovery"
    )
    window = stack.plant.window(start)
    assert out_of_band(window, stack.setpoints) == [], deviation(window, stack.setpoints)


async def test_plc_frozen_then_crashed_the_supervisor_never_stalls_silently(full_stack: WatchedStack) -> None:
    stack = full_stack
    sup = stack.supervisor

    async def connected(want: bool) -> bool:
        await stack.plant.sample()
        got = await sup.read()
        return got is not None and bool(got["Supervisor.PlcConnected"]) is want

    async def recovered_past(cycle: int) -> bool:
        await stack.plant.sample()
        got = await sup.read()
        if got is None or not got["Supervisor.PlcConnected"] or got["Supervisor.Cycle"] <= cycle:
            return False
        return bool(await stack.plc.value("PLC.Supervisor.Alive"))

    await wait_until(lambda: recovered_past(0), 60, what="the supervisor cycling with the PLC")
    start = stack.plant.mark()
    for rep in range(2):
        # Freeze: SIGSTOP for at least 3 s of wall time (15 s of the plant's model time).
        cycle = int(await sup.value("Supervisor.Cycle"))
        t_stop = await stack.model_time()
        os.kill(stack.pid("plc"), signal.SIGSTOP)
        try:
            await wait_until(lambda: connected(False), 20, what=f"PlcConnected False, freeze {rep}")
            thawed = functools.partial(stack.plant_time_reaches, t_stop + 3 * SPEED)
            await wait_until(thawed, 30, what=f"3 s of freeze {rep}")
        finally:
            os.kill(stack.pid("plc"), signal.SIGCONT)
        await stack.plc.close()
        await wait_until(functools.partial(recovered_past, cycle), 120, what=f"recovery after SIGCONT {rep}")
        # Crash, and a restart on the same port with the same retentive memory.
        await stack.procs["plc"].kill()
        await stack.plc.close()
        await wait_until(lambda: connected(False), 20, what=f"PlcConnected False, crash {rep}")
        cycle = int(await sup.value("Supervisor.Cycle"))
        await stack.start("plc")
        back = functools.partial(recovered_past, cycle)
        await wait_until(back, 60, what=f"recovery after the restart {rep}")
    window = stack.plant.window(start)
    assert out_of_band(window, stack.setpoints) == [], deviation(window, stack.setpoints)
