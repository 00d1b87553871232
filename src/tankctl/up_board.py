"""The live board of ``tankctl up``: levels, flows, loops and the tiers' health, one Read per
tier per refresh (:func:`tankctl.up.run_stack` draws it on a terminal)."""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from tankctl.ops.alarm_summary import SUMMARY_TIERS, summary_json, summary_paths, unacknowledged_line
from tanklab import paths
from tanklab.enums import GainSource, LoopMode, MpcStatus, SupervisorMode
from tanklab.paths import Tier as TierName
from tanklab.tags import plant_tags, plc_tags, supervisor_tags, tags_by_path

if TYPE_CHECKING:
    from tankctl.up import LocalStack
    from tankctl.up_process import Tier


_ALARM_PREFIXES = (paths.plc.alarms_prefix, paths.plc.interlocks_prefix)
"""The PLC's alarm and interlock nodes are shown on the board's alarm line when true."""


class Board:
    """Live view of the running stack: one Read per tier per refresh."""

    def __init__(self, stack: LocalStack) -> None:
        self.stack = stack
        site = stack.site
        self.tanks = site.tank_names
        self.pumps = site.pump_names
        self.loops = site.loop_names
        pt, ct = tags_by_path(plant_tags(site)), tags_by_path(plc_tags(site))
        plant, plc = paths.plant, paths.plc
        self.plant_paths = [plant.tank(t).level for t in self.tanks] + [
            plant.pump(p).flow for p in self.pumps
        ]
        self.plant_paths += [plant.tank(t).leak for t in self.tanks] + [
            plant.sim_time,
            plant.balance("Spilled"),
        ]
        self.plc_paths = [
            path
            for lp in map(plc.loop, self.loops)
            for path in (lp.sp, lp.pv, lp.mv, lp.mode, *lp.gains, lp.gain_source)
        ]
        self.plc_paths += [plc.scan, plc.io_healthy, plc.supervisor_alive, plc.overruns]
        self.plc_paths += [p for p in ct if p.startswith(_ALARM_PREFIXES) and ct[p].kind == "variable"]
        self.plc_paths += summary_paths("plc")
        self.links = {
            "plant": stack.link("plant", {p: pt[p] for p in self.plant_paths}, "board-plant"),
            "plc": stack.link("plc", {p: ct[p] for p in self.plc_paths}, "board-plc"),
        }
        if "supervisor" in stack.tiers:
            st = tags_by_path(supervisor_tags(site))
            sup = paths.supervisor
            self.sup_paths = [sup.mode, sup.mpc_status, sup.mpc_solve_time, sup.cycle, sup.plc_connected]
            self.sup_paths += summary_paths("supervisor")
            self.links["supervisor"] = stack.link(
                "supervisor", {p: st[p] for p in self.sup_paths}, "board-supervisor"
            )
        self.values: dict[str, Any] = {}
        self.reachable: dict[str, bool] = {}

    async def refresh(self) -> None:
        nodes = {"plant": self.plant_paths, "plc": self.plc_paths}
        if "supervisor" in self.links:
            nodes["supervisor"] = self.sup_paths
        for tier, link in self.links.items():
            ok = False
            if await link.ensure():
                with contextlib.suppress(Exception):
                    dvs = await link.read(nodes[tier])
                    self.values.update({p: dv.Value.Value for p, dv in zip(nodes[tier], dvs, strict=True)})
                    ok = True
            self.reachable[tier] = ok

    def render(self, dead: list[Tier]) -> Group:
        v = self.values
        site = self.stack.site
        title = f"tanklab · {site.name} · {self.stack.clock} · speed {self.stack.speed:g}"
        if paths.plant.sim_time in v:
            title += f" · t = {v[paths.plant.sim_time]:.0f} s"
        levels = Table(title=title, expand=True)
        for col in ("tank", "level [m]", "setpoint [m]", "leak"):
            levels.add_column(col)
        sp_of = {f"T{lp.pv[2:]}": paths.plc.loop(lp.name).sp for lp in site.plc.loops} if site.plc else {}
        for t in self.tanks:
            level = v.get(paths.plant.tank(t).level)
            sp = v.get(sp_of[t]) if t in sp_of else None
            bar = _bar(level, site.plant.tank(t).height_max_m)
            levels.add_row(t, f"{_f(level, 4)} {bar}", _f(sp, 3), _f(v.get(paths.plant.tank(t).leak), 2))
        loops = Table(expand=True)
        for col in ("loop", "mode", "PV [m]", "MV", "flow [m^3/s]", "Kp", "Ki", "Kd", "gains from"):
            loops.add_column(col)
        for lp in site.plc.loops if site.plc else []:
            p = paths.plc.loop(lp.name)
            mode = v.get(p.mode)
            src = v.get(p.gain_source)
            pump = site.plant.pump(lp.actuator)
            loops.add_row(
                lp.name,
                LoopMode(mode).name if mode is not None else "?",
                _f(v.get(p.pv), 4),
                f"{_g(v.get(p.mv))} {pump.unit}",
                _f(v.get(paths.plant.pump(lp.actuator).flow), 3, sci=True),
                _f(v.get(p.kp), 3, sci=True),
                _f(v.get(p.ki), 3, sci=True),
                _f(v.get(p.kd), 3, sci=True),
                GainSource(src).name if src is not None else "?",
            )
        status = Text()
        mode = v.get(paths.supervisor.mode)
        if mode is not None:
            ms = v.get(paths.supervisor.mpc_status)
            status.append(
                f"supervisor {SupervisorMode(mode).name}, MPC {MpcStatus(ms).name if ms is not None else '?'}"
            )
            solve = v.get(paths.supervisor.mpc_solve_time)
            if solve is not None:
                status.append(f" ({1e3 * solve:.2f} ms)")
        io = "ok" if v.get(paths.plc.io_healthy) else "LOST"
        status.append(f" · PLC scan {v.get(paths.plc.scan, '?')}, IO {io}")
        status.append(f", supervisor {'alive' if v.get(paths.plc.supervisor_alive) else 'not alive'}")
        alarms = [p.split(".", 2)[2] for p in self.plc_paths if p.startswith(_ALARM_PREFIXES) and v.get(p)]
        alarm_text = Text(
            "alarms: " + (", ".join(alarms) if alarms else "none"), style="bold red" if alarms else "green"
        )
        summaries: dict[TierName, dict[str, Any]] = {
            tier: summary_json(tier, v) for tier in SUMMARY_TIERS if tier in self.links
        }
        unacked = any(s["unacknowledged"] for s in summaries.values())
        flood = any(s["flood"] for s in summaries.values())
        unacked_text = Text(
            unacknowledged_line(summaries), style="bold red" if flood else "yellow" if unacked else "green"
        )
        lines: list[Any] = [levels, loops, status, alarm_text, unacked_text]
        for name, ok in self.reachable.items():
            if not ok:
                lines.append(Text(f"{name} unreachable at {self.stack.tiers[name].url}", style="bold red"))
        for tier in dead:
            lines.append(
                Text(f"{tier.name} DIED (exit {tier.exit_code}); see {tier.log_path}", style="bold red")
            )
        logs = ", ".join(str(t.log_path) for t in self.stack.tiers.values())
        lines.append(Text(f"logs: {logs} · Ctrl-C stops the stack", style="dim"))
        return Group(*lines)

    async def close(self) -> None:
        for link in self.links.values():
            await link.close()


def _f(value: Any, digits: int, *, sci: bool = False) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}e}" if sci else f"{value:.{digits}f}"


def _g(value: Any) -> str:
    return "-" if value is None else f"{value:.4g}"


def _bar(level: float | None, hmax: float, width: int = 20) -> str:
    if level is None:
        return ""
    filled = max(0, min(width, round(width * level / hmax)))
    return "█" * filled + "·" * (width - filled)
