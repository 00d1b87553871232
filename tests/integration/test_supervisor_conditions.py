"""The supervisor's own alarms as live OPC UA conditions, through real plant, PLC and supervisor
processes (issue 15, supervisor part).

A client subscribed to the supervisor's Server object sees no PlcLinkLost event while the PLC
runs; when the PLC process is killed it receives PlcLinkLost active (HIGH Severity, unacked,
retained); when the PLC is restarted the condition returns to normal (still unacknowledged, so
retained), and its EventId acknowledges it. ``Supervisor.AlarmSummary`` counts the loss (one
more active and unacknowledged, one more in the rate) and, after the acknowledge, agrees with a
recount of the conditions' own state nodes.

With the retentive memory on (``--retain-file``, as under ``tankctl up``): PlcLinkLost raised by
the PLC's death and acknowledged survives a crash (SIGKILL) and restart of the supervisor: the
new process shows it active and acknowledged with its comment, ConditionRefresh reports it with
an EventId of the new process, and it returns to normal (no longer retained) when the PLC comes
back.

Waits are on events (``wait_until``), never on elapsed time.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from helpers import secure, wait_until
from tanklab import paths
from tanklab.alarms import Priority, names
from tanklab.alarms.definitions import supervisor_alarms
from tanklab.config import load_site
from tanklab.tags import NAMESPACE_URI
from tanklab_testing.condition_events import Events, event_filter, refresh
from tanklab_testing.procs import free_base_port
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

FIELDS = ("EventId", "EventType", "SourceName", "Severity", "Retain", "ActiveState/Id", "AckedState/Id")
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)


async def call(client: Client, obj: ua.NodeId, method: ua.NodeId, *args: ua.Variant) -> str:
    """A raw call's status name (no exception on a Bad status)."""
    req = ua.CallMethodRequest(ObjectId=obj, MethodId=method, InputArguments=list(args))
    (result,) = await client.uaclient.call([req])
    return str(result.StatusCode.name)


@pytest.fixture
async def stack(tmp_path: Path) -> AsyncIterator[Stack]:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True)
    s = Stack(config, free_base_port(3), speed=20.0, state_file=tmp_path / "plant.json")
    try:
        await s.up()
        yield s
    finally:
        await s.down()


async def test_plc_link_lost_is_raised_when_the_plc_dies_and_clears_when_it_returns(stack: Stack) -> None:
    async with await secure(stack.supervisor_url, "operator") as op:
        idx = await op.get_namespace_index(NAMESPACE_URI)
        cid = ua.NodeId(paths.condition("supervisor", names.PLC_LINK_LOST), idx)
        connected = op.get_node(ua.NodeId(paths.supervisor.plc_connected, idx))
        await wait_until(connected.read_value, 60, what="the supervisor connected to the PLC")
        events = Events()
        sub = await op.create_subscription(100, events)
        await sub.subscribe_events(
            ua.ObjectIds.Server, ua.ObjectIds.BaseEventType, evfilter=event_filter(FIELDS)
        )

        def states() -> list[bool]:
            return [e["ActiveState/Id"] for e in events.of(cid)]

        summary_paths = paths.alarm_summary_paths("supervisor")
        summary_nodes = [op.get_node(ua.NodeId(p, idx)) for p in summary_paths.values()]
        figures: dict[str, Any] = {}

        async def unacked_is(n: int) -> bool:
            figures.update(zip(summary_paths, await op.read_values(summary_nodes), strict=True))
            return bool(figures["Unacknowledged"] == n)

        await unacked_is(-1)  # read them (no count is -1)
        base = dict(figures)  # the supervisor's own alarms before the PLC dies
        assert base["Disabled"] == 0 and base["Shelved"] == 0 and base["Flood"] is False

        await stack.kill("plc")
        await wait_until(lambda: True in states(), 60, what="the PlcLinkLost activation event")
        lost = next(e for e in events.of(cid) if e["ActiveState/Id"] is True)
        assert lost["EventType"] == ua.NodeId(ua.ObjectIds.DiscreteAlarmType)
        assert lost["SourceName"] == paths.supervisor.plc_link.rsplit(".", 1)[-1]
        assert lost["Severity"] == int(Priority.HIGH)
        assert lost["Retain"] is True and lost["AckedState/Id"] is False
        # Supervisor.AlarmSummary counts it: one more active, unacknowledged, in the rate.
        want = base["Unacknowledged"] + 1
        await wait_until(lambda: unacked_is(want), 20, what="Supervisor.AlarmSummary counting PlcLinkLost")
        assert figures["Active"] == base["Active"] + 1
        assert figures["RatePer10Min"] == base["RatePer10Min"] + 1 and figures["PeakRatePer10Min"] >= 1

        await stack.start("plc")
        await wait_until(lambda: states()[-1] is False, 60, what="PlcLinkLost back to normal")
        normal = events.of(cid)[-1]
        assert normal["Retain"] is True and normal["AckedState/Id"] is False  # still to acknowledge
        assert states() == [True, False]  # one activation, one return to normal

        comment = ua.Variant(ua.LocalizedText("PLC restarted"), ua.VariantType.LocalizedText)
        event_id = ua.Variant(normal["EventId"], ua.VariantType.ByteString)
        assert await call(op, cid, ACK, event_id, comment) == "Good"
        await wait_until(lambda: events.of(cid)[-1]["Retain"] is False, 20, what="the acknowledged event")
        assert events.of(cid)[-1]["AckedState/Id"] is True
        # Back in step with the PLC the supervisor's other alarms may change too (its MPC, its
        # adaptation): the summary agrees with a recount of every condition's own state nodes,
        # read in one Read, PlcLinkLost acknowledged among them.
        defs = supervisor_alarms(load_site(stack.config))
        fields = ("EnabledState.Id", "ActiveState.Id", "AckedState.Id")
        state_nodes = [
            op.get_node(ua.NodeId(f"{paths.condition('supervisor', d.name)}.{f}", idx))
            for d in defs
            for f in fields
        ]

        async def agrees() -> bool:
            values = await op.read_values([*summary_nodes, *state_nodes])
            summary = dict(zip(summary_paths, values[: len(summary_nodes)], strict=True))
            rest = values[len(summary_nodes) :]
            conds = {d.name: rest[3 * k : 3 * k + 3] for k, d in enumerate(defs)}
            on = [v for v in conds.values() if v[0]]
            return (
                conds[names.PLC_LINK_LOST][2] is True
                and summary["Active"] == sum(bool(v[1]) for v in on)
                and summary["Unacknowledged"] == sum(not v[2] for v in on)
                and summary["Disabled"] == len(defs) - len(on)
            )

        await wait_until(agrees, 20, what="Supervisor.AlarmSummary agreeing with its conditions")
        await sub.delete()


@pytest.fixture
async def retentive(tmp_path: Path) -> AsyncIterator[Stack]:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True)
    args = {"supervisor": ("--retain-file", str(tmp_path / "supervisor-retain.json"))}
    s = Stack(config, free_base_port(3), speed=20.0, state_file=tmp_path / "plant.json", tier_args=args)
    try:
        await s.up()
        yield s
    finally:
        await s.down()


async def test_an_acknowledged_plc_link_lost_survives_a_supervisor_restart(retentive: Stack) -> None:
    stack = retentive
    cond = paths.condition("supervisor", names.PLC_LINK_LOST)
    async with await secure(stack.supervisor_url, "operator") as op:
        idx = await op.get_namespace_index(NAMESPACE_URI)
        cid = ua.NodeId(cond, idx)
        connected = op.get_node(ua.NodeId(paths.supervisor.plc_connected, idx))
        active = op.get_node(ua.NodeId(f"{cond}.ActiveState.Id", idx))
        acked = op.get_node(ua.NodeId(f"{cond}.AckedState.Id", idx))
        await wait_until(connected.read_value, 60, what="the supervisor connected to the PLC")
        await stack.kill("plc")
        await wait_until(active.read_value, 60, what="PlcLinkLost active")
        event_id = await op.get_node(ua.NodeId(f"{cond}.EventId", idx)).read_value()
        comment = ua.Variant(ua.LocalizedText("PLC down, on it"), ua.VariantType.LocalizedText)
        assert await call(op, cid, ACK, ua.Variant(event_id, ua.VariantType.ByteString), comment) == "Good"
        assert await acked.read_value() is True

    # A crash: the call's answer came after the retentive memory was written.
    await stack.kill("supervisor")
    await stack.start("supervisor")
    async with await secure(stack.supervisor_url, "operator") as op:
        idx = await op.get_namespace_index(NAMESPACE_URI)
        cid = ua.NodeId(cond, idx)

        async def read(field: str) -> object:
            return await op.get_node(ua.NodeId(f"{cond}.{field}", idx)).read_value()

        assert await read("ActiveState.Id") is True  # the PLC is still down
        assert await read("AckedState.Id") is True
        assert await read("Retain") is True
        assert (await read("Comment")).Text == "PLC down, on it"  # type: ignore[attr-defined]
        assert (await read("ClientUserId")) == "operator"
        (restored,) = await refresh(op, cid, FIELDS)
        assert restored["ActiveState/Id"] is True and restored["AckedState/Id"] is True
        assert restored["EventId"] != event_id and restored["EventId"] == await read("EventId")
        assert restored["Severity"] == int(Priority.HIGH)

        events = Events()
        sub = await op.create_subscription(100, events)
        await sub.subscribe_events(
            ua.ObjectIds.Server, ua.ObjectIds.BaseEventType, evfilter=event_filter(FIELDS)
        )
        await stack.start("plc")
        await wait_until(
            lambda: any(e["ActiveState/Id"] is False for e in events.of(cid)), 60, what="PlcLinkLost normal"
        )
        normal = next(e for e in events.of(cid) if e["ActiveState/Id"] is False)
        assert normal["AckedState/Id"] is True and normal["Retain"] is False  # nothing left to acknowledge
        await sub.delete()
