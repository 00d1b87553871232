"""Warm restart, pure parts: the PLC's retentive memory round trip, the bumpless resume from the
plant, the durable atomic write, the plant's checkpoint of every setting and its per-pump
watchdog safe state (decision 0019)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest

from helpers import ROOT
from plant_sim.plant import PlantSimulator
from plant_sim.server import PlantServer
from plc_emulator.program import PlcProgram, ScanInputs
from plc_emulator.publish import status_values
from tanklab.config import SiteConfig, load_site
from tanklab.enums import GainSource, LoopMode, SensorFault
from tanklab_io import persist

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
"""Two PID loops (LIC1 on T1/P1, LIC2 on T2/P2, errors in m), high-high trips on T1 and T2."""

RETENTIVE = ("SP", "SPLow", "SPHigh", "Mode", "ManualMV", "Kp", "Ki", "Kd", "GainSource", "MV")


def _scan(program: PlcProgram, levels: list[float], t_s: float | None = None) -> None:
    t = program.next_scan_t_s if t_s is None else t_s
    program.scan(ScanInputs(t, np.array(levels), np.ones(len(levels), dtype=bool)))


def _retentive_values(program: PlcProgram) -> dict[str, Any]:
    v = status_values(program.status())
    keys = [f"PLC.{lp}.{item}" for lp in SITE.loop_names for item in RETENTIVE]
    keys += [f"PLC.Interlock.{t}HH" for t in ("T1", "T2")] + ["PLC.Status.Scan", "PLC.Status.ModelTime"]
    return {k: v[k] for k in keys}


def _configured_program() -> PlcProgram:
    """A program after some scans with every retentive value away from the config."""
    p = PlcProgram(SITE)
    for _ in range(3):
        _scan(p, [0.39, 0.21, 0.3])
    p.set_sp("LIC1", 0.45)
    p.set_sp_limits("LIC2", 0.1, 0.5)
    p.set_mode("LIC2", LoopMode.MANUAL)
    p.set_manual_mv("LIC2", 5.0e-5)
    assert p.stage_gains("LIC1", 5.0e-4, 6.0e-6, -1.0e-4, GainSource.ENGINEER).value == "Good"
    _scan(p, [0.59, 0.21, 0.3])  # T1 at 0.59 m >= high-high 0.58 m: trips and latches
    _scan(p, [0.50, 0.21, 0.3])
    return p


def test_retained_data_round_trips_every_field_through_json() -> None:
    a = _configured_program()
    data = json.loads(json.dumps(a.retained()))
    assert data["scan"] == 5 and data["t_s"] == 4.0  # five scans at Ts = 1 s: the last one at t = 4 s
    assert data["tripped"] == ["T1"]
    assert data["loops"]["LIC1"]["source"] == "ENGINEER"
    assert data["loops"]["LIC1"]["gains"] == [5.0e-4, 6.0e-6, -1.0e-4]
    assert data["loops"]["LIC2"]["mode"] == "MANUAL" and data["loops"]["LIC2"]["manual_mv"] == 5.0e-5
    assert data["loops"]["LIC2"]["sp_limits_m"] == [0.1, 0.5]

    b = PlcProgram(SITE)
    assert b.restore_retained(data) == []
    assert b.retained() == a.retained()
    assert _retentive_values(b) == _retentive_values(a)
    # Model time and the scan counter continue: the next scan is scan 6 at t = 5 s.
    assert b.next_scan_t_s == 5.0
    _scan(b, [0.50, 0.21, 0.3])
    assert b.scan_count == 6 and b.t_s == 5.0
    # An engineer's hold survives: the supervisor is still kept off LIC1's gains.
    assert b.engineer_holds("LIC1")
    assert b.loop("LIC1").source is GainSource.ENGINEER


def test_retained_values_are_checked_as_if_written_now() -> None:
    data = _configured_program().retained()
    data["scan"] = -1
    data["loops"]["LIC1"]["sp_m"] = 0.9  # above sp_max_m 0.6
    b = PlcProgram(SITE)
    skipped = b.restore_retained(data)
    assert len(skipped) == 2 and "scan" in skipped[0] and skipped[1].startswith("LIC1")
    assert b.scan_count == 0 and b.loop("LIC1").sp_m == 0.4  # the cold-start values, not half-applied
    assert b.loop("LIC2").mode is LoopMode.MANUAL  # the other loop restored


def test_warm_start_first_scan_continues_from_the_pumps_command_without_a_jump() -> None:
    """Hand-computed: LIC1 (Kp 4.29e-4, Ki 5.32e-6 1/s, Kd -1.42e-4 s, Ts 1 s, errors in m, b = c = 1)
    at SP 0.40 m; the plant's P1 command 6.0e-5 m^3/s and T1 reading 0.39 m before the first scan.
    The first scan with the same reading is the velocity form's increment from 6.0e-5 with no
    proportional or derivative part: u = 6.0e-5 + Ki * Ts * (0.40 - 0.39) = 6.00532e-5."""
    cold = PlcProgram(SITE)
    data = json.loads(json.dumps(cold.retained()))
    warm = PlcProgram(SITE)
    warm.restore_retained(data)
    warm.resume_from_plant(np.array([6.0e-5, 3.0e-5]), np.array([0.39, 0.2, 0.3]), np.ones(3, dtype=bool))
    v = status_values(warm.status())
    assert v["PLC.LIC1.MV"] == 6.0e-5 and v["PLC.LIC2.MV"] == 3.0e-5  # shown before the first scan
    assert v["PLC.LIC1.PV"] == 0.39 and v["PLC.IO.LT3.PV"] == 0.3
    out = warm.scan(ScanInputs(warm.next_scan_t_s, np.array([0.39, 0.2, 0.3]), np.ones(3, dtype=bool)))
    assert out.commands[0] == pytest.approx(6.0e-5 + 5.32e-6 * 1.0 * 0.01, rel=1e-12, abs=0)
    assert out.commands[1] == pytest.approx(3.0e-5, rel=0, abs=1e-18)  # LIC2 at its SP: no move
    # The cold start from the same reading: the output starts from the config's initial command
    # (0) with a proportional kick from e(-1) = 0, far from the pump's 6.0e-5.
    cold_out = cold.scan(ScanInputs(0.0, np.array([0.39, 0.2, 0.3]), np.ones(3, dtype=bool)))
    assert abs(cold_out.commands[0] - 6.0e-5) > 5.0e-5


def test_warm_start_in_remote_holds_the_pumps_command_and_manual_applies_the_operators_value() -> None:
    a = PlcProgram(SITE)
    _scan(a, [0.4, 0.2, 0.3])
    a.set_mode("LIC1", LoopMode.REMOTE)
    a.set_mode("LIC2", LoopMode.MANUAL)
    a.set_manual_mv("LIC2", 4.0e-5)
    _scan(a, [0.4, 0.2, 0.3])
    b = PlcProgram(SITE)
    assert b.restore_retained(json.loads(json.dumps(a.retained()))) == []
    b.resume_from_plant(np.array([7.0e-5, 2.0e-5]), np.array([0.4, 0.2, 0.3]), np.ones(3, dtype=bool))
    assert status_values(b.status())["PLC.LIC1.RemoteMV"] == 7.0e-5
    out = b.scan(ScanInputs(b.next_scan_t_s, np.array([0.4, 0.2, 0.3]), np.ones(3, dtype=bool)))
    assert out.commands.tolist() == [7.0e-5, 4.0e-5]


def test_warm_start_without_the_plant_resumes_from_the_retained_mv() -> None:
    a = PlcProgram(SITE)
    for _ in range(5):
        _scan(a, [0.38, 0.2, 0.3])
    mv = a.loop("LIC1").mv
    b = PlcProgram(SITE)
    b.restore_retained(json.loads(json.dumps(a.retained())))
    assert status_values(b.status())["PLC.LIC1.MV"] == mv
    b.resume_from_plant(np.array([math.nan, math.nan]), np.full(3, math.nan), np.zeros(3, dtype=bool))
    assert b.loop("LIC1").mv == mv


def test_write_atomic_is_durable_and_leaves_the_old_copy_on_failure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "var" / "plc-retain.json"
    synced: list[int] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(persist.os, "fsync", fsync)
    persist.write_json_atomic(path, {"scan": 1})
    assert persist.read_json(path) == {"scan": 1}
    assert len(synced) == 2  # the file's data before the rename, the directory after it
    assert (path.stat().st_mode & 0o777) == 0o600

    def crash(src: object, dst: object) -> None:
        raise OSError("disk gone")

    monkeypatch.setattr(persist.os, "replace", crash)
    with pytest.raises(OSError, match="disk gone"):
        persist.write_json_atomic(path, {"scan": 2})
    assert persist.read_json(path) == {"scan": 1}  # a crash before the rename keeps the old copy


# ---- the plant ------------------------------------------------------------------------------


def _site_with(**plant: Any) -> SiteConfig:
    data = SITE.model_dump(mode="json")
    data["plant"].update(plant)
    return SiteConfig.model_validate(data)


def test_plant_checkpoint_restores_every_setting_and_the_server_shows_them() -> None:
    a = PlantSimulator(SITE.plant)
    a.set_commands(np.array([6.0e-5, 3.0e-5]))
    a.set_leak("T2", 0.2)
    a.set_valve("V32", 0.6)
    a.set_disturbance("T3", -1.0e-5)
    a.set_fault("LT1", SensorFault.BIAS, 0.01)
    a.advance(5.0)
    a.set_fault("LT3", SensorFault.STUCK)
    a.advance(5.0)
    snap = json.loads(json.dumps(a.snapshot()))
    b = PlantSimulator(SITE.plant)
    b.restore(snap)
    assert b.t_s == a.t_s and b.x.tolist() == a.x.tolist() and b.balance() == a.balance()
    assert b.readings[2] == a.readings[2]  # STUCK: frozen at the value it had
    shown = PlantServer(SITE, b, "127.0.0.1", 0, cast(Any, None)).writable_values()
    assert shown["Plant.T2.Leak"] == 0.2 and shown["Plant.T1.Leak"] == 0.0
    assert shown["Plant.V32.Opening"] == 0.6 and shown["Plant.V13.Opening"] == 1.0
    assert shown["Plant.T3.Disturbance"] == -1.0e-5
    assert shown["Plant.LT1.Fault"] == int(SensorFault.BIAS) and shown["Plant.LT1.FaultValue"] == 0.01
    assert shown["Plant.LT3.Fault"] == int(SensorFault.STUCK)
    assert shown["Plant.P1.Command"] == 6.0e-5 and shown["Plant.P2.Command"] == 3.0e-5
    # The restored model goes on exactly as the original (noise aside: LT readings draw fresh noise).
    assert b.advance(3.0) is not None and a.advance(3.0) is not None
    assert b.x.tolist() == a.x.tolist()


def test_plant_checkpoint_without_faults_still_restores() -> None:
    """A state file written before faults were checkpointed resumes with no faults."""
    a = PlantSimulator(SITE.plant)
    a.set_leak("T1", 0.1)
    snap = a.snapshot()
    for key in ("faults", "fault_values", "fault_since_s", "last_readings"):
        del snap[key]
    b = PlantSimulator(SITE.plant)
    b.restore(snap)
    assert b.inputs.leak_openings.tolist() == [0.1, 0.0, 0.0]
    assert b.transmitters.fault == [SensorFault.NONE] * 3


def test_plant_checkpoint_refuses_a_broken_file_and_changes_nothing() -> None:
    a = PlantSimulator(SITE.plant)
    snap = a.snapshot()
    snap["leak_openings"] = [0.1, 2.0, 0.0]
    b = PlantSimulator(SITE.plant)
    with pytest.raises(ValueError, match="openings"):
        b.restore(snap)
    assert b.inputs.leak_openings.tolist() == [0.0, 0.0, 0.0]


def test_watchdog_safe_state_is_per_pump() -> None:
    pumps = SITE.model_dump(mode="json")["plant"]["pumps"]
    pumps[0]["watchdog_safe_state"] = "hold"  # P1 holds; P2 follows the plant's default (off)
    site = _site_with(pumps=pumps)
    assert [site.plant.pump_safe_state(p) for p in ("P1", "P2")] == ["hold", "off"]
    sim = PlantSimulator(site.plant)
    sim.set_commands(np.array([6.0e-5, 3.0e-5]))
    sim.advance(site.plant.watchdog.command_timeout_s)
    sim.advance(1.0)  # the timeout has passed: the watchdog trips at the start of this step
    assert sim.watchdog_tripped
    assert sim.inputs.pump_commands.tolist() == [6.0e-5, 0.0]
    assert sim.commands.tolist() == [6.0e-5, 3.0e-5]  # the last written commands stay shown
    sim.set_commands(np.array([5.0e-5, 2.0e-5]))  # the next command ends the safe state
    assert not sim.watchdog_tripped and sim.inputs.pump_commands.tolist() == [5.0e-5, 2.0e-5]


def test_default_safe_state_is_the_plant_watchdogs() -> None:
    assert SITE.plant.pumps[0].watchdog_safe_state is None
    assert SITE.plant.pump_safe_state("P1") == SITE.plant.watchdog.safe_state == "off"


# ---- warm or cold (the runtime's choice) ----------------------------------------------------


def test_warm_restart_only_when_the_file_exists_and_not_cold(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from plc_emulator.runtime import _warm_restore

    retain = tmp_path / "plc-retain.json"
    caplog.set_level("INFO", logger="plc_emulator.runtime")
    assert not _warm_restore(PlcProgram(SITE), None, cold=False)
    assert not _warm_restore(PlcProgram(SITE), retain, cold=False)  # configured, none there yet
    assert "no retentive memory at" in caplog.text
    persist.write_json_atomic(retain, _configured_program().retained())
    cold = PlcProgram(SITE)
    assert not _warm_restore(cold, retain, cold=True)
    assert "cold start from the config (--cold)" in caplog.text
    assert cold.scan_count == 0 and cold.loop("LIC1").sp_m == 0.4
    warm = PlcProgram(SITE)
    assert _warm_restore(warm, retain, cold=False)
    assert "warm restart from" in caplog.text and "at scan 5, t = 4.0 s" in caplog.text
    assert warm.loop("LIC1").sp_m == 0.45
    retain.write_text("{not json", encoding="utf-8")
    assert not _warm_restore(PlcProgram(SITE), retain, cold=False)  # broken: cold, and says so
    assert "unreadable" in caplog.text


async def test_retained_store_writes_off_the_scan_and_the_latest_state_wins(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from plc_emulator import runtime

    path = tmp_path / "plc-retain.json"
    store = runtime.RetainedStore(path)
    for scan in range(1, 6):  # five snapshots before the writer ran: only the latest is written
        store.offer({"scan": scan})
    await store.close()
    assert persist.read_json(path) == {"scan": 5}
    assert store.writes == 1 and store.stored == {"scan": 5}
    store.offer({"scan": 5})  # unchanged: nothing to write
    await store.close()
    assert store.writes == 1

    def full(p: Path, data: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(runtime, "write_json_atomic", full)
    store.offer({"scan": 6})
    await store.close()
    assert persist.read_json(path) == {"scan": 5} and store.stored == {"scan": 5}  # the old copy stays
    monkeypatch.undo()
    store.offer({"scan": 6})  # the next offer tries again
    await store.close()
    assert persist.read_json(path) == {"scan": 6}
