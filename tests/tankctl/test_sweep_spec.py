"""Sweep files: validation (one line naming the file, the field and the rule), the case
expansion against a hand-made oracle, seeds and draws, and the pre-flight of paths and values."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from helpers import ROOT
from sweep_support import ENERGIES, SITE, write_spec
from tankctl.sweep.cases import case_setup, draw, expand, plan_sweep
from tankctl.sweep.spec import Linspace, LogNormal, Normal, SweepSpec, load_spec
from tanklab.config import ConfigError
from tanklab.scenario import load_scenario


def _error(tmp_path: Path, **fields: object) -> str:
    path = write_spec(tmp_path, **fields)
    with pytest.raises(ConfigError) as e:
        spec, scenario = load_spec(path)
        plan_sweep(spec, scenario)
    msg = str(e.value)
    assert "\n" not in msg
    return msg


def test_unknown_field_names_file_and_field(tmp_path: Path) -> None:
    msg = _error(tmp_path, drawz=3)
    assert msg.startswith(str(tmp_path / "tiny.yaml")) and "drawz" in msg and "Extra inputs" in msg


def test_parameter_needs_exactly_one_source(tmp_path: Path) -> None:
    two = [
        {
            "name": "kp",
            "paths": ["site.plc.loops.0.gains.kp"],
            "values": [1.0],
            "uniform": {"low": 0, "high": 1},
        }
    ]
    msg = _error(tmp_path, parameters=two)
    assert "parameters[0]" in msg and "exactly one of" in msg and "values, uniform" in msg


@pytest.mark.parametrize(
    ("dist", "rule"),
    [
        ({"uniform": {"low": 1.0, "high": 1.0}}, "must be below high"),
        ({"normal": {"mean": 0.0, "std": 1.0, "low": 8.0, "high": 9.0}}, "holds"),
        ({"normal": {"mean": 0.0, "std": 0.0, "low": -1.0, "high": 1.0}}, "greater than 0"),
        ({"lognormal": {"log_mean": 0.0, "log_std": 1.0, "low": 0.0, "high": 2.0}}, "greater than 0"),
    ],
)
def test_invalid_distribution(tmp_path: Path, dist: dict[str, object], rule: str) -> None:
    msg = _error(tmp_path, parameters=[{"name": "kp", "paths": ["site.plc.loops.0.gains.kp"], **dist}])
    assert "parameters[0]" in msg and rule in msg


def test_unknown_metric_and_unrooted_path(tmp_path: Path) -> None:
    assert "metrics[0]" in _error(tmp_path, metrics=["iea"])
    msg = _error(tmp_path, parameters=[{"name": "kp", "paths": ["plc.loops.0.gains.kp"], "values": [1e-4]}])
    assert "parameters[0].paths[0]" in msg and "pattern" in msg


def test_path_that_does_not_exist_fails_before_any_case(tmp_path: Path) -> None:
    msg = _error(
        tmp_path, parameters=[{"name": "a", "paths": ["site.plant.tanks.7.area_m2"], "values": [0.01]}]
    )
    assert "parameter path site.plant.tanks.7.area_m2" in msg and "no list item 7" in msg
    msg = _error(tmp_path, parameters=[{"name": "a", "paths": ["scenario.events.0.size"], "values": [1.0]}])
    assert "scenario.events.0.size" in msg and "no field 'size'" in msg


def test_value_out_of_range_fails_before_any_case(tmp_path: Path) -> None:
    # the second grid value (a leak opening of 1.5) is refused by the scenario's own model
    params = [{"name": "leak", "paths": ["scenario.events.0.opening"], "values": [0.5, 1.5]}]
    msg = _error(tmp_path, parameters=params)
    assert "scenario overrides" in msg and "events[0]" in msg and "less than or equal to 1" in msg


def test_unknown_variant_and_loop(tmp_path: Path) -> None:
    assert "no variant 'pdi'" in _error(tmp_path, variants=["pdi"])
    assert "no loop LIC7" in _error(tmp_path, loops=["LIC7"])


def test_missing_scenario_file(tmp_path: Path) -> None:
    msg = _error(tmp_path, scenario="nope.yaml")
    assert msg.endswith("scenario: no such file nope.yaml")


def test_linspace_grid() -> None:
    assert Linspace(start=0.0, stop=1.0, num=5).grid() == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert Linspace(start=2.0, stop=3.0, num=1).grid() == [2.0]


def test_case_expansion_oracle() -> None:
    spec = SweepSpec.model_validate(
        {
            "name": "x",
            "scenario": "s.yaml",
            "seed": 11,
            "draws": 2,
            "parameters": [
                {"name": "a", "paths": ["site.a"], "values": [1, 2]},
                {"name": "u", "paths": ["site.u"], "uniform": {"low": 0.0, "high": 10.0}},
                {"name": "b", "paths": ["site.b"], "values": ["x", "y", "z"]},
            ],
        }
    )
    cases = expand(spec)
    # last grid parameter fastest, then the draw: c = (i_a * 3 + i_b) * 2 + d
    expected_grid = [(a, b) for a in (1, 2) for b in ("x", "y", "z") for _ in range(2)]
    assert [(c.values["a"], c.values["b"]) for c in cases] == expected_grid
    assert [c.index for c in cases] == list(range(12))
    assert list(cases[0].values) == ["a", "u", "b"]  # file order
    children = np.random.SeedSequence(11).spawn(12)
    for c, child in zip(cases, children, strict=True):
        assert c.seed == int(child.generate_state(1, dtype=np.uint32)[0])
        assert c.values["u"] == np.random.default_rng(child).uniform(0.0, 10.0)
    assert len({c.seed for c in cases}) == 12


def test_truncated_draws_stay_in_bounds() -> None:
    rng = np.random.default_rng(3)
    normal = Normal(mean=0.0, std=1.0, low=0.5, high=1.0)
    lognormal = LogNormal(log_mean=0.0, log_std=1.0, low=0.5, high=2.0)
    xs = [draw(normal, rng) for _ in range(500)]
    ys = [draw(lognormal, rng) for _ in range(500)]
    assert min(xs) >= 0.5 and max(xs) <= 1.0
    assert min(ys) >= 0.5 and max(ys) <= 2.0
    # the truncated normal's mean on [0.5, 1]: (phi(0.5) - phi(1)) / (Phi(1) - Phi(0.5)) = 0.7353
    pdf = lambda z: math.exp(-z * z / 2) / math.sqrt(2 * math.pi)  # noqa: E731
    cdf = lambda z: 0.5 * (1 + math.erf(z / math.sqrt(2)))  # noqa: E731
    mean = (pdf(0.5) - pdf(1.0)) / (cdf(1.0) - cdf(0.5))
    assert abs(float(np.mean(xs)) - mean) < 0.02  # 500 draws: std of the mean 0.0065


def test_case_setup_writes_paths_and_seed(tmp_path: Path) -> None:
    spec, scenario_path = load_spec(
        write_spec(
            tmp_path,
            parameters=[
                {"name": "kp", "paths": ["site.plc.loops.0.gains.kp"], "values": [3.0e-4]},
                {"name": "leak", "paths": ["scenario.events.0.opening"], "values": [0.4]},
            ],
        )
    )
    scenario, site_path = load_scenario(scenario_path)
    assert site_path == SITE.resolve()
    new_scenario, site = case_setup(spec, scenario, site_path, "pid", {"kp": 3.0e-4, "leak": 0.4}, 1234)
    assert site.plc is not None and site.plc.loops[0].gains.kp == 3.0e-4
    assert site.plant.noise_seed == 1234
    assert new_scenario.events[0].opening == 0.4  # type: ignore[union-attr]
    assert scenario.events[0].opening == 1.0  # type: ignore[union-attr]  # the loaded one is untouched


def test_shipped_sweeps_plan() -> None:
    sizes = {"energies_leak_noise": (500, 2), "kortela_mpc_weights": (15, 2)}
    for path in sorted((ROOT / "sweeps").glob("*.yaml")):
        spec, scenario_path = load_spec(path)
        plan = plan_sweep(spec, scenario_path)
        assert (len(plan.cases), len(plan.variants)) == sizes[spec.name]
        assert scenario_path.exists() and scenario_path.parent == ENERGIES.parent
