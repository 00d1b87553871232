"""The HMI's compose service (decision 0047), parsed: a client of every tier by service name,
published on the host's loopback only, its own container home (the CLI's key) mounted read-only."""

from __future__ import annotations

import re
from typing import Any

import yaml

from helpers import ROOT
from tanklab.config import parse_endpoint_url

COMPOSE = ROOT / "docker-compose.yml"
PORTS = {"plant": 4840, "plc": 4841, "supervisor": 4842, "historian": 4843}
URL_VARS = {
    "TANKLAB_PLANT_URL": "plant",
    "TANKLAB_PLC_URL": "plc",
    "TANKLAB_SUPERVISOR_URL": "supervisor",
    "TANKLAB_HISTORIAN_ENDPOINT": "historian",
}


def hmi_service() -> dict[str, Any]:
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    assert isinstance(services["hmi"], dict)
    return services["hmi"]


def default(value: str) -> str:
    """``${VAR:-default}`` as compose resolves it with VAR unset."""
    return re.sub(r"\$\{[A-Z_]+:?-([^}]*)\}", r"\1", value)


def test_hmi_service_runs_the_hmi_command_from_the_one_image() -> None:
    s = hmi_service()
    assert s["image"] == "tanklab:latest" and "build" not in s
    assert s["command"] == ["hmi"]
    assert s["restart"] == "unless-stopped" and s["cap_drop"] == ["ALL"]
    assert s["depends_on"] == {"plc": {"condition": "service_healthy"}}


def test_hmi_is_published_on_the_hosts_loopback_only() -> None:
    s = hmi_service()
    assert [default(p) for p in s["ports"]] == ["127.0.0.1:8080:8080"]
    env = s["environment"]
    # In the container it listens on every interface (the published port reaches it there).
    assert env["TANKLAB_HMI_HOST"] == "0.0.0.0" and env["TANKLAB_HMI_PORT"] == "8080"
    assert "8080/healthz" in " ".join(s["healthcheck"]["test"])


def test_hmi_reaches_every_tier_by_service_name() -> None:
    env = hmi_service()["environment"]
    for var, tier in URL_VARS.items():
        endpoint = parse_endpoint_url(env[var])
        assert (endpoint.host, endpoint.port) == (tier, PORTS[tier]), var
    assert set(hmi_service()["networks"]) == {"control", "supervisory"}


def test_hmi_mounts_its_own_container_home_read_only() -> None:
    mounts = [default(v) for v in hmi_service()["volumes"]]
    assert mounts == ["./.tanklab/containers/hmi:/etc/tanklab:ro"]
