"""node-opcua (an independent OPC UA stack, pinned by tests/node/package-lock.json) reads history
from a secured tanklab server with its own calls, as an Observer: ``readHistoryValue`` following
the continuation points, and ``readAggregateValue`` (Average). The server is a tier server secured
like every tier (site PKI, user names, roles) with :func:`install_history_read` over a store that
holds a known series (``history_url`` in conftest.py); the answers are checked against that
series by hand.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

from helpers import session_home
from history_series import T0, TAG, N, S, iso, level
from node_client import NODE, NODE_DIR, run_node_script
from tanklab_io.pki import trust

pytestmark = pytest.mark.skipif(
    NODE is None, reason="node is not installed (node-opcua needs node 20+ and `make tools`)"
)


async def _history(url: str, pki_dir: Path, start_us: int, end_us: int, interval_ms: int) -> dict[str, Any]:
    args = (url, str(pki_dir), "observer", TAG, iso(start_us), iso(end_us), str(interval_ms))
    return await run_node_script("history.mjs", *args, password="observer-test-password")


async def test_node_opcua_reads_raw_and_processed_history(history_url: str, tmp_path: Path) -> None:
    stamp = NODE_DIR / "node_modules" / ".package-lock.json"
    if not stamp.is_file() or stamp.stat().st_mtime < (NODE_DIR / "package-lock.json").stat().st_mtime:
        pytest.fail(f"{NODE_DIR}/node_modules is missing or older than package-lock.json: run `make tools`")
    pki = session_home().pki
    client_pki = tmp_path / "node-opcua-pki"
    for sub, file in (("certs", pki.ca_cert_pem), ("crl", pki.crl_pem)):
        (client_pki / "trusted" / sub).mkdir(parents=True, exist_ok=True)
        shutil.copy(file, client_pki / "trusted" / sub / file.name)
    start, end = T0, T0 + N * S
    first = await _history(history_url, client_pki, start, end, 60_000)  # makes its certificate
    assert first["ok"] is False and "BadCertificateUntrusted" in first["error"], first
    trust(pki, Path(first["certificate"]))

    result = await _history(history_url, client_pki, start, end, 60_000)
    assert result["ok"] is True and result["rc"] == 0, result
    raw = result["raw"]
    # every value, in order, with its source time and status, over three pages
    assert result["pages"] == 3
    assert [r[0] for r in raw] == [iso(T0 + k * S) for k in range(N)]
    assert [r[1] for r in raw] == pytest.approx([level(k) for k in range(N)], rel=0, abs=1e-15)
    assert [r[2] for r in raw].count("Good") == N - N // 100
    assert raw[50][2] == "BadNoCommunication"

    # Average over 60 s: interval j holds k = 60 j .. 60 j + 59, less the Bad k (k % 100 == 50)
    avg = result["average"]
    assert len(avg) == -(-N // 60)  # the last interval is partial (2,500 s = 41 2/3 min)
    for j in (0, 1, 7):
        good = [k for k in range(60 * j, 60 * j + 60) if k % 100 != 50]
        assert avg[j][0] == iso(T0 + 60 * j * S)
        assert avg[j][1] == pytest.approx(sum(level(k) for k in good) / len(good), rel=1e-12)
    # Part 13 with PercentDataGood 100: Good only where no sample of the interval is Bad, else
    # Uncertain_DataSubNormal; every result carries the HistorianCalculated bit
    for j, (_, _, status) in enumerate(avg):
        clean = all(k % 100 != 50 for k in range(60 * j, min(60 * j + 60, N)))
        assert status.startswith("Good" if clean else "UncertainDataSubNormal"), (j, status)
        assert "HistorianCalculated" in status
