"""``tankctl sweep``: the command, without its dependencies.

The command's signature lives here so that ``tankctl --help`` lists it without importing Dask,
pyarrow or the co-simulation (decisions 0023, 0039): :mod:`tankctl.sweep` is imported when the
command runs. Dask (``distributed``) and pyarrow are the ``sweep`` extra; without them the
command says in one line how to install it (exit 2) before reading the spec.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

__all__ = ["SWEEP_MISSING", "sweep_command"]

SWEEP_MISSING = (
    "sweep needs dask.distributed and pyarrow, which this install does not have: pip install 'tanklab[sweep]'"
)
"""The one line ``tankctl sweep`` prints (exit 2) when the ``sweep`` extra is not installed."""


def _fail(message: str, code: int = 2) -> typer.Exit:
    typer.echo(f"tankctl: {message}", err=True)
    return typer.Exit(code)


def _extra_available() -> bool:
    try:
        import distributed  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError:
        return False
    return True


def sweep_command(
    spec: Annotated[Path, typer.Argument(help="Sweep YAML file (sweeps/).")],
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Results directory (default: var/sweeps/<sweep name>)."),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option("--workers", "-w", min=1, help="Local worker processes (default: one per core)."),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler",
            envvar="TANKLAB_DASK_SCHEDULER",
            help="Dask scheduler address, e.g. tcp://HOST:8786 (env TANKLAB_DASK_SCHEDULER); "
            "default: a local cluster.",
        ),
    ] = None,
    fresh: Annotated[
        bool, typer.Option("--fresh", help="Discard the results already in the output.")
    ] = False,
) -> None:
    """Run a scenario sweep (grids x Monte Carlo draws) in the co-simulation on Dask."""
    if not _extra_available():
        raise _fail(SWEEP_MISSING)
    if scheduler and workers is not None:
        raise _fail("--workers applies to the local cluster only, not with --scheduler")
    from tankctl.sweep.run import run_sweep
    from tankctl.sweep.spec import load_spec
    from tankctl.sweep.summary import summary_markdown
    from tanklab.errors import TanklabError

    try:
        if output is None:
            output = Path("var") / "sweeps" / load_spec(spec)[0].name
        outcome = run_sweep(
            spec,
            output,
            scheduler=scheduler,
            workers=workers,
            fresh=fresh,
            progress=sys.stderr,
            progress_tty=sys.stderr.isatty(),
        )
    except TanklabError as e:
        raise _fail(str(e)) from None
    except OSError as e:
        raise _fail(f"cannot write output: {e.strerror or e}: {e.filename or ''}") from None
    s = outcome.plan.spec
    typer.echo(summary_markdown(s.name, s.description, len(outcome.plan.cases), outcome.summary), nl=False)
    typer.echo(f"ran {outcome.ran} case runs, {outcome.skipped} already in {output}")
    if outcome.plots_note:
        typer.echo(outcome.plots_note, err=True)
    for path in outcome.written:
        typer.echo(f"wrote {path}")
    failures = sum(v.failures for v in outcome.summary.values())
    if failures:
        typer.echo(f"{failures} case runs failed (status error in {outcome.written[0]})", err=True)
