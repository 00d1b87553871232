"""Linearization: analytic Jacobian, the papers' matrices, equilibria, small-signal agreement."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import cont2discrete
from typer.testing import CliRunner

from digest_models import three_tank_continuous
from plant_sim.integrate import step_adaptive
from plant_sim.linearize import jacobian, level_rhs, linearize, operating_point
from plant_sim.models import TankNetwork, default_inputs
from tankctl.cli import app
from tanklab.config import load_site

ROOT = Path(__file__).resolve().parents[2]
G = 9.81


def _setup(name: str):
    site = load_site(ROOT / f"configs/{name}.yaml")
    net = TankNetwork.from_config(site.plant)
    u = default_inputs(net, site.plant)
    return site, net, u


def _digest_A(at: float, ap: float, mu13: float, mu32: float, mu20: float, h) -> np.ndarray:
    """The digest's formulas (section 1.1), written out independently of plant_sim."""
    return three_tank_continuous(at, ap, mu13, mu32, mu20, np.asarray(h))[0]


@pytest.mark.parametrize(
    ("name", "params"),
    [
        ("three_tank_energies_sim", (0.0154, 5e-5, 0.5, 0.5, 0.675)),
        ("three_tank_energies_rig", (0.021, 1.26677e-4, 0.06, 0.07, 0.074)),
        ("three_tank_kortela", (0.0154, 5e-5, 0.84, 0.84, 0.84)),
    ],
)
def test_three_tank_matrices_match_the_digest_formulas(name: str, params) -> None:
    site, net, u = _setup(name)
    op = operating_point(net, site.plant, u)
    at = params[0]
    A_ref = _digest_A(*params, op.levels_m)
    B_ref = np.array([[1 / at, 0], [0, 1 / at], [0, 0]])
    A, B = jacobian(net, op.levels_m, u)
    assert np.allclose(A, A_ref, rtol=1e-12, atol=0)
    assert np.allclose(B, B_ref, rtol=1e-12)
    ts = site.plc.scan_period_s
    Ad_ref, Bd_ref, *_ = cont2discrete((A_ref, B_ref, np.eye(3), np.zeros((3, 2))), ts, method="zoh")
    model = linearize(net, op.levels_m, op.flows_m3_s, u, ts)
    assert np.allclose(model.A, Ad_ref, rtol=1e-10) and np.allclose(model.B, Bd_ref, rtol=1e-10)
    assert np.array_equal(model.C, np.eye(3)) and not model.D.any()


def test_energies_sim_values_the_digest_quotes() -> None:
    site, net, u = _setup("three_tank_energies_sim")
    op = operating_point(net, site.plant, u)
    # Holding (0.4, 0.2) needs Q = (3.502e-5, 3.184e-5); T3 then sits at 0.300 (digest 1.1).
    assert op.flows_m3_s == pytest.approx([3.502e-5, 3.184e-5], abs=5e-9)
    assert op.equilibrium_levels_m[2] == pytest.approx(0.300, abs=5e-4)
    model = linearize(net, op.levels_m, op.flows_m3_s, u, 1.0)
    # ZOH gives B(2,2) = 64.22 (the paper printed a copy of B(1,1)); Euler would give zeros here:
    assert model.B[1, 1] == pytest.approx(64.22, abs=0.005)
    assert model.A[0, 1] != 0 and model.B[2, 0] != 0
    modes = sorted(-1 / np.linalg.eigvals(jacobian(net, op.levels_m, u)[0]).real)
    assert modes == pytest.approx([27.2, 57.5, 455.6], abs=0.5)  # digest: 27, 58, 456 s
    # The printed flows are no equilibrium of the printed levels: they settle at (0.435, 0.235, 0.335).
    from plant_sim.linearize import steady_levels

    h = steady_levels(net, np.array([0.35e-4, 0.375e-4]), u, op.levels_m)
    assert h == pytest.approx([0.435, 0.235, 0.335], abs=1.5e-3)


def test_rig_and_kortela_operating_points() -> None:
    site, net, u = _setup("three_tank_energies_rig")
    op = operating_point(net, site.plant, u)
    assert op.flows_m3_s == pytest.approx([1.143e-5, 7.14e-6], rel=2e-3)
    assert op.commands == pytest.approx([557, 486], abs=1)
    assert op.equilibrium_levels_m[2] == pytest.approx(0.2847, abs=2e-4)
    modes = sorted(-1 / np.linalg.eigvals(jacobian(net, op.levels_m, u)[0]).real)
    assert modes == pytest.approx([113, 261, 2055], rel=0.01)
    site, net, u = _setup("three_tank_kortela")
    op = operating_point(net, site.plant, u)
    assert op.equilibrium_levels_m == pytest.approx([0.4037, 0.2289, 0.3163], abs=1e-4)
    modes = sorted(-1 / np.linalg.eigvals(jacobian(net, op.levels_m, u)[0]).real)
    assert modes == pytest.approx([15, 37, 330], rel=0.05)


@pytest.mark.parametrize(
    "name",
    ["three_tank_energies_sim", "single_tank_short_sim", "two_tank_interacting", "three_tank_energies_rig"],
)
def test_analytic_jacobian_matches_finite_differences(name: str) -> None:
    site, net, u = _setup(name)
    u = type(u)(u.pump_commands, u.valve_openings * 0.7, np.full(net.n_tanks, 0.3), u.disturbances_m3_s)
    op = operating_point(net, site.plant, default_inputs(net, site.plant))
    h0, q0 = op.levels_m + 0.01, op.flows_m3_s
    A, B = jacobian(net, h0, u)
    eps_h, eps_q = 1e-7, 1e-10
    A_fd = np.column_stack(
        [
            (level_rhs(net, h0 + eps_h * e, q0, u) - level_rhs(net, h0 - eps_h * e, q0, u)) / (2 * eps_h)
            for e in np.eye(net.n_tanks)
        ]
    )
    B_fd = np.column_stack(
        [
            (level_rhs(net, h0, q0 + eps_q * e, u) - level_rhs(net, h0, q0 - eps_q * e, u)) / (2 * eps_q)
            for e in np.eye(net.n_pumps)
        ]
    )
    assert np.allclose(A, A_fd, rtol=1e-6, atol=1e-12)
    assert np.allclose(B, B_fd, rtol=1e-6)


def test_nonlinear_plant_at_small_amplitude_matches_its_linearization() -> None:
    site, net, u = _setup("three_tank_energies_sim")
    op = operating_point(net, site.plant, u)
    model = linearize(net, op.equilibrium_levels_m, op.flows_m3_s, u, 1.0)
    dq = np.array([2e-7, -1e-7])
    uu = type(u)(op.flows_m3_s + dq, u.valve_openings, u.leak_openings, u.disturbances_m3_s)
    x = net.initial_state(op.equilibrium_levels_m)
    dx = np.zeros(3)
    for k in range(100):
        x = step_adaptive(net, x, uu, 1.0, t_s=k)
        dx = model.A @ dx + model.B @ dq
    dev = net.levels(x) - op.equilibrium_levels_m
    assert np.max(np.abs(dev - dx)) < 0.01 * np.max(np.abs(dx))


def test_cli_linearize_json() -> None:
    result = CliRunner().invoke(
        app, ["linearize", str(ROOT / "configs/three_tank_energies_sim.yaml"), "--ts", "1", "--json"]
    )
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert set(data) >= {"A", "B", "C", "D", "ts", "operating_point"}
    assert data["ts"] == 1.0 and data["B"][1][1] == pytest.approx(64.22, abs=0.005)
    cont = json.loads(
        CliRunner().invoke(app, ["linearize", str(ROOT / "configs/three_tank_kortela.yaml"), "--json"]).output
    )
    assert cont["ts"] is None and cont["A"][0][0] < 0
    bad = CliRunner().invoke(app, ["linearize", str(ROOT / "configs/three_tank_kortela.yaml"), "--ts", "-1"])
    assert bad.exit_code == 2 and "Traceback" not in bad.output
