"""A real PostgreSQL for tests and benchmarks, from the machine's PostgreSQL 15 binaries.

:class:`PostgresServer` runs ``initdb`` on a fresh temporary directory and ``pg_ctl start`` on a
free loopback port with its Unix socket in that directory, and stops the server and removes the
directory on every path (:meth:`PostgresServer.stop`, the context manager, and an ``atexit``
guard for an interpreter that ends without either). PostgreSQL refuses to run as root, so when
the tests run as root the directory is chowned to the ``postgres`` user and every PostgreSQL
command runs as that user (``subprocess``'s ``user=``). Authentication is ``trust`` on loopback:
the server lives only as long as the tests and listens on 127.0.0.1 alone.

The binaries come from Debian's ``postgresql-15`` package (``make tools`` installs it). When they
are missing, :meth:`PostgresServer.start` raises :class:`PostgresMissingError` naming that target: the
PostgreSQL half of a test suite fails, it never skips silently.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Mapping
from pathlib import Path

from tanklab_testing.procs import free_base_port

__all__ = ["PG_BIN", "PostgresMissingError", "PostgresServer", "pg_bin"]

PG_BIN = Path("/usr/lib/postgresql/15/bin")
"""Where Debian's postgresql-15 package puts initdb, pg_ctl and postgres."""
TEST_SETTINGS: Mapping[str, str] = {"fsync": "off", "synchronous_commit": "off", "full_page_writes": "off"}
"""What a throw-away test cluster need not pay for (durability across a power cut)."""
START_TIMEOUT_S = 60
STOP_TIMEOUT_S = 30


class PostgresMissingError(RuntimeError):
    """The PostgreSQL 15 binaries are not on this machine."""


def pg_bin() -> Path:
    """The directory of the PostgreSQL 15 binaries (``TANKLAB_PG_BIN`` overrides), checked."""
    path = Path(os.environ.get("TANKLAB_PG_BIN", str(PG_BIN)))
    missing = [name for name in ("initdb", "pg_ctl", "postgres") if not (path / name).is_file()]
    if missing:
        raise PostgresMissingError(
            f"PostgreSQL 15 binaries missing in {path} ({', '.join(missing)}): run `make tools` "
            "(installs Debian's postgresql-15) or set TANKLAB_PG_BIN"
        )
    return path


class PostgresServer:
    """One throw-away PostgreSQL cluster on 127.0.0.1:``port`` (see the module's docstring)."""

    def __init__(self, root: Path, port: int, run_as: pwd.struct_passwd | None) -> None:
        self.root = root
        self.port = port
        self._run_as = run_as
        self.data = root / "data"
        self.socket_dir = root / "sock"
        self.log = root / "postgres.log"
        self._running = False

    @property
    def url(self) -> str:
        """A libpq URL of the cluster's ``postgres`` database as its superuser ``postgres``."""
        return f"postgresql://postgres@127.0.0.1:{self.port}/postgres"

    @classmethod
    def start(cls, settings: Mapping[str, str] = TEST_SETTINGS, *, attempts: int = 3) -> PostgresServer:
        """initdb a new cluster and start it; on any failure, what was made is removed again."""
        bin_dir = pg_bin()
        run_as = pwd.getpwnam("postgres") if os.geteuid() == 0 else None
        root = Path(tempfile.mkdtemp(prefix="tanklab-pg-"))
        server = cls(root, 0, run_as)
        atexit.register(server.stop)
        try:
            server.socket_dir.mkdir()
            if run_as is not None:
                for p in (root, server.socket_dir):
                    os.chown(p, run_as.pw_uid, run_as.pw_gid)
            server._run(
                [
                    str(bin_dir / "initdb"),
                    "-D",
                    str(server.data),
                    "-U",
                    "postgres",
                    "--auth=trust",
                    "--encoding=UTF8",
                    "--locale=C",
                    "--no-sync",
                ]
            )
            options = " ".join(f"-c {k}={v}" for k, v in settings.items())
            for attempt in range(attempts):
                # a port below the ephemeral range, drawn at random (tanklab_testing.procs)
                server.port = free_base_port(count=1)
                done = server._run(
                    [
                        str(bin_dir / "pg_ctl"),
                        "-D",
                        str(server.data),
                        "-l",
                        str(server.log),
                        "-w",
                        "-t",
                        str(START_TIMEOUT_S),
                        "-o",
                        f"-p {server.port} -k {server.socket_dir} -c listen_addresses=127.0.0.1 {options}",
                        "start",
                    ],
                    check=False,
                )
                server._running = server._postmaster_pid() is not None
                if done.returncode == 0:
                    return server
                if attempt == attempts - 1:
                    raise RuntimeError(f"pg_ctl start failed ({done.returncode}): {server.log_tail()}")
                server._kill_postmaster()  # a half-started one, before the next port
        except BaseException:
            server.stop()
            raise
        raise AssertionError("unreachable")

    def _run(self, argv: list[str], *, check: bool = True) -> subprocess.CompletedProcess[str]:
        pw = self._run_as
        done = subprocess.run(
            argv,
            cwd=self.root,
            capture_output=True,
            text=True,
            timeout=START_TIMEOUT_S + 30,
            check=False,
            env={**os.environ, "LC_ALL": "C", "HOME": str(self.root)},
            user=None if pw is None else pw.pw_uid,
            group=None if pw is None else pw.pw_gid,
            extra_groups=None if pw is None else [],
        )
        if check and done.returncode != 0:
            raise RuntimeError(f"{Path(argv[0]).name} failed ({done.returncode}): {done.stderr.strip()}")
        return done

    def _postmaster_pid(self) -> int | None:
        try:
            return int((self.data / "postmaster.pid").read_text().split("\n", 1)[0])
        except (OSError, ValueError):
            return None

    def _kill_postmaster(self) -> None:
        pid = self._postmaster_pid()
        if pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        self._running = False

    def log_tail(self, lines: int = 20) -> str:
        """The server log's last lines (for a failure's message)."""
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"

    def stop(self) -> None:
        """Stop the server (fast shutdown, then SIGKILL of its postmaster) and remove its files.
        Safe to call more than once."""
        if self._running or self._postmaster_pid() is not None:
            try:
                done = self._run(
                    [
                        str(pg_bin() / "pg_ctl"),
                        "-D",
                        str(self.data),
                        "-m",
                        "fast",
                        "-w",
                        "-t",
                        str(STOP_TIMEOUT_S),
                        "stop",
                    ],
                    check=False,
                )
                if done.returncode != 0:
                    self._kill_postmaster()
            except (OSError, subprocess.SubprocessError, PostgresMissingError):
                self._kill_postmaster()
            self._running = False
        shutil.rmtree(self.root, ignore_errors=True)
        atexit.unregister(self.stop)

    def __enter__(self) -> PostgresServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
