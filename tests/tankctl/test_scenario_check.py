"""Expectations in scenarios and ``tankctl scenario check`` (issue 18).

- The pure checker (tankctl.simulate.expect): interlock trip counting by hand and as an
  invariant, bounds inclusive, undefined metrics fail, per-variant application.
- The scenario model: an expectation without bounds, min above max, an unknown variant or loop
  are one-line config errors naming the field.
- The command (tankctl.scenario_cli) through typer's CliRunner (exit 0 / 1 / 2 and its lines)
  and as a subprocess.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import typer
import yaml
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from tankctl.scenario_cli import scenario_app
from tankctl.simulate import ScenarioResult, run_scenario
from tankctl.simulate.expect import check_expectations, interlock_trips, metric_value
from tanklab.config import ConfigError
from tanklab.scenario import Expectation, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SITE = ROOT / "configs" / "single_tank_short_sim.yaml"


def write_scenario(tmp_path: Path, body: dict[str, object], name: str = "s.yaml") -> Path:
    data = {"name": "tiny", "site": str(SITE), **body}
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


STEP = {
    "duration_s": 10.0,
    "initial": {"levels_m": [0.05], "setpoints_m": {"LIC1": 0.05}},
    "events": [{"at_s": 1.0, "kind": "setpoint", "loop": "LIC1", "value_m": 0.08}],
    "variants": [{"name": "fast", "scan_period_s": 0.05}, {"name": "slow"}],
}


# ============================================================================ pure checker


def test_interlock_trips_counts_rising_edges_by_hand() -> None:
    assert interlock_trips([]) == 0
    assert interlock_trips([0, 0, 0]) == 0
    assert interlock_trips([1, 1, 1]) == 1  # latched from the first scan: one trip
    assert interlock_trips([0, 1, 1, 0, 0, 1, 0, 1]) == 3
    assert interlock_trips(np.array([0.0, 1.0])) == 1


@given(st.lists(st.booleans(), max_size=60))
def test_interlock_trips_is_the_number_of_runs_of_trips(states: list[bool]) -> None:
    runs = "".join("1" if s else "0" for s in states).split("0")
    assert interlock_trips(states) == sum(1 for r in runs if r)


@pytest.fixture(scope="module")
def step_run(tmp_path_factory: pytest.TempPathFactory) -> ScenarioResult:
    return run_scenario(write_scenario(tmp_path_factory.mktemp("step"), STEP))


def test_bounds_are_inclusive_and_apply_per_variant(step_run: ScenarioResult) -> None:
    fast = metric_value(step_run.variants["fast"], "LIC1", "iae")
    slow = metric_value(step_run.variants["slow"], "LIC1", "iae")
    assert fast is not None and slow is not None and fast > 0 and slow > 0
    exact = Expectation(variant="fast", loop="LIC1", metric="iae", max=fast, min=fast)
    below = Expectation(loop="LIC1", metric="iae", max=min(fast, slow) * 0.999)
    (only_fast,) = check_expectations(step_run, [exact])
    assert only_fast.variant == "fast" and only_fast.passed and only_fast.value == fast
    both = check_expectations(step_run, [below])
    assert [(o.variant, o.passed) for o in both] == [("fast", False), ("slow", False)]
    assert "is above" in both[0].reason and both[0].line().startswith("FAIL  fast LIC1 iae: ")
    above = Expectation(loop="LIC1", metric="iae", min=max(fast, slow) * 1.001)
    assert not any(o.passed for o in check_expectations(step_run, [above]))
    assert "is below" in check_expectations(step_run, [above])[0].reason


def test_the_metrics_are_those_of_simulate(step_run: ScenarioResult) -> None:
    run = step_run.variants["slow"]
    for metric in ("iae", "ise", "itae", "overshoot_pct", "max_du", "constraint_violations"):
        assert metric_value(run, "LIC1", metric) == pytest.approx(run.loops["LIC1"].as_dict()[metric])
    assert metric_value(run, "LIC1", "interlock_trips") == 0.0


def test_an_undefined_metric_fails_whatever_the_bound(tmp_path: Path) -> None:
    # No setpoint step and the level starts at the setpoint: no step, so no overshoot or settling.
    flat = write_scenario(
        tmp_path, {"duration_s": 2.0, "initial": {"levels_m": [0.05], "setpoints_m": {"LIC1": 0.05}}}
    )
    result = run_scenario(flat)
    for metric in ("settling_time_s", "overshoot_pct"):
        (o,) = check_expectations(result, [Expectation(loop="LIC1", metric=metric, max=1e9)])  # type: ignore[arg-type]
        assert not o.passed and o.value is None and "not defined" in o.reason


def test_an_interlock_trip_is_counted_once_while_latched(tmp_path: Path) -> None:
    # Pump at 100 % (0.2 m^3/s into 0.5 m^2: 0.4 m/s) from 0.1 m: HH 0.25 m within a second;
    # the trip stops the pump and stays latched (no reset), so exactly one trip.
    path = write_scenario(
        tmp_path,
        {
            "duration_s": 5.0,
            "initial": {"levels_m": [0.1], "setpoints_m": {"LIC1": 0.1}},
            "events": [
                {"at_s": 0.0, "kind": "loop_mode", "loop": "LIC1", "mode": "MANUAL", "mv_percent": 100}
            ],
        },
    )
    result = run_scenario(path)
    run = result.variants["default"]
    assert run.interlock_tanks == ["T1"]
    assert run.trips[-1, 0] == 1.0 and run.trips[0, 0] == 0.0
    assert metric_value(run, "LIC1", "interlock_trips") == 1.0
    (o,) = check_expectations(result, [Expectation(loop="LIC1", metric="interlock_trips", max=0)])
    assert not o.passed and o.value == 1.0


# ============================================================================ the model


@pytest.mark.parametrize(
    ("expect", "message"),
    [
        ({"loop": "LIC1", "metric": "iae"}, "expect[0]: an expectation needs max, min or both"),
        ({"loop": "LIC1", "metric": "iae", "min": 2, "max": 1}, "min 2 is above max 1"),
        ({"loop": "LIC1", "metric": "iea", "max": 1}, "expect[0].metric: Input should be"),
        (
            {"variant": "nope", "loop": "LIC1", "metric": "iae", "max": 1},
            "expect[0].variant: no variant 'nope'",
        ),
    ],
)
def test_a_bad_expectation_is_a_one_line_config_error(
    tmp_path: Path, expect: dict[str, object], message: str
) -> None:
    path = write_scenario(tmp_path, {**STEP, "expect": [expect]})
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    assert message in str(info.value) and str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_an_unknown_loop_is_refused_before_the_run(tmp_path: Path) -> None:
    path = write_scenario(tmp_path, {**STEP, "expect": [{"loop": "LIC7", "metric": "iae", "max": 1}]})
    with pytest.raises(ConfigError, match=r"expect\[0\]\.loop: unknown loop LIC7"):
        run_scenario(path)


# ============================================================================ the command


@pytest.fixture
def app() -> typer.Typer:
    main = typer.Typer()
    main.add_typer(scenario_app, name="scenario")
    return main


def test_check_passes_fails_and_refuses(app: typer.Typer, step_run: ScenarioResult, tmp_path: Path) -> None:
    iae = {name: metric_value(v, "LIC1", "iae") for name, v in step_run.variants.items()}
    ok = write_scenario(
        tmp_path,
        {
            **STEP,
            "expect": [
                {"loop": "LIC1", "metric": "iae", "max": max(iae.values())},
                {"loop": "LIC1", "metric": "constraint_violations", "max": 0},
            ],
        },
        "ok.yaml",
    )
    r = CliRunner().invoke(app, ["scenario", "check", str(ok)])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert len(lines) == 5 and all(line.startswith("pass  ") for line in lines[:4])
    assert lines[-1] == "scenario check tiny: 4 of 4 expectations met"

    tight = write_scenario(
        tmp_path,
        {
            **STEP,
            "expect": [
                {
                    "variant": "slow",
                    "loop": "LIC1",
                    "metric": "iae",
                    "max": iae["slow"] / 2,
                    "note": "half of what it does",
                }
            ],
        },
        "tight.yaml",
    )
    r = CliRunner().invoke(app, ["scenario", "check", str(tight)])
    assert r.exit_code == 1
    fail_line, summary = r.stdout.splitlines()
    assert fail_line.startswith("FAIL  slow LIC1 iae: ") and fail_line.endswith("(half of what it does)")
    assert summary == "scenario check tiny: 0 of 1 expectations met, 1 failed"

    r = CliRunner().invoke(app, ["scenario", "check", str(tight), "--variant", "fast"])
    assert r.exit_code == 2 and "no expectation applies to the variants run (fast)" in r.stderr

    bare = write_scenario(tmp_path, STEP, "bare.yaml")
    r = CliRunner().invoke(app, ["scenario", "check", str(bare)])
    assert r.exit_code == 2 and "no expect: section, nothing to check" in r.stderr


def test_check_as_a_process_exits_1_on_a_failed_expectation(tmp_path: Path) -> None:
    path = write_scenario(
        tmp_path,
        {**STEP, "variants": [{"name": "slow"}], "expect": [{"loop": "LIC1", "metric": "iae", "max": 0}]},
    )
    p = subprocess.run(
        [sys.executable, "-m", "tankctl", "scenario", "check", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert p.returncode == 1, p.stderr
    assert p.stdout.splitlines()[0].startswith("FAIL  slow LIC1 iae: ")


SHIPPED = sorted(p for p in (ROOT / "configs" / "scenarios").glob("*.yaml") if load_scenario(p)[0].expect)


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_the_shipped_expectations_hold(path: Path) -> None:
    failed = [o.line() for o in check_expectations(run_scenario(path)) if not o.passed]
    assert not failed, failed


def test_a_shipped_scenario_has_expectations() -> None:
    assert [p.stem for p in SHIPPED] == ["energies_mpc_pid_vs_pid"]
