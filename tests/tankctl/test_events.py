"""The one table of scenario event kinds (``tankctl.events``) and its in-process target.

``tankctl simulate``, the randomized scenarios and ``tankctl scenario run`` all apply events
through :func:`tankctl.events.apply_event`; here a recording target checks the table (verb,
arguments, converted enums) and the co-simulation's target checks what the verbs do to the
plant and the PLC (the OPC UA target runs against a real stack in test_ops.py).
"""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import TypeAdapter

from helpers import ROOT
from tankctl.cosim import CoSimEvents, CoSimulation
from tankctl.events import apply_event
from tanklab.config import load_site
from tanklab.enums import LoopMode, SensorFault, SupervisorMode
from tanklab.scenario import Event

CONFIG = ROOT / "configs/three_tank_energies_sim.yaml"
EVENT = TypeAdapter(Event)


class Recorder:
    """An EventTarget that records each verb and its arguments and returns the verb's name."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, tuple[Any, ...]]] = []

    def _record(self, verb: str, *args: Any) -> str:
        self.calls.append((verb, args))
        return verb

    def setpoint(self, loop: str, value_m: float) -> str:
        return self._record("setpoint", loop, value_m)

    def leak(self, tank: str, opening: float) -> str:
        return self._record("leak", tank, opening)

    def valve(self, valve: str, opening: float) -> str:
        return self._record("valve", valve, opening)

    def disturbance(self, tank: str, flow_m3_s: float) -> str:
        return self._record("disturbance", tank, flow_m3_s)

    def fault(self, transmitter: str, fault: SensorFault, value: float) -> str:
        return self._record("fault", transmitter, fault, value)

    def loop_mode(self, loop: str, mode: LoopMode, mv_percent: float | None) -> str:
        return self._record("loop_mode", loop, mode, mv_percent)

    def supervisor_mode(self, mode: SupervisorMode) -> str:
        return self._record("supervisor_mode", mode)


@pytest.mark.parametrize(
    ("event", "verb", "args"),
    [
        ({"kind": "setpoint", "loop": "LIC2", "value_m": 0.45}, "setpoint", ("LIC2", 0.45)),
        ({"kind": "leak", "tank": "T1", "opening": 0.3}, "leak", ("T1", 0.3)),
        ({"kind": "valve", "valve": "V13", "opening": 0.5}, "valve", ("V13", 0.5)),
        ({"kind": "disturbance", "tank": "T3", "flow_m3_s": -2e-5}, "disturbance", ("T3", -2e-5)),
        (
            {"kind": "fault", "transmitter": "LT2", "fault": "BIAS", "value": 0.01},
            "fault",
            ("LT2", SensorFault.BIAS, 0.01),
        ),
        (
            {"kind": "loop_mode", "loop": "LIC1", "mode": "MANUAL", "mv_percent": 40},
            "loop_mode",
            ("LIC1", LoopMode.MANUAL, 40.0),
        ),
        ({"kind": "loop_mode", "loop": "LIC1", "mode": "AUTO"}, "loop_mode", ("LIC1", LoopMode.AUTO, None)),
        (
            {"kind": "supervisor_mode", "mode": "ADAPTIVE_PID"},
            "supervisor_mode",
            (SupervisorMode.ADAPTIVE_PID,),
        ),
    ],
)
def test_each_event_kind_is_one_verb_with_its_arguments(
    event: dict[str, Any], verb: str, args: tuple[Any, ...]
) -> None:
    target = Recorder()
    assert apply_event(target, EVENT.validate_python({"at_s": 5.0, **event})) == verb
    assert target.calls == [(verb, args)]
    assert all(type(a) is type(b) for a, b in zip(target.calls[0][1], args, strict=True))


def test_the_cosimulation_target_writes_the_plant_and_the_plc() -> None:
    site = load_site(CONFIG)
    cs = CoSimulation(site)
    target = CoSimEvents(cs)
    for event in (
        {"kind": "leak", "tank": "T2", "opening": 0.25},
        {"kind": "setpoint", "loop": "LIC2", "value_m": 0.42},
        {"kind": "loop_mode", "loop": "LIC1", "mode": "MANUAL", "mv_percent": 40},
    ):
        apply_event(target, EVENT.validate_python({"at_s": 0.0, **event}))
    cs.step()
    assert cs.plant.inputs.leak_openings[1] == 0.25
    assert cs.trace.setpoints_m[-1][1] == 0.42
    assert cs.trace.modes[-1][0] == int(LoopMode.MANUAL)
    p1 = site.plant.pumps[0]
    assert site.plc is not None and site.plc.loops[0].mv_min is None and site.plc.loops[0].mv_max is None
    # MANUAL at 40 % of P1's command range: the scan commands exactly that.
    assert cs.trace.commands[-1][0] == pytest.approx(p1.command_min + 0.4 * (p1.command_max - p1.command_min))


def test_a_supervisor_mode_event_without_a_supervisor_is_refused() -> None:
    cs = CoSimulation(load_site(CONFIG))
    with pytest.raises(ValueError, match="no supervisor"):
        apply_event(
            CoSimEvents(cs), EVENT.validate_python({"at_s": 0.0, "kind": "supervisor_mode", "mode": "MPC"})
        )
