"""When a tier republishes its alarm summary (:class:`SummaryPublisher`): on demand, and on model
time exactly when an annunciated activation leaves the 600 s rate window, never otherwise."""

from __future__ import annotations

from typing import Any

from tanklab.alarms.manager import AlarmInput, AlarmManager
from tanklab.alarms.model import AlarmDefinition, ConditionKind, Priority
from tanklab_io.conditions.summary import SummaryPublisher

PVBAD = AlarmDefinition(
    name="LIC1PvBad", kind=ConditionKind.DISCRETE, source="src", message="LIC1 PV bad", priority=Priority.HIGH
)


async def test_expire_publishes_at_the_exact_instant_an_activation_leaves_the_window() -> None:
    m = AlarmManager((PVBAD,))
    now = [0.0]
    published: list[dict[str, Any]] = []

    async def publish(values: dict[str, Any]) -> None:
        published.append(values)

    s = SummaryPublisher("plc", m, publish, lambda: now[0])
    rate = "PLC.AlarmSummary.RatePer10Min"
    assert not await s.expire() and published == []  # nothing counted: nothing to expire
    m.scan({"LIC1PvBad": AlarmInput(True)}, 5.0)
    m.scan({"LIC1PvBad": AlarmInput(False)}, 6.0)
    m.scan({"LIC1PvBad": AlarmInput(True)}, 7.0)
    now[0] = 7.0
    await s.publish()
    assert published[-1][rate] == 2 and published[-1]["PLC.AlarmSummary.Active"] == 1
    for t in (8.0, 300.0, 604.999):
        now[0] = t
        assert not await s.expire()
    assert len(published) == 1
    now[0] = 605.0  # 5 s + 600 s: the first activation is out
    assert await s.expire()
    assert published[-1][rate] == 1 and published[-1]["PLC.AlarmSummary.PeakRatePer10Min"] == 2
    assert not await s.expire()  # once
    now[0] = 700.0  # past 607 s: the second is out too
    assert await s.expire() and published[-1][rate] == 0
    assert s.last is not None and s.last.rate_per_10min == 0 and s.publications == 3
    now[0] = 5000.0
    assert not await s.expire() and len(published) == 3
