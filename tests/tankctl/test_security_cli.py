"""``tankctl pki`` and ``tankctl user`` through typer's CliRunner, on tmp_path security homes.

Each failure must be exactly one line ``tankctl: ...`` on stderr with exit code 2, no traceback;
no output may contain a password or key material.
"""

from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import pytest
import typer
from cryptography.hazmat.primitives import hashes
from typer.testing import CliRunner

from tankctl import security_cli
from tankctl.security_cli import register
from tanklab.errors import SecurityError
from tanklab.tags import Role
from tanklab_io.home import SecurityHome
from tanklab_io.pki import IDENTITIES, read_certificate, self_signed
from tanklab_io.users import UsersFile

NEW_PASSWORD = "a-long-password-42"


def _app() -> typer.Typer:
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)

    @app.callback()
    def root() -> None:
        """Test root: only the security groups are mounted."""

    register(app)
    return app


APP = _app()


@dataclass(frozen=True)
class Ran:
    code: int
    stdout: str
    stderr: str


def run(*args: str, stdin: str | None = None, env: dict[str, str] | None = None) -> Ran:
    result = CliRunner().invoke(APP, list(args), input=stdin, env=env)
    ran = Ran(result.exit_code, result.stdout, result.stderr)
    assert "Traceback" not in ran.stdout + ran.stderr
    assert "PRIVATE KEY" not in ran.stdout + ran.stderr
    return ran


def one_line_error(ran: Ran) -> str:
    """The single stderr line of a failed command (exit code 2)."""
    assert ran.code == 2, (ran.stdout, ran.stderr)
    lines = ran.stderr.strip().splitlines()
    assert len(lines) == 1, ran.stderr
    assert lines[0].startswith("tankctl"), lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def pki_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A home with a PKI made by ``tankctl pki init`` (shared: key generation is the cost)."""
    home = tmp_path_factory.mktemp("home")
    ran = run("pki", "init", "--home", str(home), "--host", "localhost", "--host", "10.1.2.3")
    assert ran.code == 0, ran.stderr
    assert f"PKI at {home / 'pki'}" in ran.stdout
    return home


# --------------------------------------------------------------------------------------------
# pki
# --------------------------------------------------------------------------------------------


def test_the_real_tankctl_mounts_both_groups() -> None:
    from tankctl.cli import app

    for group in ("pki", "user"):
        ran = CliRunner().invoke(app, [group, "--help"])
        assert ran.exit_code == 0, ran.stdout


def test_pki_init_writes_the_layout(pki_home: Path) -> None:
    pki = SecurityHome(pki_home).pki
    assert pki.exists()
    assert stat.S_IMODE(pki.private_dir.stat().st_mode) == 0o700
    assert all(stat.S_IMODE(pki.key_path(n).stat().st_mode) == 0o600 for n in IDENTITIES)
    san = read_certificate(pki.cert_path("plant")).extensions
    assert "10.1.2.3" in str(san)


def test_pki_init_again_keeps_it(pki_home: Path) -> None:
    before = SecurityHome(pki_home).pki.ca_cert.read_bytes()
    ran = run("pki", "init", "--home", str(pki_home))
    assert ran.code == 0
    assert "kept" in ran.stdout
    assert SecurityHome(pki_home).pki.ca_cert.read_bytes() == before


def test_pki_init_bad_arguments(tmp_path: Path) -> None:
    line = one_line_error(run("pki", "init", "--home", str(tmp_path), "--days", "0"))
    assert line == "tankctl: pki init: --days must be a positive number of days, got 0"
    line = one_line_error(run("pki", "init", "--home", str(tmp_path), "--host", "bad host"))
    assert line == "tankctl: host 'bad host': must be a DNS name or an IP address"
    line = one_line_error(run("pki", "init", "--home", str(tmp_path), "--days", "many"))
    assert line.startswith("tankctl pki init: ") and "--days" in line


def test_pki_show_json_and_table(pki_home: Path) -> None:
    ran = run("pki", "show", "--home", str(pki_home), "--json")
    assert ran.code == 0, ran.stderr
    shown = json.loads(ran.stdout)
    rows = shown["certificates"]
    own = {r["name"]: r for r in rows if r["kind"] == "own"}
    assert set(IDENTITIES) <= set(own)
    assert own["supervisor"]["uri"] == "urn:tanklab:supervisor"
    assert any(r["kind"] == "trusted" and r["name"] == "tanklab-ca" for r in rows)
    pki = SecurityHome(pki_home).pki
    files = {(f["what"], f["format"]): f["path"] for f in shown["client_files"]}
    assert files[("CA certificate", "PEM")] == str(pki.ca_cert_pem)
    assert files[("CA revocation list", "DER")] == str(pki.crl_file)
    assert files[("client certificates", "directory")] == str(pki.trusted_dir)
    assert str(pki.ca_key) not in ran.stdout
    assert all(f["exists"] for f in shown["client_files"])
    table = run("pki", "show", "--home", str(pki_home))
    assert table.code == 0
    lines = table.stdout.splitlines()
    # One line per client file (CA cert DER + PEM, CRL DER + PEM, 4 server certs, trusted/),
    # a blank line, then the certificate table.
    assert lines[0].startswith("For a client of these servers")
    assert [ln.split()[-1] for ln in lines[1:3]] == ["certificates)"] * 2
    assert [str(pki.ca_cert) in lines[1], str(pki.ca_cert_pem) in lines[2]] == [True, True]
    assert str(pki.crl_file) in lines[3] and str(pki.crl_pem) in lines[4]
    servers = zip(("plant", "plc", "supervisor", "historian"), lines[5:9], strict=True)
    assert [str(pki.cert_path(n)) in ln for n, ln in servers] == [True] * 4
    assert str(pki.trusted_dir) in lines[9] and "tankctl pki trust" in lines[9]
    assert lines[10] == ""
    assert lines[11].split()[:2] == ["KIND", "NAME"]
    assert own["plc"]["sha1"] in table.stdout
    assert "MISSING" not in table.stdout


def test_pki_show_marks_a_missing_client_file(tmp_path: Path) -> None:
    pki = SecurityHome(tmp_path).pki
    pki.trusted_dir.mkdir(parents=True)  # a PKI directory without its files
    ran = run("pki", "show", "--home", str(tmp_path))
    assert ran.code == 0, ran.stderr
    ca_line = ran.stdout.splitlines()[1]
    assert str(pki.ca_cert) in ca_line and ca_line.endswith("MISSING (tankctl pki init)")
    trusted_line = ran.stdout.splitlines()[9]
    assert str(pki.trusted_dir) in trusted_line and "tankctl pki trust" in trusted_line


def test_pki_commands_upgrade_an_old_home_and_say_so(pki_home: Path) -> None:
    pki = SecurityHome(pki_home).pki
    key = pki.ca_key.read_bytes()
    pki.ca_key.rename(pki.legacy_ca_key)  # the layout before decision 0022
    pki.ca_cert_pem.unlink()
    ran = run("pki", "show", "--home", str(pki_home))
    assert ran.code == 0, ran.stderr
    assert ran.stderr.splitlines() == [
        f"tankctl: PKI upgraded (decision 0022): {pki.legacy_ca_key}: the CA private key, "
        f"renamed to {pki.ca_key} (0600)",
        f"tankctl: PKI upgraded (decision 0022): {pki.ca_cert_pem}: wrote the CA certificate in PEM",
    ]
    assert pki.ca_key.read_bytes() == key and stat.S_IMODE(pki.ca_key.stat().st_mode) == 0o600
    assert run("pki", "show", "--home", str(pki_home)).stderr == ""  # once
    # pki init on an old home upgrades it and keeps the CA (peers keep trusting it).
    pki.ca_key.rename(pki.legacy_ca_key)
    ca = pki.ca_cert.read_bytes()
    init = run("pki", "init", "--home", str(pki_home))
    assert init.code == 0, init.stderr
    assert "renamed to" in init.stderr and "kept" in init.stdout
    assert pki.ca_key.is_file() and not pki.legacy_ca_key.exists() and pki.ca_cert.read_bytes() == ca


def test_pki_show_without_pki(tmp_path: Path) -> None:
    line = one_line_error(run("pki", "show", "--home", str(tmp_path / "none")))
    assert line == f"tankctl: {tmp_path / 'none' / 'pki'}: no PKI (run `tankctl pki init`)"


def test_pki_trust_prints_path_and_fingerprint(pki_home: Path, tmp_path: Path) -> None:
    cert_path, _ = self_signed(tmp_path, "uaexpert", "urn:example:uaexpert")
    sha1 = read_certificate(cert_path).fingerprint(hashes.SHA1()).hex()
    ran = run("pki", "trust", str(cert_path), "--home", str(pki_home))
    assert ran.code == 0, ran.stderr
    stored = SecurityHome(pki_home).pki.trusted_dir / f"tanklab_uaexpert_{sha1}.der"
    assert stored.is_file()
    assert str(stored) in ran.stdout and sha1 in ran.stdout


def test_pki_trust_refuses_junk(pki_home: Path, tmp_path: Path) -> None:
    junk = tmp_path / "junk.pem"
    junk.write_text("-----BEGIN CERTIFICATE-----\nnope\n-----END CERTIFICATE-----\n")
    line = one_line_error(run("pki", "trust", str(junk), "--home", str(pki_home)))
    assert line == f"tankctl: {junk}: not an X.509 certificate (DER or PEM)"
    missing = one_line_error(run("pki", "trust", "--home", str(pki_home)))
    assert missing == "tankctl pki trust: Missing argument 'file'."


def test_pki_revoke(pki_home: Path, tmp_path: Path) -> None:
    pki = SecurityHome(pki_home).pki
    ran = run("pki", "revoke", str(pki.cert_path("cli")), "--home", str(pki_home))
    assert ran.code == 0, ran.stderr
    rows = json.loads(run("pki", "show", "--home", str(pki_home), "--json").stdout)["certificates"]
    revoked = {r["name"] for r in rows if r["revoked"]}
    assert revoked == {"cli"}
    foreign, _ = self_signed(tmp_path, "foreign", "urn:example:foreign")
    line = one_line_error(run("pki", "revoke", str(foreign), "--home", str(pki_home)))
    assert line == f"tankctl: {foreign}: not issued by the tanklab CA at {pki.ca_cert}"


def test_pki_revoke_without_pki(tmp_path: Path) -> None:
    cert, _ = self_signed(tmp_path, "x", "urn:x")
    line = one_line_error(run("pki", "revoke", str(cert), "--home", str(tmp_path / "h")))
    assert line == f"tankctl: {tmp_path / 'h' / 'pki'}: no tanklab CA (run `tankctl pki init`)"


# --------------------------------------------------------------------------------------------
# user
# --------------------------------------------------------------------------------------------


def _users(home: Path) -> UsersFile:
    return UsersFile.load(SecurityHome(home).users_file)


def test_user_add_from_stdin(tmp_path: Path) -> None:
    ran = run(
        "user", "add", "alice", "--role", "Operator", "--home", str(tmp_path), "--password-stdin",
        stdin=NEW_PASSWORD + "\n",
    )  # fmt: skip
    assert ran.code == 0, ran.stderr
    assert NEW_PASSWORD not in ran.stdout + ran.stderr
    assert ran.stdout.strip() == f"added user alice (Operator) in {tmp_path / 'users.json'}"
    assert stat.S_IMODE((tmp_path / "users.json").stat().st_mode) == 0o600
    assert _users(tmp_path).verify("alice", NEW_PASSWORD) is Role.OPERATOR


def test_user_add_from_env_and_home_from_env(tmp_path: Path) -> None:
    env = {"TANKLAB_HOME": str(tmp_path), "TANKLAB_NEW_PASSWORD": NEW_PASSWORD}
    ran = run("user", "add", "eve", "--role", "engineer", env=env)
    assert ran.code == 0, ran.stderr
    assert _users(tmp_path).verify("eve", NEW_PASSWORD) is Role.ENGINEER


def test_user_add_prompts_twice_without_echo(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(security_cli, "_stdin_is_terminal", lambda: True)
    ran = run(
        "user", "add", "bob", "--role", "Observer", "--home", str(tmp_path),
        stdin=f"{NEW_PASSWORD}\n{NEW_PASSWORD}\n",
    )  # fmt: skip
    assert ran.code == 0, ran.stderr
    assert "Password" in ran.stdout
    assert NEW_PASSWORD not in ran.stdout + ran.stderr
    assert _users(tmp_path).verify("bob", NEW_PASSWORD) is Role.OBSERVER


def test_user_add_prompt_at_eof(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(security_cli, "_stdin_is_terminal", lambda: True)
    ran = run("user", "add", "bob", "--role", "Observer", "--home", str(tmp_path), stdin="")
    assert ran.code == 2
    assert (
        ran.stderr.strip() == "tankctl: user add: no password (use --password-stdin or TANKLAB_NEW_PASSWORD)"
    )
    assert not (tmp_path / "users.json").exists()


def test_user_add_never_prompts_without_a_terminal(tmp_path: Path) -> None:
    line = one_line_error(run("user", "add", "bob", "--role", "Observer", "--home", str(tmp_path), stdin=""))
    assert line == (
        "tankctl: user add: no password: stdin is not a terminal "
        "(use --password-stdin or TANKLAB_NEW_PASSWORD)"
    )
    assert not (tmp_path / "users.json").exists()


def test_commands_create_the_home_0700(tmp_path: Path) -> None:
    home = tmp_path / "a" / "home"
    ran = run(
        "user",
        "add",
        "alice",
        "--role",
        "Operator",
        "--home",
        str(home),
        "--password-stdin",
        stdin=NEW_PASSWORD,
    )
    assert ran.code == 0, ran.stderr
    assert stat.S_IMODE(home.stat().st_mode) == 0o700


@pytest.mark.parametrize(
    ("args", "stdin", "expected"),
    [
        (
            ["--role", "Supervisor", "--password-stdin"],
            NEW_PASSWORD,
            "tankctl: user add: --role must be one of Observer, Operator, Engineer, got 'Supervisor'",
        ),
        (
            ["--role", "Operator", "--password-stdin"],
            "short-pw",
            "tankctl: password of 'alice': must have at least 12 characters",
        ),
        (
            ["--role", "Operator", "--password-stdin"],
            "",
            "tankctl: user add: --password-stdin: no password on stdin",
        ),
    ],
)
def test_user_add_refusals(tmp_path: Path, args: list[str], stdin: str, expected: str) -> None:
    line = one_line_error(run("user", "add", "alice", *args, "--home", str(tmp_path), stdin=stdin + "\n"))
    assert line == expected
    assert "short-pw" not in line


def test_user_add_missing_role_is_a_one_line_usage_error(tmp_path: Path) -> None:
    line = one_line_error(run("user", "add", "alice", "--home", str(tmp_path)))
    assert line.startswith("tankctl user add: ") and "--role" in line


def test_user_add_existing_needs_replace_then_list_and_remove(tmp_path: Path) -> None:
    home = ["--home", str(tmp_path)]
    add = ["user", "add", "alice", "--password-stdin", *home]
    assert run(*add, "--role", "Operator", stdin=NEW_PASSWORD).code == 0
    line = one_line_error(run(*add, "--role", "Engineer", stdin=NEW_PASSWORD))
    assert line == f"tankctl: {tmp_path / 'users.json'}: user 'alice' exists (use --replace to change it)"
    replaced = run(*add, "--role", "Engineer", "--replace", stdin="another-password")
    assert replaced.code == 0 and replaced.stdout.startswith("replaced user alice (Engineer)")
    assert (
        run("user", "add", "bob", "--role", "Observer", "--password-stdin", *home, stdin=NEW_PASSWORD).code
        == 0
    )
    listed = run("user", "list", *home)
    assert listed.code == 0
    assert listed.stdout.splitlines() == ["alice  Engineer", "bob    Observer"]
    assert run("user", "remove", "alice", *home).code == 0
    assert _users(tmp_path).names() == ["bob"]
    line = one_line_error(run("user", "remove", "alice", *home))
    assert line == f"tankctl: {tmp_path / 'users.json'}: no user 'alice'"


def test_user_list_empty_and_corrupt(tmp_path: Path) -> None:
    empty = run("user", "list", "--home", str(tmp_path))
    assert empty.code == 0 and empty.stdout.strip() == f"no users in {tmp_path / 'users.json'}"
    (tmp_path / "users.json").write_text('{"users": {"x": {"role": "PLC", "password_hash": "h"}}}')
    line = one_line_error(run("user", "list", "--home", str(tmp_path)))
    assert line.startswith(f"tankctl: {tmp_path / 'users.json'}: users.x.role: must be one of")


def test_pki_containers_lays_out_each_tier_and_says_where(tmp_path: Path) -> None:
    home = tmp_path / "home"
    assert run("pki", "init", "--home", str(home)).code == 0
    refused = one_line_error(run("pki", "containers", "--home", str(home)))
    assert "no users file" in refused  # a tier without users could serve no login
    added = run(
        "user",
        "add",
        "alice",
        "--role",
        "Operator",
        "--home",
        str(home),
        "--password-stdin",
        stdin="pw-123456789\n",
    )
    assert added.code == 0
    if os.geteuid() != 0:
        line = one_line_error(run("pki", "containers", "--home", str(home)))
        assert "needs root" in line and "sudo" in line
        return
    ran = run("pki", "containers", "--home", str(home))
    assert ran.code == 0, ran.stderr
    lines = ran.stdout.splitlines()
    for tier, line in zip(("plant", "plc", "supervisor", "historian"), lines, strict=False):
        assert line == f"{tier}: {home / 'containers' / tier} (10 files, owner 10001:10001, key 0600)"
    assert lines[-1] == f"docker-compose.yml mounts {home / 'containers'}/TIER read-only at /etc/tanklab"
    assert (home / "containers" / "plc" / "pki" / "private" / "plc.pem").stat().st_uid == 10001


def test_pki_containers_refuses_a_missing_pki_in_one_line(tmp_path: Path) -> None:
    line = one_line_error(run("pki", "containers", "--home", str(tmp_path / "none")))
    assert "incomplete PKI" in line
    line = one_line_error(run("pki", "containers", "--home", str(tmp_path), "--uid", "x"))
    assert "--uid" in line


# --------------------------------------------------------------------------------------------
# user add-external (decision 0055)
# --------------------------------------------------------------------------------------------


def test_add_external_issues_a_certificate_in_role_external(pki_home: Path) -> None:
    from tanklab_io.external import ExternalIdentities, load_external

    ran = run("user", "add-external", "ctl1", "--home", str(pki_home))
    assert ran.code == 0, ran.stderr
    sec = SecurityHome(pki_home)
    cert = sec.pki.cert_path("external-ctl1")
    assert (
        ran.stdout.splitlines()[0] == "added external controller ctl1 (External, urn:tanklab:external-ctl1)"
    )
    assert f"certificate  {cert}" in ran.stdout
    assert stat.S_IMODE(sec.pki.key_path("external-ctl1").stat().st_mode) == 0o600
    assert stat.S_IMODE((pki_home / "external.json").stat().st_mode) == 0o600
    assert "urn:tanklab:external-ctl1" in str(read_certificate(cert).extensions)
    assert set(load_external(sec)) == {"ctl1"}
    ids = ExternalIdentities(sec).current()
    assert ids == {cert.read_bytes(): ("external-ctl1", Role.EXTERNAL)}
    listed = run("user", "list", "--home", str(pki_home))
    assert "ctl1  External (certificate urn:tanklab:external-ctl1)" in listed.stdout
    # Again without --replace: refused, nothing re-issued.
    before = cert.read_bytes()
    line = one_line_error(run("user", "add-external", "ctl1", "--home", str(pki_home)))
    assert "external controller 'ctl1' exists (use --replace to re-issue)" in line
    assert cert.read_bytes() == before
    # A certificate file swapped behind the registry's back is no External identity.
    assert run("user", "add-external", "ctl2", "--home", str(pki_home)).code == 0
    ctl2 = sec.pki.cert_path("external-ctl2")
    ctl2.write_bytes(before)
    assert ("external-ctl2", Role.EXTERNAL) not in ExternalIdentities(sec).current().values()
    assert run("user", "remove-external", "ctl2", "--home", str(pki_home)).code == 0
    assert set(load_external(sec)) == {"ctl1"}


def test_add_external_bad_input_is_one_line(pki_home: Path, tmp_path: Path) -> None:
    bad = one_line_error(run("user", "add-external", "no/slash", "--home", str(pki_home)))
    assert "external controller name 'no/slash': must match" in bad
    no_pki = one_line_error(run("user", "add-external", "ctl", "--home", str(tmp_path / "empty")))
    assert "no CA; run `tankctl pki init" in no_pki
    unknown = one_line_error(run("user", "remove-external", "nobody", "--home", str(pki_home)))
    assert "no external controller 'nobody'" in unknown
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "external.json").write_text(
        '{"version": 1, "external": {"x": {"role": "Engineer"}}}'
    )
    junk = one_line_error(run("user", "list", "--home", str(tmp_path / "junk")))
    assert "external.json: external.x: must be an object with role and sha256 only" in junk


def test_a_password_user_cannot_be_external(pki_home: Path) -> None:
    line = one_line_error(
        run(
            "user",
            "add",
            "bob",
            "--role",
            "External",
            "--home",
            str(pki_home),
            "--password-stdin",
            stdin=NEW_PASSWORD,
        )
    )
    assert line == (
        "tankctl: user add: --role External is a certificate identity, not a password login: "
        "use `tankctl user add-external bob`"
    )
    assert UsersFile.load(pki_home / "users.json").get("bob") is None
    with pytest.raises(SecurityError, match="External is a certificate identity, never a password login"):
        UsersFile.load(pki_home / "users.json").add("bob", Role.EXTERNAL, NEW_PASSWORD)
