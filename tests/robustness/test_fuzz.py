"""Protocol fuzz smoke of the secured PLC server (a real PLC process scanning a real plant).

The case generators, oracles and post-conditions are ``tanklab_testing.security``'s (``make bench``
runs the same fuzz with 5,000 cases); here a few hundred seeded cases:

* raw transport on fresh sockets: random bytes, absurd Hello messages, bogus channel ids, chunk
  headers above 64 KiB or below 8 bytes, unknown message types, truncated and bit-flipped
  frames, OpenSecureChannel with garbage certificates, and on an opened discovery channel more
  than 4 chunks per message, more than 16 queued messages and mutated requests;
* typed requests through an engineer session and the supervisor's tier identity: writes of
  random Variant types (NaN, infinities, out of EURange, arrays, matrices, non-members of
  enumerations, Bad status codes, index ranges, other attributes) to every PLC node, its
  properties and foreign nodes; method calls with random arguments; node management;
  subscriptions with absurd parameters.

Afterwards the server serves a new secure session, a Read is Good, no stored value lies outside
its contract (type, finiteness, EURange, enumeration; EURange properties unchanged), and the
scan counter advances. The generators and the oracles are also checked by hand here.
"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from asyncua import ua

from helpers import TierProcess, engineer_logins, secure, wait_until
from tanklab.tags import Role, Tag, tags_by_path
from tanklab_testing import security
from tanklab_testing.procs import free_base_port  # random bases: parallel sessions do not collide
from tanklab_testing.stack import Stack

SEED = 20240607
CASES = 400
SPEED = "10"
TAGS = tags_by_path(security.PLC_TAGS)


def logins() -> security.Logins:
    """The session's security home with the test engineer's login."""
    return engineer_logins()


def _write(
    path: str | None,
    value: ua.Variant,
    *,
    attribute: int = ua.AttributeIds.Value,
    index_range: str | None = None,
    status: int = 0,
    stamp: datetime | None = None,
) -> tuple[Tag | None, ua.WriteValue]:
    """A WriteValue to ``path`` (None: a node that is no tag) and the tag behind it."""
    wv = ua.WriteValue()
    wv.NodeId = ua.NodeId(path or "PLC.LIC1.SP.EURange", 2)
    wv.AttributeId = attribute
    wv.IndexRange = index_range
    wv.Value = ua.DataValue(Value=value, StatusCode=ua.StatusCode(status), SourceTimestamp=stamp)
    return TAGS.get(path or ""), wv


def test_write_oracle_by_hand() -> None:
    d = ua.VariantType.Double
    must = security.write_must_refuse
    eng, sup = Role.ENGINEER, Role.SUPERVISOR
    cases = [
        (_write("PLC.LIC1.SP", ua.Variant(0.3, d)), eng, False),
        (_write("PLC.LIC1.SP", ua.Variant(0.6, d)), eng, False),  # the range's end is inside
        (_write("PLC.LIC1.SP", ua.Variant(0.6000001, d)), eng, True),
        (_write("PLC.LIC1.SP", ua.Variant(math.nan, d)), eng, True),
        (_write("PLC.LIC1.SP", ua.Variant(-math.inf, d)), eng, True),
        (_write("PLC.LIC1.SP", ua.Variant(0.3, ua.VariantType.Float)), eng, True),
        (_write("PLC.LIC1.SP", ua.Variant([0.3], d, is_array=True)), eng, True),
        (_write("PLC.LIC1.SP", ua.Variant(0.3, d), status=0x80000000), eng, True),
        (
            _write("PLC.LIC1.SP", ua.Variant(0.3, d), stamp=datetime(2001, 1, 1, tzinfo=UTC)),
            eng,
            False,
        ),
        (_write("PLC.LIC1.SP", ua.Variant(0.3, d), index_range="0"), eng, True),
        (_write("PLC.LIC1.SP", ua.Variant(0.3, d), attribute=ua.AttributeIds.Description), eng, True),
        (_write("PLC.LIC1.SP", ua.Variant(0.3, d)), sup, True),  # not the supervisor's node
        (_write("PLC.LIC1.Mode", ua.Variant(0, ua.VariantType.Int32)), eng, False),
        (_write("PLC.LIC1.Mode", ua.Variant(3, ua.VariantType.Int32)), eng, True),
        (_write("PLC.LIC1.Mode", ua.Variant(0, ua.VariantType.Int32)), sup, True),  # MANUAL: restricted
        (_write("PLC.LIC1.Mode", ua.Variant(2, ua.VariantType.Int32)), sup, False),
        (_write("PLC.LIC1.RemoteMV", ua.Variant(1e-5, d)), eng, True),
        (_write("PLC.LIC1.RemoteMV", ua.Variant(1e-5, d)), sup, False),
        (_write("PLC.Supervisor.Heartbeat", ua.Variant(7, ua.VariantType.UInt32)), sup, False),
        (_write("PLC.Supervisor.Heartbeat", ua.Variant(7, ua.VariantType.Int32)), sup, True),
        (_write("PLC.LIC1.Kp", ua.Variant(1e-3, d)), eng, True),  # read-only
        (_write(None, ua.Variant(1.0, d)), eng, True),  # not a tag (a property, a foreign node)
    ]
    for (tag, wv), role, refuse in cases:
        assert must(tag, role, wv) is refuse, (tag.path if tag else None, wv.Value, role)


def test_call_oracle_by_hand() -> None:
    d = ua.VariantType.Double
    set_gains = TAGS["PLC.LIC1.SetGains"]
    reset = TAGS["PLC.Interlock.Reset"]
    must = security.call_must_refuse
    ok = [ua.Variant(1e-3, d), ua.Variant(1e-5, d), ua.Variant(0.0, d)]
    assert not must(set_gains, Role.SUPERVISOR, ok)
    assert not must(set_gains, Role.ENGINEER, ok)
    assert must(set_gains, Role.OPERATOR, ok)
    assert must(set_gains, Role.SUPERVISOR, ok[:2])
    assert must(set_gains, Role.SUPERVISOR, [ua.Variant(1.0, d), *ok[1:]])  # outside the gain box
    assert must(set_gains, Role.SUPERVISOR, [ua.Variant(math.nan, d), *ok[1:]])
    assert must(set_gains, Role.SUPERVISOR, [ua.Variant(1, ua.VariantType.Int32), *ok[1:]])
    assert not must(reset, Role.OPERATOR, [])
    assert must(reset, Role.SUPERVISOR, [])
    assert must(None, Role.ENGINEER, [])


def test_cases_are_seeded() -> None:
    url = "opc.tcp://127.0.0.1:4841/tanklab/plc"
    targets = security.SessionTargets.build(2, security.PLC_TAGS)

    def draw(seed: int) -> tuple[list[bytes], list[str]]:
        rng = np.random.default_rng(seed)
        raw = [b"".join(security.raw_case(k, rng, url).steps) for k in security.RAW_KINDS]
        writes = [repr(security.random_write(rng, targets)[0]) for _ in range(50)]
        return raw, writes

    assert draw(SEED) == draw(SEED)
    assert draw(SEED) != draw(SEED + 1)


@pytest.fixture
async def plant_and_plc(tmp_path: Path) -> AsyncIterator[tuple[str, TierProcess]]:
    config = security.site_config(tmp_path / "site.yaml", at_operating_point=True)
    stack = Stack(config, free_base_port(3), speed=float(SPEED), state_file=tmp_path / "plant.json")
    try:
        await stack.up(("plant", "plc"))
        yield stack.plc_url, stack.procs["plc"]
    finally:
        await stack.down()


@pytest.mark.process
async def test_protocol_fuzz_leaves_the_plc_serving_in_contract_and_scanning(
    plant_and_plc: tuple[str, TierProcess],
) -> None:
    url, plc = plant_and_plc
    counts = await security.fuzz_server(url, logins(), n_cases=CASES, seed=SEED)

    assert sum(counts.cases.values()) == CASES
    assert set(counts.cases) >= {"write", "call"} and len(set(counts.cases) & set(security.RAW_KINDS)) >= 8
    # Nothing the contract refuses was accepted; every must-close case was closed.
    assert counts.violations == []
    assert not [k for k in counts.failed if not k.startswith(("write (not encodable", "call (not encodable"))]
    assert counts.statuses["Good"] > 0, "no admissible write got through: the generator is off"
    # The process is alive and serves a new secure session; a Read is Good.
    assert plc.proc is not None and plc.proc.returncode is None
    async with await secure(url) as client:
        scan = await security.read_scan(client)
        # Zero stored values outside their contract.
        assert await security.stored_violations(client, security.PLC_TAGS) == []

        async def scanning() -> bool:
            return await security.read_scan(client) > scan

        await wait_until(scanning, 20, what="the scan counter advancing after the fuzz")
