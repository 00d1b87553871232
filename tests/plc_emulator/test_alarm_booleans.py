"""The ``PLC.Alarms.*`` booleans, now the alarm manager's, keep today's meaning scan for scan for
every shipped PLC config: with the level deadbands at 0 they equal the formulas the program used
before the alarm core (``level >= high`` and ``level <= low`` with a good reading, ``reading >=
high_high``, the bad-PV flags, the field link, the watchdog); with the default 2 % deadband they
differ only while the reading lies inside a band that an active limit's flag is holding."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from plc_emulator.program import PlcProgram, ScanInputs
from plc_emulator.publish import status_values
from tanklab import paths
from tanklab.alarms import names
from tanklab.config import SiteConfig, load_site, site_from_mapping

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = [p for p in sorted((ROOT / "configs").glob("*.yaml")) if load_site(p).plc is not None]


def without_deadband(path: Path) -> SiteConfig:
    data: dict[str, Any] = copy.deepcopy(yaml.safe_load(path.read_text()))
    tanks = [t["name"] for t in data["plant"]["tanks"]]
    data["plc"]["alarms"] = {"overrides": {names.level(t): {"deadband_m": 0.0} for t in tanks}}
    return site_from_mapping(data)


def todays(program: PlcProgram, levels: np.ndarray, delivered: np.ndarray, io: bool) -> dict[str, bool]:
    """The booleans as ``PlcProgram.values`` computed them before the alarm core."""
    v: dict[str, bool] = {}
    for lp in program.loops:
        v[paths.plc.pv_bad_alarm(lp.spec.name)] = bool(lp.pv_bad)
    v[paths.plc.io_fault] = not program.io_healthy
    v[paths.plc.supervisor_lost] = bool(program.watchdog.ever_alive and not program.watchdog.alive)
    good = program.good
    for i, tank in enumerate(program.site.tank_names):
        raw = levels[i] if delivered[i] and io and math.isfinite(levels[i]) else math.nan
        used = levels[i] if good[i] else math.nan
        v[paths.plc.alarm(tank, "H")] = bool(good[i] and used >= program.high_m[i])
        v[paths.plc.alarm(tank, "L")] = bool(good[i] and used <= program.low_m[i])
        v[paths.plc.alarm(tank, "HH")] = bool(raw >= program.hh_m[i])
    return v


def run(site: SiteConfig, check: Any) -> int:
    """400 random scans (readings all over the range, NaN, undelivered, link failures, a
    supervisor that comes and goes, interlock resets); ``check`` per scan; return alarms seen."""
    program = PlcProgram(site)
    rng = np.random.default_rng(15)
    n = program.n_tanks
    hmax = np.array([t.height_max_m for t in site.plant.tanks])
    before = status_values(program.status())
    assert before[paths.plc.io_fault] is True  # before the first scan: as it always was
    seen = 0
    for k in range(400):
        levels = rng.uniform(-0.05, 1.1, n) * hmax
        levels[rng.random(n) < 0.05] = math.nan
        delivered = rng.random(n) > 0.1
        io = bool(rng.random() > 0.05)
        if rng.random() < 0.6:
            program.heartbeat(k)
        if k % 50 == 0:
            program.reset_interlocks()
        out = program.scan(ScanInputs(k * program.ts_s, levels, delivered, io))
        assert out.status is not None
        values = status_values(out.status)
        expect = todays(program, levels, delivered, io)
        got = {p: values[p] for p in expect}
        check(program, levels, expect, got, k)
        seen += sum(got.values())
    assert set(expect) == {p for p in values if p.startswith(paths.plc.alarms_prefix)}
    return seen


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_without_deadband_the_booleans_are_todays(path: Path) -> None:
    def check(program: PlcProgram, levels: np.ndarray, expect: dict, got: dict, k: int) -> None:
        assert got == expect, f"scan {k}"

    assert run(without_deadband(path), check) > 100  # the trace does raise alarms


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_with_the_default_deadband_they_differ_only_inside_a_band(path: Path) -> None:
    site = load_site(path)
    # boolean path -> (tank index, index of its limit in limits_m)
    limit_of = {
        paths.plc.alarm(t, kind): (i, j)
        for i, t in enumerate(site.tank_names)
        for j, kind in ((0, "HH"), (1, "H"), (2, "L"))
    }

    def check(program: PlcProgram, levels: np.ndarray, expect: dict, got: dict, k: int) -> None:
        for p, want in expect.items():
            if got[p] == want:
                continue
            assert p in limit_of and got[p] and not want, f"scan {k}: {p}"  # held, never early
            i, j = limit_of[p]
            d = program.alarms.manager.definitions[i]
            assert d.limits_m is not None
            limit = d.limits_m[j]
            assert limit is not None and abs(levels[i] - limit) <= d.deadband_m + 1e-12, f"scan {k}: {p}"

    run(site, check)
