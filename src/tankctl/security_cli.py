"""``tankctl pki`` and ``tankctl user``: the PKI and the users file of a security home.

::

    tankctl pki init [--home DIR] [--host HOST ...] [--days N] [--force]
    tankctl pki trust FILE [--home DIR]          add an external certificate (DER or PEM)
    tankctl pki revoke FILE [--home DIR]         put a CA-issued certificate on the CRL
    tankctl pki show [--home DIR] [--json]      what a client must trust and use; the certificates
    tankctl pki containers [--home DIR] [--uid N] [--gid N]   per-tier copies for docker-compose.yml
    tankctl user add NAME --role ROLE [--home DIR] [--password-stdin] [--replace]
    tankctl user list [--home DIR]
    tankctl user remove NAME [--home DIR]
    tankctl user add-external NAME [--home DIR] [--host HOST ...] [--days N] [--replace]
    tankctl user remove-external NAME [--home DIR]

``user add-external`` issues an external controller's certificate from the site CA
(``own/external-NAME.der``, ApplicationUri ``urn:tanklab:external-NAME``) and records it in role
External (``external.json``, :mod:`tanklab_io.external`); an external controller has no password,
so ``user add --role External`` is refused with a one-line pointer to ``add-external``.

``--home`` defaults to ``$TANKLAB_HOME``, else ``$XDG_CONFIG_HOME/tanklab``, else
``~/.config/tanklab``. ``user add`` reads the password from stdin (``--password-stdin``, one
line), else from ``TANKLAB_NEW_PASSWORD``, else prompts twice without echo; no command prints a
password or key material.

Every ``pki`` command first upgrades a PKI made before decision 0022 (the CA's private key
renamed from ``ca/ca.pem`` to ``ca/ca-key.pem``, PEM copies of the CA certificate and CRL) and
says so on stderr, one line per change.

Exit codes: 0 done; 2 a bad argument, an invalid or unsafe file, a refused operation; every
failure is one line ``tankctl: ...`` on stderr.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, NoReturn, TypeVar

import typer

from tankctl.usage import OneLineUsage
from tanklab.errors import TanklabError
from tanklab.tags import Role
from tanklab_io.containers import CONTAINER_GID, CONTAINER_UID, container_root, lay_out
from tanklab_io.external import add_external, application_uri, load_external, remove_external
from tanklab_io.home import SecurityHome, default_home
from tanklab_io.pki import (
    DEFAULT_DAYS,
    DEFAULT_HOSTS,
    IDENTITIES,
    Pki,
    client_files,
    describe,
    init_pki,
    migrate,
    revoke,
    trust,
)
from tanklab_io.users import LOGIN_ROLES, UsersFile

__all__ = ["ENV_NEW_PASSWORD", "pki_app", "register", "user_app"]

ENV_NEW_PASSWORD = "TANKLAB_NEW_PASSWORD"
"""Environment variable ``user add`` takes the new password from (when not --password-stdin)."""

_T = TypeVar("_T")


pki_app = typer.Typer(
    help="The PKI: CA, application certificates, trusted certificates, CRL.", no_args_is_help=True
)
user_app = typer.Typer(
    help="Users who log in with a name and password; external controllers (certificate, role External).",
    no_args_is_help=True,
)

HomeOpt = Annotated[
    Path | None,
    typer.Option(
        "--home",
        help="Security home (env TANKLAB_HOME; default $XDG_CONFIG_HOME/tanklab or ~/.config/tanklab).",
    ),
]


def _fail(message: str) -> NoReturn:
    typer.echo(f"tankctl: {message}", err=True)
    raise typer.Exit(2)


def _guard(action: Callable[[], _T]) -> _T:
    """Run ``action``; a tanklab error or an OS error becomes one line and exit code 2."""
    try:
        return action()
    except TanklabError as e:
        _fail(str(e))
    except OSError as e:
        where = f"{e.filename}: " if e.filename else ""
        _fail(f"{where}{e.strerror or e}")


def _home(home: Path | None) -> SecurityHome:
    return SecurityHome(home if home is not None else default_home())


def _writable_home(home: Path | None) -> SecurityHome:
    """The security home, its root created 0700 when missing (for commands that write)."""
    sec = _home(home)
    _guard(sec.ensure)
    return sec


def _upgraded(pki: Pki) -> Pki:
    """``pki`` after :func:`tanklab_io.pki.migrate`, each change told on stderr (one line each)."""
    if pki.root.is_dir():
        for change in _guard(lambda: migrate(pki)):
            typer.echo(f"tankctl: PKI upgraded (decision 0022): {change}", err=True)
    return pki


def _stdin_is_terminal() -> bool:
    return typer.get_text_stream("stdin").isatty()


# --------------------------------------------------------------------------------------------
# pki
# --------------------------------------------------------------------------------------------


@pki_app.command("init", cls=OneLineUsage)
def pki_init(
    home: HomeOpt = None,
    host: Annotated[
        list[str] | None,
        typer.Option(
            "--host", help="DNS name or IP the servers are reached at (repeat; default localhost, 127.0.0.1)."
        ),
    ] = None,
    days: Annotated[int, typer.Option(help="Validity of the certificates [days].")] = DEFAULT_DAYS,
    force: Annotated[bool, typer.Option(help="Replace an existing CA and all its certificates.")] = False,
) -> None:
    """Create the CA and the plant, plc, supervisor and cli certificates (kept if present)."""
    if days <= 0:
        _fail(f"pki init: --days must be a positive number of days, got {days}")
    pki = _upgraded(_writable_home(home).pki)
    if pki.exists() and not force:
        typer.echo(f"PKI at {pki.root}: kept (complete; --force replaces it)")
        return
    hosts = tuple(host) if host else DEFAULT_HOSTS
    _guard(lambda: init_pki(pki.root, hosts=hosts, days=days, force=force))
    typer.echo(f"PKI at {pki.root}: CA certificate {pki.ca_cert} and {pki.ca_cert_pem.name}")
    typer.echo(f"CA private key {pki.ca_key} (0600; never hand it out)")
    typer.echo(f"certificates in {pki.own_dir} for {', '.join(IDENTITIES)} (hosts {', '.join(hosts)})")
    typer.echo(f"private keys in {pki.private_dir} (0600); trusted: {pki.trusted_dir}; CRL: {pki.crl_file}")
    typer.echo("what a client must trust: tankctl pki show")


@pki_app.command("trust", cls=OneLineUsage)
def pki_trust(
    file: Annotated[Path, typer.Argument(help="Certificate to trust (DER or PEM).")],
    home: HomeOpt = None,
) -> None:
    """Trust an external certificate (or CA): peers presenting it, or chaining to it, are accepted."""
    pki = _upgraded(_writable_home(home).pki)
    stored = _guard(lambda: trust(pki, file))
    row = _guard(lambda: next(r for r in describe(pki) if r["path"] == str(stored)))
    typer.echo(f"trusted {file} as {stored} (SHA-1 {row['sha1']}, {row['subject']})")


@pki_app.command("revoke", cls=OneLineUsage)
def pki_revoke(
    file: Annotated[Path, typer.Argument(help="A certificate issued by the tanklab CA.")],
    home: HomeOpt = None,
) -> None:
    """Put a CA-issued certificate on the CA's revocation list."""
    pki = _upgraded(_home(home).pki)
    _guard(lambda: revoke(pki, file))
    typer.echo(f"revoked {file}: CRL {pki.crl_file} (servers reload it on restart)")


def _table(rows: list[dict[str, Any]]) -> list[str]:
    """Aligned text lines: kind, name, not_after, revoked, uri, sha1, subject."""
    head = ("KIND", "NAME", "NOT AFTER", "REVOKED", "URI", "SHA-1", "SUBJECT")
    cells = [
        (
            r["kind"],
            r["name"],
            r["not_after"][:19],
            "yes" if r["revoked"] else "no",
            r["uri"] or "-",
            r["sha1"],
            r["subject"],
        )
        for r in rows
    ]
    widths = [max(len(c[i]) for c in [head, *cells]) for i in range(len(head))]
    return ["  ".join(c[i].ljust(widths[i]) for i in range(len(head))).rstrip() for c in [head, *cells]]


def _files(pki: Pki) -> list[str]:
    """One line per file a client must trust or use: what, format, path, what to do with it."""
    rows = [
        (f.what, f.format, str(f.path), f.use if f.path.exists() else "MISSING (tankctl pki init)")
        for f in client_files(pki)
    ]
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    return ["  ".join([*(r[i].ljust(widths[i]) for i in range(3)), r[3]]) for r in rows]


@pki_app.command("show", cls=OneLineUsage)
def pki_show(
    home: HomeOpt = None,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json", help='Print {"client_files": [...], "certificates": [...]} (one object per file).'
        ),
    ] = False,
) -> None:
    """What a client must trust and use (one line per file), then every own and trusted certificate."""
    pki: Pki = _home(home).pki
    if not pki.root.is_dir():
        _fail(f"{pki.root}: no PKI (run `tankctl pki init`)")
    _upgraded(pki)
    rows = _guard(lambda: describe(pki))
    if as_json:
        files = [{**f.as_dict(), "exists": f.path.exists()} for f in client_files(pki)]
        typer.echo(json.dumps({"client_files": files, "certificates": rows}, indent=2))
        return
    typer.echo("For a client of these servers (see docs/security.md, 'Third-party clients'):")
    for line in _files(pki):
        typer.echo(line)
    typer.echo("")
    for line in _table(rows):
        typer.echo(line)


@pki_app.command("containers", cls=OneLineUsage)
def pki_containers(
    home: HomeOpt = None,
    uid: Annotated[
        int, typer.Option(help="Owner of the copies: the image's user (needs root unless your own uid).")
    ] = CONTAINER_UID,
    gid: Annotated[int, typer.Option(help="Group of the copies: the image's group.")] = CONTAINER_GID,
) -> None:
    """Lay out HOME/containers/{plant,plc,supervisor,historian,hmi}: each tier's certificates, trust
    list, CRL, users file and only its own key (the HMI's: the CLI's), owned by the container's
    user; docker-compose.yml mounts them.

    Run it again after `pki init --force`, `pki revoke` or `user add`: it replaces the copies.
    """
    sec = _home(home)
    laid = _guard(lambda: lay_out(sec, uid=uid, gid=gid))
    for tier in laid:
        typer.echo(f"{tier.tier}: {tier.root} ({len(tier.files)} files, owner {uid}:{gid}, key 0600)")
    typer.echo(f"docker-compose.yml mounts {container_root(sec)}/TIER read-only at /etc/tanklab")


# --------------------------------------------------------------------------------------------
# user
# --------------------------------------------------------------------------------------------


def _new_password(from_stdin: bool) -> str:
    """The new password: stdin (one line), else $TANKLAB_NEW_PASSWORD, else a hidden prompt, twice."""
    if from_stdin:
        line = typer.get_text_stream("stdin").readline()
        password = line.rstrip("\r\n")
        if not password:
            _fail("user add: --password-stdin: no password on stdin")
        return password
    env = os.environ.get(ENV_NEW_PASSWORD)
    if env:
        return env
    if not _stdin_is_terminal():  # getpass would fall back to reading with echo
        _fail(f"user add: no password: stdin is not a terminal (use --password-stdin or {ENV_NEW_PASSWORD})")
    try:
        answer = typer.prompt("Password", hide_input=True, confirmation_prompt=True)
    except typer.Abort:
        _fail(f"user add: no password (use --password-stdin or {ENV_NEW_PASSWORD})")
    return str(answer)


@user_app.command("add", cls=OneLineUsage)
def user_add(
    name: Annotated[str, typer.Argument(help="User name: [A-Za-z0-9_.-], 1 to 64 characters.")],
    role: Annotated[str, typer.Option("--role", help="Observer, Operator or Engineer.")],
    home: HomeOpt = None,
    password_stdin: Annotated[
        bool, typer.Option("--password-stdin", help="Read the password from stdin (one line).")
    ] = False,
    replace: Annotated[bool, typer.Option(help="Replace an existing user's role and password.")] = False,
) -> None:
    """Add a user with a login role; the password is never echoed."""
    matches = [r for r in LOGIN_ROLES if r.value.lower() == role.lower()]
    if role.lower() == Role.EXTERNAL.value.lower():
        _fail(
            f"user add: --role External is a certificate identity, not a password login: "
            f"use `tankctl user add-external {name}`"
        )
    if not matches:
        _fail(f"user add: --role must be one of {', '.join(r.value for r in LOGIN_ROLES)}, got {role!r}")
    path = _writable_home(home).users_file
    users = _guard(lambda: UsersFile.load(path))
    if users.get(name) is not None and not replace:
        _fail(f"{path}: user {name!r} exists (use --replace to change it)")
    password = _new_password(password_stdin)
    existed = users.get(name) is not None
    _guard(lambda: users.add(name, matches[0], password, replace=replace))
    _guard(users.save)
    typer.echo(f"{'replaced' if existed else 'added'} user {name} ({matches[0].value}) in {path}")


@user_app.command("list", cls=OneLineUsage)
def user_list(home: HomeOpt = None) -> None:
    """List users and their roles."""
    path = _home(home).users_file
    sec = _home(home)
    users = _guard(lambda: UsersFile.load(path))
    external = _guard(lambda: load_external(sec))
    if not users.names() and not external:
        typer.echo(f"no users in {path}")
        return
    rows = [(n, users.get(n)) for n in users.names()]
    width = max(len(n) for n in [*users.names(), *external])
    for name, record in rows:
        assert record is not None
        typer.echo(f"{name.ljust(width)}  {record.role.value}")
    for name in sorted(external):
        typer.echo(f"{name.ljust(width)}  {Role.EXTERNAL.value} (certificate {application_uri(name)})")


@user_app.command("remove", cls=OneLineUsage)
def user_remove(
    name: Annotated[str, typer.Argument(help="User to remove.")],
    home: HomeOpt = None,
) -> None:
    """Remove a user."""
    path = _home(home).users_file
    users = _guard(lambda: UsersFile.load(path))
    _guard(lambda: users.remove(name))
    _guard(users.save)
    typer.echo(f"removed user {name} from {path}")


@user_app.command("add-external", cls=OneLineUsage)
def user_add_external(
    name: Annotated[str, typer.Argument(help="Controller name: [A-Za-z0-9_.-], 1 to 48 characters.")],
    home: HomeOpt = None,
    host: Annotated[
        list[str] | None,
        typer.Option(
            "--host", help="Host name or IP for the SubjectAltName (repeat; default localhost, 127.0.0.1)."
        ),
    ] = None,
    days: Annotated[
        int, typer.Option("--days", min=1, help="Validity of the certificate [days].")
    ] = DEFAULT_DAYS,
    replace: Annotated[
        bool, typer.Option(help="Re-issue the certificate of an existing controller.")
    ] = False,
) -> None:
    """Add an external controller: a client certificate of the site PKI, in role External."""
    sec = _writable_home(home)
    _upgraded(sec.pki)
    hosts = tuple(host) if host else DEFAULT_HOSTS
    cert, key = _guard(lambda: add_external(sec, name, hosts=hosts, days=days, replace=replace))
    typer.echo(f"added external controller {name} (External, {application_uri(name)})")
    typer.echo(f"certificate  {cert}")
    typer.echo(f"private key  {key}")
    typer.echo(f"trust        {sec.pki.ca_cert} and {sec.pki.crl_file}")


@user_app.command("remove-external", cls=OneLineUsage)
def user_remove_external(
    name: Annotated[str, typer.Argument(help="External controller to remove.")],
    home: HomeOpt = None,
) -> None:
    """Remove an external controller from role External (revoke its certificate with `pki revoke`)."""
    sec = _home(home)
    _guard(lambda: remove_external(sec, name))
    typer.echo(f"removed external controller {name}")


def register(app: typer.Typer) -> None:
    """Add the ``pki`` and ``user`` groups to the main ``tankctl`` app."""
    app.add_typer(pki_app, name="pki")
    app.add_typer(user_app, name="user")
