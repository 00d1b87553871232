"""What a Dask worker runs: one case of a sweep with one variant, in the co-simulation.

:func:`run_case` sets the case up (:func:`tankctl.sweep.cases.case_setup`), runs the variant
through :func:`tankctl.simulate.runner.run_variant` (the code ``tankctl simulate`` runs) and
returns the case's result row: its id, variant, parameter values, seed, the kept loop metrics
(``<loop>.<metric>``; None where the loop got no metric, e.g. a settling time not reached),
``status`` ("ok" or "error"), ``error`` (the exception's one line, or None), ``worker`` (the Dask
worker's address, "local" outside a worker) and ``wall_s`` (the case's wall time [s], perf
counter). A case that raises is a row with status "error"; nothing propagates, so one bad case
never stops a sweep.
"""

from __future__ import annotations

import time
from functools import lru_cache
from pathlib import Path
from typing import Any

from tankctl.sweep.cases import CaseTask, case_setup
from tanklab.scenario import Scenario, load_scenario

__all__ = ["result_row", "run_case", "warm_up"]

_blas_limited = False


def _limit_blas_once() -> None:
    """One BLAS thread in this worker process, as in every computing tanklab process."""
    global _blas_limited
    if not _blas_limited:
        from tanklab_io.threads import limit_blas_threads

        limit_blas_threads()
        _blas_limited = True


@lru_cache(maxsize=8)
def _scenario(path: str) -> tuple[Scenario, Path]:
    """The scenario file, read once per worker process (the sweep's files do not change)."""
    return load_scenario(path)


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return "local"


def result_row(
    task: CaseTask, metrics: dict[str, float | None], error: str | None, wall_s: float
) -> dict[str, Any]:
    """The result row of one case and variant (column order of :func:`tankctl.sweep.store.columns`)."""
    row: dict[str, Any] = {"case": task.case.index, "variant": task.variant}
    row.update(task.case.values)
    row["seed"] = task.case.seed
    for loop in task.loops:
        for m in task.spec.metrics:
            key = f"{loop}.{m}"
            row[key] = metrics.get(key)
    row["status"] = "ok" if error is None else "error"
    row["error"] = error
    row["worker"] = _worker_name()
    row["wall_s"] = wall_s
    return row


def run_case(task: CaseTask) -> dict[str, Any]:
    """Run one case with one variant; never raises for a failing case (its row says why)."""
    started = time.perf_counter()
    metrics: dict[str, float | None] = {}
    error: str | None = None
    try:
        _limit_blas_once()
        from tankctl.simulate.runner import run_variant

        base, site_path = _scenario(task.scenario_path)
        scenario, site = case_setup(
            task.spec, base, site_path, task.variant, task.case.values, task.case.seed
        )
        variant = next(v for v in scenario.variants if v.name == task.variant)
        result = run_variant(scenario, site_path, variant, duration_s=task.spec.duration_s, site=site)
        for loop in task.loops:
            lm = result.loops.get(loop)
            values = lm.as_dict() if lm is not None else {}
            for m in task.spec.metrics:
                v = values.get(m)
                metrics[f"{loop}.{m}"] = None if v is None else float(v)
    except Exception as e:  # a failing case is a row, never the end of the sweep
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        error = f"{type(e).__name__}: {first}" if first else type(e).__name__
        metrics = {}
    return result_row(task, metrics, error, time.perf_counter() - started)


def warm_up() -> None:
    """Import the co-simulation and pin BLAS in this worker (what a first case would do), so that
    a benchmark can time the cases apart from the workers' start."""
    _limit_blas_once()
    import tankctl.simulate.runner  # noqa: F401
