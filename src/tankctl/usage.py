"""One-line usage errors for every ``tankctl`` command (the CLI's rule: one line, exit 2)."""

from __future__ import annotations

from typing import Any

import typer
from typer.core import TyperCommand


class OneLineUsage(TyperCommand):
    """A command whose usage errors (missing argument, bad number, unknown option) print one
    line ``tankctl GROUP COMMAND: message`` on stderr and exit 2, instead of typer's boxed,
    multi-line usage message. ``group`` names the command's group for a sub-app that may be
    invoked on its own (tests), where the context does not know its parent."""

    group: str | None = None

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, args)
        except typer.TyperException as e:  # typer's vendored click UsageError and subclasses
            if self.group is not None:
                where = f"{self.group} {self.name}"
            else:
                names: list[str] = []
                c = ctx
                while c is not None and c.parent is not None:
                    names.append(c.info_name or "")
                    c = c.parent
                where = " ".join(reversed(names))
            typer.echo(f"tankctl {where}: {e.format_message()}", err=True)
            raise typer.Exit(getattr(e, "exit_code", 2)) from None
