"""The float fast paths of the plant equal the array forms they replaced, bit for bit.

Guards: ``TransmitterBank.read`` (floats) against the former numpy form, kept here as the oracle;
``PlantSimulator.set_commands``' fast path against its array checks (accepts and refuses alike);
``PlantSimulator.pump_flows`` against ``TankNetwork.actual_pump_flows``; and the memo of
``HeldRhs``' held part (openings and disturbances) against a fresh build, also when an input
array is changed in place.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.models import HeldRhs, PlantInputs, TankNetwork
from plant_sim.plant import PlantSimulator
from plant_sim.sensors import TransmitterBank
from tanklab.config import load_site
from tanklab.enums import SensorFault

ROOT = Path(__file__).resolve().parents[2]
SIM = load_site(ROOT / "configs/three_tank_energies_sim.yaml").plant
RIG = load_site(ROOT / "configs/three_tank_energies_rig.yaml").plant

floats = st.floats(-0.2, 1.2, allow_nan=False)


def _array_read(bank: TransmitterBank, z: np.ndarray, levels_m: np.ndarray, t_s: float) -> np.ndarray:
    """The former numpy form of TransmitterBank.read, given the noise draw ``z``."""
    y = levels_m + bank.noise_std_m * z
    for i, f in enumerate(bank.fault):
        if f == SensorFault.BIAS:
            y[i] += bank.fault_value[i]
        elif f == SensorFault.DRIFT:
            y[i] += bank.fault_value[i] * (t_s - bank.fault_since_s[i])
    q = bank.quantization_m
    y = np.where(q > 0, np.round(y / np.where(q > 0, q, 1.0)) * q, y)
    y = np.clip(y, bank.range_min_m, bank.range_max_m)
    for i, f in enumerate(bank.fault):
        if f == SensorFault.STUCK:
            y[i] = bank.last[i]
    return y


@settings(max_examples=300, deadline=None)
@given(
    levels=st.lists(floats, min_size=3, max_size=3),
    std=st.lists(st.sampled_from([0.0, 1e-4, 3e-3]), min_size=3, max_size=3),
    quant=st.lists(st.sampled_from([0.0, 1e-4, 1e-3, 0.0123]), min_size=3, max_size=3),
    faults=st.lists(st.sampled_from(list(SensorFault)), min_size=3, max_size=3),
    value=st.floats(-0.05, 0.05),
    since=st.floats(0.0, 100.0),
    t_s=st.floats(0.0, 1000.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_transmitter_read_equals_array_form(
    levels: list[float],
    std: list[float],
    quant: list[float],
    faults: list[SensorFault],
    value: float,
    since: float,
    t_s: float,
    seed: int,
) -> None:
    bank = TransmitterBank.from_config(SIM)
    bank.noise_std_m = np.array(std)
    bank.quantization_m = np.array(quant)
    bank.rng = np.random.default_rng(seed)
    bank.last = np.array([0.11, 0.22, 0.33])
    for i, f in enumerate(faults):
        bank.set_fault(i, f, value, since)
    z = np.random.default_rng(seed).standard_normal(3)
    expected = _array_read(bank, z, np.array(levels), t_s)
    got = bank.read(np.array(levels), t_s)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(bank.last, expected)
    # the generator advanced by exactly one draw of n normals
    np.testing.assert_array_equal(
        bank.rng.standard_normal(3), np.random.default_rng(seed).standard_normal(6)[3:]
    )


@settings(max_examples=200, deadline=None)
@given(
    levels=st.lists(st.one_of(floats, st.sampled_from([np.nan, np.inf, -np.inf])), min_size=3, max_size=3),
    std=st.lists(st.sampled_from([0.0, 1e-4, 3e-3]), min_size=3, max_size=3),
    quant=st.lists(st.sampled_from([0.0, 1e-4, 1e-3, 0.0123]), min_size=3, max_size=3),
    seed=st.integers(0, 2**32 - 1),
)
def test_transmitter_read_without_faults_equals_array_form(
    levels: list[float], std: list[float], quant: list[float], seed: int
) -> None:
    """The no-fault path (no fault on any transmitter, the usual scan) against the array form,
    non-finite levels included; the readings handed out are not the bank's own ``last``."""
    bank = TransmitterBank.from_config(SIM)
    bank.noise_std_m = np.array(std)
    bank.quantization_m = np.array(quant)
    bank.rng = np.random.default_rng(seed)
    z = np.random.default_rng(seed).standard_normal(3)
    with np.errstate(invalid="ignore"):  # the oracle's np.round(inf / q) * q on an infinite level
        expected = _array_read(bank, z, np.array(levels), 5.0)
    got = bank.read(np.array(levels), 5.0)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(bank.last, expected)
    got[0] = -1.0
    assert bank.last[0] != -1.0


cmd_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e-4, 2e-4), st.floats(-100.0, 3000.0)
)


@pytest.mark.parametrize("plant", [SIM, RIG], ids=["sim", "rig"])
@settings(max_examples=200, deadline=None)
@given(cmd=st.lists(cmd_values, min_size=2, max_size=2))
def test_set_commands_fast_path_accepts_and_refuses_as_the_array_checks(
    plant: object, cmd: list[float]
) -> None:
    fast = PlantSimulator(plant)  # type: ignore[arg-type]
    slow = PlantSimulator(plant)  # type: ignore[arg-type]
    c = np.array(cmd)
    lo, hi = slow.net.pump_cmd_min, slow.net.pump_cmd_max
    valid = bool(np.all(np.isfinite(c)) and np.all(c >= lo) and np.all(c <= hi))
    if valid:
        fast.set_commands(c)
        slow.set_commands(cmd)  # a list: the array path
        np.testing.assert_array_equal(fast.inputs.pump_commands, slow.inputs.pump_commands)
        np.testing.assert_array_equal(fast.commands, c)
        assert fast.inputs.pump_commands is not c
        np.testing.assert_array_equal(fast.pump_flows, fast.net.actual_pump_flows(fast.x, fast.inputs))
    else:
        before = fast.inputs
        with pytest.raises(ValueError):
            fast.set_commands(c)
        assert fast.inputs is before


@pytest.mark.parametrize("plant", [SIM, RIG], ids=["sim", "rig"])
@settings(max_examples=100, deadline=None)
@given(
    cmd=st.lists(st.floats(-1e-3, 1e4), min_size=2, max_size=2),
    q=st.lists(st.floats(0, 2e-4), min_size=2, max_size=2),
)
def test_pump_flows_equal_array_form(plant: object, cmd: list[float], q: list[float]) -> None:
    sim = PlantSimulator(plant)  # type: ignore[arg-type]
    n = sim.net.n_tanks
    sim.x[n : n + 2] = q
    sim.inputs = PlantInputs(
        np.array(cmd), sim.inputs.valve_openings, sim.inputs.leak_openings, sim.inputs.disturbances_m3_s
    )
    np.testing.assert_array_equal(sim.pump_flows, sim.net.actual_pump_flows(sim.x, sim.inputs))


def _rhs_fields(f: HeldRhs) -> tuple[object, ...]:
    return (f.inflow, f.v_in0, f.lagged, f.outflows, f.drains, f.links, f.leaks)


@settings(max_examples=100, deadline=None)
@given(
    openings=st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4),
    leaks=st.lists(st.sampled_from([0.0, 0.3, 1.0]), min_size=3, max_size=3),
    dist=st.lists(st.sampled_from([0.0, -1e-5, 2e-5]), min_size=3, max_size=3),
    x=st.lists(st.floats(0.0, 0.6), min_size=3, max_size=3),
)
def test_held_rhs_memo_equals_fresh_build(
    openings: list[float], leaks: list[float], dist: list[float], x: list[float]
) -> None:
    net = TankNetwork.from_config(SIM)
    fresh_net = TankNetwork.from_config(SIM)  # its own, empty memo
    op = np.array(openings[: net.n_valves])
    u = PlantInputs(np.array([3e-5, 3e-5]), op, np.array(leaks), np.array(dist))
    HeldRhs(
        net, PlantInputs(u.pump_commands, op * 0.5, u.leak_openings, u.disturbances_m3_s)
    )  # memo: other values
    a = HeldRhs(net, u)
    b = HeldRhs(fresh_net, u)
    assert _rhs_fields(a) == _rhs_fields(b)
    state = [*x, 3e-5, 3e-5, 0.0, 0.0, 0.0, 0.0]
    assert a(state) == b(state)
    # an array changed in place is noticed (the memo compares values, not objects)
    u.valve_openings[0] = 0.5 * u.valve_openings[0] + 0.25
    assert _rhs_fields(HeldRhs(net, u)) == _rhs_fields(HeldRhs(TankNetwork.from_config(SIM), u))
    assert HeldRhs(net, u).part is HeldRhs(net, u).part  # reused while equal
