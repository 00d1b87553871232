"""Tests of the MRAC block (plc_emulator.mrac).

The closed-loop tests use a first-order tank model from the MRAC paper's identification table
(region 2, G11: K = 0.586 cm per L/h, tau = 54 s; dead time dropped), levels in cm and the
inflow in L/h, integrated exactly (ZOH) between 1 s scans. Setpoint: a square wave between
12.6 and 17.6 cm with a 500 s period; reference model delta = 0.7, wn = 4.6 / (delta 60 s).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from plc_emulator.mrac import DiscreteSecondOrder, Mrac, MracConfig
from tanklab.enums import LoopMode

K, TAU = 0.586, 54.0
DELTA = 0.7
WN = 4.6 / (DELTA * 60.0)
Y0 = 12.6


def analytic_step(t: np.ndarray, wn: float, delta: float) -> np.ndarray:
    """Unit step response of wn^2 / (s^2 + 2 delta wn s + wn^2)."""
    if delta < 1.0:
        wd = wn * math.sqrt(1.0 - delta**2)
        return 1.0 - np.exp(-delta * wn * t) * (np.cos(wd * t) + delta * wn / wd * np.sin(wd * t))
    if delta == 1.0:
        return 1.0 - (1.0 + wn * t) * np.exp(-wn * t)
    r = wn * math.sqrt(delta**2 - 1.0)
    p1, p2 = -delta * wn + r, -delta * wn - r
    return 1.0 + (p2 * np.exp(p1 * t) - p1 * np.exp(p2 * t)) / (p1 - p2)


def mrac(law: str = "mit", **kw: object) -> Mrac:
    cfg: dict[str, object] = {
        "ts_s": 1.0,
        "law": law,
        "wn": WN,
        "delta": DELTA,
        "gamma": 1.0 if law == "mit" else 0.2,
        "alpha": 1.0,
        "theta0": (1.0, 0.0) if law == "mit" else (1.0, 0.02),
        "theta_min": (0.0, -5.0) if law == "mit" else (0.0, 0.0),
        "theta_max": (50.0, 50.0) if law == "mit" else (50.0, 5.0),
        "u_min": 0.0,
        "u_max": 1000.0,
        "initial_mv": Y0 / K,
    }
    cfg.update(kw)
    return Mrac(MracConfig(**cfg))  # type: ignore[arg-type]


def run_square_wave(
    block: Mrac, n: int = 5000, period: int = 500
) -> tuple[np.ndarray, list[float], list[float]]:
    """Closed loop on the first-order tank; returns (|e| per scan, PV, SP)."""
    a = math.exp(-1.0 / TAU)
    y = Y0
    errs, ys, sps = [], [], []
    for k in range(n):
        sp = 17.6 if (k // (period // 2)) % 2 == 1 else 12.6
        r = block.step(sp, y)
        errs.append(abs(r.model_error))
        ys.append(y)
        sps.append(sp)
        assert block.config.u_min <= r.mv <= block.config.u_max
        assert np.all(r.theta >= np.array(block.config.theta_min))
        assert np.all(r.theta <= np.array(block.config.theta_max))
        y = a * y + (1.0 - a) * K * r.mv
    return np.array(errs), ys, sps


@pytest.mark.parametrize("delta", [0.7, 1.0, 2.0])
def test_discretised_reference_model_matches_analytic_step(delta: float) -> None:
    wn = 4.6 / (delta * 60.0)
    f = DiscreteSecondOrder(wn, delta, 1.0)
    ys = []
    for _ in range(200):
        ys.append(wn**2 * f.x[0])
        f.advance(1.0)
    assert np.array(ys) == pytest.approx(analytic_step(np.arange(200.0), wn, delta), abs=1e-12)


def test_reference_model_inside_block() -> None:
    # Entering AUTO with y = 0 starts the model at rest at 0; a unit command then gives the
    # analytic step response at the sample instants (y held at 0, plant not simulated).
    blk = mrac(initial_mv=0.0, gamma=0.0)
    y_m = [blk.step(1.0, 0.0).y_m for _ in range(100)]
    assert np.array(y_m) == pytest.approx(analytic_step(np.arange(100.0) * 1.0, WN, DELTA), abs=1e-12)


def test_mit_signs_one_step() -> None:
    # Scan 0 enters AUTO at rest at u_c = y = 10 with u = 10, so theta1 = (10 + 0 * 10) / 10 = 1
    # stays (1, 0). Scan 1: y = 11 while the model (at rest) gives y_m = 10, so e = +1 (plant
    # above the model); phi = [G_m u_c, -G_m y] = [10, -10] (filters at rest at 10). The digest's
    # signs: theta1 falls and theta2 rises (both lower u) by Ts gamma e phi / (alpha + phi'phi):
    # theta = (1, 0) - 1 * 0.5 * 1 * (10, -10) / (1 + 200) = (0.975124, 0.024876).
    blk = mrac(gamma=0.5, initial_mv=10.0)
    r0 = blk.step(10.0, 10.0)
    assert r0.theta == pytest.approx([1.0, 0.0])
    assert not r0.adapted
    r = blk.step(10.0, 11.0)
    assert r.adapted
    assert r.model_error == pytest.approx(1.0)
    assert r.phi == pytest.approx([10.0, -10.0])
    assert r.theta == pytest.approx([1.0 - 5.0 / 201.0, 5.0 / 201.0])
    assert r.mv == pytest.approx(r.theta[0] * 10.0 - r.theta[1] * 11.0)


def half_period_offsets(ys: list[float], sps: list[float]) -> np.ndarray:
    """|PV - SP| at the last scan of each 250 s half-period (cm)."""
    return np.array([abs(ys[k] - sps[k]) for k in range(249, len(ys), 250)])


def test_mit_closed_loop_reduces_model_error_and_tracks() -> None:
    # Measured mean |e| per 500 s period: 0.612 (period 2) falling every period to 0.296 cm
    # (period 20) with gamma = 1, against a constant 0.806 cm without adaptation (gamma = 0).
    # The MIT law has no integral: its offset at the end of each half-period shrinks as theta
    # adapts (0.213 cm after the first step up, 0.003 cm after the last).
    errs, ys, sps = run_square_wave(mrac(), n=10000)
    per = errs.reshape(-1, 500).mean(axis=1)
    frozen = run_square_wave(mrac(gamma=0.0), n=1000)[0].reshape(-1, 500).mean(axis=1)
    assert np.all(np.diff(per[1:]) < 0.0)  # decreases period after period
    assert per[-1] < 0.5 * per[1]
    assert per[-1] < 0.5 * frozen[-1]
    offsets = half_period_offsets(ys, sps)
    assert offsets[-4:].max() < 0.05 * offsets[:4].max()
    assert offsets[-2:].max() < 0.01


def test_adaptive_pi_closed_loop_reduces_model_error_and_tracks() -> None:
    # Measured mean |e| per period: 0.611 (period 2) -> 0.210 cm (period 20); 1.305 without
    # adaptation. The integral removes the offset once the gains have settled.
    errs, ys, sps = run_square_wave(mrac("pi"), n=10000)
    per = errs.reshape(-1, 500).mean(axis=1)
    frozen = run_square_wave(mrac("pi", gamma=0.0), n=1000)[0].reshape(-1, 500).mean(axis=1)
    assert per[-1] < 0.5 * per[1]
    assert per[-1] < 0.25 * frozen[-1]
    assert half_period_offsets(ys, sps)[-2:].max() < 0.01


@pytest.mark.parametrize(
    ("law", "lo", "hi", "theta0"),
    [("mit", (1.5, 0.0), (2.0, 0.3), (1.7, 0.0)), ("pi", (0.5, 0.0), (3.0, 0.1), (1.0, 0.02))],
)
def test_parameters_stay_inside_projection_bounds(
    law: str, lo: tuple[float, float], hi: tuple[float, float], theta0: tuple[float, float]
) -> None:
    # Tight bounds and a large gain (gamma = 50): the projection binds on both bounds of both
    # parameters, and theta never leaves the box.
    blk = mrac(law, gamma=50.0, theta_min=lo, theta_max=hi, theta0=theta0)
    a = math.exp(-1.0 / TAU)
    y = Y0
    thetas = []
    for k in range(1500):
        r = blk.step(17.6 if (k // 250) % 2 else 12.6, y)
        thetas.append(r.theta)
        y = a * y + (1.0 - a) * K * r.mv
    th = np.array(thetas)
    assert np.all(th >= np.array(lo)) and np.all(th <= np.array(hi))
    assert np.all((th == np.array(lo)).any(axis=0)) and np.all((th == np.array(hi)).any(axis=0))


@pytest.mark.parametrize("law", ["mit", "pi"])
def test_bumpless_manual_to_auto(law: str) -> None:
    blk = mrac(law, initial_mode=LoopMode.MANUAL)
    blk.set_manual_mv(25.0)
    a = math.exp(-1.0 / TAU)
    y = Y0
    for _ in range(100):
        r = blk.step(15.0, y)
        y = a * y + (1.0 - a) * K * r.mv
    assert r.mv == 25.0
    blk.set_mode(LoopMode.AUTO)
    r = blk.step(15.0, y)
    assert r.y_m == pytest.approx(y)  # the model starts at the PV
    assert r.model_error == pytest.approx(0.0)
    if law == "pi":
        # Integral initialised so the law reproduces the MV; the first move is ki Ts (u_c - y).
        assert r.mv - 25.0 == pytest.approx(0.02 * 1.0 * (15.0 - y))
    else:
        assert r.mv == pytest.approx(25.0)  # theta1 set so that theta1 u_c - theta2 y = MV
    assert abs(r.mv - 25.0) < 0.01 * 1000.0


def test_auto_to_manual_tracks_and_no_set_gains() -> None:
    blk = mrac()
    r = blk.step(15.0, Y0)
    blk.set_mode(LoopMode.MANUAL)
    assert blk.step(15.0, Y0).mv == r.mv
    assert not hasattr(blk, "set_gains")
    with pytest.raises(ValueError, match="MANUAL or AUTO"):
        blk.set_mode(LoopMode.REMOTE)


def test_output_clamped_and_adaptation_frozen_while_saturated() -> None:
    blk = mrac(u_max=30.0)
    blk.step(12.6, Y0)
    r = blk.step(25.0, Y0)
    assert r.mv == 30.0 and r.saturated
    r2 = blk.step(25.0, Y0 + 0.1)
    assert not r2.adapted  # the previous output was clamped
    assert np.array_equal(r2.theta, r.theta)


@pytest.mark.parametrize(
    ("kw", "exc"),
    [
        ({"law": "lqr"}, ValueError),
        ({"alpha": 0.0}, ValueError),
        ({"gamma": -1.0}, ValueError),
        ({"theta0": (100.0, 0.0)}, ValueError),
        ({"theta_min": (0.0, float("nan"))}, ValueError),
        ({"theta0": 1.0}, TypeError),
        ({"u_min": 10.0, "u_max": 5.0}, ValueError),
        ({"initial_mode": LoopMode.REMOTE}, ValueError),
        ({"wn": 0.0}, ValueError),
    ],
)
def test_config_validation(kw: dict[str, Any], exc: type[Exception]) -> None:
    with pytest.raises(exc):
        mrac(**kw)
