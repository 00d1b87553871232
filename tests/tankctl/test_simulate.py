"""``tankctl simulate`` / ``compare`` and the shipped paper scenarios.

- Every scenario in configs/scenarios/ runs in full (smoke), with finite metrics, a JSON document
  that serialises without NaN, and every controlled setpoint step measured against the bang-bang
  bound; no controller settles faster than the physical limit.
- The NL-PI scenario gives equal overshoot at the three levels (digest 2.2: 4.39 / 4.33 / 4.32 %
  at a 0.01 s scan), the plain PI does not, and the 1 s scan overshoots the first step > 20 %.
- The IMC scenario's gains are the tuning rules applied to the plant's own linearisation.
- Events act at the first scan at or after their time; bad scenarios fail with one line.
- The commands through typer's CliRunner and as a subprocess.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import typer
import yaml
from typer.testing import CliRunner

from plant_sim.linearize import linearize, operating_point
from plant_sim.models import TankNetwork, default_inputs
from plc_emulator.tuning import imc_from_denominator, velocity_gains, ziegler_nichols_open_loop
from tankctl.limits import fopdt_tangent_fit
from tankctl.simulate import (
    ScenarioResult,
    apply_initial,
    csv_paths,
    markdown_report,
    published_rows,
    regenerate_docs,
    register,
    result_json,
    run_scenario,
)
from tanklab.config import load_site
from tanklab.errors import ConfigError
from tanklab.scenario import InitialState, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = sorted((ROOT / "configs" / "scenarios").glob("*.yaml"))
REQUIRED_VARIANTS = {
    "nlpi_short_sim": {"nlpi", "pi"},
    "imc_pi_coupled": {"imc_pi", "zn_pi"},
    "mrac_two_tank": {"cpi", "mit", "api"},
    "kortela_mpc_vs_pi": {"pi", "mpc", "mpc_fast"},
    "energies_mpc_pid_vs_pid": {"pid", "mpc_pid", "mpc"},
}


@cache
def ran(name: str) -> ScenarioResult:
    """Each shipped scenario runs once per test session (the smoke test and the others share it)."""
    return run_scenario(ROOT / "configs" / "scenarios" / f"{name}.yaml")


# ============================================================================ shipped scenarios


def test_every_paper_has_its_scenario() -> None:
    assert {p.stem for p in SCENARIOS} >= set(REQUIRED_VARIANTS)


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_scenario_runs(path: Path) -> None:
    scenario, _ = load_scenario(path)
    result = ran(path.stem)
    assert list(result.variants) == [v.name for v in scenario.variants]
    assert REQUIRED_VARIANTS.get(path.stem, set()) <= set(result.variants)
    doc = json.loads(json.dumps(result_json(result), allow_nan=False))
    assert doc["scenario"] == scenario.name
    for name, v in result.variants.items():
        n = round(scenario.duration_s / v.ts_s)
        assert v.t_s.shape == (n,) and v.levels_m.shape[0] == n
        assert np.all(np.isfinite(v.levels_m)) and np.all(np.isfinite(v.commands))
        entry = doc["variants"][name]
        assert set(entry) >= {"loops", "steps"}
        assert v.loops, f"{name}: no controlled loop"
        for loop, m in entry["loops"].items():
            assert set(m) == {
                "iae",
                "ise",
                "itae",
                "overshoot_pct",
                "settling_time_s",
                "max_du",
                "constraint_violations",
            }, loop
            assert m["iae"] >= 0 and m["ise"] >= 0 and m["itae"] >= 0
        assert v.steps, f"{name}: no setpoint step"
        for step in entry["steps"]:
            assert set(step) >= {"loop", "time", "setpoint", "overshoot_pct", "settling_time_s"}
        for s in v.steps:
            assert s.min_time_s is not None and s.min_time_s > 0, (name, s)
            if s.settling_ratio is not None and s.min_time_method == "hold":
                # A true lower bound: no controller settles faster than its pump at the limit.
                assert s.settling_ratio >= 1.0, (name, s)
        if name == "mpc_literal":  # the paper-literal first move is not rate-limited: it shows
            assert sum(m.constraint_violations for m in v.loops.values()) > 0
        else:
            assert all(m.constraint_violations == 0 for m in v.loops.values()), name


def test_nlpi_gives_equal_overshoot_at_the_three_levels() -> None:
    # Digest 2.2: zeta = 0.7071 -> 4.32 % in continuous time; at Ts = 0.01 s 4.39 / 4.33 / 4.32 %.
    result = ran("nlpi_short_sim")
    os_ = [s.overshoot_pct for s in result.variants["nlpi"].steps]
    assert [s.setpoint_m for s in result.variants["nlpi"].steps] == [0.05, 0.10, 0.15]
    assert os_ == pytest.approx([4.32] * 3, abs=0.1)
    assert max(os_) - min(os_) < 0.1
    # The plain PI placed at the same wn, zeta at 0.15 m: 0.00 / 0.25 / 3.26 % (not equal).
    pi = [s.overshoot_pct for s in result.variants["pi"].steps]
    assert max(pi) - min(pi) > 2.0
    # The PLC's 1 s scan: 24.4 / 6.9 / 4.8 % (digest 2.2).
    one_s = [s.overshoot_pct for s in result.variants["nlpi_1s"].steps]
    assert one_s[0] > 20.0 and one_s[0] > one_s[1] > one_s[2]


def test_published_numbers_are_compared() -> None:
    rows = published_rows(ran("energies_mpc_pid_vs_pid"))
    assert {(r["variant"], r["metric"]) for r in rows} >= {
        ("pid", "settling_time_s"),
        ("mpc_pid", "overshoot_pct"),
    }
    assert all(r["ours"] is not None for r in rows)


def test_imc_scenario_gains_come_from_the_tuning_rules() -> None:
    # h2/qin1 of the calibrated plant linearised at the nominal point is K / (a2 s^2 + a1 s + 1)
    # with a2 = 1 / det A, a1 = -trace A / det A, K = B11 A21 / det A (no zero: a pure lag).
    site = load_site(ROOT / "configs" / "two_tank_interacting.yaml")
    net = TankNetwork.from_config(site.plant)
    u = default_inputs(net, site.plant)
    op = operating_point(net, site.plant, u)
    lin = linearize(net, op.equilibrium_levels_m, op.flows_m3_s, u)
    A, B = lin.A, lin.B
    det, tr = float(np.linalg.det(A)), float(np.trace(A))
    num, den = B[0, 0] * A[1, 0] / det, (1.0 / det, -tr / det, 1.0)
    lam = den[1] / 14.7  # the paper's lambda / (tau1 + tau2) = 1 / 14.7
    imc_pi = imc_from_denominator(num, den, lam, pid=False)
    imc_pid = imc_from_denominator(num, den, lam, pid=True)
    fit = fopdt_tangent_fit(imc_pi.K, imc_pi.tau1, imc_pi.tau2)
    zn = ziegler_nichols_open_loop(fit.K, fit.theta, fit.tau, "pi")
    expected = {
        "imc_pi": velocity_gains(imc_pi.Kc, imc_pi.Ti),
        "imc_pid": velocity_gains(imc_pid.Kc, imc_pid.Ti, imc_pid.Td),
        "zn_pi": velocity_gains(zn.Kc, zn.Ti),
    }
    scenario, _ = load_scenario(ROOT / "configs" / "scenarios" / "imc_pi_coupled.yaml")
    for v in scenario.variants:
        g = v.set["plc.loops.0.gains"]
        e = expected[v.name]
        assert (g["kp"], g["ki"], g["kd"]) == (
            pytest.approx(e.Kp, rel=1e-4),
            pytest.approx(e.Ki, rel=1e-4),
            pytest.approx(e.Kd, rel=1e-4, abs=1e-12),
        ), v.name
        assert v.set["plc.loops.0.pv"] == "LT2"  # h2 by qin1


def test_imc_on_the_plant_repeats_the_transfer_function_shape() -> None:
    # The same dimensionless design (lambda = (tau1 + tau2) / 14.7, Td dropped) on a plant with a
    # similar tau2 / tau1 (5.95 against 5.10) overshoots like the transfer function's 35.7 %.
    (step,) = ran("imc_pi_coupled").variants["imc_pi"].steps
    assert step.overshoot_pct == pytest.approx(35.7, abs=5.0)


# ============================================================================ events and initial state


def write_scenario(tmp_path: Path, body: dict[str, object], name: str = "s.yaml") -> Path:
    data = {"name": "tiny", "site": str(ROOT / "configs" / "single_tank_short_sim.yaml"), **body}
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_events_act_at_the_first_scan_at_or_after_their_time(tmp_path: Path) -> None:
    # Scan 0.1 s: an event at 0.25 s acts before scan 3 (t = 0.3 s); one at 0.3 s at scan 3 too
    # (0.3 / 0.1 = 2.9999999999999996 in floating point must not slip to scan 4).
    path = write_scenario(
        tmp_path,
        {
            "duration_s": 1.0,
            "initial": {"levels_m": [0.05], "setpoints_m": {"LIC1": 0.05}},
            "events": [
                {"at_s": 0.25, "kind": "setpoint", "loop": "LIC1", "value_m": 0.06},
                {"at_s": 0.3, "kind": "disturbance", "tank": "T1", "flow_m3_s": 1e-4},
                {"at_s": 5.0, "kind": "setpoint", "loop": "LIC1", "value_m": 0.2},
            ],
        },
    )
    v = run_scenario(path).variants["default"]
    sp = v.setpoints_m[:, 0]
    assert sp[2] == 0.05 and sp[3] == 0.06 and np.all(sp[3:] == 0.06)  # the 5 s event is after the end
    assert [(s.time_s, s.setpoint_m) for s in v.steps] == [(pytest.approx(0.3), 0.06)]


def test_initial_state_is_written_into_the_site() -> None:
    site = load_site(ROOT / "configs" / "three_tank_energies_sim.yaml")
    init = InitialState(
        levels_m=[0.1, 0.2, 0.3],
        leaks={"T2": 0.5},
        valves={"V13": 0.25},
        setpoints_m={"LIC1": 0.35},
        modes={"LIC2": "MANUAL"},
        pump_commands=[1e-5, 2e-5],
    )
    s = apply_initial(site, init)
    assert [t.initial_level_m for t in s.plant.tanks] == [0.1, 0.2, 0.3]
    assert s.plant.tank("T2").initial_leak_opening == 0.5
    assert s.plant.valves[0].initial_opening == 0.25
    assert s.plc is not None and s.plc.loops[0].setpoint_m == 0.35 and s.plc.loops[1].mode == "MANUAL"
    assert [p.initial_command for p in s.plant.pumps] == [1e-5, 2e-5]
    with pytest.raises(ConfigError, match="setpoint_m"):
        apply_initial(site, InitialState(setpoints_m={"LIC1": 0.61}))


def test_an_event_that_cannot_be_applied_names_itself(tmp_path: Path) -> None:
    path = write_scenario(
        tmp_path,
        {"duration_s": 1.0, "events": [{"at_s": 0.5, "kind": "setpoint", "loop": "LIC1", "value_m": 0.9}]},
    )
    with pytest.raises(ConfigError, match=r"tiny: events\[0\] \(setpoint at 0.5 s\): LIC1 SP 0.9 outside"):
        run_scenario(path)


def test_unknown_variant_and_missing_supervisor_are_config_errors(tmp_path: Path) -> None:
    path = write_scenario(
        tmp_path, {"duration_s": 1.0, "variants": [{"name": "mpc", "supervisor_mode": "MPC"}]}
    )
    with pytest.raises(ConfigError, match="no supervisor section"):
        run_scenario(path)
    with pytest.raises(ConfigError, match="no variant 'nope'"):
        run_scenario(path, variants=["nope"])


def test_csv_paths() -> None:
    assert csv_paths("out/", ["a"]) == {"a": Path("out/a.csv")}
    assert csv_paths(Path("run.csv"), ["a", "b"]) == {"a": Path("run_a.csv"), "b": Path("run_b.csv")}
    assert csv_paths(Path("x/run"), ["a"]) == {"a": Path("x/run_a.csv")}


# ============================================================================ the commands


@pytest.fixture
def app() -> typer.Typer:
    main = typer.Typer()
    register(main)
    return main


@pytest.fixture
def tiny(tmp_path: Path) -> Path:
    return write_scenario(
        tmp_path,
        {
            "duration_s": 5.0,
            "initial": {"levels_m": [0.04], "setpoints_m": {"LIC1": 0.05}},
            "events": [{"at_s": 2.0, "kind": "setpoint", "loop": "LIC1", "value_m": 0.06}],
            "variants": [{"name": "fast", "scan_period_s": 0.05}, {"name": "slow"}],
            "published": [{"variant": "fast", "loop": "LIC1", "metric": "overshoot_pct", "value": 4.32}],
        },
    )


def test_simulate_json_csv_and_plot(app: typer.Typer, tiny: Path, tmp_path: Path) -> None:
    out = tmp_path / "csv"
    out.mkdir()
    png = tmp_path / "fig.png"
    r = CliRunner().invoke(app, ["simulate", str(tiny), "--json", "--csv", str(out), "--plot", str(png)])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert doc["scenario"] == "tiny" and set(doc["variants"]) == {"fast", "slow"}
    fast = doc["variants"]["fast"]
    assert set(fast["loops"]["LIC1"]) >= {"iae", "overshoot_pct", "constraint_violations"}
    assert [s["time"] for s in fast["steps"]] == [0.0, 2.0]
    rows = (out / "fast.csv").read_text().splitlines()
    assert rows[0].startswith("t_s,level_T1_m,sp_LIC1_m,mode_LIC1,command_P1,flow_P1_m3_s,LIC1_Kp")
    assert len(rows) == 1 + 100  # 5 s at 0.05 s
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_simulate_prints_a_table_and_writes_stems(app: typer.Typer, tiny: Path, tmp_path: Path) -> None:
    r = CliRunner().invoke(app, ["simulate", str(tiny), "--csv", str(tmp_path / "run.csv"), "-v", "slow"])
    assert r.exit_code == 0, r.output
    assert "IAE" in r.stdout and "[slow]" in r.stdout and "[fast]" not in r.stdout
    assert (tmp_path / "run_slow.csv").exists() and not (tmp_path / "run_fast.csv").exists()


def test_bad_scenario_exits_2_with_one_line(app: typer.Typer, tmp_path: Path) -> None:
    bad = write_scenario(tmp_path, {"duration_s": -1.0})
    r = CliRunner().invoke(app, ["simulate", str(bad)])
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and "duration_s" in r.stderr and "Traceback" not in r.output
    r = CliRunner().invoke(app, ["compare", str(tmp_path / "missing.yaml")])
    assert r.exit_code == 2 and r.stderr.startswith("tankctl: ")


def test_compare_prints_ours_beside_the_paper(app: typer.Typer, tiny: Path) -> None:
    r = CliRunner().invoke(app, ["compare", str(tiny)])
    assert r.exit_code == 0, r.output
    assert "ours/paper" in r.stdout and "4.32" in r.stdout and "minimum-time" in r.stdout
    r = CliRunner().invoke(app, ["compare", str(tiny), "--markdown"])
    assert r.exit_code == 0 and "| variant | loop |" in r.stdout


def test_commands_as_a_subprocess(tiny: Path) -> None:
    code = (
        "import typer; from tankctl.simulate import register; "
        "app = typer.Typer(); register(app); app(prog_name='tankctl')"
    )
    p = subprocess.run(
        [sys.executable, "-c", code, "simulate", str(tiny), "--json", "-v", "slow"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["variants"]["slow"]["loops"]["LIC1"]["iae"] > 0
    p = subprocess.run(
        [sys.executable, "-c", code, "simulate", str(tiny.parent / "nope.yaml")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert p.returncode == 2 and p.stderr.count("\n") == 1


def test_generated_doc_blocks_are_rewritten(tmp_path: Path, tiny: Path) -> None:
    doc = tmp_path / "docs" / "r.md"
    doc.parent.mkdir()
    doc.write_text(
        f"# t\n<!-- generated:scenario {tiny} -->\nstale\n<!-- /generated -->\n"
        "<!-- generated:tf imc -->\nstale\n<!-- /generated -->\nend\n",
        encoding="utf-8",
    )
    done = regenerate_docs(doc, root="/")
    text = doc.read_text()
    assert len(done) == 2 and "stale" not in text and text.endswith("end\n")
    assert "IMC PI, Td dropped" in text and "![tiny](figures/tiny.png)" in text
    assert (tmp_path / "docs" / "figures" / "tiny.png").exists()
    md = markdown_report(run_scenario(tiny))
    assert md.count("| variant |") == 3
    every_loop = md.split("Every loop")[1]
    assert math.isfinite(float(every_loop.split("| fast | LIC1 | ")[1].split(" |")[0]))  # the IAE
