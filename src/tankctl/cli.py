"""``tankctl``: the command line of tanklab (composition root).

Every command validates its input at the edge and turns a failure into one line on stderr
and a non-zero exit code (2 for bad usage, a bad config or an unreachable endpoint, 1 for a
refused operation); nothing prints a traceback. ``asyncio.run`` is called only here.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import os
import signal
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ClassVar

import typer
from typer._click import Command, Context

from tankctl.entry import imports_done
from tankctl.lazy import Lazy, LazyGroup
from tankctl.ops import COMMANDS as OPERATOR_COMMANDS
from tanklab.errors import TanklabError

if TYPE_CHECKING:
    from tanklab.config import SiteConfig
    from tanklab_io.ua_security import ServerSecurity


class TankctlGroup(LazyGroup):
    """The ``tankctl`` group: the commands defined in other modules are imported when used
    (:mod:`tankctl.lazy`, decision 0039); ``order`` is the order ``--help`` lists them in."""

    lazy: ClassVar[dict[str, Lazy]] = {
        **{
            name: Lazy(f"tankctl.ops.{module}", func, one_line_usage=True)
            for name, (module, func) in OPERATOR_COMMANDS.items()
        },
        "history": Lazy("tankctl.history_cli", "history_command", one_line_usage=True),
        "simulate": Lazy("tankctl.simulate_cli", "simulate_command"),
        "compare": Lazy("tankctl.simulate_cli", "compare_command"),
        "sweep": Lazy("tankctl.sweep_cli", "sweep_command"),
        "tune": Lazy("tankctl.tune_cli", "app", group=True),
        "scenario": Lazy("tankctl.scenario_cli", "scenario_app", group=True),
        "pki": Lazy("tankctl.security_cli", "pki_app", group=True),
        "user": Lazy("tankctl.security_cli", "user_app", group=True),
        "k8s": Lazy("tankctl.k8s_cli", "k8s_app", group=True),
        "fleet": Lazy("tankctl.fleet_cli", "fleet_app", group=True),
    }
    order: ClassVar[tuple[str, ...]] = (
        *OPERATOR_COMMANDS,
        "history",
        "simulate",
        "compare",
        "sweep",
        "linearize",
        "plant",
        "plc",
        "supervisor",
        "historian",
        "hmi",
        "up",
        "config",
        "tune",
        "scenario",
        "pki",
        "user",
        "k8s",
        "docs",
        "fleet",
    )

    def resolve_command(self, ctx: Context, args: list[str]) -> tuple[str | None, Command | None, list[str]]:
        """The command to run, imported; then the garbage collector is on again
        (:func:`tankctl.entry.imports_done`)."""
        try:
            return super().resolve_command(ctx, args)
        finally:
            imports_done()


app = typer.Typer(
    name="tankctl",
    help="tanklab: a two-tier SCADA/PLC emulation over OPC UA for liquid-level control.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    cls=TankctlGroup,
)
config_app = typer.Typer(help="Validate site configs and print their schema.", no_args_is_help=True)
docs_app = typer.Typer(help="Generate documentation from the code.", no_args_is_help=True)
app.add_typer(config_app, name="config")
app.add_typer(docs_app, name="docs")

ConfigOpt = Annotated[
    Path | None,
    typer.Option("--config", "-c", help="Site YAML file (env TANKLAB_CONFIG; default: the Energies sim)."),
]
HostOpt = Annotated[str | None, typer.Option(help="Address to bind (env TANKLAB_HOST; default 127.0.0.1).")]
HomeOpt = Annotated[
    Path | None,
    typer.Option(
        help="Security home: PKI, users file, credentials (env TANKLAB_HOME; default ~/.config/tanklab)."
    ),
]
AuditOpt = Annotated[
    Path | None, typer.Option(help="Where the audit log goes (env TANKLAB_AUDIT_DIR; default HOME/audit).")
]


def server_security(home: Path | None, audit_dir: Path | None) -> ServerSecurity:
    """A tier's security settings from its options, their environment twins and the defaults."""
    from tanklab_io.home import SecurityHome, default_home
    from tanklab_io.ua_security import ServerSecurity

    audit = audit_dir or (Path(v) if (v := _env("TANKLAB_AUDIT_DIR")) else None)
    return ServerSecurity(SecurityHome(home or default_home()), audit)


SpeedOpt = Annotated[
    float | None, typer.Option(help="Model seconds per wall second (env TANKLAB_SPEED; default 1).")
]


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print one line to stderr and return the Exit to raise."""
    typer.echo(f"tankctl: {message}", err=True)
    return typer.Exit(code)


def _env(name: str) -> str | None:
    value = os.environ.get(name)
    return value if value else None


def resolve_config(path: Path | None) -> Path:
    """--config, else TANKLAB_CONFIG, else the default site."""
    if path is not None:
        return path
    env = _env("TANKLAB_CONFIG")
    return Path(env) if env else Path("configs/three_tank_energies_sim.yaml")


def resolve_speed(speed: float | None) -> float:
    """--speed, else TANKLAB_SPEED, else 1; must be a positive number."""
    if speed is None:
        env = _env("TANKLAB_SPEED")
        try:
            speed = float(env) if env else 1.0
        except ValueError:
            raise fail(f"TANKLAB_SPEED must be a number, got {env!r}") from None
    if not (speed > 0 and math.isfinite(speed)):
        raise fail(f"--speed must be a positive number, got {speed}")
    return speed


def load(path: Path) -> SiteConfig:
    """Load a site config with environment endpoint overrides; errors become one line."""
    try:
        from tanklab.config import load_site

        return load_site(path, env=os.environ)
    except TanklabError as e:
        raise fail(str(e)) from None


def setup_logging(level: int = logging.INFO) -> None:
    """One line per event: time, level, logger, message. asyncua's chatter is kept to warnings."""
    logging.basicConfig(
        level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    logging.getLogger("asyncua").setLevel(logging.WARNING)


def run_until_signal(main: Any) -> None:
    """Run ``main(stop_event)`` under asyncio; SIGINT and SIGTERM set the event."""

    async def runner() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await main(stop)

    asyncio.run(runner())


# --------------------------------------------------------------------------------------------
# config
# --------------------------------------------------------------------------------------------


@config_app.command("check")
def config_check(file: Annotated[Path, typer.Argument(help="Site YAML file to validate.")]) -> None:
    """Validate a site config: prints a summary, or one line naming file, field and rule."""
    site = load(file)
    parts = [
        f"{len(site.plant.tanks)} tanks",
        f"{len(site.plant.pumps)} pumps",
        f"{len(site.plant.valves)} valves",
    ]
    if site.plc:
        parts.append(f"{len(site.plc.loops)} loops")
    if site.supervisor:
        parts.append(f"supervisor {site.supervisor.mode}")
    typer.echo(f"{file}: ok ({site.name}: {', '.join(parts)})")


@config_app.command("schema")
def config_schema() -> None:
    """Print the JSON schema of a site config file."""
    from tanklab.config import site_schema

    typer.echo(json.dumps(site_schema(), indent=2, sort_keys=True))


@docs_app.command("address-space")
def docs_address_space(config: ConfigOpt = None) -> None:
    """Print docs/address-space.md (the contract's node table for the site)."""
    from tanklab.tags import render_markdown

    typer.echo(render_markdown(load(resolve_config(config))), nl=False)
    typer.echo("")


# --------------------------------------------------------------------------------------------
# linearize
# --------------------------------------------------------------------------------------------


@app.command()
def linearize(
    config: Annotated[Path, typer.Argument(help="Site YAML file.")],
    ts: Annotated[
        float | None, typer.Option("--ts", help="Sample time [s] for ZOH; omit: continuous.")
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print JSON (keys A, B, C, D, ts, operating_point).")
    ] = False,
) -> None:
    """Linearize the plant at its operating point: A, B, C, D w.r.t. the pump flows [m^3/s]."""
    import numpy as np

    from plant_sim.linearize import linearize as lin
    from plant_sim.linearize import operating_point
    from plant_sim.models import TankNetwork, default_inputs
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()

    if ts is not None and not (ts > 0 and np.isfinite(ts)):
        raise fail(f"--ts must be a positive number of seconds, got {ts}")
    site = load(config)
    net = TankNetwork.from_config(site.plant)
    u = default_inputs(net, site.plant)
    try:
        op = operating_point(net, site.plant, u)
    except ValueError as e:
        raise fail(f"{config}: plant.operating_point: {e}") from None
    model = lin(net, op.levels_m, op.flows_m3_s, u, ts)
    result = {
        "A": model.A.tolist(),
        "B": model.B.tolist(),
        "C": model.C.tolist(),
        "D": model.D.tolist(),
        "ts": ts,
        "states": list(model.state_names),
        "inputs": list(model.input_names),
        "operating_point": {
            "levels_m": op.levels_m.tolist(),
            "flows_m3_s": op.flows_m3_s.tolist(),
            "equilibrium_levels_m": op.equilibrium_levels_m.tolist(),
            "pump_commands": op.commands.tolist(),
            "note": site.plant.operating_point.note,
        },
    }
    if as_json:
        typer.echo(json.dumps(result, indent=2))
        return
    kind = f"discrete, ZOH, Ts = {ts:g} s" if ts else "continuous"
    typer.echo(
        f"{site.name}: linear model ({kind}), states {model.state_names}, inputs {model.input_names} [m^3/s]"
    )
    typer.echo(
        f"operating point: levels {np.round(op.levels_m, 5).tolist()} m, flows {op.flows_m3_s.tolist()} m^3/s"
    )
    with np.printoptions(precision=6, suppress=False, linewidth=120):
        for name in ("A", "B", "C", "D"):
            typer.echo(f"{name} =\n{getattr(model, name)}")


# --------------------------------------------------------------------------------------------
# tier processes
# --------------------------------------------------------------------------------------------


def _port(port: int | None, default: int) -> int:
    env_port = _env("TANKLAB_PORT")
    try:
        value = port if port is not None else int(env_port) if env_port else default
    except ValueError:
        raise fail(f"TANKLAB_PORT must be a port number, got {env_port!r}") from None
    if not 1 <= value <= 65535:
        raise fail(f"--port must be 1..65535, got {value}")
    return value


def _url(flag: str | None, env: str, default: str) -> str:
    from tanklab.config import parse_endpoint_url

    url = flag or _env(env) or default
    try:
        parse_endpoint_url(url)
    except ValueError as e:
        raise fail(f"{env.lower().removeprefix('tanklab_').replace('_', '-')}: {e}") from None
    return url


def serve(tier: str, banner: str, runner: Any) -> None:
    """Run a tier's ``runner(stop, ready)`` until SIGINT/SIGTERM; print ``banner`` when it serves."""
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()  # a tier computes every scan: one BLAS thread (tanklab_io.threads)
    setup_logging()

    async def main(stop: asyncio.Event) -> None:
        ready = asyncio.Event()
        task = asyncio.create_task(runner(stop, ready))
        waiter = asyncio.create_task(ready.wait())
        await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
        if ready.is_set():
            typer.echo(banner)
            sys.stdout.flush()
        else:
            waiter.cancel()
        await task

    try:
        run_until_signal(main)
    except OSError as e:
        raise fail(f"{tier}: cannot serve: {e.strerror or e}") from None
    except TanklabError as e:
        raise fail(f"{tier}: {e}") from None


@app.command()
def plant(
    config: ConfigOpt = None,
    host: HostOpt = None,
    port: Annotated[int | None, typer.Option(help="TCP port (env TANKLAB_PORT; default 4840).")] = None,
    speed: SpeedOpt = None,
    lockstep: Annotated[
        bool, typer.Option(help="Advance only through Plant.Sim.Advance (driven by the PLC).")
    ] = False,
    state_file: Annotated[Path | None, typer.Option(help="Checkpoint file (default: the config's).")] = None,
    home: HomeOpt = None,
    audit_dir: AuditOpt = None,
) -> None:
    """Serve the plant simulator at opc.tcp://HOST:PORT/tanklab/plant."""
    from plant_sim.runtime import run_plant

    site = load(resolve_config(config))
    bind = host or _env("TANKLAB_HOST") or "127.0.0.1"
    p = _port(port, site.endpoints.plant.port)
    spd = resolve_speed(speed)

    async def runner(stop: asyncio.Event, ready: asyncio.Event) -> None:
        await run_plant(
            site,
            host=bind,
            port=p,
            security=server_security(home, audit_dir),
            speed=spd,
            lockstep=lockstep,
            stop=stop,
            state_file=state_file,
            ready=ready,
        )

    serve("plant", f"plant: {site.name} at opc.tcp://{bind}:{p}/tanklab/plant (speed {spd:g})", runner)


@app.command()
def plc(
    config: ConfigOpt = None,
    plant_url: Annotated[str | None, typer.Option(help="Plant endpoint (env TANKLAB_PLANT_URL).")] = None,
    host: HostOpt = None,
    port: Annotated[int | None, typer.Option(help="TCP port (env TANKLAB_PORT; default 4841).")] = None,
    speed: SpeedOpt = None,
    lockstep: Annotated[
        bool, typer.Option(help="Advance the plant one scan at a time (Plant.Sim.Advance).")
    ] = False,
    trace: Annotated[
        Path | None, typer.Option(help="CSV file getting one line per scan (a small historian).")
    ] = None,
    retain_file: Annotated[
        Path | None,
        typer.Option(
            help="Retentive memory file (default: the config's plc.retain_file); warm restart if it exists."
        ),
    ] = None,
    cold: Annotated[
        bool,
        typer.Option("--cold", help="Start from the config, not from the retentive memory (cold start)."),
    ] = False,
    home: HomeOpt = None,
    audit_dir: AuditOpt = None,
) -> None:
    """Serve the soft PLC at opc.tcp://HOST:PORT/tanklab/plc, scanning against the plant.

    With a retentive memory file that exists, the PLC warm-restarts (setpoints, modes, gains,
    latched trips, scan counter and model time; outputs resumed from the plant's pumps);
    --cold starts from the config.
    """
    from plc_emulator.runtime import run_plc

    site = load(resolve_config(config))
    if site.plc is None:
        raise fail(f"{resolve_config(config)}: plc: the site has no PLC program")
    bind = host or _env("TANKLAB_HOST") or "127.0.0.1"
    p = _port(port, site.endpoints.plc.port)
    spd = resolve_speed(speed)
    below = _url(plant_url, "TANKLAB_PLANT_URL", site.endpoints.plant.url("plant"))

    async def runner(stop: asyncio.Event, ready: asyncio.Event) -> None:
        await run_plc(
            site,
            host=bind,
            port=p,
            plant_url=below,
            security=server_security(home, audit_dir),
            stop=stop,
            speed=spd,
            lockstep=lockstep,
            ready=ready,
            trace=trace,
            retain_file=retain_file,
            cold=cold,
        )

    serve(
        "plc", f"plc: {site.name} at opc.tcp://{bind}:{p}/tanklab/plc (plant {below}, speed {spd:g})", runner
    )


@app.command()
def supervisor(
    config: ConfigOpt = None,
    plc_url: Annotated[str | None, typer.Option(help="PLC endpoint (env TANKLAB_PLC_URL).")] = None,
    host: HostOpt = None,
    port: Annotated[int | None, typer.Option(help="TCP port (env TANKLAB_PORT; default 4842).")] = None,
    speed: SpeedOpt = None,
    lockstep: Annotated[bool, typer.Option(help="Acknowledge every PLC scan as fast as possible.")] = False,
    trace: Annotated[
        Path | None, typer.Option(help="CSV file getting one line per MPC sample (scan, time, plan).")
    ] = None,
    retain_file: Annotated[
        Path | None,
        typer.Option(
            help="Retentive mode and alarm states: written on every change, restored on start "
            "(default: none)."
        ),
    ] = None,
    home: HomeOpt = None,
    audit_dir: AuditOpt = None,
    controller: Annotated[
        str | None,
        typer.Option(
            help="Supervisory controller package.module:Class (default: the site's "
            "supervisor.controller, else the shipped MPC and adaptive PID)."
        ),
    ] = None,
) -> None:
    """Serve the supervisor at opc.tcp://HOST:PORT/tanklab/supervisor, supervising the PLC."""
    from supervisor.controller import build_controller
    from supervisor.runtime import run_supervisor
    from tanklab.errors import ControllerError

    site = load(resolve_config(config))
    if site.supervisor is None:
        raise fail(f"{resolve_config(config)}: supervisor: the site has no supervisor section")
    try:  # a controller that cannot be loaded is a one-line error before anything is served
        ctl = build_controller(site, controller)
    except ControllerError as e:
        raise fail(str(e) if controller else f"{resolve_config(config)}: {e}") from None
    bind = host or _env("TANKLAB_HOST") or "127.0.0.1"
    p = _port(port, site.endpoints.supervisor.port)
    spd = resolve_speed(speed)
    below = _url(plc_url, "TANKLAB_PLC_URL", site.endpoints.plc.url("plc"))

    async def runner(stop: asyncio.Event, ready: asyncio.Event) -> None:
        await run_supervisor(
            site,
            host=bind,
            port=p,
            plc_url=below,
            security=server_security(home, audit_dir),
            stop=stop,
            speed=spd,
            lockstep=lockstep,
            ready=ready,
            trace=trace,
            retain_file=retain_file,
            controller=ctl,
        )

    serve(
        "supervisor",
        f"supervisor: {site.name} at opc.tcp://{bind}:{p}/tanklab/supervisor (plc {below}, speed {spd:g})",
        runner,
    )


@app.command()
def historian(
    config: ConfigOpt = None,
    plant_url: Annotated[str | None, typer.Option(help="Plant endpoint (env TANKLAB_PLANT_URL).")] = None,
    plc_url: Annotated[str | None, typer.Option(help="PLC endpoint (env TANKLAB_PLC_URL).")] = None,
    supervisor_url: Annotated[
        str | None, typer.Option(help="Supervisor endpoint (env TANKLAB_SUPERVISOR_URL).")
    ] = None,
    host: HostOpt = None,
    port: Annotated[int | None, typer.Option(help="TCP port (env TANKLAB_PORT; default 4843).")] = None,
    speed: SpeedOpt = None,
    store: Annotated[
        str | None,
        typer.Option(
            help="Store: a postgresql:// URL or a SQLite file (env TANKLAB_HISTORIAN_URL; default the "
            "config's historian.store, else var/<site>/history.db)."
        ),
    ] = None,
    home: HomeOpt = None,
    audit_dir: AuditOpt = None,
) -> None:
    """Serve the historian at opc.tcp://HOST:PORT/tanklab/historian, recording every tier.

    Subscribes to every recorded node and to the events of the plant, the PLC and the supervisor,
    marks a gap (a BadNoCommunication sample per tag) when a tier stops publishing, and writes
    through a bounded buffer to its store (SQLite by default, PostgreSQL by URL)."""
    from historian.runtime import default_store, run_historian
    from historian.store import store_location
    from tanklab.paths import SourceTier

    site = load(resolve_config(config))
    bind = host or _env("TANKLAB_HOST") or "127.0.0.1"
    p = _port(port, site.endpoints.historian.port)
    spd = resolve_speed(speed)
    urls: dict[SourceTier, str] = {
        "plant": _url(plant_url, "TANKLAB_PLANT_URL", site.endpoints.plant.url("plant")),
    }
    if site.plc is not None:
        urls["plc"] = _url(plc_url, "TANKLAB_PLC_URL", site.endpoints.plc.url("plc"))
    if site.supervisor is not None:
        urls["supervisor"] = _url(
            supervisor_url, "TANKLAB_SUPERVISOR_URL", site.endpoints.supervisor.url("supervisor")
        )
    location = store or store_location(Path(site.historian.store or default_store(site)))

    async def runner(stop: asyncio.Event, ready: asyncio.Event) -> None:
        await run_historian(
            site,
            host=bind,
            port=p,
            urls=urls,
            store=location,
            security=server_security(home, audit_dir),
            stop=stop,
            speed=spd,
            ready=ready,
        )

    shown = location.split("@")[-1] if "://" in location else location
    serve(
        "historian",
        f"historian: {site.name} at opc.tcp://{bind}:{p}/tanklab/historian (store {shown}, speed {spd:g})",
        runner,
    )


@app.command()
def hmi(
    config: ConfigOpt = None,
    host: Annotated[
        str | None, typer.Option(help="Address to bind (env TANKLAB_HMI_HOST; default 127.0.0.1).")
    ] = None,
    port: Annotated[int | None, typer.Option(help="HTTP port (env TANKLAB_HMI_PORT; default 8080).")] = None,
    base_port: Annotated[
        int | None,
        typer.Option(help="The tiers at ports N..N+3 on 127.0.0.1 (env TANKLAB_BASE_PORT)."),
    ] = None,
    plant_url: Annotated[str | None, typer.Option(help="Plant endpoint (env TANKLAB_PLANT_URL).")] = None,
    plc_url: Annotated[str | None, typer.Option(help="PLC endpoint (env TANKLAB_PLC_URL).")] = None,
    supervisor_url: Annotated[
        str | None, typer.Option(help="Supervisor endpoint (env TANKLAB_SUPERVISOR_URL).")
    ] = None,
    historian_url: Annotated[
        str | None, typer.Option(help="Historian endpoint (env TANKLAB_HISTORIAN_ENDPOINT).")
    ] = None,
    no_historian: Annotated[
        bool, typer.Option("--no-historian", help="No historian: no trends from history.")
    ] = False,
    idle_timeout: Annotated[
        float, typer.Option(help="Seconds after which an idle login session is closed.")
    ] = 900.0,
    poll_interval: Annotated[
        float,
        typer.Option(help="Seconds between two Reads of the live set per tier (0.05 .. 0.5)."),
    ] = 0.1,
    home: HomeOpt = None,
) -> None:
    """Serve the browser HMI at http://HOST:PORT (docs/hmi.md): mimic, faceplates, trends, alarms.

    Each user logs in with their own tanklab account: the HMI opens that user's own OPC UA
    sessions to the tiers (with the CLI certificate of the security home), so the tiers check the
    password, enforce the role and audit the user. Loopback by default."""
    from tankctl.ops.errors import UsageError
    from tankctl.ops.stack import resolve_endpoints
    from tanklab_io.home import SecurityHome, default_home

    site = load(resolve_config(config))
    bind = host or _env("TANKLAB_HMI_HOST") or "127.0.0.1"
    env_port = _env("TANKLAB_HMI_PORT")
    try:
        p = port if port is not None else int(env_port) if env_port else 8080
    except ValueError:
        raise fail(f"TANKLAB_HMI_PORT must be a port number, got {env_port!r}") from None
    if not 1 <= p <= 65535:
        raise fail(f"--port must be 1..65535, got {p}")
    if not idle_timeout > 0:
        raise fail(f"--idle-timeout must be > 0, got {idle_timeout}")
    if not 0.05 <= poll_interval <= 0.5:
        raise fail(f"--poll-interval must be 0.05 .. 0.5 s, got {poll_interval}")
    if site.plc is None:
        raise fail("the HMI needs a site with a PLC program (plc section)")
    try:
        endpoints = resolve_endpoints(
            site,
            urls={
                "plant": plant_url,
                "plc": plc_url,
                "supervisor": supervisor_url,
                "historian": historian_url,
            },
            env=os.environ,
            base_port=base_port,
        )
    except UsageError as e:
        raise fail(str(e)) from None
    urls: dict[str, str] = {str(tier): url for tier, url in endpoints.items()}
    if site.supervisor is None:
        urls.pop("supervisor", None)
    if no_historian:
        urls.pop("historian", None)
    security = SecurityHome(home or default_home())

    async def runner(stop: asyncio.Event, ready: asyncio.Event) -> None:
        from hmi.runtime import run_hmi

        await run_hmi(
            site,
            host=bind,
            port=p,
            urls=urls,
            home=security,
            stop=stop,
            ready=ready,
            idle_timeout_s=idle_timeout,
            poll_s=poll_interval,
        )

    shown = f"[{bind}]" if ":" in bind else bind
    serve("hmi", f"hmi: {site.name} at http://{shown}:{p} (plc {urls['plc']})", runner)


@app.command()
def up(
    config: ConfigOpt = None,
    speed: SpeedOpt = None,
    base_port: Annotated[
        int, typer.Option(help="Ports N, N+1, N+2, N+3 for plant, PLC, supervisor, historian.")
    ] = 4840,
    clock: Annotated[
        str, typer.Option(help="realtime (wall clock x speed) or lockstep (as fast as possible).")
    ] = "realtime",
    board: Annotated[
        bool, typer.Option(help="The live board on a terminal (piped or --no-board: one line per event).")
    ] = True,
    log_dir: Annotated[
        Path, typer.Option(help="Where the tiers' logs and the plant's state file go.")
    ] = Path("var"),
    host: Annotated[str, typer.Option(help="Address the tiers bind and are reached at.")] = "127.0.0.1",
    home: HomeOpt = None,
    hmi_port: Annotated[
        int, typer.Option(help="The browser HMI's HTTP port on --host (http://HOST:PORT).")
    ] = 8080,
    no_hmi: Annotated[bool, typer.Option("--no-hmi", help="Do not start the browser HMI.")] = False,
    fresh: Annotated[
        bool,
        typer.Option(
            help="Start from the config's initial state: discard the plant's saved state and the "
            "PLC's retentive memory."
        ),
    ] = False,
) -> None:
    """Start plant, PLC, supervisor, historian and the browser HMI as child processes and show a live board.

    Before starting anything it checks that every port is free, that no stack runs from the
    same log directory and that the PKI is complete; on first use it creates the PKI and an
    engineer account whose random password goes to the home's 0600 credentials file, which the
    operator commands read by default. Piped output (or --no-board) gives one line per event.
    SIGINT/SIGTERM stop every tier within 10 s, at any moment, and ``up`` says what was saved."""
    from tankctl.up import LocalStack, PreflightError, StopSignals, run_stack, run_up
    from tanklab_io.home import SecurityHome, default_home

    # From here on a signal stops `up` through its one stop path, never halfway through a step.
    signals = StopSignals()
    signals.install()
    path = resolve_config(config)
    site = load(path)
    if site.plc is None:
        raise fail(f"{path}: plc: `tankctl up` needs a PLC program")
    if clock not in ("realtime", "lockstep"):
        raise fail(f"--clock must be realtime or lockstep, got {clock!r}")
    if not 1 <= base_port <= 65532:
        raise fail(f"--base-port must be 1..65532, got {base_port}")
    if not 1 <= hmi_port <= 65535:
        raise fail(f"--hmi-port must be 1..65535, got {hmi_port}")
    if not no_hmi and base_port <= hmi_port <= base_port + 3:
        raise fail(f"--hmi-port {hmi_port} is one of the tiers' ports {base_port}..{base_port + 3}")
    spd = resolve_speed(speed)
    stack = LocalStack(
        site,
        path,
        base_port,
        spd,
        "lockstep" if clock == "lockstep" else "realtime",
        log_dir / site.name,
        host=host,
        home=SecurityHome(home or default_home()),
        hmi_port=None if no_hmi else hmi_port,
    )
    try:
        notes = stack.preflight(sorted({"localhost", "127.0.0.1", host, socket.gethostname()}))
        stack.claim()
        if fresh:
            notes.append(stack.discard_saved())
    except PreflightError as e:
        stack.release()  # an up.pid it wrote (never a running stack's)
        raise fail(str(e)) from None
    for line in notes:
        typer.echo(line)
    # The board is an OPC UA client; its reconnect chatter (and that of the start-up probes)
    # must not scroll over the board or the event lines.
    logging.getLogger("asyncua").setLevel(logging.CRITICAL)
    logging.getLogger("tanklab_io.ua_client").setLevel(logging.ERROR)

    async def main(stop: asyncio.Event, cause: Any) -> int:
        return await run_stack(
            stack,
            board=board,
            stop=stop,
            restart=site.stack.restart,
            max_restarts=site.stack.max_restarts,
            cause=cause,
        )

    try:
        code = run_up(main, signals)
    finally:
        stack.release()
    raise typer.Exit(code)


def main() -> None:
    """Console-script entry point.

    Operator commands import only what they use (docs/decisions/0023-lazy-cli-imports.md): the
    commands that compute (the tiers, ``linearize``, ``simulate``, ``compare``) import numpy and
    scipy and limit BLAS to one thread themselves (``tanklab_io.threads``).
    """
    try:
        app()
    except KeyboardInterrupt:
        sys.exit(130)
