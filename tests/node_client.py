"""Running the node-opcua clients of ``tests/node`` (an independent OPC UA stack) from tests.

Each script takes its arguments on the command line and the password in ``TANKLAB_PASSWORD``,
and prints one ``RESULT {json}`` line; :func:`run_node_script` returns that JSON with ``rc``, the
script's exit code, added. ``make tools`` installs the pinned node-opcua (tests/node/package-lock.json).
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
from typing import Any

from tanklab_testing.procs import ROOT

NODE = shutil.which("node")
"""The node executable (None: not installed; the tests that need it skip)."""
NODE_DIR = ROOT / "tests" / "node"


async def run_node_script(script: str, *args: str, password: str, bound_s: float = 120.0) -> dict[str, Any]:
    """Run ``tests/node/<script>`` once with ``args``: its result line's JSON plus ``rc``.

    ``bound_s`` bounds a hang (not a speed check); the process is killed on every path.
    """
    assert NODE is not None
    proc = await asyncio.create_subprocess_exec(
        NODE,
        str(NODE_DIR / script),
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        cwd=NODE_DIR,
        env=dict(os.environ, TANKLAB_PASSWORD=password),
    )
    try:
        out, err = await asyncio.wait_for(proc.communicate(), bound_s)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    lines = [ln for ln in out.decode().splitlines() if ln.startswith("RESULT ")]
    assert len(lines) == 1, f"node {script}: no result line (exit {proc.returncode}): {err.decode()[-2000:]}"
    result: dict[str, Any] = json.loads(lines[0].removeprefix("RESULT "))
    result["rc"] = proc.returncode
    return result
