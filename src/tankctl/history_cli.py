"""``tankctl history``: the historian's record of a tier's tags, read through OPC UA HistoryRead
(issue 16, docs/historian.md, docs/cli.md).

    tankctl history TAG... [--from -1h] [--to now] [--aggregate avg --interval 60s] [--csv|--json]
    tankctl history export --parquet FILE [TAG...]      (no TAG: every tag of the site's tiers)
    tankctl history plot TAG... -o FILE.png

A TAG is a tier's dotted path as ``tankctl browse`` shows it (``PLC.LIC1.PV``); the historian
serves the tiers' NodeIds. The historian is at the site's historian endpoint, ``--base-port`` + 3,
``TANKLAB_HISTORIAN_ENDPOINT`` or ``--historian-url``; its site identity is checked like every
tier's. Outside :mod:`tankctl.ops` because export and plot load pyarrow and matplotlib
(:mod:`tankctl.history_files`, imported only by those two), which operator commands never import.
"""

from __future__ import annotations

import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated

import typer

from tankctl.ops.errors import UsageError
from tankctl.ops.history_output import render_csv, render_json, render_text
from tankctl.ops.history_read import (
    AGGREGATES,
    HistoryReadError,
    HistoryRow,
    parse_span_s,
    parse_time,
    read_tag_history,
)
from tankctl.ops.options import StackOptions, stack_command
from tankctl.ops.run import check_usage, run
from tankctl.ops.stack import TIERS, Stack

FromOpt = Annotated[
    str,
    typer.Option("--from", help="Start: ISO 8601 (UTC unless an offset is given), now, or -15m / -2h / -1d."),
]
ToOpt = Annotated[str, typer.Option("--to", help="End: as --from.")]
HistorianUrlOpt = Annotated[
    str | None,
    typer.Option(
        help="Historian endpoint (env TANKLAB_HISTORIAN_ENDPOINT; default: --base-port + 3, the config's)."
    ),
]

VERBS = ("export", "plot")
"""The words that start a subcommand rather than a tag (tags are dotted paths)."""


def recorded_tags(stack: Stack) -> list[str]:
    """Every variable of the site's tiers, the nodes the historian records, in contract order."""
    return [
        path
        for tier in TIERS
        if stack.has(tier)
        for path, tag in stack.tags(tier).items()
        if tag.kind == "variable"
    ]


def check_tags(stack: Stack, tags: list[str]) -> list[str]:
    """``tags`` if each is a variable of the site's tiers, else UsageError naming the first not."""
    known = set(recorded_tags(stack))
    for tag in tags:
        if tag not in known:
            raise UsageError(
                f"unknown tag {tag!r}: give a variable's path as `tankctl browse` shows it (PLC.LIC1.PV)"
            )
    return tags


@stack_command
def history_command(
    words: Annotated[
        list[str],
        typer.Argument(metavar="TAG", help="Tags to read; or `export [TAG...]`, or `plot TAG...`."),
    ],
    start: FromOpt = "-1h",
    end: ToOpt = "now",
    aggregate: Annotated[
        str | None, typer.Option(help=f"A Part 13 aggregate per --interval: {', '.join(AGGREGATES)}.")
    ] = None,
    interval: Annotated[str | None, typer.Option(help="Aggregate interval: 500ms, 60s, 5m, 1h.")] = None,
    csv_out: Annotated[
        bool, typer.Option("--csv", help="Print CSV (tag,time,value,status,status_code).")
    ] = False,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON (shape in docs/cli.md).")] = False,
    parquet: Annotated[Path | None, typer.Option(help="export: the Parquet file to write.")] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="plot: the PNG file to write.")
    ] = None,
    historian_url: HistorianUrlOpt = None,
    *,
    options: StackOptions,
) -> None:
    """The historian's record of TAGs in [--from, --to]: every value with its source time and
    status, or one --aggregate per --interval; `history export --parquet FILE [TAG...]` writes
    them (no TAG: every tag), `history plot TAG... -o FILE.png` draws them."""
    now = datetime.now(UTC)
    verb = words[0] if words and words[0] in VERBS else None
    tags = words[1:] if verb else words

    def parsed() -> tuple[datetime, datetime, float | None]:
        t0, t1 = parse_time(start, now, "--from"), parse_time(end, now, "--to")
        if t0 >= t1:
            raise UsageError(f"--from {start!r} is not before --to {end!r}")
        if (aggregate is None) != (interval is None):
            raise UsageError("--aggregate and --interval go together")
        if aggregate is not None and aggregate not in AGGREGATES:
            raise UsageError(f"--aggregate {aggregate!r}: one of {', '.join(AGGREGATES)}")
        if csv_out and json_out:
            raise UsageError("--csv and --json exclude each other")
        if verb == "export" and parquet is None:
            raise UsageError("history export needs --parquet FILE")
        if verb == "plot" and output is None:
            raise UsageError("history plot needs -o FILE.png")
        if verb != "plot" and output is not None:
            raise UsageError("-o is for `history plot`")
        if verb != "export" and parquet is not None:
            raise UsageError("--parquet is for `history export`")
        if verb != "export" and not tags:
            raise UsageError("give at least one TAG (a path as `tankctl browse` shows it)")
        return t0, t1, None if interval is None else parse_span_s(interval, "--interval")

    t0, t1, interval_s = check_usage(parsed)
    stack = options.stack(historian_url=historian_url)

    async def main() -> int:
        await stack.resolve("historian")
        asked = check_tags(stack, tags) if tags else recorded_tags(stack)
        client = stack.client("historian")
        async with client:
            histories: dict[str, list[HistoryRow]] = {}
            for tag in asked:
                try:
                    histories[tag] = await read_tag_history(
                        client.client, client.idx, tag, t0, t1, aggregate=aggregate, interval_s=interval_s
                    )
                except HistoryReadError as e:
                    if verb == "export" and e.status.name == "BadNodeIdUnknown":
                        continue  # a tag the historian has not recorded: not in the file
                    raise
        if verb == "export":
            from tankctl.history_files import write_parquet

            assert parquet is not None
            n = write_parquet(histories, parquet)
            typer.echo(f"wrote {n} values of {len(histories)} tags to {parquet}")
        elif verb == "plot":
            from tankctl.history_files import plot_history

            assert output is not None
            what = f"{aggregate} per {interval}" if aggregate else "raw"
            plot_history(
                histories, output, f"{stack.site.name}: {t0:%Y-%m-%d %H:%M:%S} .. {t1:%H:%M:%S} UTC ({what})"
            )
            typer.echo(f"wrote {output}")
        else:
            out = (
                render_csv(histories)
                if csv_out
                else render_json(histories)
                if json_out
                else render_text(histories)
            )
            sys.stdout.write(out if out.endswith("\n") else out + "\n")
        return 0

    run(main)
