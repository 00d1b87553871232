"""Interop: node-opcua (an independent OPC UA stack) reads raw history across continuation points
and an Average from ``install_history_read`` on a real asyncua server on a loopback port."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from asyncua import Server

from historian.history_read import install_history_read, site_tag_mapper
from historian.store.sqlite import SQLiteStore
from node_client import NODE, run_node_script
from tanklab.history.model import Sample
from tanklab_testing.procs import free_port

S = 1_000_000
T0 = 1_764_633_600_000_000  # 2025-12-02 00:00 UTC [us]
TAG = "PLC.LIC1.PV"
N = 150

pytestmark = pytest.mark.skipif(NODE is None, reason="node is not installed")


def iso(t_us: int) -> str:
    return (
        (datetime(1970, 1, 1, tzinfo=UTC) + timedelta(microseconds=t_us)).isoformat().replace("+00:00", "Z")
    )


async def test_node_opcua_reads_raw_and_average(tmp_path: Path) -> None:
    store = SQLiteStore(tmp_path / "history.db")
    try:
        store.append_samples(
            {TAG: [Sample(T0 + k * S, float(k), 0x8000_0000 if k % 7 == 3 else 0) for k in range(N)]}
        )
        port = free_port()
        url = f"opc.tcp://127.0.0.1:{port}/tanklab/historian"
        server = Server()
        await server.init()
        server.set_endpoint(url)
        ns = await server.register_namespace("urn:tanklab")
        install_history_read(server, store, site_tag_mapper(store, ns), max_values=50)
        async with server:
            res = await run_node_script(
                "history.mjs", url, f"ns={ns};s={TAG}", iso(T0), iso(T0 + 120 * S), "60000", password="-"
            )
    finally:
        store.close()
    assert res["ok"] and res["rc"] == 0, res
    raw = res["raw"]["values"]
    # [0, 120 s): 120 values over three responses of at most 50, times and statuses as recorded
    assert [v[1] for v in raw] == [float(k) for k in range(120)]
    assert raw[3][2] == 0x8000_0000 and raw[4][2] == 0
    assert raw[10][0] == iso(T0 + 10 * S).replace("Z", ".000Z")
    good = [k for k in range(60) if k % 7 != 3]
    avg = res["average"]["values"]
    assert len(avg) == 2 and avg[0][1] == pytest.approx(sum(good) / len(good), rel=1e-12)
    assert avg[0][2] == 0x40A4_0401  # Uncertain_DataSubNormal + Calculated
    assert res["unknown"] == 0x8034_0000  # BadNodeIdUnknown
