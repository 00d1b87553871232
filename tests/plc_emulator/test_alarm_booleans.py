"""The alarm manager's booleans equal today's ``PLC.Alarms.*`` values scan for scan, for every
shipped PLC config, when the level deadbands are 0 (the meaning the contract keeps)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from plc_emulator.program import PlcProgram, ScanInputs
from tanklab import paths
from tanklab.alarms import names
from tanklab.alarms.definitions import plc_alarms
from tanklab.alarms.manager import AlarmInput, AlarmManager
from tanklab.alarms.model import ConditionKind
from tanklab.config import load_site

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = [p for p in sorted((ROOT / "configs").glob("*.yaml")) if load_site(p).plc is not None]


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_booleans_match_the_program_values(path: Path) -> None:
    site = load_site(path)
    program = PlcProgram(site)
    defs = tuple(
        replace(d, deadband_m=0.0) if d.kind is ConditionKind.EXCLUSIVE_LEVEL else d for d in plc_alarms(site)
    )
    alarms = AlarmManager(defs, event_prefix=b"t")
    rng = np.random.default_rng(15)
    n = program.n_tanks
    hmax = np.array([t.height_max_m for t in site.plant.tanks])
    checked = 0
    for k in range(400):
        t_s = k * program.ts_s
        levels = rng.uniform(-0.05, 1.1, n) * hmax
        levels[rng.random(n) < 0.05] = math.nan
        delivered = rng.random(n) > 0.1
        io = bool(rng.random() > 0.05)
        if rng.random() < 0.6:
            program.heartbeat(k)
        if k % 50 == 0:
            program.reset_interlocks()
        values = program.scan(ScanInputs(t_s=t_s, levels_m=levels, good=delivered, io_healthy=io)).values
        good = program.good
        inputs = {}
        for i, tank in enumerate(site.tank_names):
            raw = levels[i] if delivered[i] and io and math.isfinite(levels[i]) else math.nan
            inputs[names.level(tank)] = AlarmInput(float(raw), bool(good[i]))
        for lp in program.loops:
            inputs[names.pv_bad(lp.spec.name)] = AlarmInput(bool(lp.pv_bad))
        inputs[names.IO_FAULT] = AlarmInput(not program.io_healthy)
        wd = program.watchdog
        inputs[names.SUPERVISOR_LOST] = AlarmInput(bool(wd.ever_alive and not wd.alive))
        for il in program.interlocks:
            inputs[names.trip(il.tank_name)] = AlarmInput(bool(il.tripped))
        alarms.scan(inputs, t_s)
        got = alarms.booleans()
        assert got == {p: values[p] for p in got}, f"scan {k}"
        checked += sum(got.values())
    assert checked > 100  # the trace does raise alarms
    assert set(got) == {p for p in values if p.startswith(paths.plc.alarms_prefix)}
