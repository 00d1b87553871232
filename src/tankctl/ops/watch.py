"""``tankctl watch``: a live trend of the levels against their setpoints."""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any

import typer
from rich import box
from rich.live import Live
from rich.table import Table
from rich.text import Text

from tankctl.ops.client import TierClient
from tankctl.ops.display import num, percent_of, show, stdout_console
from tankctl.ops.errors import UnreachableError, UsageError
from tankctl.ops.options import StackOptions, stack_command
from tankctl.ops.run import StopOnSignal, check_usage, run
from tankctl.ops.stack import Stack
from tanklab import paths
from tanklab.clock import Deadlines, MonotonicClock, sleep_or_stop

TREND_SAMPLES = 60
"""Samples of each level kept for the sparkline of ``watch`` (at most this many are drawn)."""


_SPARK = "▁▂▃▄▅▆▇█"


def sparkline(values: Sequence[float], lo: float, hi: float) -> str:
    """One block character per value, scaled on [lo, hi]."""
    span = hi - lo
    out = []
    for v in values:
        k = 0 if span <= 0 else round((min(max(v, lo), hi) - lo) / span * (len(_SPARK) - 1))
        out.append(_SPARK[k])
    return "".join(out)


def level_bar(level: float | None, sp: float | None, hmax: float, width: int = 24) -> Text:
    """A bar from 0 to Hmax filled to the level, with ``|`` at the setpoint."""
    text = Text()
    filled = 0 if level is None else round(min(max(level / hmax, 0.0), 1.0) * width)
    mark = None if sp is None else min(round(sp / hmax * width), width - 1)
    for i in range(width):
        if i == mark:
            text.append("|", style="bold red")
        elif i < filled:
            text.append("█", style="blue")
        else:
            text.append("·", style="dim")
    return text


@dataclass
class _Sample:
    model_time_s: float | None
    levels: dict[str, float | None]
    loops: dict[str, dict[str, Any]]
    notes: list[str]


class _Trend:
    """Recent samples of each tank's level, and how to draw them."""

    def __init__(self, stack: Stack) -> None:
        self.stack = stack
        site = stack.site
        self.tanks = site.tank_names
        self.hmax = {t.name: t.height_max_m for t in site.plant.tanks}
        self.loop_of = {"T" + lp.pv[2:]: lp.name for lp in (site.plc.loops if site.plc else [])}
        self.history: dict[str, deque[float]] = {t: deque(maxlen=TREND_SAMPLES) for t in self.tanks}
        self.last: _Sample | None = None

    def add(self, sample: _Sample) -> None:
        self.last = sample
        for t in self.tanks:
            v = sample.levels.get(t)
            if v is not None:
                self.history[t].append(v)

    def _loop(self, tank: str) -> dict[str, Any]:
        loop = self.loop_of.get(tank)
        return self.last.loops.get(loop, {}) if self.last and loop else {}

    def table(self, width: int) -> Table:
        """The live table for a terminal ``width`` columns wide (trend and bar take the rest)."""
        s = self.last
        t_text = f"{s.model_time_s:.1f} s" if s and s.model_time_s is not None else "-"
        spare = max(width - 63, 14)  # the other columns, their padding and the edges take 63
        n_trend = min(max(int(spare * 0.6), 8), TREND_SAMPLES)
        n_bar = min(max(spare - n_trend, 6), 40)
        notes = ["levels in m, | in the bar marks the setpoint", *(s.notes if s else [])]
        table = Table(
            title=f"tanklab watch: {self.stack.site.name}   model time {t_text}   (Ctrl-C to stop)",
            title_justify="left",
            caption="; ".join(notes),
            caption_justify="left",
            box=box.SIMPLE_HEAD,
        )
        right = ("level", "SP", "error", "MV %")
        for col in ("tank", "level", "SP", "error", "trend", "0..Hmax", "mode", "MV %"):
            table.add_column(col, justify="right" if col in right else "left", no_wrap=True)
        for t in self.tanks:
            level = s.levels.get(t) if s else None
            d = self._loop(t)
            sp = d.get("sp")
            err = round(sp - level, 4) + 0.0 if isinstance(sp, float) and isinstance(level, float) else None
            hist = list(self.history[t])[-n_trend:]
            # Autoscale on the window (and the setpoint), at least 2 cm tall so noise stays flat.
            pts = hist + ([sp] if isinstance(sp, float) else [])
            lo, hi = (min(pts), max(pts)) if pts else (0.0, self.hmax[t])
            if hi - lo < 0.02:
                mid = (hi + lo) / 2
                lo, hi = mid - 0.01, mid + 0.01
            pct = d.get("mv_percent")
            loop = self.loop_of.get(t)
            table.add_row(
                t,
                num(level, "m"),
                num(sp, "m") if sp is not None else "",
                num(err, "m") if err is not None else "",
                sparkline(hist, lo, hi).ljust(n_trend),
                level_bar(level, sp if isinstance(sp, float) else None, self.hmax[t], n_bar),
                f"{loop} {d.get('mode', '')}" if loop else "",
                f"{pct:.1f}" if isinstance(pct, float) else "",
            )
        return table

    def line(self) -> str:
        """The plain form of the last sample (one line per sample when not on a terminal)."""
        s = self.last
        assert s is not None
        t_text = f"{s.model_time_s:9.1f}" if s.model_time_s is not None else "        -"
        parts = [f"t={t_text} s"]
        for t in self.tanks:
            level = s.levels.get(t)
            sp = self._loop(t).get("sp")
            part = f"{t} {num(level, 'm')}"
            if sp is not None:
                part += f"/{num(sp, 'm')}"
            parts.append(part + " m")
        return "  ".join(parts + s.notes)


class _Source:
    """A tier the watch reads every interval, reconnecting (one attempt per interval) if lost."""

    def __init__(self, client: TierClient, paths: list[str]) -> None:
        self.client = client
        self.paths = paths
        self.up = False
        self.reason = ""

    async def read(self) -> dict[str, Any] | None:
        try:
            if not self.up:
                await self.client.connect()
                self.up = True
            return await self.client.read(self.paths)
        except UnreachableError as e:
            self.up = False
            self.reason = e.reason
            await self.client.close()
            return None


async def _sample(trend: _Trend, plant: _Source, plc: _Source | None) -> _Sample:
    stack = trend.stack
    pv, cv = await asyncio.gather(plant.read(), plc.read() if plc else _none())
    notes = []
    levels: dict[str, float | None] = dict.fromkeys(trend.tanks)
    model_time = None
    if pv is None:
        notes.append(f"plant unreachable ({plant.reason}), retrying")
    else:
        levels = {t: pv[paths.plant.tank(t).level] for t in trend.tanks}
        model_time = pv[paths.plant.sim_time]
    loops: dict[str, dict[str, Any]] = {}
    if plc is not None and cv is None:
        notes.append(f"plc unreachable ({plc.reason}), retrying")
    elif cv is not None:
        tags = stack.tags("plc")
        for name in stack.site.loop_names:
            p = paths.plc.loop(name)
            loops[name] = {
                "sp": cv[p.sp],
                "mode": show(tags[p.mode], cv[p.mode]),
                "mv_percent": percent_of(cv[p.mv], tags[p.mv].eu_range),
            }
        if pv is None:  # the plant is away: show the levels the PLC last read
            levels = {t: cv.get(paths.plc.io(t).pv) for t in trend.tanks}
    return _Sample(model_time, levels, loops, notes)


async def _none() -> None:
    return None


@stack_command
def watch(
    interval: Annotated[float, typer.Option(help="Wall seconds between refreshes.")] = 1.0,
    duration: Annotated[float | None, typer.Option(help="Stop after this many wall seconds.")] = None,
    *,
    options: StackOptions,
) -> None:
    """Live trend of the levels against their setpoints until Ctrl-C (exit 0) or --duration.

    On a terminal: a table redrawn in place (sparkline of the recent levels, a bar from 0 to
    Hmax with the setpoint marked, the numbers). Otherwise: one line per refresh.
    """
    stack = options.stack()

    def check() -> None:
        if not (math.isfinite(interval) and interval > 0):
            raise UsageError(f"--interval must be a positive number of seconds, got {interval:g}")
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            raise UsageError(f"--duration must be a positive number of seconds, got {duration:g}")

    check_usage(check)

    async def main() -> int:
        await stack.resolve("plant", "plc")
        site = stack.site
        plant = _Source(
            stack.client("plant"),
            [paths.plant.sim_time] + [paths.plant.tank(t).level for t in site.tank_names],
        )
        plc = None
        if stack.has("plc"):
            loops = [paths.plc.loop(n) for n in site.loop_names]
            nodes = [path for lp in loops for path in (lp.sp, lp.mv, lp.mode)]
            plc = _Source(stack.client("plc"), nodes + [paths.plc.io(t).pv for t in site.tank_names])
        # Both tiers must answer at the start; later losses are shown and retried.
        for src in (plant, plc):
            if src is not None:
                await src.client.connect()
                src.up = True
        trend = _Trend(stack)
        console = stdout_console()
        clock = MonotonicClock()
        start = clock.now()
        end = start + duration if duration is not None else math.inf
        deadlines = Deadlines(period_s=interval, next_deadline=start)
        try:
            with StopOnSignal() as stop:
                live = Live(console=console, auto_refresh=False) if console.is_terminal else None
                with live or contextlib.nullcontext():
                    while not stop.is_set():
                        trend.add(await _sample(trend, plant, plc))
                        if live is not None:
                            live.update(trend.table(console.width), refresh=True)
                        else:
                            console.print(Text(trend.line()))
                        now = clock.now()
                        if now >= end:
                            break
                        await sleep_or_stop(clock, min(deadlines.finished(now), end), stop)
        finally:
            for src in (plant, plc):
                if src is not None:
                    await src.client.close()
        return 0

    run(main)
