"""A client identity's certificate and key are read and checked once per process while their
files are unchanged (``tanklab_io.ua_security.identity_material``, decision 0039), and read
again as soon as either file changes: nothing is kept across processes or written anywhere."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from asyncua.crypto.uacrypto import load_certificate, load_private_key
from cryptography.hazmat.primitives import serialization

from tanklab_io.home import SecurityHome
from tanklab_io.ua_security import identity_material


def _copy(home: SecurityHome, name: str, to: Path) -> tuple[Path, Path]:
    cert, key = to / "own" / "id.der", to / "private" / "id.pem"
    for d in (cert.parent, key.parent):
        d.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(home.pki.cert_path(name), cert)
    shutil.copyfile(home.pki.key_path(name), key)
    return cert, key


def _der(key: object) -> bytes:
    return key.private_bytes(  # type: ignore[attr-defined]
        serialization.Encoding.DER, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


async def test_the_material_is_what_asyncua_loads_and_is_read_once(
    security_home: SecurityHome, tmp_path: Path
) -> None:
    cert_path, key_path = _copy(security_home, "cli", tmp_path)
    cert, key = identity_material(cert_path, key_path)
    assert cert == await load_certificate(str(cert_path))
    assert _der(key) == _der(await load_private_key(str(key_path)))
    again = identity_material(cert_path, key_path)
    assert again[0] is cert and again[1] is key  # not read (nor checked) a second time


def test_a_changed_file_is_read_again(security_home: SecurityHome, tmp_path: Path) -> None:
    cert_path, key_path = _copy(security_home, "cli", tmp_path)
    cert, key = identity_material(cert_path, key_path)
    # Another identity's certificate and key under the same names: a re-issued identity.
    other = _copy(security_home, "plc", tmp_path / "other")
    os.replace(other[0], cert_path)
    os.replace(other[1], key_path)
    new_cert, new_key = identity_material(cert_path, key_path)
    assert new_cert != cert and _der(new_key) != _der(key)
    assert new_cert == identity_material(cert_path, key_path)[0]
