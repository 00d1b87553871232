"""X.509 for the tanklab PKI: the CA and OPC UA application-instance certificates, built in memory.

What an application certificate carries, and why, is in :mod:`tanklab_io.pki`'s docstring
(SubjectAltName with the ApplicationUri and the hosts, the OPC UA key usages, serverAuth and
clientAuth, cA=false, key identifiers; RSA 2048 keys, SHA-256 signatures). These functions build
and read certificates and keys; :mod:`tanklab_io.pki` decides where they live and writes them.
Nothing here reads the clock (``now`` is an argument) or touches a file.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence
from datetime import datetime, timedelta

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from tanklab.errors import SecurityError

CA_DAYS = 3650
"""Validity of the CA certificate [days] (at least that of the certificates it issues)."""

KEY_BITS = 2048
"""RSA modulus size [bits] of every key."""

CLOCK_SKEW = timedelta(minutes=5)
"""notBefore is set this far in the past so that a peer whose clock lags still accepts a new cert."""

ORGANIZATION = "tanklab"
"""The Organization of every certificate's subject."""


def subject(common_name: str) -> x509.Name:
    """The subject (and a self-signed issuer) name: CN and the tanklab Organization."""
    return x509.Name(
        [
            x509.NameAttribute(NameOID.COMMON_NAME, common_name),
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, ORGANIZATION),
        ]
    )


def general_names(uri: str, hosts: Sequence[str]) -> list[x509.GeneralName]:
    """SubjectAltName entries: the ApplicationUri, then one DNSName or IPAddress per host."""
    if not uri or any(c.isspace() for c in uri):
        raise SecurityError(f"application URI {uri!r}: must be a non-empty URI without spaces")
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(uri)]
    for host in hosts:
        if not host or any(c.isspace() for c in host):
            raise SecurityError(f"host {host!r}: must be a DNS name or an IP address")
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            try:
                names.append(x509.DNSName(host))
            except ValueError as e:  # non-ASCII names
                raise SecurityError(f"host {host!r}: must be a DNS name or an IP address") from e
    return names


def application_extensions(
    builder: x509.CertificateBuilder,
    uri: str,
    hosts: Sequence[str],
    public_key: rsa.RSAPublicKey,
    issuer_key: rsa.RSAPublicKey,
) -> x509.CertificateBuilder:
    """The OPC UA application-instance extensions (see the module docstring)."""
    return (
        builder.add_extension(x509.SubjectAlternativeName(general_names(uri, hosts)), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=True,
                key_encipherment=True,
                data_encipherment=True,
                key_agreement=False,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
            critical=False,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public_key), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(issuer_key), critical=False)
    )


def validity(
    now: datetime, days: int, not_before: datetime | None, not_after: datetime | None
) -> tuple[datetime, datetime]:
    """(notBefore, notAfter): now - CLOCK_SKEW .. now + days, each replaceable."""
    if days <= 0:
        raise SecurityError(f"days: must be a positive number of days, got {days}")
    start = not_before if not_before is not None else now - CLOCK_SKEW
    end = not_after if not_after is not None else now + timedelta(days=days)
    if end <= start:
        raise SecurityError(f"validity: not_after {end.isoformat()} is not after {start.isoformat()}")
    return start, end


def fingerprint(cert: x509.Certificate) -> str:
    """SHA-1 thumbprint as 40 lowercase hex digits (what OPC UA calls the certificate thumbprint)."""
    return cert.fingerprint(hashes.SHA1()).hex()  # a thumbprint (OPC UA names files by it), not a signature


def common_name(cert: x509.Certificate) -> str:
    """The subject's CommonName (empty when it has none)."""
    attrs = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    value = attrs[0].value if attrs else ""
    return value if isinstance(value, str) else value.decode("utf-8", "replace")


def certificate_uri(cert: x509.Certificate) -> str | None:
    """The ApplicationUri of the SubjectAltName (None without one)."""
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None


def key_pem(key: rsa.RSAPrivateKey) -> bytes:
    """The key as unencrypted PKCS#8 PEM (the file is 0600; see :mod:`tanklab_io.pki`)."""
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def new_key() -> rsa.RSAPrivateKey:
    """A fresh RSA key of :data:`KEY_BITS` bits."""
    return rsa.generate_private_key(public_exponent=65537, key_size=KEY_BITS)


def make_ca(now: datetime, days: int) -> tuple[x509.Certificate, rsa.RSAPrivateKey]:
    """A self-signed CA (cA=true, path length 0, keyCertSign + cRLSign), valid from ``now`` for
    at least :data:`CA_DAYS` days; its certificate and key."""
    key = new_key()
    name = subject("tanklab CA")
    start, end = validity(now, max(days, CA_DAYS), None, None)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    return cert, key


def application_cert(
    name: str,
    uri: str,
    hosts: Sequence[str],
    start: datetime,
    end: datetime,
    issuer: tuple[x509.Certificate, rsa.RSAPrivateKey] | None,
) -> tuple[x509.Certificate, rsa.RSAPrivateKey]:
    """An application certificate signed by ``issuer`` (CA cert, CA key), or self-signed if None."""
    key = new_key()
    own = subject(f"tanklab {name}")
    issuer_name, signer = (issuer[0].subject, issuer[1]) if issuer else (own, key)
    builder = (
        x509.CertificateBuilder()
        .subject_name(own)
        .issuer_name(issuer_name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
    )
    builder = application_extensions(builder, uri, hosts, key.public_key(), signer.public_key())
    return builder.sign(signer, hashes.SHA256()), key
