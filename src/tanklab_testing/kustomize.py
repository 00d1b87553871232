"""A renderer of the kustomize subset deploy/kubernetes/ uses (kubectl is not installed here).

``render(directory)`` reads ``directory/kustomization.yaml`` and returns the objects
``kubectl kustomize directory`` prints, for these fields only (anything else is refused, so a
manifest that starts using another feature fails loudly instead of rendering wrongly):

- ``resources``: YAML files (every document in order) and directories holding a
  kustomization (rendered recursively), relative to the kustomization's directory;
- ``namespace``: set as ``metadata.namespace`` of every namespaced object (cluster-scoped kinds,
  :data:`CLUSTER_SCOPED`, are left alone);
- ``labels``: each entry's ``pairs`` added to every object's ``metadata.labels``; kustomize's
  defaults, ``includeSelectors: false`` and ``includeTemplates: false``, are the only ones
  accepted (selectors and pod templates are not touched);
- ``images``: ``name`` -> ``newName`` / ``newTag`` for every container and init container of a
  pod template (Deployment, StatefulSet, DaemonSet, Job) or a Pod whose image name matches;
- ``patches``: ``path`` to a strategic-merge patch that names its target by kind and name:
  maps merge key by key, a list of maps that all carry ``name`` merges item by item on
  ``name`` (kustomize's merge key for containers, volumes, env), any other list is replaced.

Transformers apply in kustomize's order for one kustomization: its resources (overlays'
results included) are loaded, then patches, then namespace, labels and images.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

__all__ = ["CLUSTER_SCOPED", "KustomizeError", "render", "split_image", "strategic_merge"]

CLUSTER_SCOPED = frozenset(
    {
        "Namespace",
        "ClusterRole",
        "ClusterRoleBinding",
        "PersistentVolume",
        "StorageClass",
        "CustomResourceDefinition",
        "PriorityClass",
    }
)
"""Kinds without a namespace (the namespace transformer skips them)."""

_FIELDS = frozenset({"apiVersion", "kind", "resources", "namespace", "labels", "images", "patches"})
_POD_TEMPLATE_KINDS = frozenset({"Deployment", "StatefulSet", "DaemonSet", "Job", "ReplicaSet"})


class KustomizeError(ValueError):
    """The kustomization uses a field outside the subset, or a resource or patch is broken."""


def _load_yaml(path: Path) -> list[dict[str, Any]]:
    try:
        docs = [d for d in yaml.safe_load_all(path.read_text()) if d is not None]
    except (OSError, yaml.YAMLError) as e:
        raise KustomizeError(f"{path}: {e}") from None
    for d in docs:
        if not isinstance(d, dict) or "kind" not in d or "metadata" not in d:
            raise KustomizeError(f"{path}: a document is not a Kubernetes object (kind, metadata)")
    return docs


def strategic_merge(base: Any, patch: Any) -> Any:
    """``patch`` merged into ``base`` (see the module docstring); neither is modified."""
    if isinstance(base, dict) and isinstance(patch, dict):
        out = dict(base)
        for key, value in patch.items():
            out[key] = strategic_merge(base[key], value) if key in base else copy.deepcopy(value)
        return out
    if (
        isinstance(base, list)
        and isinstance(patch, list)
        and all(isinstance(x, dict) and "name" in x for x in [*base, *patch])
    ):
        merged = [copy.deepcopy(x) for x in base]
        index = {x["name"]: k for k, x in enumerate(merged)}
        for item in patch:
            if item["name"] in index:
                merged[index[item["name"]]] = strategic_merge(merged[index[item["name"]]], item)
            else:
                merged.append(copy.deepcopy(item))
        return merged
    return copy.deepcopy(patch)


def _pod_specs(obj: dict[str, Any]) -> list[dict[str, Any]]:
    if obj["kind"] == "Pod":
        return [obj["spec"]]
    if obj["kind"] in _POD_TEMPLATE_KINDS:
        return [obj["spec"]["template"]["spec"]]
    return []


def split_image(image: str) -> tuple[str, str | None]:
    """``repo[:tag][@digest]`` -> (repo, tag or None); a ``:`` before the last ``/`` is a port."""
    bare = image.split("@", 1)[0]
    slash = bare.rfind("/")
    colon = bare.rfind(":")
    return (bare[:colon], bare[colon + 1 :]) if colon > slash else (bare, None)


def _set_image(obj: dict[str, Any], name: str, new_name: str, new_tag: str | None) -> None:
    for spec in _pod_specs(obj):
        for c in [*spec.get("containers", []), *spec.get("initContainers", [])]:
            repo, tag = split_image(c["image"])
            if repo == name:
                tag = new_tag or tag
                c["image"] = f"{new_name}:{tag}" if tag else new_name


def render(directory: Path) -> list[dict[str, Any]]:
    """The objects the kustomization in ``directory`` produces (see the module docstring).

    Raises
    ------
    KustomizeError
        A field outside the subset, a missing resource or patch, a patch without a target.
    """
    directory = Path(directory)
    kfile = directory / "kustomization.yaml"
    if not kfile.is_file():
        raise KustomizeError(f"{directory}: no kustomization.yaml")
    spec = yaml.safe_load(kfile.read_text()) or {}
    unknown = set(spec) - _FIELDS
    if unknown:
        raise KustomizeError(f"{kfile}: fields outside the supported subset: {', '.join(sorted(unknown))}")
    objects: list[dict[str, Any]] = []
    for entry in spec.get("resources", []):
        path = (directory / entry).resolve()
        if path.is_dir():
            objects += render(path)
        elif path.is_file():
            objects += _load_yaml(path)
        else:
            raise KustomizeError(f"{kfile}: resource {entry!r} does not exist")
    for entry in spec.get("patches", []):
        if set(entry) != {"path"}:
            raise KustomizeError(f"{kfile}: a patch must be {{path: FILE}} (strategic merge), got {entry}")
        for patch in _load_yaml(directory / entry["path"]):
            targets = [
                k
                for k, o in enumerate(objects)
                if o["kind"] == patch["kind"] and o["metadata"]["name"] == patch["metadata"]["name"]
            ]
            if len(targets) != 1:
                raise KustomizeError(
                    f"{kfile}: patch {entry['path']} ({patch['kind']} {patch['metadata']['name']}) "
                    f"matches {len(targets)} objects, expected 1"
                )
            objects[targets[0]] = strategic_merge(objects[targets[0]], patch)
    if (namespace := spec.get("namespace")) is not None:
        for o in objects:
            if o["kind"] not in CLUSTER_SCOPED:
                o["metadata"]["namespace"] = namespace
    for entry in spec.get("labels", []):
        if (
            entry.get("includeSelectors", False)
            or entry.get("includeTemplates", False)
            or set(entry) - {"pairs", "includeSelectors", "includeTemplates"}
        ):
            raise KustomizeError(f"{kfile}: labels: only `pairs` (no selectors, no templates) are supported")
        for o in objects:
            o["metadata"]["labels"] = {**(o["metadata"].get("labels") or {}), **entry["pairs"]}
    for entry in spec.get("images", []):
        if "name" not in entry or set(entry) - {"name", "newName", "newTag"}:
            raise KustomizeError(f"{kfile}: images: only name, newName and newTag are supported")
        for o in objects:
            _set_image(o, entry["name"], entry.get("newName", entry["name"]), entry.get("newTag"))
    return objects
