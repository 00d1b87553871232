"""``tankctl history`` and ``tankctl alarms --history`` against real processes (issue 16): plant,
PLC and historian at speed 20 on loopback ports, the historian recording into a SQLite file; the
commands run as an operator would run them (``python -m tankctl ... --base-port N``), and what
they print is checked against the store the historian wrote (read directly, the oracle).
"""

from __future__ import annotations

import csv
import io
import json
import subprocess
from collections.abc import AsyncIterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from asyncua import ua

from helpers import secure, tankctl_at, wait_until
from historian.store.sqlite import SQLiteStore
from tanklab import paths
from tanklab.tags import NAMESPACE_URI
from tanklab_testing.procs import free_base_port
from tanklab_testing.sites import site_config
from tanklab_testing.stack import Stack

pytestmark = pytest.mark.process

SCAN = paths.plc.scan
PV = paths.plc.loop("LIC1").pv
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


async def tankctl(
    *args: str, base: int, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """An operator command against the stack at ``base`` (:func:`helpers.tankctl_at`)."""
    return await tankctl_at(base, *args, env=env)


def iso(t_us: int) -> str:
    return (EPOCH + timedelta(microseconds=t_us)).isoformat()


@pytest.fixture
async def stack(tmp_path: Path) -> AsyncIterator[tuple[Stack, SQLiteStore]]:
    config = site_config(tmp_path / "site.yaml", at_operating_point=True, pumps_hold_on_watchdog=True)
    db = tmp_path / "history.db"
    s = Stack(
        config, free_base_port(), speed=20.0, tier_args={"historian": ("--store", str(db))}, log_dir=tmp_path
    )
    store: SQLiteStore | None = None
    try:
        await s.up(("plant", "plc"))
        await s.start("historian")
        store = SQLiteStore(db)
        yield s, store
    finally:
        await s.down()
        if store is not None:
            store.close()


async def test_history_commands_print_what_the_historian_recorded(
    stack: tuple[Stack, SQLiteStore], tmp_path: Path
) -> None:
    s, store = stack
    base = s.base

    def count(tag: str) -> int:
        return len(store.read_raw(tag, 0, 2**62, limit=1_000_000).samples)

    await wait_until(lambda: count(SCAN) >= 30, 60, what="30 PLC scans recorded")
    done = await tankctl("setpoint", "LIC1", "0.42", base=base)
    assert done.returncode == 0, done.stderr
    await wait_until(
        lambda: len(store.read_events(0, 2**62, limit=10_000).events) >= 1, 30, what="the audit event"
    )

    recorded = store.read_raw(SCAN, 0, 2**62, limit=1_000_000).samples
    t0, t1 = recorded[0].t_us, recorded[-1].t_us
    window = ("--from", iso(t0), "--to", iso(t1))

    # raw, JSON: exactly the store's samples in [t0, t1] (both ends inclusive), values and statuses
    got = await tankctl("history", SCAN, *window, "--json", base=base)
    assert got.returncode == 0, got.stderr
    rows = json.loads(got.stdout)
    expect = store.read_raw(SCAN, t0, t1, limit=1_000_000).samples
    assert [(r["time"], r["value"], r["status_code"]) for r in rows] == [
        (iso(x.t_us), x.value, x.status) for x in expect
    ]
    assert len(rows) >= 30

    # an aggregate: Count per 10 s of source time, by hand from the store's Good samples
    got = await tankctl(
        "history", SCAN, *window, "--aggregate", "count", "--interval", "10s", "--csv", base=base
    )
    assert got.returncode == 0, got.stderr
    table = list(csv.DictReader(io.StringIO(got.stdout)))
    times = [x.t_us for x in expect if x.status == 0]
    for k, row in enumerate(table[:-1]):  # the last interval is partial
        lo = t0 + k * 10_000_000
        assert float(row["value"]) == sum(lo <= t < lo + 10_000_000 for t in times), (k, row)

    # two tags, text: one line per value
    got = await tankctl("history", SCAN, PV, *window, base=base)
    assert got.returncode == 0, got.stderr
    lines = got.stdout.splitlines()
    assert len(lines) == len(expect) + len(store.read_raw(PV, t0, t1, limit=1_000_000).samples)

    # export and plot
    parquet = tmp_path / "h.parquet"
    got = await tankctl("history", "export", "--parquet", str(parquet), SCAN, *window, base=base)
    assert got.returncode == 0, got.stderr
    exported = pq.read_table(parquet).to_pylist()
    assert [(r["tag"], r["value"]) for r in exported] == [(SCAN, float(x.value)) for x in expect]
    png = tmp_path / "h.png"
    got = await tankctl("history", "plot", SCAN, PV, *window, "-o", str(png), base=base)
    assert got.returncode == 0, got.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # the alarm and audit events the historian recorded
    # (logins audit too, so more may arrive while the command runs: between before and after)
    before = [ev.event_id.hex() for ev in store.read_events(0, 2**62, limit=10_000).events]
    got = await tankctl("alarms", "--history", "--from", "-1d", "--json", base=base)
    after = [ev.event_id.hex() for ev in store.read_events(0, 2**62, limit=10_000).events]
    assert got.returncode == 0, got.stderr
    events: list[dict[str, Any]] = json.loads(got.stdout)
    ids = [e["event_id"] for e in events]
    assert ids[: len(before)] == before and after[: len(ids)] == ids
    assert any("LIC1" in e["message"] for e in events), events

    # bad input: one line, exit 2
    for args, says in (
        (("history", "PLC.NOPE.PV"), "unknown tag 'PLC.NOPE.PV'"),
        (("history", SCAN, "--aggregate", "median", "--interval", "1s"), "--aggregate 'median'"),
        (("history", SCAN, "--from", "now", "--to", "-1h"), "is not before --to"),
        (("history", "plot", SCAN), "history plot needs -o"),
    ):
        got = await tankctl(*args, base=base)
        assert got.returncode == 2 and says in got.stderr and len(got.stderr.splitlines()) == 1, (
            args,
            got.stderr,
        )


async def test_an_observer_reads_history_and_nobody_updates_it(stack: tuple[Stack, SQLiteStore]) -> None:
    """The historian process on its secured endpoint: an Observer's raw read returns exactly what
    the store holds; a HistoryUpdate is refused for the Observer and for the Engineer (the role
    that may write everything on the tiers) with a Bad code, and the stored value is unchanged."""
    s, store = stack
    await wait_until(
        lambda: len(store.read_raw(SCAN, 0, 2**62, limit=1_000).samples) >= 10, 60, what="10 scans recorded"
    )
    recorded = store.read_raw(SCAN, 0, 2**62, limit=1_000).samples[:10]
    t0, t9 = recorded[0].t_us, recorded[-1].t_us
    # Part 11: a raw read's interval is [start, end): the end one microsecond after the tenth
    start, end = EPOCH + timedelta(microseconds=t0), EPOCH + timedelta(microseconds=t9 + 1)

    async with await secure(s.url("historian"), "observer") as client:
        node = client.get_node(ua.NodeId(SCAN, await client.get_namespace_index(NAMESPACE_URI)))
        got = await node.read_raw_history(start, end, return_bounds=False)
        assert [(v.SourceTimestamp, v.Value.Value, v.StatusCode.value) for v in got] == [
            (EPOCH + timedelta(microseconds=x.t_us), x.value, x.status) for x in recorded
        ]

    for user in ("observer", "engineer"):
        async with await secure(s.url("historian"), user) as client:
            node = client.get_node(ua.NodeId(SCAN, await client.get_namespace_index(NAMESPACE_URI)))
            forged = ua.DataValue(ua.Variant(-1.0, ua.VariantType.Double), SourceTimestamp=start)
            details = ua.UpdateDataDetails(
                NodeId=node.nodeid, PerformInsertReplace=ua.PerformUpdateType.Replace, UpdateValues=[forged]
            )
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await node.history_update(details)
            assert refused.value.code in (
                ua.StatusCodes.BadUserAccessDenied,
                ua.StatusCodes.BadHistoryOperationUnsupported,
            ), (user, refused.value)
    assert store.read_raw(SCAN, t0, t0, limit=10).samples == recorded[:1]
