"""Operator commands of ``tankctl`` against a running stack.

::

    tankctl status [--json]                      one Read per tier: levels, loops, alarms, health
    tankctl setpoint LIC1 0.45                   PLC.LIC1.SP [m]
    tankctl leak T1 0.3 | tankctl leak T1 off    Plant.T1.Leak, opening 0..1
    tankctl valve V13 0.5                        Plant.V13.Opening, 0..1
    tankctl pump P1 0.8 | tankctl pump P1 healthy   Plant.P1.Delivered, fraction 0..1 (degradation)
    tankctl loop LIC1 manual 40                  PLC.LIC1.Mode = MANUAL, then ManualMV = 40 % of its EURange
    tankctl loop LIC1 auto                       PLC.LIC1.Mode = AUTO
    tankctl mode adaptive-pid|mpc|advisory|off   Supervisor.Mode
    tankctl gains LIC1 [--json]                  applied gains, GainSource, the supervisor's RLS state
    tankctl gains LIC1 --kp K --ki K --kd K      PLC.LIC1.SetGains as an engineer (GainSource ENGINEER)
    tankctl gains LIC1 --release                 PLC.LIC1.ReleaseGains: back under adaptation
    tankctl gains LIC1 --reset                   PLC.LIC1.ResetGains: the configured gains again
    tankctl browse [plant|plc|supervisor] [--json]   the servers' node trees, browsed
    tankctl watch [--interval 1] [--duration S]  live trend of levels against setpoints
    tankctl alarms [--json] [--all]              the PLC's standing alarms (conditions), one Read
    tankctl ack T1Level [--comment TEXT]         Acknowledge(EventId, Comment) of a condition
    tankctl shelve T1Level --for 15m | --once    TimedShelve(ms) / OneShotShelve; tankctl unshelve T1Level
    tankctl scenario run FILE                    a scenario's timed events, on the plant's model time

Endpoints (every command): ``--plant-url`` / ``--plc-url`` / ``--supervisor-url``, else
``TANKLAB_PLANT_URL`` / ``TANKLAB_PLC_URL`` / ``TANKLAB_SUPERVISOR_URL``, else ``--base-port N``
(or ``TANKLAB_BASE_PORT``) giving N, N+1, N+2 on ``--host`` (default 127.0.0.1), else the given
site config's endpoints, else 4840, 4841, 4842, with ``--host`` replacing their host when given.

The site (which tanks, valves, loops and ranges exist, so names are checked before anything is
sent) is ``--config``, else ``TANKLAB_CONFIG``, else the stack's own: each tier publishes its
site name, config digest and config (``<Tier>.Identity.*``, :mod:`tanklab.identity`). Every
connection compares them with the site and refuses another site or config in one line, exit 2
(:class:`SiteMismatchError`, decision 0020).

Units at the command line: levels in m, openings 0..1, flows in m^3/s, a manual output in
percent of the ManualMV's EURange (read from the PLC itself).

Exit codes: 0 done; 1 a write or a method call refused by a server (one line with the status
code's name, e.g. ``tankctl: PLC.LIC1.SP = 0.7 refused: BadOutOfRange``,
``tankctl: PLC.LIC1.ResetGains() refused: BadInvalidState (...)``); 2 bad usage, an unknown name, a bad
config or scenario, an unreachable endpoint (``tankctl: cannot reach plc at URL: REASON``), or a
refused login (``tankctl: login as 'alice' refused: wrong user name or password, or the account is
locked (plc at URL)``; never reported as unreachable). The login is ``TANKLAB_USER`` +
``TANKLAB_PASSWORD``, else the security home's credentials file; only one of the two variables
set is an error before anything connects (:func:`tanklab_io.ua_security.cli_identity`).
Nothing prints a traceback: asyncua's and tanklab's loggers are held at ERROR while these
commands run, and every failure at the OPC UA boundary becomes one line.

:func:`register` mounts the commands (and the ``scenario`` group) on the main typer app.

The package, one responsibility per module: :mod:`~tankctl.ops.errors` (the failures and their
exit codes), :mod:`~tankctl.ops.stack` (endpoints and the site), :mod:`~tankctl.ops.client` (one
connected tier), :mod:`~tankctl.ops.options` (the shared options, declared once),
:mod:`~tankctl.ops.run` (asyncio, one-line failures), :mod:`~tankctl.ops.display` (values for
people), and a module per command group: ``writes``, ``gains``, ``status``, ``browse``,
``watch``, ``alarms``, ``scenario`` (decision 0031).

The names below are imported from their modules when first used (PEP 562), so that a command
imports only its own module and what that needs: ``tankctl setpoint`` loads neither rich's
tables nor the scenario models (decision 0039). :func:`register` mounts every command at once
(``tankctl.cli`` mounts them one by one as they are used, :mod:`tankctl.lazy`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import typer

    from tankctl.ops.client import BrowsedNode, TierClient
    from tankctl.ops.errors import (
        CallRefusedError,
        LoginRefusedError,
        RefusedError,
        SiteMismatchError,
        StoppedError,
        UnreachableError,
        UsageError,
    )
    from tankctl.ops.options import StackOptions, stack_command
    from tankctl.ops.scenario import add_scenario_commands, scenario_app
    from tankctl.ops.stack import DEFAULT_TIMEOUT_S, TIERS, Stack, make_stack, resolve_endpoints
    from tankctl.ops.status import collect_status, render_status
    from tankctl.ops.watch import level_bar, sparkline

__all__ = [
    "DEFAULT_TIMEOUT_S",
    "TIERS",
    "BrowsedNode",
    "CallRefusedError",
    "LoginRefusedError",
    "RefusedError",
    "SiteMismatchError",
    "Stack",
    "StackOptions",
    "StoppedError",
    "TierClient",
    "UnreachableError",
    "UsageError",
    "add_scenario_commands",
    "collect_status",
    "level_bar",
    "make_stack",
    "register",
    "render_status",
    "resolve_endpoints",
    "scenario_app",
    "sparkline",
    "stack_command",
]

_HOME = {
    "BrowsedNode": "client",
    "TierClient": "client",
    "CallRefusedError": "errors",
    "LoginRefusedError": "errors",
    "RefusedError": "errors",
    "SiteMismatchError": "errors",
    "StoppedError": "errors",
    "UnreachableError": "errors",
    "UsageError": "errors",
    "StackOptions": "options",
    "stack_command": "options",
    "add_scenario_commands": "scenario",
    "scenario_app": "scenario",
    "scenario_run": "scenario",
    "DEFAULT_TIMEOUT_S": "stack",
    "TIERS": "stack",
    "Stack": "stack",
    "make_stack": "stack",
    "resolve_endpoints": "stack",
    "collect_status": "status",
    "render_status": "status",
    "level_bar": "watch",
    "sparkline": "watch",
    "leak": "writes",
    "loop_command": "writes",
    "mode": "writes",
    "setpoint": "writes",
    "valve": "writes",
    "pump": "writes",
}
"""The module of this package that defines each name the package exports. (``status``,
``browse``, ``gains`` and ``watch`` are the modules of those commands: :data:`COMMANDS`.)"""

COMMANDS: dict[str, tuple[str, str]] = {
    "status": ("status", "status"),
    "setpoint": ("writes", "setpoint"),
    "leak": ("writes", "leak"),
    "valve": ("writes", "valve"),
    "pump": ("writes", "pump"),
    "loop": ("writes", "loop_command"),
    "mode": ("writes", "mode"),
    "gains": ("gains", "gains"),
    "browse": ("browse", "browse"),
    "watch": ("watch", "watch"),
    "alarms": ("alarms", "alarms"),
    "ack": ("alarms", "ack"),
    "shelve": ("alarms", "shelve"),
    "unshelve": ("alarms", "unshelve"),
}
"""The operator commands, in the order ``tankctl --help`` lists them: name -> (module of this
package, function)."""


def __getattr__(name: str) -> Any:
    """An exported name, imported from its module on first use (PEP 562)."""
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


def register(app: typer.Typer) -> None:
    """Add the operator commands and the ``scenario`` group to the main ``tankctl`` app."""
    from tankctl.ops.scenario import scenario_app
    from tankctl.usage import OneLineUsage

    for name, (module, func) in COMMANDS.items():
        command = getattr(importlib.import_module(f"{__name__}.{module}"), func)
        app.command(name, cls=OneLineUsage)(command)
    app.add_typer(scenario_app, name="scenario")
