"""The fast path's kernel equals the reference right-hand side bit for bit.

Guards :mod:`plant_sim.kernel` (``bind``: ``rhs`` and ``rhs_at``, traced from
``HeldRhs.derivative``) against the reference ``HeldRhs`` itself, and the RK4 step on the kernel
against the same step on the reference (``plant_sim.integrate.reference_rhs``), for every shipped
site config (with and without a lagged pump), over random states and inputs that include the
non-smooth regions: levels in the laminar band around empty, negative levels and -0.0, levels at
and above Hmax (spilling), equal levels across a valve, closed valves and leaks, commands beyond
the pumps' ranges, inflow and outflow disturbances. Equality is of the bits (``-0.0 != 0.0``
here), not of the values.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.integrate import reference_rhs, rk4_step
from plant_sim.kernel import bind, kernel_for
from plant_sim.models import HeldRhs, PlantInputs, TankNetwork
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


IDS = [f"{name}-{'lag' if lag else 'nolag'}" for name, lag in NETS]


@pytest.mark.parametrize("key", list(NETS), ids=IDS)
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_kernel_equals_the_reference_bit_for_bit(key: tuple[str, bool], data: st.DataObject) -> None:
    net = NETS[key]
    u, x, k, c = data.draw(_case(net))
    f = HeldRhs(net, u)
    bound = bind(f, rk4_step)
    rhs, rhs_at = bound.rhs, bound.rhs_at
    assert _bits(rhs(x)) == _bits(f(x))
    assert _bits(rhs(x)) == _bits(net.rhs(0.0, np.array(x), u).tolist())
    # a stage point, formed inside rhs_at as the integrator forms it as a list
    m = net.n_tanks + net.n_pumps
    stage = [a + c * b for a, b in zip(x[:m], k, strict=False)]
    assert _bits(rhs_at(x, k, c)) == _bits(f(stage))


@pytest.mark.parametrize("key", list(NETS), ids=IDS)
@settings(max_examples=60, deadline=None)
@given(data=st.data(), h=st.sampled_from([0.05, 0.5, 0.716, 1.0]) | st.floats(1e-3, 2.5))
def test_traced_rk4_step_equals_it_on_the_reference(
    key: tuple[str, bool], data: st.DataObject, h: float
) -> None:
    net = NETS[key]
    u, x, _k, _c = data.draw(_case(net))
    f = HeldRhs(net, u)
    bound = bind(f, rk4_step)
    y_ref, spilled_ref = rk4_step(*reference_rhs(f), x, h)
    for y_new, spilled in (bound.step(x, h), rk4_step(bound.rhs, bound.rhs_at, x, h)):
        assert _bits(y_new) == _bits(y_ref)
        assert _bits([spilled]) == _bits([spilled_ref])


def test_kernel_is_straight_line_traced_code_and_cached() -> None:
    net = TankNetwork.from_config(load_site(CONFIGS[0]).plant)
    u = PlantInputs(
        np.full(net.n_pumps, 1e-5), np.ones(net.n_valves), np.zeros(net.n_tanks), np.zeros(net.n_tanks)
    )
    a, b = kernel_for(HeldRhs(net, u), rk4_step), kernel_for(HeldRhs(net, u), rk4_step)
    assert a is b  # compiled once per layout, not per step
    src = a.source
    assert "HeldRhs.derivative" in src and "def rhs(x):" in src and "def rhs_at(y, k, c):" in src
    assert "def step(y, h):" in src
    body = src.split('"""')[-1]
    assert "for " not in body and "while " not in body  # straight-line: the loops ran while tracing
    assert "math_sqrt(" in body  # the laws, inlined from plant_sim.models
    # closing a valve changes the layout: new code, the old kept in the network's cache
    shut = PlantInputs(u.pump_commands, np.zeros(net.n_valves), u.leak_openings, u.disturbances_m3_s)
    assert kernel_for(HeldRhs(net, shut), rk4_step) is not a
    assert kernel_for(HeldRhs(net, u), rk4_step) is a


def test_kernel_refuses_pump_flows_given_directly() -> None:
    """``level_rhs``' form (every pump held at a given flow) is the reference's alone."""
    net = TankNetwork.from_config(load_site(CONFIGS[0]).plant)
    n = net.n_tanks
    u = PlantInputs(np.zeros(net.n_pumps), np.ones(net.n_valves), np.zeros(n), np.zeros(n))
    with pytest.raises(ValueError, match="pump_flows_m3_s"):
        bind(HeldRhs(net, u, pump_flows_m3_s=[1e-5] * net.n_pumps), rk4_step)
