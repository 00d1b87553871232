"""``tankctl browse``: the servers' tanklab node trees, browsed and read."""

from __future__ import annotations

import asyncio
import json
from typing import Annotated, Any

import typer
from rich.table import Table

from tankctl.ops.client import BrowsedNode
from tankctl.ops.display import num, plain, stdout_console
from tankctl.ops.errors import UnreachableError
from tankctl.ops.options import JsonOpt, StackOptions, stack_command
from tankctl.ops.run import fail, run
from tankctl.ops.stack import TIERS, Stack
from tanklab.tags import Tier


def _value_cell(node: BrowsedNode) -> str:
    if node.node_class == "Method":
        ins = ", ".join(node.inputs or [])
        outs = ", ".join(node.outputs or [])
        return f"method ({ins})" + (f" -> ({outs})" if outs else "")
    if node.node_class != "Variable":
        return ""
    if node.status:
        return node.status
    if node.enum_name is not None:
        return f"{node.enum_name} ({node.value})"
    v = node.value
    if isinstance(v, list):
        text = "[" + ", ".join(num(x) for x in v[:4]) + (", ..." if len(v) > 4 else "") + "]"
        return f"{text} ({len(v)})"
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return num(v, node.unit)
    if isinstance(v, str):
        return repr(v)
    return str(plain(v))


def render_tree(tier: str, url: str, roots: list[BrowsedNode]) -> Table:
    """One table per tier: the node tree (indented), value, unit, EURange, access."""
    table = Table(title=f"{tier}  {url}", title_justify="left")
    for col in ("node", "value", "unit", "EURange", "access"):
        table.add_column(col)
    for root in roots:
        for depth, node in root.walk():
            name = node.name + ("()" if node.node_class == "Method" else "")
            if node.node_class == "Variable":
                access = "rw" if node.writable else "r"
            else:
                access = "call" if node.node_class == "Method" else ""
            rng = f"{node.eu_range[0]:g} .. {node.eu_range[1]:g}" if node.eu_range else ""
            table.add_row("  " * depth + name, _value_cell(node), node.unit or "", rng, access)
    return table


async def _browse_tier(stack: Stack, tier: Tier) -> list[BrowsedNode] | UnreachableError:
    try:
        async with stack.client(tier) as client:
            return await client.browse_tree()
    except UnreachableError as e:
        return e


@stack_command
def browse(
    tier: Annotated[
        str | None, typer.Argument(help="plant, plc or supervisor (default: every tier).")
    ] = None,
    as_json: JsonOpt = False,
    *,
    options: StackOptions,
) -> None:
    """Browse the servers' tanklab nodes under Objects: tree, values, units, EURange, access.

    Exit 2 (after printing the tiers that answered) if a tier asked for does not answer.
    """
    stack = options.stack()
    key = tier.strip().lower() if tier is not None else None
    if key is not None and key not in TIERS:
        raise fail(f"tier must be plant, plc or supervisor, got {tier!r}", 2)

    asked: list[Tier] = [t for t in TIERS if t == key]

    def which() -> list[Tier]:
        for t in asked:
            stack.require(t)
        return asked or [t for t in TIERS if stack.has(t)]

    async def main() -> int:
        await stack.resolve(*asked)
        tiers = which()
        results = await asyncio.gather(*(_browse_tier(stack, t) for t in tiers))
        doc: dict[str, Any] = {}
        console = stdout_console()
        failures: list[UnreachableError] = []
        for t, res in zip(tiers, results, strict=True):
            if isinstance(res, UnreachableError):
                failures.append(res)
                doc[t] = {"reachable": False, "url": stack.urls[t], "error": res.reason}
                continue
            doc[t] = {"reachable": True, "url": stack.urls[t], "nodes": [n.as_json() for n in res]}
            if not as_json:
                console.print(render_tree(t, stack.urls[t], res))
        if as_json:
            typer.echo(json.dumps(doc, indent=2))
        for e in failures:
            typer.echo(f"tankctl: {e}", err=True)
        return 2 if failures else 0

    run(main)
