"""Unit tests of the soft PLC's scan core (plc_emulator.program.PlcProgram), no plant.

Every scan is fed hand-built ScanInputs, so each rule of issue 3 is checked against numbers
computed by hand in the comments: velocity-form increments, error scaling to centimetres, the
scan boundary of staged gains, GainSource transitions, the watchdog's timing, interlock trips and
reset, PV-bad substitution and bumpless resumption, and bumpless mode switches of all three
blocks. Hypothesis then drives random request sequences and checks the invariants: every command
inside its pump's range, nothing NaN, never half a gain set.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plc_emulator.program import GainStatus, PlcProgram, ScanInputs, ScanOutputs
from plc_emulator.publish import RUNTIME_OWNED_TAGS, status_values
from tanklab.config import SiteConfig, site_from_mapping
from tanklab.enums import GainSource, LoopMode
from tanklab.gains import LoopGains
from tanklab.tags import ALARM_SUMMARY_ITEMS, identity_paths, plc_tags

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))
AUTO, MANUAL, REMOTE = LoopMode.AUTO, LoopMode.MANUAL, LoopMode.REMOTE
FIXED, SUPERVISOR, FALLBACK = GainSource.FIXED, GainSource.SUPERVISOR, GainSource.FALLBACK
ENGINEER = GainSource.ENGINEER

# Energies fixed gains (digest 2.1), u in m^3/s, e in m.
KP1, KI1, KD1 = 4.29e-4, 5.32e-6, -1.42e-4
KP2, KI2, KD2 = 10.83e-4, 3.94e-5, -13.51e-4
SPAN = 1.2e-4  # pump range [0, 1.2e-4] m^3/s


def raw(name: str) -> dict[str, Any]:
    """A shipped config as a plain mapping (to build variants from)."""
    data: dict[str, Any] = yaml.safe_load((ROOT / "configs" / name).read_text())
    return data


def site_of(data: dict[str, Any]) -> SiteConfig:
    return site_from_mapping(copy.deepcopy(data))


def energies(mutate: Callable[[dict[str, Any]], None] | None = None) -> SiteConfig:
    data = raw("three_tank_energies_sim.yaml")
    if mutate is not None:
        mutate(data)
    return site_of(data)


def single_tank(block: str = "nlpi", **loop: Any) -> SiteConfig:
    """The single simulation tank (b = 2, a' = 0.5, Ts = 0.1 s, pump 0..0.2) with one loop."""
    data = raw("single_tank_short_sim.yaml")
    lp = data["plc"]["loops"][0]
    lp["block"] = block
    if block == "pid":
        # The linearisation at 0.15 m (a = a'/(2 sqrt h) = 0.645) placed at wn 0.5, zeta 0.7071.
        lp["gains"] = {"kp": 0.0310, "ki": 0.125, "kd": 0.0}
    if block == "mrac":
        lp["mrac"] = {"law": "mit", "wn_rad_s": 0.5, "gamma": 0.5, "delta": 0.7}
    lp.update(loop)
    return site_of(data)


def inputs(
    t: float, levels: Sequence[float], good: Sequence[bool] | None = None, io: bool = True
) -> ScanInputs:
    lv = np.array(levels, dtype=float)
    g = np.ones(len(lv), dtype=bool) if good is None else np.array(good, dtype=bool)
    return ScanInputs(t, lv, g, io)


class Rig:
    """A PlcProgram with a scan counter for its model time (t = k Ts)."""

    def __init__(self, site: SiteConfig, **kw: Any) -> None:
        self.plc = PlcProgram(site, **kw)
        self.k = 0
        self.t0 = 0.0

    def scan(self, levels: Sequence[float], **kw: Any) -> ScanOutputs:
        out = self.plc.scan(inputs(self.t0 + self.k * self.plc.ts_s, levels, **kw))
        self.k += 1
        return out

    def trust(self, levels: Sequence[float], scans: int = 3) -> None:
        """Heartbeat for ``scans`` scans so the supervisor becomes trusted."""
        for _ in range(scans):
            self.plc.heartbeat(1000 + self.k)
            self.scan(levels)


def published(out: ScanOutputs) -> dict[str, Any]:
    """The PLC's node values of a scan, as the server publishes them."""
    assert out.status is not None
    return status_values(out.status)


def mv(out: ScanOutputs, loop: str) -> float:
    value: float = published(out)[f"PLC.{loop}.MV"]
    return value


# =========================================================================== publishing
@pytest.mark.parametrize("path", [p for p in CONFIGS if "plc:" in p.read_text()], ids=lambda p: p.name)
def test_values_publish_exactly_the_program_owned_plc_tags(path: Path) -> None:
    site = site_of(yaml.safe_load(path.read_text()))
    program = PlcProgram(site)
    expected = {
        t.path
        for t in plc_tags(site)
        if t.kind == "variable"
        and t.path not in RUNTIME_OWNED_TAGS
        and not t.path.endswith(".Block")
        and t.path not in identity_paths("plc").values()
    }
    assert set(RUNTIME_OWNED_TAGS) == {
        "PLC.Status.ScanPeriod",
        "PLC.Status.LastScanDuration",
        "PLC.Status.Overruns",
        "PLC.Supervisor.Heartbeat",
        "PLC.Supervisor.Timeout",
        "PLC.External.Heartbeat",
        "PLC.External.Timeout",
        "PLC.Status.PlantLink.Attempts",
        "PLC.Status.PlantLink.Connects",
        "PLC.Status.PlantLink.LastError",
        "PLC.Status.PlantLink.RetryDelay",
        *(f"PLC.AlarmSummary.{item}" for item in ALARM_SUMMARY_ITEMS),
    }
    # before the first scan too (the server's initial publish)
    assert set(status_values(program.status())) == expected
    levels = [t.initial_level_m for t in site.plant.tanks]
    out = program.scan(inputs(0.0, levels))
    assert set(published(out)) == expected
    out = program.scan(inputs(program.ts_s, [math.nan] * len(levels), io=False))
    assert set(published(out)) == expected
    for path_, value in published(out).items():  # plain Python types, never NaN
        assert type(value) in (int, float, bool), path_
        assert not (isinstance(value, float) and not math.isfinite(value)), path_


def test_scan_state_arrays_are_new_copies_that_match_the_published_values() -> None:
    # The scan keeps its per-tank and per-pump state in lists; levels_m, good, last_good_m and
    # commands are arrays built on each read, and each scan hands out a commands array of its own
    # (the co-simulation keeps it, read-only, in its trace).
    rig = Rig(energies())
    plc = rig.plc
    assert plc.commands.tolist() == [0.0, 0.0] and plc.last_good_m.tolist() == [0.0, 0.0, 0.0]
    assert np.isnan(plc.levels_m).all() and not plc.good.any()  # before the first scan
    first = rig.scan([0.3, 0.2, 0.25])
    first.commands.flags.writeable = False
    out = rig.scan([0.31, math.nan, 0.7])  # T2 not finite, T3 over range
    assert out.commands is not first.commands and out.commands.flags.writeable
    assert plc.commands.tolist() == out.commands.tolist() and plc.commands is not plc.commands
    assert plc.levels_m.dtype == np.float64 and plc.good.dtype == np.bool_
    assert plc.good.tolist() == [True, False, False]
    assert np.array_equal(plc.levels_m, [0.31, math.nan, math.nan], equal_nan=True)
    assert plc.last_good_m.tolist() == [0.31, 0.2, 0.25]
    for i, name in enumerate(("1", "2", "3")):
        assert published(out)[f"PLC.IO.LT{name}.PV"] == plc.last_good_m[i]
        assert published(out)[f"PLC.IO.LT{name}.Good"] is bool(plc.good[i])
    plc.commands[:] = 1.0  # writing to a copy changes nothing in the program
    plc.last_good_m[:] = 1.0
    assert plc.commands.tolist() == out.commands.tolist()
    assert plc.last_good_m.tolist() == [0.31, 0.2, 0.25]


# =========================================================================== velocity-form PID
def test_velocity_form_increments_three_scans_by_hand() -> None:
    # LIC1, SP 0.4, u(-1) = 0, e(-1) = e(-2) = 0 (digest 2.1), PV 0.30, 0.32, 0.33:
    # k=0: e=0.10  P = 4.29e-4 (0.10)        = 4.290e-5
    #              I = 5.32e-6 (0.10)        = 5.320e-7
    #              D = -1.42e-4 (0.10)       = -1.420e-5   u0 = 2.9232e-5
    # k=1: e=0.08  P = 4.29e-4 (-0.02)       = -8.580e-6
    #              I = 5.32e-6 (0.08)        = 4.256e-7
    #              D = -1.42e-4 (0.08-0.20)  = 1.704e-5    u1 = 3.81176e-5
    # k=2: e=0.07  P = 4.29e-4 (-0.01)       = -4.290e-6
    #              I = 5.32e-6 (0.07)        = 3.724e-7
    #              D = -1.42e-4 (0.07-0.16+0.10) = -1.420e-6  u2 = 3.27800e-5
    rig = Rig(energies())
    expected = [2.9232e-5, 3.81176e-5, 3.27800e-5]
    for h1, u in zip([0.30, 0.32, 0.33], expected, strict=True):
        out = rig.scan([h1, 0.2, 0.25])
        assert mv(out, "LIC1") == pytest.approx(u, rel=1e-9, abs=1e-15)
        assert out.commands[0] == mv(out, "LIC1")
    # LIC2 saw e = 0 all along: MV stays at u(-1) = 0.
    assert out.commands[1] == 0.0
    assert published(out)["PLC.Status.Scan"] == 3
    assert published(out)["PLC.Status.ModelTime"] == 2.0


@pytest.mark.parametrize(("c", "kick"), [(None, 0.0), (0.0, 0.0), (1.0, 1e-2 * 0.02 / 0.1)])
def test_pid_setpoint_weights_come_from_the_config(c: float | None, kick: float) -> None:
    # Single tank PID, Ts = 0.1 s, Kp 0.031, Ki 0.125, Kd 1e-2, pump at 0.05 (inside 0..0.2).
    # Settled at SP = PV = 0.1 (three scans flush the zero memory), then SP 0.1 -> 0.12.
    # The step's increment: Kp 0.02 (b = 1) + Ki Ts 0.02 + the D kick: Kd 0.02 / Ts = 2e-3 with
    # c = 1 (D on the error), none with c = 0, the site default (derivative on the measurement).
    loop: dict[str, Any] = {"gains": {"kp": 0.031, "ki": 0.125, "kd": 1e-2}, "setpoint_m": 0.1}
    if c is not None:
        loop["setpoint_weight_d"] = c
    site = single_tank("pid", **loop)
    data = site.model_dump(mode="json")
    data["plant"]["pumps"][0]["initial_command"] = 0.05
    rig = Rig(site_of(data))
    lp = rig.plc.loop("LIC1")
    assert lp.pid is not None
    assert [w.tolist() for w in lp.pid.setpoint_weights] == [[1.0], [0.0 if c is None else c]]
    for _ in range(3):
        before = mv(rig.scan([0.1]), "LIC1")
    assert 0.0 < before < 0.2
    rig.plc.set_sp("LIC1", 0.12)
    after = mv(rig.scan([0.1]), "LIC1")
    assert after - before == pytest.approx(0.031 * 0.02 + 0.125 * 0.1 * 0.02 + kick, rel=1e-9)


def test_rig_errors_are_in_centimetres() -> None:
    # Rig: Kp 100, Ki 1, Kd 10 in rpm per cm (digest 2.1), SP 0.40 m = 40 cm, u(-1) = 0.
    # k=0: PV 0.35 m: e = 5 cm:  P = 500, I = 5, D = 10 (5)           = 50   u0 = 555 rpm
    # k=1: PV 0.36 m: e = 4 cm:  P = -100, I = 4, D = 10 (4 - 10 + 0) = -60  u1 = 399 rpm
    # (with e in metres the first move would be 5.55 rpm.)
    site = site_of(raw("three_tank_energies_rig.yaml"))
    rig = Rig(site)
    out0 = rig.scan([0.35, 0.2, 0.25])
    out1 = rig.scan([0.36, 0.2, 0.25])
    assert mv(out0, "LIC1") == pytest.approx(555.0, rel=1e-12)
    assert mv(out1, "LIC1") == pytest.approx(399.0, rel=1e-12)
    lp = rig.plc.loop("LIC1")
    assert lp.pid is not None
    assert lp.pid.working_sp[0] == pytest.approx(40.0)  # the block works in cm
    cfg = lp.pid.config
    assert np.asarray(cfg.sp_max) == pytest.approx([60.0])  # sp_max_m 0.6 scaled to cm
    assert published(out1)["PLC.LIC1.SP"] == 0.4  # published in metres
    assert published(out1)["PLC.LIC1.PV"] == 0.36


def test_cross_gains_couple_loops_in_one_mimo_block() -> None:
    # LIC1 also acts on LIC2's error with Kp 1e-4, Ki 1e-6: P1 gets both contributions.
    # k=0: e1 = 0.10, e2 = 0.05: u1 = 2.9232e-5 + 1e-4 (0.05) + 1e-6 (0.05) = 3.42820e-5
    def mutate(d: dict[str, Any]) -> None:
        d["plc"]["loops"][0]["cross_gains"] = {"LIC2": {"kp": 1e-4, "ki": 1e-6, "kd": 0.0}}

    rig = Rig(energies(mutate))
    assert len(rig.plc.pid_groups) == 1
    out = rig.scan([0.30, 0.15, 0.25])
    assert mv(out, "LIC1") == pytest.approx(3.42820e-5, rel=1e-9)


def test_coupled_loops_must_share_pv_bad_scans() -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["plc"]["loops"][0]["cross_gains"] = {"LIC2": {"kp": 1e-4, "ki": 1e-6}}
        d["plc"]["loops"][1]["pv_bad_scans"] = 5

    with pytest.raises(ValueError, match="must share pv_bad_scans"):
        PlcProgram(energies(mutate))


def test_mv_range_never_leaves_the_pump_range() -> None:
    def wide(d: dict[str, Any]) -> None:
        d["plc"]["loops"][0].update(mv_min=-1.0, mv_max=1.0)

    lp = PlcProgram(energies(wide)).loop("LIC1")
    assert (lp.mv_min, lp.mv_max) == (0.0, 1.2e-4)

    def disjoint(d: dict[str, Any]) -> None:
        d["plc"]["loops"][0].update(mv_min=2e-4, mv_max=3e-4)

    with pytest.raises(ValueError, match="does not overlap"):
        PlcProgram(energies(disjoint))


def test_bad_input_shape_is_refused_before_anything_changes() -> None:
    plc = PlcProgram(energies())
    plc.heartbeat(1)
    with pytest.raises(ValueError, match="3 levels"):
        plc.scan(inputs(5.0, [0.1, 0.2]))
    assert plc.scan_count == 0 and plc.t_s == 0.0 and plc.watchdog.last_value is None


# =========================================================================== gain staging
def test_staged_gains_take_effect_exactly_at_the_next_scan_boundary() -> None:
    rig = Rig(energies())
    levels = [0.39, 0.2, 0.25]  # e1 = 0.01 every scan
    rig.trust(levels)
    assert rig.plc.supervisor_trusted
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0) is GainStatus.STAGED
    lp = rig.plc.loop("LIC1")
    # Nothing changes before the boundary: applied gains, source, published values, block gains.
    assert lp.applied is not None and (lp.applied.kp, lp.applied.ki, lp.applied.kd) == (KP1, KI1, KD1)
    assert lp.source is FIXED and status_values(rig.plc.status())["PLC.LIC1.Kp"] == KP1
    assert lp.pid is not None and lp.pid.gains.ki[0, 0] == KI1
    u_before = lp.mv
    out = rig.scan(levels)
    # The very next scan runs with all three new gains: constant e, so dMV = Ki_new Ts e = 2e-7.
    assert mv(out, "LIC1") - u_before == pytest.approx(2e-5 * 0.01, rel=1e-9)
    assert (published(out)["PLC.LIC1.Kp"], published(out)["PLC.LIC1.Ki"], published(out)["PLC.LIC1.Kd"]) == (
        1e-3,
        2e-5,
        0.0,
    )
    assert published(out)["PLC.LIC1.GainSource"] == SUPERVISOR
    # The other loop is untouched.
    assert published(out)["PLC.LIC2.GainSource"] == FIXED and published(out)["PLC.LIC2.Kp"] == KP2


def test_last_staged_set_wins_whole() -> None:
    rig = Rig(energies())
    rig.trust([0.4, 0.2, 0.3])
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 1e-4) is GainStatus.STAGED
    assert rig.plc.stage_gains("LIC1", 2e-3, 3e-5, -1e-4) is GainStatus.STAGED
    out = rig.scan([0.4, 0.2, 0.3])
    assert (published(out)["PLC.LIC1.Kp"], published(out)["PLC.LIC1.Ki"], published(out)["PLC.LIC1.Kd"]) == (
        2e-3,
        3e-5,
        -1e-4,
    )


@pytest.mark.parametrize(
    ("gains", "status"),
    [
        ((math.nan, 1e-5, 0.0), GainStatus.OUT_OF_RANGE),
        ((1e-3, math.inf, 0.0), GainStatus.OUT_OF_RANGE),
        ((1e-3, 1e-5, -math.inf), GainStatus.OUT_OF_RANGE),
        ((2e-2, 1e-5, 0.0), GainStatus.OUT_OF_RANGE),  # Kp above 1e-2
        ((-1e-4, 1e-5, 0.0), GainStatus.OUT_OF_RANGE),  # Kp below 0
        ((1e-3, 2e-3, 0.0), GainStatus.OUT_OF_RANGE),  # Ki above 1e-3
        ((1e-3, 1e-5, 0.02), GainStatus.OUT_OF_RANGE),  # Kd above 1e-2
        ((1e-3, 1e-5, -0.02), GainStatus.OUT_OF_RANGE),  # Kd below -1e-2
    ],
)
def test_inadmissible_gain_sets_are_refused_whole(
    gains: tuple[float, float, float], status: GainStatus
) -> None:
    rig = Rig(energies())
    rig.trust([0.4, 0.2, 0.3])
    assert rig.plc.stage_gains("LIC1", *gains) is status
    out = rig.scan([0.4, 0.2, 0.3])
    assert (published(out)["PLC.LIC1.Kp"], published(out)["PLC.LIC1.Ki"], published(out)["PLC.LIC1.Kd"]) == (
        KP1,
        KI1,
        KD1,
    )
    assert published(out)["PLC.LIC1.GainSource"] == FIXED


def test_gain_box_bounds_are_inclusive() -> None:
    rig = Rig(energies())
    rig.trust([0.4, 0.2, 0.3])
    assert rig.plc.stage_gains("LIC1", 1e-2, 1e-3, -1e-2) is GainStatus.STAGED


def test_gains_refused_until_the_supervisor_is_trusted() -> None:
    rig = Rig(energies())
    levels = [0.4, 0.2, 0.3]
    assert rig.plc.stage_gains("LIC1", 1e-3, 1e-5, 0.0) is GainStatus.INVALID_STATE  # never alive
    for k in range(3):
        rig.plc.heartbeat(k + 1)
        rig.scan(levels)
        # good for k + 1 scans: trusted only after the third
        expected = GainStatus.STAGED if k == 2 else GainStatus.INVALID_STATE
        assert rig.plc.stage_gains("LIC1", 1e-3, 1e-5, 0.0) is expected, k


@pytest.mark.parametrize("block", ["nlpi", "mrac"])
def test_set_gains_on_a_block_without_pid_gains_is_invalid_state(block: str) -> None:
    rig = Rig(single_tank(block))
    rig.trust([0.05])
    assert rig.plc.stage_gains("LIC1", 0.1, 0.1, 0.0) is GainStatus.INVALID_STATE
    assert rig.plc.stage_gains("LIC1", math.nan, 0.1, 0.0) is GainStatus.INVALID_STATE
    assert rig.plc.loop("LIC1").staged is None


# =========================================================================== gain sources
def _gains(out: ScanOutputs, loop: str) -> tuple[float, float, float]:
    v = published(out)
    return v[f"PLC.{loop}.Kp"], v[f"PLC.{loop}.Ki"], v[f"PLC.{loop}.Kd"]


def test_engineer_set_gains_is_labelled_engineer_and_needs_no_supervisor() -> None:
    rig = Rig(energies())
    levels = [0.39, 0.2, 0.25]  # e1 = 0.01 every scan
    for _ in range(3):  # no heartbeat ever: the supervisor would be refused (never trusted)
        out = rig.scan(levels)
    assert not rig.plc.supervisor_trusted
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0) is GainStatus.INVALID_STATE
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0, ENGINEER) is GainStatus.STAGED
    assert rig.plc.loop("LIC1").source is FIXED  # nothing before the boundary
    u_before = mv(out, "LIC1")
    out = rig.scan(levels)
    # Constant e after three scans (the D memory flushed): dMV = Ki_new Ts e = 2e-5 * 1 * 0.01.
    assert mv(out, "LIC1") - u_before == pytest.approx(2e-7, rel=1e-9)
    assert _gains(out, "LIC1") == (1e-3, 2e-5, 0.0)
    assert published(out)["PLC.LIC1.GainSource"] == ENGINEER == 3
    assert published(out)["PLC.LIC2.GainSource"] == FIXED
    with pytest.raises(ValueError, match="SUPERVISOR or ENGINEER"):
        rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0, FALLBACK)


@pytest.mark.parametrize(
    "gains", [(math.nan, 1e-5, 0.0), (1e-3, math.inf, 0.0), (2e-2, 1e-5, 0.0), (1e-3, 1e-5, -0.02)]
)
def test_inadmissible_engineer_gains_are_refused_and_the_old_ones_stay(
    gains: tuple[float, float, float],
) -> None:
    rig = Rig(energies())
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0, ENGINEER) is GainStatus.STAGED
    rig.scan([0.4, 0.2, 0.3])
    assert rig.plc.stage_gains("LIC1", *gains, ENGINEER) is GainStatus.OUT_OF_RANGE
    out = rig.scan([0.4, 0.2, 0.3])
    assert _gains(out, "LIC1") == (1e-3, 2e-5, 0.0) and published(out)["PLC.LIC1.GainSource"] == ENGINEER


def test_supervisor_is_refused_while_an_engineer_holds_the_loop_until_release() -> None:
    rig = Rig(energies())
    levels = [0.4, 0.2, 0.3]
    rig.trust(levels)
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0, ENGINEER) is GainStatus.STAGED
    # Refused already while the engineer's set waits for the boundary, and after it.
    assert rig.plc.stage_gains("LIC1", 5e-4, 6e-6, 0.0) is GainStatus.INVALID_STATE
    rig.plc.heartbeat(1)
    out = rig.scan(levels)
    assert published(out)["PLC.LIC1.GainSource"] == ENGINEER and rig.plc.engineer_holds("LIC1")
    assert rig.plc.stage_gains("LIC1", 5e-4, 6e-6, 0.0) is GainStatus.INVALID_STATE
    # The other loop is the supervisor's as before.
    assert rig.plc.stage_gains("LIC2", 1e-3, 3e-5, -1e-3) is GainStatus.STAGED
    rig.plc.heartbeat(2)
    out = rig.scan(levels)
    assert published(out)["PLC.LIC2.GainSource"] == SUPERVISOR and _gains(out, "LIC1") == (1e-3, 2e-5, 0.0)
    # ReleaseGains: the gains stay, source FIXED, and the supervisor may push again.
    assert rig.plc.release_gains("LIC1") is GainStatus.STAGED
    assert rig.plc.loop("LIC1").source is FIXED and not rig.plc.engineer_holds("LIC1")
    rig.plc.heartbeat(3)
    out = rig.scan(levels)
    assert _gains(out, "LIC1") == (1e-3, 2e-5, 0.0) and published(out)["PLC.LIC1.GainSource"] == FIXED
    assert rig.plc.stage_gains("LIC1", 5e-4, 6e-6, 0.0) is GainStatus.STAGED
    rig.plc.heartbeat(4)
    out = rig.scan(levels)
    assert _gains(out, "LIC1") == (5e-4, 6e-6, 0.0) and published(out)["PLC.LIC1.GainSource"] == SUPERVISOR
    # Release on a loop nobody holds changes nothing.
    assert rig.plc.release_gains("LIC1") is GainStatus.STAGED
    assert rig.plc.loop("LIC1").source is SUPERVISOR


def test_release_drops_an_engineer_set_still_staged() -> None:
    rig = Rig(energies())
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0, ENGINEER) is GainStatus.STAGED
    assert rig.plc.release_gains("LIC1") is GainStatus.STAGED
    out = rig.scan([0.4, 0.2, 0.3])
    assert _gains(out, "LIC1") == (KP1, KI1, KD1) and published(out)["PLC.LIC1.GainSource"] == FIXED


@pytest.mark.parametrize("holder", [SUPERVISOR, ENGINEER])
def test_reset_returns_to_the_fixed_gains_at_the_boundary_without_a_bump(holder: GainSource) -> None:
    rig = Rig(energies())
    levels = [0.39, 0.2, 0.25]  # e1 = 0.01 every scan
    rig.trust(levels)
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 5e-4, holder) is GainStatus.STAGED
    for k in range(3):  # three scans at constant e under the new gains: D memory flushed
        rig.plc.heartbeat(100 + k)
        out = rig.scan(levels)
    assert published(out)["PLC.LIC1.GainSource"] == holder and _gains(out, "LIC1") == (1e-3, 2e-5, 5e-4)
    assert rig.plc.reset_gains("LIC1") is GainStatus.STAGED
    # Until the boundary: the applied gains stay, and the supervisor may not stage over the reset.
    assert rig.plc.loop("LIC1").source is holder
    assert rig.plc.stage_gains("LIC1", 5e-4, 6e-6, 0.0) is GainStatus.INVALID_STATE
    u_before = mv(out, "LIC1")
    rig.plc.heartbeat(200)
    out = rig.scan(levels)
    # The scan after the boundary moves the MV by the fixed gains' increment only: constant e, so
    # P and D increments are 0 and dMV = KI1 Ts e = 5.32e-6 * 1 * 0.01 (no jump from the gains).
    assert mv(out, "LIC1") - u_before == pytest.approx(KI1 * 0.01, rel=1e-9)
    assert _gains(out, "LIC1") == (KP1, KI1, KD1) and published(out)["PLC.LIC1.GainSource"] == FIXED
    assert not rig.plc.engineer_holds("LIC1")
    assert rig.plc.stage_gains("LIC1", 5e-4, 6e-6, 0.0) is GainStatus.STAGED  # adaptation again


def test_reset_is_refused_while_a_mode_change_is_pending() -> None:
    rig = Rig(energies())
    levels = [0.4, 0.2, 0.3]
    rig.scan(levels)
    rig.plc.set_mode("LIC1", MANUAL)
    assert rig.plc.mode_change_pending("LIC1") and not rig.plc.mode_change_pending("LIC2")
    assert rig.plc.reset_gains("LIC1") is GainStatus.INVALID_STATE
    assert rig.plc.loop("LIC1").staged is None
    assert rig.plc.reset_gains("LIC2") is GainStatus.STAGED  # the other loop is not changing mode
    rig.scan(levels)  # the new mode has run: the reset is accepted again
    assert not rig.plc.mode_change_pending("LIC1")
    assert rig.plc.reset_gains("LIC1") is GainStatus.STAGED
    rig.plc.set_mode("LIC1", MANUAL)  # the same mode again is no change
    assert not rig.plc.mode_change_pending("LIC1")


@pytest.mark.parametrize("block", ["nlpi", "mrac"])
def test_reset_and_release_on_a_block_without_pid_gains_are_invalid_state(block: str) -> None:
    rig = Rig(single_tank(block))
    assert rig.plc.reset_gains("LIC1") is GainStatus.INVALID_STATE
    assert rig.plc.release_gains("LIC1") is GainStatus.INVALID_STATE
    assert rig.plc.stage_gains("LIC1", 0.1, 0.1, 0.0, ENGINEER) is GainStatus.INVALID_STATE
    assert rig.plc.loop("LIC1").staged is None


def test_watchdog_leaves_engineer_gains_and_an_engineer_request_alone() -> None:
    rig = Rig(energies())
    levels = [0.4, 0.2, 0.3]
    rig.trust(levels)
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0, ENGINEER) is GainStatus.STAGED
    assert rig.plc.stage_gains("LIC2", 1e-3, 3e-5, -1e-3) is GainStatus.STAGED
    rig.plc.heartbeat(1)
    rig.scan(levels)
    # The heartbeat stops; an engineer stages new gains just before the timeout.
    for _ in range(2):
        rig.scan(levels)
    assert rig.plc.stage_gains("LIC1", 2e-3, 3e-5, 0.0, ENGINEER) is GainStatus.STAGED
    out = rig.scan(levels)  # timeout 3 s: expired on this scan
    assert not rig.plc.watchdog.alive
    assert published(out)["PLC.LIC2.GainSource"] == FALLBACK and _gains(out, "LIC2") == (KP2, KI2, KD2)
    assert published(out)["PLC.LIC1.GainSource"] == ENGINEER and _gains(out, "LIC1") == (2e-3, 3e-5, 0.0)
    for _ in range(5):
        out = rig.scan(levels)
    assert published(out)["PLC.LIC1.GainSource"] == ENGINEER and _gains(out, "LIC1") == (2e-3, 3e-5, 0.0)
    # An engineer works while the supervisor is lost: SetGains and ResetGains.
    assert rig.plc.reset_gains("LIC1") is GainStatus.STAGED
    out = rig.scan(levels)
    assert published(out)["PLC.LIC1.GainSource"] == FIXED and _gains(out, "LIC1") == (KP1, KI1, KD1)


def test_an_engineer_hold_survives_a_warm_restart() -> None:
    rig = Rig(energies())
    assert rig.plc.stage_gains("LIC1", 1e-3, 2e-5, 0.0, ENGINEER) is GainStatus.STAGED
    rig.scan([0.4, 0.2, 0.3])
    saved = rig.plc.retained()
    assert saved["loops"]["LIC1"]["source"] == "ENGINEER" and saved["loops"]["LIC1"]["gains"] == [
        1e-3,
        2e-5,
        0.0,
    ]
    new = Rig(energies())
    assert new.plc.restore_retained(saved) == []
    lp = new.plc.loop("LIC1")
    assert lp.source is ENGINEER and lp.applied == LoopGains(kp=1e-3, ki=2e-5, kd=0.0)
    fixed = energies().plc
    assert fixed is not None and lp.last_accepted == LoopGains.of_spec(
        fixed.loops[0].gains
    )  # not the supervisor's
    assert not new.plc.mode_change_pending("LIC1")  # a restored mode is no change in progress
    new.trust([0.4, 0.2, 0.3])
    assert new.plc.stage_gains("LIC1", 5e-4, 6e-6, 0.0) is GainStatus.INVALID_STATE  # still held
    assert new.plc.release_gains("LIC1") is GainStatus.STAGED
    assert new.plc.stage_gains("LIC1", 5e-4, 6e-6, 0.0) is GainStatus.STAGED


# =========================================================================== watchdog
def test_heartbeat_loss_falls_back_within_timeout_plus_one_scan() -> None:
    # Heartbeats before scans 0..9; the scan at t = 9 s sees the last change. Timeout 3 s:
    # alive at 9, 10, 11; at t = 12 s Alive goes false and the loop on supervisor gains switches
    # to FALLBACK (the fixed gains). The last write came after the scan at 8 s, so the switch
    # comes within Timeout + 1 scan of it.
    rig = Rig(energies())
    levels = [0.399, 0.2, 0.3]  # e1 = 0.001
    for k in range(10):
        rig.plc.heartbeat(k)
        rig.scan(levels)
        if k == 4:
            assert rig.plc.stage_gains("LIC1", 1e-3, 1e-5, 0.0) is GainStatus.STAGED
    lp = rig.plc.loop("LIC1")
    assert lp.source is SUPERVISOR
    sources, alive = [], []
    for _ in range(4):  # t = 10, 11, 12, 13
        u_before = lp.mv
        out = rig.scan(levels)
        sources.append(lp.source)
        alive.append(published(out)["PLC.Supervisor.Alive"])
        if lp.source is FALLBACK and sources.count(FALLBACK) == 1:
            # Switching scan: the velocity form continues from the applied MV with the fixed
            # gains' increment, Ki Ts e = 5.32e-6 (0.001) = 5.32e-9 (no bump).
            assert lp.mv - u_before == pytest.approx(KI1 * 0.001, rel=1e-9)
            assert abs(lp.mv - u_before) <= 0.01 * SPAN
            assert rig.plc.t_s == 12.0
    assert sources == [SUPERVISOR, SUPERVISOR, FALLBACK, FALLBACK]
    assert alive == [True, True, False, False]
    assert published(out)["PLC.Alarms.SupervisorLost"] is True
    assert (published(out)["PLC.LIC1.Kp"], published(out)["PLC.LIC1.Ki"]) == (KP1, KI1)


def test_fallback_timing_is_exact_at_a_fine_scan() -> None:
    # At Ts = 0.01 s model time is a sum of 0.01's; 300 scans after the last change must still
    # count as the 3 s timeout (not 301).
    site = energies(lambda d: d["plc"].update(scan_period_s=0.01))
    plc = PlcProgram(site)
    t = 0.0
    plc.heartbeat(1)
    scans_after = None
    for k in range(400):
        plc.scan(inputs(t, [0.4, 0.2, 0.3]))
        if k > 0 and not plc.watchdog.alive and scans_after is None:
            scans_after = k
        t += 0.01
    assert scans_after == 300


def test_remote_loop_sheds_to_auto_at_its_setpoint_bumplessly() -> None:
    # LIC2 in REMOTE at 3.184e-5; PV 0.199 (e2 = 0.001 at SP 0.2). The PID's error memory
    # follows in REMOTE, so the shedding scan's AUTO move is Ki Ts e = 3.94e-5 (0.001) = 3.94e-8.
    rig = Rig(energies(lambda d: d["plc"]["loops"][1].update(mode="REMOTE")))
    levels = [0.4, 0.199, 0.3]
    for k in range(5):
        rig.plc.heartbeat(k)
        rig.plc.set_remote_mv("LIC2", 3.184e-5)
        out = rig.scan(levels)
        assert mv(out, "LIC2") == 3.184e-5
    for _ in range(2):  # t = 5, 6: still alive (last change at t = 4)
        out = rig.scan(levels)
        assert published(out)["PLC.LIC2.Mode"] == REMOTE
    out = rig.scan(levels)  # t = 7
    assert published(out)["PLC.LIC2.Mode"] == AUTO
    assert published(out)["PLC.LIC2.SP"] == 0.2
    assert mv(out, "LIC2") - 3.184e-5 == pytest.approx(KI2 * 0.001, rel=1e-9)
    assert abs(mv(out, "LIC2") - 3.184e-5) <= 0.01 * SPAN


def test_fallback_to_last_accepted_gains() -> None:
    rig = Rig(energies(lambda d: d["plc"]["watchdog"].update(fallback="last_accepted")))
    levels = [0.4, 0.2, 0.3]
    rig.trust(levels)
    assert rig.plc.stage_gains("LIC1", 1e-3, 1e-5, 0.0) is GainStatus.STAGED
    rig.scan(levels)
    for _ in range(3):
        rig.scan(levels)
    out = rig.scan(levels)
    assert published(out)["PLC.LIC1.GainSource"] == FALLBACK
    assert (published(out)["PLC.LIC1.Kp"], published(out)["PLC.LIC1.Ki"], published(out)["PLC.LIC1.Kd"]) == (
        1e-3,
        1e-5,
        0.0,
    )


def test_supervisor_gains_accepted_again_only_after_good_scans() -> None:
    # FIXED -> SUPERVISOR -> FALLBACK -> SUPERVISOR: after the loss, the returning supervisor
    # is refused until its heartbeat has been good for 3 scans.
    rig = Rig(energies())
    levels = [0.4, 0.2, 0.3]
    lp = rig.plc.loop("LIC1")
    history = [lp.source]
    rig.trust(levels)
    assert rig.plc.stage_gains("LIC1", 1e-3, 1e-5, 0.0) is GainStatus.STAGED
    rig.scan(levels)
    history.append(lp.source)
    while lp.source is not FALLBACK:
        rig.scan(levels)
    history.append(lp.source)
    statuses = []
    for k in range(3):
        rig.plc.heartbeat(5000 + k)
        rig.scan(levels)
        statuses.append(rig.plc.stage_gains("LIC1", 2e-3, 2e-5, 0.0))
    assert statuses == [GainStatus.INVALID_STATE, GainStatus.INVALID_STATE, GainStatus.STAGED]
    assert lp.source is FALLBACK  # staged, not yet applied
    rig.plc.heartbeat(6000)
    rig.scan(levels)
    history.append(lp.source)
    assert history == [FIXED, SUPERVISOR, FALLBACK, SUPERVISOR]
    assert lp.applied is not None and (lp.applied.kp, lp.applied.ki) == (2e-3, 2e-5)


def test_gains_staged_just_before_the_timeout_are_dropped() -> None:
    rig = Rig(energies())
    levels = [0.4, 0.2, 0.3]
    rig.plc.heartbeat(1)
    rig.scan(levels)  # t = 0: change seen
    rig.scan(levels)  # t = 1
    rig.scan(levels)  # t = 2: good for 3 scans, trusted
    assert rig.plc.stage_gains("LIC1", 1e-3, 1e-5, 0.0) is GainStatus.STAGED
    out = rig.scan(levels)  # t = 3: expired at this boundary
    assert published(out)["PLC.Supervisor.Alive"] is False
    assert published(out)["PLC.LIC1.GainSource"] == FIXED and published(out)["PLC.LIC1.Kp"] == KP1
    assert rig.plc.loop("LIC1").staged is None


def test_grace_period_counts_from_the_first_scan_not_from_time_zero() -> None:
    # A PLC (re)started at model time 5000 s keeps a REMOTE loop for the first timeout.
    rig = Rig(energies(lambda d: d["plc"]["loops"][1].update(mode="REMOTE")))
    rig.t0 = 5000.0
    modes = [published(rig.scan([0.4, 0.2, 0.3]))["PLC.LIC2.Mode"] for _ in range(4)]
    assert modes == [REMOTE, REMOTE, REMOTE, AUTO]
    assert status_values(rig.plc.status())["PLC.Alarms.SupervisorLost"] is False  # never alive: not "lost"


def test_unchanged_heartbeat_is_not_alive() -> None:
    rig = Rig(energies())
    for _ in range(6):
        rig.plc.heartbeat(7)
        out = rig.scan([0.4, 0.2, 0.3])
    assert published(out)["PLC.Supervisor.Alive"] is False  # one change at t = 0, then timeout at 3


# =========================================================================== interlocks
@pytest.mark.parametrize("mode", [MANUAL, AUTO, REMOTE])
@pytest.mark.parametrize("supervisor", ["alive", "dead"])
def test_interlock_trips_within_one_scan_in_every_mode(mode: LoopMode, supervisor: str) -> None:
    rig = Rig(energies())
    plc = rig.plc
    levels = [0.50, 0.19, 0.3]  # LIC2 below its SP, so P2 runs
    rig.trust(levels)
    assert plc.stage_gains("LIC1", 5e-3, 1e-4, 0.0) is GainStatus.STAGED  # strong supervisor gains
    plc.set_sp("LIC1", 0.6)
    plc.set_mode("LIC1", mode)
    if mode is MANUAL:
        plc.set_manual_mv("LIC1", 1e-4)
    if mode is REMOTE:
        plc.set_remote_mv("LIC1", 1e-4)
    for _ in range(2):
        if supervisor == "alive":
            plc.heartbeat(rig.k)
        out = rig.scan(levels)
    assert out.commands[0] > 0.0
    if supervisor == "alive":
        plc.heartbeat(rig.k)
    out = rig.scan([0.58, 0.19, 0.3])  # at high-high
    assert out.commands[0] == 0.0 and mv(out, "LIC1") == 0.0
    assert published(out)["PLC.Interlock.T1HH"] is True and published(out)["PLC.Alarms.T1HH"] is True
    assert out.commands[1] > 0.0  # the other tank's pump is not touched


def test_interlock_latches_resets_only_below_reset_level_and_on_request() -> None:
    # T1: HH 0.58, reset below 0.55. SP 0.54; two scans at PV 0.50 before the reset, so after it
    # e = 0.04 = e(k-1) = e(k-2) and the AUTO loop resumes from the forced 0 with only
    # Ki Ts e = 5.32e-6 (0.04) = 2.128e-7 (bumpless).
    rig = Rig(energies())
    plc = rig.plc
    plc.set_sp("LIC1", 0.54)
    rig.scan([0.50, 0.2, 0.3])
    out = rig.scan([0.59, 0.2, 0.3])
    assert published(out)["PLC.Interlock.T1HH"] is True and out.commands[0] == 0.0
    out = rig.scan([0.56, 0.2, 0.3])  # below HH, above reset: latched
    assert published(out)["PLC.Interlock.T1HH"] is True and out.commands[0] == 0.0
    assert plc.reset_interlocks() == []  # 0.56 is not below 0.55
    for _ in range(2):
        out = rig.scan([0.50, 0.2, 0.3])  # below reset, but no request: still latched
        assert published(out)["PLC.Interlock.T1HH"] is True and out.commands[0] == 0.0
    assert plc.reset_interlocks() == ["T1"]
    out = rig.scan([0.50, 0.2, 0.3])
    assert published(out)["PLC.Interlock.T1HH"] is False
    assert out.commands[0] == pytest.approx(KI1 * 0.04, rel=1e-9)


def test_manual_loop_does_not_restart_its_pump_after_a_reset() -> None:
    rig = Rig(energies())
    plc = rig.plc
    plc.set_mode("LIC1", MANUAL)
    plc.set_manual_mv("LIC1", 1e-4)
    assert rig.scan([0.50, 0.2, 0.3]).commands[0] == 1e-4
    out = rig.scan([0.58, 0.2, 0.3])
    assert out.commands[0] == 0.0 and published(out)["PLC.LIC1.ManualMV"] == 0.0
    rig.scan([0.50, 0.2, 0.3])
    assert plc.reset_interlocks() == ["T1"]
    assert rig.scan([0.50, 0.2, 0.3]).commands[0] == 0.0  # stays off until the operator writes
    plc.set_manual_mv("LIC1", 5e-5)
    assert rig.scan([0.50, 0.2, 0.3]).commands[0] == 5e-5


def test_over_range_reading_trips_fail_safe_and_bad_reading_does_not() -> None:
    rig = Rig(energies())
    out = rig.scan([0.70, 0.2, 0.3])  # above the 0..0.62 transmitter range: PV bad, but trips
    assert published(out)["PLC.IO.LT1.Good"] is False
    assert published(out)["PLC.Interlock.T1HH"] is True and out.commands[0] == 0.0
    rig2 = Rig(energies())
    out = rig2.scan([0.70, 0.2, 0.3], good=[False, True, True])  # the link flagged it: unknown
    assert published(out)["PLC.Interlock.T1HH"] is False


def test_interlock_stops_a_pump_that_no_loop_drives() -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["plc"]["loops"] = d["plc"]["loops"][:1]
        d["plant"]["pumps"][1]["initial_command"] = 3e-5

    rig = Rig(energies(mutate))
    assert rig.scan([0.4, 0.2, 0.3]).commands[1] == 3e-5
    out = rig.scan([0.4, 0.58, 0.3])
    assert out.commands[1] == 0.0 and published(out)["PLC.Interlock.T2HH"] is True


# =========================================================================== PV quality
BAD_SPELLS: dict[str, dict[str, Any]] = {
    "link_lost": {"levels": [0.3, 0.2, 0.3], "io": False},
    "link_flag": {"levels": [0.3, 0.2, 0.3], "good": [False, False, True]},
    "nan": {"levels": [math.nan, math.nan, 0.3]},
    "below_range": {"levels": [-0.01, -0.01, 0.3]},
    "above_range": {"levels": [0.63, 0.63, 0.3]},
}


@pytest.mark.parametrize("cause", sorted(BAD_SPELLS))
def test_pv_bad_substitutes_after_n_scans_and_resumes_bumplessly(cause: str) -> None:
    # LIC1: hold; LIC2: value 2e-5; N = 3. Before the spell: two scans at e1 = 0.01, e2 = -0.01.
    # LIC1: k=0 P 4.29e-6 I 5.32e-8 D -1.42e-6 -> 2.9232e-6; k=1: P 0, I 5.32e-8,
    # D = -1.42e-4 (0.01 - 0.02) = 1.42e-6 -> 4.3964e-6. LIC2 is clamped at 0 (e2 < 0).
    # Spell: scans 1 and 2 hold (no increment), scan 3 applies the substitute (LIC2 -> 2e-5).
    # First good scan after: memory re-initialised, integral-only move from the held MV:
    # LIC1 4.3964e-6 + 5.32e-6 (0.01) = 4.4496e-6;  LIC2 2e-5 + 3.94e-5 (-0.01) = 1.9606e-5.
    def mutate(d: dict[str, Any]) -> None:
        d["plc"]["loops"][1].update(substitute="value", substitute_mv=2e-5)
        d["plc"]["interlocks"] = []  # keep the over-range spell from tripping

    rig = Rig(energies(mutate))
    good_levels = [0.39, 0.21, 0.3]
    rig.scan(good_levels)
    out = rig.scan(good_levels)
    assert out.commands == pytest.approx([4.3964e-6, 0.0], rel=1e-9)
    spell = BAD_SPELLS[cause]
    cmds = []
    for _ in range(4):
        out = rig.scan(spell["levels"], good=spell.get("good"), io=spell.get("io", True))
        cmds.append(out.commands.copy())
        assert (
            published(out)["PLC.Alarms.LIC1PvBad"] is True and published(out)["PLC.Alarms.LIC2PvBad"] is True
        )
        assert published(out)["PLC.LIC1.PV"] == 0.39  # last good value published
        assert published(out)["PLC.Status.IoHealthy"] is (cause != "link_lost")
    assert [c[0] for c in cmds] == pytest.approx([4.3964e-6] * 4, rel=1e-9)
    assert [c[1] for c in cmds] == pytest.approx([0.0, 0.0, 2e-5, 2e-5], rel=1e-9, abs=1e-18)
    out = rig.scan(good_levels)
    assert published(out)["PLC.Alarms.LIC1PvBad"] is False
    assert out.commands == pytest.approx([4.4496e-6, 1.9606e-5], rel=1e-9)


def test_frozen_reading_is_bad_after_the_configured_repeats() -> None:
    rig = Rig(energies(lambda d: d["plc"].update(pv_frozen_scans=3)))
    good = [published(rig.scan([0.4, 0.2 + 1e-4 * k, 0.3]))["PLC.IO.LT1.Good"] for k in range(5)]
    # LT1 repeats from the 2nd scan on: 1, 2, 3 repeats -> bad at the 3rd repeat (4th scan).
    assert good == [True, True, True, False, False]
    assert status_values(rig.plc.status())["PLC.IO.LT2.Good"] is True


def test_io_loss_marks_every_reading_bad_even_if_flagged_good() -> None:
    rig = Rig(energies())
    out = rig.scan([0.4, 0.2, 0.3], good=[True, True, True], io=False)
    assert published(out)["PLC.Status.IoHealthy"] is False and published(out)["PLC.Alarms.IoFault"] is True
    assert not any(published(out)[f"PLC.IO.LT{i}.Good"] for i in (1, 2, 3))


@pytest.mark.parametrize("block", ["nlpi", "mrac"])
@pytest.mark.parametrize("substitute", ["hold", "value"])
def test_single_loop_blocks_substitute_and_resume_bumplessly(block: str, substitute: str) -> None:
    rig = Rig(single_tank(block, substitute=substitute, substitute_mv=0.2, pv_bad_scans=2))
    h = 0.05
    for _ in range(30):
        out = rig.scan([h])
    held = mv(out, "LIC1")
    mvs = [mv(rig.scan([math.nan]), "LIC1") for _ in range(3)]
    sub = 0.2 if substitute == "value" else held
    assert mvs == pytest.approx([held, sub, sub])
    out = rig.scan([h])
    # Back from the spell: the block re-initialised from the applied MV; only a one-scan move.
    assert abs(mv(out, "LIC1") - sub) <= 0.01 * 0.5
    if block == "mrac":
        assert mv(out, "LIC1") == pytest.approx(sub, abs=1e-12)  # MRAC re-enters exactly


def test_mrac_in_manual_follows_the_operator_while_the_pv_is_bad() -> None:
    rig = Rig(single_tank("mrac", mode="MANUAL", manual_mv=0.1))
    rig.scan([math.nan])
    rig.plc.set_manual_mv("LIC1", 0.15)
    assert mv(rig.scan([math.nan]), "LIC1") == 0.15


def test_rate_limit_applies_to_single_loop_blocks() -> None:
    # NL-PI from empty, SP 0.2: its first unlimited move would be Ki Ts e = 0.125 (0.1) (0.2) =
    # 0.0025 and it grows as the integrator winds up; du_max 0.001 limits every scan to +0.001
    # (the block is told the applied value, so its integrator back-calculates from it).
    rig = Rig(single_tank("nlpi", du_max=0.001, setpoint_m=0.2))
    mvs = [mv(rig.scan([0.0]), "LIC1") for _ in range(3)]
    assert mvs == pytest.approx([0.001, 0.002, 0.003])


# =========================================================================== modes
def _steady(rig: Rig, h: float, n: int = 20) -> ScanOutputs:
    out = rig.scan([h])
    for _ in range(n - 1):
        out = rig.scan([h])
    return out


@pytest.mark.parametrize("block", ["pid", "nlpi", "mrac"])
def test_mode_transitions_are_bumpless_for_every_block(block: str) -> None:
    # Single tank, SP 0.10, PV held at 0.099 (e = 0.001 m): on each switching scan the MV moves
    # by at most one scan's integral action, well inside 1 % of the 0.2 m^3/s span.
    site = single_tank(block, setpoint_m=0.10)
    rig = Rig(site)
    plc = rig.plc
    h = 0.099
    rig.trust([h], scans=1)
    out = _steady(rig, h)
    for mode in (MANUAL, AUTO, REMOTE, AUTO, REMOTE, MANUAL, REMOTE, MANUAL, AUTO):
        before = mv(out, "LIC1")
        plc.heartbeat(rig.k)
        plc.set_mode("LIC1", mode)
        out = rig.scan([h])
        assert published(out)["PLC.LIC1.Mode"] == mode
        assert abs(mv(out, "LIC1") - before) <= 0.01 * 0.2, (block, mode)
        for _ in range(3):
            plc.heartbeat(rig.k)
            out = rig.scan([h])
    # MANUAL and REMOTE apply the operator's and the supervisor's values.
    plc.set_mode("LIC1", MANUAL)
    plc.set_manual_mv("LIC1", 0.15)
    assert mv(rig.scan([h]), "LIC1") == 0.15
    plc.heartbeat(rig.k)
    plc.set_mode("LIC1", REMOTE)
    plc.set_remote_mv("LIC1", 0.18)
    assert mv(rig.scan([h]), "LIC1") == 0.18


def test_pid_auto_entry_increment_by_hand() -> None:
    # MANUAL at 5e-5, PV 0.399 (e1 = 0.001, steady, so the memory holds e = 0.001): entering AUTO
    # moves by Ki Ts e = 5.32e-9 exactly.
    rig = Rig(energies())
    rig.plc.set_mode("LIC1", MANUAL)
    rig.plc.set_manual_mv("LIC1", 5e-5)
    for _ in range(3):
        rig.scan([0.399, 0.2, 0.3])
    rig.plc.set_mode("LIC1", AUTO)
    out = rig.scan([0.399, 0.2, 0.3])
    assert mv(out, "LIC1") - 5e-5 == pytest.approx(KI1 * 0.001, rel=1e-9)


def test_nlpi_auto_entry_increment_by_hand() -> None:
    # NL-PI on the simulation tank: Ki = wn^2 / b = 0.125, Ts = 0.1 s. From MANUAL at 0.05 with
    # SP 0.10, PV 0.099: the integrator is re-initialised to reproduce 0.05, then the first AUTO
    # move is Ki Ts e = 0.125 (0.1) (0.001) = 1.25e-5.
    rig = Rig(single_tank("nlpi", setpoint_m=0.10, mode="MANUAL", manual_mv=0.05))
    for _ in range(3):
        assert mv(rig.scan([0.099]), "LIC1") == 0.05
    rig.plc.set_mode("LIC1", AUTO)
    assert mv(rig.scan([0.099]), "LIC1") - 0.05 == pytest.approx(1.25e-5, rel=1e-9)


def test_setpoint_ramp_applies_to_single_loop_blocks() -> None:
    # NL-PI at rest at 0.10 m, ramp 0.01 m/s at Ts 0.1 s: a step to 0.15 is seen as 0.101, 0.102,
    # ... so the first move is Ki Ts (r - h) = 0.125 (0.1) (0.001) = 1.25e-5, not 6.25e-4.
    rig = Rig(single_tank("nlpi", setpoint_m=0.10, sp_ramp_m_s=0.01, mode="MANUAL", manual_mv=0.05))
    rig.scan([0.10])
    rig.plc.set_mode("LIC1", AUTO)
    rig.plc.set_sp("LIC1", 0.15)
    assert mv(rig.scan([0.10]), "LIC1") - 0.05 == pytest.approx(1.25e-5, rel=1e-9)
    assert rig.plc.loop("LIC1").working_sp_m == pytest.approx(0.101)


def test_setpoint_outside_its_range_is_refused() -> None:
    plc = PlcProgram(energies())
    for bad in (-0.01, 0.61, math.nan, math.inf):
        with pytest.raises(ValueError, match="LIC1 SP"):
            plc.set_sp("LIC1", bad)
    assert plc.loop("LIC1").sp_m == 0.4
    with pytest.raises(ValueError, match="MV"):
        plc.set_manual_mv("LIC1", 2e-4)
    with pytest.raises(KeyError):
        plc.set_sp("LIC9", 0.1)


# =========================================================================== Hypothesis
LOOPS = ("LIC1", "LIC2")
finite_gain = st.floats(-2e-2, 2e-2, allow_nan=False)
any_gain = st.one_of(finite_gain, st.sampled_from([math.nan, math.inf, -math.inf]))
level = st.floats(-0.05, 0.7, allow_nan=False)

requests = st.one_of(
    st.tuples(st.just("sp"), st.sampled_from(LOOPS), st.floats(0.0, 0.6)),
    st.tuples(st.just("mode"), st.sampled_from(LOOPS), st.sampled_from([MANUAL, AUTO, REMOTE])),
    st.tuples(st.just("manual"), st.sampled_from(LOOPS), st.floats(0.0, 1.2e-4)),
    st.tuples(st.just("remote"), st.sampled_from(LOOPS), st.floats(0.0, 1.2e-4)),
    st.tuples(st.just("gains"), st.sampled_from(LOOPS), st.tuples(any_gain, any_gain, any_gain)),
    st.tuples(st.just("egains"), st.sampled_from(LOOPS), st.tuples(any_gain, any_gain, any_gain)),
    st.tuples(st.just("greset"), st.sampled_from(LOOPS), st.none()),
    st.tuples(st.just("release"), st.sampled_from(LOOPS), st.none()),
    st.tuples(st.just("reset"), st.none(), st.none()),
    st.tuples(
        st.just("scan"),
        st.tuples(level, level, level),
        st.sampled_from(["good", "nan", "io", "flag"]),
    ),
    st.tuples(st.just("silent"), st.integers(1, 6), st.none()),  # scans without a heartbeat
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(requests, min_size=1, max_size=60), st.sampled_from(["fixed", "last_accepted"]))
def test_random_requests_keep_every_invariant(seq: list[tuple[Any, Any, Any]], fallback: str) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["plc"]["watchdog"]["fallback"] = fallback
        d["plc"]["loops"][0].update(du_max=2e-5)
        d["plc"]["loops"][1].update(substitute="value", substitute_mv=3e-5)

    site = energies(mutate)
    plc = PlcProgram(site)
    fixed = {lp.name: (lp.gains.kp, lp.gains.ki, lp.gains.kd) for lp in site.plc.loops}  # type: ignore[union-attr]
    admitted: dict[str, set[tuple[float, float, float]]] = {n: {g} for n, g in fixed.items()}
    lo, hi = plc.pump_min, plc.pump_max
    t, beat = 0.0, 0
    last_levels = np.array([0.4, 0.2, 0.3])
    touched: set[str] = set()  # loops an engineer or operator acted on since the last scan

    def scan(levels: np.ndarray, quality: str) -> None:
        nonlocal t
        held = {lp.spec.name: (lp.applied, lp.source) for lp in plc.loops if lp.source is ENGINEER}
        good = np.array([quality != "flag", True, quality != "flag"])
        lv = np.where(quality == "nan", np.nan, levels)
        prev = {lp.spec.name: lp.mv for lp in plc.loops}
        out = plc.scan(ScanInputs(t, lv, good, quality != "io"))
        t += plc.ts_s
        c = out.commands
        assert np.all(np.isfinite(c)) and np.all(c >= lo) and np.all(c <= hi)
        for key, value in published(out).items():
            assert not (isinstance(value, float) and not math.isfinite(value)), key
        for lp in plc.loops:
            g = (
                published(out)[f"PLC.{lp.spec.name}.Kp"],
                published(out)[f"PLC.{lp.spec.name}.Ki"],
                published(out)[f"PLC.{lp.spec.name}.Kd"],
            )
            assert g in admitted[lp.spec.name]  # a whole admitted set, never a mix
            assert lp.pid is not None
            i = lp.slot
            assert (lp.pid.gains.kp[i, i], lp.pid.gains.ki[i, i], lp.pid.gains.kd[i, i]) == g
        # ENGINEER gains change only by an engineer's or operator's own request (never the
        # watchdog, never the supervisor).
        for name, before in held.items():
            if name not in touched:
                lp = plc.loop(name)
                assert (lp.applied, lp.source) == before, name
        touched.clear()
        # Interlocks: a delivered reading at or above HH stops that tank's pump this scan.
        for il in plc.interlocks:
            if quality != "io" and good[il.tank] and lv[il.tank] >= il.high_high_m:
                assert np.all(c[plc.pump_tank == il.tank] == 0.0)
        # Rate limit on LIC1 in every mode unless an interlock forced the pump.
        lp1 = plc.loop("LIC1")
        if not published(out)["PLC.Interlock.T1HH"]:
            assert abs(lp1.mv - prev["LIC1"]) <= 2e-5 * (1 + 1e-9)

    for kind, a, b in seq:
        if kind == "sp":
            plc.set_sp(a, b)
        elif kind == "mode":
            plc.set_mode(a, b)
        elif kind == "manual":
            plc.set_manual_mv(a, b)
        elif kind == "remote":
            plc.set_remote_mv(a, b)
        elif kind in ("gains", "egains"):
            held = plc.engineer_holds(a)
            status = plc.stage_gains(a, b[0], b[1], b[2], ENGINEER if kind == "egains" else SUPERVISOR)
            if status is GainStatus.STAGED:
                admitted[a].add((float(b[0]), float(b[1]), float(b[2])))
            if kind == "gains" and held:  # refused (OUT_OF_RANGE first if the values are bad)
                assert status is not GainStatus.STAGED
            if kind == "egains":
                touched.add(a)
        elif kind == "greset":
            pending = plc.mode_change_pending(a)
            assert (plc.reset_gains(a) is GainStatus.INVALID_STATE) == pending
            touched.add(a)
        elif kind == "release":
            assert plc.release_gains(a) is GainStatus.STAGED
            assert plc.loop(a).source is not ENGINEER
            touched.add(a)
        elif kind == "reset":
            plc.reset_interlocks()
        elif kind == "scan":
            beat += 1
            plc.heartbeat(beat)
            last_levels = np.array(a)
            scan(last_levels, b)
        else:
            for _ in range(a):
                scan(last_levels, "good")


single_requests = st.one_of(
    st.tuples(st.just("sp"), st.floats(0.0, 0.22)),  # the site's sp_max
    st.tuples(st.just("mode"), st.sampled_from([MANUAL, AUTO, REMOTE])),
    st.tuples(st.just("manual"), st.floats(0.0, 0.2)),  # the pump's span
    st.tuples(st.just("remote"), st.floats(0.0, 0.2)),
    st.tuples(st.just("reset"), st.none()),
    st.tuples(st.just("scan"), st.one_of(st.floats(-0.05, 0.35, allow_nan=False), st.just(math.nan))),
    st.tuples(st.just("hold"), st.integers(1, 40)),  # the last level for a while (frozen when enabled)
)


@pytest.mark.parametrize("block", ["nlpi", "adaptive_nlpi", "mrac", "pid"])
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seq=st.lists(single_requests, min_size=1, max_size=60))
def test_random_requests_on_single_loop_blocks_stay_in_range(block: str, seq: list[tuple[Any, Any]]) -> None:
    kw: dict[str, Any] = {"du_max": 0.05, "substitute": "value", "substitute_mv": 0.1, "pv_bad_scans": 2}
    if block == "adaptive_nlpi":
        kw["nlpi"] = {"b": 2.0, "a_prime": 0.5, "wn_rad_s": 0.5, "adaptive": True}
    site = single_tank("nlpi" if block == "adaptive_nlpi" else block, **kw)
    data = site.model_dump()
    data["plc"]["pv_frozen_scans"] = 10
    plc = PlcProgram(site_from_mapping(data))
    t, beat, h = 0.0, 0, 0.05

    def scan(level: float) -> None:
        nonlocal t, beat
        beat += 1
        plc.heartbeat(beat)
        prev = plc.loop("LIC1").mv
        out = plc.scan(inputs(t, [level]))
        t += plc.ts_s
        u = float(out.commands[0])
        assert math.isfinite(u) and 0.0 <= u <= 0.2
        assert all(not (isinstance(v, float) and not math.isfinite(v)) for v in published(out).values())
        if published(out)["PLC.Interlock.T1HH"]:
            assert u == 0.0
        else:
            assert abs(u - prev) <= 0.05 * (1 + 1e-9)  # rate limit in every mode

    for kind, a in seq:
        if kind == "sp":
            plc.set_sp("LIC1", a)
        elif kind == "mode":
            plc.set_mode("LIC1", a)
        elif kind == "manual":
            plc.set_manual_mv("LIC1", a)
        elif kind == "remote":
            plc.set_remote_mv("LIC1", a)
        elif kind == "reset":
            plc.reset_interlocks()
        elif kind == "scan":
            h = a
            scan(h)
        else:
            for _ in range(a):
                scan(h)


def test_warm_restart_restores_sp_mode_gains_and_trips() -> None:
    """Retentive memory: a new program restored from retained() continues where the old one was."""
    from tanklab.config import load_site as _load

    site = _load(ROOT / "configs/three_tank_energies_sim.yaml")
    old = PlcProgram(site)
    old.set_sp("LIC1", 0.45)
    old.set_mode("LIC2", LoopMode.MANUAL)
    old.set_manual_mv("LIC2", 2e-5)
    old.loop("LIC1").applied = LoopGains(kp=8e-4, ki=9e-6, kd=-1e-4)
    old.loop("LIC1").source = GainSource.SUPERVISOR
    old.interlocks[0].tripped = True
    saved = old.retained()
    new = PlcProgram(site)
    assert new.restore_retained(saved) == []
    assert new.loop("LIC1").sp_m == 0.45
    assert new.loop("LIC2").mode is LoopMode.MANUAL and new.loop("LIC2").manual_mv == 2e-5
    assert new.loop("LIC1").applied == LoopGains(kp=8e-4, ki=9e-6, kd=-1e-4)
    assert new.loop("LIC1").source is GainSource.SUPERVISOR
    assert new.interlocks[0].tripped
    # A retained value that fails today's checks keeps the cold-start value and is reported.
    saved["loops"]["LIC1"]["sp_m"] = 5.0
    saved["loops"]["LIC2"]["gains"] = [1.0, 0.0, 0.0]
    other = PlcProgram(site)
    skipped = other.restore_retained(saved)
    assert len(skipped) == 2
    assert other.loop("LIC1").sp_m == 0.4
    assert other.loop("LIC2").applied == LoopGains.of_spec(site.plc.loops[1].gains)


# =========================================================================== one MIMO shell or two
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(requests, min_size=1, max_size=60))
def test_zero_cross_gains_scan_like_two_single_loops(seq: list[tuple[Any, Any, Any]]) -> None:
    # The scan runs each group of loops through one shell and one PID law: two decentralised
    # loops as two one-loop groups; coupled by cross gains of zero, as one 2 x 2 group. The two
    # programs must publish and command the same, scan for scan, under any request sequence
    # (ramps, rate limits, substitutes, frozen PVs, trips): the n-loop law sums the same products.
    def mutate(d: dict[str, Any]) -> None:
        d["plc"]["pv_frozen_scans"] = 2
        d["plc"]["loops"][0].update(du_max=2e-5, sp_ramp_m_s=0.002, error_unit="cm", pv_bad_scans=2)
        d["plc"]["loops"][1].update(substitute="value", substitute_mv=3e-5, pv_bad_scans=2)

    def coupled(d: dict[str, Any]) -> None:
        mutate(d)
        d["plc"]["loops"][0]["cross_gains"] = {"LIC2": {"kp": 0.0, "ki": 0.0, "kd": 0.0}}

    fast, ref = PlcProgram(energies(mutate)), PlcProgram(energies(coupled))
    assert [len(g.loops) for g in fast.pid_groups] == [1, 1]
    assert [len(g.loops) for g in ref.pid_groups] == [2]
    t, beat = 0.0, 0

    def scan(levels: tuple[float, ...], quality: str) -> None:
        nonlocal t
        good = np.array([quality != "flag", True, quality != "flag"])
        lv = np.array([math.nan if quality == "nan" else x for x in levels])
        a, b = (plc.scan(ScanInputs(t, lv.copy(), good, quality != "io")) for plc in (fast, ref))
        t += fast.ts_s
        np.testing.assert_array_equal(a.commands, b.commands)  # exactly (a zero's sign aside)
        assert published(a).keys() == published(b).keys()
        for key, value in published(a).items():
            assert type(value) is type(published(b)[key]), key
            assert value == published(b)[key], key

    def request(plc: PlcProgram, kind: str, a: Any, b: Any) -> object:
        """Apply one request; its answer (a status, the tanks reset, or the refusal)."""
        try:
            if kind == "sp":
                plc.set_sp(a, b)
            elif kind == "mode":
                plc.set_mode(a, b)
            elif kind == "manual":
                plc.set_manual_mv(a, b)
            elif kind == "remote":
                plc.set_remote_mv(a, b)
            elif kind == "gains":
                return plc.stage_gains(a, *b)
            else:
                return plc.reset_interlocks()
        except ValueError as e:
            return str(e)
        return None

    last: tuple[float, ...] = (0.4, 0.2, 0.3)
    for kind, a, b in seq:
        if kind == "scan":
            beat += 1
            fast.heartbeat(beat)
            ref.heartbeat(beat)
            last = a
            scan(a, b)
        elif kind == "silent":
            for _ in range(a):
                scan(last, "good")
        else:
            assert request(fast, kind, a, b) == request(ref, kind, a, b)
