"""``tankctl up``: the whole stack on one machine, with a live board.

Starts the plant, the PLC and the supervisor as child processes (``python -m tankctl <tier>``)
on ports N, N+1, N+2, each logging to its own file, waits until each answers an OPC UA read,
prints the three endpoints and shows a live board (rich) until Ctrl-C or SIGTERM, which stop all
three cleanly (supervisor first, plant last). If a tier dies, the board says so and ``up`` stops
the others and exits 1, or restarts the tier when the site's ``stack.restart`` asks for it.

With ``--clock lockstep`` the plant follows the PLC's scans (``Plant.Sim.Advance``) instead of the
wall clock and the PLC waits for the supervisor's acknowledgement of every scan: the run is
deterministic and as fast as the machine allows.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from tanklab.config import SiteConfig
from tanklab.enums import GainSource, LoopMode, MpcStatus, SupervisorMode
from tanklab.home import SecurityHome, default_home
from tanklab.tags import Tag, plant_tags, plc_tags, supervisor_tags, tags_by_path
from tanklab.ua import Link
from tanklab.ua_security import cli_identity, client_setup

TIERS = ("plant", "plc", "supervisor")
READY_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 15.0


@dataclass
class Tier:
    """One child process of the stack."""

    name: str
    args: list[str]
    url: str
    log_path: Path
    proc: asyncio.subprocess.Process | None = None
    restarts: int = 0
    exit_code: int | None = None
    log_file: Any = None

    async def start(self, env: dict[str, str]) -> None:
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self.log_file = self.log_path.open("ab")
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "tankctl",
            *self.args,
            stdout=asyncio.subprocess.DEVNULL,
            stderr=self.log_file,
            env=env,
            start_new_session=True,
        )
        self.exit_code = None
        # The pid file lets an operator (or a test) signal exactly this tier.
        self.pid_path.write_text(f"{self.proc.pid}\n", encoding="utf-8")

    @property
    def pid_path(self) -> Path:
        """``<log dir>/<tier>.pid`` while the tier runs."""
        return self.log_path.with_suffix(".pid")

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.returncode is None

    async def stop(self) -> None:
        if self.proc is not None and self.proc.returncode is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(self.proc.wait(), STOP_TIMEOUT_S)
            except TimeoutError:
                self.proc.kill()
                await self.proc.wait()
        if self.log_file is not None:
            self.log_file.close()
            self.log_file = None


@dataclass
class Stack:
    """The three tiers of a site."""

    site: SiteConfig
    config_path: Path
    base_port: int
    speed: float
    clock: Literal["realtime", "lockstep"]
    log_dir: Path
    host: str = "127.0.0.1"
    home: SecurityHome = field(default_factory=lambda: SecurityHome(default_home()))
    tiers: dict[str, Tier] = field(default_factory=dict)

    def __post_init__(self) -> None:
        urls = {t: f"opc.tcp://{self.host}:{self.base_port + i}/tanklab/{t}" for i, t in enumerate(TIERS)}
        common = ["--config", str(self.config_path), "--host", self.host, "--speed", f"{self.speed:g}"]
        common += ["--home", str(self.home.root)]
        lock = ["--lockstep"] if self.clock == "lockstep" else []
        state = self.log_dir / "plant-state.json"
        self.tiers = {
            "plant": Tier(
                "plant",
                ["plant", *common, "--port", str(self.base_port), "--state-file", str(state), *lock],
                urls["plant"],
                self.log_dir / "plant.log",
            ),
            "plc": Tier(
                "plc",
                ["plc", *common, "--port", str(self.base_port + 1), "--plant-url", urls["plant"], *lock],
                urls["plc"],
                self.log_dir / "plc.log",
            ),
        }
        if self.site.supervisor is not None:
            self.tiers["supervisor"] = Tier(
                "supervisor",
                ["supervisor", *common, "--port", str(self.base_port + 2), "--plc-url", urls["plc"], *lock],
                urls["supervisor"],
                self.log_dir / "supervisor.log",
            )

    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        for var in (
            "TANKLAB_PLANT_URL",
            "TANKLAB_PLC_URL",
            "TANKLAB_SUPERVISOR_URL",
            "TANKLAB_PORT",
            "TANKLAB_HOST",
            "TANKLAB_SPEED",
            "TANKLAB_CONFIG",
        ):
            env.pop(var, None)
        return env

    def link(self, tier: str, tags: dict[str, Tag], name: str) -> Link:
        """A reconnecting client of ``tier`` as the CLI (the board and the start-up checks)."""
        return Link(
            self.tiers[tier].url, tags, name=name, setup=client_setup(cli_identity(self.home)), timeout_s=2.0
        )

    async def start(self) -> None:
        """Start the tiers bottom-up; each must answer a read before the next starts.

        In lock-step the PLC waits for the supervisor's first heartbeat, so the supervisor is
        started right after the PLC has started listening.
        """
        for name in TIERS:
            tier = self.tiers.get(name)
            if tier is None:
                continue
            await tier.start(self.env())
            await self.wait_ready(tier)

    async def wait_ready(self, tier: Tier) -> None:
        path = {"plant": "Plant.Sim.Time", "plc": "PLC.Status.Scan", "supervisor": "Supervisor.Mode"}[
            tier.name
        ]
        tags = {"plant": plant_tags, "plc": plc_tags, "supervisor": supervisor_tags}[tier.name](self.site)
        link = self.link(tier.name, {path: tags_by_path(tags)[path]}, tier.name)
        deadline = time.monotonic() + READY_TIMEOUT_S
        try:
            while True:
                if not tier.running:
                    raise RuntimeError(f"{tier.name} exited during start-up (see {tier.log_path})")
                if await link.ensure():
                    with contextlib.suppress(Exception):
                        await link.read([path])
                        return
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        f"{tier.name} did not answer at {tier.url} within {READY_TIMEOUT_S:.0f} s"
                    )
                await asyncio.sleep(0.1)
        finally:
            await link.close()

    async def stop(self) -> None:
        for name in reversed(TIERS):
            tier = self.tiers.get(name)
            if tier is not None:
                await tier.stop()

    def dead(self) -> list[Tier]:
        """Tiers whose process has exited."""
        out = []
        for tier in self.tiers.values():
            if tier.proc is not None and tier.proc.returncode is not None:
                tier.exit_code = tier.proc.returncode
                out.append(tier)
        return out


class Board:
    """Live view of the running stack: one Read per tier per refresh."""

    def __init__(self, stack: Stack) -> None:
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


async def run_stack(
    stack: Stack, *, board: bool, stop: asyncio.Event, restart: bool, max_restarts: int
) -> int:
    """Start the stack, show the board until ``stop`` or a tier death; return the exit code."""
    console = Console()
    try:
        await stack.start()
    except RuntimeError as e:
        await stack.stop()
        console.print(f"tankctl: {e}", style="bold red", highlight=False)
        return 1
    for tier in stack.tiers.values():
        console.print(f"{tier.name:10s} {tier.url}   (log {tier.log_path})", highlight=False)
    view = Board(stack)
    code = 0
    try:
        live = (
            Live(view.render([]), console=console, refresh_per_second=2, transient=False) if board else None
        )
        with live if live is not None else contextlib.nullcontext():
            while not stop.is_set():
                dead = stack.dead()
                if dead:
                    if restart and all(t.restarts < max_restarts for t in dead):
                        for tier in dead:
                            tier.restarts += 1
                            await tier.stop()
                            await tier.start(stack.env())
                    else:
                        await view.refresh()
                        if live is not None:
                            live.update(view.render(dead))
                        else:
                            for tier in dead:
                                console.print(
                                    f"tankctl: {tier.name} died (exit {tier.exit_code}); see {tier.log_path}"
                                )
                        code = 1
                        break
                if live is not None:
                    await view.refresh()
                    live.update(view.render([]))
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), 1.0)
    finally:
        await view.close()
        await stack.stop()
    return code
