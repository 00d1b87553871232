"""The PLC program's typed status and its mapping to the nodes (plc_emulator.status, .publish).

``PlcProgram.status()`` replaced ``PlcProgram.values()``, which built the published dict inside
the pure core. What the server publishes must not change: the same paths, the same Python types,
the same values, in the same order. Each shipped config with a PLC is driven through a few
hundred scans of random requests (modes, held outputs, setpoints and their limits, gain sets of
both sources, resets and releases, interlock resets) and field faults (bad flags, NaN, lost
link, over-range, frozen readings, high-high trips, the supervisor alive, lost and back), and
after every scan, before the first and after a warm restart:

- the mapped keys are exactly the PLC variables of the contract (``tanklab.tags.plc_tags``) that
  the program owns, each once, each value of its tag's Python type;
- every value equals the old ``values()``'s, of the same type, in the old order (the oracle
  below: that function as it was, reading the program's state; a field added to the status
  later adds nodes, which the contract check covers, and leaves these untouched).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from plc_emulator.program import PlcProgram, ScanInputs
from plc_emulator.publish import RUNTIME_OWNED_TAGS, status_values
from plc_emulator.status import LoopStatus, PlcStatus
from tanklab import paths
from tanklab.config import site_from_mapping
from tanklab.enums import GainSource, LoopMode
from tanklab.tag_model import DataType
from tanklab.tags import identity_paths, plc_tags

ROOT = Path(__file__).resolve().parents[2]
PLC_CONFIGS = sorted(p for p in (ROOT / "configs").glob("*.yaml") if "plc:" in p.read_text())
SCANS = 300
WATCHDOG_SCANS = 20
"""The heartbeat timeout of the test's programs, in scans (the configs' are longer than a run)."""
PY_TYPE = {DataType.DOUBLE: float, DataType.INT32: int, DataType.UINT32: int, DataType.BOOLEAN: bool}


def old_values(program: PlcProgram) -> dict[str, Any]:
    """The oracle: ``PlcProgram.values()`` as it was before the typed status (commit 3d27bfc),
    with the ``PLC.Alarms.*`` booleans the alarm manager's (as the alarm core made them: with no
    deadband and no delays they are the old comparisons, which test_alarm_booleans.py checks)."""
    alarms = program.alarms.booleans()
    v: dict[str, Any] = {}
    for lp in program.loops:
        n = paths.plc.loop(lp.spec.name)
        v[n.sp] = float(lp.sp_m)
        v[n.sp_low], v[n.sp_high] = program.sp_limits(lp.spec.name)
        v[n.pv] = float(lp.pv_last_good_m)
        v[n.mv] = float(lp.mv)
        v[n.mode] = int(lp.mode)
        v[n.manual_mv] = float(lp.manual_mv)
        v[n.remote_mv] = float(lp.remote_mv)
        g = lp.applied
        v[n.kp] = float(g.kp) if g else 0.0
        v[n.ki] = float(g.ki) if g else 0.0
        v[n.kd] = float(g.kd) if g else 0.0
        v[n.gain_source] = int(lp.source)
        v[paths.plc.pv_bad_alarm(lp.spec.name)] = alarms[paths.plc.pv_bad_alarm(lp.spec.name)]
    v[paths.plc.scan] = int(program.scan_count)
    v[paths.plc.io_healthy] = bool(program.io_healthy)
    v[paths.plc.model_time] = float(program.t_s)
    v[paths.plc.supervisor_alive] = bool(program.watchdog.alive)
    v[paths.plc.io_fault] = alarms[paths.plc.io_fault]
    v[paths.plc.supervisor_lost] = alarms[paths.plc.supervisor_lost]
    for i, name in enumerate(program.site.tank_names):
        ok = program._good[i]
        io = paths.plc.io(name)
        v[io.pv] = program._last_good_m[i]
        v[io.good] = ok
        for kind in ("H", "L", "HH"):
            v[paths.plc.alarm(name, kind)] = alarms[paths.plc.alarm(name, kind)]
    for il in program.interlocks:
        v[paths.plc.interlock(il.tank_name)] = bool(il.tripped)
    return v


class Checker:
    """Compares one program's mapped status with the contract and the oracle."""

    def __init__(self, program: PlcProgram) -> None:
        tags = plc_tags(program.site)
        skip = set(RUNTIME_OWNED_TAGS) | set(identity_paths("plc").values())
        owned = [
            t for t in tags if t.kind == "variable" and t.path not in skip and not t.path.endswith(".Block")
        ]
        assert owned and len({t.path for t in owned}) == len(owned)
        self.types = {t.path: PY_TYPE[t.data_type] for t in owned if t.data_type is not None}
        assert len(self.types) == len(owned)  # every owned variable has a scalar type
        self.checked = 0

    def check(self, program: PlcProgram, status: PlcStatus | None = None) -> dict[str, Any]:
        status = program.status() if status is None else status
        mapped = status_values(status)
        assert set(mapped) == set(self.types)  # every owned variable, nothing else (dict: once)
        for path, value in mapped.items():
            assert type(value) is self.types[path], (path, value)
        expected = old_values(program)
        assert [p for p in mapped if p in expected] == list(expected)  # the old order
        for path, value in expected.items():
            assert type(mapped[path]) is type(value), path
            assert mapped[path] == value, (path, mapped[path], value)
        self.checked += 1
        return mapped


class Driver:
    """Random requests and field faults on a program, reproducible from a seed."""

    def __init__(self, program: PlcProgram, seed: int) -> None:
        self.p = program
        self.rng = np.random.default_rng(seed)
        self.levels = np.array([t.initial_level_m for t in program.site.plant.tanks], dtype=float)
        self.beat = 0
        self.k = 0
        self.frozen_for = 0
        self.seen: set[str] = set()  # what happened, to show the run covered it

    def requests(self) -> None:
        p, rng = self.p, self.rng
        # Heartbeat: alive for 60 scans, away for 60 (lost after WATCHDOG_SCANS), back from then
        # on; the supervisor's gains on every PID loop at scan 40, so that they fall back at 80.
        if not 60 <= self.k < 120:
            self.beat += 1
            p.heartbeat(self.beat)
        if self.k == 40:
            for lp in p.loops:
                if lp.fixed is not None:
                    f = lp.fixed
                    p.release_gains(lp.spec.name)  # an engineer's hold would refuse them
                    p.stage_gains(lp.spec.name, f.kp, f.ki, f.kd)
        for lp in p.loops:
            name = lp.spec.name
            r = rng.random()
            if 40 <= self.k < 100 and r >= 0.18:
                continue  # no other gain request until the supervisor's gains have fallen back
            try:
                if r < 0.04:
                    p.set_mode(name, LoopMode(int(rng.integers(0, 3))))
                elif r < 0.08:
                    p.set_manual_mv(name, float(rng.uniform(lp.mv_min, lp.mv_max)))
                elif r < 0.12:
                    p.set_remote_mv(name, float(rng.uniform(lp.mv_min, lp.mv_max)))
                elif r < 0.16:
                    lo, hi = p.sp_limits(name)
                    p.set_sp(name, float(rng.uniform(lo, hi)))
                elif r < 0.18:
                    lo, hi = lp.spec.sp_min_m, lp.spec.sp_max_m
                    a, b = sorted(rng.uniform(lo, hi, size=2).tolist())
                    p.set_sp_limits(name, min(a, lp.sp_m), max(b, lp.sp_m))
                elif r < 0.21 and lp.fixed is not None:
                    scale = float(rng.uniform(0.5, 1.5))
                    src = GainSource.SUPERVISOR if rng.random() < 0.5 else GainSource.ENGINEER
                    f = lp.fixed
                    p.stage_gains(name, f.kp * scale, f.ki * scale, f.kd * scale, src)
                elif r < 0.22:
                    p.reset_gains(name)
                elif r < 0.23:
                    p.release_gains(name)
            except ValueError:
                self.seen.add("refused")
        if rng.random() < 0.05 and p.reset_interlocks():
            self.seen.add("interlock reset")

    def inputs(self) -> ScanInputs:
        p, rng = self.p, self.rng
        n = p.n_tanks
        lo, hi = p.tr_range[:, 0], p.tr_range[:, 1]
        if self.frozen_for > 0:
            self.frozen_for -= 1  # the same readings again
        else:
            self.levels = np.clip(self.levels + rng.normal(0.0, 0.01, n), lo, hi)
            if rng.random() < 0.03:
                self.frozen_for = p.pv_frozen_scans + 2
        levels = self.levels.copy()
        good = np.ones(n, dtype=bool)
        io = True
        r = rng.random()
        k = int(rng.integers(0, n))
        if r < 0.05:
            good[k] = False
        elif r < 0.08:
            levels[k] = math.nan
        elif r < 0.10:
            io = False
        elif r < 0.13:
            levels[k] = hi[k] + 0.05  # over range: bad, and a high-high for the interlock
        elif r < 0.20 and np.isfinite(p.hh_m[k]):
            levels[k] = min(p.hh_m[k] + 0.01, hi[k])  # a trip
        elif r < 0.30:
            levels[k] = float(rng.choice([p.high_m[k], p.low_m[k], p.high_m[k] + 0.01, p.low_m[k] - 0.001]))
        return ScanInputs(p.next_scan_t_s, levels, good, io)

    def note(self, mapped: dict[str, Any]) -> None:
        for path, value in mapped.items():
            if value is True and path.startswith(paths.plc.alarms_prefix):
                self.seen.add(path[len(paths.plc.alarms_prefix) :])
            if value is True and path.startswith(paths.plc.interlocks_prefix):
                self.seen.add("tripped")
        self.seen |= {f"mode {LoopMode(lp.mode).name}" for lp in self.p.loops}
        self.seen |= {f"source {GainSource(lp.source).name}" for lp in self.p.loops}


@pytest.mark.parametrize("path", PLC_CONFIGS, ids=lambda p: p.name)
def test_mapped_status_is_what_values_published_scan_for_scan(path: Path) -> None:
    site = site_from_mapping(yaml.safe_load(path.read_text()))
    assert site.plc is not None
    program = PlcProgram(site, watchdog_timeout_s=WATCHDOG_SCANS * site.plc.scan_period_s)
    checker = Checker(program)
    checker.check(program)  # before the first scan: the server's initial publish
    drive = Driver(program, seed=sum(path.name.encode()))
    for _ in range(SCANS):
        drive.requests()
        out = program.scan(drive.inputs())
        assert out.status is not None
        drive.note(checker.check(program, out.status))
        drive.k += 1
    # A warm restart publishes what it restored, before its first scan.
    warm = PlcProgram(site)
    assert warm.restore_retained(program.retained()) == []
    warm.resume_from_plant(program.commands, drive.levels, np.ones(program.n_tanks, dtype=bool))
    checker.check(warm)
    assert checker.checked == SCANS + 2
    # The run went through what the mapping has to show (the loops' and the tanks' cases).
    must = {"mode MANUAL", "mode AUTO", "mode REMOTE", "IoFault", "SupervisorLost"}
    must |= {f"{lp.spec.name}PvBad" for lp in program.loops}
    must |= {f"{t}{a}" for t in site.tank_names for a in ("H", "L")}
    if program.interlocks:
        must |= {"tripped", "interlock reset"}
    if any(lp.fixed is not None for lp in program.loops):
        must |= {"source SUPERVISOR", "source ENGINEER", "source FALLBACK", "source FIXED"}
    assert must <= drive.seen, must - drive.seen


def test_status_is_a_frozen_value_without_node_paths() -> None:
    program = PlcProgram(
        site_from_mapping(yaml.safe_load((ROOT / "configs/three_tank_energies_sim.yaml").read_text()))
    )
    levels = np.array([t.initial_level_m for t in program.site.plant.tanks])
    first = program.scan(ScanInputs(0.0, levels, np.ones(3, dtype=bool))).status
    assert first is not None and first == program.status()  # nothing changed since the scan
    assert [lp.name for lp in first.loops] == ["LIC1", "LIC2"]
    assert [t.name for t in first.tanks] == ["T1", "T2", "T3"]
    assert isinstance(first.loops[0], LoopStatus) and first.loops[0].mode is LoopMode.AUTO
    with pytest.raises(AttributeError):
        first.loops[0].sp_m = 1.0  # type: ignore[misc]
    assert not hasattr(first, "__dict__") and not hasattr(first.loops[0], "__dict__")  # slotted
    program.set_sp("LIC1", 0.3)
    assert first.loops[0].sp_m != 0.3 and program.status().loops[0].sp_m == 0.3  # a copy, not a view
    # A scan that does not publish builds no status (the co-simulation without a supervisor).
    assert program.scan(ScanInputs(1.0, levels, np.ones(3, dtype=bool)), publish=False).status is None


def test_the_co_simulation_builds_a_status_only_for_its_supervisor(monkeypatch: pytest.MonkeyPatch) -> None:
    # Without a supervisor nobody reads the PLC's nodes: no scan builds a status (a tenth of a
    # scan's time). With one, every scan does, and the supervisor's snapshot is read from it.
    from tankctl.cosim import CoSimulation

    site = site_from_mapping(yaml.safe_load((ROOT / "configs/three_tank_energies_sim.yaml").read_text()))
    built: list[int] = []
    status = PlcProgram.status

    def counted(self: PlcProgram) -> PlcStatus:
        built.append(self.scan_count)
        return status(self)

    monkeypatch.setattr(PlcProgram, "status", counted)
    CoSimulation(site).run(20.0)
    assert built == []
    cs = CoSimulation(site, supervisor_mode="MPC")
    cs.run(5.0)
    assert built == [1, 2, 3, 4, 5]  # after each scan
    snap = cs.port.snapshot()
    assert snap is not None and snap.scan == 5 and snap.t_s == 4.0
