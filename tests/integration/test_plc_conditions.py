"""The PLC's alarms as live OPC UA conditions, through real plant and PLC processes (issue 15).

A leak in T1 with LIC1 in MANUAL at 0 (the pump off) drains T1 below its low switch: a client
subscribed to the Server object receives the T1Level condition's event (Active, limit Low, the
Low limit's Severity). Acknowledge with its EventId is Good; again BadConditionBranchAlreadyAcked;
with the superseded EventId BadEventIdUnknown; as observer BadUserAccessDenied. After a
reconnect ConditionRefresh delivers the standing condition, with its latest EventId, between
RefreshStart and RefreshEnd; after a warm restart of the PLC the restored condition is shown and
refreshed with a fresh EventId of the new process.

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
from tanklab.alarms.model import LimitState
from tanklab.config import load_site
from tanklab.tags import NAMESPACE_URI
from tanklab_testing.condition_events import Events, event_filter
from tanklab_testing.condition_events import refresh as condition_refresh
from tanklab_testing.procs import free_base_port
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
T1 = names.level("T1")
LOW_SEVERITY = next(
    int(d.limit_priorities[2]) for d in plc_alarms(SITE) if d.name == T1 and d.limit_priorities is not None
)
"""The Low limit's Severity (HighHigh, High, Low, LowLow)."""
LOW_M = SITE.plant.tank("T1").switch_levels().low_m
FIELDS = (
    "EventId",
    "EventType",
    "SourceName",
    "Severity",
    "Message",
    "Retain",
    "ActiveState/Id",
    "AckedState/Id",
    "LimitState/CurrentState",
)
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)


async def subscribe(client: Client, events: Events) -> Any:
    sub = await client.create_subscription(100, events)
    await sub.subscribe_events(ua.ObjectIds.Server, ua.ObjectIds.BaseEventType, evfilter=event_filter(FIELDS))
    return sub


async def call(client: Client, obj: ua.NodeId, method: ua.NodeId, *args: ua.Variant) -> str:
    """A raw call's status name (no exception on a Bad status)."""
    req = ua.CallMethodRequest(ObjectId=obj, MethodId=method, InputArguments=list(args))
    (result,) = await client.uaclient.call([req])
    return str(result.StatusCode.name)


def double(x: float) -> ua.Variant:
    return ua.Variant(x, ua.VariantType.Double)


def int32(x: int) -> ua.Variant:
    return ua.Variant(x, ua.VariantType.Int32)


def acknowledge(event_id: bytes, comment: str = "") -> tuple[ua.Variant, ua.Variant]:
    return (
        ua.Variant(event_id, ua.VariantType.ByteString),
        ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
    )


async def refresh(client: Client, condition: ua.NodeId) -> list[dict[str, Any]]:
    """ConditionRefresh on a fresh Server subscription: the events between RefreshStart and
    RefreshEnd (both received)."""
    return await condition_refresh(client, condition, FIELDS)


@pytest.fixture
async def stack(tmp_path: Path) -> AsyncIterator[Stack]:
    config = site_config(
        tmp_path / "site.yaml",
        at_operating_point=True,
        retain=tmp_path / "retain.json",
        pumps_hold_on_watchdog=True,
    )
    s = Stack(config, free_base_port(3), speed=20.0, state_file=tmp_path / "plant.json")
    try:
        await s.start("plant")
        await s.start("plc")
        yield s
    finally:
        await s.down()


async def test_t1_low_is_a_live_condition_acknowledged_refreshed_and_restored(stack: Stack) -> None:
    async with await secure(stack.plc_url, "operator") as op:
        idx = await op.get_namespace_index(NAMESPACE_URI)
        cid = ua.NodeId(paths.condition("plc", T1), idx)
        events = Events()
        await subscribe(op, events)
        # At the operating point T1 is normal: no T1Level event yet.
        active_id = ua.NodeId(f"{paths.condition('plc', T1)}.ActiveState.Id", idx)
        assert await op.get_node(active_id).read_value() is False
        async with await secure(stack.plant_url) as eng_plant, await secure(stack.plc_url) as eng_plc:
            # Both pumps off (MANUAL at 0: T2 and T3 would otherwise hold T1 up through the
            # valves), then the leak.
            for loop in ("LIC1", "LIC2"):
                await eng_plc.get_node(ua.NodeId(f"PLC.{loop}.Mode", idx)).write_value(int32(0))
                await eng_plc.get_node(ua.NodeId(f"PLC.{loop}.ManualMV", idx)).write_value(double(0.0))
            pidx = await eng_plant.get_namespace_index(NAMESPACE_URI)
            await eng_plant.get_node(ua.NodeId("Plant.T1.Leak", pidx)).write_value(double(1.0))

        def active() -> list[dict[str, Any]]:
            return [e for e in events.of(cid) if e["ActiveState/Id"] is True]

        await wait_until(lambda: bool(active()), 120, what="the T1Level activation event")
        ev = active()[0]
        assert ev["SourceName"] == "LT1"  # the level transmitter is the source
        assert ev["LimitState/CurrentState"].Text == LimitState.LOW.value
        assert ev["Severity"] == LOW_SEVERITY
        assert ev["AckedState/Id"] is False and ev["Retain"] is True
        assert ev["EventType"] == ua.NodeId(ua.ObjectIds.ExclusiveLevelAlarmType)
        pv = await op.get_node(ua.NodeId("PLC.LIC1.PV", idx)).read_value()
        assert pv <= LOW_M + 0.02  # the alarm came with the level at its low switch (deadband aside)

        # Acknowledge: Good, again AlreadyAcked, with the superseded EventId unknown, as observer denied.
        first = ev["EventId"]
        assert await call(op, cid, ACK, *acknowledge(first, "leak seen")) == "Good"
        await wait_until(
            lambda: any(e["AckedState/Id"] is True for e in events.of(cid)), 20, what="the acknowledged event"
        )
        acked = next(e for e in events.of(cid) if e["AckedState/Id"] is True)
        assert acked["ActiveState/Id"] is True and acked["EventId"] != first
        latest = acked["EventId"]
        assert await call(op, cid, ACK, *acknowledge(latest)) == "BadConditionBranchAlreadyAcked"
        assert await call(op, cid, ACK, *acknowledge(first)) == "BadEventIdUnknown"
    async with await secure(stack.plc_url, "observer") as observer:
        assert await call(observer, cid, ACK, *acknowledge(latest)) == "BadUserAccessDenied"

    # A reconnecting client gets the standing condition from ConditionRefresh.
    async with await secure(stack.plc_url, "operator") as op:
        (refreshed,) = await refresh(op, cid)
        assert refreshed["EventId"] == latest  # acknowledgeable from the refresh
        assert refreshed["ActiveState/Id"] is True and refreshed["AckedState/Id"] is True

    # Warm restart (the retentive memory is on): the restored condition is shown and refreshed
    # with an EventId of the new process.
    assert await stack.stop("plc") == 0
    await stack.start("plc")
    async with await secure(stack.plc_url, "operator") as op:
        assert await op.get_node(active_id).read_value() is True
        (restored,) = await refresh(op, cid)
        assert restored["ActiveState/Id"] is True and restored["AckedState/Id"] is True
        assert restored["EventId"] not in (first, latest)
        assert restored["LimitState/CurrentState"].Text == LimitState.LOW.value
