"""The options every operator command shares are declared once (``tankctl.ops.options``).

Each command mounted by ``tankctl.ops.register`` ends with the same seven options, in the same
order, with the same flags, defaults and help; what they were given arrives as one
``StackOptions``. No stack is needed: the checks are on the click commands typer builds and on
a command run with bad shared options (exit 2 before anything connects).
"""

from __future__ import annotations

from typing import Any

import typer
from typer.testing import CliRunner

from tankctl.ops import DEFAULT_TIMEOUT_S, StackOptions, register, stack_command

SHARED = ["config", "host", "base_port", "plant_url", "plc_url", "supervisor_url", "timeout"]
COMMANDS = ["status", "setpoint", "leak", "valve", "loop", "mode", "gains", "browse", "watch"]


def _group() -> Any:
    """The click group typer builds for an app with the operator commands (typer's own click)."""
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    register(app)
    return typer.main.get_command(app)


def _shared_params(cmd: Any) -> list[tuple[str | None, tuple[str, ...], object, str | None]]:
    params = [p for p in cmd.params if p.name in SHARED]
    return [(p.name, tuple(p.opts), p.default, getattr(p, "help", None)) for p in params]


def test_every_operator_command_ends_with_the_same_shared_options() -> None:
    group = _group()
    scenario = group.commands["scenario"]
    commands = [group.commands[name] for name in COMMANDS] + [scenario.commands["run"]]
    first = _shared_params(commands[0])
    assert [name for name, *_ in first] == SHARED
    assert first[0][1] == ("--config", "-c") and first[-1][2] == DEFAULT_TIMEOUT_S
    for cmd in commands:
        names = [p.name for p in cmd.params]
        assert names[-len(SHARED) :] == SHARED, cmd.name  # after the command's own, in order
        assert _shared_params(cmd) == first, cmd.name


def test_the_command_gets_what_was_given_as_one_stack_options() -> None:
    seen: list[StackOptions] = []

    @stack_command
    def probe(name: str, *, options: StackOptions) -> None:
        seen.append(options)

    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    app.command("probe")(probe)
    app.command("other")(lambda: None)  # two commands: "probe" is a subcommand
    result = CliRunner().invoke(app, ["probe", "x", "--base-port", "4900", "--plc-url", "opc.tcp://h:1"])
    assert result.exit_code == 0, result.output
    assert seen == [StackOptions(base_port=4900, plc_url="opc.tcp://h:1")]


def test_a_bad_shared_option_is_one_line_and_exit_2_before_connecting() -> None:
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    register(app)
    result = CliRunner().invoke(app, ["setpoint", "LIC1", "0.4", "--timeout", "-1"])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        "tankctl: --timeout must be a positive number of seconds, got -1.0"
    ]
