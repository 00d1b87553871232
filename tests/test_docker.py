"""Docker packaging without a Docker engine: the compose file, the Dockerfile, the image's steps.

These checks need no engine and run everywhere; tests/system/test_docker_engine.py builds the
image and runs the README's Docker steps on a real one (dockerd started by that test). Here:

1. ``docker-compose config`` (Debian's docker-compose 1.29, installed by ``make tools``)
   accepts docker-compose.yml, and rejects a broken copy (so the check has teeth);
2. the compose wiring, parsed: three tiers and the historian, their commands, published ports,
   endpoints by service name, healthchecks that run ``tankctl.health`` against the tier's own
   port, ``depends_on`` on healthy tiers, restart policies, the control / supervisory networks,
   the historian's store on its named volume (and TANKLAB_HISTORIAN_URL passed through);
3. the Dockerfile, parsed: two stages on ``ARG BASE_IMAGE`` (python:3.11-slim), the install done by
   docker/install.sh, only /opt/venv and configs/ in the final stage, no compilers, a
   non-root user, ``ENTRYPOINT ["tankctl"]``;
4. the image's install and start steps for real: docker/install.sh builds the wheel and
   installs it into a fresh venv (from PyPI, through pip's cache), ``tankctl plant`` starts from
   that venv in a directory laid out like the image's /app, ``tankctl.health`` reads it (exit
   0), SIGTERM stops it (exit 0), and the probe then reports it down (exit 1, one line).

The health probe itself is also tested in-process against a real plant server.
"""

from __future__ import annotations

import asyncio
import fnmatch
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml

from helpers import free_port, hang_bound, identity, server_security, wait_until
from historian.store import store_location
from tankctl import health
from tanklab.config import load_site, parse_endpoint_url
from tanklab.tags import historian_tags, plant_tags, plc_tags, supervisor_tags

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "docker-compose.yml"
DOCKERFILE = ROOT / "Dockerfile"
DOCKERIGNORE = ROOT / ".dockerignore"
INSTALL_SCRIPT = ROOT / "docker" / "install.sh"

TIERS = {"plant": 4840, "plc": 4841, "supervisor": 4842, "historian": 4843}
"""Each tier's service name and its OPC UA port (the architecture's defaults; the historian is
base + 3, decision 0043)."""
URL_VARS = {"TANKLAB_PLANT_URL": "plant", "TANKLAB_PLC_URL": "plc", "TANKLAB_SUPERVISOR_URL": "supervisor"}
COMPILERS = re.compile(
    r"\b(build-essential|gcc|g\+\+|clang|cc|make|cmake|python3?-dev|libc6?-dev|gfortran|cython)\b"
)
"""Packages that must not be installed in the image (it ships binary wheels only)."""


# --------------------------------------------------------------------------------------------
# 1. docker-compose config
# --------------------------------------------------------------------------------------------


def _docker_compose() -> str:
    exe = shutil.which("docker-compose")
    if exe is None:
        pytest.skip("docker-compose is not installed (`make tools` installs Debian's package as root)")
    return exe


def _compose_config(exe: str, file: Path, home: Path) -> subprocess.CompletedProcess[str]:
    # A clean environment: no engine, no user config, no TANKLAB_* from the caller's shell.
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(home)}
    return subprocess.run(
        [exe, "-f", str(file), "config"],
        cwd=file.parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_docker_compose_config_accepts_the_file(tmp_path: Path) -> None:
    exe = _docker_compose()
    result = _compose_config(exe, COMPOSE, tmp_path)
    assert result.returncode == 0, result.stderr
    resolved = yaml.safe_load(result.stdout)
    # Interpolation defaults resolved as intended when the shell sets nothing.
    for name in TIERS:
        env = resolved["services"][name]["environment"]
        assert env["TANKLAB_CONFIG"] == "configs/three_tank_energies_sim.yaml"
        assert env["TANKLAB_SPEED"] == "1"


def test_docker_compose_config_rejects_a_broken_file(tmp_path: Path) -> None:
    exe = _docker_compose()
    broken = tmp_path / "docker-compose.yml"
    broken.write_text(COMPOSE.read_text().replace("service_healthy", "service_healty"))
    (tmp_path / "Dockerfile").write_text("FROM scratch\n")
    result = _compose_config(exe, broken, tmp_path)
    assert result.returncode != 0
    assert "service_healty" in result.stderr


# --------------------------------------------------------------------------------------------
# 2. compose wiring
# --------------------------------------------------------------------------------------------


def _compose() -> dict[str, Any]:
    data = yaml.safe_load(COMPOSE.read_text())
    assert isinstance(data, dict)
    return data


def _env(service: dict[str, Any]) -> dict[str, str]:
    env = service.get("environment") or {}
    if isinstance(env, list):  # the KEY=VALUE list form
        env = dict(item.split("=", 1) for item in env)
    return {str(k): str(v) for k, v in env.items()}


def _interpolated(value: str) -> str:
    """``${VAR:-default}`` -> default (what compose substitutes when VAR is unset)."""
    return re.sub(r"\$\{[A-Z_]+:?-([^}]*)\}", r"\1", value)


def _command(service: dict[str, Any]) -> list[str]:
    cmd = service["command"]
    return shlex.split(cmd) if isinstance(cmd, str) else [str(c) for c in cmd]


def _seconds(duration: str) -> float:
    m = re.fullmatch(r"(\d+(?:\.\d+)?)(ms|s|m)", duration)
    assert m, f"unexpected duration {duration!r}"
    return float(m[1]) * {"ms": 1e-3, "s": 1.0, "m": 60.0}[m[2]]


def test_compose_has_the_four_tiers_built_from_one_image() -> None:
    services = _compose()["services"]
    assert set(services) == {*TIERS, "hmi"}  # the HMI: tests/hmi/test_server_compose.py
    assert {s["image"] for s in services.values()} == {"tanklab:latest"}
    builders = [name for name, s in services.items() if "build" in s]
    assert builders, "some service must build the image"
    for name in builders:
        build = services[name]["build"]
        context = build if isinstance(build, str) else build.get("context", ".")
        assert (COMPOSE.parent / context / "Dockerfile").resolve() == DOCKERFILE
        # The base image is the Dockerfile's build argument, from the environment or the default.
        assert build["args"]["BASE_IMAGE"] == "${TANKLAB_BASE_IMAGE:-python:3.11-slim}"


def test_compose_runs_each_tier_command_on_its_published_port() -> None:
    services = _compose()["services"]
    image_env = _dockerfile_env(_stages(_instructions())[-1])
    for name, port in TIERS.items():
        s = services[name]
        assert _command(s)[0] == name
        published = [_interpolated(str(p)) for p in s["ports"]]
        assert f"{port}:{port}" in published, f"{name}: port {port} not published"
        # The host port can move (TANKLAB_<TIER>_HOST_PORT): the engine test publishes free ports.
        assert f"${{TANKLAB_{name.upper()}_HOST_PORT:-{port}}}:{port}" in [str(p) for p in s["ports"]]
        env = _env(s)
        # Listening on every interface (image ENV or service env) is what makes ports reachable.
        assert env.get("TANKLAB_HOST", image_env.get("TANKLAB_HOST")) == "0.0.0.0"
        assert env.get("TANKLAB_PORT", str(port)) == str(port)
        config = _interpolated(env["TANKLAB_CONFIG"])
        assert not Path(config).is_absolute(), "configs live under the image's WORKDIR"
        site = load_site(ROOT / config)  # ships in the image (COPY configs) and validates
        assert getattr(site.endpoints, name).port == port
        assert float(_interpolated(env["TANKLAB_SPEED"])) > 0


def test_compose_endpoints_name_the_services_and_ports() -> None:
    services = _compose()["services"]
    wanted = {
        "plc": ["TANKLAB_PLANT_URL"],
        "supervisor": ["TANKLAB_PLC_URL"],
        # The historian collects from every tier: each by its service name.
        "historian": ["TANKLAB_PLANT_URL", "TANKLAB_PLC_URL", "TANKLAB_SUPERVISOR_URL"],
    }
    for name, names in wanted.items():
        for var in names:
            assert var in _env(services[name]), f"{name} needs {var} to reach {URL_VARS[var]}"
    for name, s in services.items():
        for var, value in _env(s).items():
            if var not in URL_VARS:
                continue
            tier = URL_VARS[var]
            endpoint = parse_endpoint_url(value)
            assert endpoint.host == tier, f"{name}: {var} must name the service {tier!r}"
            assert endpoint.port == TIERS[tier]
            assert value == f"opc.tcp://{tier}:{TIERS[tier]}/tanklab/{tier}"
            # ...and the two services share a network.
            assert set(_networks(s)) & set(_networks(services[tier])), f"{name} cannot reach {tier}"


def _networks(service: dict[str, Any]) -> list[str]:
    nets = service.get("networks", ["default"])
    return list(nets)


def test_compose_networks_follow_the_secured_layout() -> None:
    compose = _compose()
    services = compose["services"]
    assert set(_networks(services["plant"])) == {"control"}
    assert set(_networks(services["plc"])) == {"control", "supervisory"}
    assert set(_networks(services["supervisor"])) == {"supervisory"}
    # The historian reads plant and PLC on `control`, the supervisor on `supervisory`.
    assert set(_networks(services["historian"])) == {"control", "supervisory"}
    assert set(compose["networks"]) == {"control", "supervisory"}
    for net in compose["networks"].values():
        # An internal network could not publish ports; the CLI on the host needs all three.
        assert not (net or {}).get("internal", False)


def _mounts(service: dict[str, Any]) -> dict[str, tuple[str, str]]:
    """Container path -> (host path, mode) of a service's bind mounts."""
    out = {}
    for vol in service.get("volumes", []):
        parts = _interpolated(vol).split(":")
        if len(parts) == 3:
            out[parts[1]] = (parts[0], parts[2])
    return out


def test_compose_mounts_each_tiers_container_home_read_only() -> None:
    services = _compose()["services"]
    for tier in TIERS:
        mounts = _mounts(services[tier])
        secret = {c: hm for c, hm in mounts.items() if c.startswith("/etc/tanklab")}
        # One mount: the tier's copy laid out by `tankctl pki containers` (only its own key,
        # owned by the image's user; tests/tanklab_io/test_containers.py checks the layout).
        assert secret == {"/etc/tanklab": (f"./.tanklab/containers/{tier}", "ro")}, tier
    assert _dockerfile_env(_stages(_instructions())[-1])["TANKLAB_HOME"] == "/etc/tanklab"


def _named_volumes(service: dict[str, Any]) -> dict[str, str]:
    """Container path -> volume name of a service's named volumes (``name:/path``)."""
    out = {}
    for vol in service.get("volumes", []):
        parts = str(vol).split(":")
        if len(parts) == 2 and not parts[0].startswith((".", "/", "$")):
            out[parts[1]] = parts[0]
    return out


def test_compose_keeps_each_tiers_state_on_its_own_named_volume() -> None:
    compose = _compose()
    services = compose["services"]
    volumes = {tier: _named_volumes(services[tier]).get("/var/lib/tanklab") for tier in TIERS}
    assert volumes == {tier: f"{tier}-state" for tier in TIERS}
    assert set(compose["volumes"]) == set(volumes.values())
    # The historian's store: a SQLite file on that volume unless TANKLAB_HISTORIAN_URL says
    # otherwise (the historian reads the variable itself: historian.store.store_location).
    env = _env(services["historian"])
    assert env["TANKLAB_HISTORIAN_URL"] == "${TANKLAB_HISTORIAN_URL:-/var/lib/tanklab/history.db}"
    store = store_location(
        Path("var/unused.db"), {"TANKLAB_HISTORIAN_URL": _interpolated(env["TANKLAB_HISTORIAN_URL"])}
    )
    assert Path(store).parent == Path("/var/lib/tanklab")
    assert _command(services["historian"]) == ["historian"]  # no --store: it would win over the URL


def test_docker_compose_config_passes_the_historians_store_url(tmp_path: Path) -> None:
    exe = _docker_compose()
    env = {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "HOME": str(tmp_path),
        "TANKLAB_HISTORIAN_URL": "postgresql://tanklab@db:5432/history",
        "TANKLAB_HISTORIAN_HOST_PORT": "14843",
    }
    result = subprocess.run(
        [exe, "-f", str(COMPOSE), "config"],
        cwd=COMPOSE.parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    historian = yaml.safe_load(result.stdout)["services"]["historian"]
    assert historian["environment"]["TANKLAB_HISTORIAN_URL"] == "postgresql://tanklab@db:5432/history"
    assert [(str(p["published"]), p["target"]) for p in historian["ports"]] == [("14843", 4843)]


def test_no_secret_can_enter_the_image() -> None:
    patterns = [line.strip() for line in DOCKERIGNORE.read_text().splitlines() if line.strip()]
    for pattern in (".tanklab", "*.pem", "*.der"):
        assert pattern in patterns
    for ins in _instructions():
        assert "pki" not in ins.args and "users.json" not in ins.args, ins


def test_compose_starts_each_tier_after_the_tier_below_is_healthy() -> None:
    services = _compose()["services"]
    assert "depends_on" not in services["plant"]
    assert services["plc"]["depends_on"] == {"plant": {"condition": "service_healthy"}}
    assert services["supervisor"]["depends_on"] == {"plc": {"condition": "service_healthy"}}
    # The historian starts once every tier it collects from answers.
    healthy = {"condition": "service_healthy"}
    assert services["historian"]["depends_on"] == dict.fromkeys(("plant", "plc", "supervisor"), healthy)


def test_compose_healthchecks_read_the_tier_over_opc_ua() -> None:
    services = _compose()["services"]
    for name, port in TIERS.items():
        hc = services[name]["healthcheck"]
        url = f"opc.tcp://localhost:{port}/tanklab/{name}"
        assert hc["test"] == ["CMD", "python", "-m", "tankctl.health", url]
        assert health.default_path(url) == health.DEFAULT_PATHS[name]
        for key in ("interval", "timeout", "start_period"):
            assert _seconds(hc[key]) > 0
        assert int(hc["retries"]) >= 1
        # The probe bounds itself; docker's timeout must leave it room to say why it failed.
        assert _seconds(hc["timeout"]) > health.DEFAULT_TIMEOUT_S + 1.0


def test_compose_restarts_tiers_unless_stopped() -> None:
    for name, s in _compose()["services"].items():
        assert s["restart"] == "unless-stopped", name


def test_health_default_nodes_are_in_the_contract() -> None:
    site = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
    paths = {
        "plant": {t.path for t in plant_tags(site)},
        "plc": {t.path for t in plc_tags(site)},
        "supervisor": {t.path for t in supervisor_tags(site)},
        "historian": {t.path for t in historian_tags(site)},
    }
    for tier, path in health.DEFAULT_PATHS.items():
        assert path in paths[tier], f"{tier}: {path} is not a node of the contract"


# --------------------------------------------------------------------------------------------
# 3. Dockerfile
# --------------------------------------------------------------------------------------------


@dataclass
class Instruction:
    """One Dockerfile instruction: keyword (upper case) and its argument text."""

    keyword: str
    args: str

    def exec_form(self) -> list[str]:
        """The JSON array of an exec-form instruction."""
        value = yaml.safe_load(self.args)  # a JSON array is valid YAML
        assert isinstance(value, list), f"{self.keyword} must be in exec form: {self.args}"
        return [str(v) for v in value]


@dataclass
class Stage:
    """A build stage: its FROM line and the instructions after it."""

    base: str
    name: str | None
    body: list[Instruction] = field(default_factory=list)

    def all(self, keyword: str) -> list[Instruction]:
        return [i for i in self.body if i.keyword == keyword]


def _instructions() -> list[Instruction]:
    """Instructions of the Dockerfile: comments dropped, continuation lines joined."""
    out: list[Instruction] = []
    pending = ""
    for raw in DOCKERFILE.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        line, pending = pending + line, ""
        keyword, _, args = line.partition(" ")
        out.append(Instruction(keyword.upper(), args.strip()))
    assert not pending, "dangling line continuation"
    return out


def _stages(instructions: list[Instruction]) -> list[Stage]:
    stages: list[Stage] = []
    for ins in instructions:
        if ins.keyword == "ARG" and not stages:
            continue  # a global ARG (the base image), before the first stage
        if ins.keyword == "FROM":
            parts = ins.args.split()
            name = parts[2] if len(parts) == 3 and parts[1].upper() == "AS" else None
            stages.append(Stage(parts[0], name))
        else:
            assert stages, f"{ins.keyword} before the first FROM"
            stages[-1].body.append(ins)
    return stages


def _dockerfile_env(stage: Stage) -> dict[str, str]:
    env: dict[str, str] = {}
    for ins in stage.all("ENV"):
        for item in shlex.split(ins.args):
            key, _, value = item.partition("=")
            env[key] = value
    return env


def test_dockerfile_has_a_builder_and_a_slim_final_stage() -> None:
    instructions = _instructions()
    # ARG before the first FROM: the base image of both stages, python:3.11-slim by default.
    assert instructions[0] == Instruction("ARG", "BASE_IMAGE=python:3.11-slim")
    builder, final = _stages(instructions)
    assert builder.base == "${BASE_IMAGE}" and builder.name == "builder"
    assert final.base == "${BASE_IMAGE}"
    # The builder runs docker/install.sh (the same script the fresh-venv test below runs).
    copies = [c.args.split() for c in builder.all("COPY")]
    assert ["docker/", "/usr/local/share/tanklab-docker/"] in copies
    deps, run = builder.all("RUN")
    # First the dependencies alone (a layer only pyproject.toml feeds), then the project.
    assert shlex.split(deps.args) == [
        "sh",
        "/usr/local/share/tanklab-docker/install.sh",
        "--deps-only",
        "/src",
        "/opt/venv",
    ]
    body = builder.body
    assert body.index(deps) < min(body.index(c) for c in builder.all("COPY") if c.args.startswith("src"))
    assert shlex.split(run.args) == [
        "sh",
        "/usr/local/share/tanklab-docker/install.sh",
        "/src",
        "/opt/venv",
        "/tmp/wheels",
    ]


def test_dockerfile_final_stage_copies_only_the_venv_and_configs() -> None:
    final = _stages(_instructions())[-1]
    copies = sorted(c.args.split() for c in final.all("COPY") + final.all("ADD"))
    assert copies == [["--from=builder", "/opt/venv", "/opt/venv"], ["configs", "./configs"]]
    (workdir,) = final.all("WORKDIR")
    assert workdir.args == "/app"  # so TANKLAB_CONFIG=configs/... resolves to /app/configs/...


def test_dockerfile_installs_no_compiler() -> None:
    for stage in _stages(_instructions()):
        for run in stage.all("RUN"):
            installs = re.findall(r"(?:apt-get|apt|apk)\s+(?:-\S+\s+)*(?:install|add)\b([^&;|]*)", run.args)
            for packages in installs:
                assert not COMPILERS.search(packages), f"compiler installed: {run.args}"
    script = INSTALL_SCRIPT.read_text()
    assert "--only-binary=:all:" in script, "dependencies must come as wheels (no compiler)"
    assert not re.search(r"apt-get|apk add", script)


def test_dockerfile_runs_tankctl_as_a_non_root_user() -> None:
    final = _stages(_instructions())[-1]
    users = final.all("USER")
    assert users, "the final stage must switch to a non-root user"
    user = users[-1].args.split(":")[0]
    assert user not in {"root", "0"}
    (run,) = [r for r in final.all("RUN") if "useradd" in r.args]
    assert re.search(rf"useradd\b.*--uid (\d+)\b.*\b{user}\s*(&&|$)", run.args)
    uid = int(re.search(r"--uid (\d+)", run.args)[1])  # type: ignore[index]
    assert uid >= 1000
    # USER comes after every RUN: nothing after it could need root.
    body = final.body
    assert max(i for i, ins in enumerate(body) if ins.keyword == "RUN") < body.index(users[-1])
    (entry,) = final.all("ENTRYPOINT")
    assert entry.exec_form() == ["tankctl"]
    (cmd,) = final.all("CMD")
    assert cmd.exec_form() == ["plant"]


def test_dockerfile_environment_and_ports() -> None:
    final = _stages(_instructions())[-1]
    env = _dockerfile_env(final)
    assert env["PATH"].split(":")[0] == "/opt/venv/bin"
    assert env["PYTHONUNBUFFERED"] == "1"
    assert env["TANKLAB_HOST"] == "0.0.0.0"
    (expose,) = final.all("EXPOSE")
    assert sorted(int(p) for p in expose.args.split()) == sorted(TIERS.values())


def test_dockerignore_keeps_the_context_small_but_complete() -> None:
    patterns = [
        line.strip()
        for line in DOCKERIGNORE.read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]

    def ignored(path: str) -> bool:
        parts = path.split("/")
        prefixes = ["/".join(parts[: i + 1]) for i in range(len(parts))]
        return any(fnmatch.fnmatch(p, pat) for pat in patterns for p in prefixes)

    for path in (".venv", ".git", ".pytest_cache", ".mypy_cache", ".ruff_cache", ".hypothesis", "tests"):
        assert ignored(path), f"{path} must not be in the build context"
    # Everything the Dockerfile copies from the context must be in it.
    needed = ["pyproject.toml", "README.md", "src/tankctl/cli.py", "configs/three_tank_energies_sim.yaml"]
    for path in [*needed, "docker/install.sh"]:
        assert not ignored(path), f"{path} is needed by the Dockerfile"
        assert (ROOT / path).exists()


# --------------------------------------------------------------------------------------------
# 4. the image's install and start steps, in a fresh venv
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fresh_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A venv made by docker/install.sh exactly as the builder stage makes /opt/venv."""
    base = tmp_path_factory.mktemp("image")
    venv, wheels = base / "venv", base / "wheels"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TANKLAB_", "VIRTUAL_ENV", "PYTHON"))}
    env["PYTHON"] = sys.executable  # the builder stage's python3 is 3.11 too
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    # The builder's two steps: the dependencies alone (its own layer), then the project.
    for args in (["--deps-only", str(ROOT), str(venv)], [str(ROOT), str(venv), str(wheels)]):
        result = subprocess.run(
            ["sh", str(INSTALL_SCRIPT), *args],
            env=env,
            capture_output=True,
            text=True,
            timeout=hang_bound(600),
            check=False,
        )
        assert result.returncode == 0, (
            f"docker/install.sh {args[0]} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
        )
        if args[0] == "--deps-only":
            # Every runtime dependency, and not the project itself yet.
            listed = subprocess.run(
                [str(venv / "bin" / "python"), "-m", "pip", "list", "--format=freeze"],
                capture_output=True,
                text=True,
                check=True,
            ).stdout.lower()
            assert "asyncua==" in listed and "numpy==" in listed and "tanklab==" not in listed
    return venv


def _image_env(venv: Path) -> dict[str, str]:
    """The environment a container gets: the Dockerfile's ENV, no TANKLAB_* of the caller."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TANKLAB_", "VIRTUAL_ENV", "PYTHON"))}
    image = _dockerfile_env(_stages(_instructions())[-1])
    env.update({k: v for k, v in image.items() if k != "PATH"})
    env["PATH"] = f"{venv / 'bin'}:{env.get('PATH', '/usr/bin:/bin')}"
    return env


@pytest.mark.process
@pytest.mark.timeout(1800)
async def test_image_install_and_start_steps_in_a_fresh_venv(fresh_venv: Path, tmp_path: Path) -> None:
    env = _image_env(fresh_venv)
    # What compose mounts read-only at TANKLAB_HOME (the image has no keys), and the audit volume.
    env["TANKLAB_HOME"] = os.environ["TANKLAB_HOME"]
    env["TANKLAB_AUDIT_DIR"] = str(tmp_path / "audit")
    python = str(fresh_venv / "bin" / "python")
    # The venv holds its own copy of the code, not the source tree.
    where = subprocess.run(
        [python, "-c", "import tankctl, tanklab, plant_sim; print(tankctl.__file__)"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert Path(where.stdout.strip()).is_relative_to(fresh_venv)

    # /app of the image: configs/ only.
    app = tmp_path / "app"
    shutil.copytree(ROOT / "configs", app / "configs")
    port = free_port()
    proc = await asyncio.create_subprocess_exec(
        str(fresh_venv / "bin" / "tankctl"),
        "plant",
        "--port",
        str(port),
        "--config",
        "configs/three_tank_energies_sim.yaml",
        cwd=app,
        env=env,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        start_new_session=True,
    )
    try:
        assert proc.stdout is not None
        banner = (await asyncio.wait_for(proc.stdout.readline(), 30)).decode().strip()
        assert f"at opc.tcp://0.0.0.0:{port}/tanklab/plant" in banner, banner  # TANKLAB_HOST from ENV

        # As the compose healthcheck does: localhost, the server listening on 0.0.0.0.
        url = f"opc.tcp://localhost:{port}/tanklab/plant"
        code, out, err = await _probe(python, url, app, env)
        assert code == 0, err
        assert out.startswith(f"ok {url} Plant.Sim.Time = ")

        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), 30) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()

    code, out, err = await _probe(python, url, app, env)
    assert code == 1 and out == ""
    assert len(err.splitlines()) == 1 and err.startswith(f"tankctl.health: {url}: cannot connect")


async def _probe(python: str, url: str, cwd: Path, env: dict[str, str]) -> tuple[int, str, str]:
    probe = await asyncio.create_subprocess_exec(
        python,
        "-m",
        "tankctl.health",
        url,
        cwd=cwd,
        env=env,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    out, err = await asyncio.wait_for(probe.communicate(), hang_bound(20))
    assert probe.returncode is not None
    return probe.returncode, out.decode().strip(), err.decode().strip()


# --------------------------------------------------------------------------------------------
# the health probe in-process
# --------------------------------------------------------------------------------------------


async def test_health_reads_a_running_plant() -> None:
    from plant_sim.runtime import run_plant

    site = load_site(ROOT / "configs/three_tank_energies_sim.yaml")
    port = free_port()
    stop, ready = asyncio.Event(), asyncio.Event()
    task = asyncio.create_task(
        run_plant(
            site, host="127.0.0.1", port=port, security=server_security(), speed=1.0, stop=stop, ready=ready
        )
    )
    try:
        await wait_until(ready.is_set, 20, what="plant server ready")
        url = f"opc.tcp://127.0.0.1:{port}/tanklab/plant"
        own = identity(tier="plant")  # the probe acts with the tier's own certificate
        t = await health.read_once(url, "Plant.Sim.Time", own)
        assert isinstance(t, float) and t >= 0.0
        with pytest.raises(health.ProbeError, match=r"Plant\.Nope: BadNodeIdUnknown"):
            await health.read_once(url, "Plant.Nope", own)
        # A plc URL on the plant's port: the plc's default node is not there.
        with pytest.raises(health.ProbeError, match=r"PLC\.Status\.Scan: BadNodeIdUnknown"):
            await health.read_once(
                url.replace("/plant", "/plc"), health.default_path("x/plc"), identity(tier="plc")
            )
        # The supervisor's certificate is no identity on the plant: refused, one line.
        with pytest.raises(health.ProbeError, match="BadUserAccessDenied"):
            await health.read_once(url, "Plant.Sim.Time", identity(tier="supervisor"))
    finally:
        stop.set()
        await asyncio.wait_for(task, hang_bound(20))


def test_health_default_path_by_tier() -> None:
    assert health.default_path("opc.tcp://plant:4840/tanklab/plant") == "Plant.Sim.Time"
    assert health.default_path("opc.tcp://h:4841/tanklab/plc/") == "PLC.Status.Scan"
    assert health.default_path("opc.tcp://h:4842/tanklab/supervisor") == "Supervisor.Mode"
    with pytest.raises(ValueError, match="pass --path"):
        health.default_path("opc.tcp://h:4840/")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "the following arguments are required: url"),
        (["http://x/tanklab/plant"], "not an opc.tcp:// URL"),
        (["opc.tcp://127.0.0.1:1/tanklab/other"], "cannot tell the tier"),
        (["opc.tcp://127.0.0.1:1/tanklab/plant", "--timeout", "0"], "--timeout must be a positive"),
        (["opc.tcp://127.0.0.1:1/tanklab/plant", "--timeout", "x"], "invalid float value"),
    ],
)
def test_health_bad_usage_is_one_line_and_exit_1(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        code = health.main(argv)
    except SystemExit as e:
        code = e.code  # type: ignore[assignment]
    out, err = capsys.readouterr()
    assert code == 1 and out == ""
    assert len(err.splitlines()) == 1 and message in err


def test_health_unreachable_tier_is_one_line_and_exit_1(capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()  # nothing listens there
    assert health.main([f"opc.tcp://127.0.0.1:{port}/tanklab/plc", "--timeout", "2"]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert len(err.splitlines()) == 1 and "cannot connect" in err
