"""Running a sweep on Dask: the plan, the cluster, the cases, the results, the summary.

``run_sweep`` checks the sweep (:func:`tankctl.sweep.cases.plan_sweep`: every path and grid
value, before any case runs), opens the output (:class:`tankctl.sweep.store.ResultStore`:
cases already there are skipped), connects a ``distributed.Client`` (to the scheduler at
``scheduler``, else to a ``LocalCluster`` of ``workers`` single-threaded worker processes, one
per core by default) and submits one task per case and variant that is not done
(:func:`tankctl.sweep.worker.run_case`). Completed tasks are written per batch (whatever
``as_completed`` hands over together) and counted on the progress bar. At the end it writes
``summary.json``, ``summary.md`` and, with matplotlib, ``distributions.png`` and (two grid
parameters) ``heatmap.png``. The code is the same for a local and a remote cluster.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from tankctl.sweep.cases import CaseTask, Plan, plan_sweep
from tankctl.sweep.spec import load_spec
from tankctl.sweep.summary import VariantSummary, summarize, summary_json, summary_markdown
from tanklab.errors import TanklabError

__all__ = [
    "CONNECT_TIMEOUT_S",
    "SchedulerError",
    "SweepOutcome",
    "connect",
    "execute",
    "run_sweep",
    "write_summary",
]

CONNECT_TIMEOUT_S = 10.0
"""How long to try to reach an explicit scheduler before giving up [s]."""


class SchedulerError(TanklabError):
    """The Dask scheduler cannot be reached (or the local cluster cannot start)."""


@dataclass
class SweepOutcome:
    """What a run did: the plan, every row (resumed ones included), how many ran now, files written."""

    plan: Plan
    rows: list[dict[str, Any]]
    ran: int
    skipped: int
    summary: dict[str, VariantSummary]
    written: list[Path] = field(default_factory=list)
    plots_note: str | None = None


@contextlib.contextmanager
def connect(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """A ``distributed.Client``: to ``scheduler``, or to a new LocalCluster (closed after).

    Raises
    ------
    SchedulerError
        The scheduler does not answer within :data:`CONNECT_TIMEOUT_S`.
    """
    from distributed import Client, LocalCluster

    # Dask logs every connection at INFO on stderr, where the progress bar is: warnings only.
    logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as e:
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise SchedulerError(f"cannot reach the Dask scheduler at {scheduler}: {msg}") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(
        n_workers=n,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        # the scheduler's HTTP server (health, metrics) on a free loopback port, not on 8787
        dashboard_address="127.0.0.1:0",
        silence_logs=logging.ERROR,
    )
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def _failed_row(task: CaseTask, error: BaseException) -> dict[str, Any]:
    """The row of a task Dask itself could not run (a worker died under it, say)."""
    from tankctl.sweep.worker import result_row

    first = str(error).strip().splitlines()[0] if str(error).strip() else ""
    row = result_row(task, {}, f"{type(error).__name__}: {first}" if first else type(error).__name__, 0.0)
    row["worker"] = None
    return row


def execute(
    client: Any,
    tasks: Sequence[CaseTask],
    on_batch: Callable[[list[dict[str, Any]]], None],
    key_prefix: str = "tanklab-sweep",
) -> int:
    """Run ``tasks`` on ``client``; call ``on_batch`` with the rows of each completed batch.

    Returns the number of rows produced. Every task gives a row, whatever happens to it.
    """
    from distributed import as_completed

    from tankctl.sweep.worker import run_case

    if not tasks:
        return 0
    futures = {}
    for t in tasks:
        key = f"{key_prefix}-{t.case.index}-{t.variant}"
        futures[client.submit(run_case, t, key=key, pure=False, retries=0)] = t
    produced = 0
    for batch in as_completed(list(futures), with_results=False).batches():
        rows = []
        for fut in batch:
            task = futures[fut]
            if fut.status == "finished":
                rows.append(fut.result())
            else:
                try:
                    error = fut.exception()
                except BaseException as e:  # a cancelled future has no exception: its cancellation is
                    error = e
                rows.append(_failed_row(task, error))
            fut.release()
        produced += len(rows)
        on_batch(rows)
    return produced


def write_summary(
    plan: Plan, rows: list[dict[str, Any]], directory: Path
) -> tuple[dict[str, VariantSummary], list[Path], str | None]:
    """summary.json, summary.md and the plots (when matplotlib is installed)."""
    metrics = plan.metric_columns
    summary = summarize(rows, plan.variants, metrics)
    spec = plan.spec
    errors: list[str] = []
    seen: set[str] = set()
    for r in rows:
        if r["status"] == "error" and r["error"] not in seen:
            seen.add(r["error"])
            errors.append(f"case {r['case']} ({r['variant']}): {r['error']}")
    doc = summary_json(spec.name, len(plan.cases), summary)
    js = directory / "summary.json"
    js.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    md = directory / "summary.md"
    md.write_text(
        summary_markdown(spec.name, spec.description, len(plan.cases), summary, errors[:10]), encoding="utf-8"
    )
    written = [js, md]
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return summary, written, "plots skipped: matplotlib is not installed (pip install 'tanklab[plots]')"
    from tankctl.sweep.plots import plot_distributions, plot_heatmaps

    written.append(
        plot_distributions(rows, plan.variants, metrics, directory / "distributions.png", spec.name)
    )
    grids = spec.grid_parameters
    if len(grids) == 2 and len(plan.variants) * len(metrics) <= 40:
        written.append(
            plot_heatmaps(
                rows,
                plan.variants,
                metrics,
                (grids[0].name, grids[0].grid()),
                (grids[1].name, grids[1].grid()),
                directory / "heatmap.png",
                spec.name,
            )
        )
    return summary, written, None


def run_sweep(
    spec_path: str | Path,
    output: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    fresh: bool = False,
    progress: TextIO | None = None,
    progress_tty: bool = False,
    order: Callable[[list[CaseTask]], list[CaseTask]] | None = None,
) -> SweepOutcome:
    """Check, run (what is not done yet) and summarise a sweep.

    Parameters
    ----------
    spec_path : the sweep YAML file.  output : the results directory.
    scheduler : a Dask scheduler address (``tcp://HOST:8786``); None: a LocalCluster.
    workers : the LocalCluster's worker processes (default: one per core).
    fresh : discard the results already in ``output``.
    progress, progress_tty : where the progress bar goes (None: nowhere) and whether it is a terminal.
    order : reorders the tasks before submission (the determinism tests shuffle them).

    Raises
    ------
    ConfigError
        A bad spec, scenario or site, a path that does not exist, a value out of range, an
        output holding another sweep: before any case runs.
    SchedulerError
        The scheduler cannot be reached: before any case runs.
    """
    from tankctl.sweep.progress import Progress
    from tankctl.sweep.store import ResultStore, fingerprint

    spec, scenario_path = load_spec(spec_path)
    plan = plan_sweep(spec, scenario_path)
    fp = fingerprint(plan)
    out = Path(output)
    store = ResultStore(out, plan, fp, fresh=fresh)
    done = store.done
    tasks = [t for t in plan.tasks() if (t.case.index, t.variant) not in done]
    if order is not None:
        tasks = order(tasks)
    total = len(plan.cases) * len(plan.variants)
    bar = Progress(total, total - len(tasks), progress, tty=progress_tty) if progress is not None else None

    def on_batch(rows: list[dict[str, Any]]) -> None:
        store.add(rows)
        if bar is not None:
            bar.update(len(rows))

    ran = 0
    if tasks:
        with connect(scheduler, workers) as client:
            ran = execute(client, tasks, on_batch, key_prefix=f"tanklab-sweep-{fp[:12]}")
        if bar is not None:
            bar.close()
    else:
        store.write()
    rows = store.sorted_rows()
    summary, written, note = write_summary(plan, rows, out)
    return SweepOutcome(plan, rows, ran, total - len(tasks), summary, [store.path, *written], note)
