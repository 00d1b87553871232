"""node-opcua, a third-party OPC UA stack, connects to a tanklab server the README's way.

README.md ("Any OPC UA client") and docs/security.md ("Third-party clients") say what a client
must do: take the paths from ``tankctl pki show``, put the CA certificate into its
``trusted/certs`` and the CA's CRL into its ``trusted/crl``, have its own certificate trusted by
the site with ``tankctl pki trust``, then log in with a user name and password on a
Basic256Sha256 SignAndEncrypt endpoint. This test does exactly that with node-opcua (pinned by
tests/node/package-lock.json, installed by ``make tools``) against a real plant server, and
checks each step that the README says is needed is needed: without the CA the client refuses
the server (BadCertificateChainIncomplete), without the CRL too (BadCertificateRevocationUnknown),
without the site trusting the client's certificate the server refuses it
(BadCertificateUntrusted). Issue #21, item 9, saw the first two with a README that did not say so.

Skips only when ``node`` is not installed; node present but ``make tools`` not run is a failure.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import sys
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from helpers import ROOT, free_port, wait_until
from node_client import NODE, NODE_DIR, run_node_script
from plant_sim.runtime import run_plant
from tanklab.config import load_site
from tanklab_io.home import SecurityHome
from tanklab_io.ua_client import resolve
from tanklab_io.ua_security import ClientIdentity, ServerSecurity, secure_client
from tanklab_io.users import Credentials

SCRIPT = NODE_DIR / "read.mjs"
USER, PASSWORD = "alice", "alice-node-opcua-password"
OPENING = 0.37
"""What an asyncua operator writes to Plant.V13.Opening [fraction open] for node-opcua to read back."""

pytestmark = pytest.mark.skipif(
    NODE is None, reason="node is not installed (the node-opcua client test needs node 20+ and `make tools`)"
)


def _require_node_modules() -> None:
    stamp = NODE_DIR / "node_modules" / ".package-lock.json"
    lock = NODE_DIR / "package-lock.json"
    if not stamp.is_file() or stamp.stat().st_mtime < lock.stat().st_mtime:
        pytest.fail(f"{NODE_DIR}/node_modules is missing or older than package-lock.json: run `make tools`")


async def _tankctl(home: Path, *args: str, stdin: str | None = None) -> str:
    """``tankctl ARGS --home HOME`` as a user types it; its stdout (it must exit 0)."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "tankctl",
        *args,
        "--home",
        str(home),
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        cwd=ROOT,
    )
    try:
        out, err = await asyncio.wait_for(proc.communicate(stdin.encode() if stdin else None), 120)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode == 0, f"tankctl {' '.join(args)}: exit {proc.returncode}: {err.decode()}"
    return out.decode()


async def _node_read(url: str, pki_dir: Path, path: str) -> dict[str, Any]:
    """Run the node-opcua client once: its JSON result line plus ``rc`` (its exit code)."""
    return await run_node_script(SCRIPT.name, url, str(pki_dir), USER, path, password=PASSWORD)


@pytest.fixture
def home(tmp_path: Path) -> SecurityHome:
    """A security home of this test's own (the session's is shared by every other test)."""
    return SecurityHome(tmp_path / "home")


@pytest.fixture
async def plant_url(home: SecurityHome):
    _require_node_modules()
    await _tankctl(home.root, "pki", "init")
    login = f"{PASSWORD}\n"
    await _tankctl(home.root, "user", "add", USER, "--role", "Operator", "--password-stdin", stdin=login)
    site = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
    port = free_port()
    stop, ready = asyncio.Event(), asyncio.Event()
    task = asyncio.create_task(
        run_plant(
            site,
            host="127.0.0.1",
            port=port,
            security=ServerSecurity(home),
            stop=stop,
            ready=ready,
            state_file=home.root / "plant-state.json",
        )
    )
    try:
        await wait_until(ready.is_set, 60, what="plant server ready")
        yield f"opc.tcp://127.0.0.1:{port}/tanklab/plant"
    finally:
        stop.set()
        await asyncio.wait_for(task, 20)


async def test_node_opcua_connects_the_readme_way_and_not_without_the_ca_or_crl(
    home: SecurityHome, plant_url: str, tmp_path: Path
) -> None:
    shown = json.loads(await _tankctl(home.root, "pki", "show", "--json"))
    files = {(f["what"], f["format"]): Path(f["path"]) for f in shown["client_files"]}
    ca_pem, crl_pem = files[("CA certificate", "PEM")], files[("CA revocation list", "PEM")]
    trusted_dir = files[("client certificates", "directory")]
    assert ca_pem.read_bytes().startswith(b"-----BEGIN CERTIFICATE-----")
    assert crl_pem.read_bytes().startswith(b"-----BEGIN X509 CRL-----")
    client_pki = tmp_path / "node-opcua-pki"

    # An empty client PKI: node-opcua makes its own certificate, then refuses the server's,
    # whose issuer it does not know.
    first = await _node_read(plant_url, client_pki, "Plant.V13.Opening")
    assert (first["ok"], first["rc"]) == (False, 1)
    assert "BadCertificateChainIncomplete" in first["error"]
    client_cert = Path(first["certificate"])
    assert client_cert == client_pki / "own" / "certs" / "client_certificate.pem"
    assert client_cert.is_file()

    # The CA certificate alone: its CRL is missing.
    (client_pki / "trusted" / "certs").mkdir(parents=True, exist_ok=True)
    shutil.copy(ca_pem, client_pki / "trusted" / "certs" / ca_pem.name)
    no_crl = await _node_read(plant_url, client_pki, "Plant.V13.Opening")
    assert no_crl["ok"] is False and "BadCertificateRevocationUnknown" in no_crl["error"]

    # CA and CRL: the client trusts the server; the site does not trust the client yet.
    (client_pki / "trusted" / "crl").mkdir(parents=True, exist_ok=True)
    shutil.copy(crl_pem, client_pki / "trusted" / "crl" / crl_pem.name)
    untrusted = await _node_read(plant_url, client_pki, "Plant.V13.Opening")
    assert untrusted["ok"] is False and "BadCertificateUntrusted" in untrusted["error"]

    # The site trusts the client's certificate (no server restart), and an asyncua operator
    # writes a value node-opcua must then read.
    said = await _tankctl(home.root, "pki", "trust", str(client_cert))
    assert said.startswith(f"trusted {client_cert} as {trusted_dir}/")
    client = Client(plant_url, timeout=10.0)
    await secure_client(client, ClientIdentity(home, "cli", Credentials(USER, PASSWORD)))
    async with client:
        node = (await resolve(client, ["Plant.V13.Opening"]))["Plant.V13.Opening"]
        await node.write_value(ua.Variant(OPENING, ua.VariantType.Double))
    read = await _node_read(plant_url, client_pki, "Plant.V13.Opening")
    assert read["ok"] is True, read
    assert read["value"] == pytest.approx(OPENING, abs=1e-12)
    assert read["rc"] == 0
