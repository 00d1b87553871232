"""``tankctl simulate`` and ``tankctl compare``: the commands, without the co-simulation.

The commands' signatures (arguments, options, help) live here so that the main ``tankctl`` app
can list and parse them without importing :mod:`tankctl.simulate`, which pulls in the
co-simulation (:mod:`tankctl.cosim`, the PLC and supervisor cores, the MPC and OSQP) and
:mod:`tankctl.limits` (``scipy.signal``, ``scipy.integrate``, ``scipy.optimize``): about a second
of imports that an operator command such as ``tankctl setpoint`` must not pay
(docs/decisions/0023-lazy-cli-imports.md). Each command imports the co-simulation when it runs.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from tankctl.simulate import ScenarioResult

__all__ = ["compare_command", "register", "simulate_command"]


def _fail(message: str, code: int = 2) -> typer.Exit:
    typer.echo(f"tankctl: {message}", err=True)
    return typer.Exit(code)


ScenarioArg = Annotated[Path, typer.Argument(help="Scenario YAML file (configs/scenarios/).")]
ConfigOpt = Annotated[
    Path | None, typer.Option("--config", "-c", help="Site YAML file instead of the scenario's own.")
]
VariantOpt = Annotated[
    list[str] | None, typer.Option("--variant", "-v", help="Run only this variant (repeatable).")
]
ControllerOpt = Annotated[
    str | None,
    typer.Option(
        "--controller",
        help="Supervisory controller package.module:Class run by the supervisor (default: the site's "
        "supervisor.controller, else the shipped MPC and adaptive PID).",
    ),
]


def _run(
    file: Path, config: Path | None, variant: list[str] | None, controller: str | None = None
) -> ScenarioResult:
    # The co-simulation computes: one BLAS thread, as in the tiers (tanklab_io.threads).
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()
    from tankctl.simulate import run_scenario
    from tanklab.errors import TanklabError

    try:
        return run_scenario(file, config=config, variants=variant, controller=controller)
    except TanklabError as e:
        raise _fail(str(e)) from None


PLOTS_MISSING = "--plot needs matplotlib, which this install does not have: pip install 'tanklab[plots]'"
"""The one line ``simulate --plot`` prints (exit 2) when matplotlib is not installed."""


def _plots_available() -> bool:
    """Whether matplotlib imports: it is the ``plots`` extra, not a runtime dependency."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def simulate_command(
    scenario: ScenarioArg,
    config: ConfigOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON on stdout.")] = False,
    csv_out: Annotated[
        str | None,
        typer.Option("--csv", help="Trajectories: OUT/<variant>.csv (directory) or OUT_<variant>.csv."),
    ] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="One PNG with every variant.")] = None,
    variant: VariantOpt = None,
    controller: ControllerOpt = None,
) -> None:
    """Run a scenario in the co-simulation, once per variant; print metrics per loop and step."""
    if plot is not None and not _plots_available():  # before the run (and its imports)
        raise _fail(PLOTS_MISSING)
    from tankctl.simulate import result_json, summary_text, write_csv

    result = _run(scenario, config, variant, controller)
    written: list[Path] = []
    try:
        if csv_out is not None:
            written += write_csv(result, csv_out)
        if plot is not None:
            from tankctl.plots import plot_scenario

            plot_scenario(result, plot)
            written.append(plot)
    except OSError as e:
        raise _fail(f"cannot write output: {e.strerror or e}: {e.filename or ''}") from None
    if as_json:
        typer.echo(json.dumps(result_json(result), indent=2, allow_nan=False))
    else:
        typer.echo(summary_text(result))
        for path in written:
            typer.echo(f"wrote {path}")


def compare_command(
    scenario: ScenarioArg,
    config: ConfigOpt = None,
    variant: VariantOpt = None,
    markdown: Annotated[bool, typer.Option("--markdown", help="Print markdown tables instead.")] = False,
) -> None:
    """Run a scenario and print our metrics beside the paper's published ones."""
    from tankctl.simulate import TF_REFERENCES, compare_text, markdown_report, tf_markdown

    result = _run(scenario, config, variant)
    if markdown:
        text = markdown_report(result)
        if result.scenario.name in TF_REFERENCES:
            text += "\nThe paper's experiment on its own transfer function:\n\n" + tf_markdown()
        typer.echo(text, nl=False)
    else:
        typer.echo(compare_text(result))


def register(app: typer.Typer) -> None:
    """Add ``simulate`` and ``compare`` to the main ``tankctl`` app."""
    app.command("simulate")(simulate_command)
    app.command("compare")(compare_command)
