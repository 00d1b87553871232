"""The live board of ``tankctl up``: levels, flows, loops and the tiers' health, one Read per
tier per refresh (:func:`tankctl.up.run_stack` draws it on a terminal)."""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from tanklab.enums import GainSource, LoopMode, MpcStatus, SupervisorMode
from tanklab.tags import plant_tags, plc_tags, supervisor_tags, tags_by_path

if TYPE_CHECKING:
    from tankctl.up import LocalStack
    from tankctl.up_process import Tier


class Board:
    """Live view of the running stack: one Read per tier per refresh."""

    def __init__(self, stack: LocalStack) -> None:
        self.stack = stack
        site = stack.site
        self.tanks = site.tank_names
        self.pumps = site.pump_names
        self.loops = site.loop_names
        pt, ct = tags_by_path(plant_tags(site)), tags_by_path(plc_tags(site))
        self.plant_paths = [f"Plant.{t}.Level" for t in self.tanks] + [f"Plant.{p}.Flow" for p in self.pumps]
        self.plant_paths += [f"Plant.{t}.Leak" for t in self.tanks] + [
            "Plant.Sim.Time",
            "Plant.Balance.Spilled",
        ]
        items = ("SP", "PV", "MV", "Mode", "Kp", "Ki", "Kd", "GainSource")
        self.plc_paths = [f"PLC.{lp}.{i}" for lp in self.loops for i in items]
        self.plc_paths += [
            "PLC.Status.Scan",
            "PLC.Status.IoHealthy",
            "PLC.Supervisor.Alive",
            "PLC.Status.Overruns",
        ]
        self.plc_paths += [
            p for p in ct if p.startswith(("PLC.Alarms.", "PLC.Interlock.")) and ct[p].kind == "variable"
        ]
        self.links = {
            "plant": stack.link("plant", {p: pt[p] for p in self.plant_paths}, "board-plant"),
            "plc": stack.link("plc", {p: ct[p] for p in self.plc_paths}, "board-plc"),
        }
        if "supervisor" in stack.tiers:
            st = tags_by_path(supervisor_tags(site))
            self.sup_paths = [
                "Supervisor.Mode",
                "Supervisor.MPC.Status",
                "Supervisor.MPC.SolveTime",
                "Supervisor.Cycle",
                "Supervisor.PlcConnected",
            ]
            self.links["supervisor"] = stack.link(
                "supervisor", {p: st[p] for p in self.sup_paths}, "board-supervisor"
            )
        self.values: dict[str, Any] = {}
        self.reachable: dict[str, bool] = {}

    async def refresh(self) -> None:
        paths = {"plant": self.plant_paths, "plc": self.plc_paths}
        if "supervisor" in self.links:
            paths["supervisor"] = self.sup_paths
        for tier, link in self.links.items():
            ok = False
            if await link.ensure():
                with contextlib.suppress(Exception):
                    dvs = await link.read(paths[tier])
                    self.values.update({p: dv.Value.Value for p, dv in zip(paths[tier], dvs, strict=True)})
                    ok = True
            self.reachable[tier] = ok

    def render(self, dead: list[Tier]) -> Group:
        v = self.values
        site = self.stack.site
        title = f"tanklab · {site.name} · {self.stack.clock} · speed {self.stack.speed:g}"
        if "Plant.Sim.Time" in v:
            title += f" · t = {v['Plant.Sim.Time']:.0f} s"
        levels = Table(title=title, expand=True)
        for col in ("tank", "level [m]", "setpoint [m]", "leak"):
            levels.add_column(col)
        sp_of = {f"T{lp.pv[2:]}": f"PLC.{lp.name}.SP" for lp in site.plc.loops} if site.plc else {}
        for t in self.tanks:
            level = v.get(f"Plant.{t}.Level")
            sp = v.get(sp_of[t]) if t in sp_of else None
            bar = _bar(level, site.plant.tank(t).height_max_m)
            levels.add_row(t, f"{_f(level, 4)} {bar}", _f(sp, 3), _f(v.get(f"Plant.{t}.Leak"), 2))
        loops = Table(expand=True)
        for col in ("loop", "mode", "PV [m]", "MV", "flow [m^3/s]", "Kp", "Ki", "Kd", "gains from"):
            loops.add_column(col)
        for lp in site.plc.loops if site.plc else []:
            p = f"PLC.{lp.name}"
            mode = v.get(f"{p}.Mode")
            src = v.get(f"{p}.GainSource")
            pump = site.plant.pump(lp.actuator)
            loops.add_row(
                lp.name,
                LoopMode(mode).name if mode is not None else "?",
                _f(v.get(f"{p}.PV"), 4),
                f"{_g(v.get(f'{p}.MV'))} {pump.unit}",
                _f(v.get(f"Plant.{lp.actuator}.Flow"), 3, sci=True),
                _f(v.get(f"{p}.Kp"), 3, sci=True),
                _f(v.get(f"{p}.Ki"), 3, sci=True),
                _f(v.get(f"{p}.Kd"), 3, sci=True),
                GainSource(src).name if src is not None else "?",
            )
        status = Text()
        mode = v.get("Supervisor.Mode")
        if mode is not None:
            ms = v.get("Supervisor.MPC.Status")
            status.append(
                f"supervisor {SupervisorMode(mode).name}, MPC {MpcStatus(ms).name if ms is not None else '?'}"
            )
            solve = v.get("Supervisor.MPC.SolveTime")
            if solve is not None:
                status.append(f" ({1e3 * solve:.2f} ms)")
        io = "ok" if v.get("PLC.Status.IoHealthy") else "LOST"
        status.append(f" · PLC scan {v.get('PLC.Status.Scan', '?')}, IO {io}")
        status.append(f", supervisor {'alive' if v.get('PLC.Supervisor.Alive') else 'not alive'}")
        alarms = [
            p.split(".", 2)[2]
            for p in self.plc_paths
            if p.startswith(("PLC.Alarms.", "PLC.Interlock.")) and v.get(p)
        ]
        alarm_text = Text(
            "alarms: " + (", ".join(alarms) if alarms else "none"), style="bold red" if alarms else "green"
        )
        lines: list[Any] = [levels, loops, status, alarm_text]
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
