"""Security of the three servers, through real encrypted OPC UA sessions on loopback ports.

Each asyncua 2.1.0 weakness measured in issue #7 has its regression test here: the default
user manager's ``admin`` with any password, anonymous sessions, the unencrypted channel's
plaintext session (upstream issue #1014), missing per-node permissions, non-atomic batches,
client timestamps and Bad status codes in writes, the default transport limits and the 600 s
session timeout. The role matrix is checked cell by cell against the table below, which
restates docs/security.md independently of ``tanklab.tags`` (so a contract change that widens
a role fails here).

The servers run in-process without their scan loops (the matrix needs the address space, not
the dynamics); the test security home comes from conftest.security_home.
"""

from __future__ import annotations

import asyncio
import math
import shutil
from collections.abc import AsyncIterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from asyncua import Client, ua

from helpers import (
    ROOT,
    TEST_PASSWORDS,
    free_port,
    identity,
    server_security,
    session_home,
    wait_until,
)
from plant_sim.plant import PlantSimulator
from plant_sim.server import PlantServer
from plc_emulator.program import PlcProgram
from plc_emulator.server import PlcServer
from supervisor.cycle import SupervisorCore
from supervisor.server import SupervisorServer
from tanklab.config import load_site
from tanklab.enums import LoopMode
from tanklab.tags import Role, Tag, plant_tags, plc_tags, supervisor_tags
from tanklab_io.audit import read_audit
from tanklab_io.pki import init_pki, issue, revoke, self_signed, trust
from tanklab_io.ua import variant
from tanklab_io.ua_security import LIMITS, ClientIdentity, secure_client
from tanklab_io.users import Credentials

SITE = load_site(ROOT / "configs/three_tank_energies_sim.yaml")

OPS = {Role.OPERATOR, Role.ENGINEER}
# The documented matrix (docs/security.md): writable node families and who may write them.
MATRIX: dict[str, set[Role]] = {
    "Plant.T*.Leak": OPS,
    "Plant.T*.Disturbance": OPS,
    "Plant.V*.Opening": OPS,
    "Plant.LT*.Fault": OPS,
    "Plant.LT*.FaultValue": OPS,
    "Plant.P*.Delivered": OPS,  # pump degradation (issue 20): simulation control
    "Plant.P*.Command": {Role.PLC},
    "Plant.Sim.Advance": {Role.PLC},
    "PLC.LIC*.SP": OPS,
    "PLC.LIC*.Mode": OPS | {Role.SUPERVISOR, Role.EXTERNAL},  # those two: AUTO <-> REMOTE only
    "PLC.LIC*.ManualMV": OPS,
    "PLC.LIC*.SPLow": {Role.ENGINEER},
    "PLC.LIC*.SPHigh": {Role.ENGINEER},
    "PLC.LIC*.RemoteMV": {Role.SUPERVISOR, Role.EXTERNAL},  # the one its RemoteSource names
    "PLC.LIC*.RemoteSource": {Role.ENGINEER},
    "PLC.External.Heartbeat": {Role.EXTERNAL},
    "PLC.LIC*.SetGains": {Role.ENGINEER, Role.SUPERVISOR},
    "PLC.Supervisor.Heartbeat": {Role.SUPERVISOR},
    "PLC.Interlock.Reset": OPS,
    "PLC.LIC*.ResetGains": OPS,
    "PLC.LIC*.ReleaseGains": OPS,
    "Supervisor.Mode": {Role.ENGINEER},
}
# Who can open a session on which tier: tier certificates act on the tier below them, and
# observe their own tier (the health probe); anywhere else they get no session.
SESSIONS = {
    "plant": {Role.OBSERVER, Role.OPERATOR, Role.ENGINEER, Role.PLC},
    "plc": {Role.OBSERVER, Role.OPERATOR, Role.ENGINEER, Role.SUPERVISOR, Role.PLC, Role.EXTERNAL},
    "supervisor": {Role.OBSERVER, Role.OPERATOR, Role.ENGINEER, Role.SUPERVISOR},
}
OWN_CERT = {"plc": Role.PLC, "supervisor": Role.SUPERVISOR}
"""The certificate identity that is the tier itself: an Observer there."""


def family(path: str) -> str:
    """``PLC.LIC2.SP`` -> ``PLC.LIC*.SP`` (instance numbers replaced by ``*``)."""
    parts = path.split(".")
    out = []
    for part in parts:
        stem = part.rstrip("0123456789")
        out.append(stem + "*" if stem != part and stem in ("T", "V", "LT", "P", "LIC") else part)
    return ".".join(out)


def identity_of(role: Role) -> ClientIdentity:
    return {
        Role.OBSERVER: identity("observer"),
        Role.OPERATOR: identity("operator"),
        Role.ENGINEER: identity("engineer"),
        Role.SUPERVISOR: identity(tier="supervisor"),
        Role.PLC: identity(tier="plc"),
        Role.EXTERNAL: identity(tier="external"),
    }[role]


OWNED = ("PLC.LIC*.RemoteMV", "PLC.LIC*.Mode")
"""Nodes the External role writes only on a loop handed to it (RemoteSource EXTERNAL): every loop
of a fresh PLC is the supervisor's, so the External identity's write there is refused."""


@dataclass
class Servers:
    urls: dict[str, str]
    plc: PlcServer


async def _serve(tiers: tuple[str, ...]) -> AsyncIterator[Servers]:
    sec = server_security()
    made = {
        "plant": lambda: PlantServer(SITE, PlantSimulator(SITE.plant), "127.0.0.1", free_port(), sec),
        "plc": lambda: PlcServer(SITE, PlcProgram(SITE), "127.0.0.1", free_port(), sec),
        "supervisor": lambda: SupervisorServer(SITE, SupervisorCore(SITE), "127.0.0.1", free_port(), sec),
    }
    started: dict[str, Any] = {}
    try:
        for tier in tiers:
            server = made[tier]()
            await server.start()
            started[tier] = server
        yield Servers({t: s.url for t, s in started.items()}, started["plc"])
    finally:
        for server in started.values():
            await server.stop()


@pytest.fixture
async def servers() -> AsyncIterator[Servers]:
    """All three tiers' servers."""
    async for s in _serve(("plant", "plc", "supervisor")):
        yield s


@pytest.fixture
async def plc_server() -> AsyncIterator[Servers]:
    """The PLC's server alone (most checks need one server only)."""
    async for s in _serve(("plc",)):
        yield s


async def connect(url: str, ident: ClientIdentity) -> Client:
    client = Client(url, timeout=4)
    await secure_client(client, ident)
    await client.connect()
    return client


def status_of(exc: BaseException) -> str:
    return type(exc).__name__


async def write_status(client: Client, tag: Tag, value: Any) -> str:
    idx = await client.get_namespace_index("urn:tanklab")
    node = client.get_node(ua.NodeId(tag.path, idx))
    try:
        await node.write_value(ua.DataValue(variant(tag, value)))
    except ua.UaStatusCodeError as e:
        return status_of(e)
    return "Good"


async def read(client: Client, path: str) -> Any:
    idx = await client.get_namespace_index("urn:tanklab")
    return await client.get_node(ua.NodeId(path, idx)).read_value()


async def call_status(client: Client, tag: Tag, *args: Any) -> str:
    idx = await client.get_namespace_index("urn:tanklab")
    parent = client.get_node(ua.NodeId(tag.parent, idx))
    try:
        await parent.call_method(ua.NodeId(tag.path, idx), *args)
    except ua.UaStatusCodeError as e:
        return status_of(e)
    return "Good"


# --------------------------------------------------------------------------------------------
# Endpoints and channels
# --------------------------------------------------------------------------------------------


async def test_only_encrypted_endpoints_are_offered(servers: Servers) -> None:
    for url in servers.urls.values():
        client = Client(url)
        endpoints = await client.connect_and_get_server_endpoints()
        offered = {(e.SecurityPolicyUri.rsplit("#", 1)[-1], e.SecurityMode) for e in endpoints}
        assert offered == {
            ("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt),
            ("Aes128_Sha256_RsaOaep", ua.MessageSecurityMode.SignAndEncrypt),
        }
        tokens = {t.TokenType for e in endpoints for t in e.UserIdentityTokens}
        assert tokens == {ua.UserTokenType.UserName, ua.UserTokenType.Certificate}


async def test_the_unencrypted_channel_serves_discovery_only(servers: Servers) -> None:
    """Regression, upstream issue #1014: a session on the None channel, even with a valid user
    name and password, must not read, write or call."""
    for url in servers.urls.values():
        client = Client(url, timeout=4)
        client.set_user("engineer")
        client.set_password(TEST_PASSWORDS["engineer"])
        with pytest.raises(ua.UaStatusCodeError) as err:
            await client.connect()
        assert status_of(err.value) == "BadSecurityModeRejected"
        client.disconnect_socket()
    audit = read_audit(servers.plc.tier.audit.path)  # type: ignore[union-attr]
    assert any(r["action"] == "activate" and r["status"] == "BadSecurityModeRejected" for r in audit)


async def test_both_policies_connect(plc_server: Servers) -> None:
    for policy in ("Basic256Sha256", "Aes128Sha256RsaOaep"):
        client = await connect(plc_server.urls["plc"], identity("observer", policy=policy))
        try:
            assert await read(client, "PLC.LIC1.SP") == pytest.approx(SITE.plc.loops[0].setpoint_m)
        finally:
            await client.disconnect()


async def test_anonymous_and_default_admin_are_refused(plc_server: Servers) -> None:
    """Regression: asyncua's default user manager makes ``admin`` with any password an Admin and
    lets anonymous sessions write; here neither gets a session."""
    home = session_home()
    url = plc_server.urls["plc"]
    admin = ClientIdentity(home, "cli", Credentials("admin", "anything-at-all"))
    with pytest.raises(ua.UaStatusCodeError) as err:
        await connect(url, admin)
    assert status_of(err.value) == "BadUserAccessDenied"
    # Anonymous: the CLI's certificate on the channel and no identity token at all.
    client = Client(url, timeout=4)
    client.application_uri = "urn:tanklab:cli"
    await client.set_security_string(
        f"Basic256Sha256,SignAndEncrypt,{home.pki.cert_path('cli')},{home.pki.key_path('cli')}"
    )
    with pytest.raises(ua.UaStatusCodeError) as err:
        await client.connect()
    assert status_of(err.value) in ("BadIdentityTokenRejected", "BadUserAccessDenied")


# --------------------------------------------------------------------------------------------
# Certificates
# --------------------------------------------------------------------------------------------


async def test_untrusted_expired_revoked_and_mismatched_certificates_are_refused(
    plc_server: Servers, tmp_path: Path
) -> None:
    """Each client presents a certificate with a defect and otherwise valid credentials."""
    base = session_home()
    url = plc_server.urls["plc"]
    login = Credentials("engineer", TEST_PASSWORDS["engineer"])

    def home_with(cert: Path, key: Path, name: str) -> ClientIdentity:
        # A private copy of the home whose `cli` identity is the defective certificate.
        root = tmp_path / name
        shutil.copytree(base.root / "pki", root / "pki")
        shutil.copy(cert, root / "pki" / "own" / "cli.der")
        shutil.copy(key, root / "pki" / "private" / "cli.pem")
        from tanklab_io.home import SecurityHome

        return ClientIdentity(SecurityHome(root), "cli", login)

    pki = base.pki
    now = datetime.now(UTC)
    cases = {
        "untrusted": self_signed(tmp_path / "ext", "stranger", "urn:tanklab:cli"),
        "expired": issue(
            pki,
            "expired",
            "urn:tanklab:cli",
            not_before=now - timedelta(days=30),
            not_after=now - timedelta(days=1),
        ),
        "uri": issue(pki, "wronguri", "urn:somebody:else"),
        "revoked": issue(pki, "revoked", "urn:tanklab:cli"),
    }
    revoke(pki, cases["revoked"][0])
    expected = {
        "untrusted": "BadCertificateUntrusted",
        "expired": "BadCertificateTimeInvalid",
        "uri": "BadCertificateUriInvalid",
        "revoked": "BadCertificateRevoked",
    }
    for name, (cert, key) in cases.items():
        with pytest.raises(ua.UaStatusCodeError) as err:
            await connect(url, home_with(cert, key, name))
        assert status_of(err.value) == expected[name], name
    # `tankctl pki trust` of the external certificate lets it in (no restart).
    trust(pki, cases["untrusted"][0])
    client = await connect(url, home_with(*cases["untrusted"], "trusted-now"))
    await client.disconnect()


async def test_session_certificate_must_be_the_channel_certificate(plc_server: Servers) -> None:
    """CreateSession carrying somebody else's (public) certificate is refused."""
    client = Client(plc_server.urls["plc"], timeout=4)
    await secure_client(client, identity("engineer"))
    other = session_home().pki.cert_path("supervisor").read_bytes()
    original = client.security_policy.host_certificate
    await client.connect_socket()
    try:
        await client.send_hello()
        await client.open_secure_channel()
        client.security_policy.host_certificate = other  # what CreateSession will carry
        with pytest.raises(ua.UaStatusCodeError) as err:
            await client.create_session()
        assert status_of(err.value) == "BadCertificateInvalid"
    finally:
        client.security_policy.host_certificate = original
        client.disconnect_socket()


# --------------------------------------------------------------------------------------------
# The role matrix, cell by cell
# --------------------------------------------------------------------------------------------


def _writable(tags: list[Tag]) -> list[Tag]:
    return [t for t in tags if t.writable]


def test_the_contract_matches_the_documented_matrix() -> None:
    tags = plant_tags(SITE) + plc_tags(SITE) + supervisor_tags(SITE)
    seen = set()
    for tag in _writable(tags):
        fam = family(tag.path)
        assert fam in MATRIX, f"{tag.path} is writable but not in the documented matrix"
        assert set(tag.writers) == MATRIX[fam], tag.path
        seen.add(fam)
    assert seen == set(MATRIX)


def _valid_args(tag: Tag) -> list[Any]:
    if tag.name == "Advance":
        return [1.0, [0.0] * len(SITE.pump_names)]
    if tag.name == "SetGains":
        g = SITE.plc.loops[0].gains
        return [g.kp, g.ki, g.kd]
    return []


async def test_every_cell_of_the_role_matrix(servers: Servers) -> None:
    builders = {"plant": plant_tags, "plc": plc_tags, "supervisor": supervisor_tags}
    cells = 0
    for tier, url in servers.urls.items():
        tags = _writable(builders[tier](SITE))
        for role in Role:
            if role not in SESSIONS[tier]:
                with pytest.raises(ua.UaStatusCodeError) as err:
                    await connect(url, identity_of(role))
                assert status_of(err.value) == "BadUserAccessDenied", (tier, role)
                cells += 1
                continue
            client = await connect(url, identity_of(role))
            acting = Role.OBSERVER if OWN_CERT.get(tier) == role else role
            try:
                for tag in tags:
                    allowed = acting in MATRIX[family(tag.path)]
                    if acting is Role.EXTERNAL and family(tag.path) in OWNED:
                        allowed = False
                    if tag.kind == "method":
                        status = await call_status(client, tag, *_valid_args(tag))
                        if allowed:
                            assert status != "BadUserAccessDenied", (tier, role.value, tag.path)
                        else:
                            assert status == "BadUserAccessDenied", (tier, role.value, tag.path)
                    else:
                        old = await read(client, tag.path)
                        status = await write_status(client, tag, old)  # the same value back
                        assert status == ("Good" if allowed else "BadUserAccessDenied"), (
                            tier,
                            role.value,
                            tag.path,
                            status,
                        )
                        assert await read(client, tag.path) == old
                    cells += 1
            finally:
                await client.disconnect()
    n_roles = len(Role)
    assert cells >= n_roles * 3  # every tier x role cell was visited


async def test_the_supervisor_switches_modes_only_between_auto_and_remote(plc_server: Servers) -> None:
    url = plc_server.urls["plc"]
    (mode,) = [t for t in plc_tags(SITE) if t.path == "PLC.LIC1.Mode"]
    sup = await connect(url, identity(tier="supervisor"))
    eng = await connect(url, identity("engineer"))
    try:
        assert await read(sup, "PLC.LIC1.Mode") == int(LoopMode.AUTO)
        assert await write_status(sup, mode, int(LoopMode.REMOTE)) == "Good"
        assert await write_status(sup, mode, int(LoopMode.AUTO)) == "Good"
        assert await write_status(sup, mode, int(LoopMode.MANUAL)) == "BadUserAccessDenied"
        assert await read(sup, "PLC.LIC1.Mode") == int(LoopMode.AUTO)
        # Out of MANUAL (an operator's choice) the supervisor may not take the loop.
        assert await write_status(eng, mode, int(LoopMode.MANUAL)) == "Good"
        assert await write_status(sup, mode, int(LoopMode.REMOTE)) == "BadUserAccessDenied"
        assert await read(sup, "PLC.LIC1.Mode") == int(LoopMode.MANUAL)
    finally:
        await sup.disconnect()
        await eng.disconnect()


async def test_engineer_program_limits_bound_the_operator(plc_server: Servers) -> None:
    tags = {t.path: t for t in plc_tags(SITE)}
    url = plc_server.urls["plc"]
    eng = await connect(url, identity("engineer"))
    op = await connect(url, identity("operator"))
    try:
        sp = await read(op, "PLC.LIC1.SP")
        assert await write_status(eng, tags["PLC.LIC1.SPHigh"], sp + 0.05) == "Good"
        assert await write_status(op, tags["PLC.LIC1.SP"], sp + 0.08) == "BadOutOfRange"
        assert await write_status(op, tags["PLC.LIC1.SP"], sp + 0.04) == "Good"
        # A limit that would leave the current SP outside is refused whole.
        assert await write_status(eng, tags["PLC.LIC1.SPHigh"], sp) == "BadOutOfRange"
        assert await read(op, "PLC.LIC1.SPHigh") == pytest.approx(sp + 0.05)
        assert await write_status(op, tags["PLC.LIC1.SPHigh"], sp + 0.1) == "BadUserAccessDenied"
    finally:
        await eng.disconnect()
        await op.disconnect()


# --------------------------------------------------------------------------------------------
# Logins
# --------------------------------------------------------------------------------------------


async def test_five_failed_logins_lock_the_user_for_60_s(plc_server: Servers) -> None:
    manager = plc_server.plc.tier.server.iserver.user_manager  # type: ignore[union-attr]
    now = [1000.0]
    manager.clock = lambda: now[0]  # model the 60 s without waiting for them
    url = plc_server.urls["plc"]
    wrong = ClientIdentity(session_home(), "cli", Credentials("operator", "not-the-password"))
    for _ in range(5):
        with pytest.raises(ua.UaStatusCodeError):
            await connect(url, wrong)
    with pytest.raises(ua.UaStatusCodeError) as err:
        await connect(url, identity("operator"))  # the right password, but locked
    assert status_of(err.value) == "BadUserAccessDenied"
    other = await connect(url, identity("engineer"))  # other users are not affected
    await other.disconnect()
    now[0] += 59.0
    with pytest.raises(ua.UaStatusCodeError):
        await connect(url, identity("operator"))
    now[0] += 1.0
    client = await connect(url, identity("operator"))
    await client.disconnect()
    refused = [
        r
        for r in read_audit(plc_server.plc.tier.audit.path)
        if r["action"] == "activate" and r["user"] == "operator"
    ]
    assert len(refused) >= 7 and {r["new"] for r in refused} >= {"bad user name or password", "locked"}


# --------------------------------------------------------------------------------------------
# Validation, batches, audit
# --------------------------------------------------------------------------------------------


async def test_client_timestamps_are_ignored_and_bad_status_writes_refused(plc_server: Servers) -> None:
    client = await connect(plc_server.urls["plc"], identity("operator"))
    try:
        idx = await client.get_namespace_index("urn:tanklab")
        node = client.get_node(ua.NodeId("PLC.LIC1.SP", idx))
        future = datetime.now(UTC) + timedelta(days=365)
        await node.write_value(ua.DataValue(ua.Variant(0.3, ua.VariantType.Double), SourceTimestamp=future))
        dv = await node.read_data_value()
        assert dv.Value.Value == 0.3 and dv.SourceTimestamp < future - timedelta(days=300)
        with pytest.raises(ua.UaStatusCodeError) as err:
            await node.write_value(
                ua.DataValue(
                    ua.Variant(0.35, ua.VariantType.Double),
                    StatusCode=ua.StatusCode(ua.StatusCodes.Uncertain),
                )
            )
        assert status_of(err.value) == "BadWriteNotSupported"
        assert await node.read_value() == 0.3
    finally:
        await client.disconnect()


async def test_batch_semantics_hold_in_100_of_100_trials(plc_server: Servers) -> None:
    """A batch is judged item by item: good items stored, refused items keep their old value,
    each item's status its own (docs/security.md). Random batches of 2..6 items."""
    tags = {t.path: t for t in plc_tags(SITE)}
    rng = np.random.default_rng(7)
    client = await connect(plc_server.urls["plc"], identity("operator"))
    try:
        idx = await client.get_namespace_index("urn:tanklab")
        paths = ["PLC.LIC1.SP", "PLC.LIC2.SP", "PLC.LIC1.ManualMV", "PLC.LIC2.ManualMV", "PLC.LIC1.RemoteMV"]
        for trial in range(100):
            chosen = [paths[i] for i in rng.integers(0, len(paths), rng.integers(2, 7))]
            chosen = list(dict.fromkeys(chosen))  # one write per node in a batch
            before = {p: await read(client, p) for p in chosen}
            values, expect = [], {}
            for p in chosen:
                t = tags[p]
                a, b = t.eu_range  # type: ignore[misc]
                kind = rng.integers(0, 4)
                if p.endswith("RemoteMV"):
                    v, st = float(rng.uniform(a, b)), "BadUserAccessDenied"  # not the operator's
                elif kind == 0:
                    v, st = float(rng.uniform(a, b)), "Good"
                elif kind == 1:
                    v, st = float(b + 1.0), "BadOutOfRange"
                elif kind == 2:
                    v, st = math.nan, "BadOutOfRange"
                else:
                    v, st = float(a - 1.0), "BadOutOfRange"
                values.append(ua.DataValue(ua.Variant(v, ua.VariantType.Double)))
                expect[p] = (st, v)
            statuses = await client.uaclient.write_attributes(
                [ua.NodeId(p, idx) for p in chosen], values, ua.AttributeIds.Value
            )
            for p, s in zip(chosen, statuses, strict=True):
                st, v = expect[p]
                assert s.name == st, (trial, p, v, s.name)
                after = await read(client, p)
                assert after == (v if st == "Good" else before[p]), (trial, p)
    finally:
        await client.disconnect()


async def test_every_write_and_call_is_audited_and_raised_as_an_event(plc_server: Servers) -> None:
    url = plc_server.urls["plc"]
    client = await connect(url, identity("operator"))
    received: list[Any] = []

    class Handler:
        def event_notification(self, event: Any) -> None:
            received.append(event)

    try:
        idx = await client.get_namespace_index("urn:tanklab")
        etype = await client.nodes.base_event_type.get_child(f"{idx}:TanklabAuditEventType")
        sub = await client.create_subscription(50, Handler())
        await sub.subscribe_events(client.nodes.server, etype)
        tags = {t.path: t for t in plc_tags(SITE)}
        assert await write_status(client, tags["PLC.LIC1.SP"], 0.31) == "Good"
        assert await write_status(client, tags["PLC.LIC1.SP"], 9.0) == "BadOutOfRange"
        assert await write_status(client, tags["PLC.LIC1.RemoteMV"], 0.0) == "BadUserAccessDenied"
        assert await call_status(client, tags["PLC.LIC1.SetGains"], 1e-3, 1e-5, 0.0) == "BadUserAccessDenied"
        await wait_until(lambda: len(received) >= 4, 10, what="four audit events")
    finally:
        await client.disconnect()
    records = read_audit(plc_server.plc.tier.audit.path)  # type: ignore[union-attr]
    mine = [
        (r["action"], r["node"], r["status"], r["user"], r["role"])
        for r in records
        if r["user"] == "operator"
    ]
    assert ("write", "PLC.LIC1.SP", "Good", "operator", "Operator") in mine
    assert ("write", "PLC.LIC1.SP", "BadOutOfRange", "operator", "Operator") in mine
    assert ("write", "PLC.LIC1.RemoteMV", "BadUserAccessDenied", "operator", "Operator") in mine
    assert ("call", "PLC.LIC1.SetGains", "BadUserAccessDenied", "operator", "Operator") in mine
    good = next(
        r for r in records if r["node"] == "PLC.LIC1.SP" and r["status"] == "Good" and r["new"] == 0.31
    )
    assert good["old"] == pytest.approx(SITE.plc.loops[0].setpoint_m)
    statuses = sorted(e.Status for e in received[:4])
    assert statuses == sorted(["Good", "BadOutOfRange", "BadUserAccessDenied", "BadUserAccessDenied"])
    assert plc_server.plc.tier.audit.path.stat().st_mode & 0o777 == 0o600  # type: ignore[union-attr]


# --------------------------------------------------------------------------------------------
# Transport limits
# --------------------------------------------------------------------------------------------


async def test_session_timeout_is_capped(plc_server: Servers) -> None:
    client = Client(plc_server.urls["plc"], timeout=4)
    client.session_timeout = 600_000  # what asyncua's subscriptions-outlive-TCP case relied on
    await secure_client(client, identity("observer"))
    await client.connect()
    try:
        assert client.session_timeout <= LIMITS.max_session_timeout_ms
    finally:
        await client.disconnect()


async def test_oversized_and_malformed_chunks_close_the_connection(plc_server: Servers) -> None:
    host, port = "127.0.0.1", int(plc_server.urls["plc"].split(":")[2].split("/")[0])
    too_big = LIMITS.chunk_bytes + 1
    for payload in (
        b"HEL" + b"F" + too_big.to_bytes(4, "little") + b"\0" * 64,  # chunk above the limit
        b"XYZF" + (32).to_bytes(4, "little") + b"\0" * 24,  # unknown message type
        b"MSGF" + (4).to_bytes(4, "little"),  # size below the header
    ):
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(payload)
        await writer.drain()
        data = await asyncio.wait_for(reader.read(), 10)  # EOF: the server closed it
        assert data == b""
        writer.close()
    # Still serving.
    client = await connect(plc_server.urls["plc"], identity("observer"))
    await client.disconnect()


async def test_parked_sockets_do_not_lock_out_a_client_and_are_closed(plc_server: Servers) -> None:
    host, port = "127.0.0.1", int(plc_server.urls["plc"].split(":")[2].split("/")[0])
    parked = [await asyncio.open_connection(host, port) for _ in range(200)]
    try:
        client = await connect(plc_server.urls["plc"], identity("observer"))
        assert await read(client, "PLC.LIC1.SP") is not None
        await client.disconnect()
        # Each parked socket sees EOF once the server's handshake limit closed it.
        eofs = await asyncio.wait_for(asyncio.gather(*(reader.read() for reader, _ in parked)), 30)
        assert eofs == [b""] * len(parked)
    finally:
        for _, writer in parked:
            writer.close()


def test_limits_are_tight() -> None:
    assert LIMITS.message_bytes <= 1 << 20
    assert LIMITS.handshake_s == 2.0
    assert LIMITS.max_session_timeout_ms <= 60_000
    assert LIMITS.max_connections >= 200 + 8  # 200 parked sockets must leave room


async def test_a_fresh_pki_is_complete_and_private(tmp_path: Path) -> None:
    pki = init_pki(tmp_path / "pki")
    assert pki.exists()
    for name in ("plant", "plc", "supervisor", "cli"):
        assert pki.key_path(name).stat().st_mode & 0o777 == 0o600


async def test_publishing_intervals_are_clamped(plc_server: Servers) -> None:
    """Regression: asyncua takes any publishing interval (1 us took a core per subscription)."""
    client = await connect(plc_server.urls["plc"], identity("observer"))
    try:
        params = ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=0.001,
            RequestedLifetimeCount=300,
            RequestedMaxKeepAliveCount=10,
            MaxNotificationsPerPublish=0,
            PublishingEnabled=True,
            Priority=0,
        )
        result = await client.uaclient.create_subscription(params, lambda _: None)
        assert result.RevisedPublishingInterval >= LIMITS.min_publishing_interval_ms
    finally:
        await client.disconnect()
