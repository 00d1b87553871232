"""Pump degradation (plant fault): a pump delivers the fraction f of its command's flow."""

from __future__ import annotations

import numpy as np
import pytest

from plant_sim.plant import PlantSimulator
from tanklab_testing.sites import SITE


def test_degraded_pump_delivers_its_fraction() -> None:
    sim = PlantSimulator(SITE.plant)
    sim.set_commands(np.array([1.0e-4, 0.5e-4]))
    sim.set_pump_fraction("P1", 0.8)
    # flow-commanded pumps (slope 1, no offset): 0.8 * 1e-4 by hand
    assert sim.pump_flows == pytest.approx([0.8e-4, 0.5e-4], rel=1e-12)
    assert sim.commands == pytest.approx([1.0e-4, 0.5e-4])  # the command stays as written
    sim.set_commands(np.array([0.5e-4, 0.5e-4]))
    assert sim.pump_flows[0] == pytest.approx(0.4e-4, rel=1e-12)  # and applies to new commands


def test_degradation_is_checkpointed_and_validated() -> None:
    sim = PlantSimulator(SITE.plant)
    sim.set_pump_fraction("P2", 0.5)
    snap = sim.snapshot()
    other = PlantSimulator(SITE.plant)
    other.restore(snap)
    assert other.pump_fractions.tolist() == [1.0, 0.5]
    with pytest.raises(ValueError, match=r"P1 delivered fraction 1\.5 outside"):
        sim.set_pump_fraction("P1", 1.5)
    with pytest.raises(KeyError, match=r"P9"):
        sim.set_pump_fraction("P9", 0.5)
    bad = dict(snap, pump_fractions=[2.0, 1.0])
    with pytest.raises(ValueError, match="pump_fractions"):
        other.restore(bad)
    assert other.pump_fractions.tolist() == [1.0, 0.5]  # left as it was
