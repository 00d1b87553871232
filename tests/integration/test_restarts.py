"""Restarts of real tier processes: every tier publishes exactly what it resumed, the PLC
warm-restarts bumplessly and its model time continues (issue 21, decision 0019).

* The plant alone in lock-step (its model time stands still without a PLC, so every node can be
  compared exactly): leaks, a valve, sensor faults with their values and a disturbance set;
  SIGTERM or SIGKILL (after the state file holds the settings); every node read through OPC UA
  before and after is the same (the transmitter readings aside: they draw fresh noise).
* Plant and PLC in real time at speed 5 (one 1 s scan is 200 ms of wall time), at the Energies
  operating point, every pump with the watchdog safe state ``hold``: a leak, a valve, a setpoint,
  a mode, engineer gains; the PLC restarted with SIGTERM and then with SIGKILL, then the plant;
  the PLC's retentive nodes are the same before and after, its scan counter and model time
  continue (its ``--trace`` CSV), its first output after a restart is where the pump was, and
  the largest deviation of T1's true level from its setpoint over each PLC restart stays small;
  then ``--cold`` starts from the config.
* The same with the shipped safe state ``off``: the PLC away until the plant's watchdog has
  stopped the pumps; the restarted PLC starts from P1's last command, not from 0.
"""

from __future__ import annotations

import contextlib
import csv
import json
from collections.abc import AsyncIterator, Sequence
from pathlib import Path
from typing import Any

import pytest
import yaml
from asyncua import ua

from helpers import ROOT, TierProcess, secure, wait_until
from tanklab.config import load_site
from tanklab.enums import GainSource, LoopMode, SensorFault
from tanklab.tags import plant_tags, plc_tags
from tanklab_io.ua_client import read_values, resolve
from tanklab_testing.procs import free_base_port  # random bases: parallel sessions do not collide
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

SPEED = 5.0
SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
PLANT_VARIABLES = [t.path for t in plant_tags(SITE) if t.kind == "variable"]
PLC_RETENTIVE = [
    f"PLC.{lp}.{item}"
    for lp in SITE.loop_names
    for item in ("SP", "SPLow", "SPHigh", "Mode", "ManualMV", "Kp", "Ki", "Kd", "GainSource")
] + [t.path for t in plc_tags(SITE) if t.path.startswith("PLC.Interlock.") and t.kind == "variable"]
"""The PLC's retentive nodes (RemoteMV is not retentive: a loop in REMOTE resumes holding its
pump's command until the supervisor writes again)."""
RESTART_BAND_M = 0.005
"""Largest deviation of T1's true level from its setpoint over a PLC restart [m] (issue 21's
bound for a restart during a running scenario)."""
ENGINEER_GAINS = (5.0e-4, 6.0e-6, -1.42e-4)


async def read_nodes(url: str, paths: Sequence[str]) -> dict[str, Any]:
    async with await secure(url) as client:
        nodes = await resolve(client, paths)
        values = await read_values(client, [nodes[p] for p in paths])
    return dict(zip(paths, values, strict=True))


async def write(url: str, values: dict[str, ua.Variant]) -> None:
    """Writes as the engineer, in order (raises on a Bad status)."""
    async with await secure(url) as client:
        nodes = await resolve(client, list(values))
        for path, value in values.items():
            await nodes[path].write_value(value)


def double(x: float) -> ua.Variant:
    return ua.Variant(x, ua.VariantType.Double)


def int32(x: int) -> ua.Variant:
    return ua.Variant(x, ua.VariantType.Int32)


async def stop(proc: TierProcess, how: str) -> None:
    if how == "SIGKILL":
        await proc.kill()
    else:
        assert await proc.stop() == 0


# ---- the plant alone, lock-step: every node exactly --------------------------------------------


@pytest.mark.parametrize("how", ["SIGTERM", "SIGKILL"])
async def test_plant_restart_publishes_exactly_the_state_it_resumed(tmp_path: Path, how: str) -> None:
    base = free_base_port(1)
    url = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"
    state = tmp_path / "plant-state.json"
    config = site_config(tmp_path / "site.yaml", at_operating_point=True)
    args = ("plant", "--config", str(config), "--port", str(base), "--lockstep", "--state-file", str(state))
    plant = await TierProcess(*args).start()
    try:
        await write(
            url,
            {
                "Plant.T2.Leak": double(0.2),
                "Plant.V32.Opening": double(0.6),
                "Plant.T3.Disturbance": double(-1.0e-5),
                "Plant.LT1.Fault": int32(int(SensorFault.BIAS)),
                "Plant.LT1.FaultValue": double(0.01),
                "Plant.LT3.Fault": int32(int(SensorFault.DRIFT)),
                "Plant.LT3.FaultValue": double(1.0e-4),
            },
        )
        before = await read_nodes(url, PLANT_VARIABLES)

        def saved() -> bool:  # an operator's write is checkpointed at the next tick
            with contextlib.suppress(OSError, ValueError):
                snap = json.loads(state.read_text(encoding="utf-8"))
                return snap["leak_openings"][1] == 0.2 and snap["fault_values"][2] == 1.0e-4
            return False

        await wait_until(saved, 20, what="the state file holding the operator's settings")
        await stop(plant, how)
        plant = await TierProcess(*args).start()
        after = await read_nodes(url, PLANT_VARIABLES)
    finally:
        await plant.stop()
    assert before["Plant.T2.Leak"] == 0.2 and before["Plant.V32.Opening"] == 0.6
    noisy = {p for p in PLANT_VARIABLES if p.endswith(".PV")}
    differ = {p: (before[p], after[p]) for p in PLANT_VARIABLES if p not in noisy and before[p] != after[p]}
    assert differ == {}
    assert after["Plant.LT1.Fault"] == int(SensorFault.BIAS) and after["Plant.LT3.FaultValue"] == 1.0e-4


# ---- plant and PLC in real time -----------------------------------------------------------------


class SampledStack(Stack):
    """The test-support :class:`Stack`'s plant and PLC, restartable, with the plant sampled; every
    PLC run has its own ``--trace`` and the one retentive-memory file."""

    def __init__(self, tmp_path: Path, safe_state: str = "hold") -> None:
        config = site_config(tmp_path / "site.yaml", at_operating_point=True)
        data = yaml.safe_load(config.read_text(encoding="utf-8"))
        for pump in data["plant"]["pumps"]:
            pump["watchdog_safe_state"] = safe_state
        config.write_text(yaml.safe_dump(data), encoding="utf-8")
        super().__init__(config, free_base_port(2), speed=SPEED, state_file=tmp_path / "plant-state.json")
        self.tmp = tmp_path
        self.retain = tmp_path / "plc-retain.json"
        self.samples: list[tuple[float, float]] = []  # (plant model time, T1 true level)
        self.watchdog = False  # the plant's pump watchdog at the last sample

    @property
    def plant(self) -> TierProcess | None:
        return self.procs.get("plant")

    @property
    def plc(self) -> TierProcess | None:
        return self.procs.get("plc")

    @property
    def plc_runs(self) -> int:
        return self.runs["plc"]

    def traces(self) -> list[Path]:
        return [self.tmp / f"plc-trace-{k}.csv" for k in range(1, self.plc_runs + 1)]

    async def start_plant(self) -> None:
        await self.start("plant")

    async def start_plc(self, *extra: str) -> None:
        trace = self.tmp / f"plc-trace-{self.plc_runs + 1}.csv"
        await self.start("plc", "--retain-file", str(self.retain), "--trace", str(trace), *extra)

    async def sample(self) -> float:
        got = await read_nodes(self.plant_url, ["Plant.Sim.Time", "Plant.T1.Level", "Plant.Sim.Watchdog"])
        t = float(got["Plant.Sim.Time"])
        self.samples.append((t, float(got["Plant.T1.Level"])))
        self.watchdog = bool(got["Plant.Sim.Watchdog"])
        return t

    async def run_for(self, model_s: float) -> None:
        t0 = await self.sample()

        async def reached() -> bool:
            return await self.sample() >= t0 + model_s

        await wait_until(reached, 120, what=f"{model_s:g} s of the plant's model time")


@pytest.fixture
async def stack(tmp_path: Path) -> AsyncIterator[SampledStack]:
    s = SampledStack(tmp_path)
    try:
        await s.start_plant()
        await s.start_plc()
        yield s
    finally:
        await s.down()


def trace_rows(path: Path) -> list[dict[str, float]]:
    with path.open(encoding="utf-8") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


async def test_plc_warm_restart_resumes_settings_model_time_and_output_then_the_plant_restarts(
    stack: SampledStack,
) -> None:
    s = stack

    async def regulating() -> bool:
        got = await read_nodes(s.plc_url, ["PLC.Status.IoHealthy", "PLC.IO.LT1.PV"])
        return bool(got["PLC.Status.IoHealthy"]) and abs(got["PLC.IO.LT1.PV"] - 0.4) < 0.01

    await wait_until(regulating, 60, what="the PLC scanning at the operating point")
    # The operator's and the engineer's settings, on both tiers.
    await write(s.plant_url, {"Plant.T3.Leak": double(0.05), "Plant.V13.Opening": double(0.9)})
    await write(s.plc_url, {"PLC.LIC1.SP": double(0.41), "PLC.LIC2.Mode": int32(int(LoopMode.MANUAL))})
    async with await secure(s.plc_url) as client:
        lic1 = (await resolve(client, ["PLC.LIC1"]))["PLC.LIC1"]
        idx = lic1.nodeid.NamespaceIndex
        await lic1.call_method(ua.NodeId("PLC.LIC1.SetGains", idx), *ENGINEER_GAINS)

    async def settled() -> bool:
        await s.sample()
        got = await read_nodes(s.plc_url, ["PLC.IO.LT1.PV", "PLC.LIC1.GainSource"])
        return (
            got["PLC.LIC1.GainSource"] == int(GainSource.ENGINEER)
            and abs(got["PLC.IO.LT1.PV"] - 0.41) < 0.002
        )

    await wait_until(settled, 120, what="T1 settled at its new 0.41 m setpoint on the engineer's gains")
    await s.run_for(30.0)

    deviations: list[float] = []
    for how in ("SIGTERM", "SIGKILL"):
        before = await read_nodes(s.plc_url, PLC_RETENTIVE)
        assert before["PLC.LIC1.SP"] == 0.41 and before["PLC.LIC2.Mode"] == int(LoopMode.MANUAL)
        assert [before[f"PLC.LIC1.{g}"] for g in ("Kp", "Ki", "Kd")] == list(ENGINEER_GAINS)
        start = len(s.samples)
        assert s.plc is not None
        await stop(s.plc, how)
        retained = json.loads(s.retain.read_text(encoding="utf-8"))
        await s.start_plc()
        after = await read_nodes(s.plc_url, [*PLC_RETENTIVE, "PLC.Status.Scan", "PLC.Status.ModelTime"])
        # Restored means shown, from the first read on.
        assert {p: after[p] for p in PLC_RETENTIVE} == before, how
        assert (
            after["PLC.Status.Scan"] >= retained["scan"] and after["PLC.Status.ModelTime"] >= retained["t_s"]
        )
        await s.run_for(60.0)
        window = [h for _, h in s.samples[start:]]
        deviations.append(max(abs(h - 0.41) for h in window))
        old, new = trace_rows(s.traces()[-2]), trace_rows(s.traces()[-1])
        # Scan counter and model time continue: the first scan after the restart is the next
        # one after the last retained scan (SIGTERM stores the last scan; a SIGKILL may lose the
        # write of the last one or two, still queued).
        assert new[0]["scan"] == retained["scan"] + 1 and new[0]["t_s"] == retained["t_s"] + 1.0
        lost = old[-1]["scan"] - retained["scan"]
        assert lost == 0 if how == "SIGTERM" else 0 <= lost <= 2, (how, old[-1], retained["scan"])
        assert new[0]["scan"] <= old[-1]["scan"] + 1
        # Bumpless: P1's first command after the restart is its last one before, plus at most
        # one scan's ordinary PI move (here well under 1 % of the 1.2e-4 m^3/s range).
        assert abs(new[0]["P1_cmd"] - old[-1]["P1_cmd"]) < 1.2e-6, (old[-1], new[0])
        # LIC2 in MANUAL holds its manual MV through the restart.
        assert new[0]["P2_cmd"] == old[-1]["P2_cmd"]
        print(
            f"{how}: PLC model time {old[-1]['t_s']:.1f} s (scan {old[-1]['scan']:.0f}) before, "
            f"{new[0]['t_s']:.1f} s (scan {new[0]['scan']:.0f}) at the first scan after; P1 command "
            f"{old[-1]['P1_cmd']:.6g} -> {new[0]['P1_cmd']:.6g} m^3/s; largest T1 deviation "
            f"{1e3 * deviations[-1]:.2f} mm"
        )
    assert max(deviations) <= RESTART_BAND_M, deviations

    # Then the plant: SIGTERM (it saves on stop); its writable nodes show what it resumed.
    plant_writable = [
        p for p in PLANT_VARIABLES if p.endswith((".Leak", ".Opening", ".Fault", ".FaultValue"))
    ]
    plant_before = await read_nodes(s.plant_url, plant_writable)
    assert plant_before["Plant.T3.Leak"] == 0.05 and plant_before["Plant.V13.Opening"] == 0.9
    t_stop = await s.sample()
    assert s.plant is not None
    await stop(s.plant, "SIGTERM")
    await s.start_plant()
    assert await read_nodes(s.plant_url, plant_writable) == plant_before
    assert await s.sample() >= t_stop  # the plant's model time continues too

    async def plc_back() -> bool:
        got = await read_nodes(s.plc_url, ["PLC.Status.IoHealthy"])
        return bool(got["PLC.Status.IoHealthy"])

    await wait_until(plc_back, 60, what="the PLC scanning the restarted plant")
    assert await read_nodes(s.plc_url, PLC_RETENTIVE) == before

    # --cold: the config's setpoints, modes and gains, model time from 0, whatever the file says.
    assert s.plc is not None
    await stop(s.plc, "SIGTERM")
    await s.start_plc("--cold")
    clock = ["PLC.Status.ModelTime", "PLC.Status.Scan", "PLC.Status.ScanPeriod"]
    cold = await read_nodes(s.plc_url, [*PLC_RETENTIVE, *clock])
    assert cold["PLC.LIC1.SP"] == 0.4 and cold["PLC.LIC2.Mode"] == int(LoopMode.AUTO)
    assert cold["PLC.LIC1.GainSource"] == int(GainSource.FIXED)
    # Model time restarted from 0: it counts this process's scans only (a loaded machine may
    # have let a scan or two run before the read), far from the warm run's time.
    t_cold, scans = cold["PLC.Status.ModelTime"], cold["PLC.Status.Scan"]
    assert t_cold == pytest.approx(max(scans - 1, 0) * cold["PLC.Status.ScanPeriod"])
    assert t_cold < t_stop / 2


async def test_plc_warm_restart_after_the_pumps_were_stopped_resumes_from_the_last_command(
    tmp_path: Path,
) -> None:
    """Safe state ``off`` (the shipped default): the PLC is killed and stays away until the plant's
    watchdog has stopped the pumps; the restarted PLC starts from P1's last command, not from 0,
    and T1 comes back to its setpoint (issue 21: the cold restart let T1 fall from 0.410 to
    0.354 m and restarted from MV 0)."""
    s = SampledStack(tmp_path, safe_state="off")
    try:
        await s.start_plant()
        await s.start_plc()

        async def regulating() -> bool:
            await s.sample()
            got = await read_nodes(s.plc_url, ["PLC.Status.IoHealthy", "PLC.IO.LT1.PV"])
            return bool(got["PLC.Status.IoHealthy"]) and abs(got["PLC.IO.LT1.PV"] - 0.4) < 0.003

        await wait_until(regulating, 120, what="the PLC regulating at the operating point")
        await s.run_for(20.0)
        assert s.plc is not None
        await s.plc.kill()
        start = len(s.samples)

        async def pumps_off() -> bool:
            await s.sample()
            return s.watchdog

        await wait_until(pumps_off, 30, what="the plant's watchdog stopping the pumps")
        await s.run_for(5.0)
        await s.start_plc()
        await s.run_for(100.0)
        # And 100 scans of the restarted PLC: on a busy machine it scans fewer times per second
        # of the plant's model time, and the recovery is the loop's, scan by scan.
        scan_s = SITE.plc.scan_period_s if SITE.plc else 1.0

        async def scanned() -> bool:
            await s.sample()
            return len(trace_rows(s.traces()[1])) >= 100.0 / scan_s

        await wait_until(scanned, 240, what="100 scans of the restarted PLC")
    finally:
        await s.down()
    old, new = trace_rows(s.traces()[0]), trace_rows(s.traces()[1])
    assert new[0]["scan"] == old[-1]["scan"] + 1 or new[0]["scan"] == old[-1]["scan"]
    assert new[0]["P1_cmd"] > 0.5 * old[-1]["P1_cmd"]  # from the last command, not from 0
    low = min(h for _, h in s.samples[start:])
    end = s.samples[-1][1]
    print(
        f"safe state off: P1 {old[-1]['P1_cmd']:.6g} -> {new[0]['P1_cmd']:.6g} m^3/s at the first scan; "
        f"T1 lowest {low:.4f} m (setpoint 0.40), {end:.4f} m 100 s after the restart"
    )
    # The sag is the gap's (no pump while the PLC is away); from the restart on T1 climbs back,
    # more than half the way to its setpoint in 100 s (the loop's full recovery, within 400 s of
    # model time, is test_failures.py's). How deep the sag is depends on how early the restarted
    # PLC holds the pumps (decision 0026), not asserted here.
    assert low < 0.40 - 0.005
    assert end - low > 0.5 * (0.40 - low)
