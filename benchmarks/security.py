"""Robustness of the secured PLC server: protocol fuzz, write flood, freeze-then-crash, parked sockets.

Issue #7, item 7. Every measurement runs real tier processes (``python -m tankctl plant | plc |
supervisor``, :mod:`benchmarks.procs`) on free loopback ports, secured with a security home made
for the run in a temporary directory (a PKI and one engineer login, ``--home``). The CI-sized
tests in ``tests/robustness/`` drive the same case generators, oracles and post-conditions with
small sizes; the functions here are the full-size runs of ``make bench``.

:func:`fuzz` (``n_cases``, ``seed``)
    A seeded protocol fuzz of the PLC server while it scans against a real plant. Raw-transport
    cases, each on a fresh socket (:data:`RAW_KINDS`): random bytes; Hello messages with absurd
    buffer sizes, URL lengths and length prefixes that lie; MSG / OPN / CLO with bogus channel
    ids; chunk headers announcing more than 64 KiB or less than 8 bytes; unknown message types;
    truncated frames; valid Hello + OpenSecureChannel bytes with flipped bytes; OPN with
    garbage certificates or unknown policies; and, on an opened unencrypted (discovery) channel,
    more than 4 chunks per message, more than 16 queued messages, and requests with flipped
    bytes. Typed cases through authenticated sessions (the engineer's login and the supervisor's
    tier identity, :data:`SESSION_KINDS`): writes of random Variant types (scalars, arrays,
    matrices, NaN, infinities, out-of-EURange values, non-members of enumerations, non-Good
    status codes, client timestamps, index ranges, attributes other than Value) to every PLC
    node, its EURange / EnumStrings / EngineeringUnits properties, standard nodes and unknown
    nodes; method calls with random arguments (counts, types, NaN, outside the gain box, on the
    wrong object); node-management requests (AddNodes, DeleteNodes, AddReferences,
    DeleteReferences); subscriptions with absurd parameters.

    Oracles: a write or call the contract must refuse (:func:`write_must_refuse`,
    :func:`call_must_refuse`, written independently of ``tanklab_io.ua``'s checks) that answers
    Good is a violation, and so is a node-management request that succeeds or a raw case of a
    kind the transport limits must close (:data:`MUST_CLOSE`) that the server leaves open.
    Post-conditions (:func:`post_conditions`): the server still serves a new secure session;
    a Read is Good; no stored value of any PLC node lies outside its EURange, is not finite, is
    of the wrong type or outside its enumeration, and the EURange properties are unchanged; the
    scan counter still advances.

:func:`flood` (``seconds``, ``clients``)
    ``clients`` engineer sessions write as fast as they can (one request in flight each) a mix of
    valid and invalid values to SP, ManualMV and Mode (valid writes keep the loops regulating:
    SP within 2 cm of 0.4 m / 0.2 m, Mode AUTO) while the PLC scans at speed 5 (200 ms of wall
    time per scan). Reported: writes per second accepted and refused (by status), overruns
    before and after, the largest ``LastScanDuration`` seen, the PLC's model time against the
    plant's over the flood (a PLC that skips deadlines falls behind), scan lateness from the
    PLC's stop line.

:func:`freeze_crash` (``repeats``)
    Plant, PLC and supervisor at speed 5. Each repeat: SIGSTOP the PLC for 3 s, SIGCONT, wait for
    recovery, SIGKILL it and restart it on the same port with the same retentive-memory file,
    wait for recovery. The supervisor is sampled every 50 ms: a *silent stall* is a PLC absence
    (freeze or crash) during which ``Supervisor.PlcConnected`` never went False, or a recovery
    that does not come within 60 s (``PlcConnected`` True, ``Supervisor.Cycle`` advancing past
    its value before the fault and ``PLC.Supervisor.Alive`` True). Recovery times in wall
    seconds: from SIGCONT, and from the restarted PLC's banner.

:func:`idle_sockets` (``n``)
    ``n`` raw TCP sockets parked on the PLC's port without a Hello; then a legitimate secure
    client connects and reads (target <= 1 s, reported), and every parked socket should be
    closed by the server after the 2 s handshake limit (time to closure reported).

:func:`login_storm` (``n``, ``concurrency``)
    Failed password logins with unknown user names, ``concurrency`` at a time, against the PLC
    at speed 5; the scan overruns they cause are reported (there were 2 to 4 while the scrypt
    check ran inside the server's event loop; it now runs in a worker thread).

Every stack starts at the default config's operating point (:func:`site_config`): the loops
regulate from the first scan instead of filling empty tanks. :func:`run_all` and
:func:`markdown` give ``benchmarks/run.py`` the results and a section of ``docs/benchmarks.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import signal
import struct
import tempfile
import time
import uuid
from collections import Counter
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from asyncua import Client, ua
from asyncua.common.connection import SecureConnection, TransportLimits
from asyncua.common.utils import Buffer
from asyncua.crypto.security_policies import SecurityPolicyNone
from asyncua.ua.ua_binary import header_from_binary, struct_from_binary, struct_to_binary, uatcp_to_binary

from benchmarks.common import ENERGIES, Summary, fmt, load
from benchmarks.procs import Proc, free_base_port
from benchmarks.stack import LATENESS_RE
from plant_sim.linearize import operating_point
from plant_sim.models import TankNetwork, default_inputs
from tanklab.config import SiteConfig
from tanklab.enums import LoopMode
from tanklab.tags import DataType, Role, Tag, plc_tags
from tanklab_io.home import SecurityHome
from tanklab_io.home import provision as provision_home
from tanklab_io.ua import namespace_index, new_client, quiet_disconnect
from tanklab_io.ua_security import LIMITS, ClientIdentity, secure_client
from tanklab_io.users import Credentials, load_credentials

HOST = "127.0.0.1"
SITE = load(ENERGIES)
PLC_TAGS = plc_tags(SITE)
NONE_POLICY_URI = "http://opcfoundation.org/UA/SecurityPolicy#None"
SECURE_POLICY_URIS = (
    "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256",
    "http://opcfoundation.org/UA/SecurityPolicy#Aes128_Sha256_RsaOaep",
)
RAW_KINDS = (
    "garbage",
    "hello",
    "chunk_size",
    "unknown_type",
    "bogus_channel",
    "truncated",
    "mutated",
    "bad_open",
    "chunk_count",
    "queue_flood",
    "mutated_request",
)
"""Raw-transport case kinds, each on a fresh TCP connection."""
MUST_CLOSE = frozenset({"chunk_size", "unknown_type", "chunk_count", "queue_flood"})
"""Kinds the transport limits must answer by closing the connection (bad chunk header type or
size, more than 4 chunks in a message, more than 16 queued messages)."""
SESSION_KINDS = ("write", "call", "node_management", "subscription")
"""Typed case kinds, through an authenticated session."""
RAW_SHARE = 0.6
"""Share of raw-transport cases among all cases (the rest go through sessions)."""


# ----------------------------------------------------------------------------------------------
# Logins
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Logins:
    """A security home and the passwords of its login users (user name -> credentials)."""

    home: SecurityHome
    credentials: dict[str, Credentials]

    def identity(self, who: str) -> ClientIdentity:
        """A login user's identity, or a tier's (``plc``, ``supervisor``) certificate identity."""
        if who in ("plc", "supervisor"):
            return ClientIdentity(self.home, who)
        return ClientIdentity(self.home, "cli", self.credentials[who])


ROLE_OF = {"engineer": Role.ENGINEER, "operator": Role.OPERATOR, "supervisor": Role.SUPERVISOR}
"""The role a fuzz session acts in on the PLC."""


def provision(root: Path) -> Logins:
    """A fresh security home at ``root``: the PKI and one engineer with a random password
    (what ``tankctl up`` provisions on first run)."""
    home = SecurityHome(root)
    provision_home(home)
    creds = load_credentials(home.credentials_file, {})
    assert creds is not None, f"{home.credentials_file}: not written by provision"
    return Logins(home, {creds.username: creds})


@contextlib.asynccontextmanager
async def session(url: str, logins: Logins, who: str, timeout_s: float = 10.0) -> AsyncIterator[Client]:
    """A connected, encrypted and authenticated client of ``url`` acting as ``who``."""
    client = new_client(url, timeout_s)
    await secure_client(client, logins.identity(who))
    async with client:
        yield client


# ----------------------------------------------------------------------------------------------
# Raw transport: frames (pure) and one exchange per case
# ----------------------------------------------------------------------------------------------

_U32 = struct.Struct("<I")
_EPOCH = datetime(2024, 1, 1, tzinfo=UTC)


def _u32(x: int) -> bytes:
    return _U32.pack(x & 0xFFFFFFFF)


def _pick(rng: np.random.Generator, items: Sequence[Any]) -> Any:
    return items[int(rng.integers(len(items)))]


def _frame(mtype: bytes, payload: bytes, *, chunk: bytes = b"F", size: int | None = None) -> bytes:
    """An OPC UA TCP frame: 3-byte type, chunk type, size (the true one unless given), payload."""
    return mtype + chunk + _u32(8 + len(payload) if size is None else size) + payload


def _ua_string(text: bytes | None, *, length: int | None = None) -> bytes:
    """An OPC UA String / ByteString: Int32 length (-1 = null; may lie when given) and bytes."""
    if text is None:
        return struct.pack("<i", -1)
    return struct.pack("<i", len(text) if length is None else length) + text


def hello(
    url: str = "",
    *,
    version: int = 0,
    recv: int = 65535,
    send: int = 65535,
    max_message: int = 0,
    max_chunks: int = 0,
) -> bytes:
    """A well-formed Hello frame with the given limits."""
    msg = ua.Hello(
        ProtocolVersion=version,
        ReceiveBufferSize=recv,
        SendBufferSize=send,
        MaxMessageSize=max_message,
        MaxChunkCount=max_chunks,
        EndpointUrl=url,
    )
    return uatcp_to_binary(ua.MessageType.Hello, msg)


def open_request(
    *,
    policy_uri: str = NONE_POLICY_URI,
    certificate: bytes | None = None,
    mode: ua.MessageSecurityMode = ua.MessageSecurityMode.None_,
    channel_id: int = 0,
    sequence: int = 1,
    request_id: int = 1,
) -> bytes:
    """An OpenSecureChannel frame (unencrypted body: right for the None policy only)."""
    req = ua.OpenSecureChannelRequest()
    req.RequestHeader.Timestamp = _EPOCH  # a fixed stamp: the same seed gives the same bytes
    req.Parameters.ClientProtocolVersion = 0
    req.Parameters.RequestType = ua.SecurityTokenRequestType.Issue
    req.Parameters.SecurityMode = mode
    req.Parameters.ClientNonce = b""
    req.Parameters.RequestedLifetime = 60_000
    security = _ua_string(policy_uri.encode()) + _ua_string(certificate) + _ua_string(None)
    payload = _u32(channel_id) + security + _u32(sequence) + _u32(request_id) + struct_to_binary(req)
    return _frame(b"OPN", payload)


def _random_bytes(rng: np.random.Generator, n: int) -> bytes:
    return rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()


def _flip(rng: np.random.Generator, data: bytes, k: int, start: int = 0) -> bytes:
    """``data`` with ``k`` random bytes at or after ``start`` XOR-ed with a random non-zero mask."""
    buf = bytearray(data)
    if len(buf) <= start:
        return bytes(buf)
    for _ in range(k):
        i = int(rng.integers(start, len(buf)))
        buf[i] ^= int(rng.integers(1, 256))
    return bytes(buf)


_ABSURD_U32 = (0, 1, 7, 8, 1024, 8191, 8192, 65535, 65536, 2**31 - 1, 2**31, 2**32 - 1)


@dataclass(frozen=True)
class RawCase:
    """One raw-transport case: what to send, in steps.

    ``steps``: byte strings sent in order; before each step after the first the case reads the
    server's answer to the previous one (up to ``answer_s``) when ``await_answers`` is set.
    ``open_channel``: first open an unencrypted channel properly (Hello, OpenSecureChannel) and
    then call ``after_open(connection)`` for the steps (they need the channel and token ids).
    ``half_close``: shut down the sending side after the last step.
    """

    kind: str
    steps: tuple[bytes, ...] = ()
    await_answers: bool = False
    half_close: bool = False
    after_open: Callable[[SecureConnection], list[bytes]] | None = None


def _request_bytes(conn: SecureConnection, request: Any, request_id: int) -> bytes:
    return conn.message_to_binary(struct_to_binary(request), ua.MessageType.SecureMessage, request_id)


def raw_case(kind: str, rng: np.random.Generator, url: str) -> RawCase:
    """A random case of ``kind`` (pure: the same generator state gives the same case)."""
    if kind == "garbage":
        n = int(_pick(rng, (1, 3, 7, 8, 12, 64, 512, 4096)))
        data = _random_bytes(rng, n)
        if rng.random() < 0.5 and n >= 8:  # a known type in front, the rest random
            data = _pick(rng, (b"HELF", b"MSGF", b"OPNF", b"CLOF", b"ACKF", b"ERRF")) + data[4:]
        return RawCase(kind, (data,))
    if kind == "hello":
        fields = [int(_pick(rng, _ABSURD_U32)) for _ in range(5)]
        choice = int(rng.integers(4))
        if choice == 0:  # a long URL (possibly longer than a chunk)
            n = int(_pick(rng, (0, 255, 4096, 65000, 70000)))
            body = b"".join(_u32(f) for f in fields) + _ua_string(b"u" * n)
        elif choice == 1:  # the URL's length prefix lies
            lie = int(_pick(rng, (-2, -1, 1 << 20, 2**31 - 1, 5)))
            body = b"".join(_u32(f) for f in fields) + _ua_string(b"opc.tcp://x", length=lie)
        elif choice == 2:  # invalid UTF-8
            body = b"".join(_u32(f) for f in fields) + _ua_string(_random_bytes(rng, 32))
        else:
            return RawCase(
                kind,
                (
                    hello(
                        url,
                        **dict(
                            zip(("version", "recv", "send", "max_message", "max_chunks"), fields, strict=True)
                        ),
                    ),
                ),
            )
        return RawCase(kind, (_frame(b"HEL", body),))
    if kind == "chunk_size":
        size = int(
            _pick(rng, (0, 1, 7, LIMITS.chunk_bytes + 1, LIMITS.chunk_bytes + 1000, 1 << 20, 2**32 - 1))
        )
        mtype = _pick(rng, (b"HEL", b"MSG", b"OPN", b"CLO"))
        bad = _frame(mtype, _random_bytes(rng, int(rng.integers(4, 64))), size=size)
        if rng.random() < 0.5:  # after a valid Hello and its Acknowledge
            return RawCase(kind, (hello(url), bad), await_answers=True)
        return RawCase(kind, (bad,))
    if kind == "unknown_type":
        letters = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz\x00\xff"
        while True:
            mtype = bytes(int(_pick(rng, letters)) for _ in range(3))
            if mtype not in (b"HEL", b"ACK", b"ERR", b"RHE", b"OPN", b"CLO", b"MSG"):
                break
        bad = _frame(mtype, _random_bytes(rng, int(rng.integers(4, 128))))
        if rng.random() < 0.5:
            return RawCase(kind, (hello(url), bad), await_answers=True)
        return RawCase(kind, (bad,))
    if kind == "bogus_channel":
        mtype = _pick(rng, (b"MSG", b"OPN", b"CLO"))
        channel = int(rng.integers(0, 2**32))
        payload = _u32(channel) + _u32(int(rng.integers(0, 2**32))) + _u32(1) + _u32(1)
        payload += _random_bytes(rng, int(rng.integers(0, 256)))
        return RawCase(kind, (hello(url), _frame(mtype, payload)), await_answers=True)
    if kind == "truncated":
        whole = _pick(rng, (hello(url), open_request()))
        cut = int(rng.integers(1, len(whole)))
        return RawCase(kind, (whole[:cut],), half_close=bool(rng.random() < 0.5))
    if kind == "mutated":
        data = hello(url) + open_request()
        return RawCase(kind, (_flip(rng, data, int(rng.integers(1, 9))),))
    if kind == "bad_open":
        choice = int(rng.integers(4))
        if choice == 0:  # a secure policy with a garbage certificate
            frame = open_request(
                policy_uri=_pick(rng, SECURE_POLICY_URIS),
                certificate=_random_bytes(rng, int(_pick(rng, (0, 16, 900, 3000)))),
                mode=ua.MessageSecurityMode.SignAndEncrypt,
            )
        elif choice == 1:  # an unknown policy
            frame = open_request(policy_uri="http://opcfoundation.org/UA/SecurityPolicy#Basic128Rsa15")
        elif choice == 2:  # the None policy asking for SignAndEncrypt
            frame = open_request(mode=ua.MessageSecurityMode.SignAndEncrypt)
        else:  # a garbage policy URI
            frame = open_request(policy_uri=_random_bytes(rng, 40).hex())
        return RawCase(kind, (hello(url), frame), await_answers=True)
    if kind == "chunk_count":
        n = LIMITS.max_chunks + 1 + int(rng.integers(0, 4))

        def too_many_chunks(conn: SecureConnection) -> list[bytes]:
            chunks = []
            sec = conn.security_token
            for i in range(n):
                conn._sequence_number += 1  # the server checks that sequence numbers increase
                payload = _u32(sec.ChannelId) + _u32(sec.TokenId) + _u32(conn._sequence_number) + _u32(7)
                payload += b"\x00" * 64
                chunks.append(_frame(b"MSG", payload, chunk=b"F" if i == n - 1 else b"C"))
            return [b"".join(chunks)]

        return RawCase(kind, after_open=too_many_chunks)
    if kind == "queue_flood":
        n = 4 * LIMITS.max_pending_messages + int(rng.integers(0, 64))

        def many_requests(conn: SecureConnection) -> list[bytes]:
            return [b"".join(_request_bytes(conn, ua.GetEndpointsRequest(), 10 + i) for i in range(n))]

        return RawCase(kind, after_open=many_requests)
    if kind == "mutated_request":
        request = _pick(
            rng,
            (ua.GetEndpointsRequest, ua.FindServersRequest, ua.CreateSessionRequest, ua.ReadRequest),
        )()
        k = int(rng.integers(1, 9))

        def flipped(conn: SecureConnection) -> list[bytes]:
            data = _request_bytes(conn, request, 2)
            return [_flip(rng, data, k, start=24)]  # past the header: the channel checks pass

        return RawCase(kind, after_open=flipped)
    raise ValueError(f"unknown raw case kind {kind!r}")


@dataclass
class RawOutcome:
    """What the server did: the type of its first answer (or ``""``), and whether it closed."""

    kind: str
    reply: str = ""
    closed: bool = False
    close_s: float = math.nan
    failed: str = ""


async def _read_frame(reader: asyncio.StreamReader, timeout_s: float) -> bytes:
    head = await asyncio.wait_for(reader.readexactly(8), timeout_s)
    size = _U32.unpack(head[4:8])[0]
    return head + await asyncio.wait_for(reader.readexactly(size - 8), timeout_s)


async def _open_plain_channel(
    reader: asyncio.StreamReader, writer: asyncio.StreamWriter, url: str, timeout_s: float
) -> SecureConnection:
    """Hello and OpenSecureChannel with the None policy (what discovery clients do)."""
    writer.write(hello(url))
    ack = await _read_frame(reader, timeout_s)
    if ack[:3] != b"ACK":
        raise ConnectionError(f"no Acknowledge: {ack[:3]!r}")
    conn = SecureConnection(SecurityPolicyNone(), TransportLimits())
    req = ua.OpenSecureChannelRequest()
    req.Parameters.RequestType = ua.SecurityTokenRequestType.Issue
    req.Parameters.SecurityMode = ua.MessageSecurityMode.None_
    req.Parameters.ClientNonce = b""
    req.Parameters.RequestedLifetime = 60_000
    writer.write(conn.message_to_binary(struct_to_binary(req), ua.MessageType.SecureOpen, 1))
    data = Buffer(await _read_frame(reader, timeout_s))
    header = header_from_binary(data)
    msg = conn.receive_from_header_and_body(header, data)
    response = struct_from_binary(ua.OpenSecureChannelResponse, msg.body())
    response.ResponseHeader.ServiceResult.check()
    conn.set_channel(response.Parameters, ua.SecurityTokenRequestType.Issue, b"")
    return conn


async def run_raw_case(
    case: RawCase, host: str, port: int, url: str, *, answer_s: float = 0.3, close_wait_s: float = 5.0
) -> RawOutcome:
    """Send ``case`` on a new connection; wait for the answer (``answer_s``), or for the server
    to close the connection (``close_wait_s``) when the case's kind must be closed."""
    out = RawOutcome(case.kind)
    loop = asyncio.get_running_loop()
    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), 10.0)
    except (OSError, TimeoutError) as e:
        out.failed = f"connect: {type(e).__name__}"
        return out
    t0 = loop.time()
    try:
        steps = list(case.steps)
        if case.after_open is not None:
            conn = await _open_plain_channel(reader, writer, url, 10.0)
            steps = case.after_open(conn)
        for i, step in enumerate(steps):
            if i > 0 and case.await_answers:
                with contextlib.suppress(TimeoutError, asyncio.IncompleteReadError):
                    await _read_frame(reader, 10.0)
            writer.write(step)
            await writer.drain()
        if case.half_close and writer.can_write_eof():
            writer.write_eof()
        t0 = loop.time()
        wait = close_wait_s if case.kind in MUST_CLOSE else answer_s
        got = b""
        while True:
            remaining = t0 + wait - loop.time()
            if remaining <= 0:
                break
            try:
                chunk = await asyncio.wait_for(reader.read(65536), remaining)
            except TimeoutError:
                break
            if not chunk:
                out.closed = True
                out.close_s = loop.time() - t0
                break
            got += chunk
        out.reply = got[:3].decode("latin-1") if got else ""
    except (ConnectionError, asyncio.IncompleteReadError):
        out.closed = True
        out.close_s = loop.time() - t0
    except Exception as e:
        out.failed = f"{type(e).__name__}: {e}"
    finally:
        writer.close()
        with contextlib.suppress(Exception):
            await asyncio.wait_for(writer.wait_closed(), 2.0)
    return out


# ----------------------------------------------------------------------------------------------
# Typed cases through a session: values (pure), oracles (pure), one request per case
# ----------------------------------------------------------------------------------------------

VT = ua.VariantType
_INT_RANGES: dict[ua.VariantType, tuple[int, int]] = {
    VT.SByte: (-(2**7), 2**7 - 1),
    VT.Byte: (0, 2**8 - 1),
    VT.Int16: (-(2**15), 2**15 - 1),
    VT.UInt16: (0, 2**16 - 1),
    VT.Int32: (-(2**31), 2**31 - 1),
    VT.UInt32: (0, 2**32 - 1),
    VT.Int64: (-(2**63), 2**63 - 1),
    VT.UInt64: (0, 2**64 - 1),
}
_OTHER_TYPES = (
    VT.Boolean,
    VT.String,
    VT.DateTime,
    VT.Guid,
    VT.ByteString,
    VT.NodeId,
    VT.StatusCode,
    VT.QualifiedName,
    VT.LocalizedText,
    VT.ExtensionObject,
    VT.Null,
)
_VARIANT_OF = {
    DataType.DOUBLE: VT.Double,
    DataType.INT32: VT.Int32,
    DataType.UINT32: VT.UInt32,
    DataType.BOOLEAN: VT.Boolean,
    DataType.STRING: VT.String,
    DataType.DOUBLE_ARRAY: VT.Double,
}


def _number(rng: np.random.Generator, tag: Tag | None) -> float:
    """A float that probes the edges: non-finite, extreme, inside / just outside EURange, enum."""
    lo, hi = tag.eu_range if tag is not None and tag.eu_range is not None else (-1.0, 1.0)
    span = hi - lo or 1.0
    choices: list[Callable[[], float]] = [
        lambda: math.nan,
        lambda: math.inf,
        lambda: -math.inf,
        lambda: 0.0,
        lambda: -0.0,
        lambda: 5e-324,
        lambda: 1e308,
        lambda: -1e308,
        lambda: float(rng.uniform(lo, hi)),
        lambda: float(rng.uniform(lo, hi)),
        lambda: hi + span * 1e-9 + 1e-12,
        lambda: lo - span * 1e-9 - 1e-12,
        lambda: hi * 10 + 1.0,
        lambda: float(int(rng.integers(-1, 5))),
        lambda: float(rng.normal() * 10.0 ** int(rng.integers(-8, 9))),
    ]
    return float(_pick(rng, choices)())


def _integer(rng: np.random.Generator, vt: ua.VariantType, tag: Tag | None) -> int:
    lo, hi = _INT_RANGES[vt]
    pool = [lo, hi, 0, 1, 2, 3, 4, -1, int(rng.integers(-5, 6))]
    if tag is not None and tag.eu_range is not None:
        pool += [int(tag.eu_range[0]), int(tag.eu_range[1]), int(tag.eu_range[1]) + 1]
    x = int(_pick(rng, pool))
    return min(max(x, lo), hi)


def _scalar(rng: np.random.Generator, vt: ua.VariantType, tag: Tag | None) -> Any:
    if vt in _INT_RANGES:
        return _integer(rng, vt, tag)
    if vt == VT.Double:
        return _number(rng, tag)
    if vt == VT.Float:
        x = _number(rng, tag)
        return x if not math.isfinite(x) or abs(x) < 3e38 else math.copysign(3e38, x)
    if vt == VT.Boolean:
        return bool(rng.random() < 0.5)
    if vt == VT.String:
        return _pick(rng, ("", "0.4", "AUTO", "REMOTE", "nan", "\x00", "ü" * 40, "x" * 4000))
    if vt == VT.DateTime:
        return datetime(1601, 1, 2, tzinfo=UTC) + timedelta(days=float(rng.uniform(0, 3_000_000)))
    if vt == VT.Guid:
        return uuid.UUID(bytes=_random_bytes(rng, 16))
    if vt == VT.ByteString:
        return _random_bytes(rng, int(rng.integers(0, 64)))
    if vt == VT.NodeId:
        return ua.NodeId(int(rng.integers(0, 100_000)), int(rng.integers(0, 4)))
    if vt == VT.StatusCode:
        return ua.StatusCode(int(_pick(rng, (0, 0x40000000, 0x80000000, ua.StatusCodes.BadOutOfRange))))
    if vt == VT.QualifiedName:
        return ua.QualifiedName("SP", int(rng.integers(0, 4)))
    if vt == VT.LocalizedText:
        return ua.LocalizedText(_pick(rng, ("AUTO", "REMOTE", "0.4")))
    if vt == VT.ExtensionObject:
        return ua.Range(Low=_number(rng, tag), High=_number(rng, tag))
    return None


def random_variant(rng: np.random.Generator, tag: Tag | None) -> ua.Variant:
    """A Variant of a random type; biased toward the tag's own type so values reach the
    range checks. Scalars, 1-D arrays (0 to 5 items) and 2 x 2 matrices."""
    r = rng.random()
    if tag is not None and tag.data_type is not None and r < 0.45:
        vt = _VARIANT_OF[tag.data_type]
    elif r < 0.75:
        vt = _pick(rng, (VT.Double, VT.Float, VT.Int32, VT.UInt32, VT.Int64, VT.Boolean))
    else:
        vt = _pick(rng, (*_INT_RANGES, *_OTHER_TYPES, VT.Float, VT.Double))
    if vt == VT.Null:
        return ua.Variant()
    shape = rng.random()
    if shape < 0.8:
        return ua.Variant(_scalar(rng, vt, tag), vt)
    if shape < 0.93:
        n = int(rng.integers(0, 6))
        return ua.Variant([_scalar(rng, vt, tag) for _ in range(n)], vt, is_array=True)
    matrix = [[_scalar(rng, vt, tag) for _ in range(2)] for _ in range(2)]
    return ua.Variant(matrix, vt, Dimensions=[2, 2], is_array=True)


def _scalar_of(v: ua.Variant, want: ua.VariantType) -> Any:
    """The scalar value of ``v`` if it is a scalar of type ``want``, else None."""
    if v is None or v.VariantType != want or v.is_array or isinstance(v.Value, list) or v.Dimensions:
        return None
    return v.Value


def write_must_refuse(tag: Tag | None, role: Role, wv: ua.WriteValue) -> bool:
    """Whether the contract requires the server to refuse this write (any refusal status).

    Written from the architecture's rules, not from ``tanklab_io.ua``'s code: only the Value of a
    writable tag, by one of its writers, as a scalar of the tag's type, finite, inside EURange,
    a member of its enumeration, inside a restricted role's allowed set, with a Good (or absent)
    status and no index range may be stored. Everything else (properties, standard nodes,
    unknown nodes, other attributes) must be refused.
    """
    if tag is None or tag.kind != "variable" or tag.data_type is None:
        return True
    if wv.AttributeId != ua.AttributeIds.Value or not tag.writable or role not in tag.writers:
        return True
    if wv.IndexRange:
        return True
    dv = wv.Value
    if dv is None or (dv.StatusCode is not None and not dv.StatusCode.is_good()):
        return True
    x = _scalar_of(dv.Value, _VARIANT_OF[tag.data_type])
    if x is None or tag.data_type == DataType.DOUBLE_ARRAY:
        return True
    if isinstance(x, float) and not math.isfinite(x):
        return True
    if tag.eu_range is not None and not tag.eu_range[0] <= x <= tag.eu_range[1]:
        return True
    if tag.enum is not None and int(x) not in {int(m) for m in tag.enum}:
        return True
    allowed = dict(tag.restricted).get(role)
    return allowed is not None and int(x) not in allowed


def _gain_box(site: SiteConfig, loop: str) -> tuple[tuple[float, float], ...] | None:
    assert site.plc is not None
    for lp in site.plc.loops:
        if lp.name == loop and lp.gain_box is not None:
            box = lp.gain_box
            return (tuple(box.kp), tuple(box.ki), tuple(box.kd))  # type: ignore[return-value]
    return None


def call_must_refuse(
    tag: Tag | None, role: Role, args: Sequence[ua.Variant], site: SiteConfig = SITE
) -> bool:
    """Whether the contract requires the server to refuse this method call.

    Refused: a node that is not a method of the contract, a role not among its writers, the wrong
    number of arguments, an argument not a scalar Double, a gain that is not finite or outside
    the loop's gain box. (An admissible SetGains may still be refused with BadInvalidState while
    the supervisor is not trusted: that is the PLC's state, not the contract.)
    """
    if tag is None or tag.kind != "method" or role not in tag.writers:
        return True
    if len(args) != len(tag.inputs):
        return True
    values = []
    for arg, v in zip(tag.inputs, args, strict=True):
        x = _scalar_of(v, _VARIANT_OF[arg.data_type])
        if x is None:
            return True
        values.append(x)
    if tag.name == "SetGains":
        if not all(math.isfinite(x) for x in values):
            return True
        box = _gain_box(site, tag.path.split(".")[1])
        if box is not None and not all(lo <= x <= hi for x, (lo, hi) in zip(values, box, strict=True)):
            return True
    return False


@dataclass
class SessionTargets:
    """What a fuzz session aims at: NodeIds of every PLC tag, its properties, standard and
    unknown nodes; the tag behind each NodeId (None for the others)."""

    idx: int
    variables: list[tuple[ua.NodeId, Tag | None]]
    methods: list[tuple[ua.NodeId, ua.NodeId, Tag | None]]  # (object, method, tag)

    @classmethod
    def build(cls, idx: int, tags: Sequence[Tag]) -> SessionTargets:
        variables: list[tuple[ua.NodeId, Tag | None]] = []
        methods: list[tuple[ua.NodeId, ua.NodeId, Tag | None]] = []
        objects = sorted({t.parent for t in tags})
        for t in tags:
            node = ua.NodeId(t.path, idx)
            if t.kind == "method":
                methods.append((ua.NodeId(t.parent, idx), node, t))
                # the same method on another object, and the method id as a variable
                methods.append((ua.NodeId(objects[0], idx), node, t))
                variables.append((node, None))
                continue
            variables.append((node, t))
            if t.eu_range is not None:
                variables.append((ua.NodeId(f"{t.path}.EURange", idx), None))
            if t.enum is not None:
                variables.append((ua.NodeId(f"{t.path}.EnumStrings", idx), None))
            if t.unit is not None:
                variables.append((ua.NodeId(f"{t.path}.EngineeringUnits", idx), None))
        for std in (
            ua.ObjectIds.Server_NamespaceArray,
            ua.ObjectIds.Server_ServerStatus_State,
            ua.ObjectIds.Server_ServerStatus_CurrentTime,
            ua.ObjectIds.Server_ServiceLevel,
            ua.ObjectIds.Server_ServerCapabilities_MaxBrowseContinuationPoints,
        ):
            variables.append((ua.NodeId(std), None))
        variables.append((ua.NodeId("PLC.NoSuchNode", idx), None))
        variables.append((ua.NodeId(123456, 7), None))
        variables.append((ua.NodeId(objects[0], idx), None))  # an object, not a variable
        methods.append(
            (ua.NodeId(ua.ObjectIds.Server), ua.NodeId(ua.ObjectIds.Server_GetMonitoredItems), None)
        )
        methods.append((ua.NodeId("PLC.NoSuchObject", idx), ua.NodeId("PLC.NoSuchMethod", idx), None))
        return cls(idx, variables, methods)


_OTHER_ATTRIBUTES = (
    ua.AttributeIds.DisplayName,
    ua.AttributeIds.Description,
    ua.AttributeIds.AccessLevel,
    ua.AttributeIds.UserAccessLevel,
    ua.AttributeIds.DataType,
    ua.AttributeIds.ValueRank,
    ua.AttributeIds.BrowseName,
    ua.AttributeIds.NodeId,
    ua.AttributeIds.Historizing,
)


def random_write(rng: np.random.Generator, targets: SessionTargets) -> tuple[ua.WriteValue, Tag | None]:
    """One WriteValue: a random target (half the time a writable tag, so that values reach the
    range checks and some are stored), mostly its Value, a random Variant and DataValue."""
    writable = [(n, t) for n, t in targets.variables if t is not None and t.writable]
    node, tag = _pick(rng, writable if writable and rng.random() < 0.5 else targets.variables)
    wv = ua.WriteValue()
    wv.NodeId = node
    wv.AttributeId = ua.AttributeIds.Value if rng.random() < 0.9 else _pick(rng, _OTHER_ATTRIBUTES)
    if rng.random() < 0.05:
        wv.IndexRange = _pick(rng, ("0", "1:2", "0:0", "x", "-1"))
    status = ua.StatusCode(ua.StatusCodes.Good)
    if rng.random() < 0.15:
        status = ua.StatusCode(
            int(
                _pick(
                    rng,
                    (
                        0x40000000,
                        0x80000000,
                        ua.StatusCodes.BadOutOfRange,
                        ua.StatusCodes.UncertainLastUsableValue,
                    ),
                )
            )
        )
    stamp = datetime(2000, 1, 1, tzinfo=UTC) + timedelta(days=float(rng.uniform(0, 20_000)))
    wv.Value = ua.DataValue(
        Value=random_variant(rng, tag),
        StatusCode=status,
        SourceTimestamp=stamp if rng.random() < 0.5 else None,
        ServerTimestamp=stamp if rng.random() < 0.1 else None,
    )
    return wv, tag


def random_call(rng: np.random.Generator, targets: SessionTargets) -> tuple[ua.CallMethodRequest, Tag | None]:
    """One method call: a random (object, method), 0 to 5 random arguments (often three
    Doubles probing the gain box)."""
    obj, method, tag = _pick(rng, targets.methods)
    req = ua.CallMethodRequest()
    req.ObjectId = obj
    req.MethodId = method
    if tag is not None and tag.name == "SetGains" and rng.random() < 0.6:
        box = _gain_box(SITE, tag.path.split(".")[1]) or ((0.0, 1.0),) * 3
        args = []
        for lo, hi in box:
            x = float(rng.uniform(lo, hi)) if rng.random() < 0.7 else _number(rng, None)
            args.append(ua.Variant(x, VT.Double))
        req.InputArguments = args
    else:
        req.InputArguments = [random_variant(rng, None) for _ in range(int(rng.integers(0, 6)))]
    return req, tag


@dataclass
class FuzzCounts:
    """Cases per kind, the server's answers, and the violations of the oracles."""

    cases: Counter[str] = field(default_factory=Counter)
    statuses: Counter[str] = field(default_factory=Counter)
    closed: Counter[str] = field(default_factory=Counter)
    replies: Counter[str] = field(default_factory=Counter)
    close_s: list[float] = field(default_factory=list)
    failed: Counter[str] = field(default_factory=Counter)
    violations: list[str] = field(default_factory=list)
    admissible_refused: int = 0
    findings: Counter[str] = field(default_factory=Counter)
    """Accepted requests that break OPC UA but not the tanklab contract (not violations)."""

    def merge_raw(self, out: RawOutcome) -> None:
        self.cases[out.kind] += 1
        if out.failed:
            self.failed[out.kind] += 1
            return
        if out.closed:
            self.closed[out.kind] += 1
            if math.isfinite(out.close_s):
                self.close_s.append(out.close_s)
        self.replies[f"{out.kind}:{out.reply or '-'}"] += 1
        if out.kind in MUST_CLOSE and not out.closed:
            self.violations.append(f"raw {out.kind}: connection left open (reply {out.reply or 'none'})")

    def as_dict(self) -> dict[str, Any]:
        return {
            "cases": dict(self.cases),
            "statuses": dict(self.statuses.most_common()),
            "closed": dict(self.closed),
            "replies": dict(sorted(self.replies.items())),
            "close_s": Summary.of(self.close_s).__dict__,
            "failed": dict(self.failed),
            "violations": list(self.violations),
            "admissible_refused": self.admissible_refused,
            "findings": dict(self.findings),
        }


def _status_name(code: ua.StatusCode | int) -> str:
    value = code.value if isinstance(code, ua.StatusCode) else int(code)
    return ua.StatusCode(value).name


async def _guarded(counts: FuzzCounts, kind: str, coro: Any) -> Any:
    """Run one session request; a service fault counts as a refusal by its status."""
    try:
        return await coro
    except ua.UaStatusCodeError as e:
        counts.statuses[_status_name(e.code)] += 1
        return None
    except (TimeoutError, ConnectionError) as e:
        counts.failed[kind] += 1
        counts.violations.append(f"{kind}: the server did not answer ({type(e).__name__})")
        return None


async def session_case(
    client: Client, role: Role, targets: SessionTargets, rng: np.random.Generator, counts: FuzzCounts
) -> None:
    """One typed case through ``client`` (acting as ``role``), judged by the oracles."""
    r = rng.random()
    if r < 0.7:
        kind = "write"
        items = [random_write(rng, targets) for _ in range(int(_pick(rng, (1, 1, 1, 2, 4))))]
        params = ua.WriteParameters(NodesToWrite=[wv for wv, _ in items])
        counts.cases[kind] += 1
        try:
            results = await _guarded(counts, kind, client.uaclient.write(params))
        except (struct.error, OverflowError, ValueError, TypeError) as e:  # not encodable: not sent
            counts.failed[f"{kind} (not encodable: {type(e).__name__})"] += 1
            return
        for (wv, tag), status in zip(items, results or [], strict=False):
            counts.statuses[_status_name(status)] += 1
            refuse = write_must_refuse(tag, role, wv)
            if status.is_good() and refuse:
                what = tag.path if tag is not None else wv.NodeId.to_string()
                counts.violations.append(
                    f"write {what} attr {wv.AttributeId} = {wv.Value.Value!r} by {role.value}: accepted"
                )
            elif not status.is_good() and not refuse:
                counts.admissible_refused += 1
    elif r < 0.9:
        kind = "call"
        req, tag = random_call(rng, targets)
        counts.cases[kind] += 1
        try:
            results = await _guarded(counts, kind, client.uaclient.call([req]))
        except (struct.error, OverflowError, ValueError, TypeError) as e:
            counts.failed[f"{kind} (not encodable: {type(e).__name__})"] += 1
            return
        for res in results or []:
            status = res.StatusCode
            counts.statuses[_status_name(status)] += 1
            refuse = call_must_refuse(tag, role, req.InputArguments)
            if status.is_good() and refuse:
                what = tag.path if tag is not None else req.MethodId.to_string()
                counts.violations.append(f"call {what}({req.InputArguments!r}) by {role.value}: accepted")
            elif not status.is_good() and not refuse:
                counts.admissible_refused += 1
            if status.is_good() and tag is not None and req.ObjectId.Identifier != tag.parent:
                # OPC UA Part 4 wants BadMethodInvalid; asyncua dispatches on the MethodId alone.
                counts.findings[f"{tag.path} called through {req.ObjectId.Identifier}: Good"] += 1
    elif r < 0.96:
        kind = "node_management"
        counts.cases[kind] += 1
        await _node_management_case(client, role, targets, rng, counts)
    else:
        kind = "subscription"
        counts.cases[kind] += 1
        await _subscription_case(client, targets, rng, counts)


async def _node_management_case(
    client: Client, role: Role, targets: SessionTargets, rng: np.random.Generator, counts: FuzzCounts
) -> None:
    """AddNodes, DeleteNodes, AddReferences or DeleteReferences: no tanklab role may change the
    address space, so any success is a violation."""
    node, _ = _pick(rng, targets.variables)
    parent = ua.NodeId("PLC.LIC1", targets.idx)
    which = int(rng.integers(4))
    if which == 0:
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = ua.NodeId(f"PLC.Fuzz{int(rng.integers(1_000_000))}", targets.idx)
        item.BrowseName = ua.QualifiedName("Fuzz", targets.idx)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = parent
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.BaseDataVariableType)
        attrs = ua.VariableAttributes()
        attrs.Value = ua.Variant(1.0, VT.Double)
        item.NodeAttributes = attrs
        results = await _guarded(counts, "node_management", client.uaclient.add_nodes([item]))
        codes = [r.StatusCode for r in results or []]
    elif which == 1:
        item = ua.DeleteNodesItem(NodeId=node, DeleteTargetReferences=True)
        params = ua.DeleteNodesParameters(NodesToDelete=[item])
        codes = await _guarded(counts, "node_management", client.uaclient.delete_nodes(params)) or []
    elif which == 2:
        ref = ua.AddReferencesItem(
            SourceNodeId=parent,
            ReferenceTypeId=ua.NodeId(ua.ObjectIds.HasComponent),
            IsForward=True,
            TargetNodeId=node,
            TargetNodeClass=ua.NodeClass.Variable,
        )
        codes = await _guarded(counts, "node_management", client.uaclient.add_references([ref])) or []
    else:
        ref = ua.DeleteReferencesItem(
            SourceNodeId=parent,
            ReferenceTypeId=ua.NodeId(ua.ObjectIds.HasComponent),
            IsForward=True,
            TargetNodeId=node,
            DeleteBidirectional=True,
        )
        codes = await _guarded(counts, "node_management", client.uaclient.delete_references([ref])) or []
    for code in codes:
        status = code if isinstance(code, ua.StatusCode) else ua.StatusCode(int(code))
        counts.statuses[status.name] += 1
        if status.is_good():
            counts.violations.append(
                f"node management ({which}) on {node.to_string()} by {role.value}: accepted"
            )


async def _subscription_case(
    client: Client, targets: SessionTargets, rng: np.random.Generator, counts: FuzzCounts
) -> None:
    """A subscription with absurd parameters and monitored items, created then deleted."""
    params = ua.CreateSubscriptionParameters()
    params.RequestedPublishingInterval = float(_pick(rng, (0.0, -1.0, math.nan, 1e-3, 1e12)))
    params.RequestedLifetimeCount = int(_pick(rng, (0, 1, 2**32 - 1)))
    params.RequestedMaxKeepAliveCount = int(_pick(rng, (0, 1, 2**32 - 1)))
    params.MaxNotificationsPerPublish = int(_pick(rng, (0, 2**32 - 1)))
    params.PublishingEnabled = True
    params.Priority = int(rng.integers(0, 256))
    result = await _guarded(
        counts, "subscription", client.uaclient.create_subscription(params, lambda *_: None)
    )
    if result is None:
        return
    counts.statuses["Good"] += 1
    items = []
    for _ in range(int(rng.integers(1, 4))):
        node, _tag = _pick(rng, targets.variables)
        req = ua.MonitoredItemCreateRequest()
        req.ItemToMonitor = ua.ReadValueId(NodeId=node, AttributeId=ua.AttributeIds.Value)
        req.MonitoringMode = ua.MonitoringMode.Reporting
        mp = ua.MonitoringParameters()
        mp.ClientHandle = int(rng.integers(0, 2**32))
        mp.SamplingInterval = float(_pick(rng, (0.0, -1.0, math.nan, 1e-6, 1e12)))
        mp.QueueSize = int(_pick(rng, (0, 1, 2**32 - 1)))
        mp.DiscardOldest = bool(rng.random() < 0.5)
        req.RequestedParameters = mp
        items.append(req)
    mparams = ua.CreateMonitoredItemsParameters(
        SubscriptionId=result.SubscriptionId,
        TimestampsToReturn=ua.TimestampsToReturn.Both,
        ItemsToCreate=items,
    )
    created = await _guarded(counts, "subscription", client.uaclient.create_monitored_items(mparams))
    for res in created or []:
        counts.statuses[_status_name(res.StatusCode)] += 1
    await _guarded(counts, "subscription", client.uaclient.delete_subscriptions([result.SubscriptionId]))


# ----------------------------------------------------------------------------------------------
# Post-conditions
# ----------------------------------------------------------------------------------------------


async def stored_violations(client: Client, tags: Sequence[Tag]) -> list[str]:
    """Every stored value that breaks the contract: not Good, wrong type, not finite, outside
    EURange, not a member of its enumeration; and every EURange property that changed."""
    idx = await namespace_index(client)
    variables = [t for t in tags if t.kind == "variable" and t.data_type is not None]
    nodes = [client.get_node(ua.NodeId(t.path, idx)) for t in variables]
    out: list[str] = []
    for t, dv in zip(variables, await client.read_attributes(nodes), strict=True):
        assert t.data_type is not None
        if dv.StatusCode is not None and not dv.StatusCode.is_good():
            out.append(f"{t.path}: status {dv.StatusCode.name}")
            continue
        v = dv.Value
        want = _VARIANT_OF[t.data_type]
        is_list = isinstance(v.Value, list) if v is not None else False
        if v is None or v.VariantType != want or is_list != (t.data_type == DataType.DOUBLE_ARRAY):
            out.append(f"{t.path}: stored {v!r}, not a {t.data_type.value}")
            continue
        for x in v.Value if is_list else [v.Value]:
            if isinstance(x, float) and not math.isfinite(x):
                out.append(f"{t.path}: stored {x!r}")
            elif (
                t.eu_range is not None
                and isinstance(x, int | float)
                and not t.eu_range[0] <= x <= t.eu_range[1]
            ):
                out.append(f"{t.path}: stored {x!r} outside EURange {t.eu_range}")
            elif t.enum is not None and int(x) not in {int(m) for m in t.enum}:
                out.append(f"{t.path}: stored {x!r}, not a member of {t.enum.__name__}")
    ranged = [t for t in variables if t.eu_range is not None]
    props = [client.get_node(ua.NodeId(f"{t.path}.EURange", idx)) for t in ranged]
    for t, dv in zip(ranged, await client.read_attributes(props), strict=True):
        assert t.eu_range is not None
        rng = dv.Value.Value if dv.Value is not None else None
        if not isinstance(rng, ua.Range) or (rng.Low, rng.High) != tuple(float(x) for x in t.eu_range):
            out.append(f"{t.path}.EURange: now {rng!r}, contract {t.eu_range}")
    return out


async def read_scan(client: Client) -> int:
    """``PLC.Status.Scan`` (raises unless the read is Good)."""
    idx = await namespace_index(client)
    dv = (await client.read_attributes([client.get_node(ua.NodeId("PLC.Status.Scan", idx))]))[0]
    if dv.StatusCode is not None and not dv.StatusCode.is_good():
        raise ua.UaStatusCodeError(dv.StatusCode.value)
    return int(dv.Value.Value)


@dataclass
class PostConditions:
    """The server after the fuzz."""

    alive: bool = False
    read_good: bool = False
    out_of_contract: list[str] = field(default_factory=list)
    scan_before: int = -1
    scan_after: int = -1
    error: str = ""

    @property
    def ok(self) -> bool:
        return (
            self.alive
            and self.read_good
            and not self.out_of_contract
            and self.scan_after > self.scan_before
            and not self.error
        )


async def post_conditions(
    url: str, logins: Logins, who: str = "engineer", scan_wait_s: float = 30.0
) -> PostConditions:
    """A new secure session reads Good, every stored value keeps its contract, and the scan
    counter advances (within ``scan_wait_s`` of wall time)."""
    post = PostConditions()
    try:
        async with session(url, logins, who) as client:
            post.alive = True
            post.scan_before = await read_scan(client)
            post.read_good = True
            post.out_of_contract = await stored_violations(client, PLC_TAGS)
            deadline = time.monotonic() + scan_wait_s
            while time.monotonic() < deadline:
                post.scan_after = await read_scan(client)
                if post.scan_after > post.scan_before:
                    break
                await asyncio.sleep(0.05)
    except Exception as e:
        post.error = f"{type(e).__name__}: {e}"
    return post


# ----------------------------------------------------------------------------------------------
# The fuzz driver
# ----------------------------------------------------------------------------------------------


async def fuzz_server(
    url: str,
    logins: Logins,
    *,
    n_cases: int,
    seed: int,
    concurrency: int = 8,
    sessions: Sequence[str] = ("engineer", "supervisor"),
) -> FuzzCounts:
    """Run ``n_cases`` seeded cases against the PLC server at ``url``: about
    :data:`RAW_SHARE` of them raw-transport cases (``concurrency`` connections at a time,
    interleaved with the session cases), the rest typed cases spread over ``sessions``."""
    host_port = url.split("//", 1)[1].split("/", 1)[0]
    host, port = host_port.rsplit(":", 1)
    rng = np.random.default_rng(seed)
    counts = FuzzCounts()
    n_raw = round(n_cases * RAW_SHARE)
    raw_cases = [raw_case(_pick(rng, RAW_KINDS), rng, url) for _ in range(n_raw)]
    n_session = n_cases - n_raw
    seeds = rng.integers(0, 2**63, size=len(sessions))
    sem = asyncio.Semaphore(concurrency)

    async def one_raw(case: RawCase) -> None:
        async with sem:
            counts.merge_raw(await run_raw_case(case, host, int(port), url))

    async def typed(who: str, n: int, s: int) -> None:
        sub = np.random.default_rng(s)
        async with session(url, logins, who) as client:
            idx = await namespace_index(client)
            targets = SessionTargets.build(idx, PLC_TAGS)
            for _ in range(n):
                await session_case(client, ROLE_OF[who], targets, sub, counts)

    shares = [
        n_session // len(sessions) + (1 if k < n_session % len(sessions) else 0) for k in range(len(sessions))
    ]
    await asyncio.gather(
        *(one_raw(c) for c in raw_cases),
        *(typed(who, n, int(s)) for who, n, s in zip(sessions, shares, seeds, strict=True)),
    )
    return counts


# ----------------------------------------------------------------------------------------------
# Processes
# ----------------------------------------------------------------------------------------------


def site_config(path: Path, *, retain: Path | None = None, at_operating_point: bool = False) -> Path:
    """The default config written to ``path``, optionally with a retentive-memory file and the
    tanks starting at the operating point with the equilibrium pump flows (so the loops start
    settled instead of filling empty tanks)."""
    data = yaml.safe_load(ENERGIES.read_text(encoding="utf-8"))
    if retain is not None:
        data["plc"]["retain_file"] = str(retain)
    if at_operating_point:
        net = TankNetwork.from_config(SITE.plant)
        op = operating_point(net, SITE.plant, default_inputs(net, SITE.plant))
        for tank, level in zip(data["plant"]["tanks"], op.equilibrium_levels_m, strict=True):
            tank["initial_level_m"] = float(level)
        for pump, command in zip(data["plant"]["pumps"], op.commands, strict=True):
            pump["initial_command"] = float(command)
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


@dataclass
class Stack:
    """Tier processes of one measurement and their URLs."""

    logins: Logins
    config: Path
    speed: float
    log_dir: Path
    base: int
    plant: Proc | None = None
    plc: Proc | None = None
    supervisor: Proc | None = None
    logs: dict[str, str] = field(default_factory=dict)
    """Log text of every process, by log file name, kept when the processes stop (the
    temporary directory goes away with the stack)."""

    @property
    def plant_url(self) -> str:
        return f"opc.tcp://{HOST}:{self.base}/tanklab/plant"

    @property
    def plc_url(self) -> str:
        return f"opc.tcp://{HOST}:{self.base + 1}/tanklab/plc"

    @property
    def supervisor_url(self) -> str:
        return f"opc.tcp://{HOST}:{self.base + 2}/tanklab/supervisor"

    def _common(self) -> list[str]:
        return [
            "--config",
            str(self.config),
            "--host",
            HOST,
            "--speed",
            f"{self.speed:g}",
            "--home",
            str(self.logins.home.root),
        ]

    def plc_proc(self, n: int = 0) -> Proc:
        args = ["plc", *self._common(), "--port", str(self.base + 1), "--plant-url", self.plant_url]
        return Proc("plc", args, self.log_dir / f"plc-{n}.log")

    async def start(self, *, supervisor: bool = False) -> Stack:
        state = self.log_dir / "plant-state.json"
        self.plant = await Proc(
            "plant",
            ["plant", *self._common(), "--port", str(self.base), "--state-file", str(state)],
            self.log_dir / "plant.log",
        ).start()
        self.plc = await self.plc_proc().start()
        if supervisor:
            args = ["supervisor", *self._common(), "--port", str(self.base + 2), "--plc-url", self.plc_url]
            self.supervisor = await Proc("supervisor", args, self.log_dir / "supervisor.log").start()
        return self

    async def stop(self) -> None:
        for p in (self.supervisor, self.plc, self.plant):
            if p is not None:
                if p.proc is not None and p.proc.returncode is None:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(p.proc.pid, signal.SIGCONT)  # a frozen process must hear SIGTERM
                await p.stop()
        for log in sorted(self.log_dir.glob("*.log")):
            self.logs[log.name] = log.read_text(encoding="utf-8", errors="replace")


@contextlib.asynccontextmanager
async def stack(speed: float, *, supervisor: bool = False, retain: bool = False) -> AsyncIterator[Stack]:
    """A temporary security home and config, and plant + PLC (+ supervisor) at ``speed``."""
    with tempfile.TemporaryDirectory(prefix="tanklab-security-") as tmp:
        root = Path(tmp)
        logins = provision(root / "home")
        config = site_config(
            root / "site.yaml", retain=root / "plc-retain.json" if retain else None, at_operating_point=True
        )
        st = Stack(logins, config, speed, root, free_base_port(3))
        try:
            await st.start(supervisor=supervisor)
            yield st
        finally:
            await st.stop()


# ----------------------------------------------------------------------------------------------
# The benchmarks
# ----------------------------------------------------------------------------------------------

FUZZ_SPEED = 10.0
FLOOD_SPEED = 5.0
FAIL_SPEED = 5.0


async def fuzz_async(n_cases: int = 5000, seed: int = 0) -> dict[str, Any]:
    async with stack(FUZZ_SPEED) as st:
        started = time.perf_counter()
        counts = await fuzz_server(st.plc_url, st.logins, n_cases=n_cases, seed=seed)
        wall = time.perf_counter() - started
        post = await post_conditions(st.plc_url, st.logins)
    return {
        "n_cases": n_cases,
        "seed": seed,
        "speed": FUZZ_SPEED,
        "wall_s": wall,
        **counts.as_dict(),
        "post": {
            "alive": post.alive,
            "read_good": post.read_good,
            "out_of_contract": post.out_of_contract,
            "scan_before": post.scan_before,
            "scan_after": post.scan_after,
            "error": post.error,
            "ok": post.ok,
        },
    }


def fuzz(n_cases: int = 5000, seed: int = 0) -> dict[str, Any]:
    """The protocol fuzz of the PLC server (see the module docstring)."""
    return asyncio.run(fuzz_async(n_cases, seed))


# ---- flood ---------------------------------------------------------------------------------

FLOOD_TARGETS = (
    "PLC.LIC1.SP",
    "PLC.LIC2.SP",
    "PLC.LIC1.ManualMV",
    "PLC.LIC2.ManualMV",
    "PLC.LIC1.Mode",
    "PLC.LIC2.Mode",
)


def flood_value(rng: np.random.Generator, tag: Tag) -> tuple[ua.Variant, bool]:
    """A flood write's value for ``tag`` and whether it is valid: valid SPs stay within 2 cm of
    the configured setpoint, the valid Mode is AUTO (the loops keep regulating); invalid values
    are NaN, outside EURange, non-members or of the wrong type."""
    valid = rng.random() < 0.5
    if tag.name == "Mode":
        if valid:
            return ua.Variant(int(LoopMode.AUTO), VT.Int32), True
        return _pick(
            rng, (ua.Variant(7, VT.Int32), ua.Variant(-1, VT.Int32), ua.Variant(1.0, VT.Double))
        ), False
    assert tag.eu_range is not None
    lo, hi = tag.eu_range
    if valid:
        if tag.name == "SP":
            assert SITE.plc is not None
            sp0 = next(lp.setpoint_m for lp in SITE.plc.loops if lp.name == tag.path.split(".")[1])
            return ua.Variant(float(rng.uniform(sp0 - 0.02, sp0 + 0.02)), VT.Double), True
        return ua.Variant(float(rng.uniform(lo, hi)), VT.Double), True
    return _pick(
        rng,
        (
            ua.Variant(math.nan, VT.Double),
            ua.Variant(hi + 1.0, VT.Double),
            ua.Variant(lo - 1.0, VT.Double),
            ua.Variant(1, VT.Int32),
        ),
    ), False


@dataclass
class FloodCounts:
    """Writes of a flood: sent, accepted, refused by status, and the oracle's violations."""

    sent: int = 0
    accepted: int = 0
    statuses: Counter[str] = field(default_factory=Counter)
    violations: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)


async def flood_writes(
    url: str,
    logins: Logins,
    *,
    seconds: float,
    clients: int,
    seed: int = 0,
    who: str = "engineer",
    on_start: Callable[[], Awaitable[None]] | None = None,
) -> FloodCounts:
    """``clients`` sessions writing single values back to back for ``seconds`` of wall time.

    The sessions log in first (a password login costs the server one scrypt, ~70 ms); the flood
    starts when all are in, after ``on_start`` (where a watcher takes its "before" reading).
    """
    tags = {t.path: t for t in PLC_TAGS}
    counts = FloodCounts()
    ready = asyncio.Barrier(clients + 1)
    go = asyncio.Event()
    end = [math.inf]

    async def writer(k: int) -> None:
        rng = np.random.default_rng([seed, k])
        try:
            async with session(url, logins, who) as client:
                idx = await namespace_index(client)
                await ready.wait()
                await go.wait()
                while time.monotonic() < end[0]:
                    path = _pick(rng, FLOOD_TARGETS)
                    tag = tags[path]
                    value, valid = flood_value(rng, tag)
                    wv = ua.WriteValue(
                        NodeId=ua.NodeId(path, idx),
                        AttributeId=ua.AttributeIds.Value,
                        Value=ua.DataValue(value),
                    )
                    counts.sent += 1
                    try:
                        status = (await client.uaclient.write(ua.WriteParameters(NodesToWrite=[wv])))[0]
                    except ua.UaStatusCodeError as e:
                        status = ua.StatusCode(e.code)
                    counts.statuses[status.name] += 1
                    if status.is_good():
                        counts.accepted += 1
                        if not valid:
                            counts.violations.append(f"{path} = {value!r} accepted")
        except Exception as e:
            counts.errors.append(f"writer {k}: {type(e).__name__}: {e}")
            await ready.abort()

    async def release() -> None:
        with contextlib.suppress(asyncio.BrokenBarrierError):
            await ready.wait()
        if on_start is not None:
            await on_start()
        end[0] = time.monotonic() + seconds
        go.set()

    await asyncio.gather(release(), *(writer(k) for k in range(clients)))
    return counts


STATUS_PATHS = (
    "PLC.Status.Scan",
    "PLC.Status.ModelTime",
    "PLC.Status.Overruns",
    "PLC.Status.LastScanDuration",
)


async def plc_status(client: Client) -> dict[str, Any]:
    """Scan, model time, overruns and last scan duration in one Read."""
    idx = await namespace_index(client)
    dvs = await client.read_attributes([client.get_node(ua.NodeId(p, idx)) for p in STATUS_PATHS])
    return {p.rsplit(".", 1)[1]: dv.Value.Value for p, dv in zip(STATUS_PATHS, dvs, strict=True)}


async def status_after_scans(client: Client, scans: int, limit_s: float = 30.0) -> dict[str, Any]:
    """:func:`plc_status` once the scan counter has advanced by ``scans`` (bounded wait)."""
    first = await plc_status(client)
    deadline = time.monotonic() + limit_s
    while True:
        now = await plc_status(client)
        if int(now["Scan"]) >= int(first["Scan"]) + scans or time.monotonic() > deadline:
            return now
        await asyncio.sleep(0.02)


async def plant_time(client: Client) -> float:
    idx = await namespace_index(client)
    return float(await client.get_node(ua.NodeId("Plant.Sim.Time", idx)).read_value())


@dataclass
class FloodWatch:
    """The PLC and the plant seen by a watching session during a flood."""

    before: dict[str, Any] = field(default_factory=dict)
    after: dict[str, Any] = field(default_factory=dict)
    plant_before: float = math.nan
    plant_after: float = math.nan
    max_scan_duration_s: float = 0.0
    samples: int = 0

    @property
    def model_lag_s(self) -> float:
        """How much less model time the PLC ran than the plant over the flood [model s]."""
        plc = float(self.after["ModelTime"]) - float(self.before["ModelTime"])
        return (self.plant_after - self.plant_before) - plc


async def watched_flood(
    plc_url: str, plant_url: str, logins: Logins, *, seconds: float, clients: int, seed: int = 0
) -> tuple[FloodCounts, FloodWatch]:
    """A flood with a watching session on the PLC (status every 100 ms) and one on the plant;
    "before" is read once every flooding session is logged in, "after" when the writes stop."""
    watch = FloodWatch()
    async with session(plc_url, logins, "engineer") as plc, session(plant_url, logins, "engineer") as plant:

        async def before() -> None:
            # Overruns of a scan are published with the next scan: let the logins' scans go by.
            watch.before = await status_after_scans(plc, 2)
            watch.plant_before = await plant_time(plant)

        flood_task = asyncio.create_task(
            flood_writes(plc_url, logins, seconds=seconds, clients=clients, seed=seed, on_start=before)
        )
        while not flood_task.done():
            if watch.before:
                st = await plc_status(plc)
                watch.samples += 1
                watch.max_scan_duration_s = max(watch.max_scan_duration_s, float(st["LastScanDuration"]))
            await asyncio.wait({flood_task}, timeout=0.1)
        counts = flood_task.result()
        watch.plant_after = await plant_time(plant)
        watch.after = await plc_status(plc)
        late = await status_after_scans(plc, 2)
        watch.after["Overruns"] = late["Overruns"]
    return counts, watch


async def flood_async(seconds: float = 60.0, clients: int = 4) -> dict[str, Any]:
    async with stack(FLOOD_SPEED) as st:
        counts, watch = await watched_flood(
            st.plc_url, st.plant_url, st.logins, seconds=seconds, clients=clients
        )
    lateness = LATENESS_RE.findall(st.logs.get("plc-0.log", ""))
    p50, p99 = (float(lateness[-1][2]), float(lateness[-1][3])) if lateness else (math.nan, math.nan)
    refused = counts.sent - counts.accepted
    ts = SITE.plc.scan_period_s if SITE.plc else 1.0
    scans = int(watch.after["Scan"]) - int(watch.before["Scan"])
    return {
        "seconds": seconds,
        "clients": clients,
        "speed": FLOOD_SPEED,
        "writes": counts.sent,
        "accepted": counts.accepted,
        "refused": refused,
        "writes_per_s": counts.sent / seconds,
        "accepted_per_s": counts.accepted / seconds,
        "refused_per_s": refused / seconds,
        "statuses": dict(counts.statuses.most_common()),
        "violations": counts.violations,
        "errors": counts.errors,
        "overruns_before": int(watch.before["Overruns"]),
        "overruns_after": int(watch.after["Overruns"]),
        "scans": scans,
        "scans_expected": seconds * FLOOD_SPEED / ts,
        "model_lag_s": watch.model_lag_s,
        "max_scan_duration_ms": 1e3 * watch.max_scan_duration_s,
        "lateness_p50_ms": p50,
        "lateness_p99_ms": p99,
    }


def flood(seconds: float = 60.0, clients: int = 4) -> dict[str, Any]:
    """The write flood (see the module docstring)."""
    return asyncio.run(flood_async(seconds, clients))


# ---- freeze then crash -----------------------------------------------------------------------

RECOVERY_LIMIT_S = 60.0


class Probe:
    """A session on one tier that reconnects on demand: :meth:`read` answers the values of
    ``paths`` (one Read), or None (dropping the session) while the tier is away or frozen.

    One login per connection, not per read: a password login costs the server one scrypt.
    """

    def __init__(self, url: str, paths: Sequence[str], logins: Logins, who: str = "engineer") -> None:
        self.url = url
        self.paths = list(paths)
        self.logins = logins
        self.who = who
        self.client: Client | None = None
        self.nodes: list[Any] = []

    async def read(self) -> dict[str, Any] | None:
        if self.client is None:
            client = new_client(self.url, 2.0)
            try:
                await asyncio.wait_for(secure_client(client, self.logins.identity(self.who)), 4.0)
                await asyncio.wait_for(client.connect(), 4.0)
                idx = await namespace_index(client)
            except Exception:
                await quiet_disconnect(client, 2.0)
                return None
            self.client = client
            self.nodes = [client.get_node(ua.NodeId(p, idx)) for p in self.paths]
        try:
            values = await asyncio.wait_for(self.client.read_values(self.nodes), 2.0)
        except Exception:
            await self.close()
            return None
        return dict(zip(self.paths, values, strict=True))

    async def value(self, path: str) -> Any:
        """One value, or None while the tier is away."""
        got = await self.read()
        return None if got is None else got[path]

    async def close(self) -> None:
        client, self.client = self.client, None
        if client is not None:
            await quiet_disconnect(client, 2.0)


async def _until(cond: Callable[[], Awaitable[bool]], limit_s: float, poll_s: float = 0.05) -> float:
    """Wall seconds until ``cond()`` is true, or NaN after ``limit_s``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit_s:
        if await cond():
            return time.monotonic() - t0
        await asyncio.sleep(poll_s)
    return math.nan


async def freeze_crash_async(repeats: int = 10, freeze_s: float = 3.0) -> dict[str, Any]:
    stalls: list[str] = []
    freeze_recovery: list[float] = []
    crash_recovery: list[float] = []
    noticed: list[float] = []
    async with stack(FAIL_SPEED, supervisor=True, retain=True) as st:
        sup = Probe(st.supervisor_url, ("Supervisor.PlcConnected", "Supervisor.Cycle"), st.logins)
        plc = Probe(st.plc_url, ("PLC.Supervisor.Alive",), st.logins)

        async def cycle() -> int:
            got = await sup.read()
            return int(got["Supervisor.Cycle"]) if got is not None else -1

        async def disconnected() -> bool:
            got = await sup.read()
            return got is not None and not got["Supervisor.PlcConnected"]

        def recovered_past(before: int) -> Callable[[], Awaitable[bool]]:
            async def cond() -> bool:
                got = await sup.read()
                if got is None or not got["Supervisor.PlcConnected"] or got["Supervisor.Cycle"] <= before:
                    return False
                return bool(await plc.value("PLC.Supervisor.Alive"))

            return cond

        async def wait_recovery(before: int, what: str, into: list[float]) -> None:
            back = await _until(recovered_past(before), RECOVERY_LIMIT_S)
            if math.isnan(back):
                stalls.append(f"{what}: no recovery within {RECOVERY_LIMIT_S:g} s")
            else:
                into.append(back)

        try:
            if math.isnan(await _until(recovered_past(0), RECOVERY_LIMIT_S, 0.2)):
                raise RuntimeError("the supervisor never cycled with the PLC")
            for rep in range(repeats):
                assert st.plc is not None and st.plc.pid is not None
                # Freeze for freeze_s of wall time; the supervisor must notice.
                before = await cycle()
                os.kill(st.plc.pid, signal.SIGSTOP)
                try:
                    seen = await _until(disconnected, freeze_s)
                    if not math.isnan(seen):
                        noticed.append(seen)
                        await asyncio.sleep(freeze_s - seen)
                    else:
                        stalls.append(
                            f"repeat {rep}: PlcConnected stayed True through a {freeze_s:g} s freeze"
                        )
                finally:
                    os.kill(st.plc.pid, signal.SIGCONT)
                await plc.close()
                await wait_recovery(
                    max(before, await cycle()), f"repeat {rep}, after SIGCONT", freeze_recovery
                )
                # Crash, and a restart on the same port with the same retentive memory.
                os.kill(st.plc.pid, signal.SIGKILL)
                await st.plc.stop()
                await plc.close()
                seen = await _until(disconnected, 30.0)
                if math.isnan(seen):
                    stalls.append(f"repeat {rep}: PlcConnected stayed True for 30 s after the PLC died")
                else:
                    noticed.append(seen)
                before = await cycle()
                st.plc = await st.plc_proc(rep + 1).start()
                await wait_recovery(before, f"repeat {rep}, after the restart", crash_recovery)
        finally:
            await sup.close()
            await plc.close()
    return {
        "repeats": repeats,
        "freeze_s": freeze_s,
        "speed": FAIL_SPEED,
        "silent_stalls": len(stalls),
        "stalls": stalls,
        "noticed_s": Summary.of(noticed).__dict__,
        "freeze_recovery_s": Summary.of(freeze_recovery).__dict__,
        "crash_recovery_s": Summary.of(crash_recovery).__dict__,
    }


def freeze_crash(repeats: int = 10) -> dict[str, Any]:
    """Freeze-then-crash of the PLC under a running supervisor (see the module docstring)."""
    return asyncio.run(freeze_crash_async(repeats))


# ---- parked sockets --------------------------------------------------------------------------


async def idle_sockets_async(n: int = 200) -> dict[str, Any]:
    async with stack(FUZZ_SPEED) as st:
        # A first session warms the server up (and proves it serves).
        async with session(st.plc_url, st.logins, "engineer") as client:
            await read_scan(client)
        loop = asyncio.get_running_loop()
        parked: list[tuple[asyncio.StreamReader, asyncio.StreamWriter, float]] = []
        refused = 0
        for _ in range(n):
            try:
                r, w = await asyncio.open_connection(HOST, st.base + 1)
                parked.append((r, w, loop.time()))
            except OSError:
                refused += 1

        async def closed_after(r: asyncio.StreamReader, opened: float) -> float:
            try:
                data = await asyncio.wait_for(r.read(1), 30.0)
            except TimeoutError:
                return math.nan
            except ConnectionError:
                data = b""
            return loop.time() - opened if not data else math.nan

        watchers = [asyncio.create_task(closed_after(r, t)) for r, _, t in parked]
        t0 = time.perf_counter()
        connect_read_s = math.nan
        error = ""
        try:
            async with session(st.plc_url, st.logins, "engineer") as client:
                await read_scan(client)
                connect_read_s = time.perf_counter() - t0
        except Exception as e:
            error = f"{type(e).__name__}: {e}"
        close_s = await asyncio.gather(*watchers)
        for _, w, _ in parked:
            w.close()
    closed = [c for c in close_s if math.isfinite(c)]
    return {
        "n": n,
        "refused_at_connect": refused,
        "connect_read_s": connect_read_s,
        "connect_target_s": 1.0,
        "error": error,
        "closed": len(closed),
        "close_s": Summary.of(closed).__dict__,
        "handshake_limit_s": LIMITS.handshake_s,
    }


def idle_sockets(n: int = 200) -> dict[str, Any]:
    """Parked sockets against a legitimate client (see the module docstring)."""
    return asyncio.run(idle_sockets_async(n))


# ---- failed logins ---------------------------------------------------------------------------


async def login_storm_async(n: int = 48, concurrency: int = 8) -> dict[str, Any]:
    async with stack(FLOOD_SPEED) as st, session(st.plc_url, st.logins, "engineer") as watcher:

        async def failed_login(k: int) -> None:
            client = new_client(st.plc_url, 10.0)
            who = ClientIdentity(st.logins.home, "cli", Credentials(f"nobody{k}", "not-the-password"))
            await secure_client(client, who)
            with contextlib.suppress(Exception):
                await client.connect()
            await quiet_disconnect(client, 2.0)

        before = await status_after_scans(watcher, 2)
        started = time.perf_counter()
        for burst in range(0, n, concurrency):
            await asyncio.gather(*(failed_login(k) for k in range(burst, min(n, burst + concurrency))))
        wall = time.perf_counter() - started
        after = await status_after_scans(watcher, 2)
    return {
        "logins": n,
        "concurrency": concurrency,
        "speed": FLOOD_SPEED,
        "wall_s": wall,
        "overruns": int(after["Overruns"]) - int(before["Overruns"]),
    }


def login_storm(n: int = 48, concurrency: int = 8) -> dict[str, Any]:
    """Failed password logins (unknown user names, in bursts of ``concurrency``) against the
    PLC at speed 5: the overruns they cause (see the module docstring of ``tests/robustness/
    test_flood.py``)."""
    return asyncio.run(login_storm_async(n, concurrency))


# ---- all, and the report ---------------------------------------------------------------------


def run_all(full: bool = True) -> dict[str, Any]:
    """Every robustness benchmark, full size (``make bench``) or small; a failing one is
    reported under ``errors`` and the others still run."""
    plan: dict[str, Callable[[], dict[str, Any]]] = {
        "fuzz": lambda: fuzz(5000 if full else 500),
        "flood": lambda: flood(60.0 if full else 10.0),
        "freeze_crash": lambda: freeze_crash(10 if full else 2),
        "idle_sockets": lambda: idle_sockets(200),
        "login_storm": lambda: login_storm(48 if full else 24),
    }
    out: dict[str, Any] = {"full": full, "errors": []}
    for name, body in plan.items():
        try:
            out[name] = body()
        except Exception as e:
            out["errors"].append(f"{name}: {type(e).__name__}: {e}")
    return out


def _summary_ms(s: dict[str, Any]) -> str:
    if not s or not s.get("n"):
        return "n/a"
    return f"median {fmt(1e3 * s['median'])} ms, max {fmt(1e3 * s['maximum'])} ms (n = {s['n']})"


def _summary_s(s: dict[str, Any]) -> str:
    if not s or not s.get("n"):
        return "n/a"
    return f"median {fmt(s['median'])} s, max {fmt(s['maximum'])} s (n = {s['n']})"


def _counts(c: dict[str, int]) -> str:
    return ", ".join(f"{k} {v:,}" for k, v in c.items()) or "none"


def _fuzz_md(fz: dict[str, Any]) -> list[str]:
    post = fz["post"]
    lines = [
        f"### Protocol fuzz ({fz['n_cases']:,} cases, seed {fz['seed']}, PLC at speed {fz['speed']:g})",
        "",
        "| kind | cases | closed by the server | first answers |",
        "|---|---:|---:|---|",
    ]
    for kind in (*RAW_KINDS, *SESSION_KINDS):
        if kind not in fz["cases"]:
            continue
        name = f"{kind} (must close)" if kind in MUST_CLOSE else kind
        if kind in RAW_KINDS:
            closed = str(fz["closed"].get(kind, 0))
            answers = {k.split(":", 1)[1]: v for k, v in fz["replies"].items() if k.startswith(kind + ":")}
            lines.append(f"| {name} | {fz['cases'][kind]:,} | {closed} | {_counts(answers)} |")
        else:
            lines.append(f"| {name} | {fz['cases'][kind]:,} | | |")
    out_of_contract = post["out_of_contract"]
    lines += [
        "",
        f"Typed requests, answers by status: {_counts(fz['statuses'])}.",
        "",
        f"- Oracle violations (accepted although the contract refuses, must-close left open):"
        f" **{len(fz['violations'])}**"
        + (f" ({'; '.join(fz['violations'][:5])})" if fz["violations"] else ""),
        f"- Admissible requests the PLC refused from its state (e.g. SetGains before the supervisor"
        f" is trusted): {fz['admissible_refused']:,}",
        f"- Accepted although OPC UA says no (not a tanklab contract violation):"
        f" {_counts(fz.get('findings', {}))}",
        f"- Connections closed by the server: {_summary_ms(fz['close_s'])} after the last byte",
        f"- After the fuzz: alive {post['alive']}, a Read Good {post['read_good']}, stored values outside"
        f" their contract **{len(out_of_contract)}**, scan counter {post['scan_before']} ->"
        f" {post['scan_after']}" + (f" ({post['error']})" if post["error"] else ""),
        f"- Wall time {fmt(fz['wall_s'])} s; cases that could not be sent: {_counts(fz['failed'])}",
        "",
    ]
    return lines


def _flood_md(fl: dict[str, Any]) -> list[str]:
    overruns = fl["overruns_after"] - fl["overruns_before"]
    return [
        f"### Write flood ({fl['clients']} engineer sessions, {fl['seconds']:g} s,"
        f" PLC at speed {fl['speed']:g})",
        "",
        "| writes/s | accepted/s | refused/s | overruns | scans (expected) | PLC lag behind the plant |"
        " largest scan | lateness p50 / p99 |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
        f"| {fmt(fl['writes_per_s'])} | {fmt(fl['accepted_per_s'])} | {fmt(fl['refused_per_s'])} |"
        f" {overruns} | {fl['scans']} ({fmt(fl['scans_expected'])}) | {fmt(fl['model_lag_s'])} s |"
        f" {fmt(fl['max_scan_duration_ms'])} ms |"
        f" {fmt(fl['lateness_p50_ms'])} / {fmt(fl['lateness_p99_ms'])} ms |",
        "",
        f"Answers by status: {_counts(fl['statuses'])}. Invalid writes accepted: **{len(fl['violations'])}**."
        + (f" Errors: {'; '.join(fl['errors'])}." if fl["errors"] else "")
        + " Lateness: start of each scan minus its deadline, over the PLC's whole run.",
        "",
    ]


def _freeze_md(fc: dict[str, Any]) -> list[str]:
    stalls = f" ({'; '.join(fc['stalls'])})" if fc["stalls"] else ""
    return [
        f"### Freeze then crash of the PLC under a running supervisor ({fc['repeats']} repeats,"
        f" speed {fc['speed']:g})",
        "",
        f"SIGSTOP for {fc['freeze_s']:g} s, SIGCONT, then SIGKILL and a restart on the same port with",
        "the same retentive memory. Silent stalls (the supervisor kept reporting the PLC connected",
        f"while it was away, or did not recover within {RECOVERY_LIMIT_S:g} s):"
        f" **{fc['silent_stalls']}**{stalls}.",
        "Recovered: PlcConnected True, Supervisor.Cycle past its value before the fault,",
        "PLC.Supervisor.Alive True.",
        "",
        "| | wall time |",
        "|---|---|",
        f"| PLC loss noticed (PlcConnected False) | {_summary_s(fc['noticed_s'])} |",
        f"| recovery after SIGCONT | {_summary_s(fc['freeze_recovery_s'])} |",
        f"| recovery after the restarted PLC serves | {_summary_s(fc['crash_recovery_s'])} |",
        "",
    ]


def _idle_md(idle: dict[str, Any]) -> list[str]:
    ok = math.isfinite(idle["connect_read_s"]) and idle["connect_read_s"] <= idle["connect_target_s"]
    return [
        f"### Parked sockets ({idle['n']} TCP connections without a Hello)",
        "",
        f"- A legitimate secure client connected and read in {fmt(idle['connect_read_s'])} s"
        f" (target <= {idle['connect_target_s']:g} s: {'met' if ok else '**not met**'})"
        + (f"; error: {idle['error']}" if idle["error"] else ""),
        f"- Parked sockets closed by the server: {idle['closed']} of {idle['n']},"
        f" {_summary_s(idle['close_s'])} after connecting (handshake limit {idle['handshake_limit_s']:g} s);"
        f" refused at connect: {idle['refused_at_connect']}",
        "",
    ]


def _logins_md(ls: dict[str, Any]) -> list[str]:
    return [
        f"### Failed password logins ({ls['logins']} unknown user names, {ls['concurrency']} at a time,"
        f" PLC at speed {ls['speed']:g})",
        "",
        f"Scan overruns caused: **{ls['overruns']}** in {fmt(ls['wall_s'])} s. The password check",
        "(scrypt, about 70 ms) runs in a worker thread before asyncua's synchronous user lookup, and",
        "past ten failures a minute (any names) password checks are suspended for the window.",
        "",
    ]


def markdown(results: dict[str, Any]) -> str:
    """The robustness section of ``docs/benchmarks.md``."""
    lines = [
        "## 8. Robustness of the secured PLC server",
        "",
        "Real plant and PLC processes (and the supervisor for freeze-then-crash) on loopback, secured",
        "with a fresh PKI and an engineer login, tanks starting at the operating point;",
        "`benchmarks/security.py` (CI-sized twins in `tests/robustness/`).",
        "",
    ]
    sections: list[tuple[str, Callable[[dict[str, Any]], list[str]]]] = [
        ("fuzz", _fuzz_md),
        ("flood", _flood_md),
        ("freeze_crash", _freeze_md),
        ("idle_sockets", _idle_md),
        ("login_storm", _logins_md),
    ]
    for key, render in sections:
        if results.get(key):
            lines += render(results[key])
    for err in results.get("errors", []):
        lines.append(f"- error: {err}")
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    import json
    import sys

    which = sys.argv[1] if len(sys.argv) > 1 else "all"
    res = run_all(full=False) if which == "all" else {which: globals()[which]()}
    print(json.dumps(res, indent=1, default=str))
    print(markdown(res))
