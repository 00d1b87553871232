"""``tankctl alarms`` / ``ack`` / ``shelve`` / ``unshelve`` through real plant and PLC processes.

The set-up of test_plc_conditions.py: both pumps off (LIC1 and LIC2 in MANUAL at 0) and T1's
leak open drain T1 below its low switch, so the T1Level condition goes active (limit Low).
Then the CLI, run as the operator commands are elsewhere (a ``python -m tankctl`` process
against the stack's base port, logged in through the session's credentials file as engineer):
it lists the alarm unacknowledged, acknowledges it, lists it acknowledged, refuses a second
acknowledgement with BadConditionBranchAlreadyAcked (exit 1), shelves and unshelves it.

Across the tiers (plant, PLC and supervisor processes): with the PLC killed, ``tankctl alarms``
reports the PLC down in one line on stderr and still lists the supervisor's PlcLinkLost (tier
``supervisor``), which ``ack`` acknowledges by its bare name; with the PLC back both tiers'
conditions are listed (a TIER column), ``supervisor/NAME`` shelves and ``unshelve`` finds the
supervisor's condition; with the supervisor killed the PLC's alarms are still listed.

Waits are on node values (``wait_until``), never on elapsed time.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from helpers import secure, tankctl_at, wait_until
from tanklab import paths
from tanklab.tags import NAMESPACE_URI
from tanklab_testing.procs import free_base_port
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process


async def tankctl(
    *args: str, base: int, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """An operator command against the stack at ``base`` (:func:`helpers.tankctl_at`)."""
    return await tankctl_at(base, *args, env=env)


@pytest.fixture
async def stack(tmp_path: Path) -> AsyncIterator[Stack]:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True)
    s = Stack(config, free_base_port(3), speed=20.0, state_file=tmp_path / "plant.json")
    try:
        await s.start("plant")
        await s.start("plc")
        yield s
    finally:
        await s.down()


def _int32(x: int) -> ua.Variant:
    return ua.Variant(x, ua.VariantType.Int32)


def _double(x: float) -> ua.Variant:
    return ua.Variant(x, ua.VariantType.Double)


async def _alarms(base: int, *extra: str) -> dict[str, dict[str, Any]]:
    r = await tankctl("alarms", "--json", *extra, base=base)
    assert r.returncode == 0, r.stderr
    return {row["name"]: row for row in json.loads(r.stdout)}


async def test_the_cli_lists_acknowledges_and_shelves_a_live_alarm(stack: Stack) -> None:
    base = stack.base
    # At the operating point nothing stands.
    assert "T1Level" not in await _alarms(base)
    every = await _alarms(base, "--all")
    assert every["T1Level"]["state"] == "RTN ACK" and every["T1Level"]["limit"] is None

    async with await secure(stack.plc_url) as plc, await secure(stack.plant_url) as plant:
        idx = await plc.get_namespace_index(NAMESPACE_URI)
        for loop in ("LIC1", "LIC2"):
            await plc.get_node(ua.NodeId(f"PLC.{loop}.Mode", idx)).write_value(_int32(0))
            await plc.get_node(ua.NodeId(f"PLC.{loop}.ManualMV", idx)).write_value(_double(0.0))
        pidx = await plant.get_namespace_index(NAMESPACE_URI)
        await plant.get_node(ua.NodeId("Plant.T1.Leak", pidx)).write_value(_double(1.0))
        active = plc.get_node(ua.NodeId(f"{paths.condition('plc', 'T1Level')}.ActiveState.Id", idx))

        async def is_active() -> bool:
            return bool(await active.read_value())

        await wait_until(is_active, 120, what="T1Level active")

    row = (await _alarms(base))["T1Level"]
    assert (row["state"], row["limit"], row["acked"], row["standing"]) == ("ACTIVE UNACK", "Low", False, True)
    assert row["since"] and row["severity"] > 0 and row["message"]

    r = await tankctl("ack", "T1Level", "--comment", "x", base=base)
    assert r.returncode == 0, r.stderr
    assert r.stdout == (
        "T1Level: acknowledged, comment 'x' (was ACTIVE UNACK, limit Low; now ACTIVE ACK, limit Low)\n"
    )
    assert (await _alarms(base))["T1Level"]["state"] == "ACTIVE ACK"

    r = await tankctl("ack", "T1Level", base=base)
    assert r.returncode == 1
    assert r.stderr.strip().endswith("refused: BadConditionBranchAlreadyAcked")
    assert len(r.stderr.strip().splitlines()) == 1

    r = await tankctl("shelve", "T1Level", "--for", "10m", base=base)
    assert r.returncode == 0, r.stderr
    assert r.stdout.endswith("(was ACTIVE ACK, limit Low; now ACTIVE ACK SHELVED, limit Low, TimedShelved)\n")
    shelved = (await _alarms(base))["T1Level"]
    assert shelved["shelved"] == "TimedShelved" and shelved["state"] == "ACTIVE ACK SHELVED"

    # Part 9 lets a timed shelve become one-shot; a second one-shot shelve is refused.
    r = await tankctl("shelve", "T1Level", "--once", base=base)
    assert r.returncode == 0, r.stderr
    assert r.stdout.endswith("now ACTIVE ACK SHELVED, limit Low, OneShotShelved)\n")
    r = await tankctl("shelve", "T1Level", "--once", base=base)
    assert r.returncode == 1 and r.stderr.strip().endswith("refused: BadConditionAlreadyShelved")

    r = await tankctl("unshelve", "T1Level", base=base)
    assert r.returncode == 0, r.stderr
    assert r.stdout.endswith("now ACTIVE ACK, limit Low)\n")
    assert (await _alarms(base))["T1Level"]["shelved"] == "Unshelved"

    r = await tankctl("unshelve", "T1Level", base=base)
    assert r.returncode == 1 and r.stderr.strip().endswith("refused: BadConditionNotShelved")
    r = await tankctl("ack", "T9Level", base=base)
    assert r.returncode == 2 and "unknown alarm 'T9Level' (the PLC has T1Level" in r.stderr


@pytest.fixture
async def full_stack(tmp_path: Path) -> AsyncIterator[Stack]:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True)
    s = Stack(config, free_base_port(3), speed=20.0, state_file=tmp_path / "plant.json")
    try:
        await s.up()
        yield s
    finally:
        await s.down()


async def test_the_cli_lists_and_acknowledges_both_tiers_and_reports_a_tier_down(full_stack: Stack) -> None:
    stack, base = full_stack, full_stack.base
    cond = paths.condition("supervisor", "PlcLinkLost")
    async with await secure(stack.supervisor_url) as sup:
        idx = await sup.get_namespace_index(NAMESPACE_URI)
        connected = sup.get_node(ua.NodeId(paths.supervisor.plc_connected, idx))
        await wait_until(connected.read_value, 60, what="the supervisor connected to the PLC")
        await stack.kill("plc")
        active = sup.get_node(ua.NodeId(f"{cond}.ActiveState.Id", idx))
        await wait_until(active.read_value, 60, what="PlcLinkLost active")

    # The PLC is down: one line says so, the supervisor's alarms are still listed (exit 0).
    r = await tankctl("alarms", "--json", base=base)
    assert r.returncode == 0, r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith(f"tankctl: cannot reach plc at {stack.plc_url}") and "not listed" in line
    rows = {row["name"]: row for row in json.loads(r.stdout)}
    lost = rows["PlcLinkLost"]
    assert (lost["tier"], lost["state"], lost["priority"]) == ("supervisor", "ACTIVE UNACK", "HIGH")

    r = await tankctl("ack", "PlcLinkLost", "--comment", "PLC restarting", base=base)
    assert r.returncode == 0, r.stderr
    assert (
        r.stdout == "PlcLinkLost: acknowledged, comment 'PLC restarting' (was ACTIVE UNACK; now ACTIVE ACK)\n"
    )

    # Both tiers up: every condition of both, in tier order, with the TIER column.
    await stack.start("plc")
    async with await secure(stack.supervisor_url) as sup:
        idx = await sup.get_namespace_index(NAMESPACE_URI)
        active = sup.get_node(ua.NodeId(f"{cond}.ActiveState.Id", idx))

        async def normal() -> bool:
            return not await active.read_value()

        await wait_until(normal, 60, what="PlcLinkLost back to normal")
    r = await tankctl("alarms", "--all", "--json", base=base)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    every = json.loads(r.stdout)
    tiers = [row["tier"] for row in every]
    assert tiers == sorted(tiers, key=["plc", "supervisor"].index) and set(tiers) == {"plc", "supervisor"}
    by_name = {row["name"]: row for row in every}
    assert by_name["T1Level"]["tier"] == "plc"
    assert by_name["PlcLinkLost"]["state"] == "RTN ACK" and by_name["PlcLinkLost"]["standing"] is False
    r = await tankctl("alarms", "--all", base=base)
    assert r.returncode == 0, r.stderr
    table = r.stdout.splitlines()
    assert table[0].split()[:2] == ["TIER", "NAME"]
    assert any(row.split()[:2] == ["supervisor", "MpcFailing"] for row in table[1:])

    r = await tankctl("shelve", "supervisor/MpcFailing", "--for", "1h", base=base)
    assert r.returncode == 0, r.stderr
    assert r.stdout.endswith("(was RTN ACK; now RTN ACK SHELVED, TimedShelved)\n")
    r = await tankctl("unshelve", "mpcfailing", base=base)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "MpcFailing: unshelved (was RTN ACK SHELVED, TimedShelved; now RTN ACK)\n"
    r = await tankctl("ack", "plc/PlcLinkLost", base=base)
    assert r.returncode == 2 and "unknown alarm 'plc/PlcLinkLost' (the PLC has T1Level" in r.stderr

    # The supervisor down: the PLC's alarms are still listed.
    await stack.kill("supervisor")
    r = await tankctl("alarms", "--all", "--json", base=base)
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip().startswith(f"tankctl: cannot reach supervisor at {stack.supervisor_url}")
    assert {row["tier"] for row in json.loads(r.stdout)} == {"plc"}
