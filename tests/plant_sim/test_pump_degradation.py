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


def test_delivered_node_sets_and_publishes_the_fraction() -> None:
    """``Plant.P1.Delivered``: a write goes to the simulator (out of range refused, value kept)
    and the writable values publish it."""
    from typing import Any, cast

    from plant_sim.server import PlantServer
    from tanklab import paths
    from tanklab.tags import plant_tags, tags_by_path

    sim = PlantSimulator(SITE.plant)
    server = PlantServer(SITE, sim, "127.0.0.1", 0, cast(Any, None))
    path = paths.plant.pump("P1").delivered
    tag = tags_by_path(plant_tags(SITE))[path]
    handler = server.write_handlers()[path]
    assert handler(tag, 0.7) is None
    assert sim.pump_fractions[0] == 0.7
    refused = handler(tag, 1.2)
    assert refused is not None and refused.name == "BadOutOfRange"
    assert sim.pump_fractions[0] == 0.7
    assert server.writable_values()[path] == 0.7
