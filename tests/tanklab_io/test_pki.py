"""The tanklab PKI, checked field by field and against asyncua 2.1.0's own trust store and validator.

One PKI is made for the module (RSA key generation is the cost): the identities, an external
self-signed certificate that is trusted, one that is not, an expired CA-issued certificate (a
fixed validity in 2020, no clock read), and a CA-issued ``victim`` that is revoked.
"""

from __future__ import annotations

import stat
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import pytest
from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.uacrypto import load_certificate, load_private_key
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from tanklab.errors import SecurityError
from tanklab.tags import APPLICATION_URIS
from tanklab_io.home import SecurityHome, provision
from tanklab_io.pki import (
    IDENTITIES,
    SERVER_IDENTITIES,
    Pki,
    client_files,
    describe,
    init_pki,
    issue,
    migrate,
    read_certificate,
    revoke,
    self_signed,
    trust,
)

STRICT = CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT


@dataclass(frozen=True)
class World:
    pki: Pki
    external: Path  # self-signed, trusted
    stranger: Path  # self-signed, not trusted
    expired: Path  # CA-issued, valid 2020-01-01 .. 2021-01-01
    victim: Path  # CA-issued, revoked
    outside: Path  # scratch directory outside the PKI


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> World:
    base = tmp_path_factory.mktemp("pki")
    outside = base / "outside"
    outside.mkdir()
    pki = init_pki(base / "pki")
    external, _ = self_signed(outside, "uaexpert", "urn:example:uaexpert")
    trust(pki, external)
    stranger, _ = self_signed(outside, "stranger", "urn:example:stranger")
    expired, _ = issue(
        pki,
        "expired",
        "urn:tanklab:expired",
        not_before=datetime(2020, 1, 1, tzinfo=UTC),
        not_after=datetime(2021, 1, 1, tzinfo=UTC),
    )
    victim, _ = issue(pki, "victim", "urn:tanklab:victim")
    revoke(pki, victim)
    return World(pki, external, stranger, expired, victim, outside)


async def store(pki: Pki) -> TrustStore:
    ts = TrustStore([pki.trusted_dir], [pki.crl_dir])
    await ts.load()
    return ts


def client(uri: str) -> ua.ApplicationDescription:
    return ua.ApplicationDescription(ApplicationUri=uri, ApplicationType=ua.ApplicationType.Client)


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def files_of(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------------------------
# Layout and file modes
# --------------------------------------------------------------------------------------------


def test_layout_paths(tmp_path: Path) -> None:
    pki = Pki.at(tmp_path)
    assert pki.ca_cert == tmp_path / "ca" / "ca.der"
    assert pki.ca_key == tmp_path / "ca" / "ca-key.pem"
    assert pki.ca_cert_pem == tmp_path / "ca" / "ca-cert.pem"
    assert pki.crl_pem == tmp_path / "crl" / "ca.crl.pem"
    assert pki.trusted_dir == tmp_path / "trusted"
    assert pki.crl_dir == tmp_path / "crl"
    assert pki.cert_path("plc") == tmp_path / "own" / "plc.der"
    assert pki.key_path("plc") == tmp_path / "private" / "plc.pem"
    assert not pki.exists()
    with pytest.raises(SecurityError):
        pki.cert_path("../etc/passwd")


def test_directories_0700_keys_0600(world: World) -> None:
    pki = world.pki
    assert pki.exists()
    for d in (pki.root, pki.ca_cert.parent, pki.own_dir, pki.private_dir, pki.trusted_dir, pki.crl_dir):
        assert mode(d) == 0o700, d
    for key in [pki.ca_key, *(pki.key_path(n) for n in IDENTITIES)]:
        assert mode(key) == 0o600, key
    assert (pki.crl_dir / "ca.crl.der").is_file()
    assert (pki.trusted_dir / "tanklab-ca.der").read_bytes() == pki.ca_cert.read_bytes()


def test_private_keys_are_unencrypted_pkcs8_pem_matching_their_certificate(world: World) -> None:
    for name in IDENTITIES:
        pem = world.pki.key_path(name).read_bytes()
        assert pem.startswith(b"-----BEGIN PRIVATE KEY-----")  # PKCS#8, not "RSA PRIVATE KEY"
        key = serialization.load_pem_private_key(pem, password=None)
        assert isinstance(key, rsa.RSAPrivateKey)
        assert key.key_size == 2048
        cert = read_certificate(world.pki.cert_path(name))
        assert cert.public_key().public_numbers() == key.public_key().public_numbers()


# --------------------------------------------------------------------------------------------
# Certificate contents
# --------------------------------------------------------------------------------------------


def test_ca_certificate(world: World) -> None:
    ca = read_certificate(world.pki.ca_cert)
    assert ca.subject == ca.issuer
    ca.verify_directly_issued_by(ca)
    bc = ca.extensions.get_extension_for_class(x509.BasicConstraints)
    assert bc.critical and bc.value.ca
    ku = ca.extensions.get_extension_for_class(x509.KeyUsage).value
    assert ku.key_cert_sign and ku.crl_sign
    assert isinstance(ca.signature_hash_algorithm, hashes.SHA256)


@pytest.mark.parametrize("name", IDENTITIES)
def test_identity_certificate_extensions(world: World, name: str) -> None:
    ca = read_certificate(world.pki.ca_cert)
    cert = read_certificate(world.pki.cert_path(name))
    cert.verify_directly_issued_by(ca)
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == f"tanklab {name}"
    assert isinstance(cert.signature_hash_algorithm, hashes.SHA256)
    ext = cert.extensions
    san = ext.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.UniformResourceIdentifier) == [APPLICATION_URIS[name]]
    assert san.get_values_for_type(x509.DNSName) == ["localhost"]
    assert [str(ip) for ip in san.get_values_for_type(x509.IPAddress)] == ["127.0.0.1"]
    ku = ext.get_extension_for_class(x509.KeyUsage)
    assert ku.critical
    assert ku.value.digital_signature and ku.value.content_commitment
    assert ku.value.key_encipherment and ku.value.data_encipherment
    assert not ku.value.key_cert_sign
    eku = ext.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert set(eku) == {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH}
    bc = ext.get_extension_for_class(x509.BasicConstraints)
    assert bc.critical and not bc.value.ca
    ski = ext.get_extension_for_class(x509.SubjectKeyIdentifier).value
    assert ski == x509.SubjectKeyIdentifier.from_public_key(cert.public_key())
    aki = ext.get_extension_for_class(x509.AuthorityKeyIdentifier).value
    ca_ski = ca.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value
    assert aki.key_identifier == ca_ski.digest


def test_hosts_go_into_the_subject_alt_name(tmp_path: Path, world: World) -> None:
    cert_path, _ = issue(world.pki, "remote", "urn:tanklab:remote", hosts=("plc.example", "10.0.0.7", "::1"))
    san = read_certificate(cert_path).extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.DNSName) == ["plc.example"]
    assert [str(ip) for ip in san.get_values_for_type(x509.IPAddress)] == ["10.0.0.7", "::1"]
    with pytest.raises(SecurityError, match="host 'bad host'"):
        issue(world.pki, "remote2", "urn:x", hosts=("bad host",))


def test_explicit_validity(world: World) -> None:
    cert = read_certificate(world.expired)
    assert cert.not_valid_before_utc == datetime(2020, 1, 1, tzinfo=UTC)
    assert cert.not_valid_after_utc == datetime(2021, 1, 1, tzinfo=UTC)


# --------------------------------------------------------------------------------------------
# asyncua 2.1.0 accepts them
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", IDENTITIES)
async def test_asyncua_loads_certificate_and_key(world: World, name: str) -> None:
    cert = await load_certificate(world.pki.cert_path(name))
    key = await load_private_key(world.pki.key_path(name))
    assert cert.public_key().public_numbers() == key.public_key().public_numbers()


async def test_truststore_trusts_identities_and_the_trusted_external_cert(world: World) -> None:
    ts = await store(world.pki)
    for name in IDENTITIES:
        cert = await load_certificate(world.pki.cert_path(name))
        assert ts.is_trusted(cert), name
        assert not ts.is_revoked(cert), name
    assert ts.is_trusted(await load_certificate(world.external))


async def test_truststore_refuses_untrusted_and_flags_revoked(world: World) -> None:
    ts = await store(world.pki)
    assert not ts.is_trusted(await load_certificate(world.stranger))
    victim = await load_certificate(world.victim)
    assert ts.is_trusted(victim)  # still chains to the CA ...
    assert ts.is_revoked(victim)  # ... but is on the CRL
    assert not ts.validate(victim)


@pytest.mark.parametrize("name", IDENTITIES)
async def test_validator_accepts_each_identity(world: World, name: str) -> None:
    validator = CertificateValidator(STRICT, await store(world.pki))
    await validator.validate(
        await load_certificate(world.pki.cert_path(name)), client(APPLICATION_URIS[name])
    )


async def test_validator_accepts_trusted_external(world: World) -> None:
    validator = CertificateValidator(STRICT, await store(world.pki))
    await validator.validate(await load_certificate(world.external), client("urn:example:uaexpert"))


@pytest.mark.parametrize(
    ("which", "uri", "status"),
    [
        ("expired", "urn:tanklab:expired", ua.StatusCodes.BadCertificateTimeInvalid),
        ("cli", "urn:tanklab:plc", ua.StatusCodes.BadCertificateUriInvalid),
        ("stranger", "urn:example:stranger", ua.StatusCodes.BadCertificateUntrusted),
        ("victim", "urn:tanklab:victim", ua.StatusCodes.BadCertificateRevoked),
    ],
)
async def test_validator_refusals(world: World, which: str, uri: str, status: int) -> None:
    paths = {
        "expired": world.expired,
        "cli": world.pki.cert_path("cli"),
        "stranger": world.stranger,
        "victim": world.victim,
    }
    validator = CertificateValidator(STRICT, await store(world.pki))
    with pytest.raises(ServiceError) as caught:
        await validator.validate(await load_certificate(paths[which]), client(uri))
    assert caught.value.code == status


# --------------------------------------------------------------------------------------------
# init_pki: idempotent, --force, repair
# --------------------------------------------------------------------------------------------


def test_init_keeps_a_complete_pki(world: World) -> None:
    before = files_of(world.pki.root)
    assert init_pki(world.pki.root) == world.pki
    assert files_of(world.pki.root) == before


def test_force_replaces_and_missing_identity_is_reissued_by_the_same_ca(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    pki = init_pki(tmp_path / "pki", hosts=("plant.local",))
    assert capsys.readouterr() == ("", "")  # nothing printed, least of all key material
    assert caplog.records == []
    ca = pki.ca_cert.read_bytes()
    plant = pki.cert_path("plant").read_bytes()
    pki.cert_path("plc").unlink()
    assert not pki.exists()
    init_pki(pki.root)
    assert pki.exists()
    assert pki.ca_cert.read_bytes() == ca
    assert pki.cert_path("plant").read_bytes() == plant
    read_certificate(pki.cert_path("plc")).verify_directly_issued_by(read_certificate(pki.ca_cert))
    init_pki(pki.root, force=True)
    assert pki.ca_cert.read_bytes() != ca
    assert pki.cert_path("plant").read_bytes() != plant
    crl = x509.load_der_x509_crl((pki.crl_dir / "ca.crl.der").read_bytes())
    assert list(crl) == []


# --------------------------------------------------------------------------------------------
# trust, revoke, describe
# --------------------------------------------------------------------------------------------


def test_trust_pem_is_stored_as_der_named_by_cn_and_sha1(world: World) -> None:
    cert = read_certificate(world.stranger)
    pem = world.outside / "stranger-copy.pem"
    pem.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    other = Pki.at(world.outside / "other-pki")
    stored = trust(other, pem)
    sha1 = cert.fingerprint(hashes.SHA1()).hex()
    assert stored == other.trusted_dir / f"tanklab_stranger_{sha1}.der"
    assert stored.read_bytes() == cert.public_bytes(serialization.Encoding.DER)
    assert trust(other, pem) == stored  # again: same file


def test_trust_refuses_a_file_that_is_not_a_certificate(world: World) -> None:
    junk = world.outside / "junk.der"
    junk.write_bytes(b"not a certificate")
    with pytest.raises(SecurityError, match=r"junk\.der: not an X\.509 certificate"):
        trust(world.pki, junk)
    with pytest.raises(SecurityError, match=r"missing\.der: cannot read"):
        trust(world.pki, world.outside / "missing.der")


def test_crl_is_signed_by_the_ca_and_revoking_twice_keeps_one_entry(world: World) -> None:
    ca = read_certificate(world.pki.ca_cert)
    serial = read_certificate(world.victim).serial_number
    revoke(world.pki, world.victim)
    crl = x509.load_der_x509_crl((world.pki.crl_dir / "ca.crl.der").read_bytes())
    assert crl.issuer == ca.subject
    assert crl.is_signature_valid(ca.public_key())
    assert [e.serial_number for e in crl] == [serial]
    assert crl.extensions.get_extension_for_class(x509.CRLNumber).value.crl_number == 3  # init 1, 2 revokes


def test_revoke_refuses_foreign_certificates_and_the_ca(world: World) -> None:
    with pytest.raises(SecurityError, match="not issued by the tanklab CA"):
        revoke(world.pki, world.external)
    with pytest.raises(SecurityError, match="is the CA itself"):
        revoke(world.pki, world.pki.ca_cert)


def test_describe(world: World) -> None:
    rows = {(r["kind"], r["name"]): r for r in describe(world.pki)}
    plc = rows[("own", "plc")]
    cert = read_certificate(world.pki.cert_path("plc"))
    assert plc["uri"] == "urn:tanklab:plc"
    assert plc["sha1"] == cert.fingerprint(hashes.SHA1()).hex()
    assert plc["not_after"] == cert.not_valid_after_utc.isoformat()
    assert plc["subject"] == "O=tanklab,CN=tanklab plc"
    assert plc["revoked"] is False
    assert rows[("own", "victim")]["revoked"] is True
    assert rows[("trusted", "tanklab-ca")]["uri"] is None
    trusted_uris = {r["uri"] for (kind, _), r in rows.items() if kind == "trusted"}
    assert trusted_uris == {None, "urn:example:uaexpert"}
    assert {name for kind, name in rows if kind == "own"} >= set(IDENTITIES)


# --------------------------------------------------------------------------------------------
# PEM copies, the client's files, homes made before decision 0022
# --------------------------------------------------------------------------------------------


def test_pem_copies_are_the_der_files(world: World) -> None:
    pki = world.pki
    assert read_certificate(pki.ca_cert_pem) == read_certificate(pki.ca_cert)
    assert pki.ca_cert_pem.read_bytes().startswith(b"-----BEGIN CERTIFICATE-----")
    assert mode(pki.ca_cert_pem) == 0o644
    # The CRL's PEM copy follows every re-signing (the world revoked ``victim``).
    pem = x509.load_pem_x509_crl(pki.crl_pem.read_bytes())
    assert pem.public_bytes(serialization.Encoding.DER) == pki.crl_file.read_bytes()
    assert read_certificate(world.victim).serial_number in {e.serial_number for e in pem}


def test_client_files_name_what_a_client_trusts_and_they_exist(world: World) -> None:
    files = client_files(world.pki)
    pki = world.pki
    assert [(f.what, f.format, f.path) for f in files[:4]] == [
        ("CA certificate", "DER", pki.ca_cert),
        ("CA certificate", "PEM", pki.ca_cert_pem),
        ("CA revocation list", "DER", pki.crl_file),
        ("CA revocation list", "PEM", pki.crl_pem),
    ]
    assert [f.path for f in files[4:-1]] == [pki.cert_path(n) for n in SERVER_IDENTITIES]
    assert (files[-1].format, files[-1].path) == ("directory", pki.trusted_dir)
    assert "tankctl pki trust" in files[-1].use
    assert all(f.path.exists() for f in files)
    assert pki.ca_key not in {f.path for f in files}  # the key is never among a client's files
    assert files[0].as_dict() == {
        "what": "CA certificate",
        "format": "DER",
        "path": str(pki.ca_cert),
        "use": files[0].use,
    }


def _old_layout(root: Path) -> tuple[Pki, bytes]:
    """A PKI as ``tankctl pki init`` made it before decision 0022; returns it and its CA key."""
    return _old_layout_of(init_pki(root))


def _old_layout_of(pki: Pki) -> tuple[Pki, bytes]:
    """``pki`` turned back into the layout before decision 0022; returns it and its CA key."""
    key = pki.ca_key.read_bytes()
    pki.ca_key.rename(pki.legacy_ca_key)
    pki.ca_cert_pem.unlink()
    pki.crl_pem.unlink()
    return pki, key


def test_an_old_home_is_upgraded_on_first_use_and_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    pki, key = _old_layout(tmp_path / "pki")
    ca = pki.ca_cert.read_bytes()
    assert not pki.exists()  # so that provision / up run init_pki, which upgrades it
    with caplog.at_level("WARNING", logger="tanklab_io.pki"):
        init_pki(pki.root)
    assert pki.exists()
    assert not pki.legacy_ca_key.exists()
    assert pki.ca_key.read_bytes() == key and mode(pki.ca_key) == 0o600
    assert pki.ca_cert.read_bytes() == ca  # the same CA: peers keep trusting it
    assert read_certificate(pki.ca_cert_pem) == read_certificate(pki.ca_cert)
    assert (
        x509.load_pem_x509_crl(pki.crl_pem.read_bytes()).public_bytes(serialization.Encoding.DER)
        == pki.crl_file.read_bytes()
    )
    logged = [r.getMessage() for r in caplog.records if r.name == "tanklab_io.pki"]
    assert logged == [
        f"PKI upgraded (decision 0022): {pki.legacy_ca_key}: the CA private key, "
        f"renamed to {pki.ca_key} (0600)",
        f"PKI upgraded (decision 0022): {pki.ca_cert_pem}: wrote the CA certificate in PEM",
        f"PKI upgraded (decision 0022): {pki.crl_pem}: wrote the CA's revocation list in PEM",
    ]
    assert migrate(pki) == []  # idempotent


def test_issue_and_revoke_upgrade_an_old_home_too(tmp_path: Path) -> None:
    pki, key = _old_layout(tmp_path / "pki")
    cert, _ = issue(pki, "hmi", "urn:example:hmi")
    assert pki.ca_key.read_bytes() == key and not pki.legacy_ca_key.exists()
    read_certificate(cert).verify_directly_issued_by(read_certificate(pki.ca_cert))
    revoke(pki, cert)
    assert read_certificate(cert).serial_number in {
        e.serial_number for e in x509.load_pem_x509_crl(pki.crl_pem.read_bytes())
    }


def test_migrate_leaves_a_non_key_alone_and_refuses_two_different_keys(tmp_path: Path) -> None:
    pki = init_pki(tmp_path / "pki")
    assert migrate(pki) == []
    # A user who put the CA certificate at ca/ca.pem (what the old name suggested) keeps it.
    pki.legacy_ca_key.write_bytes(pki.ca_cert_pem.read_bytes())
    assert migrate(pki) == [] and pki.legacy_ca_key.is_file()
    # A second copy of the key under the old name is removed; a different key is refused.
    pki.legacy_ca_key.write_bytes(pki.ca_key.read_bytes())
    removed = f"{pki.legacy_ca_key}: removed (a second copy of the CA private key {pki.ca_key})"
    assert migrate(pki) == [removed]
    assert not pki.legacy_ca_key.exists()
    other = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    pki.legacy_ca_key.write_bytes(
        other.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    with pytest.raises(SecurityError, match=r"an old-layout CA private key next to a different ca-key\.pem"):
        migrate(pki)
    assert pki.legacy_ca_key.is_file() and pki.ca_key.is_file()


def test_migrate_on_no_pki_writes_nothing(tmp_path: Path) -> None:
    assert migrate(Pki.at(tmp_path / "none")) == []
    assert not (tmp_path / "none").exists()


def test_provision_upgrades_an_old_home_and_keeps_its_users(tmp_path: Path) -> None:
    home = SecurityHome(tmp_path / "home")
    assert provision(home) is not None  # first use: PKI and the engineer account
    pki, key = _old_layout_of(home.pki)
    assert provision(home) is None  # users exist: no new account
    assert pki.ca_key.read_bytes() == key and not pki.legacy_ca_key.exists() and pki.exists()
