"""The README's Docker section on a real engine: build, five healthy services, restarts, down.

What runs, in one test (marker ``docker_engine``; ``pytest -m docker_engine`` selects it):

1. **Its own engine.** ``dockerd`` (Debian's docker.io, installed by ``make tools``) is started
   by this test with its own ``--exec-root``, ``--pidfile`` and unix socket in a fresh /tmp
   directory and ``DOCKER_HOST`` pointing there, so it never talks to a system daemon; its
   ``--data-root`` is a cache (``~/.cache/tanklab/docker/data``, a lock file serialises runs)
   so that the base image and unchanged layers survive between runs. It is stopped (SIGTERM,
   then SIGKILL of its process group) on every path.
2. **A base image without a registry.** No registry is reachable on the development machines,
   so debootstrap builds a Debian bookworm root filesystem with python3, venv, pip and
   ca-certificates, cached as a tarball keyed by suite and package list, and
   ``docker import`` makes it ``tanklab-base:...``; ``TANKLAB_BASE_IMAGE`` hands it to the
   Dockerfile (``ARG BASE_IMAGE``, both stages).
3. **The README's steps verbatim.** The fenced ``sh`` block of README.md's "Docker" section is
   read from the file and run line by line by bash in a copy of the repository (exported
   variables carry over from line to line); every line must exit 0. The checks below are
   hooked on the lines they follow, so a README change that drops a step fails here.
   The test's own environment only says where: ``DOCKER_HOST``, a unique
   ``COMPOSE_PROJECT_NAME``, free host ports (``TANKLAB_*_HOST_PORT`` for compose and
   ``TANKLAB_BASE_PORT`` for the CLI), the base image, and ``PIP_CERT`` when pip on this host
   trusts a site CA bundle.
4. **Checks.** After ``up``: five healthy services (plant, plc, supervisor, historian, hmi).
   ``setpoint`` and ``leak`` are read back with ``tankctl status --json``. After ``tankctl
   history``: the historian recorded the new setpoint and the leak (Good, through HistoryRead
   with the host CLI, ``tankctl history --json``) and the PLC's scan counter; the rows up to a
   fixed time are kept. After ``restart historian``: healthy again, those rows read back exactly
   (none lost, none duplicated: the SQLite store is on the volume), a BadNoCommunication gap
   marker after them and Good values recorded after the marker. After ``restart plant``: the
   leak is still there and the plant's model time went on (the state file is on the volume).
   After ``stop plc``: the plant's pump watchdog trips and its pumps deliver nothing (safe state
   ``off`` in the config), and the supervisor publishes the lost link (``Supervisor.PlcConnected`` false,
   ``PlcLink.Attempts`` > 0 and ``LastError`` set). After ``down -v``: no container and no
   volume of the project is left.

The build's seconds, the seconds from the first container's creation to four healthy services
and the image size are printed (``-s``) and
written to ``~/.cache/tanklab/docker/last-run.json``; docs/docker.md has the numbers.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import yaml

from helpers import free_base_port, free_port, wait_until, wait_until_sync

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
SITE = ROOT / "configs" / "three_tank_energies_sim.yaml"
CACHE = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "tanklab" / "docker"
SUITE = "bookworm"
MIRROR = "http://deb.debian.org/debian"
BASE_PACKAGES = ("python3", "python3-venv", "python3-pip", "ca-certificates")
"""What the Dockerfile's stages need from the base: python3 (3.11), its venv module and pip
(builder), CA certificates (pip over TLS); groupadd and useradd come with minbase (passwd)."""
TIERS = ("plant", "plc", "supervisor", "historian")
"""docker-compose.yml's services (the historian at host port base + 3, as the CLI expects)."""
HISTORY_TAGS = ("PLC.LIC1.SP", "Plant.T2.Leak", "PLC.Status.Scan")
"""What the history checks read: the two values the README sets, and a counter that moves every
scan (so new rows show that recording went on)."""

pytestmark = [pytest.mark.docker_engine, pytest.mark.process, pytest.mark.timeout(1800)]


# --------------------------------------------------------------------------------------------
# The README's block
# --------------------------------------------------------------------------------------------


def readme_docker_lines(text: str) -> list[str]:
    """The command lines of the first fenced ``sh`` block under ``## Docker`` (comments kept)."""
    section = re.search(r"^## Docker\n(.*?)(?=^## )", text, re.S | re.M)
    assert section, "README.md has no '## Docker' section"
    block = re.search(r"^```sh\n(.*?)^```", section[1], re.S | re.M)
    assert block, "README.md's Docker section has no ```sh block"
    return [line for line in block[1].splitlines() if line.strip()]


def test_readme_block_is_found_and_has_the_steps_the_checks_follow() -> None:
    lines = readme_docker_lines(README.read_text())
    for step in HOOKS:
        assert [line for line in lines if _command(line) == step], f"README lost the step {step!r}"
    with pytest.raises(AssertionError, match="no '## Docker'"):
        readme_docker_lines("# x\n## Other\n")


def _command(line: str) -> str:
    """A README line without its trailing comment and extra blanks (comments start `  #`)."""
    return re.sub(r"\s+#\s.*$", "", line).strip()


# --------------------------------------------------------------------------------------------
# The engine
# --------------------------------------------------------------------------------------------


@dataclass
class Engine:
    """A dockerd this test started; ``env`` points docker and docker-compose at it."""

    proc: subprocess.Popen[bytes]
    run_dir: Path
    env: dict[str, str]

    def docker(self, *args: str, timeout: float = 120, check: bool = True) -> str:
        out = subprocess.run(
            ["docker", *args], env=self.env, capture_output=True, text=True, timeout=timeout, check=False
        )
        if check:
            assert out.returncode == 0, f"docker {' '.join(args)}: {out.stderr.strip()}"
        return out.stdout


def _skip_unless_tools() -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root: dockerd and debootstrap run as root (`make tools` installs them)")
    for tool in ("dockerd", "docker", "docker-compose", "debootstrap"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (`make tools` installs Debian's package as root)")


@contextlib.contextmanager
def _lock(path: Path, deadline_s: float) -> Iterator[None]:
    """An exclusive lock on ``path`` (another run on this machine shares the data root)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as f:

        def locked() -> bool:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return False
            return True

        wait_until_sync(locked, deadline_s, what=f"another run to release {path}", poll_s=1.0)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _stop_engine(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM dockerd (it stops its containers and containerd), SIGKILL its group if it hangs."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # a containerd left behind in dockerd's group


@pytest.fixture(scope="module")
def engine() -> Iterator[Engine]:
    _skip_unless_tools()
    with _lock(CACHE / "lock", deadline_s=1500):
        # A short /tmp path: containerd's sockets live under the exec root (108-byte limit).
        run_dir = Path(tempfile.mkdtemp(prefix="tl-dockerd-", dir="/tmp"))
        sock = run_dir / "docker.sock"
        log = (run_dir / "dockerd.log").open("wb")
        proc = subprocess.Popen(
            [
                "dockerd",
                "--data-root",
                str(CACHE / "data"),
                "--exec-root",
                str(run_dir / "exec"),
                "--pidfile",
                str(run_dir / "docker.pid"),
                "--host",
                f"unix://{sock}",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        env = {k: v for k, v in os.environ.items() if not k.startswith(("TANKLAB_", "DOCKER_", "COMPOSE_"))}
        env["DOCKER_HOST"] = f"unix://{sock}"
        eng = Engine(proc, run_dir, env)
        try:

            def serving() -> bool:
                assert proc.poll() is None, (
                    f"dockerd exited {proc.returncode}: {_tail(run_dir / 'dockerd.log')}"
                )
                return sock.exists() and _answers(eng)

            try:
                wait_until_sync(serving, 120, what=f"dockerd at {sock}")
            except AssertionError as e:
                raise AssertionError(f"{e}: {_tail(run_dir / 'dockerd.log')}") from None
            yield eng
        finally:
            _stop_engine(proc)
            log.close()
            shutil.rmtree(run_dir, ignore_errors=True)


def _answers(engine: Engine) -> bool:
    probe = subprocess.run(["docker", "info"], env=engine.env, capture_output=True, timeout=30, check=False)
    return probe.returncode == 0


def _tail(path: Path, n: int = 15) -> str:
    return "\n".join(path.read_text(errors="replace").splitlines()[-n:]) if path.exists() else ""


def base_image(engine: Engine) -> str:
    """``tanklab-base:bookworm-KEY``: imported from a cached debootstrap tarball, built if missing."""
    key = hashlib.sha256(f"{SUITE} {MIRROR} {' '.join(BASE_PACKAGES)}".encode()).hexdigest()[:12]
    tag = f"tanklab-base:{SUITE}-{key}"
    if engine.docker("image", "ls", "-q", tag).strip():
        return tag
    tarball = CACHE / f"rootfs-{SUITE}-{key}.tar"
    if not tarball.exists():
        with tempfile.TemporaryDirectory(prefix="tl-rootfs-", dir=CACHE) as tmp:
            rootfs = Path(tmp) / "rootfs"
            subprocess.run(
                [
                    "debootstrap",
                    "--variant=minbase",
                    f"--include={','.join(BASE_PACKAGES)}",
                    SUITE,
                    str(rootfs),
                    MIRROR,
                ],
                capture_output=True,
                timeout=1200,
                check=True,
            )
            for junk in ("var/cache/apt/archives", "var/lib/apt/lists"):
                for f in (rootfs / junk).glob("*"):
                    if f.is_file():
                        f.unlink()
            partial = tarball.with_suffix(".partial")
            subprocess.run(["tar", "-C", str(rootfs), "-cf", str(partial), "."], check=True, timeout=600)
            partial.rename(tarball)
    with tarball.open("rb") as f:
        out = subprocess.run(
            ["docker", "import", "-", tag],
            stdin=f,
            env=engine.env,
            capture_output=True,
            timeout=600,
            check=False,
        )
    assert out.returncode == 0, out.stderr.decode()
    return tag


# --------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------


def _pip_cert() -> str | None:
    """The CA bundle pip on this host trusts, when it is told one (env or pip's config)."""
    for var in ("PIP_CERT", "REQUESTS_CA_BUNDLE"):
        if os.environ.get(var):
            return os.environ[var]
    got = subprocess.run(
        ["python3", "-m", "pip", "config", "get", "global.cert"], capture_output=True, text=True, check=False
    )
    return got.stdout.strip() or None


def _copy_repository(dest: Path) -> None:
    """The repository's files (tracked and untracked, not ignored) into ``dest``."""
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for rel in filter(None, listed.split("\0")):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


@dataclass
class ReadmeShell:
    """The README's shell session: its directory and environment, carried from line to line."""

    engine: Engine
    cwd: Path
    env: dict[str, str]
    ran: list[str] = field(default_factory=list)
    marks: dict[str, float] = field(default_factory=dict)
    steps: dict[str, float] = field(default_factory=dict)
    """Seconds of each README line with its check (for docs/docker.md's numbers)."""
    history: dict[str, Any] = field(default_factory=dict)
    """What the history checks keep between README lines (window, rows read before a restart)."""

    def sh(self, line: str, timeout: float = 900) -> None:
        """Run one README line with bash; it must exit 0; its exported variables carry over."""
        env_file = self.cwd / ".readme-env"
        script = f"set -euo pipefail\n{line}\nenv -0 > {env_file}\n"
        out = subprocess.run(
            ["bash", "-c", script],
            cwd=self.cwd,
            env=self.env,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )
        assert out.returncode == 0, (
            f"README line failed ({out.returncode}): {line}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
        )
        self.env = dict(item.split("=", 1) for item in env_file.read_text().split("\0") if "=" in item)
        self.ran.append(_command(line))

    def tankctl(self, *args: str) -> subprocess.CompletedProcess[str]:
        """The host CLI ``tankctl ARGS`` in the session's environment (120 s: a hang bound)."""
        return subprocess.run(
            ["tankctl", *args],
            cwd=self.cwd,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )

    def tankctl_json(self, *args: str) -> tuple[int, dict[str, Any]]:
        """``tankctl ARGS --json`` in the session's environment: exit code and parsed output."""
        out = self.tankctl(*args, "--json")
        assert out.stdout.strip(), f"tankctl {' '.join(args)}: no output ({out.returncode}): {out.stderr}"
        data = json.loads(out.stdout)
        assert isinstance(data, dict)
        return out.returncode, data

    def history_rows(self, tags: tuple[str, ...], start: str, end: str) -> dict[str, list[dict[str, Any]]]:
        """``tankctl history TAGS --from START --to END --json`` through the historian's
        published port (``TANKLAB_BASE_PORT`` + 3): tag -> its rows, in the historian's order."""
        out = self.tankctl("history", *tags, "--from", start, "--to", end, "--json")
        assert out.returncode == 0, f"tankctl history ({out.returncode}): {out.stderr.strip()}"
        rows: dict[str, list[dict[str, Any]]] = {tag: [] for tag in tags}
        for row in json.loads(out.stdout):
            rows[row["tag"]].append(row)
        return rows

    def compose(self, *args: str, check: bool = True) -> str:
        out = subprocess.run(
            ["docker-compose", *args],
            cwd=self.cwd,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        if check:
            assert out.returncode == 0, f"docker-compose {' '.join(args)}: {out.stderr.strip()}"
        return out.stdout

    def health(self) -> dict[str, str]:
        """Service name -> health status of the project's containers."""
        out: dict[str, str] = {}
        for cid in self.compose("ps", "-q").split():
            fmt = (
                '{{index .Config.Labels "com.docker.compose.service"}} '
                "{{if .State.Health}}{{.State.Health.Status}}{{else}}{{.State.Status}}{{end}}"
            )
            name, status = self.engine.docker("inspect", "--format", fmt, cid).split()
            out[name] = status
        return out


def _walk(nodes: list[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    for node in nodes:
        yield node
        yield from _walk(node.get("children", []))


def _site() -> dict[str, Any]:
    data = yaml.safe_load(SITE.read_text())
    assert isinstance(data, dict)
    return data


async def _after_up(stack: ReadmeShell) -> None:
    await wait_until(
        lambda: stack.health() == dict.fromkeys((*TIERS, "hmi"), "healthy"),
        300,
        what="five healthy services",
        poll_s=1.0,
    )
    # `up --build` builds first: the build ends when the first container (the plant) is created.
    (plant,) = stack.compose("ps", "-q", "plant").split()
    created = stack.engine.docker("inspect", "--format", "{{.Created}}", plant).strip()
    created_s = datetime.fromisoformat(re.sub(r"(\.\d{6})\d*", r"\1", created.replace("Z", "+00:00")))
    stack.marks["build_s"] = created_s.timestamp() - stack.marks["up_started_wall"]
    stack.marks["healthy_s"] = time.time() - created_s.timestamp()


async def _after_setpoint(stack: ReadmeShell) -> None:
    code, status = stack.tankctl_json("status")
    assert code == 0
    assert status["site"] == "three_tank_energies_sim"
    assert status["plc"]["loops"]["LIC1"]["sp_m"] == pytest.approx(0.45)


async def _after_leak(stack: ReadmeShell) -> None:
    code, status = stack.tankctl_json("status")
    assert code == 0
    assert status["plant"]["tanks"]["T2"]["leak"] == pytest.approx(0.2)
    stack.marks["plant_time_before_restart"] = status["plant"]["model_time_s"]


def _iso(wall_s: float) -> str:
    return datetime.fromtimestamp(wall_s, UTC).isoformat()


def _good(rows: list[dict[str, Any]], value: float) -> bool:
    return any(r["status"] == "Good" and r["value"] == pytest.approx(value) for r in rows)


async def _after_history(stack: ReadmeShell) -> None:
    # From a minute before `up` (the store is new: nothing older), to now.
    start = _iso(stack.marks["up_started_wall"] - 60.0)

    # Judged on the rows older than 5 s, as the fixed end below is: a row just recorded would
    # satisfy a read to "now" and still lie after that end.
    def recorded() -> bool:
        rows = stack.history_rows(HISTORY_TAGS, start, _iso(time.time() - 5.0))
        return (
            _good(rows["PLC.LIC1.SP"], 0.45)
            and _good(rows["Plant.T2.Leak"], 0.2)
            and sum(r["status"] == "Good" for r in rows["PLC.Status.Scan"]) >= 10
        )

    await wait_until(recorded, 120, what="the historian recording the setpoint and the leak", poll_s=2.0)
    # The rows up to a fixed end, once two reads agree (what was in flight is stored by then).
    end = _iso(time.time() - 5.0)
    last: list[dict[str, list[dict[str, Any]]]] = []

    def settled() -> bool:
        rows = stack.history_rows(HISTORY_TAGS, start, end)
        same = bool(last) and rows == last[-1]
        last.append(rows)
        return same

    await wait_until(settled, 60, what="the historian's rows up to a fixed time to settle", poll_s=2.0)
    rows = last[-1]
    assert _good(rows["PLC.LIC1.SP"], 0.45) and _good(rows["Plant.T2.Leak"], 0.2)
    for tag, tag_rows in rows.items():
        times = [r["time"] for r in tag_rows]
        assert times == sorted(set(times)), f"{tag}: times not strictly increasing"
    stack.history.update(start=start, end=end, rows=rows)


async def _after_restart_historian(stack: ReadmeShell) -> None:
    await wait_until(
        lambda: stack.health().get("historian") == "healthy", 180, what="historian healthy again", poll_s=1.0
    )
    start, end, before = stack.history["start"], stack.history["end"], stack.history["rows"]
    # The same window reads back the same rows: nothing lost, nothing duplicated (the volume
    # kept them). A tag whose newest row was in the window gains the restart's gap marker
    # (1 us after that row, decision 0043), and nothing else.
    after = stack.history_rows(HISTORY_TAGS, start, end)
    for tag in HISTORY_TAGS:
        added = after[tag][len(before[tag]) :]
        assert after[tag][: len(before[tag])] == before[tag], f"{tag}: earlier rows changed"
        assert [r["status"] for r in added] in ([], ["BadNoCommunication"]), f"{tag}: {added}"
    # The setpoint and the leak did not change: their newest rows were in the window.
    assert [after[tag][-1]["status"] for tag in ("PLC.LIC1.SP", "Plant.T2.Leak")] == [
        "BadNoCommunication"
    ] * 2
    n_before = len(before["PLC.Status.Scan"])
    assert n_before >= 10

    def recording_again() -> bool:
        scan = stack.history_rows(("PLC.Status.Scan",), start, "now")["PLC.Status.Scan"]
        assert scan[:n_before] == before["PLC.Status.Scan"]
        gaps = [i for i, r in enumerate(scan) if r["status"] == "BadNoCommunication"]
        # The restart's gap marker, then Good values recorded by the restarted historian.
        return bool(gaps) and any(r["status"] == "Good" for r in scan[gaps[-1] + 1 :])

    await wait_until(recording_again, 120, what="the restarted historian recording again", poll_s=2.0)


async def _after_restart_plant(stack: ReadmeShell) -> None:
    await wait_until(
        lambda: stack.health().get("plant") == "healthy", 180, what="plant healthy again", poll_s=1.0
    )
    code, status = stack.tankctl_json("status")
    assert code == 0, status
    plant = status["plant"]
    assert plant["tanks"]["T2"]["leak"] == pytest.approx(0.2)  # restored from the volume, and shown
    assert plant["model_time_s"] > stack.marks["plant_time_before_restart"]  # went on, not from 0
    assert status["plc"]["loops"]["LIC1"]["sp_m"] == pytest.approx(0.45)


async def _after_stop_plc(stack: ReadmeShell) -> None:
    safe = _site()["plant"]["watchdog"]["safe_state"]
    assert safe == "off"  # what the pump check below relies on

    def tripped() -> bool:
        code, status = stack.tankctl_json("status")
        assert code == 2 and not status["plc"]["reachable"]  # exit 2: a tier asked for is down
        plant = status["plant"]
        return bool(plant["watchdog"]) and all(p["flow_m3_s"] == 0.0 for p in plant["pumps"].values())

    await wait_until(tripped, 120, what="the plant's watchdog stopping the pumps", poll_s=2.0)


async def _after_browse_supervisor(stack: ReadmeShell) -> None:
    def lost() -> bool:
        code, browse = stack.tankctl_json("browse", "supervisor")
        assert code == 0
        values = {n["path"]: n.get("value") for n in _walk(browse["supervisor"]["nodes"])}
        return (
            values["Supervisor.PlcConnected"] is False
            and values["Supervisor.PlcLink.Attempts"] > 0
            and bool(values["Supervisor.PlcLink.LastError"])
        )

    await wait_until(lost, 120, what="the supervisor reporting the lost PLC link", poll_s=2.0)


async def _after_down(stack: ReadmeShell) -> None:
    assert stack.compose("ps", "-q").split() == []
    project = stack.env["COMPOSE_PROJECT_NAME"]
    volumes = stack.engine.docker(
        "volume", "ls", "-q", "--filter", f"label=com.docker.compose.project={project}"
    )
    assert volumes.split() == []


HOOKS: dict[str, Callable[[ReadmeShell], Any]] = {
    "docker-compose up -d --build": _after_up,
    "tankctl setpoint LIC1 0.45": _after_setpoint,
    "tankctl leak T2 0.2": _after_leak,
    "tankctl history PLC.LIC1.SP Plant.T2.Leak --from -10m": _after_history,
    "docker-compose restart historian": _after_restart_historian,
    "docker-compose restart plant": _after_restart_plant,
    "docker-compose stop plc": _after_stop_plc,
    "tankctl browse supervisor": _after_browse_supervisor,
    "docker-compose down -v": _after_down,
}
"""The checks, each run right after the README line it names (exactly, comment stripped)."""


async def test_readme_docker_section_on_a_real_engine(engine: Engine, tmp_path: Path) -> None:
    started = time.monotonic()
    lines = readme_docker_lines(README.read_text())
    base = base_image(engine)
    work = tmp_path / "repo"
    _copy_repository(work)
    port = free_base_port()
    env = dict(engine.env)
    env.update(
        {
            "PATH": f"{Path(sys.executable).parent}:{env.get('PATH', '/usr/bin:/bin')}",
            "COMPOSE_PROJECT_NAME": f"tanklabtest{os.getpid()}",
            "COMPOSE_HTTP_TIMEOUT": "300",
            "TANKLAB_BASE_IMAGE": base,
            "TANKLAB_PLANT_HOST_PORT": str(port),
            "TANKLAB_PLC_HOST_PORT": str(port + 1),
            "TANKLAB_SUPERVISOR_HOST_PORT": str(port + 2),
            "TANKLAB_HISTORIAN_HOST_PORT": str(port + 3),
            "TANKLAB_HMI_HOST_PORT": str(free_port()),  # the HMI's 8080 is one per machine
            "TANKLAB_BASE_PORT": str(port),
        }
    )
    cert = _pip_cert()
    if cert:
        env["PIP_CERT"] = cert
    stack = ReadmeShell(engine, work, env)
    try:
        for line in lines:
            if _command(line).startswith("docker-compose up"):
                stack.marks["up_started_wall"] = time.time()
            step_started = time.monotonic()
            stack.sh(line)
            hook = HOOKS.get(_command(line))
            if hook is not None:
                await hook(stack)
            stack.steps[_command(line)[:40]] = round(time.monotonic() - step_started, 1)
        assert [s for s in stack.ran if s in HOOKS] == list(HOOKS)  # every check ran, in order
    finally:
        if "docker-compose down -v" not in stack.ran:
            stack.compose("down", "-v", "--remove-orphans", check=False)
    size = engine.docker("image", "ls", "--format", "{{.Size}}", "tanklab:latest").strip()
    # Dangling images older than a day: earlier builds. The legacy builder's cache is the recent
    # untagged builder-stage images, so a plain prune would make every next build cold.
    engine.docker("image", "prune", "--force", "--filter", "until=24h")
    result = {
        "build_s": round(stack.marks["build_s"], 1),
        "up_to_healthy_s": round(stack.marks["healthy_s"], 1),
        "image_size": size,
        "test_s": round(time.monotonic() - started, 1),
        "steps_s": stack.steps,
    }
    (CACHE / "last-run.json").write_text(json.dumps(result) + "\n")
    print(f"docker engine test: {result}")
