"""The PLC's alarm summary nodes through real plant and PLC processes (issue 15).

At the operating point every count and rate is 0. A leak in T1 with both loops in MANUAL at 0
drains T1 below its low switch: the T1Level condition's event arrives, and ``PLC.AlarmSummary.*``
then agree with a recount of every condition's state nodes read in the same Read (T1Level
active and unacknowledged among them, the peak rate at least that one activation). After
Acknowledge the recount agrees again with T1Level acknowledged; a one-shot shelve makes Shelved
exactly 1 and an engineer's Disable of LIC2PvBad Disabled exactly 1 (nothing else shelves or
disables); 600 s of model time after the last activation RatePer10Min is 0 again, its peak kept.
Waits are on events and node values (``wait_until``), never on elapsed time.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from helpers import ROOT, secure, wait_until
from tanklab import paths
from tanklab.alarms import names
from tanklab.alarms.definitions import plc_alarms
from tanklab.config import load_site
from tanklab.tags import ALARM_SUMMARY_ITEMS, NAMESPACE_URI
from tanklab_testing.condition_events import Events, event_filter
from tanklab_testing.procs import free_base_port
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
T1 = names.level("T1")
CONDITIONS = [d.name for d in plc_alarms(SITE)]
STATES = (
    "EnabledState.Id",
    "ActiveState.Id",
    "AckedState.Id",
    "SuppressedState.Id",
    "ShelvingState.CurrentState",
)
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
ONE_SHOT = ua.NodeId(ua.ObjectIds.AlarmConditionType_ShelvingState_OneShotShelve)
DISABLE = ua.NodeId(ua.ObjectIds.ConditionType_Disable)


@pytest.fixture
async def stack(tmp_path: Path) -> AsyncIterator[Stack]:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True, pumps_hold_on_watchdog=True)
    s = Stack(config, free_base_port(3), speed=20.0, state_file=tmp_path / "plant.json")
    try:
        await s.start("plant")
        await s.start("plc")
        yield s
    finally:
        await s.down()


class Reader:
    """Reads the summary nodes and every condition's state nodes in one Read."""

    def __init__(self, client: Client, idx: int) -> None:
        self.client = client
        self.summary = [ua.NodeId(p, idx) for p in paths.alarm_summary_paths("plc").values()]
        self.states = [
            ua.NodeId(f"{paths.condition('plc', name)}.{field}", idx)
            for name in CONDITIONS
            for field in STATES
        ]

    async def read(self) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        nodes = [self.client.get_node(n) for n in (*self.summary, *self.states)]
        values = await self.client.read_values(nodes)
        summary = dict(zip(ALARM_SUMMARY_ITEMS, values[: len(self.summary)], strict=True))
        rest = values[len(self.summary) :]
        conditions = {
            name: dict(zip(STATES, rest[k * len(STATES) : (k + 1) * len(STATES)], strict=True))
            for k, name in enumerate(CONDITIONS)
        }
        return summary, conditions


def recount(conditions: dict[str, dict[str, Any]]) -> dict[str, int]:
    """The counts of docs/alarms.md from the conditions' own state nodes."""
    on = [c for c in conditions.values() if c["EnabledState.Id"]]
    return {
        "Active": sum(bool(c["ActiveState.Id"]) for c in on),
        "Unacknowledged": sum(not c["AckedState.Id"] for c in on),
        "Shelved": sum(c["ShelvingState.CurrentState"].Text != "Unshelved" for c in on),
        "Suppressed": sum(bool(c["SuppressedState.Id"]) for c in on),
        "Disabled": len(conditions) - len(on),
    }


def agrees(summary: dict[str, Any], conditions: dict[str, dict[str, Any]]) -> bool:
    return all(summary[k] == v for k, v in recount(conditions).items())


async def call(client: Client, obj: ua.NodeId, method: ua.NodeId, *args: ua.Variant) -> str:
    req = ua.CallMethodRequest(ObjectId=obj, MethodId=method, InputArguments=list(args))
    (result,) = await client.uaclient.call([req])
    return str(result.StatusCode.name)


async def test_the_summary_follows_a_leak_an_acknowledge_a_shelve_and_a_disable(stack: Stack) -> None:
    async with await secure(stack.plc_url, "operator") as op:
        idx = await op.get_namespace_index(NAMESPACE_URI)
        reader = Reader(op, idx)
        summary, conditions = await reader.read()
        assert summary == dict.fromkeys(ALARM_SUMMARY_ITEMS, 0) | {"Flood": False}
        assert agrees(summary, conditions)
        for item in ALARM_SUMMARY_ITEMS:  # the contract's types on the wire
            dv = await op.get_node(ua.NodeId(paths.alarm_summary_paths("plc")[item], idx)).read_data_value()
            assert dv.Value.VariantType == (
                ua.VariantType.Boolean if item == "Flood" else ua.VariantType.UInt32
            )

        cid = ua.NodeId(paths.condition("plc", T1), idx)
        events = Events()
        sub = await op.create_subscription(100, events)
        fields = ("EventId", "ActiveState/Id", "AckedState/Id")
        await sub.subscribe_events(
            ua.ObjectIds.Server, ua.ObjectIds.BaseEventType, evfilter=event_filter(fields)
        )
        async with await secure(stack.plant_url) as eng_plant, await secure(stack.plc_url) as eng_plc:
            for loop in ("LIC1", "LIC2"):
                lp = paths.plc.loop(loop)
                await eng_plc.get_node(ua.NodeId(lp.mode, idx)).write_value(
                    ua.Variant(0, ua.VariantType.Int32)
                )
                await eng_plc.get_node(ua.NodeId(lp.manual_mv, idx)).write_value(
                    ua.Variant(0.0, ua.VariantType.Double)
                )
            pidx = await eng_plant.get_namespace_index(NAMESPACE_URI)
            leak = ua.NodeId(paths.plant.tank("T1").leak, pidx)
            await eng_plant.get_node(leak).write_value(ua.Variant(1.0, ua.VariantType.Double))

        def active() -> list[dict[str, Any]]:
            return [e for e in events.of(cid) if e["ActiveState/Id"] is True]

        await wait_until(lambda: bool(active()), 120, what="the T1Level activation event")
        seen: dict[str, Any] = {}

        async def consistent(t1_acked: bool) -> bool:
            s, c = await reader.read()
            seen.update(summary=s, conditions=c)
            t1 = c[T1]
            return agrees(s, c) and t1["ActiveState.Id"] is True and t1["AckedState.Id"] is t1_acked

        await wait_until(lambda: consistent(False), 20, what="the summary counting T1Level unacknowledged")
        s = seen["summary"]
        assert s["Active"] >= 1 and s["Unacknowledged"] >= 1
        assert s["PeakRatePer10Min"] >= 1 and s["RatePer10Min"] <= s["PeakRatePer10Min"]
        assert s["Shelved"] == 0 and s["Disabled"] == 0 and s["Suppressed"] == 0

        event_id = active()[-1]["EventId"]
        comment = ua.Variant(ua.LocalizedText("leak seen"), ua.VariantType.LocalizedText)
        assert await call(op, cid, ACK, ua.Variant(event_id, ua.VariantType.ByteString), comment) == "Good"
        await wait_until(lambda: consistent(True), 20, what="the summary after the acknowledge")

        shelving = ua.NodeId(f"{paths.condition('plc', T1)}.ShelvingState", idx)
        assert await call(op, shelving, ONE_SHOT) == "Good"
        await wait_until(lambda: consistent(True), 20, what="the summary after the shelve")
        assert seen["summary"]["Shelved"] == 1

    async with await secure(stack.plc_url) as eng:  # Engineer: Enable / Disable
        pv_bad = ua.NodeId(paths.condition("plc", names.pv_bad("LIC2")), idx)
        assert await call(eng, pv_bad, DISABLE) == "Good"
        reader = Reader(eng, idx)
        await wait_until(lambda: consistent(True), 20, what="the summary after the disable")
        assert seen["summary"]["Disabled"] == 1 and seen["summary"]["Shelved"] == 1

        # 600 s of model time (30 s of wall time at speed 20) after the last activation the rate
        # is back to 0, with no condition event to trigger it (rate_expiring), the peak kept.
        async def rate_expired() -> bool:
            s, _ = await reader.read()
            seen["summary"] = s
            return bool(s["RatePer10Min"] == 0)

        await wait_until(rate_expired, 90, what="the rate window to pass on model time")
        assert seen["summary"]["PeakRatePer10Min"] >= 1 and seen["summary"]["Flood"] is False
