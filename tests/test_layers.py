"""The architecture's layer rules, enforced: import-linter contracts and pure-core purity."""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"

# Pure cores: take values, return values; never a clock, a socket, a sleep, asyncio or asyncua.
PURE_MODULES = [
    "tanklab/enums.py",
    "tanklab/errors.py",
    "tanklab/tags.py",
    "tanklab/tag_model.py",
    "tanklab/paths.py",
    "tanklab/handlers.py",
    "tanklab/rls.py",
    "tanklab/alarms/model.py",
    "tanklab/alarms/names.py",
    "tanklab/alarms/condition.py",
    "tanklab/alarms/manager.py",
    "tanklab/alarms/definitions.py",
    "plant_sim/models.py",
    "plant_sim/integrate.py",
    "plant_sim/linearize.py",
    "plant_sim/sensors.py",
    "plant_sim/plant.py",
    "plc_emulator/pid.py",
    "plc_emulator/nlpi.py",
    "plc_emulator/mrac.py",
    "plc_emulator/tuning.py",
    "plc_emulator/program.py",
    "plc_emulator/alarms.py",
    "plc_emulator/manual_auto.py",
    "tanklab/checks.py",
    "supervisor/mpc/__init__.py",
    "supervisor/mpc/model.py",
    "supervisor/mpc/formulation.py",
    "supervisor/mpc/backends.py",
    "supervisor/mpc/controller.py",
    "supervisor/estimator.py",
    "supervisor/adaptation/__init__.py",
    "supervisor/adaptation/_validate.py",
    "supervisor/adaptation/model.py",
    "supervisor/adaptation/closed_loop.py",
    "supervisor/adaptation/config.py",
    "supervisor/adaptation/decisions.py",
    "supervisor/adaptation/limits.py",
    "supervisor/adaptation/guards.py",
    "supervisor/adaptation/noise.py",
    "supervisor/adaptation/path.py",
    "supervisor/adaptation/adapter.py",
    "supervisor/cycle.py",
]
FORBIDDEN = {"asyncua", "asyncio", "time", "socket", "threading", "logging", "datetime", "random", "os"}


def test_import_linter_contracts_hold() -> None:
    exe = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(exe)], cwd=ROOT, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    n = len(declared["tool"]["importlinter"]["contracts"])
    assert f"Contracts: {n} kept, 0 broken" in result.stdout


@pytest.mark.parametrize("module", PURE_MODULES)
def test_pure_core_imports_no_io(module: str) -> None:
    path = SRC / module
    if not path.exists():
        pytest.fail(f"pure module {module} is missing")
    tree = ast.parse(path.read_text(), filename=str(path))
    imported: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert not (imported & FORBIDDEN), f"{module} imports {sorted(imported & FORBIDDEN)}"
    source = path.read_text()
    for call in ("open(", "print(", "sleep("):
        assert f" {call}" not in source and f"\n{call}" not in source, f"{module} calls {call}"
