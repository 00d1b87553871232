"""``tankctl fleet``: up, status and down of a fleet of live sites (decision 0057).

Imported when a ``fleet`` command runs (decision 0039); each command imports what it needs in
its body, so ``fleet status`` and ``fleet down`` never import the tiers' numerics.
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Annotated, Any

import typer

from tankctl.cli import ConfigOpt, HomeOpt, SpeedOpt, fail, load, resolve_config, resolve_speed

fleet_app = typer.Typer(
    help="Fleets of live sites: many independent plant/PLC/supervisor sites, many per process.",
    no_args_is_help=True,
)

DEFAULT_BASE_PORT = 5000
DEFAULT_PER_PROCESS = 25
"""Sites per hosting process by default: the measured choice (docs/benchmarks.md section 17)."""
FleetDirOpt = Annotated[
    Path, typer.Option(help="The fleet's directory: layout, pid files, per-site state and logs.")
]
DEFAULT_FLEET_DIR = Path("var/fleet")


@fleet_app.command("up")
def fleet_up(
    sites: Annotated[int, typer.Option(help="How many independent sites (N >= 1).")] = 3,
    config: ConfigOpt = None,
    base_port: Annotated[
        int, typer.Option(help="Site i serves plant, PLC, supervisor on P+3i, P+3i+1, P+3i+2.")
    ] = DEFAULT_BASE_PORT,
    sites_per_process: Annotated[
        int, typer.Option(help="Sites hosted by one process (one asyncio loop); K >= 1.")
    ] = DEFAULT_PER_PROCESS,
    fleet_dir: FleetDirOpt = DEFAULT_FLEET_DIR,
    speed: SpeedOpt = None,
    host: Annotated[str, typer.Option(help="Address the sites bind and are reached at.")] = "127.0.0.1",
    home: HomeOpt = None,
) -> None:
    """Run N sites in the foreground (Ctrl-C or SIGTERM stops them all; `fleet down` from another shell).

    Before starting anything it checks the options, that every one of the 3 N ports is free,
    that no fleet runs from the directory and that the PKI (one for the fleet) is complete,
    creating it on first use. Prints one line per hosting process once its sites serve, then
    one line per event."""
    from tankctl.fleet import Fleet, hosts_for_pki, run_fleet
    from tankctl.fleet_layout import FleetError, FleetLayout
    from tankctl.up import StopSignals, run_up
    from tanklab_io.home import SecurityHome, default_home

    signals = StopSignals()  # a signal from here on stops through the one stop path
    signals.install()
    path = resolve_config(config)
    site = load(path)
    if site.plc is None:
        raise fail(f"{path}: plc: a fleet's sites need a PLC program")
    spd = resolve_speed(speed)
    root = (home or default_home()).resolve()
    try:
        layout = FleetLayout(
            fleet_dir=fleet_dir.resolve(),
            config_path=path.resolve(),
            sites=sites,
            base_port=base_port,
            per_process=sites_per_process,
            speed=spd,
            host=host,
            home=root,
            base_name=site.name,
        )
        fleet = Fleet(layout, SecurityHome(root), say=typer.echo)
        notes = fleet.preflight(hosts_for_pki(host))
        fleet.claim()
    except FleetError as e:
        raise fail(str(e)) from None
    for line in notes:
        typer.echo(line)

    async def main(stop: asyncio.Event, cause: Any) -> int:
        return await run_fleet(fleet, stop, cause)

    try:
        code = run_up(main, signals)
    finally:
        fleet.release()
    raise typer.Exit(code)


@fleet_app.command("status")
def fleet_status(
    fleet_dir: FleetDirOpt = DEFAULT_FLEET_DIR,
    each: Annotated[
        bool, typer.Option("--each", help="One line per site (else only sites not well).")
    ] = False,
    probe: Annotated[
        bool, typer.Option(help="Read every site's plant, PLC and supervisor over OPC UA (reachability).")
    ] = True,
    timeout: Annotated[float, typer.Option(help="Per read [s].")] = 5.0,
) -> None:
    """Summarise a fleet: processes (RSS, CPU), sites up and reachable, PLC overruns.

    Exit 0 when every site is up and answers, 1 otherwise, 2 when there is no fleet."""
    from tankctl.fleet import probe_fleet, status_lines
    from tankctl.fleet_layout import FleetError, FleetLayout
    from tanklab_io.home import SecurityHome, default_home

    try:
        layout = FleetLayout.load(fleet_dir.resolve())
    except FleetError as e:
        raise fail(str(e)) from None
    reach = None
    if probe:
        logging.getLogger("asyncua").setLevel(logging.CRITICAL)
        logging.getLogger("tanklab_io.ua_client").setLevel(logging.CRITICAL)
        home = SecurityHome(layout.home or default_home())
        reach = asyncio.run(probe_fleet(layout, home, timeout))
    lines, ok = status_lines(layout, reach, each)
    for line in lines:
        typer.echo(line)
    raise typer.Exit(0 if ok else 1)


@fleet_app.command("down")
def fleet_down(fleet_dir: FleetDirOpt = DEFAULT_FLEET_DIR) -> None:
    """Stop every process of the fleet (SIGTERM to `fleet up`, then to any hosting process left)."""
    from tankctl import fleet
    from tankctl.fleet_layout import FleetError, FleetLayout

    try:
        layout = FleetLayout.load(fleet_dir.resolve())
    except FleetError as e:
        raise fail(str(e)) from None
    left = asyncio.run(fleet.fleet_down(layout, typer.echo))
    if left:
        raise fail(f"{left} processes of the fleet are still running")


@fleet_app.command("host", hidden=True)
def fleet_host(
    fleet_dir: FleetDirOpt,
    index: Annotated[int, typer.Option(help="Which hosting process of the layout.")],
    base_port: Annotated[int, typer.Option(help="The fleet's base port (names the fleet).")] = 0,
) -> None:
    """One hosting process of a fleet (started by `fleet up`)."""
    from tankctl.cli import run_until_signal, server_security
    from tankctl.fleet_host import Host, host_logging
    from tankctl.fleet_layout import FleetError, FleetLayout
    from tanklab_io.threads import limit_blas_threads

    limit_blas_threads()
    try:
        layout = FleetLayout.load(fleet_dir)
    except FleetError as e:
        raise fail(str(e)) from None
    if base_port and base_port != layout.base_port:
        raise fail(f"--base-port {base_port} is not the fleet's ({layout.base_port})")
    if not 0 <= index < layout.processes:
        raise fail(f"--index must be 0..{layout.processes - 1}, got {index}")
    site = load(layout.config_path)
    router = host_logging(layout, index)
    host = Host(layout, index, site, server_security(layout.home, None))

    async def main(stop: asyncio.Event) -> None:
        await host.run(stop)

    try:
        run_until_signal(main)
    finally:
        router.close()
