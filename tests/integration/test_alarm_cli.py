"""``tankctl alarms`` / ``ack`` / ``shelve`` / ``unshelve`` through real plant and PLC processes.

The set-up of test_plc_conditions.py: both pumps off (LIC1 and LIC2 in MANUAL at 0) and T1's
leak open drain T1 below its low switch, so the T1Level condition goes active (limit Low).
Then the CLI, run as the operator commands are elsewhere (a ``python -m tankctl`` process
against the stack's base port, logged in through the session's credentials file as engineer):
it lists the alarm unacknowledged, acknowledges it, lists it acknowledged, refuses a second
acknowledgement with BadConditionBranchAlreadyAcked (exit 1), shelves and unshelves it.

Waits are on node values (``wait_until``), never on elapsed time.
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from helpers import ROOT, secure, wait_until
from tanklab import paths
from tanklab.tags import NAMESPACE_URI
from tanklab_testing.procs import free_base_port
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process


async def tankctl(*args: str, base: int) -> subprocess.CompletedProcess[str]:
    """An operator command against the stack at ``base``, in a thread (the test's loop runs on)."""
    return await asyncio.to_thread(
        subprocess.run,
        [sys.executable, "-m", "tankctl", *args, "--base-port", str(base)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
        check=False,
    )


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
