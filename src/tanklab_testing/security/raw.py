"""Raw-transport fuzz cases: OPC UA TCP frames built byte by byte (pure, seeded) and one exchange per case.

Each case runs on a fresh TCP connection; :data:`MUST_CLOSE` names the kinds the transport
limits (``tanklab_io.ua_security.LIMITS``: chunk size 8 B .. 64 KiB, 4 chunks per message, 16
queued messages) must answer by closing the connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from asyncua import ua
from asyncua.common.connection import SecureConnection, TransportLimits
from asyncua.common.utils import Buffer
from asyncua.crypto.security_policies import SecurityPolicyNone
from asyncua.ua.ua_binary import header_from_binary, struct_from_binary, struct_to_binary, uatcp_to_binary

from tanklab_io.ua_security import LIMITS
from tanklab_testing.security.draws import pick, random_bytes

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

_U32 = struct.Struct("<I")
_EPOCH = datetime(2024, 1, 1, tzinfo=UTC)


def _u32(x: int) -> bytes:
    return _U32.pack(x & 0xFFFFFFFF)


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
        n = int(pick(rng, (1, 3, 7, 8, 12, 64, 512, 4096)))
        data = random_bytes(rng, n)
        if rng.random() < 0.5 and n >= 8:  # a known type in front, the rest random
            data = pick(rng, (b"HELF", b"MSGF", b"OPNF", b"CLOF", b"ACKF", b"ERRF")) + data[4:]
        return RawCase(kind, (data,))
    if kind == "hello":
        fields = [int(pick(rng, _ABSURD_U32)) for _ in range(5)]
        choice = int(rng.integers(4))
        if choice == 0:  # a long URL (possibly longer than a chunk)
            n = int(pick(rng, (0, 255, 4096, 65000, 70000)))
            body = b"".join(_u32(f) for f in fields) + _ua_string(b"u" * n)
        elif choice == 1:  # the URL's length prefix lies
            lie = int(pick(rng, (-2, -1, 1 << 20, 2**31 - 1, 5)))
            body = b"".join(_u32(f) for f in fields) + _ua_string(b"opc.tcp://x", length=lie)
        elif choice == 2:  # invalid UTF-8
            body = b"".join(_u32(f) for f in fields) + _ua_string(random_bytes(rng, 32))
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
            pick(rng, (0, 1, 7, LIMITS.chunk_bytes + 1, LIMITS.chunk_bytes + 1000, 1 << 20, 2**32 - 1))
        )
        mtype = pick(rng, (b"HEL", b"MSG", b"OPN", b"CLO"))
        bad = _frame(mtype, random_bytes(rng, int(rng.integers(4, 64))), size=size)
        if rng.random() < 0.5:  # after a valid Hello and its Acknowledge
            return RawCase(kind, (hello(url), bad), await_answers=True)
        return RawCase(kind, (bad,))
    if kind == "unknown_type":
        letters = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz\x00\xff"
        while True:
            mtype = bytes(int(pick(rng, letters)) for _ in range(3))
            if mtype not in (b"HEL", b"ACK", b"ERR", b"RHE", b"OPN", b"CLO", b"MSG"):
                break
        bad = _frame(mtype, random_bytes(rng, int(rng.integers(4, 128))))
        if rng.random() < 0.5:
            return RawCase(kind, (hello(url), bad), await_answers=True)
        return RawCase(kind, (bad,))
    if kind == "bogus_channel":
        mtype = pick(rng, (b"MSG", b"OPN", b"CLO"))
        channel = int(rng.integers(0, 2**32))
        payload = _u32(channel) + _u32(int(rng.integers(0, 2**32))) + _u32(1) + _u32(1)
        payload += random_bytes(rng, int(rng.integers(0, 256)))
        return RawCase(kind, (hello(url), _frame(mtype, payload)), await_answers=True)
    if kind == "truncated":
        whole = pick(rng, (hello(url), open_request()))
        cut = int(rng.integers(1, len(whole)))
        return RawCase(kind, (whole[:cut],), half_close=bool(rng.random() < 0.5))
    if kind == "mutated":
        data = hello(url) + open_request()
        return RawCase(kind, (_flip(rng, data, int(rng.integers(1, 9))),))
    if kind == "bad_open":
        choice = int(rng.integers(4))
        if choice == 0:  # a secure policy with a garbage certificate
            frame = open_request(
                policy_uri=pick(rng, SECURE_POLICY_URIS),
                certificate=random_bytes(rng, int(pick(rng, (0, 16, 900, 3000)))),
                mode=ua.MessageSecurityMode.SignAndEncrypt,
            )
        elif choice == 1:  # an unknown policy
            frame = open_request(policy_uri="http://opcfoundation.org/UA/SecurityPolicy#Basic128Rsa15")
        elif choice == 2:  # the None policy asking for SignAndEncrypt
            frame = open_request(mode=ua.MessageSecurityMode.SignAndEncrypt)
        else:  # a garbage policy URI
            frame = open_request(policy_uri=random_bytes(rng, 40).hex())
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
        request = pick(
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
