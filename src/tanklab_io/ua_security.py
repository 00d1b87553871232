"""Secure OPC UA for the three tiers and their clients: endpoints, identities, roles, limits.

Server side (:func:`secure_server`)
    * Endpoints: SignAndEncrypt with Basic256Sha256 and Aes128Sha256RsaOaep only. An
      unencrypted (None) channel still opens, because clients need it to fetch the endpoints and
      the server certificate, but :class:`_SecureProcessor` answers every request on it other
      than GetEndpoints, FindServers and CloseSecureChannel with BadSecurityModeRejected, so the
      plaintext-session bypass of asyncua's permission ruleset (upstream issue #1014) is closed.
    * Certificates: the client's application certificate must be the one that signed the
      secure channel, be trusted (the tanklab CA or ``tankctl pki trust``), unexpired, not
      revoked, and carry the client's ApplicationUri: else BadCertificateUntrusted /
      BadCertificateTimeInvalid / BadCertificateRevoked / BadCertificateUriInvalid /
      BadCertificateInvalid. The trust list and CRL are re-read when their folders change.
    * Identities (:class:`TankUserManager`): a user name and password from the users file
      (scrypt), acting in the user's role; or an X509 identity token with a tier certificate of
      the PKI (the supervisor's on the PLC: role Supervisor; the PLC's on the plant: role PLC;
      a tier's own on its own server: Observer, for its health probe; on the PLC also an
      external controller's, registered by ``tankctl user add-external``: role External,
      :mod:`tanklab_io.external`). Anonymous sessions are
      refused. Five failed logins lock a user name for 60 s; past ten failed logins within 60 s
      (any names) password checks are suspended for the rest of the window. The scrypt check
      (~70 ms) runs in a worker thread before asyncua's synchronous user lookup, so logins never
      hold up the tier's event loop.
    * Roles are checked per node by :class:`tanklab_io.ua.WriteGuard` and the method adapter.
    * Event filters: OfType matches the type and its subtypes
      (:func:`tanklab_io.conditions.oftype.match_event_subtypes`; asyncua matches the exact type).
    * Audit: every write and call (accepted or refused) and every refused session activation
      goes to the tier's :class:`~tanklab_io.audit.AuditLog` and is raised as a
      ``TanklabAuditEventType`` event on the Server object.
    * Limits (:data:`LIMITS`): 64 KiB chunks, at most 4 per message (256 KiB), 16 queued
      messages per connection, 256 connections, 2 s to send a first message while more than 32
      connections have no activated session (parked sockets are closed then) and 30 s to finish
      the handshake (through ActivateSession) in any case, sessions of at most 30 s timeout,
      publishing intervals of at least 100 ms; a chunk header announcing more than the chunk
      limit closes the connection at once.

Client side (:func:`secure_client`)
    A tier (PLC to plant, supervisor to PLC) connects with its own certificate on the channel
    and as X509 identity; the CLI with its certificate on the channel and a user name and
    password (:func:`tanklab_io.users.load_credentials`). Both check the server certificate
    against the same trust list.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import os
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.common.utils import Buffer, ServiceError
from asyncua.crypto import uacrypto
from asyncua.crypto.permission_rules import User
from asyncua.server.binary_server_asyncio import BinaryServer, OPCUAProtocol
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua.ua_binary import struct_from_binary, struct_to_binary

from tanklab.errors import SecurityError
from tanklab.handlers import check_handlers
from tanklab.tags import APPLICATION_URIS, NAMESPACE_URI, Role, Tag, tags_by_path
from tanklab_io.audit import AuditLog, AuditRecord
from tanklab_io.conditions.oftype import match_event_subtypes
from tanklab_io.external import ExternalIdentities
from tanklab_io.home import SecurityHome
from tanklab_io.pki import Pki
from tanklab_io.ua import (
    CURRENT_SESSION,
    CURRENT_USER,
    MethodHandler,
    Publisher,
    TankUser,
    WriteGuard,
    WriteHandler,
    build_nodes,
    install_write_guard,
)

# The client side, re-exported for the tiers and tests that import it from here (decision 0044).
from tanklab_io.ua_client_security import (  # noqa: F401
    CLIENT_POLICIES,
    ClientIdentity,
    ReloadingValidator,
    cli_identity,
    client_setup,
    identity_material,
    secure_client,
)
from tanklab_io.users import Lockout, UsersFile

log = logging.getLogger(__name__)

SECURITY_POLICIES = [
    ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
]
"""The endpoints every tier offers (nothing unencrypted, nothing sign-only)."""


@dataclass(frozen=True)
class Limits:
    """Transport and session limits of a tier's server."""

    chunk_bytes: int = 65_535
    max_chunks: int = 4
    max_pending_messages: int = 16
    max_connections: int = 256
    handshake_s: float = 2.0
    """A connection that has sent no complete message this long after TCP accept, while more
    than ``crowd`` connections are without an activated session, is parked and closed [wall s]."""
    crowd: int = 32
    """Connections without an activated session beyond which silent ones are closed at
    ``handshake_s`` (a dozen concurrent logins is a busy operator station, 200 is an attack)."""
    activation_s: float = 30.0
    """Any connection without an activated session this long after TCP accept is closed
    [wall s]: a hang bound, not a speed bound. A legitimate login (Hello, an RSA
    OpenSecureChannel, CreateSession, ActivateSession with one scrypt in a worker thread) is a
    few hundred ms on an idle machine and took over 2 s on a loaded two-core one, even to its
    Hello (the client's loop busy with its other logins' RSA), where asyncua's single 2 s
    watchdog closed it mid-handshake (issue #21: fuzz and flood sessions lost)."""
    max_session_timeout_ms: float = 30_000.0
    min_publishing_interval_ms: float = 100.0
    max_failed_logins: int = 10
    failed_login_window_s: float = 60.0

    @property
    def message_bytes(self) -> int:
        """Largest request a client may send [bytes]."""
        return self.chunk_bytes * self.max_chunks


LIMITS = Limits()

# Tier certificate -> the role it acts in, on the server of the tier below.
# (A tier's own certificate observes its own server: that is how its health probe reads.)
_IDENTITY_ROLES: dict[str, dict[str, Role]] = {
    "plant": {"plc": Role.PLC, "plant": Role.OBSERVER, "historian": Role.OBSERVER},
    "plc": {"supervisor": Role.SUPERVISOR, "plc": Role.OBSERVER, "historian": Role.OBSERVER},
    "supervisor": {"supervisor": Role.OBSERVER, "historian": Role.OBSERVER},
    "historian": {"historian": Role.OBSERVER},
}

_EXTERNAL_TIERS = frozenset({"plc"})
"""Tiers whose server maps External certificate identities (decision 0055)."""

_OPTIONAL_IDENTITIES = frozenset({"historian"})
"""Identities a tier maps when their certificate exists but does not require: a home made before
the historian (issue 16) still starts its plant, PLC and supervisor (`tankctl up` and `tankctl pki
init` issue the missing certificate; the historian reads as Observer)."""

_DISCOVERY = frozenset(
    ua.NodeId(i)
    for i in (
        ua.ObjectIds.GetEndpointsRequest_Encoding_DefaultBinary,
        ua.ObjectIds.FindServersRequest_Encoding_DefaultBinary,
        ua.ObjectIds.FindServersOnNetworkRequest_Encoding_DefaultBinary,
        ua.ObjectIds.CloseSecureChannelRequest_Encoding_DefaultBinary,
    )
)
_CREATE_SESSION = ua.NodeId(ua.ObjectIds.CreateSessionRequest_Encoding_DefaultBinary)
_SUBSCRIPTION_PARAMS = {
    ua.NodeId(ua.ObjectIds.CreateSubscriptionRequest_Encoding_DefaultBinary): ua.CreateSubscriptionParameters,
    ua.NodeId(ua.ObjectIds.ModifySubscriptionRequest_Encoding_DefaultBinary): ua.ModifySubscriptionParameters,
}
_ACTIVATE_SESSION = ua.NodeId(ua.ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary)
_TCP_TYPES = frozenset({b"HEL", b"ACK", b"ERR", b"RHE", b"OPN", b"CLO", b"MSG"})


# --------------------------------------------------------------------------------------------
# Identities
# --------------------------------------------------------------------------------------------


class TankUserManager:
    """asyncua user manager: users file (password) or tier certificate (X509) -> TankUser.

    Parameters
    ----------
    users_file : the users file; re-read when it changes, so ``tankctl user add`` needs no
        restart.
    identities : DER of a tier certificate -> (identity name, role) it acts in here.
    audit : where refused activations are recorded.
    lockout : the failed-login bookkeeping (5 failures lock for 60 s by default).
    clock : monotonic seconds (injected for tests of the lockout).
    external : the External identities (re-read when their registry changes), where the tier
        serves them (the PLC).
    """

    def __init__(
        self,
        users_file: Path,
        identities: dict[bytes, tuple[str, Role]],
        audit: AuditLog,
        *,
        lockout: Lockout | None = None,
        clock: Callable[[], float] = time.monotonic,
        external: ExternalIdentities | None = None,
    ) -> None:
        self.users_file = users_file
        self.external = external
        self.identities = identities
        self.audit = audit
        self.lockout = lockout or Lockout()
        self.clock = clock
        self._failures: deque[float] = deque()
        self._verdicts: dict[tuple[str, bytes], Role | None] = {}
        self._key = os.urandom(32)
        self._users: UsersFile | None = None
        self._stamp: tuple[float, int] | None = None

    def _current_users(self) -> UsersFile:
        try:
            st = self.users_file.stat()
            stamp: tuple[float, int] | None = (st.st_mtime, st.st_size)
        except FileNotFoundError:
            stamp = None
        if self._users is None or stamp != self._stamp:
            self._users = UsersFile.load(self.users_file)
            self._stamp = stamp
        return self._users

    def get_user(
        self, iserver: Any, username: str | None = None, password: str | None = None, certificate: Any = None
    ) -> User | None:
        """The session's user, or None (asyncua answers BadUserAccessDenied)."""
        if username is not None:
            return self._password_user(username, password or "")
        if certificate is not None:
            der = certificate if isinstance(certificate, bytes) else uacrypto.der_from_x509(certificate)
            found = self.identities.get(der)
            if found is None and self.external is not None:
                found = self.external.current().get(der)
            if found is not None:
                return TankUser.of(found[0], found[1])
            self._refuse("certificate", "certificate not a tier identity here")
            return None
        self._refuse("anonymous", "anonymous sessions are not allowed")
        return None

    def _verdict_key(self, username: str, password: str) -> tuple[str, bytes]:
        # The password itself is not kept, only a keyed digest of it for the moment between
        # the off-loop check and asyncua's synchronous call.
        return username, hmac.new(self._key, password.encode(), "sha256").digest()

    async def preverify(self, username: str, password: str) -> None:
        """Check a login's password in a worker thread (scrypt releases the GIL), so that the
        synchronous :meth:`get_user` asyncua calls next finds the verdict ready and the tier's
        event loop (its scan) never waits ~70 ms for a hash."""
        now = self.clock()
        if self.lockout.locked(username, now) or self._over_budget(now):
            return  # get_user refuses these without hashing
        users = self._current_users()
        role = await asyncio.to_thread(users.verify, username, password)
        if len(self._verdicts) < 1000:
            self._verdicts[self._verdict_key(username, password)] = role

    def _over_budget(self, now: float) -> bool:
        while self._failures and now - self._failures[0] >= LIMITS.failed_login_window_s:
            self._failures.popleft()
        return len(self._failures) >= LIMITS.max_failed_logins

    def _password_user(self, username: str, password: str) -> User | None:
        now = self.clock()
        if self.lockout.locked(username, now):
            self._refuse(username, "locked")
            return None
        if self._over_budget(now):
            # The hash runs on the server's event loop (asyncua asks synchronously): a storm of
            # wrong logins, e.g. with ever new names the per-name lockout cannot catch, would
            # steal the scan's time. Past the budget, logins wait until the window has passed.
            self._refuse(username, "too many failed logins; try again later")
            return None
        try:
            key = self._verdict_key(username, password)
            if key in self._verdicts:
                role = self._verdicts.pop(key)
            else:  # not pre-verified (a direct call): hash here
                role = self._current_users().verify(username, password)
        except Exception as e:  # a broken users file refuses everybody, loudly
            log.error("users file %s unusable: %s", self.users_file, e)
            role = None
        if role is None:
            self._failures.append(now)
            locks = self.lockout.failed(username, now)
            self._refuse(username, "locked after repeated failures" if locks else "bad user name or password")
            return None
        self.lockout.succeeded(username)
        return TankUser.of(username, role)

    def _refuse(self, user: str, reason: str) -> None:
        log.warning("session activation refused for %r: %s", user, reason)
        self.audit.record("activate", user=user, role="none", new=reason, status="BadUserAccessDenied")


def tier_identities(pki: Pki, tier: str) -> dict[bytes, tuple[str, Role]]:
    """The tier certificates that may act on ``tier``'s server, with their roles."""
    out: dict[bytes, tuple[str, Role]] = {}
    for name, role in _IDENTITY_ROLES[tier].items():
        path = pki.cert_path(name)
        if name != tier and name in _OPTIONAL_IDENTITIES and not path.exists():
            continue
        out[path.read_bytes()] = (name, role)
    return out


# --------------------------------------------------------------------------------------------
# The server's transport: discovery-only None channel, size checks, the request's user
# --------------------------------------------------------------------------------------------


class _SecureProcessor(UaProcessor):
    """asyncua's message processor with tanklab's channel rules in front."""

    audit: AuditLog | None = None

    async def _preverify(self, body: Any) -> None:
        """Hash a user-name login's password off the event loop before asyncua asks for it."""
        manager = self.iserver.user_manager
        if not isinstance(manager, TankUserManager) or self.session is None:
            return
        try:
            params = struct_from_binary(ua.ActivateSessionParameters, body.copy())
            token = params.UserIdentityToken
            if not isinstance(token, ua.UserNameIdentityToken):
                return
            name, password = self.iserver.decrypt_user_token(self.session, token)
        except Exception:
            return  # asyncua's own activation path reports a malformed token
        await manager.preverify(name, password)

    async def _process_message(self, typeid: ua.NodeId, requesthdr: Any, seqhdr: Any, body: Any) -> Any:
        policy = self._connection.security_policy
        if policy.Mode != ua.MessageSecurityMode.SignAndEncrypt and typeid not in _DISCOVERY:
            if typeid in (_CREATE_SESSION, _ACTIVATE_SESSION) and self.audit is not None:
                self.audit.record(
                    "activate",
                    user="?",
                    role="none",
                    new="unencrypted channel",
                    status="BadSecurityModeRejected",
                )
            raise ServiceError(ua.StatusCodes.BadSecurityModeRejected)
        if typeid == _CREATE_SESSION:
            params = struct_from_binary(ua.CreateSessionParameters, body.copy())
            if params.ClientCertificate != policy.peer_certificate:
                # The session's certificate must be the one that signed the channel.
                raise ServiceError(ua.StatusCodes.BadCertificateInvalid)
        if typeid in _SUBSCRIPTION_PARAMS:
            body = _clamped_subscription(_SUBSCRIPTION_PARAMS[typeid], body)
        if typeid == _ACTIVATE_SESSION:
            await self._preverify(body)
        token = CURRENT_USER.set(self.session.user if self.session is not None else None)
        session_token = CURRENT_SESSION.set(self.session.session_id if self.session is not None else None)
        try:
            return await super()._process_message(typeid, requesthdr, seqhdr, body)
        except ServiceError as e:
            if (
                typeid == _ACTIVATE_SESSION
                and self.audit is not None
                and e.code != ua.StatusCodes.BadUserAccessDenied
            ):
                self.audit.record(
                    "activate", user="?", role="none", new="refused", status=ua.StatusCode(e.code).name
                )
            raise
        finally:
            CURRENT_SESSION.reset(session_token)
            CURRENT_USER.reset(token)


def _clamped_subscription(kind: Any, body: Any) -> Any:
    """The request body with its publishing interval raised to the server's minimum (asyncua
    takes any interval, down to a busy loop: one client could take a core)."""
    params = struct_from_binary(kind, body.copy())
    floor = LIMITS.min_publishing_interval_ms
    if not params.RequestedPublishingInterval >= floor:  # also NaN
        params.RequestedPublishingInterval = floor
        return Buffer(struct_to_binary(params))
    return body


class _Protocol(OPCUAProtocol):
    """One connection: tanklab's processor, and chunk headers checked before buffering."""

    audit: AuditLog | None = None
    activation_s: float = LIMITS.activation_s
    crowd: int = LIMITS.crowd
    spoke = False
    """Whether a complete message has arrived (the connection is not parked)."""

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        if self.processor is not None:  # type: ignore[has-type]
            processor = _SecureProcessor(self.iserver, self.transport, self.limits)
            processor.audit = self.audit
            processor.set_policies(self.policies)
            self.processor = processor

    def data_received(self, data: bytes) -> None:
        head = self._buffer + data if len(self._buffer) < 8 else self._buffer
        if len(head) >= 8:
            size = int.from_bytes(head[4:8], "little")
            if head[:3] not in _TCP_TYPES or size < 8 or size > self.limits.max_recv_buffer:
                log.warning("closing connection from %s: bad chunk header", self.peer_name)
                if self.transport is not None:
                    self.transport.close()
                return
        pending = len(self._buffer) + len(data)
        super().data_received(data)
        if len(self._buffer) < pending:  # a complete message was taken off the buffer
            self.spoke = True

    async def _activation_watchdog(self) -> None:
        """Close a parked connection (no complete message ``handshake_s`` after TCP accept while
        more than ``crowd`` connections are unactivated) and any connection whose handshake
        never finishes (no activated session ``activation_s`` after accept).

        Replaces asyncua's single bound (``max_pending_activation_seconds`` from accept to
        ActivateSession, for every connection), which on a loaded machine closed legitimate
        logins mid-handshake: the handshake is RSA and scrypt work on both sides, its wall time
        is the machine's speed, not the client's intent. Parked sockets still go after
        ``handshake_s`` when they crowd the server (the only harm they do is taking slots).
        """
        try:
            first = self.iserver.max_pending_activation_seconds
            await asyncio.sleep(first)
            if not self.spoke and self._unactivated() > self.crowd:
                self._close_unactivated(f"no message within {first:.1f} s, {self.crowd}+ connections waiting")
                return
            await asyncio.sleep(max(0.0, self.activation_s - first))
            self._close_unactivated(f"no activated session within {self.activation_s:.1f} s")
        except asyncio.CancelledError:
            pass

    def _activated(self) -> bool:
        session = self.processor.session if self.processor is not None else None
        return session is not None and session.is_activated()

    def _unactivated(self) -> int:
        """Connections of this server without an activated session (this one included)."""
        return sum(1 for c in self.clients if not (isinstance(c, _Protocol) and c._activated()))

    def _close_unactivated(self, why: str) -> None:
        if self._activated():
            return
        log.warning("closing connection from %s: %s", self.peer_name, why)
        if self.transport is not None:
            self.transport.close()


class _BinaryServer(BinaryServer):
    audit: AuditLog | None = None
    activation_s: float = LIMITS.activation_s
    crowd: int = LIMITS.crowd

    def _make_protocol(self) -> OPCUAProtocol:
        protocol = _Protocol(
            iserver=self.iserver,
            policies=self._policies,
            clients=self.clients,
            closing_tasks=self.closing_tasks,
            limits=self.limits,
        )
        protocol.audit = self.audit
        protocol.activation_s = self.activation_s
        protocol.crowd = self.crowd
        return protocol


class TanklabServer(Server):
    """asyncua's server listening through tanklab's secure transport (:class:`_Protocol`)."""

    audit: AuditLog | None = None
    audit_events: AuditEvents | None = None
    activation_s: float = LIMITS.activation_s
    """Bound from TCP accept to an activated session [wall s] (:attr:`Limits.activation_s`)."""
    crowd: int = LIMITS.crowd
    """Unactivated connections beyond which silent ones are closed early (:attr:`Limits.crowd`)."""

    async def start(self) -> None:
        """Set up the endpoints and listen (asyncua's start, with tanklab's transport)."""
        await self._setup_server_nodes()
        await self.iserver.start()
        try:
            host, port = self._get_bind_socket_info()
            self.bserver = _BinaryServer(self.iserver, host, port, self.limits)
            self.bserver.audit = self.audit
            self.bserver.activation_s = self.activation_s
            self.bserver.crowd = self.crowd
            self.bserver.set_policies(self._policies)
            await self.bserver.start()
        except Exception:
            await self.iserver.stop()
            raise

    async def stop(self) -> None:
        """Stop listening and raising audit events; close the audit log."""
        if self.audit_events is not None:
            self.audit_events.close()
        await super().stop()
        if self.audit is not None:
            self.audit.close()


# --------------------------------------------------------------------------------------------
# Audit events
# --------------------------------------------------------------------------------------------


class AuditEvents:
    """Raises each audit record as a ``TanklabAuditEventType`` event on the Server object.

    Records are queued (at most ``QUEUE`` waiting; beyond that events are dropped and counted,
    the file log still has every record) and raised one at a time by a background task, since
    asyncua's event generator holds one event object. While the server has no subscription at
    all, no event is raised (nobody could receive it; lock-step writes thousands per second).
    """

    FIELDS = ("Action", "User", "Role", "Node", "OldValue", "NewValue", "Status")
    QUEUE = 1000

    def __init__(self) -> None:
        self._generator: Any = None
        self._subscriptions: dict[int, Any] = {}
        self._queue: asyncio.Queue[AuditRecord] = asyncio.Queue(self.QUEUE)
        self._task: asyncio.Task[None] | None = None
        self.dropped = 0

    async def install(self, server: Server, audit: AuditLog) -> None:
        """Create the event type and start raising ``audit``'s records."""
        idx = await server.register_namespace(NAMESPACE_URI)
        etype = await server.create_custom_event_type(
            idx,
            "TanklabAuditEventType",
            ua.ObjectIds.BaseEventType,
            [(f, ua.VariantType.String) for f in self.FIELDS],
        )
        self._generator = await server.get_event_generator(etype, ua.ObjectIds.Server)
        self._subscriptions = server.iserver.subscription_service.subscriptions
        audit.listeners.append(self._enqueue)
        self._task = asyncio.get_running_loop().create_task(self._run())

    def _enqueue(self, rec: AuditRecord) -> None:
        if not self._subscriptions:
            return  # nobody could receive it: skip the event's cost (the file has the record)
        try:
            self._queue.put_nowait(rec)
        except asyncio.QueueFull:
            self.dropped += 1

    async def _run(self) -> None:
        while True:
            rec = await self._queue.get()
            ev = self._generator.event
            ev.Action, ev.User, ev.Role, ev.Node = rec.action, rec.user, rec.role, rec.node
            ev.OldValue, ev.NewValue, ev.Status = repr(rec.old), repr(rec.new), rec.status
            ev.Severity = 100 if rec.status == "Good" else 500
            try:
                await self._generator.trigger(
                    message=f"{rec.action} {rec.node} by {rec.user or '?'} ({rec.role}): {rec.status}"
                )
            except Exception:  # a subscriber's trouble must not stop the audit events
                log.exception("audit event not raised")

    def close(self) -> None:
        """Stop raising events."""
        if self._task is not None:
            self._task.cancel()


# --------------------------------------------------------------------------------------------
# Wiring
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ServerSecurity:
    """What a tier's server needs: the security home and where its audit log goes."""

    home: SecurityHome
    audit_dir: Path | None = None

    @property
    def audit_directory(self) -> Path:
        return self.audit_dir or self.home.audit_dir


def set_transport_limits(server: Server, limits: Limits = LIMITS) -> None:
    """The chunk size, chunk count and message size a tier's server accepts and sends."""
    server.limits.max_recv_buffer = limits.chunk_bytes
    server.limits.max_chunk_count = limits.max_chunks
    server.limits.max_message_size = limits.message_bytes


async def secure_server(
    server: TanklabServer, tier: str, security: ServerSecurity, limits: Limits = LIMITS
) -> AuditLog:
    """Configure ``server`` (initialised, not started) for ``tier``; returns its audit log.

    A tier needs only its own key: its certificate and key, the certificates of the identities
    it maps to roles, the trust list and the CRL. Raises :class:`~tanklab.errors.SecurityError`
    naming what is missing.
    """
    pki = security.home.pki
    needed = [pki.cert_path(tier), pki.key_path(tier), pki.trusted_dir, pki.crl_dir]
    needed += [
        pki.cert_path(name)
        for name in _IDENTITY_ROLES[tier]
        if name == tier or name not in _OPTIONAL_IDENTITIES
    ]
    missing = [str(p) for p in needed if not p.exists()]
    if missing:
        raise SecurityError(
            f"{pki.root}: incomplete PKI (missing {', '.join(missing)}); "
            f"run `tankctl pki init --home {security.home.root}` first"
        )
    audit = AuditLog(security.audit_directory, tier)
    await server.load_certificate(str(pki.cert_path(tier)))
    await server.load_private_key(str(pki.key_path(tier)))
    server.set_security_policy(SECURITY_POLICIES)
    server.set_identity_tokens([ua.UserNameIdentityToken, ua.X509IdentityToken])
    external = ExternalIdentities(security.home) if tier in _EXTERNAL_TIERS else None
    server.iserver.user_manager = TankUserManager(
        security.home.users_file, tier_identities(pki, tier), audit, external=external
    )
    server.set_certificate_validator(ReloadingValidator(pki))
    set_transport_limits(server, limits)
    iserver = server.iserver
    iserver.max_connections = limits.max_connections
    iserver.max_pending_activation_seconds = limits.handshake_s
    server.activation_s = limits.activation_s
    server.crowd = limits.crowd
    iserver.max_pending_messages_per_connection = limits.max_pending_messages
    iserver.max_session_timeout_ms = limits.max_session_timeout_ms
    server.audit = audit
    server.audit_events = AuditEvents()
    await server.audit_events.install(server, audit)
    # Event filters' OfType matches subtypes (asyncua: the exact type only), so a client
    # filtering on AlarmConditionType receives the tier's level and off-normal alarms.
    match_event_subtypes(server)
    return audit


@dataclass
class TierServer:
    """A started tier server: its nodes, publisher, write guard and audit log."""

    server: TanklabServer
    nodes: dict[str, Any]
    publisher: Publisher
    guard: WriteGuard
    audit: AuditLog


async def start_tier_server(
    tier: str,
    *,
    url: str,
    name: str,
    security: ServerSecurity,
    tags: list[Tag],
    writes: Mapping[str, WriteHandler],
    methods: Mapping[str, MethodHandler] | None = None,
) -> TierServer:
    """Create, secure, populate and start the server of ``tier`` at ``url``.

    ``writes`` and ``methods`` attach one handler to each writable variable and each method of
    ``tags``, by path (:class:`tanklab.handlers.HandlerTable`); a tag without its handler, or a
    handler without its tag, is refused before anything listens (ValueError).
    """
    check_handlers(tags, writes, methods or {})
    server = TanklabServer()
    await server.init()
    server.set_endpoint(url)
    server.set_server_name(name)
    await server.set_application_uri(APPLICATION_URIS[tier])
    audit = await secure_server(server, tier, security)
    _, nodes = await build_nodes(server, tags, methods, audit)
    guard = install_write_guard(server, tags, nodes, writes, audit)
    publisher = Publisher(server, tags_by_path(tags), nodes)
    await server.start()
    return TierServer(server, nodes, publisher, guard, audit)
