"""The kustomize subset renderer (tanklab_testing.kustomize) against hand-worked outputs."""

from __future__ import annotations

from pathlib import Path

import pytest

from tanklab_testing.kustomize import KustomizeError, render, split_image, strategic_merge


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


DEPLOYMENT = """\
apiVersion: apps/v1
kind: Deployment
metadata: {name: web, labels: {app: web}}
spec:
  selector: {matchLabels: {app: web}}
  template:
    metadata: {labels: {app: web}}
    spec:
      initContainers: [{name: init, image: "registry.local:5000/tanklab:1.0"}]
      containers:
        - {name: a, image: tanklab:latest, env: [{name: X, value: "1"}, {name: Y, value: "2"}]}
        - {name: b, image: other/tanklab:2}
---
apiVersion: v1
kind: Namespace
metadata: {name: spare}
"""


def test_strategic_merge_maps_named_lists_and_plain_lists() -> None:
    base = {"a": 1, "m": {"x": 1, "y": 2}, "l": [1, 2], "n": [{"name": "p", "v": 1}, {"name": "q", "v": 2}]}
    patch = {"m": {"y": 3, "z": 4}, "l": [9], "n": [{"name": "q", "v": 5}, {"name": "r", "v": 6}]}
    assert strategic_merge(base, patch) == {
        "a": 1,
        "m": {"x": 1, "y": 3, "z": 4},
        "l": [9],
        "n": [{"name": "p", "v": 1}, {"name": "q", "v": 5}, {"name": "r", "v": 6}],
    }
    assert base["m"] == {"x": 1, "y": 2}  # inputs untouched


@pytest.mark.parametrize(
    ("image", "expected"),
    [
        ("tanklab", ("tanklab", None)),
        ("tanklab:latest", ("tanklab", "latest")),
        ("registry.local:5000/tanklab", ("registry.local:5000/tanklab", None)),
        ("registry.local:5000/tanklab:1.0@sha256:ab", ("registry.local:5000/tanklab", "1.0")),
    ],
)
def test_split_image(image: str, expected: tuple[str, str | None]) -> None:
    assert split_image(image) == expected


def test_overlay_on_a_base(tmp_path: Path) -> None:
    write(tmp_path / "base" / "app.yaml", DEPLOYMENT)
    write(tmp_path / "base" / "kustomization.yaml", "resources: [app.yaml]\nlabels: [{pairs: {team: ops}}]\n")
    write(
        tmp_path / "overlay" / "patch.yaml",
        "apiVersion: apps/v1\nkind: Deployment\nmetadata: {name: web}\n"
        "spec:\n  template:\n    spec:\n      containers: [{name: a, env: [{name: Y, value: '3'}]}]\n",
    )
    write(
        tmp_path / "overlay" / "kustomization.yaml",
        "namespace: prod\nresources: [../base]\npatches: [{path: patch.yaml}]\n"
        "images: [{name: tanklab, newName: reg.example/tanklab, newTag: '7'}]\n",
    )
    deployment, namespace = render(tmp_path / "overlay")
    assert deployment["metadata"] == {
        "name": "web",
        "labels": {"app": "web", "team": "ops"},
        "namespace": "prod",
    }
    assert deployment["spec"]["selector"] == {"matchLabels": {"app": "web"}}  # selectors untouched
    assert deployment["spec"]["template"]["metadata"]["labels"] == {"app": "web"}  # templates too
    spec = deployment["spec"]["template"]["spec"]
    a, b = spec["containers"]
    assert a == {
        "name": "a",
        "image": "reg.example/tanklab:7",
        "env": [{"name": "X", "value": "1"}, {"name": "Y", "value": "3"}],
    }
    assert b["image"] == "other/tanklab:2"  # another repository of the same last name
    assert spec["initContainers"][0]["image"] == "registry.local:5000/tanklab:1.0"
    assert "namespace" not in namespace["metadata"]  # cluster-scoped


@pytest.mark.parametrize(
    ("kustomization", "message"),
    [
        (
            "resources: [app.yaml]\nconfigMapGenerator: []\n",
            "outside the supported subset: configMapGenerator",
        ),
        ("resources: [missing.yaml]\n", "does not exist"),
        ("resources: [app.yaml]\nlabels: [{pairs: {a: b}, includeSelectors: true}]\n", "only `pairs`"),
        ("resources: [app.yaml]\npatches: [{path: p.yaml, target: {kind: Deployment}}]\n", "strategic merge"),
        ("resources: [app.yaml]\npatches: [{path: p.yaml}]\n", "matches 0 objects"),
    ],
)
def test_outside_the_subset_is_refused(tmp_path: Path, kustomization: str, message: str) -> None:
    write(tmp_path / "app.yaml", DEPLOYMENT)
    write(tmp_path / "p.yaml", "apiVersion: v1\nkind: ConfigMap\nmetadata: {name: nope}\n")
    write(tmp_path / "kustomization.yaml", kustomization)
    with pytest.raises(KustomizeError, match=message):
        render(tmp_path)
