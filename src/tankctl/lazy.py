"""Commands of ``tankctl`` whose module is imported when the command is used (decision 0039).

Every ``tankctl`` command is a fresh process. typer builds the click command of every command
it knows before it parses the command line, so each process imported all of ``tankctl``: the
operator commands (asyncua, rich), the security commands (the PKI), tune, simulate. Here a
command group lists some of its commands as :class:`Lazy` entries, a module and a name: the
group's mapping of commands (:class:`LazyCommands`) knows every name, and builds a lazy entry's
click command, through typer's own functions and from the same ``CommandInfo`` or
``TyperInfo`` that ``app.command(...)`` or ``app.add_typer(...)`` would have recorded, the first
time it is looked up. ``tankctl setpoint`` so imports :mod:`tankctl.ops.writes` and what it
needs, and builds one command; ``tankctl --help`` (which lists every command with its help)
and an unknown command's suggestions (which need only the names) work as before.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import typer
import typer.main
from typer._click import Command
from typer.core import TyperGroup

from tankctl.usage import OneLineUsage


@dataclass(frozen=True)
class Lazy:
    """A command (a function) or a command group (a ``typer.Typer``) named ``attr`` in
    ``module``, mounted on a group under its own name; ``one_line_usage`` mounts a command
    with ``cls=OneLineUsage``."""

    module: str
    attr: str
    group: bool = False
    one_line_usage: bool = False

    def load(self) -> Any:
        """The function or typer app (its module imported now, once)."""
        return getattr(importlib.import_module(self.module), self.attr)

    def build(self, name: str, settings: BuildSettings) -> Command:
        """The click command typer would have built for ``name`` had it been mounted eagerly."""
        scratch = typer.Typer()
        if self.group:
            scratch.add_typer(self.load(), name=name)
            return typer.main.get_group_from_info(
                scratch.registered_groups[0],
                pretty_exceptions_short=settings.pretty_exceptions_short,
                rich_markup_mode=settings.rich_markup_mode,
                suggest_commands=settings.suggest_commands,
            )
        scratch.command(name, cls=OneLineUsage if self.one_line_usage else None)(self.load())
        return typer.main.get_command_from_info(
            scratch.registered_commands[0],
            pretty_exceptions_short=settings.pretty_exceptions_short,
            rich_markup_mode=settings.rich_markup_mode,
        )


@dataclass(frozen=True)
class BuildSettings:
    """What typer passes from the root app to every command it builds."""

    pretty_exceptions_short: bool
    rich_markup_mode: Any
    suggest_commands: bool


class LazyCommands(MutableMapping[str, Command]):
    """A group's commands by name: the ones typer built, and :class:`Lazy` ones built on first
    lookup. Names iterate in ``order`` (the order ``--help`` lists them), then any others."""

    def __init__(
        self,
        built: Mapping[str, Command],
        lazy: Mapping[str, Lazy],
        order: Sequence[str],
        build: Callable[[str, Lazy], Command],
    ) -> None:
        self._built = dict(built)
        self._lazy = dict(lazy)
        self._order = list(order)
        self._build = build

    def __getitem__(self, name: str) -> Command:
        if name not in self._built:
            if name not in self._lazy:
                raise KeyError(name)
            self._built[name] = self._build(name, self._lazy[name])
        return self._built[name]

    def __setitem__(self, name: str, command: Command) -> None:
        self._lazy.pop(name, None)
        self._built[name] = command

    def __delitem__(self, name: str) -> None:
        if name not in self._built and name not in self._lazy:
            raise KeyError(name)
        self._built.pop(name, None)
        self._lazy.pop(name, None)

    def _names(self) -> list[str]:
        known = {*self._built, *self._lazy}
        first = [n for n in self._order if n in known]
        return first + [n for n in [*self._built, *self._lazy] if n not in first]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names())

    def __len__(self) -> int:
        return len({*self._built, *self._lazy})

    def __contains__(self, name: object) -> bool:
        return name in self._built or name in self._lazy


class LazyGroup(TyperGroup):
    """A typer group (``typer.Typer(cls=...)``) with :attr:`lazy` commands besides the ones
    registered on its app, all listed in :attr:`order`. Subclass it with the table."""

    lazy: ClassVar[Mapping[str, Lazy]] = {}
    order: ClassVar[Sequence[str]] = ()
    pretty_exceptions_short: ClassVar[bool] = True
    """The app's ``pretty_exceptions_short`` (typer does not hand it to the group)."""

    def __init__(self, **attrs: Any) -> None:
        super().__init__(**attrs)
        settings = BuildSettings(self.pretty_exceptions_short, self.rich_markup_mode, self.suggest_commands)
        self.commands = LazyCommands(
            self.commands, self.lazy, self.order, lambda name, entry: entry.build(name, settings)
        )
