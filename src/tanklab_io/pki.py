"""The tanklab PKI: one local CA, an application certificate per identity, a trust list, a CRL.

Layout under ``root`` (directories 0700, private keys 0600 unencrypted PKCS#8 PEM, certs DER)::

    ca/ca.der              the tanklab CA's certificate: self-signed, BasicConstraints cA=true
    ca/ca-cert.pem         (critical), KeyUsage keyCertSign + cRLSign; the same in PEM
    ca/ca-key.pem          the CA's private key (0600): never handed out
    own/{name}.der         application certificates, one per IDENTITY (plant, plc, supervisor,
    private/{name}.pem     cli) plus any issued later; their private keys
    trusted/               what a peer must chain to: the CA's copy (tanklab-ca.der) and external
                           certificates added by :func:`trust` (``{CN}_{sha1}.der``)
    crl/ca.crl.der         the CA's revocation list, signed by the CA; the same in PEM
    crl/ca.crl.pem

What a third-party client must trust is the CA certificate and its CRL (:func:`client_files`
lists them for ``tankctl pki show``): node-opcua, for one, refuses a server certificate whose
issuer or CRL it does not hold (BadCertificateChainIncomplete, BadCertificateRevocationUnknown).

Homes made before decision 0022 kept the CA's private key as ``ca/ca.pem``, a name a user
takes for "the CA certificate in PEM". :func:`migrate` renames it to ``ca/ca-key.pem`` (still
0600) and writes the missing PEM copies; every function here that opens the CA runs it first
and logs what it changed, so an old home is upgraded on first use.

These are the locations asyncua's ``TrustStore([trusted], [crl])`` reads: a peer is trusted
when its certificate chains to a certificate in ``trusted/`` (cryptography's client verifier)
and revoked when its serial is on a CRL in ``crl/``.

Every application certificate carries what OPC UA Part 6 (and asyncua's CertificateValidator)
checks: SubjectAltName with the ApplicationUri plus DNSName / IPAddress entries for the hosts,
KeyUsage digitalSignature, contentCommitment (nonRepudiation), keyEncipherment,
dataEncipherment; ExtendedKeyUsage serverAuth + clientAuth; BasicConstraints cA=false; Subject
and Authority KeyIdentifiers. Keys are RSA 2048, signatures RSA PKCS#1 v1.5 with SHA-256 (the
Basic256Sha256 and Aes128_Sha256_RsaOaep policies' certificate requirements). They are built
in memory by :mod:`tanklab_io.certs`; this module decides where they live and writes them.

This module reads the wall clock (certificate validity starts now) and writes files; it never
logs or prints key material.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa

from tanklab.errors import SecurityError
from tanklab.tags import APPLICATION_URIS
from tanklab_io.certs import (
    CA_DAYS,
    KEY_BITS,
    application_cert,
    certificate_uri,
    common_name,
    fingerprint,
    general_names,
    key_pem,
    make_ca,
    validity,
)
from tanklab_io.persist import write_bytes_atomic

__all__ = [
    "CA_DAYS",
    "DEFAULT_DAYS",
    "DEFAULT_HOSTS",
    "IDENTITIES",
    "KEY_BITS",
    "SERVER_IDENTITIES",
    "ClientFile",
    "Pki",
    "client_files",
    "describe",
    "init_pki",
    "issue",
    "migrate",
    "read_certificate",
    "revoke",
    "self_signed",
    "trust",
    "trusted_name",
    "write_file",
]

IDENTITIES = ("plant", "plc", "supervisor", "historian", "cli")
"""The application identities :func:`init_pki` issues a certificate for (keys of APPLICATION_URIS)."""

SERVER_IDENTITIES = ("plant", "plc", "supervisor", "historian")
"""The identities that serve OPC UA (the certificates a third-party client is presented)."""

_log = logging.getLogger(__name__)

DEFAULT_HOSTS = ("localhost", "127.0.0.1")
"""Hosts written into every certificate's SubjectAltName (DNSName, or IPAddress when it parses)."""

DEFAULT_DAYS = 825
"""Validity of an application certificate and the CRL's nextUpdate horizon [days]."""

CA_TRUST_NAME = "tanklab-ca.der"
"""File name of the CA's copy in ``trusted/``."""

LEGACY_CA_KEY_NAME = "ca.pem"
"""Where homes made before decision 0022 kept the CA's private key (``ca/``); :func:`migrate`."""

_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


@dataclass(frozen=True)
class Pki:
    """Paths of a PKI rooted at ``root`` (see the module docstring); build it with :meth:`at`."""

    root: Path
    ca_cert: Path
    ca_key: Path
    trusted_dir: Path
    crl_dir: Path

    @classmethod
    def at(cls, root: Path) -> Pki:
        """The PKI layout under ``root`` (nothing is read or written)."""
        root = Path(root)
        return cls(
            root=root,
            ca_cert=root / "ca" / "ca.der",
            ca_key=root / "ca" / "ca-key.pem",
            trusted_dir=root / "trusted",
            crl_dir=root / "crl",
        )

    @property
    def own_dir(self) -> Path:
        """Directory of the application certificates (DER)."""
        return self.root / "own"

    @property
    def private_dir(self) -> Path:
        """Directory of the application private keys (PEM, 0600)."""
        return self.root / "private"

    @property
    def ca_cert_pem(self) -> Path:
        """The CA certificate in PEM (``ca/ca-cert.pem``), for clients that take PEM."""
        return self.ca_cert.parent / "ca-cert.pem"

    @property
    def legacy_ca_key(self) -> Path:
        """``ca/ca.pem``: the CA's private key in homes made before decision 0022."""
        return self.ca_cert.parent / LEGACY_CA_KEY_NAME

    @property
    def crl_file(self) -> Path:
        """The CA's revocation list (DER)."""
        return self.crl_dir / "ca.crl.der"

    @property
    def crl_pem(self) -> Path:
        """The CA's revocation list in PEM (``crl/ca.crl.pem``; asyncua's TrustStore reads both)."""
        return self.crl_dir / "ca.crl.pem"

    def cert_path(self, name: str) -> Path:
        """Application certificate of ``name``: ``root/own/{name}.der``."""
        return self.own_dir / f"{_checked_name(name)}.der"

    def key_path(self, name: str) -> Path:
        """Private key of ``name``: ``root/private/{name}.pem`` (unencrypted PKCS#8 PEM, 0600)."""
        return self.private_dir / f"{_checked_name(name)}.pem"

    def exists(self) -> bool:
        """True when the CA (cert and key) and every IDENTITY's cert and key are present."""
        files = [self.ca_cert, self.ca_key]
        for name in IDENTITIES:
            files += [self.cert_path(name), self.key_path(name)]
        return all(f.is_file() for f in files)


# --------------------------------------------------------------------------------------------
# Pure helpers: names, extensions, encodings
# --------------------------------------------------------------------------------------------


def _checked_name(name: str) -> str:
    if not _NAME.match(name):
        raise SecurityError(f"certificate name {name!r}: must match [A-Za-z0-9_.-]{{1,64}}")
    return name


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------


def _now() -> datetime:
    return datetime.now(UTC)


def _mkdir(path: Path) -> None:
    """Create ``path`` (and parents) and make ``path`` itself 0700."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(path, 0o700)


def write_file(path: Path, data: bytes, mode: int, *, owner: tuple[int, int] | None = None) -> None:
    """Write a PKI file atomically with ``mode`` (and ``owner``), its directory 0700 when new."""
    write_bytes_atomic(path, data, mode=mode, owner=owner, dir_mode=0o700)


def _write_cert(path: Path, cert: x509.Certificate) -> None:
    write_file(path, cert.public_bytes(serialization.Encoding.DER), 0o644)


def _write_key(path: Path, key: rsa.RSAPrivateKey) -> None:
    write_file(path, key_pem(key), 0o600)


def read_certificate(file: Path) -> x509.Certificate:
    """Load a certificate from a DER or PEM file; anything else is a :class:`SecurityError`."""
    try:
        data = Path(file).read_bytes()
    except OSError as e:
        raise SecurityError(f"{file}: cannot read: {e.strerror or e}") from None
    try:
        if b"-----BEGIN" in data:
            return x509.load_pem_x509_certificate(data)
        return x509.load_der_x509_certificate(data)
    except ValueError:
        raise SecurityError(f"{file}: not an X.509 certificate (DER or PEM)") from None


def _read_ca(pki: Pki) -> tuple[x509.Certificate, rsa.RSAPrivateKey]:
    _migrate_logged(pki)
    if not (pki.ca_cert.is_file() and pki.ca_key.is_file()):
        raise SecurityError(f"{pki.root}: no tanklab CA (run `tankctl pki init`)")
    cert = read_certificate(pki.ca_cert)
    try:
        key = serialization.load_pem_private_key(pki.ca_key.read_bytes(), password=None)
    except (OSError, ValueError, TypeError):
        raise SecurityError(f"{pki.ca_key}: not a readable unencrypted PEM private key") from None
    if not isinstance(key, rsa.RSAPrivateKey):
        raise SecurityError(f"{pki.ca_key}: not an RSA private key")
    return cert, key


# --------------------------------------------------------------------------------------------
# CA, certificates, CRL
# --------------------------------------------------------------------------------------------


def _revoked_entries(pki: Pki) -> tuple[list[x509.RevokedCertificate], int]:
    """Entries of the current CRL and its CRLNumber (none and 0 when there is no CRL)."""
    if not pki.crl_file.is_file():
        return [], 0
    try:
        crl = x509.load_der_x509_crl(pki.crl_file.read_bytes())
    except (OSError, ValueError):
        raise SecurityError(f"{pki.crl_file}: not a readable DER CRL") from None
    try:
        number = crl.extensions.get_extension_for_class(x509.CRLNumber).value.crl_number
    except x509.ExtensionNotFound:
        number = 0
    return list(crl), number


def _write_crl(
    pki: Pki,
    ca: tuple[x509.Certificate, rsa.RSAPrivateKey],
    revoked: Sequence[x509.RevokedCertificate],
    number: int,
    now: datetime,
    days: int,
) -> None:
    cert, key = ca
    builder = (
        x509.CertificateRevocationListBuilder()
        .issuer_name(cert.subject)
        .last_update(now)
        .next_update(now + timedelta(days=days))
        .add_extension(x509.CRLNumber(number), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(key.public_key()), critical=False)
    )
    for entry in revoked:
        builder = builder.add_revoked_certificate(entry)
    crl = builder.sign(key, hashes.SHA256())
    write_file(pki.crl_file, crl.public_bytes(serialization.Encoding.DER), 0o644)
    write_file(pki.crl_pem, crl.public_bytes(serialization.Encoding.PEM), 0o644)


def init_pki(
    root: Path,
    *,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    days: int = DEFAULT_DAYS,
    force: bool = False,
) -> Pki:
    """Create the tanklab CA and one certificate per IDENTITY under ``root``; idempotent.

    A complete PKI (:meth:`Pki.exists`) is kept as it is unless ``force``. With ``force``, or
    when the CA is missing, a new CA is made and every identity re-issued (the CRL starts
    empty); when only some identities are missing, those are issued by the existing CA.
    Externally trusted certificates in ``trusted/`` are always kept.

    Parameters
    ----------
    root : Path
        Directory of the PKI (created 0700).
    hosts : sequence of str
        DNS names and IP addresses the servers are reached at (SubjectAltName).
    days : int
        Validity of the application certificates and the CRL's nextUpdate [days].
    force : bool
        Replace an existing CA and all its certificates.
    """
    pki = Pki.at(root)
    _migrate_logged(pki)
    if pki.exists() and not force:
        return pki
    general_names("urn:check", hosts)  # reject a bad host before anything is written
    validity(_now(), days, None, None)  # and bad days
    for sub in (pki.root, pki.ca_cert.parent, pki.own_dir, pki.private_dir, pki.trusted_dir, pki.crl_dir):
        _mkdir(sub)
    now = _now()
    fresh = force or not (pki.ca_cert.is_file() and pki.ca_key.is_file())
    if fresh:
        ca = make_ca(now, days)
        _write_key(pki.ca_key, ca[1])
        _write_cert(pki.ca_cert, ca[0])
        write_file(pki.ca_cert_pem, ca[0].public_bytes(serialization.Encoding.PEM), 0o644)
    else:
        ca = _read_ca(pki)
    start, end = validity(now, days, None, None)
    for name in IDENTITIES:
        if fresh or not (pki.cert_path(name).is_file() and pki.key_path(name).is_file()):
            cert, key = application_cert(name, APPLICATION_URIS[name], hosts, start, end, ca)
            _write_key(pki.key_path(name), key)
            _write_cert(pki.cert_path(name), cert)
    if fresh or not (pki.trusted_dir / CA_TRUST_NAME).is_file():
        _write_cert(pki.trusted_dir / CA_TRUST_NAME, ca[0])
    if fresh or not pki.crl_file.is_file():
        _write_crl(pki, ca, [], 1, now, days)
    return pki


def issue(
    pki: Pki,
    name: str,
    uri: str,
    *,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    days: int = DEFAULT_DAYS,
    not_before: datetime | None = None,
    not_after: datetime | None = None,
) -> tuple[Path, Path]:
    """Issue another CA-signed application certificate, written to own/{name}.der and private/{name}.pem.

    ``not_before`` / ``not_after`` (timezone-aware) replace the default validity
    ``now - 5 min .. now + days`` (tests make expired and not-yet-valid certificates this way).
    An existing certificate of the same name is replaced. Returns (cert_path, key_path).
    """
    ca = _read_ca(pki)
    start, end = validity(_now(), days, not_before, not_after)
    cert, key = application_cert(name, uri, hosts, start, end, ca)
    cert_path, key_path = pki.cert_path(name), pki.key_path(name)
    _write_key(key_path, key)
    _write_cert(cert_path, cert)
    return cert_path, key_path


def self_signed(
    directory: Path,
    name: str,
    uri: str,
    *,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    days: int = DEFAULT_DAYS,
) -> tuple[Path, Path]:
    """A self-signed application certificate outside the PKI (what an external client brings).

    Same extensions as the CA-issued ones. Written to ``directory/{name}.der`` and
    ``directory/{name}.pem`` (0600); returns (cert_path, key_path).
    """
    start, end = validity(_now(), days, None, None)
    cert, key = application_cert(_checked_name(name), uri, hosts, start, end, None)
    cert_path, key_path = Path(directory) / f"{name}.der", Path(directory) / f"{name}.pem"
    _write_key(key_path, key)
    _write_cert(cert_path, cert)
    return cert_path, key_path


def trusted_name(cert: x509.Certificate) -> str:
    """File name of ``cert`` in ``trusted/``: ``{CN}_{sha1}.der`` with the CN reduced to [A-Za-z0-9_.-]."""
    safe = _SAFE.sub("_", common_name(cert)).strip("_.") or "certificate"
    return f"{safe[:64]}_{fingerprint(cert)}.der"


def trust(pki: Pki, file: Path) -> Path:
    """Add an external certificate (DER or PEM) to ``trusted/`` as DER; returns the stored path.

    Trusting a CA certificate trusts everything it issued (asyncua's TrustStore chains to it).
    Adding the same certificate again rewrites the same file.
    """
    cert = read_certificate(file)
    target = pki.trusted_dir / trusted_name(cert)
    _mkdir(pki.trusted_dir)
    _write_cert(target, cert)
    return target


def revoke(pki: Pki, cert_file: Path, *, days: int = DEFAULT_DAYS) -> None:
    """Put a CA-issued certificate's serial on the CA's CRL (re-signed, nextUpdate now + ``days``).

    A certificate the tanklab CA did not issue, or the CA itself, is a :class:`SecurityError`.
    Revoking a certificate twice keeps one entry.
    """
    cert = read_certificate(cert_file)
    ca = _read_ca(pki)
    try:
        cert.verify_directly_issued_by(ca[0])
    except (ValueError, TypeError, InvalidSignature):
        raise SecurityError(f"{cert_file}: not issued by the tanklab CA at {pki.ca_cert}") from None
    if cert.serial_number == ca[0].serial_number:
        raise SecurityError(f"{cert_file}: is the CA itself (replace it with `tankctl pki init --force`)")
    now = _now()
    entries, number = _revoked_entries(pki)
    if all(e.serial_number != cert.serial_number for e in entries):
        entries.append(
            x509.RevokedCertificateBuilder().serial_number(cert.serial_number).revocation_date(now).build()
        )
    _mkdir(pki.crl_dir)
    _write_crl(pki, ca, entries, number + 1, now, days)


def _describe_one(path: Path, kind: str, revoked: set[int]) -> dict[str, Any]:
    cert = read_certificate(path)
    return {
        "name": path.stem,
        "kind": kind,
        "subject": cert.subject.rfc4514_string(),
        "uri": certificate_uri(cert),
        "not_after": cert.not_valid_after_utc.isoformat(),
        "sha1": fingerprint(cert),
        "revoked": cert.serial_number in revoked,
        "path": str(path),
    }


def describe(pki: Pki) -> list[dict[str, Any]]:
    """One dict per certificate for ``tankctl pki show``: own first, then trusted, by file name.

    Keys: ``name`` (file stem), ``kind`` ("own" or "trusted"), ``subject`` (RFC 4514), ``uri``
    (first SubjectAltName URI or None), ``not_after`` (ISO 8601, UTC), ``sha1`` (thumbprint, hex),
    ``revoked`` (serial on the CA's CRL), ``path``. A file in ``trusted/`` that is not a
    certificate is a :class:`SecurityError` (asyncua's TrustStore would fail on it too).
    """
    revoked = {e.serial_number for e in _revoked_entries(pki)[0]}
    rows: list[dict[str, Any]] = []
    if pki.own_dir.is_dir():
        rows += [_describe_one(p, "own", revoked) for p in sorted(pki.own_dir.glob("*.der"))]
    if pki.trusted_dir.is_dir():
        files = sorted(p for p in pki.trusted_dir.iterdir() if p.suffix.lower() in (".der", ".pem"))
        rows += [_describe_one(p, "trusted", revoked) for p in files]
    return rows


# --------------------------------------------------------------------------------------------
# Upgrading homes made before decision 0022; what a third-party client needs
# --------------------------------------------------------------------------------------------


def _is_private_key_pem(path: Path) -> bool:
    try:
        return b"PRIVATE KEY-----" in path.read_bytes()
    except OSError:
        return False


def migrate(pki: Pki) -> list[str]:
    """Bring a PKI made before decision 0022 to the current layout; returns what it changed.

    - ``ca/ca.pem`` holding a private key (the old name of the CA's key) is renamed to
      ``ca/ca-key.pem`` and kept 0600. When both exist with the same bytes the old name is
      removed; with different bytes nothing is touched and a :class:`SecurityError` names both
      (which key signed ``ca/ca.der`` is for a person to decide, not a guess).
    - The PEM copies of the CA certificate and of the CRL are written when their DER files
      exist and they do not.

    Idempotent: a current PKI, or a directory with no PKI, returns ``[]`` and writes nothing.
    A ``ca/ca.pem`` that is not a private key is left alone. Safe against a second process
    migrating at the same time (the rename is atomic; losing the race is not an error).
    """
    changes: list[str] = []
    old, new = pki.legacy_ca_key, pki.ca_key
    if old.is_file() and _is_private_key_pem(old):
        if new.is_file():
            if old.read_bytes() != new.read_bytes():
                raise SecurityError(
                    f"{old}: an old-layout CA private key next to a different {new.name}: "
                    f"keep the key of {pki.ca_cert.name} as {new.name} and remove the other"
                )
            old.unlink(missing_ok=True)
            changes.append(f"{old}: removed (a second copy of the CA private key {new})")
        else:
            try:
                os.replace(old, new)
            except FileNotFoundError:  # another process renamed it first
                pass
            else:
                changes.append(f"{old}: the CA private key, renamed to {new} (0600)")
        if new.is_file():
            os.chmod(new, 0o600)
    if pki.ca_cert.is_file() and not pki.ca_cert_pem.is_file():
        cert = read_certificate(pki.ca_cert)
        write_file(pki.ca_cert_pem, cert.public_bytes(serialization.Encoding.PEM), 0o644)
        changes.append(f"{pki.ca_cert_pem}: wrote the CA certificate in PEM")
    if pki.crl_file.is_file() and not pki.crl_pem.is_file():
        try:
            crl = x509.load_der_x509_crl(pki.crl_file.read_bytes())
        except (OSError, ValueError):
            raise SecurityError(f"{pki.crl_file}: not a readable DER CRL") from None
        write_file(pki.crl_pem, crl.public_bytes(serialization.Encoding.PEM), 0o644)
        changes.append(f"{pki.crl_pem}: wrote the CA's revocation list in PEM")
    return changes


def _migrate_logged(pki: Pki) -> None:
    """:func:`migrate`, each change logged as a warning (an upgrade the owner should know of)."""
    for change in migrate(pki):
        _log.warning("PKI upgraded (decision 0022): %s", change)


@dataclass(frozen=True)
class ClientFile:
    """One file a third-party OPC UA client must be given, or one place it must use.

    ``what`` is the role in words, ``format`` "DER", "PEM" or "directory", ``path`` where it is,
    ``use`` what the client (or its user) does with it.
    """

    what: str
    format: str
    path: Path
    use: str

    def as_dict(self) -> dict[str, str]:
        """JSON-ready: the four fields, the path as a string."""
        return {"what": self.what, "format": self.format, "path": str(self.path), "use": self.use}


def client_files(pki: Pki) -> list[ClientFile]:
    """What a client of the tanklab servers must trust and use, in the order of ``pki show``.

    The CA certificate and its CRL (both in DER and PEM) go into the client's trust list: every
    server certificate chains to the CA, and clients such as node-opcua and UaExpert refuse a
    CA-issued certificate whose issuer's CRL they lack. The server certificates are listed for
    clients that pin a server certificate instead. The client's own certificate goes into the
    site's ``trusted/`` through ``tankctl pki trust``. Nothing here reads or writes a file.
    """
    files = [
        ClientFile("CA certificate", "DER", pki.ca_cert, "client trusts it (its trusted certificates)"),
        ClientFile("CA certificate", "PEM", pki.ca_cert_pem, "client trusts it (its trusted certificates)"),
        ClientFile("CA revocation list", "DER", pki.crl_file, "client trusts it (its trusted CRLs)"),
        ClientFile("CA revocation list", "PEM", pki.crl_pem, "client trusts it (its trusted CRLs)"),
    ]
    files += [
        ClientFile(
            f"{name} server certificate",
            "DER",
            pki.cert_path(name),
            "issued by the CA; trust it directly only if the client cannot trust the CA",
        )
        for name in SERVER_IDENTITIES
    ]
    files.append(
        ClientFile(
            "client certificates",
            "directory",
            pki.trusted_dir,
            "the client's own certificate goes here: tankctl pki trust CLIENT_CERT",
        )
    )
    return files
