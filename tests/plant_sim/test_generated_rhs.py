"""The generated right-hand side and RK4 step equal their loop forms bit for bit.

Guards :func:`plant_sim.models._generate_rhs` (``ScalarRhs.fn``, ``fn_at`` and ``code.outside``)
against ``ScalarRhs.generic`` and :func:`plant_sim.integrate.rk4_step_for` against
``_rk4_reference``, for every shipped site config (with and without a lagged pump), over random
states and inputs that include the non-smooth regions: levels in the laminar band around empty,
negative levels and -0.0, levels at and above Hmax (spilling), equal levels across a valve,
closed valves and leaks, commands beyond the pumps' ranges, inflow and outflow disturbances.
Equality is of the bits (``-0.0 != 0.0`` here), not of the values.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.integrate import _rk4_reference, rk4_step_for
from plant_sim.models import PlantInputs, ScalarRhs, TankNetwork
from tanklab.config import load_site

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


def _network(path: Path, lagged: bool) -> TankNetwork:
    plant = load_site(path).plant.model_copy(deep=True)
    if lagged and plant.pumps:
        plant.pumps[0].lag_s = 3.0
    return TankNetwork.from_config(plant)


NETS = {(p.name, lag): _network(p, lag) for p in CONFIGS for lag in (False, True)}


def _bits(v: list[float]) -> list[int]:
    return np.array(v, dtype=np.float64).view(np.int64).tolist()


def _level(hmax: float) -> st.SearchStrategy[float]:
    return st.one_of(
        st.floats(0.0, hmax),
        st.sampled_from([0.0, -0.0, 1e-4, -1e-4, 5e-5, hmax, math.nextafter(hmax, 0.0)]),
        st.floats(-3e-4, 3e-4),  # the laminar band around empty, and below it
        st.floats(hmax - 1e-3, hmax + 1e-3),  # the overflow edge
    )


@st.composite
def _case(draw: st.DrawFn, net: TankNetwork) -> tuple[PlantInputs, list[float], list[float], float]:
    n, p, k = net.n_tanks, net.n_pumps, net.n_valves
    hmax = net.hmax_m.tolist()
    h = [draw(_level(top)) for top in hmax]
    if n > 1 and draw(st.booleans()):  # a head across a valve near zero or zero
        i, j = draw(st.permutations(range(n)))[:2]
        h[j] = h[i] + draw(st.sampled_from([0.0, -0.0, 1e-4, -1e-4]) | st.floats(-3e-4, 3e-4))
    lo, hi = net.pump_cmd_min.tolist(), net.pump_cmd_max.tolist()
    cmd = [
        draw(st.floats(a - 0.2 * (b - a) - 1.0, b + 0.2 * (b - a) + 1.0)) for a, b in zip(lo, hi, strict=True)
    ]
    opening = st.sampled_from([0.0, 1.0]) | st.floats(0.0, 1.0)
    valves = [draw(opening) for _ in range(k)]
    leaks = [draw(opening) for _ in range(n)]
    dist = [draw(st.sampled_from([0.0, -0.0]) | st.floats(-1e-4, 1e-4)) for _ in range(n)]
    q = [draw(st.floats(0.0, 2e-4)) for _ in range(p)]
    x = [*h, *q, *(draw(st.floats(0.0, 1.0)) for _ in range(4))]
    slope = [draw(st.floats(-1.0, 1.0)) for _ in range(n + p + 4)]
    c = draw(st.sampled_from([0.0, 0.25, 0.5, 1.0]) | st.floats(0.0, 1.0))
    u = PlantInputs(np.array(cmd), np.array(valves), np.array(leaks), np.array(dist))
    return u, x, slope, c


@pytest.mark.parametrize("key", list(NETS), ids=[f"{name}-{'lag' if lag else 'nolag'}" for name, lag in NETS])
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_generated_rhs_equals_generic_bit_for_bit(key: tuple[str, bool], data: st.DataObject) -> None:
    net = NETS[key]
    u, x, k, c = data.draw(_case(net))
    f = ScalarRhs(net, u)
    assert _bits(f.fn(x)) == _bits(f.generic(x))
    assert _bits(f(x)) == _bits(f.generic(x))
    # a stage point, formed inside fn_at as the loop form forms it as a list
    m = net.n_tanks + net.n_pumps
    stage = [a + c * b for a, b in zip(x[:m], k, strict=False)]
    assert _bits(f.fn_at(x, k, c)) == _bits(f.generic(stage))
    n, hmax = net.n_tanks, f.hmax
    assert f.code.outside(x) == any(x[i] < 0.0 or x[i] > hmax[i] for i in range(n))


@pytest.mark.parametrize("key", list(NETS), ids=[f"{name}-{'lag' if lag else 'nolag'}" for name, lag in NETS])
@settings(max_examples=60, deadline=None)
@given(data=st.data(), h=st.sampled_from([0.05, 0.5, 0.716, 1.0]) | st.floats(1e-3, 2.5))
def test_generated_rk4_step_equals_the_loop_form(
    key: tuple[str, bool], data: st.DataObject, h: float
) -> None:
    net = NETS[key]
    u, x, _k, _c = data.draw(_case(net))
    f = ScalarRhs(net, u)
    y_new, spilled = rk4_step_for(len(x))(f.fn, f.fn_at, x, h)
    y_ref, spilled_ref = _rk4_reference(f, x, h)
    assert _bits(y_new) == _bits(y_ref)
    assert spilled == spilled_ref


def test_generated_code_is_readable_and_cached() -> None:
    net = TankNetwork.from_config(load_site(CONFIGS[0]).plant)
    u = PlantInputs(
        np.full(net.n_pumps, 1e-5), np.ones(net.n_valves), np.zeros(net.n_tanks), np.zeros(net.n_tanks)
    )
    a, b = ScalarRhs(net, u), ScalarRhs(net, u)
    assert a.code is b.code  # compiled once per layout, not per step
    src = a.code.source
    assert (
        "tests/plant_sim/test_generated_rhs.py" in src
        and "def rhs(x):" in src
        and "def rhs_at(y, k, c):" in src
    )
    assert "for " not in src.split('"""')[-1]  # straight-line: no loops
    assert "def rk4_step(rhs, rhs_at, y, h):" in rk4_step_for(9).source  # type: ignore[attr-defined]
    # closing a valve changes the layout: new code, the old kept in the network's cache
    shut = PlantInputs(u.pump_commands, np.zeros(net.n_valves), u.leak_openings, u.disturbances_m3_s)
    assert ScalarRhs(net, shut).code is not a.code
    assert ScalarRhs(net, u).code is a.code
