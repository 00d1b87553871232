"""Scenario sweeps on Dask (issue 19): throughput on 1 and 2 local workers, scheduling overhead
per case, memory per worker, and a 1,000-case run of the shipped Energies sweep.

Throughput: the shipped ``sweeps/energies_leak_noise.yaml`` with ``draws`` cut to
:data:`THROUGHPUT_DRAWS` (20 grid points x draws cases, each with both variants), run through
:func:`tankctl.sweep.run.execute` on a LocalCluster of 1, then 2, single-threaded worker
processes; the clock runs from the first submission to the last row (the cluster's start and the
workers' first imports are timed apart, as *start-up*). Cases per second count case runs (one
variant of one case). *Scheduling overhead per case* is the workers' time not spent inside
cases, ``(workers x wall - sum of the cases' wall_s) / case runs``; *memory per worker* the
workers' RSS after the run (as they report it to the scheduler). The large run is ``tankctl sweep``'s own
:func:`tankctl.sweep.run.run_sweep` on the file's grid with 50 draws (1,000 cases) and its fixed
PID variant, its summary as it writes it.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from benchmarks.common import ROOT, Goal, fmt, speed_reference

SPEC = ROOT / "sweeps" / "energies_leak_noise.yaml"
THROUGHPUT_DRAWS = 1
QUICK_DRAWS = 1
LARGE_DRAWS = 50
"""The large run: 20 grid points x 50 draws = 1,000 cases."""
LARGE_VARIANTS = ["pid"]
"""The large run's variant: the fixed PID (0.5 s a case here); the adapted PID's cases take
about 3 s each on this shared machine, and 1,000 of them do not fit a session's benchmark."""
GOAL_SPEEDUP = 1.8


@dataclass
class Throughput:
    """One LocalCluster size."""

    workers: int
    runs: int
    startup_s: float
    wall_s: float
    case_s: list[float]
    rss_mb: list[float]
    failures: int

    @property
    def rate(self) -> float:
        return self.runs / self.wall_s if self.wall_s > 0 else math.nan

    @property
    def busy(self) -> float:
        """Fraction of the workers' time spent inside cases: sum(case wall) / (workers x wall)."""
        return sum(self.case_s) / (self.workers * self.wall_s) if self.wall_s > 0 else math.nan

    @property
    def overhead_ms(self) -> float:
        return 1e3 * (self.workers * self.wall_s - sum(self.case_s)) / self.runs if self.runs else math.nan


@dataclass
class SweepBench:
    """Everything the section shows."""

    speed_ms: float
    draws: int = THROUGHPUT_DRAWS
    throughput: list[Throughput] = field(default_factory=list)
    large: dict[str, Any] | None = None
    errors: list[str] = field(default_factory=list)


def _spec_with_draws(directory: Path, draws: int, variants: list[str] | None = None) -> Path:
    """The shipped Energies sweep with ``draws`` (and ``variants``) changed, in ``directory``."""
    data = yaml.safe_load(SPEC.read_text(encoding="utf-8"))
    data["draws"] = draws
    if variants is not None:
        data["variants"] = variants
    data["scenario"] = str((SPEC.parent / data["scenario"]).resolve())
    out = directory / f"energies_leak_noise_d{draws}{'_' + '_'.join(variants) if variants else ''}.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return out


def throughput(workers: int, spec_path: Path) -> Throughput:
    """Run every case of ``spec_path`` on a new LocalCluster of ``workers`` processes."""
    from tankctl.sweep.cases import plan_sweep
    from tankctl.sweep.run import connect, execute
    from tankctl.sweep.spec import load_spec
    from tankctl.sweep.worker import warm_up

    spec, scenario = load_spec(spec_path)
    plan = plan_sweep(spec, scenario)
    tasks = plan.tasks()
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    with connect(None, workers) as client:
        client.wait_for_workers(workers)
        # the workers' first imports (numpy, scipy, the co-simulation) belong to the start-up
        client.run(warm_up)
        t1 = time.perf_counter()
        execute(client, tasks, rows.extend, key_prefix=f"bench-{workers}")
        t2 = time.perf_counter()
        # each worker's resident memory as its nanny last reported it to the scheduler
        info = client.scheduler_info()["workers"]
        rss = [w["metrics"]["memory"] / 2**20 for w in info.values()]
    return Throughput(
        workers,
        len(rows),
        t1 - t0,
        t2 - t1,
        [float(r["wall_s"]) for r in rows],
        [float(x) for x in rss],
        sum(r["status"] != "ok" for r in rows),
    )


def run(log: Callable[[str], None], quick: bool = False) -> SweepBench:
    """The section's measurements (the 1,000-case run only without ``quick``)."""
    from tankctl.sweep.run import run_sweep

    res = SweepBench(speed_reference(), QUICK_DRAWS if quick else THROUGHPUT_DRAWS)
    with tempfile.TemporaryDirectory(prefix="tanklab-sweep-bench-") as tmp:
        spec = _spec_with_draws(Path(tmp), res.draws)
        for n in (1, 2):
            log(f"  throughput on {n} local worker(s)")
            t = throughput(n, spec)
            res.throughput.append(t)
            log(f"    {t.runs} case runs in {t.wall_s:.1f} s: {t.rate:.2f} /s (start-up {t.startup_s:.1f} s)")
            if t.failures:
                res.errors.append(f"sweep throughput on {n} workers: {t.failures} failed case runs")
        if not quick:
            log(
                f"  the shipped Energies sweep's grid, {LARGE_DRAWS} draws, the fixed PID: 1,000 cases, "
                "2 workers"
            )
            out = Path(tmp) / "large"
            large_spec = _spec_with_draws(Path(tmp), LARGE_DRAWS, LARGE_VARIANTS)
            started = time.perf_counter()
            outcome = run_sweep(large_spec, out, workers=2)
            wall = time.perf_counter() - started
            res.large = {
                "wall_s": wall,
                "cases": len(outcome.plan.cases),
                "runs": len(outcome.rows),
                "failures": sum(s.failures for s in outcome.summary.values()),
                "summary": (out / "summary.md").read_text(encoding="utf-8"),
                "case_s": [float(r["wall_s"]) for r in outcome.rows],
            }
            log(f"    {len(outcome.rows)} case runs in {wall:.0f} s")
    res.speed_ms = (res.speed_ms + speed_reference()) / 2
    return res


def goals(res: SweepBench) -> list[Goal]:
    """2 workers at least 1.8x one on this 2-core machine."""
    if len(res.throughput) < 2:
        return [Goal("sweep throughput, 2 workers vs 1", f">= {GOAL_SPEEDUP}x", "n/a", None)]
    one, two = res.throughput[0], res.throughput[1]
    speedup = two.rate / one.rate
    # what the scheduling alone allows, with the cases as costly in both runs (the machine's
    # other load moves the case cost between the runs): workers x busy fraction, 2 against 1
    scheduled = (two.workers * two.busy) / (one.workers * one.busy)
    return [
        Goal(
            "sweep throughput, 2 local workers vs 1",
            f">= {GOAL_SPEEDUP}x",
            f"{speedup:.2f}x ({fmt(one.rate)} and {fmt(two.rate)} case runs/s)",
            speedup >= GOAL_SPEEDUP,
            f"section 14: {one.runs} case runs of the shipped Energies sweep "
            f"(fixed PID and adapted PID, 1000 s each); at equal case cost (workers x busy fraction) "
            f"{scheduled:.2f}x; case wall medians {fmt(statistics.median(one.case_s))} and "
            f"{fmt(statistics.median(two.case_s))} s",
        )
    ]


def markdown(res: SweepBench) -> str:
    """Section 14 of the benchmark document."""
    lines = [
        "## 14. Scenario sweeps on Dask",
        "",
        "`benchmarks/sweep.py` (`python -m benchmarks.run --only sweep`): the shipped "
        "`sweeps/energies_leak_noise.yaml` (fixed PID `pid` and adapted PID `mpc_pid`, 1000 s of model "
        f"time each) with its draws cut to {res.draws} (20 grid points x {res.draws} x 2 variants), "
        "on a LocalCluster of 1 and of 2 single-threaded worker processes (`tankctl.sweep.run.execute`). "
        "The wall clock runs from the first submission to the last row; *start-up* is the cluster's "
        "start and the workers' first imports. *Overhead per case* = (workers x wall - sum of the "
        "cases' own wall times) / case runs: the time a worker spends outside cases (scheduling, "
        "serialisation, idle at the end); *busy fraction* = sum of the cases' wall times / (workers x "
        "wall). The machine's other load changes a case's cost between the runs (compare the case "
        "wall medians): workers x busy fraction is the speed-up the scheduling allows at equal case "
        "cost. *RSS* is each worker's resident memory after the run. "
        f"Machine speed reference {fmt(res.speed_ms)} ms.",
        "",
        "| workers | case runs | start-up [s] | wall [s] | case runs/s | speed-up | case wall median [s] "
        "| busy fraction | overhead per case [ms] | RSS per worker [MiB] | failed |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    base = res.throughput[0].rate if res.throughput else math.nan
    for t in res.throughput:
        lines.append(
            f"| {t.workers} | {t.runs} | {fmt(t.startup_s)} | {fmt(t.wall_s)} | {fmt(t.rate)} | "
            f"{t.rate / base:.2f}x | {fmt(statistics.median(t.case_s))} | {t.busy:.3f} | "
            f"{fmt(t.overhead_ms)} | "
            f"{', '.join(fmt(x) for x in t.rss_mb)} | {t.failures} |"
        )
    if res.large is not None:
        lg = res.large
        lines += [
            "",
            f"The file's grid with `draws: {LARGE_DRAWS}` and `variants: {LARGE_VARIANTS}` through "
            f"`run_sweep(..., workers=2)` ({lg['cases']:,} cases, {lg['runs']:,} case runs, the "
            "LocalCluster's start included): "
            f"**{fmt(lg['wall_s'])} s** of wall time, {fmt(lg['runs'] / lg['wall_s'])} case runs/s, "
            f"case wall median {fmt(statistics.median(lg['case_s']))} s, {lg['failures']} failed. "
            "Its summary "
            "(`summary.md`, headings shifted down):",
            "",
        ]
        for ln in lg["summary"].splitlines():
            lines.append("#" * 2 + ln if ln.startswith("#") else ln)
    return "\n".join(lines).rstrip() + "\n"
