"""``tankctl`` mounts the commands of other modules lazily (``tankctl.lazy``, decision 0039).

The lazy group must be the same command line as the eager one it replaces: the same commands
in the same order, the same ``--help`` of every command and group, the same one-line usage
errors and suggestions. The eager app here is built the way ``tankctl.cli`` built it before
(every module imported, every command registered with typer), from the same functions.
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from helpers import ROOT

ENV = {"COLUMNS": "100", "TERMINAL_WIDTH": "100"}


def _eager_app() -> typer.Typer:
    from tankctl import (
        cli,
        fleet_cli,
        history_cli,
        k8s_cli,
        ops,
        scenario_cli,
        security_cli,
        simulate_cli,
        sweep_cli,
        tune_cli,
    )
    from tankctl.usage import OneLineUsage

    app = typer.Typer(
        name="tankctl",
        help=cli.app.info.help,
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        add_completion=False,
    )
    app.add_typer(cli.config_app, name="config")
    app.add_typer(tune_cli.app, name="tune")
    ops.register(app)
    # the real CLI's scenario group is tankctl.scenario_cli's: ops' `run` plus `check`
    for group in app.registered_groups:
        if group.name == "scenario":
            group.typer_instance = scenario_cli.scenario_app
    app.command("history", cls=OneLineUsage)(history_cli.history_command)
    simulate_cli.register(app)
    app.command("sweep")(sweep_cli.sweep_command)
    security_cli.register(app)
    app.add_typer(k8s_cli.k8s_app, name="k8s")
    app.add_typer(cli.docs_app, name="docs")
    for command in (cli.linearize, cli.plant, cli.plc, cli.supervisor, cli.historian, cli.hmi, cli.up):
        app.command()(command)
    app.add_typer(fleet_cli.fleet_app, name="fleet")
    return app


def _paths(group: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = [prefix]
    for name in group.list_commands(None):
        sub = group.get_command(None, name)
        if hasattr(sub, "list_commands"):
            out += _paths(sub, (*prefix, name))
        else:
            out.append((*prefix, name))
    return out


def _run(app: typer.Typer, *argv: str) -> tuple[int, str]:
    r = CliRunner().invoke(app, list(argv), env=ENV)
    return r.exit_code, r.output


def test_the_same_commands_in_the_same_order() -> None:
    from tankctl.cli import app

    lazy: Any = typer.main.get_command(app)
    eager: Any = typer.main.get_command(_eager_app())
    assert list(lazy.commands) == list(eager.commands)
    assert _paths(lazy) == _paths(eager)


def test_every_help_is_the_eager_one() -> None:
    from tankctl.cli import app

    eager = _eager_app()
    paths = _paths(typer.main.get_command(eager))
    assert len(paths) > 30
    for path in paths:
        assert _run(app, *path, "--help") == _run(eager, *path, "--help"), path


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["setpiont"],
        ["setpoint"],
        ["setpoint", "LIC1", "abc"],
        ["status", "--bogus"],
        ["tune", "bogus"],
        ["scenario"],
        ["setpoint", "LIC1", "0.4", "--timeout", "-1"],
        ["mode", "foo", "--base-port", "4900"],
    ],
)
def test_usage_errors_are_the_eager_ones(argv: list[str]) -> None:
    from tankctl.cli import app

    assert _run(app, *argv) == _run(_eager_app(), *argv)


def _modules_after(*argv: str) -> tuple[subprocess.CompletedProcess[str], set[str]]:
    code = (
        "import json, sys\n"
        "from tankctl.cli import main\n"
        "sys.argv = ['tankctl', *sys.argv[1:]]\n"
        "try:\n"
        "    main()\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(json.dumps(sorted(sys.modules)), file=sys.stderr)\n"
    )
    p = subprocess.run(
        [sys.executable, "-c", code, *argv], capture_output=True, text=True, cwd=ROOT, timeout=60, check=False
    )
    return p, set(json.loads(p.stderr.strip().splitlines()[-1]))


def test_a_command_imports_its_own_module_only() -> None:
    """A usage error of ``setpoint`` builds that command alone: its module, not the other
    commands' (status and its rich tables, the scenario models, the PKI commands, tune)."""
    p, modules = _modules_after("setpoint", "LIC1")
    assert "Missing argument 'value'" in p.stderr
    assert "tankctl.ops.writes" in modules
    others = {
        "tankctl.ops.status",
        "tankctl.ops.browse",
        "tankctl.ops.watch",
        "tankctl.ops.gains",
        "tankctl.ops.scenario",
        "tankctl.security_cli",
        "tankctl.tune_cli",
        "tankctl.simulate_cli",
        "tanklab.scenario",
        "rich.table",
    }
    assert modules & others == set()


def test_an_unknown_command_is_suggested_from_the_names_alone() -> None:
    p, modules = _modules_after("setpiont")
    assert "Did you mean 'setpoint'?" in p.stderr
    assert not {m for m in modules if m.startswith("tankctl.ops.")}
