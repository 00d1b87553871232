"""Writes: ``setpoint``, ``leak``, ``valve``, ``pump``, ``loop``, ``mode`` (one node each, old value
shown)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Annotated, Any

import typer

from tankctl.ops.display import with_unit
from tankctl.ops.errors import UsageError
from tankctl.ops.options import StackOptions, stack_command
from tankctl.ops.run import check_usage, run
from tankctl.ops.stack import Stack
from tanklab import paths
from tanklab.enums import LoopMode, SupervisorMode
from tanklab.tags import Tier

if TYPE_CHECKING:
    from tankctl.ops.client import TierClient
    from tankctl.ops.relayed import RelayedClient


async def write_and_tell(client: TierClient | RelayedClient, path: str, value: Any, note: str = "") -> str:
    """Read the old value, write the new one, return ``PATH = NEW unit (was OLD unit)``."""
    tag = client.tags[path]
    old = (await client.read([path]))[path]
    await client.write(path, value)
    extra = f" ({note})" if note else f" (was {with_unit(tag, old)})"
    return f"{path} = {with_unit(tag, value)}{extra}"


def _write_one(stack: Stack, tier: Tier, path: Callable[[], str], value: Any) -> None:
    """Run a one-node write: know the site, check the name (``path()`` raises UsageError for an
    unknown one), write the node of ``tier`` and print ``PATH = NEW (was OLD)``."""

    async def main() -> int:
        stack.use_relay()  # a read and a write: the relay's when ``up`` serves one
        await stack.resolve(tier)
        node = path()
        # The old value is read with the identity (one Read), unless resolve() connected already.
        async with stack.io(tier).will_read([node]) as client:
            typer.echo(await write_and_tell(client, node, value))
        return 0

    run(main)


@stack_command
def setpoint(
    loop: Annotated[str, typer.Argument(help="Loop, e.g. LIC1.")],
    value: Annotated[float, typer.Argument(help="New setpoint, in m.")],
    *,
    options: StackOptions,
) -> None:
    """Write a loop's setpoint, in m, to the PLC (PLC.LIC{j}.SP; the PLC range-checks it)."""
    stack = options.stack()
    _write_one(stack, "plc", lambda: paths.plc.loop(stack.loop(loop)).sp, value)


def _opening(text: str, what: str, words: Mapping[str, float]) -> float:
    key = text.strip().lower()
    if key in words:
        return words[key]
    try:
        value = float(key)
    except ValueError:
        raise UsageError(
            f"{what} must be a number 0..1 or {' / '.join(repr(w) for w in words)}, got {text!r}"
        ) from None
    if not math.isfinite(value):
        raise UsageError(f"{what} must be a finite number, got {text!r}")
    return value


@stack_command
def leak(
    tank: Annotated[str, typer.Argument(help="Tank, e.g. T1.")],
    opening: Annotated[str, typer.Argument(help="Leak valve opening 0..1, or 'off' (= 0).")],
    *,
    options: StackOptions,
) -> None:
    """Open a tank's leak valve to the drain (Plant.T{i}.Leak, 0..1); 'off' closes it."""
    stack = options.stack()
    value = check_usage(lambda: _opening(opening, "the leak opening", {"off": 0.0}))
    _write_one(stack, "plant", lambda: paths.plant.tank(stack.tank(tank)).leak, value)


@stack_command
def valve(
    name: Annotated[str, typer.Argument(help="Valve, e.g. V13.")],
    opening: Annotated[
        str, typer.Argument(help="Opening 0 (clogged) .. 1 (free); 'open' = 1, 'closed' = 0.")
    ],
    *,
    options: StackOptions,
) -> None:
    """Set a connecting or outlet valve's opening (Plant.V{mn}.Opening, 0..1): a clog."""
    stack = options.stack()
    value = check_usage(lambda: _opening(opening, "the valve opening", {"open": 1.0, "closed": 0.0}))
    _write_one(stack, "plant", lambda: paths.plant.valve_opening(stack.valve(name)), value)


@stack_command
def pump(
    name: Annotated[str, typer.Argument(help="Pump, e.g. P1.")],
    fraction: Annotated[
        str, typer.Argument(help="Fraction 0..1 of its command's flow it delivers; 'healthy' = 1.")
    ],
    *,
    options: StackOptions,
) -> None:
    """Degrade a pump (Plant.P{i}.Delivered, 0..1): it delivers that fraction of its command's flow."""
    stack = options.stack()
    value = check_usage(lambda: _opening(fraction, "the delivered fraction", {"healthy": 1.0}))
    _write_one(stack, "plant", lambda: paths.plant.pump(stack.pump(name)).delivered, value)


def _loop_mode(text: str) -> LoopMode:
    try:
        return LoopMode[text.strip().upper()]
    except KeyError:
        raise UsageError(f"loop mode must be manual, auto or remote, got {text!r}") from None


def _check_percent(percent: float | None, mode: LoopMode) -> None:
    if percent is None:
        return
    if mode is not LoopMode.MANUAL:
        raise UsageError(f"an output percentage goes with manual only, not {mode.name.lower()}")
    if not (math.isfinite(percent) and 0.0 <= percent <= 100.0):
        raise UsageError(f"the manual output must be 0..100 % of the MV range, got {percent:g}")


async def apply_loop_mode(plc: TierClient, loop: str, mode: LoopMode, percent: float | None) -> list[str]:
    """Switch a loop's mode; for MANUAL with a percentage, then move ManualMV to it.

    Mode first, then the output: the PLC's MANUAL switch is bumpless (it starts ManualMV from
    the applied MV, overwriting any preset), so a ManualMV written before the switch would be
    lost; written after it, it steps the output from where the loop was.
    """
    lines: list[str] = []
    mode_path, mv_path = paths.plc.loop(loop).mode, paths.plc.loop(loop).manual_mv
    lines.append(await write_and_tell(plc, mode_path, int(mode)))
    if percent is not None:
        rng = await plc.eu_range(mv_path) or plc.tags[mv_path].eu_range
        assert rng is not None  # every ManualMV tag has a range
        value = rng[0] + percent / 100.0 * (rng[1] - rng[0])
        tag = plc.tags[mv_path]
        unit = f" {tag.unit}" if tag.unit and tag.unit != "1" else ""
        note = f"{percent:g} % of {rng[0]:g} .. {rng[1]:g}{unit}"
        lines.append(await write_and_tell(plc, mv_path, value, note))
    return lines


@stack_command
def loop_command(
    loop: Annotated[str, typer.Argument(help="Loop, e.g. LIC1.")],
    mode: Annotated[str, typer.Argument(help="manual, auto or remote.")],
    percent: Annotated[
        float | None, typer.Argument(help="Manual output in percent of the ManualMV's EURange (0..100).")
    ] = None,
    *,
    options: StackOptions,
) -> None:
    """Switch a loop: 'manual [PERCENT]' (bumpless, then the output to PERCENT), 'auto', 'remote'."""
    stack = options.stack()
    new_mode = check_usage(lambda: _loop_mode(mode))
    check_usage(lambda: _check_percent(percent, new_mode))

    async def main() -> int:
        await stack.resolve("plc")
        name = stack.loop(loop)
        async with stack.client("plc") as plc:
            for line in await apply_loop_mode(plc, name, new_mode, percent):
                typer.echo(line)
        return 0

    run(main)


def _supervisor_mode(text: str) -> SupervisorMode:
    try:
        return SupervisorMode[text.strip().upper().replace("-", "_")]
    except KeyError:
        raise UsageError(f"mode must be adaptive-pid, mpc, advisory or off, got {text!r}") from None


@stack_command
def mode(
    name: Annotated[str, typer.Argument(help="adaptive-pid, mpc, advisory or off.")],
    *,
    options: StackOptions,
) -> None:
    """Switch the supervisor's mode (Supervisor.Mode); it takes effect at its next cycle."""
    stack = options.stack()
    new = check_usage(lambda: _supervisor_mode(name))

    def path() -> str:
        stack.require("supervisor")
        return paths.supervisor.mode

    _write_one(stack, "supervisor", path, int(new))
