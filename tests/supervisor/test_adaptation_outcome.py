"""The gain adaptation judged by outcome (issue 14, ADR 0014), on model time only.

Each case is the Energies scenario (``configs/scenarios/energies_mpc_pid_vs_pid.yaml``: empty tanks
to 0.4 / 0.2 m, T1's leak open from 600 s to 700 s, 1000 s at 1 s) or a variant of our own, run in
the co-simulation with the supervisor OFF (the fixed PID as printed), in ADAPTIVE_PID, and, where
compared, in MPC:

- ``shipped``: the scenario as shipped;
- ``leak_t2``: the leak on T2 instead of T1;
- ``noise``: 0.5 mm of transmitter noise on every tank, 3000 s;
- ``setpoints``: other setpoints (0.3 / 0.15 m);
- ``down``: downward steps (LIC1 to 0.3 m at 400 s, LIC2 to 0.12 m at 700 s), 1200 s;
- ``bias``: LT1 reads 1 cm high from 300 s;
- ``valves``: V13 and V32 half closed from the start (the model assumes them open).

Asserted, per case (measured values in docs/adaptation.md 2.10 and the decision record):

- no gain of the estimate or of the applied set on a box limit at the end, Kp and Ki > 0, and Kd
  never of the opposite sign to the fixed Kd (the model-based tuning has Kd = 0);
- IAE (true levels) no worse than the fixed PID's by more than 2 % on either loop, over the whole
  run and after the leak opens (t >= 600 s);
- the pump moves' standard deviation (whole run) never above the teaching MPC's, and at most 3x the
  fixed PID's under 0.5 mm of noise;
- on the shipped scenario: IAE within 15 % of the MPC's on both loops, overshoot <= 3 % on both;
  on the downward steps, undershoot <= 3 %;
- bad input: a NaN level never produces a push.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from supervisor.adaptation import PidGainAdapter
from supervisor.server import status_values
from tankctl.cosim import CoSimulation
from tankctl.simulate import apply_event, apply_initial
from tanklab.config import load_site
from tanklab.scenario import Scenario, Variant, load_scenario, variant_site
from tanklab.tags import all_tags, tags_by_path

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs/scenarios/energies_mpc_pid_vs_pid.yaml"
NOISE_M = 5e-4
LEAK_OPEN_S = 600.0
IAE_MARGIN = 1.02  # the adapted PID may be at most 2 % worse than the fixed PID (rounding, noise)


def _scenario() -> tuple[Scenario, Path]:
    return load_scenario(SCENARIO)


def _events(sc: Scenario, events: list[dict[str, Any]]) -> Any:
    return Scenario.model_validate({**sc.model_dump(), "events": events}).events


def case(name: str) -> tuple[Scenario, dict[str, Any]]:
    """The scenario and site overrides of one case (module doc)."""
    sc, _ = _scenario()
    noise = {f"plant.tanks.{i}.transmitter": {"noise_std_m": NOISE_M} for i in range(3)}
    if name == "shipped":
        return sc, {}
    if name == "leak_t2":
        leak = [
            {"at_s": 600, "kind": "leak", "tank": "T2", "opening": 1.0},
            {"at_s": 700, "kind": "leak", "tank": "T2", "opening": 0.0},
        ]
        return sc.model_copy(update={"events": _events(sc, leak)}), {}
    if name == "noise":
        return sc.model_copy(update={"duration_s": 3000.0}), noise
    if name == "setpoints":
        initial = sc.initial.model_copy(update={"setpoints_m": {"LIC1": 0.3, "LIC2": 0.15}})
        return sc.model_copy(update={"initial": initial}), {}
    if name == "down":
        steps = [
            {"at_s": 400, "kind": "setpoint", "loop": "LIC1", "value_m": 0.3},
            {"at_s": 700, "kind": "setpoint", "loop": "LIC2", "value_m": 0.12},
        ]
        events = [e.model_dump() for e in sc.events] + steps
        return sc.model_copy(update={"events": _events(sc, events), "duration_s": 1200.0}), {}
    if name == "bias":
        fault = [{"at_s": 300, "kind": "fault", "transmitter": "LT1", "fault": "BIAS", "value": 0.01}]
        events = [e.model_dump() for e in sc.events] + fault
        return sc.model_copy(update={"events": _events(sc, events)}), {}
    if name == "valves":
        initial = sc.initial.model_copy(update={"valves": {"V13": 0.5, "V32": 0.5}})
        return sc.model_copy(update={"initial": initial}), {}
    raise KeyError(name)


CASES = ("shipped", "leak_t2", "noise", "setpoints", "down", "bias", "valves")


@dataclass(frozen=True)
class Outcome:
    iae: np.ndarray  # (2,) [m s], whole run, true levels
    iae_after_leak: np.ndarray  # (2,) [m s], t >= 600 s
    overshoot_pct: np.ndarray  # (2,) first step from empty
    move_std: np.ndarray  # (2,) std of the pump commands' scan-to-scan changes [m^3/s]
    adapter: PidGainAdapter | None
    t_s: np.ndarray  # (N,) [s]
    levels_m: np.ndarray  # (N, 2) true T1, T2 levels [m]


@cache
def outcome(name: str, mode: str) -> Outcome:
    """Run one case in one supervisor mode (OFF, ADAPTIVE_PID, MPC) on model time."""
    sc, overrides = case(name)
    _, site_path = _scenario()
    site = variant_site(sc, site_path, Variant(name="case", set=overrides))
    site = apply_initial(site, sc.initial)
    cs = CoSimulation(site, supervisor_mode=None if mode == "OFF" else mode)  # type: ignore[arg-type]
    due: dict[int, list[Any]] = {}
    for ev in sc.sorted_events():
        due.setdefault(round(ev.at_s / cs.ts_s), []).append(ev)
    for k in range(round(sc.duration_s / cs.ts_s)):
        for ev in due.get(k, []):
            apply_event(cs, ev)
        cs.step()
    tr = cs.trace
    t = tr.array("t_s")
    levels, sp = tr.array("levels_m")[:, :2], tr.array("setpoints_m")
    err = np.abs(sp - levels) * cs.ts_s
    first = sp[0]
    peak = levels[t < 400.0].max(axis=0)
    adapter = cs.supervisor.adapter if mode == "ADAPTIVE_PID" and cs.supervisor is not None else None
    return Outcome(
        iae=err.sum(axis=0),
        iae_after_leak=err[t >= LEAK_OPEN_S].sum(axis=0),
        overshoot_pct=np.maximum((peak - first) / first * 100.0, 0.0),
        move_std=np.diff(tr.array("commands"), axis=0).std(axis=0),
        adapter=adapter,
        t_s=t,
        levels_m=levels,
    )


def _numbers(name: str) -> str:
    pid, ada = outcome(name, "OFF"), outcome(name, "ADAPTIVE_PID")
    return (
        f"{name}: IAE pid {pid.iae.round(3)} mpc_pid {ada.iae.round(3)}; after 600 s pid "
        f"{pid.iae_after_leak.round(3)} mpc_pid {ada.iae_after_leak.round(3)}; move std ratio "
        f"{(ada.move_std / pid.move_std).round(2)}"
    )


@pytest.mark.parametrize("name", CASES)
def test_no_gain_ends_on_a_box_limit_and_no_gain_flips_sign(name: str) -> None:
    ada = outcome(name, "ADAPTIVE_PID").adapter
    assert ada is not None
    d = ada.diagnostics()
    assert not any(p.on_box_limit for p in d.pumps), [p.box_distance for p in d.pumps]
    fixed, applied, est = ada.fixed, ada.applied, ada.estimate()
    for g in (applied, est):
        assert (g.kp.diagonal() > 0.0).all() and (g.ki.diagonal() > 0.0).all()
        # Kd keeps the fixed sign or is 0 (the model-based tuning's Kd): never the opposite sign.
        assert (g.kd.diagonal() * fixed.kd.diagonal() >= 0.0).all(), g.kd.diagonal()
    for p in d.pumps:
        assert math.isfinite(p.condition_number) and 1.0 <= p.condition_number < 1e6
        assert p.excitation >= 0.0


@pytest.mark.parametrize("name", CASES)
def test_the_adapted_pid_is_no_worse_than_the_fixed_one(name: str) -> None:
    pid, ada = outcome(name, "OFF"), outcome(name, "ADAPTIVE_PID")
    assert (ada.iae <= IAE_MARGIN * pid.iae).all(), _numbers(name)
    assert (ada.iae_after_leak <= IAE_MARGIN * pid.iae_after_leak).all(), _numbers(name)


@pytest.mark.parametrize("name", CASES)
def test_pump_moves_stay_bounded(name: str) -> None:
    pid, ada, mpc = outcome(name, "OFF"), outcome(name, "ADAPTIVE_PID"), outcome(name, "MPC")
    assert (ada.move_std <= mpc.move_std).all(), _numbers(name)
    if name == "noise":
        # Measured 2.38 / 0.93: the noise limit holds pump 1's loop gain to the move budget.
        assert (ada.move_std <= 3.0 * pid.move_std).all(), _numbers(name)


def test_shipped_scenario_meets_the_issue_criteria() -> None:
    ada, mpc = outcome("shipped", "ADAPTIVE_PID"), outcome("shipped", "MPC")
    ratio = ada.iae / mpc.iae
    # Measured: IAE 14.56 / 5.51 against the MPC's 13.99 / 5.47 (1.04 / 1.01); overshoot 0.55 / 1.56 %.
    assert (ratio <= 1.15).all(), ratio
    assert (ada.overshoot_pct <= 3.0).all(), ada.overshoot_pct


def test_downward_steps_do_not_overshoot() -> None:
    # LIC1 0.4 -> 0.3 m at 400 s, LIC2 0.2 -> 0.12 m at 700 s: undershoot below the new setpoint as
    # a percentage of the step. Measured: 1.66 / 0.30 % (fixed PID 3.57 / 0.94 %, MPC 0.14 / 0.0 %;
    # the former estimator: up to 28 %, issue 14).
    run = outcome("down", "ADAPTIVE_PID")
    t, y = run.t_s, run.levels_m
    os1 = max(0.0, 0.3 - y[(t >= 400.0) & (t < LEAK_OPEN_S), 0].min()) / 0.1 * 100.0  # before the leak
    os2 = max(0.0, 0.12 - y[t >= 700.0, 1].min()) / 0.08 * 100.0
    assert os1 <= 3.0 and os2 <= 3.0, (os1, os2)


def test_a_nan_level_never_produces_a_push() -> None:
    site = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
    cs = CoSimulation(site, supervisor_mode="ADAPTIVE_PID")
    core = cs.supervisor
    assert core is not None and core.adapter is not None
    adapter = core.adapter
    cs.run(100.0)
    pushed = adapter.diagnostics().accepted_pushes
    assert pushed >= 1
    gains = adapter.applied
    last = core.last
    assert last is not None
    for k in range(1, 60):
        levels = last.levels_m.copy()
        levels[0] = math.nan
        snap = type(last)(
            scan=last.scan + k,
            t_s=last.t_s + k * cs.ts_s,
            sp_m=last.sp_m,
            pv_m=np.array([math.nan, last.pv_m[1]]),
            mv=last.mv,
            modes=last.modes,
            gains=last.gains,
            levels_m=levels,
            good=np.array([False, True, True]),
        )
        act = core.cycle(snap)
        assert not act.gains
    assert adapter.diagnostics().accepted_pushes == pushed
    assert adapter.applied.allclose(gains)


def test_the_health_nodes_are_published_declared_and_in_range() -> None:
    site = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
    cs = CoSimulation(site, supervisor_mode="ADAPTIVE_PID")
    cs.run(200.0)
    assert cs.supervisor is not None
    values = status_values(cs.supervisor.status())
    tags = tags_by_path(all_tags(site))
    for loop in ("LIC1", "LIC2"):
        p = f"Supervisor.RLS.{loop}"
        for item in ("Excitation", "ConditionNumber", "BoxDistance", "OnBoxLimit", "Prior", "NoiseStd"):
            path = f"{p}.{item}"
            tag = tags[path]
            value = values[path]
            items = value if isinstance(value, list) else [value]
            assert all(math.isfinite(float(v)) for v in items), path
            if tag.eu_range is not None:
                lo, hi = tag.eu_range
                assert all(lo <= float(v) <= hi for v in items), (path, value)
        assert values[f"{p}.OnBoxLimit"] is False
        assert len(values[f"{p}.BoxDistance"]) == 3 and len(values[f"{p}.Prior"]) == 3
        assert values[f"{p}.ConditionNumber"] >= 1.0
        # Noiseless plant: what is left is the linear model's error through the fill (measured
        # 4.7e-6 / 2.4e-5 m), below the 0.1 mm of a good transmitter.
        assert values[f"{p}.NoiseStd"] < 1e-4
