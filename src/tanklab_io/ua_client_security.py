"""The client side of tanklab's secure OPC UA: who a client is and how it sets up its channel.

:class:`ClientIdentity` names a client's certificate in the PKI (``cli``, ``plc``,
``supervisor``) and, for the CLI, its login; :func:`secure_client` prepares an asyncua client to
connect as it (SignAndEncrypt, the server certificate checked by :class:`ReloadingValidator`
against the PKI's trust list and CRL); :func:`cli_identity` is the operator's identity from the
environment or the credentials file; :func:`client_setup` is the
:class:`tanklab_io.ua_client.Link` ``setup`` for an identity.

Split from :mod:`tanklab_io.ua_security` (which re-exports every name) so that a client, an
operator command above all, imports none of the server side: asyncua's server processors, the
write guard, the audit log, the condition projection (decision 0044).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Client, ua
from asyncua.crypto import uacrypto
from asyncua.crypto.security_policies import (
    SecurityPolicy,
    SecurityPolicyAes128Sha256RsaOaep,
    SecurityPolicyBasic256Sha256,
    SecurityPolicyNone,
)
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives import serialization

from tanklab.errors import SecurityError
from tanklab.tags import APPLICATION_URIS
from tanklab_io.home import SecurityHome, default_home
from tanklab_io.pki import Pki
from tanklab_io.ua_client import ClientSetup
from tanklab_io.users import Credentials, cli_login

CLIENT_POLICIES = {
    "Basic256Sha256": SecurityPolicyBasic256Sha256,
    "Aes128Sha256RsaOaep": SecurityPolicyAes128Sha256RsaOaep,
}
"""Policies a tanklab client can pick by name (default Basic256Sha256)."""


class ReloadingValidator:
    """asyncua certificate validator over the PKI's trust list and CRL, re-read on change.

    Checks validity period, the ApplicationUri in the subjectAltName, trust (directly or by
    the tanklab CA) and revocation.
    """

    OPTIONS = (
        CertificateValidatorOptions.TIME_RANGE
        | CertificateValidatorOptions.URI
        | CertificateValidatorOptions.TRUSTED
        | CertificateValidatorOptions.REVOKED
    )

    def __init__(self, pki: Pki) -> None:
        self.pki = pki
        self._store = TrustStore([pki.trusted_dir], [pki.crl_dir])
        self._validator = CertificateValidator(self.OPTIONS, self._store)
        self._stamp: tuple[float, ...] | None = None

    def _folders_stamp(self) -> tuple[float, ...]:
        stamps: list[float] = []
        for folder in (self.pki.trusted_dir, self.pki.crl_dir):
            stamps.append(folder.stat().st_mtime)
            stamps.extend(p.stat().st_mtime for p in sorted(folder.iterdir()))
        return tuple(stamps)

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        stamp = self._folders_stamp()
        if stamp != self._stamp:
            await self._store.load()
            self._stamp = stamp
        await self._validator.validate(cert, app)


@dataclass(frozen=True)
class ClientIdentity:
    """Who a tanklab client is: its certificate's name in the PKI, and for the CLI a login.

    ``name`` is ``cli`` (with ``credentials``), or ``plc`` / ``supervisor`` (their tier
    certificate is also their X509 identity).
    """

    home: SecurityHome
    name: str = "cli"
    credentials: Credentials | None = None
    policy: str = "Basic256Sha256"


async def secure_client(client: Client, identity: ClientIdentity) -> None:
    """Set up ``client`` (not yet connected) to connect as ``identity``.

    Fetches the server's endpoints over the discovery channel (the one thing it serves). The
    identity's certificate and private key are read and checked once per process while their
    files stay unchanged (:func:`identity_material`): the key's validation is the costliest
    step of a connection, and ``tankctl status`` connects to three tiers.
    """
    pki = identity.home.pki
    cert, key = pki.cert_path(identity.name), pki.key_path(identity.name)
    if not cert.exists() or not key.exists():
        raise SecurityError(f"{pki.root}: no certificate for {identity.name!r}; run `tankctl pki init`")
    if identity.policy not in CLIENT_POLICIES:
        known = ", ".join(CLIENT_POLICIES)
        raise SecurityError(f"unknown security policy {identity.policy!r}; one of {known}")
    login = identity.name == "cli" or identity.credentials is not None
    if login and identity.credentials is None:
        where = identity.home.credentials_file
        raise SecurityError(f"no credentials: set TANKLAB_USER and TANKLAB_PASSWORD, or write {where}")
    client.application_uri = APPLICATION_URIS.get(identity.name, f"urn:tanklab:{identity.name}")
    client.certificate_validator = ReloadingValidator(pki)
    certificate, private_key = identity_material(cert, key)
    await _set_security(client, CLIENT_POLICIES[identity.policy], certificate, private_key)
    if identity.credentials is not None:
        client.set_user(identity.credentials.username)
        client.set_password(identity.credentials.password)
    else:
        client.user_certificate = certificate
        client.user_private_key = private_key


_MATERIAL: dict[tuple[Path, Path], tuple[tuple[int, ...], x509.Certificate, Any]] = {}
"""What :func:`identity_material` read, by file pair, with the files' stamps (this process only)."""


def _stamp(*paths: Path) -> tuple[int, ...]:
    out: list[int] = []
    for path in paths:
        st = path.stat()
        out += [st.st_ino, st.st_size, st.st_mtime_ns]
    return tuple(out)


def identity_material(cert_path: Path, key_path: Path) -> tuple[x509.Certificate, Any]:
    """The certificate and private key of an identity, read and checked once (each as PEM if
    its file name ends in ``.pem``, else DER, as asyncua decides).

    Kept in memory for this process only, and read again as soon as either file changes (a
    re-issued certificate, a new key): its inode, size or modification time. Nothing is written
    anywhere. The key is loaded with cryptography's full RSA key validation (about 20-40 ms of
    CPU on the reference machines), which is why it is worth not repeating per connection.
    """
    stamp = _stamp(cert_path, key_path)
    kept = _MATERIAL.get((cert_path, key_path))
    if kept is not None and kept[0] == stamp:
        return kept[1], kept[2]
    pem = (cert_path.suffix.lower() == ".pem", key_path.suffix.lower() == ".pem")
    data = cert_path.read_bytes()
    certificate = x509.load_pem_x509_certificate(data) if pem[0] else x509.load_der_x509_certificate(data)
    data = key_path.read_bytes()
    load_key = serialization.load_pem_private_key if pem[1] else serialization.load_der_private_key
    private_key = load_key(data, password=None)
    _MATERIAL[(cert_path, key_path)] = (stamp, certificate, private_key)
    return certificate, private_key


async def _set_security(
    client: Client, policy: type[SecurityPolicy], certificate: x509.Certificate, key: Any
) -> None:
    """asyncua 2.1.0's ``Client.set_security(policy, cert, key, mode=SignAndEncrypt)`` without a
    server certificate, for a certificate and key already loaded (its own loads them from
    files every time): the server's certificate from its endpoints over a discovery channel,
    the client certificate checked against the application URI and host name (warnings only,
    as asyncua does), then the policy installed on the client and its UA client."""
    mode = ua.MessageSecurityMode.SignAndEncrypt
    none = SecurityPolicyNone()
    client.security_policy = none
    client.uaclient.security_policy = none
    endpoints = await client.connect_and_get_server_endpoints()
    endpoint = Client.find_endpoint(endpoints, mode, policy.URI)
    server_certificate = uacrypto.x509_from_der(endpoint.ServerCertificate)
    uacrypto.check_certificate(certificate, client.application_uri, socket.gethostname())
    client.security_policy = policy(server_certificate, certificate, key, mode, host_cert_chain=[])
    client.uaclient.set_security(client.security_policy)


def cli_identity(
    home: SecurityHome | None = None, environ: Mapping[str, str] | None = None
) -> ClientIdentity:
    """Who the CLI (operator commands, the board) connects as: the ``cli`` certificate of
    ``home`` (default: ``TANKLAB_HOME``, else ``~/.config/tanklab``) and the login from
    ``TANKLAB_USER`` and ``TANKLAB_PASSWORD`` or the home's 0600 credentials file.

    Raises
    ------
    SecurityError
        Only one of ``TANKLAB_USER`` and ``TANKLAB_PASSWORD`` is set (non-empty): a user name
        without its password is an error before connecting, never a login as the file's user.
    """
    env = os.environ if environ is None else environ
    home = home or SecurityHome(default_home(env))
    return ClientIdentity(home, "cli", cli_login(home.credentials_file, env))


def client_setup(identity: ClientIdentity) -> ClientSetup:
    """A :class:`tanklab_io.ua_client.Link` ``setup`` connecting as ``identity``."""

    async def setup(client: Client) -> None:
        await secure_client(client, identity)

    return setup
