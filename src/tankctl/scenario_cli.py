"""``tankctl scenario``: ``check`` a scenario's expectations in the co-simulation, ``run`` it live.

``run`` (:mod:`tankctl.ops.scenario`) is an operator command: it imports no numerics. ``check``
runs the co-simulation, so it lives here and imports it when it runs, as ``tankctl simulate``
does (:mod:`tankctl.simulate_cli`; docs/decisions/0023-lazy-cli-imports.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from tankctl.ops.run import fail
from tankctl.ops.scenario import add_scenario_commands
from tankctl.usage import OneLineUsage
from tanklab.errors import TanklabError
from tanklab.scenario import load_scenario

__all__ = ["scenario_app", "scenario_check"]


def scenario_check(
    file: Annotated[Path, typer.Argument(help="Scenario YAML file with an expect: section.")],
    config: Annotated[
        Path | None, typer.Option("--config", "-c", help="Site YAML file instead of the scenario's own.")
    ] = None,
    variant: Annotated[
        list[str] | None, typer.Option("--variant", "-v", help="Run only this variant (repeatable).")
    ] = None,
) -> None:
    """Run a scenario in the co-simulation and check its expect: bounds (a CI gate).

    One line per expectation and variant (pass / FAIL with the reason), then a summary. Exit 0
    when every expectation is met, 1 when one is not, 2 when the scenario cannot be run.
    """
    try:
        scenario, _ = load_scenario(file)
    except TanklabError as e:
        raise fail(str(e), 2) from None
    if not scenario.expect:
        raise fail(f"{file}: no expect: section, nothing to check", 2)
    # The co-simulation computes: one BLAS thread, as in the tiers (tanklab_io.threads).
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()
    from tankctl.simulate import run_scenario
    from tankctl.simulate.expect import check_expectations

    try:
        result = run_scenario(file, config=config, variants=variant)
    except TanklabError as e:
        raise fail(str(e), 2) from None
    outcomes = check_expectations(result)
    if not outcomes:
        raise fail(f"{file}: no expectation applies to the variants run ({', '.join(result.variants)})", 2)
    for o in outcomes:
        typer.echo(o.line())
    failed = sum(not o.passed for o in outcomes)
    typer.echo(
        f"scenario check {scenario.name}: {len(outcomes) - failed} of {len(outcomes)} expectations met"
        + (f", {failed} failed" if failed else "")
    )
    if failed:
        raise typer.Exit(1)


scenario_app = typer.Typer(
    help="Scenarios: check one's expectations in the co-simulation, or run one against a running stack.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
"""The ``tankctl scenario`` group."""

add_scenario_commands(scenario_app)
scenario_app.command("check", cls=OneLineUsage)(scenario_check)
