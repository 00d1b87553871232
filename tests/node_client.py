"""Running the node-opcua clients of ``tests/node`` (an independent OPC UA stack) from tests.

Each script takes its arguments on the command line and the password in ``TANKLAB_PASSWORD``,
and prints one ``RESULT {json}`` line; :func:`run_node_script` returns that JSON with ``rc``, the
script's exit code, added. A script that must say when it is ready (``READY``, before the test
drives the process) runs under :func:`node_script`, which reads its lines as they come.
``make tools`` installs the pinned node-opcua (tests/node/package-lock.json).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
from collections.abc import AsyncIterator
from typing import Any

from tanklab_testing.procs import ROOT

NODE = shutil.which("node")
"""The node executable (None: not installed; the tests that need it skip)."""
NODE_DIR = ROOT / "tests" / "node"
LINE_LIMIT = 64 * 1024 * 1024
"""The longest stdout line read [bytes]: a result line may carry a whole history read."""


async def run_node_script(script: str, *args: str, password: str, bound_s: float = 120.0) -> dict[str, Any]:
    """Run ``tests/node/<script>`` once with ``args``: its result line's JSON plus ``rc``.

    ``bound_s`` bounds a hang (not a speed check); the process is killed on every path.
    """
    async with node_script(script, *args, password=password) as run:
        return await run.result(bound_s)


class NodeRun:
    """A running node script (:func:`node_script`): its stdout read line by line."""

    def __init__(self, proc: asyncio.subprocess.Process, script: str) -> None:
        self.proc = proc
        self.script = script
        self._stderr = bytearray()
        self._drain = asyncio.ensure_future(self._read_stderr())

    async def _read_stderr(self) -> None:
        """Keep the script's stderr (its last 4 kB) so a full pipe never blocks it."""
        assert self.proc.stderr is not None
        while chunk := await self.proc.stderr.read(65536):
            self._stderr += chunk
            del self._stderr[:-4096]

    async def line(self, prefix: str, bound_s: float) -> str:
        """The next stdout line starting with ``prefix`` (the lines before it are skipped);
        ``bound_s`` bounds a hang. AssertionError with the script's stderr if it ends first."""
        assert self.proc.stdout is not None

        async def find() -> str:
            assert self.proc.stdout is not None
            while raw := await self.proc.stdout.readline():
                text = raw.decode().rstrip("\n")
                if text.startswith(prefix):
                    return text
            return ""

        got = await asyncio.wait_for(find(), bound_s)
        if not got:
            rc = await asyncio.wait_for(self.proc.wait(), bound_s)
            await asyncio.wait_for(self._drain, bound_s)
            err = self._stderr.decode(errors="replace")[-2000:]
            raise AssertionError(f"node {self.script}: exited {rc} without a {prefix!r} line: {err}")
        return got

    async def result(self, bound_s: float) -> dict[str, Any]:
        """The ``RESULT`` line's JSON plus ``rc``, once the script has exited (bounded)."""
        line = await self.line("RESULT ", bound_s)
        await asyncio.wait_for(self.proc.wait(), bound_s)
        result: dict[str, Any] = json.loads(line.removeprefix("RESULT "))
        result["rc"] = self.proc.returncode
        return result


@contextlib.asynccontextmanager
async def node_script(script: str, *args: str, password: str) -> AsyncIterator[NodeRun]:
    """``tests/node/<script>`` running with ``args`` while the block runs; killed on every path
    if it has not exited by then."""
    assert NODE is not None
    proc = await asyncio.create_subprocess_exec(
        NODE,
        str(NODE_DIR / script),
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        cwd=NODE_DIR,
        env=dict(os.environ, TANKLAB_PASSWORD=password),
        limit=LINE_LIMIT,
    )
    run = NodeRun(proc, script)
    try:
        yield run
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        run._drain.cancel()
