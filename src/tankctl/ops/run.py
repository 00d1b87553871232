"""Running an operator command: asyncio.run, quiet logging, one-line failures, signals."""

from __future__ import annotations

import asyncio
import logging
import signal
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

import typer

from tankctl.ops.errors import RefusedError, StoppedError, UsageError
from tanklab.errors import TanklabError

_T = TypeVar("_T")


def fail(message: str, code: int) -> typer.Exit:
    typer.echo(f"tankctl: {message}", err=True)
    return typer.Exit(code)


def quiet_logging() -> None:
    """asyncua (and tanklab's links) log below ERROR only to debug a session: not here."""
    for name in ("asyncua", "tanklab"):
        logging.getLogger(name).setLevel(logging.ERROR)


def run(main: Callable[[], Coroutine[Any, Any, int]]) -> None:
    """Run ``main()`` under asyncio; its result is the exit code, its errors one line each."""
    quiet_logging()
    try:
        code = asyncio.run(main())
    except RefusedError as e:
        raise fail(str(e), 1) from None
    except StoppedError as e:
        raise fail(str(e), 130) from None
    except TanklabError as e:  # UnreachableError, UsageError, ConfigError
        raise fail(str(e), 2) from None
    except Exception as e:  # the CLI's boundary: a bug still gets one line, not a traceback
        raise fail(f"internal error: {type(e).__name__}: {e}", 1) from None
    if code:
        raise typer.Exit(code)


def check_usage(check: Callable[[], _T]) -> _T:
    """Run a local argument check; its UsageError is one line and exit code 2."""
    try:
        return check()
    except UsageError as e:
        raise fail(str(e), 2) from None


class StopOnSignal:
    """An event set by SIGINT/SIGTERM while the block runs (where signals can be handled)."""

    def __init__(self) -> None:
        self.event = asyncio.Event()
        self._installed: list[signal.Signals] = []

    def __enter__(self) -> asyncio.Event:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, self.event.set)
                self._installed.append(sig)
            except (NotImplementedError, RuntimeError, ValueError):
                pass  # not the main thread (or no signal support): Ctrl-C keeps its default
        return self.event

    def __exit__(self, *exc: object) -> None:
        loop = asyncio.get_running_loop()
        for sig in self._installed:
            loop.remove_signal_handler(sig)
