"""Sweeps on real Dask clusters: a LocalCluster of 2 worker processes gives the rows 1 worker
gives (tasks submitted in a shuffled order), a scheduler and worker started here on loopback
ports run the same sweep by address, a resumed sweep recomputes nothing, a failing case is a
row, and the summary's numbers match hand-computed medians and 95th percentiles."""

from __future__ import annotations

import io
import math
import random
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from helpers import ROOT, free_port, wait_until_sync
from sweep_support import stable, write_spec
from tankctl.sweep.progress import Progress, format_duration, progress_line
from tankctl.sweep.run import run_sweep
from tankctl.sweep.store import CASES_FILE
from tankctl.sweep.summary import summarize

pytestmark = pytest.mark.timeout(240)


def _shuffled(tasks: list) -> list:  # type: ignore[type-arg]
    out = list(tasks)
    random.Random(5).shuffle(out)
    return out


def test_two_workers_give_the_rows_of_one(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    one = run_sweep(spec, tmp_path / "one", workers=1)
    two = run_sweep(spec, tmp_path / "two", workers=2, order=_shuffled)
    assert one.ran == two.ran == 4
    assert all(r["status"] == "ok" for r in one.rows), one.rows
    assert stable(one.rows) == stable(two.rows)
    assert len({r["worker"] for r in two.rows}) == 2  # both workers took cases
    # the file holds the rows in case order, whatever order they completed in
    table = pq.read_table(tmp_path / "two" / CASES_FILE)
    assert table.column("case").to_pylist() == [0, 1, 2, 3]
    assert stable(table.to_pylist()) == stable(one.rows)
    # a real result: the kp grid changed the loop (distinct IAEs), the seeds differ per case
    assert len({r["LIC1.iae"] for r in one.rows}) == 4
    assert len({r["seed"] for r in one.rows}) == 4
    for name in ("summary.json", "summary.md", "distributions.png"):
        assert (tmp_path / "two" / name).stat().st_size > 0


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[str]:
    """A dask scheduler and one worker process on loopback free ports; stopped after."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    bindir = Path(sys.executable).parent
    log = (tmp_path / "dask.log").open("w")
    scheduler = subprocess.Popen(
        [str(bindir / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=ROOT,
    )
    worker = subprocess.Popen(
        [
            str(bindir / "dask"),
            "worker",
            address,
            "--nworkers",
            "1",
            "--nthreads",
            "1",
            "--no-dashboard",
            "--host",
            "127.0.0.1",
        ],
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=ROOT,
    )
    try:
        yield address
    finally:
        for proc in (worker, scheduler):
            proc.terminate()
        for proc in (worker, scheduler):
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()


def test_explicit_scheduler_gives_the_same_rows(tmp_path: Path, dask_cluster: str) -> None:
    from distributed import Client

    def worker_up() -> bool:
        try:
            with Client(dask_cluster, timeout=2) as c:
                return len(c.scheduler_info()["workers"]) == 1
        except OSError:
            return False

    wait_until_sync(worker_up, 60, what="the dask worker registered")
    spec = write_spec(tmp_path)
    remote = run_sweep(spec, tmp_path / "remote", scheduler=dask_cluster)
    local = run_sweep(spec, tmp_path / "local", workers=1, order=_shuffled)
    assert remote.ran == 4
    assert stable(remote.rows) == stable(local.rows)
    assert {r["worker"] for r in remote.rows} != {r["worker"] for r in local.rows}


def test_resume_skips_done_cases(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    out = tmp_path / "out"
    full = run_sweep(spec, out, workers=1)
    # as a kill after the first batch would leave it: rows of cases 0 and 2 only
    table = pq.read_table(out / CASES_FILE)
    kept = table.filter(pc.is_in(table.column("case"), pa.array([0, 2])))
    pq.write_table(kept, out / CASES_FILE)
    resumed = run_sweep(spec, out, workers=1)
    assert (resumed.ran, resumed.skipped) == (2, 2)
    assert stable(resumed.rows) == stable(full.rows)
    before = {r["case"]: r for r in kept.to_pylist()}
    for r in resumed.rows:
        if r["case"] in before:
            assert r == before[r["case"]]  # the same row, wall time and worker included: not rerun
    again = run_sweep(spec, out, workers=1)  # all done: nothing runs, no cluster is started
    assert (again.ran, again.skipped) == (0, 4)
    fresh = run_sweep(spec, out, workers=1, fresh=True)
    assert fresh.ran == 4


def test_output_of_another_sweep_is_refused(tmp_path: Path) -> None:
    from tanklab.config import ConfigError

    out = tmp_path / "out"
    run_sweep(write_spec(tmp_path, draws=1), out, workers=1)
    with pytest.raises(ConfigError, match=r"holds another sweep.*--fresh"):
        run_sweep(write_spec(tmp_path, draws=2), out, workers=1)


def test_failing_case_is_a_row_and_the_sweep_goes_on(tmp_path: Path) -> None:
    # a setpoint event the PLC refuses (above LIC1's sp_max 0.6 m) fails only when the case runs
    scenario = tmp_path / "sp.yaml"
    scenario.write_text(
        "name: sp\n"
        f"site: {ROOT / 'configs/three_tank_energies_sim.yaml'}\n"
        "duration_s: 20\n"
        "events:\n  - {at_s: 5, kind: setpoint, loop: LIC1, value_m: 0.3}\n"
        "variants:\n  - {name: pid, supervisor_mode: 'OFF'}\n",
        encoding="utf-8",
    )
    spec = write_spec(
        tmp_path,
        scenario=str(scenario),
        duration_s=None,
        draws=1,
        parameters=[{"name": "sp", "paths": ["scenario.events.0.value_m"], "values": [0.3, 0.9, 0.5]}],
    )
    out = run_sweep(spec, tmp_path / "out", workers=1)
    status = {r["sp"]: (r["status"], r["error"]) for r in out.rows}
    assert status[0.3] == ("ok", None) and status[0.5] == ("ok", None)
    assert status[0.9][0] == "error"
    assert "events[0] (setpoint at 5 s)" in status[0.9][1] and "outside" in status[0.9][1]
    bad = next(r for r in out.rows if r["sp"] == 0.9)
    assert bad["LIC1.iae"] is None
    assert out.summary["pid"].failures == 1 and out.summary["pid"].metrics["LIC1.iae"].n == 2
    assert "1 failed" in (tmp_path / "out" / "summary.md").read_text()


def test_summary_against_hand_computed_percentiles() -> None:
    values = [4.0, 1.0, 10.0, 3.0, 2.0]
    rows = [{"variant": "a", "status": "ok", "m": v} for v in values]
    rows += [
        {"variant": "a", "status": "ok", "m": None},  # not reached: not counted
        {"variant": "a", "status": "error", "m": None},
        {"variant": "b", "status": "ok", "m": 7.0},
    ]
    s = summarize(rows, ["a", "b", "c"], ["m"])
    # sorted 1 2 3 4 10: median 3; p95 at h = 0.95 * 4 = 3.8: 4 + 0.8 (10 - 4) = 8.8
    a = s["a"].metrics["m"]
    assert (s["a"].cases, s["a"].failures, a.n, a.median) == (7, 1, 5, 3.0)
    assert a.p95 == pytest.approx(8.8, rel=1e-12)
    assert (s["b"].metrics["m"].median, s["b"].metrics["m"].p95) == (7.0, 7.0)
    assert (s["c"].cases, s["c"].metrics["m"].median) == (0, None)


def test_progress_line_and_piped_bar() -> None:
    assert format_duration(3725) == "1:02:05" and format_duration(65) == "1:05"
    assert format_duration(float("inf")) == "?"
    line = progress_line(25, 100, 20, 10.0, width=10)
    # 20 new cases in 10 s: 2 cases/s, 75 left: 37.5 s
    assert line == "sweep [##........] 25/100  25% 2.00 cases/s ETA 0:38"  # 2.5 of 10 cells: 2
    now = [0.0]
    stream = io.StringIO()
    bar = Progress(20, 0, stream, tty=False, every_pct=25.0, clock=lambda: now[0])
    for _ in range(20):
        now[0] += 1.0
        bar.update(1)
    lines = stream.getvalue().splitlines()
    assert [ln.split()[2] for ln in lines] == ["5/20", "10/20", "15/20", "20/20"]
    assert lines[-1].endswith("ETA 0:00")


def test_heatmap_cells_are_medians_over_draws(tmp_path: Path) -> None:
    from tankctl.sweep.plots import heatmap_grid, plot_heatmaps

    rows = [
        {"variant": "v", "status": "ok", "a": a, "b": b, "m": m}
        for a, b, m in [
            (1, "x", 1.0),
            (1, "x", 3.0),
            (1, "x", 8.0),
            (1, "y", 2.0),
            (2, "x", None),
            (2, "y", 5.0),
        ]
    ]
    rows.append({"variant": "v", "status": "error", "a": 2, "b": "x", "m": None})
    grid = heatmap_grid(rows, "v", "m", ("a", [1, 2]), ("b", ["x", "y"]))
    assert grid[0].tolist() == [3.0, 2.0] and grid[1, 1] == 5.0
    assert math.isnan(grid[1, 0])  # no case of the cell has the metric
    out = plot_heatmaps(rows, ["v"], ["m"], ("a", [1, 2]), ("b", ["x", "y"]), tmp_path / "h.png", "t")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_terminal_bar_redraws_one_line_and_counts_resumed_cases_as_done() -> None:
    now = [0.0]
    stream = io.StringIO()
    bar = Progress(10, 4, stream, tty=True, clock=lambda: now[0])  # 4 found done in the output
    now[0] = 3.0
    bar.update(3)
    bar.close()
    text = stream.getvalue()
    assert text.count("\r") == 1 and text.endswith("\n") and text.count("\n") == 1
    # 3 new in 3 s: 1 case/s, 3 left: 3 s
    assert text.strip() == progress_line(7, 10, 3, 3.0) and text.rstrip().endswith("1.00 cases/s ETA 0:03")


def test_distributions_of_a_metric_equal_in_every_case(tmp_path: Path) -> None:
    """A metric equal up to rounding in every case (a pump's saturated max_du) still plots."""
    import numpy as np

    from tankctl.sweep.plots import plot_distributions

    # two values one ulp apart: numpy cannot make 5 finite-sized bins of that range
    x = 1.2e-4
    values = [x, float(np.nextafter(x, 1.0))] * 10
    rows = [{"variant": "v", "status": "ok", "m": m, "c": 0.0} for m in values]
    out = plot_distributions(rows, ["v"], ["m", "c"], tmp_path / "d.png", "t")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
