"""The options every operator command shares, declared once.

:func:`stack_command` appends ``--config``, ``--host``, ``--base-port``, the three URLs and
``--timeout`` to a command (after its own options, as each command listed them before) and
hands the command one :class:`StackOptions` instead of seven parameters; the command makes its
:class:`~tankctl.ops.stack.Stack` with :meth:`StackOptions.stack` when its own arguments are
checked (``scenario run`` first loads its scenario, whose site gives the endpoints' fallback).
The options stay on each command, not on the ``tankctl`` group: ``tankctl setpoint LIC1 0.4
--base-port 4900`` is the command line the docs and scripts use (decision 0031).
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from tankctl.ops.run import fail
from tankctl.ops.stack import DEFAULT_TIMEOUT_S, Stack, make_stack
from tanklab.config import SiteConfig
from tanklab.errors import TanklabError

ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        "-c",
        help="Site YAML the stack must run: checked against every tier's identity (env "
        "TANKLAB_CONFIG; default: the site the stack publishes).",
    ),
]
HostOpt = Annotated[
    str | None,
    typer.Option(help="Host of the tiers for --base-port or the config's ports (default 127.0.0.1)."),
]
BasePortOpt = Annotated[
    int | None,
    typer.Option(
        help="Plant at N, PLC at N+1, supervisor at N+2, historian at N+3 (env TANKLAB_BASE_PORT; "
        "default: the config's endpoints, 4840..4843)."
    ),
]
PlantUrlOpt = Annotated[str | None, typer.Option(help="Plant endpoint (env TANKLAB_PLANT_URL).")]
PlcUrlOpt = Annotated[str | None, typer.Option(help="PLC endpoint (env TANKLAB_PLC_URL).")]
SupervisorUrlOpt = Annotated[
    str | None, typer.Option(help="Supervisor endpoint (env TANKLAB_SUPERVISOR_URL).")
]
TimeoutOpt = Annotated[float, typer.Option(help="Seconds to wait for a tier to connect or answer.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON (shape in docs/cli.md).")]


@dataclass(frozen=True)
class StackOptions:
    """The shared options as given on the command line (flags; None when not given)."""

    config: Path | None = None
    host: str | None = None
    base_port: int | None = None
    plant_url: str | None = None
    plc_url: str | None = None
    supervisor_url: str | None = None
    timeout: float = DEFAULT_TIMEOUT_S
    """Wall-time bound of connecting and of every request [s] (``--timeout``)."""

    def stack(self, endpoints_of: SiteConfig | None = None, historian_url: str | None = None) -> Stack:
        """The :class:`Stack` of these options (:func:`make_stack`; ``historian_url``: the
        ``--historian-url`` of the commands that read history); a failure is one line, exit 2."""
        try:
            return make_stack(
                self.config,
                self.host,
                self.base_port,
                self.plant_url,
                self.plc_url,
                self.supervisor_url,
                self.timeout,
                endpoints_of=endpoints_of,
                historian_url=historian_url,
            )
        except TanklabError as e:
            raise fail(str(e), 2) from None


def _shared(name: str, annotation: Any, default: Any = None) -> inspect.Parameter:
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)


SHARED_OPTIONS: tuple[inspect.Parameter, ...] = (
    _shared("config", ConfigOpt),
    _shared("host", HostOpt),
    _shared("base_port", BasePortOpt),
    _shared("plant_url", PlantUrlOpt),
    _shared("plc_url", PlcUrlOpt),
    _shared("supervisor_url", SupervisorUrlOpt),
    _shared("timeout", TimeoutOpt, DEFAULT_TIMEOUT_S),
)
"""The shared options in the order ``--help`` lists them, after the command's own."""


def stack_command(func: Callable[..., None]) -> Callable[..., None]:
    """A command taking ``options: StackOptions`` (keyword-only), shown to typer with the
    :data:`SHARED_OPTIONS` in its place; typer's parsed values arrive as one StackOptions.

    typer reads a command's parameters from ``inspect.signature``, which honours
    ``__signature__``: the wrapper's signature is the command's own parameters, then the
    shared ones, with their annotations evaluated (the modules use postponed annotations).
    """
    own = inspect.signature(func, eval_str=True)
    if "options" not in own.parameters:
        raise TypeError(f"{func.__name__} takes no options: StackOptions parameter")
    names = [p.name for p in SHARED_OPTIONS]

    @functools.wraps(func)
    def command(*args: Any, **kwargs: Any) -> None:
        given = {name: kwargs.pop(name) for name in names if name in kwargs}
        func(*args, options=StackOptions(**given), **kwargs)

    params = [p for p in own.parameters.values() if p.name != "options"]
    command.__signature__ = own.replace(parameters=[*params, *SHARED_OPTIONS])  # type: ignore[attr-defined]
    return command
