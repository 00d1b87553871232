"""``tankctl sweep`` through typer's CliRunner and as a subprocess: one-line errors before any
case runs (bad spec, a path that does not exist, an unreachable scheduler), the summary on
stdout, the files written; and the shipped sweep files run (one case each)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from helpers import ROOT, free_port, wait_until_sync
from sweep_support import write_spec
from tankctl.cli import app
from tankctl.sweep.cases import plan_sweep
from tankctl.sweep.run import run_sweep
from tankctl.sweep.spec import load_spec
from tankctl.sweep.worker import run_case
from tankctl.sweep_cli import SWEEP_MISSING
from tanklab_testing.procs import alive, descendants

pytestmark = pytest.mark.timeout(240)


def _run(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, ["sweep", *args])
    return result.exit_code, result.stdout, result.stderr


def test_bad_spec_is_one_line(tmp_path: Path) -> None:
    code, out, err = _run(str(write_spec(tmp_path, draws=0)), "-o", str(tmp_path / "o"))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("tankctl: ") and "draws" in err
    assert not (tmp_path / "o").exists()  # nothing ran, nothing written


def test_missing_path_is_one_line(tmp_path: Path) -> None:
    params = [{"name": "x", "paths": ["site.plc.loops.0.gains.kq"], "values": [1.0]}]
    code, _, err = _run(str(write_spec(tmp_path, parameters=params)), "-o", str(tmp_path / "o"))
    assert code == 2 and err.count("\n") == 1 and "site.plc.loops.0.gains.kq: no field 'kq'" in err


def test_unreachable_scheduler_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from tankctl.sweep import run

    monkeypatch.setattr(run, "CONNECT_TIMEOUT_S", 2.0)
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    monkeypatch.setenv("TANKLAB_DASK_SCHEDULER", address)
    code, out, err = _run(str(write_spec(tmp_path)), "-o", str(tmp_path / "o"))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and f"cannot reach the Dask scheduler at {address}" in err
    assert not (tmp_path / "o" / "cases.parquet").exists()


def test_workers_with_scheduler_is_refused(tmp_path: Path) -> None:
    code, _, err = _run(str(write_spec(tmp_path)), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1")
    assert code == 2 and "--workers applies to the local cluster only" in err


def test_cli_runs_a_sweep(tmp_path: Path) -> None:
    out_dir = tmp_path / "o"
    code, out, err = _run(str(write_spec(tmp_path, draws=1)), "-o", str(out_dir), "--workers", "1")
    assert code == 0, err
    assert "# Sweep tiny" in out and "| LIC1.iae | 2 |" in out
    assert "ran 2 case runs, 0 already in" in out
    assert "sweep [" in err and "2/2 100%" in err  # the piped progress bar
    assert pq.read_table(out_dir / "cases.parquet").num_rows == 2


def test_subprocess_sweep_and_resume(tmp_path: Path) -> None:
    out_dir = tmp_path / "o"
    spec = write_spec(tmp_path, draws=1)
    cmd = [sys.executable, "-m", "tankctl", "sweep", str(spec), "-o", str(out_dir), "-w", "1"]
    env = {k: v for k, v in os.environ.items() if k != "TANKLAB_DASK_SCHEDULER"}
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=ROOT, env=env, check=False)
    assert first.returncode == 0, first.stderr
    assert "ran 2 case runs, 0 already" in first.stdout
    second = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=ROOT, env=env, check=False)
    assert second.returncode == 0, second.stderr
    assert "ran 0 case runs, 2 already" in second.stdout


@pytest.mark.parametrize("name", ["energies_leak_noise", "kortela_mpc_weights"])
def test_shipped_sweep_case_runs(name: str) -> None:
    """One case of each shipped sweep, every variant, full length, in this process."""
    spec, scenario_path = load_spec(ROOT / "sweeps" / f"{name}.yaml")
    plan = plan_sweep(spec, scenario_path)
    tasks = [t for t in plan.tasks() if t.case.index == len(plan.cases) - 1]
    assert len(tasks) == len(plan.variants)
    for task in tasks:
        row = run_case(task)
        assert row["status"] == "ok", row["error"]
        assert row["worker"] == "local"
        assert all(row[c] is not None for c in plan.metric_columns if not c.endswith("settling_time_s"))
        assert row["LIC1.iae"] > 0


_LIST_MODULES = (
    "import json, sys\n"
    "{block}"
    "from tankctl.entry import main\n"
    "sys.argv = ['tankctl', *sys.argv[1:]]\n"
    "try:\n"
    "    main()\n"
    "except SystemExit as e:\n"
    "    code = e.code\n"
    "print(json.dumps(sorted(sys.modules)), file=sys.stderr)\n"
    "sys.exit(code)\n"
)


def test_help_imports_no_dask_and_missing_extra_is_one_line(tmp_path: Path) -> None:
    """``tankctl --help`` lists sweep without importing Dask or pyarrow; without the extra
    (``sys.modules[name] = None``: every import of it raises ImportError) the command says how
    to install it in one line, exit 2, before reading the spec."""
    p = subprocess.run(
        [sys.executable, "-c", _LIST_MODULES.format(block=""), "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
        check=False,
    )
    assert p.returncode == 0 and " sweep " in p.stdout
    modules = set(json.loads(p.stderr.strip().splitlines()[-1]))
    assert not modules & {"dask", "distributed", "pyarrow", "numpy", "tankctl.sweep"}
    block = "sys.modules['distributed'] = None\n"
    spec = write_spec(tmp_path)
    p = subprocess.run(
        [
            sys.executable,
            "-c",
            _LIST_MODULES.format(block=block),
            "sweep",
            str(spec),
            "-o",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
        check=False,
    )
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and lines[0] == f"tankctl: {SWEEP_MISSING}" and len(lines) == 2
    assert not (tmp_path / "o").exists()


def test_killed_sweep_resumes_without_recomputing(tmp_path: Path) -> None:
    """``tankctl sweep`` SIGKILLed (with its cluster) after its first rows were written: the
    rerun computes only the missing case runs, and the rows written before are unchanged."""
    spec = write_spec(
        tmp_path,
        duration_s=1000.0,
        draws=6,
        parameters=[{"name": "kp", "paths": ["site.plc.loops.0.gains.kp"], "values": [3.0e-4, 6.0e-4]}],
    )
    out_dir = tmp_path / "o"
    cases = out_dir / "cases.parquet"
    env = {k: v for k, v in os.environ.items() if k != "TANKLAB_DASK_SCHEDULER"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "tankctl", "sweep", str(spec), "-o", str(out_dir), "-w", "1"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        wait_until_sync(cases.exists, 120, what="the first batch written", poll_s=0.05)
        family = [proc.pid, *descendants(proc.pid)]
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    wait_until_sync(lambda: not any(alive(pid) for pid in family), 30, what="the sweep's processes gone")
    before = pq.read_table(cases).to_pylist()
    assert 1 <= len(before) < 12, "the sweep finished before it was killed"
    resumed = run_sweep(spec, out_dir, workers=1)
    assert (resumed.ran, resumed.skipped) == (12 - len(before), len(before))
    assert [r["case"] for r in resumed.rows] == list(range(12))
    by_case = {r["case"]: r for r in resumed.rows}
    for row in before:
        assert by_case[row["case"]] == row  # wall time and worker included: not run again
    assert all(r["status"] == "ok" for r in resumed.rows)


def test_without_matplotlib_the_sweep_runs_and_says_the_plots_were_skipped(tmp_path: Path) -> None:
    block = "sys.modules['matplotlib'] = None\n"
    spec = write_spec(tmp_path, draws=1)
    p = subprocess.run(
        [
            sys.executable,
            "-c",
            _LIST_MODULES.format(block=block),
            "sweep",
            str(spec),
            "-o",
            str(tmp_path / "o"),
            "-w",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=180,
        cwd=ROOT,
        check=False,
    )
    assert p.returncode == 0, p.stderr
    assert "plots skipped: matplotlib is not installed (pip install 'tanklab[plots]')" in p.stderr
    assert sorted(f.name for f in (tmp_path / "o").iterdir()) == [
        "cases.parquet",
        "summary.json",
        "summary.md",
    ]
