"""The HistoryRead server the ``historian-read`` bench reads from, as its own process.

``python -m benchmarks.histread_server PORT sqlite PATH`` or ``... PORT postgres URL SCHEMA``:
serves the store at ``opc.tcp://127.0.0.1:PORT/tanklab/historian`` with
:func:`historian.history_read.install_history_read`, prints ``ready NS`` (the site namespace's
index) on stdout once it listens, and stops when its stdin closes.
"""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from asyncua import Server

from historian.history_read import install_history_read, site_tag_mapper
from historian.store import HistoryStore
from historian.store.postgres import PostgresStore
from historian.store.sqlite import SQLiteStore

MAX_VALUES = 100_000


async def serve(port: int, store: HistoryStore) -> None:
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}/tanklab/historian")
    ns = await server.register_namespace("urn:tanklab")
    install_history_read(server, store, site_tag_mapper(store, ns), max_values=MAX_VALUES)
    async with server:
        print(f"ready {ns}", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


def main(argv: list[str]) -> int:
    port, kind, *where = argv
    store: HistoryStore = (
        SQLiteStore(Path(where[0])) if kind == "sqlite" else PostgresStore(where[0], schema=where[1])
    )
    try:
        asyncio.run(serve(int(port), store))
    finally:
        store.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
