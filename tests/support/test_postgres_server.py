"""tanklab_testing.postgres: a real cluster starts as the postgres user, answers, and is gone
(process and files) after stop; missing binaries fail loudly, naming `make tools`."""

from __future__ import annotations

import os
from pathlib import Path

import psycopg
import pytest

from tanklab_testing.postgres import PostgresMissingError, PostgresServer, pg_bin


def test_a_cluster_serves_on_loopback_and_leaves_nothing_behind() -> None:
    server = PostgresServer.start()
    try:
        pid = server._postmaster_pid()
        assert pid is not None
        with psycopg.connect(server.url) as conn:
            row = conn.execute("SELECT current_setting('listen_addresses'), current_user").fetchone()
            assert row == ("127.0.0.1", "postgres")
            (version,) = conn.execute("SHOW server_version_num").fetchone()  # type: ignore[misc]
            assert int(version) // 10000 == 15
        if os.geteuid() == 0:
            assert server.data.stat().st_uid != 0  # run as the postgres user, not as root
    finally:
        server.stop()
    assert not server.root.exists()
    assert not Path(f"/proc/{pid}").exists() or "postgres" not in Path(f"/proc/{pid}/cmdline").read_text()
    server.stop()  # twice is harmless


def test_missing_binaries_fail_naming_make_tools(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TANKLAB_PG_BIN", str(tmp_path))
    with pytest.raises(PostgresMissingError, match="make tools"):
        pg_bin()
    with pytest.raises(PostgresMissingError, match="initdb"):
        PostgresServer.start()
