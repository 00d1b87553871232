"""The operator path imports only what it uses (docs/decisions/0023-lazy-cli-imports.md).

``import tankctl.cli`` used to pull in the co-simulation, scipy.signal, scipy.stats and the MPC
for every command, a setpoint write included: over a second of imports before the command ran.
These tests guard the structure without timing anything: each runs a fresh interpreter and
asserts on the modules it loaded, for the bare import, for ``--help`` and for a real
``setpoint`` and ``status`` against real plant and PLC processes. The commands that compute
still load the numerics they need, and every command is still listed.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from helpers import ROOT, TierProcess, free_base_port, secure
from tankctl.simulate_cli import PLOTS_MISSING
from tanklab_io.ua_client import resolve

CONFIG = str(ROOT / "configs/three_tank_energies_sim.yaml")

HEAVY = (
    "numpy",
    "scipy",
    "matplotlib",
    "osqp",
    "cvxpy",
    "tankctl.simulate",
    "tankctl.cosim",
    "tankctl.limits",
    "tankctl.plots",
    "plant_sim",
    "plc_emulator",
    "supervisor",
)
"""Packages and modules an operator command must not load: the numerics (numpy, scipy and
what builds on them), plotting, and the tiers' own code (the CLI talks to them over OPC UA)."""

# Runs tankctl's console-script entry point with the given argv, then prints the modules that
# were loaded, as JSON on the last line of stderr (stdout stays the command's own), with the
# marker GC_ON among them when the garbage collector is enabled at the end (tankctl.entry turns
# it off while the CLI imports and back on once the command is imported: decision 0044).
GC_ON = "<gc enabled>"
_RUN_AND_LIST = (
    "import gc, json, sys\n"
    "from tankctl.entry import main\n"
    "sys.argv = ['tankctl', *sys.argv[1:]]\n"
    "try:\n"
    "    main()\n"
    "except SystemExit as e:\n"
    "    code = e.code\n"
    "else:\n"
    "    code = 0\n"
    f"print(json.dumps(sorted(sys.modules) + ([{GC_ON!r}] if gc.isenabled() else [])), file=sys.stderr)\n"
    "sys.exit(code)\n"
)


def _loaded(modules: list[str]) -> list[str]:
    """The modules of ``modules`` that are, or are inside, one of HEAVY."""
    return [m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY)]


def _run(*argv: str, timeout_s: float = 600.0) -> tuple[subprocess.CompletedProcess[str], list[str]]:
    p = subprocess.run(
        [sys.executable, "-c", _RUN_AND_LIST, *argv],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout_s,
        check=False,
    )
    lines = p.stderr.strip().splitlines()
    assert lines, p
    return p, json.loads(lines[-1])


def test_importing_the_cli_loads_no_numerics() -> None:
    """Nor, since the commands of other modules are mounted when used (decision 0039), the
    transport, the config models or the operator commands' modules."""
    code = "import json, sys, tankctl.cli; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600, check=True
    )
    modules = json.loads(out.stdout)
    assert "tankctl.cli" in modules and "tankctl.ops" in modules and "typer" in modules
    assert _loaded(modules) == []
    assert not [m for m in modules if m.split(".")[0] in ("asyncua", "pydantic", "rich")]
    assert not [m for m in modules if m.startswith("tankctl.ops.")]


@pytest.mark.parametrize("argv", [["--help"], ["setpoint", "--help"], ["status", "--help"]])
def test_help_loads_no_numerics(argv: list[str]) -> None:
    p, modules = _run(*argv)
    assert p.returncode == 0, p.stderr
    assert "Usage: tankctl" in p.stdout
    assert _loaded(modules) == []


def test_a_computing_command_still_loads_its_numerics() -> None:
    """``linearize`` computes: it loads numpy, scipy and plant_sim when it runs, and limits
    BLAS to one thread as before (tanklab_io.threads)."""
    p, modules = _run("linearize", CONFIG, "--json")
    assert p.returncode == 0, p.stderr
    assert len(json.loads(p.stdout)["A"]) == 3
    assert {"numpy", "scipy.linalg", "plant_sim.linearize", "tanklab_io.threads"} <= set(modules)


def test_every_command_is_still_listed() -> None:
    """The lazily imported groups are mounted as before: ``tankctl --help`` lists them."""
    from tankctl.cli import app

    r = CliRunner().invoke(app, ["--help"])
    assert r.exit_code == 0
    for name in (
        "simulate",
        "compare",
        "sweep",
        "tune",
        "linearize",
        "setpoint",
        "status",
        "scenario",
        "pki",
        "up",
    ):
        assert f" {name} " in r.stdout, name
    r = CliRunner().invoke(app, ["tune", "zn", "--gain", "2", "--dead-time", "1", "--tau", "5", "--json"])
    assert r.exit_code == 0 and json.loads(r.stdout)["Kc"] == pytest.approx(0.9 * 5 / (2 * 1))  # ZN PI


def test_plot_without_matplotlib_is_one_line_before_the_run(tmp_path: Path) -> None:
    """matplotlib is the ``plots`` extra: without it ``simulate --plot`` says so in one line,
    exit 2, before simulating anything; without --plot the same scenario runs. The interpreter is
    made to lack matplotlib the way Python marks a module absent (``sys.modules[name] = None``:
    every import of it raises ImportError), so the real command runs, nothing stands in for it."""
    scenario = str(ROOT / "configs/scenarios/nlpi_short_sim.yaml")
    png = tmp_path / "out.png"
    block = "import sys; sys.modules['matplotlib'] = None\n"
    argv = ["simulate", scenario, "--plot", str(png)]
    p = subprocess.run(
        [sys.executable, "-c", block + _RUN_AND_LIST, *argv],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,  # a bound against a hang, not a speed check: a busy machine is slow
        check=False,
    )
    message = p.stderr.strip().splitlines()[:-1]  # the last line is the module list
    assert p.returncode == 2 and message == [f"tankctl: {PLOTS_MISSING}"], p.stderr
    assert not png.exists() and p.stdout == ""
    assert "tankctl.cosim" not in json.loads(p.stderr.strip().splitlines()[-1])  # refused before the run
    p, _ = _run("simulate", scenario, "--plot", str(png))  # matplotlib present: drawn
    assert p.returncode == 0 and png.stat().st_size > 0, p.stderr


@pytest.mark.process
async def test_setpoint_and_status_against_a_real_plc_load_no_numerics() -> None:
    base = free_base_port()
    plant_url = f"opc.tcp://127.0.0.1:{base}/tanklab/plant"
    common = ("--config", CONFIG, "--speed", "20")
    plant = TierProcess("plant", *common, "--port", str(base))
    plc = TierProcess("plc", *common, "--port", str(base + 1), "--plant-url", plant_url)
    try:
        await plant.start()
        await plc.start()
        where = ("--config", CONFIG, "--base-port", str(base))
        p, modules = _run("setpoint", "LIC1", "0.45", *where)
        assert p.returncode == 0, p.stderr
        assert p.stdout.startswith("PLC.LIC1.SP = 0.45 m")
        assert _loaded(modules) == []
        # Nor what only other commands use (decision 0039): rich, the scenario models.
        assert {"asyncua", "tankctl.ops.writes"} <= set(modules)
        assert not {"rich", "tanklab.scenario", "tankctl.ops.status", "tankctl.security_cli"} & set(modules)
        # Nor the server side of the transport (decision 0044): the client half of the security
        # module and the value conversion are modules of their own.
        server_side = {"tanklab_io.ua", "tanklab_io.ua_security", "tanklab_io.audit", "tanklab_io.conditions"}
        assert {"tanklab_io.ua_client_security", "tanklab_io.ua_values"} <= set(modules)
        assert not server_side & set(modules)
        assert not {"tanklab.alarms.condition", "tanklab.alarms.manager"} & set(modules)
        assert GC_ON in modules  # the collector is back on once the command is imported
        async with await secure(f"opc.tcp://127.0.0.1:{base + 1}/tanklab/plc") as client:
            sp = await (await resolve(client, ["PLC.LIC1.SP"]))["PLC.LIC1.SP"].read_value()
        assert sp == pytest.approx(0.45)

        p, modules = _run("status", "--json", *where)
        assert p.returncode == 0, p.stderr
        assert "tankctl.ops" in modules and _loaded(modules) == []
        assert json.loads(p.stdout)["plc"]["loops"]["LIC1"]["sp_m"] == pytest.approx(0.45)

        # `alarms` (one Read of the conditions) loads its own module, not rich nor the others'.
        p, modules = _run("alarms", "--json", "--all", *where)
        assert p.returncode == 0, p.stderr
        assert "tankctl.ops.alarms" in modules and _loaded(modules) == []
        assert not {"rich", "tanklab.scenario", "tankctl.ops.status", "tankctl.ops.writes"} & set(modules)
        assert {"T1Level", "IoFault"} <= {row["name"] for row in json.loads(p.stdout)}
    finally:
        await plc.stop()
        await plant.stop()
