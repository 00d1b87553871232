"""deploy/kubernetes/ without a cluster: rendered, validated offline, checked against compose.

1. Both overlays (``site``, ``fleet``) render with the kustomize subset of
   :mod:`tanklab_testing.kustomize` and every object validates against the Kubernetes OpenAPI
   schemas of :data:`K8S_VERSION` (kubernetes-validate, offline, strict: unknown fields fail).
2. The site's tiers are docker-compose.yml's services: the same image, the same arguments to the
   Dockerfile's ``ENTRYPOINT ["tankctl"]``, the same environment (URLs by Service name), the
   compose healthcheck as their exec probes; the HMI runs ``tankctl hmi`` on 8080 with an HTTP
   probe on ``/healthz``. The fleet's site pod runs the same commands, probes and homes.
3. Security: non-root uid 10001 (the Dockerfile's user), read-only root filesystem,
   no privilege escalation, every capability dropped, RuntimeDefault seccomp, no service account
   token; every writable mount a PVC or an emptyDir, and every path a tier writes (state file,
   retentive file, audit log, historian store) on its PVC.
4. Secrets are never inline: no Secret object and no key material in the manifests; every
   Secret key a pod projects is one ``tankctl k8s secrets`` renders.
5. NetworkPolicies allow exactly the compose paths: each client -> server connection of the
   compose wiring (the URLs each service is given), the HMI's four, and operator pods' to every
   port; nothing else (the supervisor never reaches the plant).
6. The fleet's ``pick-site`` script, run for real: the pod index picks the site file.
7. ``tankctl k8s secrets`` on a throw-away home: valid Secrets holding the home's bytes, files
   with ``--output``, one-line errors for an incomplete home or a bad name, no asyncua imported.
"""

from __future__ import annotations

import base64
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import kubernetes_validate
import pytest
import yaml
from typer.testing import CliRunner

from tankctl.cli import app
from tankctl.k8s import PUBLIC_FILES, WORKLOAD_IDENTITY, public_key
from tanklab_io.containers import CONTAINER_GID, CONTAINER_UID
from tanklab_testing import kustomize
from tanklab_testing.logins import provision

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy" / "kubernetes"
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
DOCKERFILE = (ROOT / "Dockerfile").read_text()

K8S_VERSION = "1.31.0"
"""Kubernetes version whose schemas the objects are validated against (pod-index label: >= 1.28)."""

TIER_PORTS = {"plant": 4840, "plc": 4841, "supervisor": 4842, "historian": 4843}
HMI_PORT = 8080
WORKLOADS = (*TIER_PORTS, "hmi")
OPERATOR = "operator"
"""Pseudo-workload: a pod labelled tanklab.io/client=operator (the CLI of the compose host)."""

URL = re.compile(r"^opc\.tcp://([a-z]+):(\d+)/tanklab/([a-z]+)$")


@pytest.fixture(scope="module")
def site() -> list[dict[str, Any]]:
    return kustomize.render(DEPLOY / "overlays" / "site")


@pytest.fixture(scope="module")
def fleet() -> list[dict[str, Any]]:
    return kustomize.render(DEPLOY / "overlays" / "fleet")


def one(objects: list[dict[str, Any]], kind: str, name: str) -> dict[str, Any]:
    (obj,) = [o for o in objects if o["kind"] == kind and o["metadata"]["name"] == name]
    return obj


def pod_spec(obj: dict[str, Any]) -> dict[str, Any]:
    spec: dict[str, Any] = obj["spec"]["template"]["spec"]
    return spec


def workload_containers(objects: list[dict[str, Any]]) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
    """(pod spec, container) of every container and init container of every workload."""
    for o in objects:
        if o["kind"] in ("Deployment", "StatefulSet"):
            spec = pod_spec(o)
            for c in [*spec.get("initContainers", []), *spec["containers"]]:
                yield spec, c


def site_container(site: list[dict[str, Any]], workload: str) -> dict[str, Any]:
    (c,) = pod_spec(one(site, "Deployment", workload))["containers"]
    return c


def fleet_container(fleet: list[dict[str, Any]], workload: str) -> dict[str, Any]:
    (c,) = [c for c in pod_spec(one(fleet, "StatefulSet", "site"))["containers"] if c["name"] == workload]
    return c


def env_of(container: dict[str, Any], objects: list[dict[str, Any]]) -> dict[str, str]:
    """The container's environment with ConfigMap references resolved."""
    out = {}
    for e in container.get("env", []):
        if "value" in e:
            out[e["name"]] = e["value"]
        elif "configMapKeyRef" in e.get("valueFrom", {}):
            ref = e["valueFrom"]["configMapKeyRef"]
            out[e["name"]] = one(objects, "ConfigMap", ref["name"])["data"][ref["key"]]
    return out


# ---------------------------------------------------------------------------------------------
# 1. Render and validate
# ---------------------------------------------------------------------------------------------


def test_site_renders_the_five_workloads_their_services_and_volumes(site: list[dict[str, Any]]) -> None:
    kinds = {(o["kind"], o["metadata"]["name"]) for o in site}
    for w in WORKLOADS:
        assert ("Deployment", w) in kinds and ("Service", w) in kinds and ("NetworkPolicy", w) in kinds
    for tier in TIER_PORTS:
        assert ("PersistentVolumeClaim", f"{tier}-state") in kinds
    assert {o["metadata"].get("namespace") for o in site if o["kind"] != "Namespace"} == {"tanklab"}
    assert all(
        o["metadata"]["labels"]["app.kubernetes.io/part-of"] == "tanklab"
        for o in site
        if o["kind"] != "Namespace"
    )


@pytest.mark.parametrize("overlay", ["site", "fleet"])
def test_every_rendered_object_validates_against_the_kubernetes_schemas(overlay: str) -> None:
    objects = kustomize.render(DEPLOY / "overlays" / overlay)
    assert objects
    for obj in objects:
        kubernetes_validate.validate(obj, K8S_VERSION, strict=True)


def test_the_validator_refuses_a_broken_object(site: list[dict[str, Any]]) -> None:
    """The schema check has teeth: a misspelt field and a wrong type are refused."""
    deployment = one(site, "Deployment", "plc")
    broken = yaml.safe_load(yaml.safe_dump(deployment))
    pod_spec(broken)["containers"][0]["securityContext"]["readOnlyRootFilesytem"] = True
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(broken, K8S_VERSION, strict=True)
    broken = yaml.safe_load(yaml.safe_dump(deployment))
    broken["spec"]["replicas"] = "one"
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(broken, K8S_VERSION, strict=True)


# ---------------------------------------------------------------------------------------------
# 2. The same tiers as docker-compose.yml
# ---------------------------------------------------------------------------------------------


def test_dockerfile_entrypoint_is_what_the_args_are_given_to() -> None:
    assert 'ENTRYPOINT ["tankctl"]' in DOCKERFILE


@pytest.mark.parametrize("tier", TIER_PORTS)
def test_site_tiers_run_the_compose_services(site: list[dict[str, Any]], tier: str) -> None:
    service = COMPOSE["services"][tier]
    c = site_container(site, tier)
    assert c["image"] == service.get("image", "tanklab:latest") == "tanklab:latest"
    assert "command" not in c, "the image's ENTRYPOINT (tankctl) must stay"
    assert c["args"] == service["command"]
    env = env_of(c, site)
    for key, value in service["environment"].items():
        default = re.fullmatch(r"\$\{[A-Z_]+:-(.*)\}", str(value))
        assert env[key] == (default.group(1) if default else str(value)), key
    assert env["TANKLAB_HOME"] == "/etc/tanklab"
    assert [p["containerPort"] for p in c["ports"]] == [TIER_PORTS[tier]]
    svc = one(site, "Service", tier)
    assert svc["spec"]["type"] == "ClusterIP"
    assert [p["port"] for p in svc["spec"]["ports"]] == [TIER_PORTS[tier]]
    assert svc["spec"]["selector"] == pod_template_labels(site, tier)


def pod_template_labels(objects: list[dict[str, Any]], workload: str) -> dict[str, str]:
    labels: dict[str, str] = one(objects, "Deployment", workload)["spec"]["template"]["metadata"]["labels"]
    return labels


@pytest.mark.parametrize("tier", TIER_PORTS)
def test_tier_probes_are_the_compose_healthcheck(
    site: list[dict[str, Any]], fleet: list[dict[str, Any]], tier: str
) -> None:
    compose_test = COMPOSE["services"][tier]["healthcheck"]["test"]
    assert compose_test[0] == "CMD"
    for c in (site_container(site, tier), fleet_container(fleet, tier)):
        for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
            assert c[probe]["exec"]["command"] == compose_test[1:], (tier, probe)
            assert c[probe]["timeoutSeconds"] == 30  # compose's timeout: a loaded machine took 6.9 s


def test_hmi_serves_8080_with_an_http_probe_on_healthz(
    site: list[dict[str, Any]], fleet: list[dict[str, Any]]
) -> None:
    c = site_container(site, "hmi")
    args = c["args"]
    assert args[0] == "hmi" and "command" not in c
    opts = dict(zip(args[1::2], args[2::2], strict=True))
    assert opts["--host"] == "0.0.0.0" and opts["--port"] == str(HMI_PORT)
    assert opts["--config"] == "$(TANKLAB_CONFIG)" and "TANKLAB_CONFIG" in env_of(c, site)
    for tier, port in TIER_PORTS.items():
        assert opts[f"--{tier}-url"] == f"opc.tcp://{tier}:{port}/tanklab/{tier}"
    assert c["ports"] == [{"name": "http", "containerPort": HMI_PORT}]
    svc = one(site, "Service", "hmi")
    assert svc["spec"]["type"] == "ClusterIP" and svc["spec"]["ports"][0]["port"] == HMI_PORT
    for c in (site_container(site, "hmi"), fleet_container(fleet, "hmi")):
        for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
            assert c[probe]["httpGet"] == {"path": "/healthz", "port": "http"}


@pytest.mark.parametrize("workload", WORKLOADS)
def test_fleet_site_pod_runs_the_same_tiers_on_localhost(
    site: list[dict[str, Any]], fleet: list[dict[str, Any]], workload: str
) -> None:
    base, pod = site_container(site, workload), fleet_container(fleet, workload)
    assert pod["image"] == base["image"]
    rewritten = [re.sub(r"opc\.tcp://[a-z]+:", "opc.tcp://localhost:", a) for a in base["args"]]
    assert pod["args"] == rewritten
    base_env, pod_env = env_of(base, site), env_of(pod, fleet)
    for key, value in base_env.items():
        expected = {"TANKLAB_CONFIG": "/run/tanklab/site.yaml"}.get(
            key, re.sub(r"opc\.tcp://[a-z]+:", "opc.tcp://localhost:", value)
        )
        assert pod_env[key] == expected, key
    assert pod["resources"] == base["resources"]
    spec = pod_spec(one(fleet, "StatefulSet", "site"))
    home = {v["name"]: v for v in spec["volumes"]}[f"home-{workload}"]
    base_home = {v["name"]: v for v in pod_spec(one(site, "Deployment", workload))["volumes"]}["home"]
    assert home["projected"] == base_home["projected"]


# ---------------------------------------------------------------------------------------------
# 3. Security contexts, writable paths, resources
# ---------------------------------------------------------------------------------------------


def test_dockerfile_user_is_the_pods_uid() -> None:
    assert f"--uid {CONTAINER_UID}" in DOCKERFILE and f"--gid {CONTAINER_GID}" in DOCKERFILE


@pytest.mark.parametrize("overlay", ["site", "fleet"])
def test_security_contexts(overlay: str) -> None:
    objects = kustomize.render(DEPLOY / "overlays" / overlay)
    checked = 0
    for spec, c in workload_containers(objects):
        pod = spec["securityContext"]
        assert pod["runAsNonRoot"] is True and pod["runAsUser"] == CONTAINER_UID
        assert pod["runAsGroup"] == CONTAINER_GID and pod["fsGroup"] == CONTAINER_GID
        assert pod["seccompProfile"] == {"type": "RuntimeDefault"}
        assert spec["automountServiceAccountToken"] is False
        assert not spec.get("hostNetwork") and not spec.get("hostPID") and not spec.get("hostIPC")
        sc = c["securityContext"]
        assert sc["runAsNonRoot"] is True
        assert sc["allowPrivilegeEscalation"] is False
        assert sc["readOnlyRootFilesystem"] is True
        assert sc["capabilities"] == {"drop": ["ALL"]}
        assert sc["seccompProfile"] == {"type": "RuntimeDefault"}
        assert not sc.get("privileged")
        assert all("hostPath" not in v for v in spec["volumes"])
        checked += 1
    assert checked == (5 if overlay == "site" else 6)  # the fleet: five tiers and pick-site


def writes_of(container: dict[str, Any], env: dict[str, str]) -> list[str]:
    """Paths the tier writes: its --state-file / --retain-file, its audit log, the SQLite store."""
    args = container["args"]
    paths = [args[k + 1] for k, a in enumerate(args) if a in ("--state-file", "--retain-file")]
    if container["name"] != "hmi":
        paths.append(f"{env['TANKLAB_AUDIT_DIR']}/{container['name']}.log")  # tanklab_io.audit
    if "TANKLAB_HISTORIAN_URL" in env:
        paths.append(env["TANKLAB_HISTORIAN_URL"])
    return paths


@pytest.mark.parametrize("overlay", ["site", "fleet"])
def test_every_writable_mount_is_a_volume_and_every_write_lands_on_a_pvc(overlay: str) -> None:
    objects = kustomize.render(DEPLOY / "overlays" / overlay)
    claims = {o["metadata"]["name"] for o in objects if o["kind"] == "PersistentVolumeClaim"}
    for o in objects:
        if o["kind"] not in ("Deployment", "StatefulSet"):
            continue
        spec = pod_spec(o)
        templates = {t["metadata"]["name"] for t in o["spec"].get("volumeClaimTemplates", [])}
        volumes = {v["name"]: v for v in spec["volumes"]}

        persistent = set(templates) | {
            name
            for name, v in volumes.items()
            if v.get("persistentVolumeClaim", {}).get("claimName") in claims
        }
        for c in [*spec.get("initContainers", []), *spec["containers"]]:
            mounts = c["volumeMounts"]
            for m in mounts:
                if not m.get("readOnly"):
                    assert m["name"] in persistent or "emptyDir" in volumes[m["name"]], (c["name"], m)
            assert any(m["mountPath"] == "/tmp" and "emptyDir" in volumes[m["name"]] for m in mounts)
            if c["name"] == "pick-site":
                continue
            for path in writes_of(c, env_of(c, objects)):
                under = [m for m in mounts if path.startswith(m["mountPath"].rstrip("/") + "/")]
                assert under and under[-1]["name"] in persistent and not under[-1].get("readOnly"), (
                    c["name"],
                    path,
                )
    if overlay == "site":
        assert claims == {f"{t}-state" for t in TIER_PORTS}


def test_fleet_tiers_share_their_site_volume_without_sharing_a_file(fleet: list[dict[str, Any]]) -> None:
    spec = pod_spec(one(fleet, "StatefulSet", "site"))
    tiers = [c for c in spec["containers"] if c["name"] in TIER_PORTS]
    writes = [p for c in tiers for p in writes_of(c, env_of(c, fleet))]
    assert len(writes) == len(set(writes)) == 8  # 3 state or retentive files, 4 audit logs, the store
    for c in tiers:
        (state,) = [m for m in c["volumeMounts"] if m["mountPath"] == "/var/lib/tanklab"]
        assert state["name"] == "state" and "subPath" not in state  # a subPath dir would be root's


@pytest.mark.parametrize("overlay", ["site", "fleet"])
def test_resources_are_requested_and_bounded(overlay: str) -> None:
    for _spec, c in workload_containers(kustomize.render(DEPLOY / "overlays" / overlay)):
        r = c["resources"]
        assert set(r["requests"]) == {"cpu", "memory"} and set(r["limits"]) == {"cpu", "memory"}, c["name"]


MEASURED_MIB = {
    "plant": (184.9, 200.2),
    "plc": (162.1, 177.5),
    "supervisor": (193.1, 208.3),
    "historian": (158.6, 173.2),
}
"""(steady RSS, peak RSS) of each tier under `tankctl up` [MiB] (docs/kubernetes.md "Resources")."""
PROBE_MIB = 66.8
"""Peak RSS of one `python -m tankctl.health` [MiB]: an exec probe runs in the tier's cgroup."""


def mebibytes(quantity: str) -> float:
    units = {"Mi": 1.0, "Gi": 1024.0}
    return float(quantity[:-2]) * units[quantity[-2:]]


@pytest.mark.parametrize("tier", MEASURED_MIB)
def test_memory_figures_cover_the_measured_rss_and_a_probe(site: list[dict[str, Any]], tier: str) -> None:
    steady, peak = MEASURED_MIB[tier]
    resources = site_container(site, tier)["resources"]
    assert mebibytes(resources["requests"]["memory"]) >= steady
    assert mebibytes(resources["limits"]["memory"]) >= peak + PROBE_MIB


@pytest.mark.parametrize("overlay", ["site", "fleet"])
def test_single_writer_workloads_never_overlap(overlay: str) -> None:
    """One PLC driving the pumps and one writer of each volume: Recreate, one replica."""
    for o in kustomize.render(DEPLOY / "overlays" / overlay):
        if o["kind"] == "Deployment":
            assert o["spec"]["replicas"] == 1 and o["spec"]["strategy"] == {"type": "Recreate"}


# ---------------------------------------------------------------------------------------------
# 4. Secrets referenced, never inline
# ---------------------------------------------------------------------------------------------


def strings(value: Any) -> Iterator[str]:
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for v in value.values():
            yield from strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from strings(v)


def projected_keys(objects: list[dict[str, Any]]) -> dict[str, set[str]]:
    """Secret name -> the keys the pods project from it."""
    out: dict[str, set[str]] = {}
    for o in objects:
        if o["kind"] in ("Deployment", "StatefulSet"):
            for v in pod_spec(o)["volumes"]:
                assert "secret" not in v, "Secrets are projected into a home, never mounted flat"
                for source in v.get("projected", {}).get("sources", []):
                    secret = source["secret"]
                    out.setdefault(secret["name"], set()).update(i["key"] for i in secret["items"])
    return out


@pytest.mark.parametrize("overlay", ["site", "fleet"])
def test_no_secret_data_in_the_manifests(overlay: str) -> None:
    objects = kustomize.render(DEPLOY / "overlays" / overlay)
    assert not [o for o in objects if o["kind"] == "Secret"]
    for o in objects:
        for s in strings(o):
            assert "PRIVATE KEY" not in s and "BEGIN CERTIFICATE" not in s and "password" not in s.lower()
    for _spec, c in workload_containers(objects):
        assert "envFrom" not in c and all(
            "secretKeyRef" not in e.get("valueFrom", {}) for e in c.get("env", [])
        )


@pytest.mark.parametrize("overlay", ["site", "fleet"])
def test_each_pod_holds_only_its_own_key_at_the_home_layout(overlay: str) -> None:
    objects = kustomize.render(DEPLOY / "overlays" / overlay)
    for spec, c in workload_containers(objects):
        if c["name"] == "pick-site":
            continue
        (home,) = [m for m in c["volumeMounts"] if m["mountPath"] == "/etc/tanklab"]
        assert home["readOnly"] is True
        volume = {v["name"]: v for v in spec["volumes"]}[home["name"]]
        items = {i["key"]: i for s in volume["projected"]["sources"] for i in s["secret"]["items"]}
        identity = WORKLOAD_IDENTITY[c["name"]]
        secrets = {s["secret"]["name"] for s in volume["projected"]["sources"]}
        assert {n for n in secrets if "-key-" in n} == {f"tanklab-key-{identity}"}
        assert items[f"{identity}.pem"]["path"] == f"pki/private/{identity}.pem"
        assert items[f"{identity}.pem"]["mode"] == 0o400
        for rel in PUBLIC_FILES:
            assert items[public_key(rel)]["path"] == f"pki/{rel}"
        assert ("users.json" in items) == (c["name"] != "hmi")


# ---------------------------------------------------------------------------------------------
# 5. NetworkPolicies: exactly the compose paths
# ---------------------------------------------------------------------------------------------


def compose_paths() -> set[tuple[str, str, int]]:
    """(client, server, port) of every URL a compose service is given, plus the HMI's four
    (hmi-contract: --plant-url ... --historian-url) and the operators' CLI to every port."""
    paths = set()
    for name, service in COMPOSE["services"].items():
        for value in service.get("environment", {}).values():
            if m := URL.match(str(value)):
                paths.add((name, m.group(1), int(m.group(2))))
    paths |= {("hmi", tier, port) for tier, port in TIER_PORTS.items()}
    paths |= {(OPERATOR, w, port) for w, port in [*TIER_PORTS.items(), ("hmi", HMI_PORT)]}
    return paths


def selects(selector: dict[str, Any], labels: dict[str, str]) -> bool:
    assert set(selector) <= {"matchLabels"}, "only matchLabels selectors are evaluated here"
    return all(labels.get(k) == v for k, v in selector.get("matchLabels", {}).items())


def allows(rules: list[dict[str, Any]], peer_key: str, peer: dict[str, str], port: int) -> bool:
    for rule in rules:
        peers = rule.get(peer_key, [])
        ports = [p["port"] for p in rule.get("ports", [])]
        same_namespace = [p for p in peers if "namespaceSelector" not in p]
        if any(selects(p["podSelector"], peer) for p in same_namespace) and port in ports:
            return True
    return False


def connection_allowed(
    policies: list[dict[str, Any]], client: dict[str, str], server: dict[str, str], port: int
) -> bool:
    """NetworkPolicy semantics: a pod selected by any policy of a type is isolated for it, and a
    connection needs the client's egress and the server's ingress to allow it."""

    def direction(pod: dict[str, str], kind: str, peer_key: str, peer: dict[str, str]) -> bool:
        mine = [
            p for p in policies if kind in p["spec"]["policyTypes"] and selects(p["spec"]["podSelector"], pod)
        ]
        if not mine:
            return True
        return any(allows(p["spec"].get(kind.lower(), []), peer_key, peer, port) for p in mine)

    return direction(client, "Egress", "to", server) and direction(server, "Ingress", "from", client)


def test_network_policies_allow_exactly_the_compose_paths(site: list[dict[str, Any]]) -> None:
    policies = [o for o in site if o["kind"] == "NetworkPolicy"]
    labels = {w: pod_template_labels(site, w) for w in WORKLOADS}
    labels[OPERATOR] = {"tanklab.io/client": "operator"}
    ports = {**TIER_PORTS, "hmi": HMI_PORT}
    allowed = {
        (client, server, ports[server])
        for client in labels
        for server in WORKLOADS
        if client != server and connection_allowed(policies, labels[client], labels[server], ports[server])
    }
    assert allowed == compose_paths()
    assert ("supervisor", "plant", 4840) not in allowed  # the zones' point
    # a pod of the namespace that is none of these reaches nothing
    stranger = {"app": "something-else"}
    assert not any(connection_allowed(policies, stranger, labels[w], ports[w]) for w in WORKLOADS)
    # and other ports of a tier are closed even to its clients
    assert not connection_allowed(policies, labels["plc"], labels["plant"], 4841)


def test_clients_may_resolve_service_names_and_servers_open_nothing(site: list[dict[str, Any]]) -> None:
    for w in WORKLOADS:
        policy = one(site, "NetworkPolicy", w)
        egress = policy["spec"]["egress"]
        if w == "plant":
            assert egress == []
        else:
            dns = [r for r in egress if any("namespaceSelector" in p for p in r["to"])]
            assert len(dns) == 1 and {p["port"] for p in dns[0]["ports"]} == {53}
    assert one(site, "NetworkPolicy", "default-deny")["spec"] == {
        "podSelector": {},
        "policyTypes": ["Ingress", "Egress"],
    }


def test_fleet_sites_accept_only_operators(fleet: list[dict[str, Any]]) -> None:
    policies = [o for o in fleet if o["kind"] == "NetworkPolicy"]
    pod = one(fleet, "StatefulSet", "site")["spec"]["template"]["metadata"]["labels"]
    operator = {"tanklab.io/client": "operator"}
    for port in [*TIER_PORTS.values(), HMI_PORT]:
        assert connection_allowed(policies, operator, pod, port)
        assert not connection_allowed(policies, pod, pod, port)  # a site never reaches another
    assert not connection_allowed(policies, operator, pod, 22)


# ---------------------------------------------------------------------------------------------
# 6. The fleet: the pod index picks the site
# ---------------------------------------------------------------------------------------------


def site_image(fleet: list[dict[str, Any]]) -> str:
    images = {c["image"] for c in pod_spec(one(fleet, "StatefulSet", "site"))["containers"]}
    assert len(images) == 1
    return images.pop()


def pick_site(
    fleet: list[dict[str, Any]], tmp_path: Path, index: str, sites: str
) -> subprocess.CompletedProcess[str]:
    spec = pod_spec(one(fleet, "StatefulSet", "site"))
    (init,) = spec["initContainers"]
    assert init["command"] == ["sh", "-c"]  # the one container that replaces the entrypoint
    assert init["image"] == site_image(fleet)
    env_names = {e["name"] for e in init["env"]}
    assert env_names == {"TANKLAB_SITE_INDEX", "TANKLAB_FLEET_SITES", "TANKLAB_SITE_OUT"}
    index_ref = next(e for e in init["env"] if e["name"] == "TANKLAB_SITE_INDEX")["valueFrom"]["fieldRef"]
    assert index_ref["fieldPath"] == "metadata.labels['apps.kubernetes.io/pod-index']"
    (tmp_path / "sites.txt").write_text(sites)
    env = {
        **os.environ,
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
        "TANKLAB_SITE_INDEX": index,
        "TANKLAB_FLEET_SITES": str(tmp_path / "sites.txt"),
        "TANKLAB_SITE_OUT": str(tmp_path / "site.yaml"),
    }
    return subprocess.run(
        ["sh", "-c", init["args"][0]],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_fleet_pod_index_picks_the_site_file(fleet: list[dict[str, Any]], tmp_path: Path) -> None:
    sites = "# the fleet\nconfigs/three_tank_energies_sim.yaml\n\nconfigs/three_tank_kortela.yaml\n"
    for index, expected in [
        ("0", "three_tank_energies_sim"),
        ("1", "three_tank_kortela"),
        ("2", "three_tank_energies_sim"),
    ]:
        run = pick_site(fleet, tmp_path, index, sites)
        assert run.returncode == 0, run.stderr
        assert (tmp_path / "site.yaml").read_text() == (ROOT / "configs" / f"{expected}.yaml").read_text()
        assert f"site {index} runs configs/{expected}.yaml" in run.stdout
    tiers = [c for c in pod_spec(one(fleet, "StatefulSet", "site"))["containers"] if c["name"] != "hmi"]
    assert {env_of(c, fleet)["TANKLAB_CONFIG"] for c in tiers} == {"/run/tanklab/site.yaml"}
    sites_map = one(fleet, "ConfigMap", "tanklab-fleet-sites")["data"]["sites.txt"]
    for line in sites_map.splitlines():
        if line.strip() and not line.startswith("#"):
            assert (ROOT / line.strip()).is_file(), line


@pytest.mark.parametrize(
    ("index", "sites", "message"),
    [
        ("0", "# nothing\n\n", "lists no site file"),
        ("x1", "configs/three_tank_energies_sim.yaml\n", "is not a number"),
        ("0", "configs/no_such_site.yaml\n", "no_such_site.yaml"),
    ],
)
def test_fleet_pick_site_refuses_bad_input(
    fleet: list[dict[str, Any]], tmp_path: Path, index: str, sites: str, message: str
) -> None:
    run = pick_site(fleet, tmp_path, index, sites)
    assert run.returncode != 0
    assert message in run.stderr
    assert not (tmp_path / "site.yaml").exists()


# ---------------------------------------------------------------------------------------------
# 7. tankctl k8s secrets
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A throw-away security home: a fresh PKI and one engineer (tanklab_testing.logins)."""
    return provision(tmp_path_factory.mktemp("k8s-home")).home.root


def secrets_cli(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, ["k8s", "secrets", *args])
    return result.exit_code, result.stdout, result.stderr


def test_k8s_secrets_renders_valid_secrets_with_the_homes_files(
    home: Path, site: list[dict[str, Any]], fleet: list[dict[str, Any]]
) -> None:
    code, out, err = secrets_cli("--home", str(home), "--namespace", "tanklab")
    assert code == 0, err
    docs = list(yaml.safe_load_all(out))
    assert {d["kind"] for d in docs} == {"Secret"}
    for d in docs:
        kubernetes_validate.validate(d, K8S_VERSION, strict=True)
        assert d["metadata"]["namespace"] == "tanklab" and d["type"] == "Opaque"
    secrets = {d["metadata"]["name"]: {k: base64.b64decode(v) for k, v in d["data"].items()} for d in docs}
    assert secrets["tanklab-users"] == {"users.json": (home / "users.json").read_bytes()}
    for rel in PUBLIC_FILES:
        assert secrets["tanklab-pki"][public_key(rel)] == (home / "pki" / rel).read_bytes()
    for identity in set(WORKLOAD_IDENTITY.values()):
        key = secrets[f"tanklab-key-{identity}"]
        assert key == {f"{identity}.pem": (home / "pki" / "private" / f"{identity}.pem").read_bytes()}
    private = [name for name, data in secrets.items() if any(b"PRIVATE KEY" in v for v in data.values())]
    assert sorted(private) == sorted(f"tanklab-key-{i}" for i in set(WORKLOAD_IDENTITY.values()))
    assert not any(b"ca-key" in k.encode() for data in secrets.values() for k in data)
    ca_key = (home / "pki" / "ca" / "ca-key.pem").read_bytes()
    assert all(ca_key not in v for data in secrets.values() for v in data.values())
    for objects in (site, fleet):
        for name, keys in projected_keys(objects).items():
            assert keys <= set(secrets[name]), name


def test_k8s_secrets_output_dir(home: Path, tmp_path: Path) -> None:
    out_dir = tmp_path / "secrets"
    code, out, err = secrets_cli("--home", str(home), "--name-prefix", "site7", "--output", str(out_dir))
    assert code == 0, err
    assert out_dir.stat().st_mode & 0o777 == 0o700
    files = sorted(p.name for p in out_dir.iterdir())
    assert "kustomization.yaml" in files and "site7-pki.yaml" in files and "site7-key-plc.yaml" in files
    assert all((out_dir / f).stat().st_mode & 0o777 == 0o600 for f in files)
    assert set(out.split()) == {str(out_dir / f) for f in files}
    rendered = kustomize.render(out_dir)
    assert sorted(o["metadata"]["name"] for o in rendered) == sorted(
        f.removesuffix(".yaml") for f in files if f != "kustomization.yaml"
    )
    assert all("namespace" not in o["metadata"] for o in rendered)


def test_k8s_secrets_names_the_missing_file(tmp_path: Path) -> None:
    broken = provision(tmp_path / "home").home.root
    (broken / "pki" / "own" / "historian.der").unlink()
    code, out, err = secrets_cli("--home", str(broken))
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and f"{broken}/pki/own/historian.der: missing" in err
    (broken / "users.json").unlink()
    code, out, err = secrets_cli("--home", str(broken / "nowhere"))
    assert code == 2 and err.count("\n") == 1 and "no security home there" in err


def test_k8s_secrets_names_a_missing_users_file(tmp_path: Path) -> None:
    broken = provision(tmp_path / "home").home.root
    (broken / "users.json").unlink()
    code, out, err = secrets_cli("--home", str(broken), "--output", str(tmp_path / "out"))
    assert (code, out) == (2, "") and err.count("\n") == 1
    assert f"{broken}/users.json: missing; add a user first" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("option", "value"), [("--namespace", "Tanklab_1"), ("--name-prefix", "-x"), ("--name-prefix", "a" * 60)]
)
def test_k8s_secrets_refuses_bad_names(home: Path, option: str, value: str) -> None:
    code, out, err = secrets_cli("--home", str(home), option, value)
    assert (code, out) == (2, "") and err.count("\n") == 1 and "DNS-1123" in err and option in err


def test_k8s_secrets_notes_a_trusted_client_certificate_it_cannot_place(tmp_path: Path) -> None:
    extra_home = provision(tmp_path / "home").home.root
    (extra_home / "pki" / "trusted" / "uaexpert_abc.der").write_bytes(b"0\x82")
    code, out, err = secrets_cli("--home", str(extra_home))
    assert code == 0
    (pki,) = [d for d in yaml.safe_load_all(out) if d["metadata"]["name"] == "tanklab-pki"]
    assert "trusted.uaexpert_abc.der" in pki["data"]
    assert "note: trusted.uaexpert_abc.der is in Secret tanklab-pki" in err


def test_k8s_secrets_imports_no_asyncua(home: Path) -> None:
    code = (
        "import sys\n"
        f"sys.argv = ['tankctl', 'k8s', 'secrets', '--home', {str(home)!r}]\n"
        "from tankctl.entry import main\n"
        "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
        "loaded = any(m == 'asyncua' or m.startswith('asyncua.') for m in sys.modules)\n"
        "print('ASYNCUA', loaded, file=sys.stderr)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False, cwd=ROOT
    )
    assert run.returncode == 0, run.stderr
    assert "ASYNCUA False" in run.stderr
    assert "kind: Secret" in run.stdout
