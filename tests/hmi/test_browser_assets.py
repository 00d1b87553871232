"""The front end's files (src/hmi/static/) as shipped: self-contained, complete, and what the
contract's element ids say (no browser needed).

Oracles: the files themselves and the HMI contract v1 (docs/hmi.md). Every module a module
imports and every file index.html loads is in static/; nothing names a host (no network load);
the vendored uPlot is the version docs/decisions/0049 records, with its licence; every element
id the browser tests rely on is in index.html or written by the modules.
"""

from __future__ import annotations

import re
import tomllib

from helpers import ROOT

STATIC = ROOT / "src/hmi/static"
MODULES = sorted(STATIC.glob("*.js"))
OWN = [*MODULES, STATIC / "index.html", STATIC / "hmi.css"]


def test_every_import_and_every_loaded_file_is_shipped() -> None:
    for module in MODULES:
        for target in re.findall(r'^import .* from "(\./[^"]+)";$', module.read_text(encoding="utf-8"), re.M):
            assert (module.parent / target).is_file(), f"{module.name} imports {target}"
    html = (STATIC / "index.html").read_text(encoding="utf-8")
    loaded = re.findall(r'(?:src|href)="(/static/[^"]+)"', html)
    assert {"/static/app.js", "/static/vendor/uplot/uPlot.iife.min.js"} <= set(loaded)
    for url in loaded:
        assert (STATIC / url.removeprefix("/static/")).is_file(), url


def test_nothing_is_loaded_from_another_host() -> None:
    for path in OWN:
        text = path.read_text(encoding="utf-8")
        # the SVG namespace is a name, not a load; anything else with a scheme or // is a host
        hosts = [
            u for u in re.findall(r"(?:https?:)?//[\w.-]+\.[a-z]{2,}[^\s\"')]*", text) if "w3.org" not in u
        ]
        assert hosts == [], f"{path.name} names {hosts}"


def test_uplot_is_the_recorded_version_with_its_licence() -> None:
    vendor = STATIC / "vendor/uplot"
    version = (vendor / "VERSION").read_text(encoding="utf-8").strip()
    assert re.fullmatch(r"1\.6\.\d+", version)
    decision = (ROOT / "docs/decisions/0049-hmi-front-end.md").read_text(encoding="utf-8")
    assert f"uPlot {version}" in decision and f"uplot@{version}" in decision
    assert (vendor / "LICENSE").read_text(encoding="utf-8").startswith("The MIT License")
    assert {p.name for p in vendor.iterdir()} == {"LICENSE", "VERSION", "uPlot.iife.min.js", "uPlot.min.css"}


def test_the_contract_element_ids_exist() -> None:
    html = (STATIC / "index.html").read_text(encoding="utf-8")
    for element_id in (
        "login-form",
        "login-user",
        "login-password",
        "login-submit",
        "login-error",
        "logout",
        "whoami",
        "mimic",
        "alarm-banner",
        "alarm-list",
        "faceplate",
        "trend",
    ):
        assert f'id="{element_id}"' in html, element_id
    scripts = "\n".join(p.read_text(encoding="utf-8") for p in MODULES) + html
    for name in ("sp-input", "status", "mode", "manual-input", "leak-input", "disturbance-input"):
        assert f'field: "{name}"' in scripts or f"field: {name}" in scripts, name
    for name in (
        "sp-apply",
        "manual-apply",
        "reset-gains",
        "leak-apply",
        "disturbance-apply",
        "export-csv",
        "export-png",
    ):
        assert f'action: "{name}"' in scripts or f'data-action="{name}"' in scripts, name
    assert "alarmId: a.id" in scripts  # the alarm rows: tr[data-alarm-id]


def test_the_wheel_ships_the_static_tree() -> None:
    """hatchling puts every file of a listed package in the wheel (src/hmi/static/ too, checked
    once by hand with `pip wheel`): src/hmi must stay a listed package."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "src/hmi" in project["tool"]["hatch"]["build"]["targets"]["wheel"]["packages"]
