"""Testing a control idea with tanklab's pytest plugin (docs/your-controller.md).

Run it wherever tanklab is installed, with a site config of your own or a shipped one:

    pytest examples/pytest --tanklab-config configs/single_tank_short_sim.yaml

The fixtures come from the plugin (entry point ``pytest11``); nothing here imports test support.
The first two tests run the co-simulation in this process; the last one runs the real plant and
PLC processes in lock-step on free loopback ports and talks to the PLC over OPC UA as an operator.
"""

from __future__ import annotations

import pytest


def test_the_loop_fills_the_tank_to_its_setpoint(tanklab_cosim):
    trace = tanklab_cosim.run(20.0)  # model seconds, on the co-simulation's virtual clock
    level_m = trace.array("levels_m")[:, 0]
    setpoint_m = trace.array("setpoints_m")[:, 0]
    assert abs(level_m[-1] - setpoint_m[-1]) < 2e-3  # within 2 mm after 20 s
    assert level_m.max() < setpoint_m[-1] * 1.10  # less than 10 % overshoot


@pytest.mark.tanklab_site(overrides={"plc.loops.0.setpoint_m": 0.1})
def test_a_higher_setpoint_is_reached_too(tanklab_site, tanklab_cosim):
    assert tanklab_site.plc.loops[0].setpoint_m == 0.1
    level_m = tanklab_cosim.run(30.0).array("levels_m")[:, 0]
    assert abs(level_m[-1] - 0.1) < 2e-3


@pytest.mark.tanklab_stack(clock="lockstep", role="operator")
def test_the_real_plc_brings_the_level_to_a_new_setpoint(tanklab_stack):
    plc = tanklab_stack.plc  # an encrypted OPC UA session on the PLC, logged in as an operator
    tanklab_stack.advance(20.0)  # model seconds: the loop settles at the config's setpoint first
    before_m = plc.read("PLC.LIC1.PV")
    plc.write("PLC.LIC1.SP", 0.1)
    tanklab_stack.advance(30.0)
    after_m = plc.read("PLC.LIC1.PV")
    assert abs(after_m - 0.1) < abs(before_m - 0.1)  # the level moved toward the new setpoint
    assert abs(after_m - 0.1) < 2e-3  # and reached it within 2 mm in 30 model seconds
