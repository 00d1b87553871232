"""``tankctl up``: the whole stack on one machine, with a live board or one line per event.

Lifecycle, in this order (decision record 0018):

1. **Preflight**, before anything is started or written: every port the stack will bind is free
   (checked by binding it, as the tiers will), no pid file of the run's directory names a running
   tanklab process (a stale one is replaced), the site's PKI and the CLI's login are complete
   (created on first run as :func:`tanklab_io.home.provision` does). A failure is one line and
   :class:`PreflightError`; nothing was started and no pid file was touched.
2. **Start** the plant, the PLC, the supervisor and the historian bottom-up as child processes
   (``python -m tankctl <tier>``), each in its own session (process group), logging to its own
   file, with a pid file ``<run dir>/<tier>.pid``; each must answer an OPC UA read before the
   next starts. SIGINT and SIGTERM are handled from before the first child starts: start-up is
   interrupted at once.
3. **Run** with a live board on a terminal, or one line per event when the output is piped
   (``--no-board`` too): started, a tier died (with the last error line of its log), restarted.
   A tier that dies stops the stack (exit 1) unless the site's ``stack.restart`` restarts it.
4. **Stop**, the one path for a signal, a tier's death, a start-up failure and an exception:
   SIGTERM to the PLC first (its retentive memory then still holds the running stack's modes and
   gain sources, before it could see its supervisor or plant go), then to the supervisor, the
   historian (which stores what it buffered and marks nothing: its next start marks the gap) and
   the plant (which checkpoints its state); whatever still runs after ``STOP_GRACE_S`` gets SIGKILL
   to its process group. Pid files are removed; ``up`` says what was saved and where.

With ``--clock lockstep`` the plant follows the PLC's scans (``Plant.Sim.Advance``) instead of the
wall clock and the PLC waits for the supervisor's acknowledgement of every scan: the run is
deterministic and as fast as the machine allows.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import socket
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from rich.console import Console
from rich.live import Live

from historian.store import URL_ENV
from tankctl.ports import unbindable
from tankctl.relay import Relay
from tankctl.up_board import Board
from tankctl.up_process import Tier, last_error_line, running_pid, terminate
from tanklab import paths
from tanklab.config import SiteConfig
from tanklab.errors import TanklabError
from tanklab.tags import Tag, historian_tags, plant_tags, plc_tags, supervisor_tags, tags_by_path
from tanklab_io.home import SecurityHome, default_home, provision
from tanklab_io.pki import IDENTITIES
from tanklab_io.ua_client import Link
from tanklab_io.ua_security import ClientIdentity, cli_identity, client_setup

__all__ = [
    "LocalStack",
    "PreflightError",
    "StartError",
    "StopReport",
    "StopSignals",
    "Tier",
    "last_error_line",
    "run_stack",
    "run_up",
    "running_pid",
]

TIERS = ("plant", "plc", "supervisor", "historian")
"""Every OPC UA tier ``up`` starts, bottom-up and in port order (base port + index)."""
PROCESSES = (*TIERS, "hmi")
"""Every process ``up`` starts, in start order: the tiers, then the HMI (``--hmi-port``)."""
HMI_PORT = 8080
"""The HMI's default HTTP port (``--hmi-port``)."""
READY_TIMEOUT_S = 60.0
"""How long a started tier gets to answer its first OPC UA read."""
STOP_BOUND_S = 10.0
"""The product's bound: every tier ``up`` started is gone this long after the stop began."""
PLC_FIRST_S = 4.0
"""How long the PLC alone gets to stop before the supervisor and the plant are signalled."""
STOP_GRACE_S = 8.0
"""From the first SIGTERM to SIGKILL; the rest of ``STOP_BOUND_S`` is for reaping the killed."""
REAP_S = STOP_BOUND_S - STOP_GRACE_S


class PreflightError(Exception):
    """Why ``up`` refuses to start (one line); nothing was started and no pid file touched."""


class StartError(Exception):
    """A tier died or did not answer during start-up (one line, with the reason from its log)."""


@dataclass
class StopReport:
    """What a stop did: which tiers needed SIGKILL, how long it took, what was saved."""

    killed: list[str]
    seconds: float
    lines: list[str]
    gone_at: dict[str, float] = field(default_factory=dict)
    """Per tier, seconds from the stop's start until its exit was seen."""


@dataclass
class LocalStack:
    """The tiers of a site that ``tankctl up`` runs on this machine as child processes: their
    command lines, files and lifecycle.

    Not :class:`tankctl.ops.Stack`, which is what an operator command connects to (endpoints,
    the site, one client per tier), wherever the tiers run (decision 0031).
    """

    site: SiteConfig
    config_path: Path
    base_port: int
    speed: float
    clock: Literal["realtime", "lockstep"]
    log_dir: Path
    host: str = "127.0.0.1"
    home: SecurityHome = field(default_factory=lambda: SecurityHome(default_home()))
    say: Callable[[str], None] = print
    tiers: dict[str, Tier] = field(default_factory=dict)
    identity: ClientIdentity | None = None
    hmi_port: int | None = HMI_PORT
    """The HMI's HTTP port on ``host``; None: no HMI (``--no-hmi``)."""

    def __post_init__(self) -> None:
        urls = {t: f"opc.tcp://{self.host}:{self.base_port + i}/tanklab/{t}" for i, t in enumerate(TIERS)}
        common = ["--config", str(self.config_path), "--host", self.host, "--speed", f"{self.speed:g}"]
        common += ["--home", str(self.home.root)]
        lock = ["--lockstep"] if self.clock == "lockstep" else []
        state = self.state_file
        retain = ["--retain-file", str(self.retain_file)]
        self.tiers = {
            "plant": Tier(
                "plant",
                ["plant", *common, "--port", str(self.base_port), "--state-file", str(state), *lock],
                urls["plant"],
                self.base_port,
                self.log_dir / "plant.log",
            ),
            "plc": Tier(
                "plc",
                [
                    "plc",
                    *common,
                    "--port",
                    str(self.base_port + 1),
                    "--plant-url",
                    urls["plant"],
                    *retain,
                    *lock,
                ],
                urls["plc"],
                self.base_port + 1,
                self.log_dir / "plc.log",
            ),
        }
        if self.site.supervisor is not None:
            self.tiers["supervisor"] = Tier(
                "supervisor",
                [
                    "supervisor",
                    *common,
                    "--port",
                    str(self.base_port + 2),
                    "--plc-url",
                    urls["plc"],
                    "--retain-file",
                    str(self.supervisor_retain_file),
                    *lock,
                ],
                urls["supervisor"],
                self.base_port + 2,
                self.log_dir / "supervisor.log",
            )
        below = ["--plant-url", urls["plant"], "--plc-url", urls["plc"]]
        if self.site.supervisor is not None:
            below += ["--supervisor-url", urls["supervisor"]]
        # The store: TANKLAB_HISTORIAN_URL, else the config's historian.store, else a SQLite file
        # in the run directory (var/<site>/history.db), beside the plant's state.
        store = (
            []
            if os.environ.get(URL_ENV) or self.site.historian.store
            else ["--store", str(self.history_file)]
        )
        self.tiers["historian"] = Tier(
            "historian",
            ["historian", *common, "--port", str(self.base_port + 3), *below, *store],
            urls["historian"],
            self.base_port + 3,
            self.log_dir / "historian.log",
        )
        if self.hmi_port is not None:
            shown = f"[{self.host}]" if ":" in self.host else self.host
            hmi_urls = [*below, "--historian-url", urls["historian"]]
            self.tiers["hmi"] = Tier(
                "hmi",
                [
                    "hmi",
                    "--config",
                    str(self.config_path),
                    "--host",
                    self.host,
                    "--port",
                    str(self.hmi_port),
                    "--home",
                    str(self.home.root),
                    *hmi_urls,
                ],
                f"http://{shown}:{self.hmi_port}",
                self.hmi_port,
                self.log_dir / "hmi.log",
            )

    # ---- files ----------------------------------------------------------------------------

    @property
    def state_file(self) -> Path:
        """The plant's checkpoint (levels, valves, leaks, faults, volumes) of this run directory."""
        return self.log_dir / "plant-state.json"

    @property
    def retain_file(self) -> Path:
        """The PLC's retentive memory of this run directory (like the plant's state file, it is
        the run directory's whatever the config says)."""
        return self.log_dir / "plc-retain.json"

    @property
    def supervisor_retain_file(self) -> Path:
        """The supervisor's retentive mode of this run directory."""
        return self.log_dir / "supervisor-retain.json"

    @property
    def history_file(self) -> Path:
        """The historian's SQLite store of this run directory (unless a store is configured)."""
        return self.log_dir / "history.db"

    @property
    def pid_path(self) -> Path:
        """``<log dir>/up.pid`` while this ``up`` runs: one stack per run directory."""
        return self.log_dir / "up.pid"

    def pid_files(self) -> list[Path]:
        return [self.pid_path, *(self.log_dir / f"{t}.pid" for t in PROCESSES)]

    # ---- preflight ------------------------------------------------------------------------

    def preflight(self, hosts: Sequence[str]) -> list[str]:
        """Check ports, pid files and the PKI before anything starts; return lines to print.

        Raises :class:`PreflightError` (one line) on the first problem. The PKI and the first
        user are created when missing (first run); that is the only thing written.
        """
        self.check_ports()
        self.check_pid_files()
        return self.check_security(hosts)

    def check_ports(self) -> None:
        """Bind every port the tiers will bind, as they will (SO_REUSEADDR, like asyncio)."""
        for tier in self.tiers.values():
            try:
                what = unbindable(self.host, tier.port)
            except socket.gaierror as e:
                raise PreflightError(f"--host {self.host}: {e.strerror or e}") from None
            if what:
                raise PreflightError(
                    f"port {tier.port} ({tier.name}) on {self.host} {what}; "
                    "nothing started (another stack? --base-port picks other ports)"
                )

    def check_pid_files(self) -> None:
        """Refuse when a pid file of the run directory names a running tanklab process."""
        for path in self.pid_files():
            pid = running_pid(path)
            if pid is not None:
                raise PreflightError(
                    f"{path}: pid {pid} is running: a stack already runs from {self.log_dir}; "
                    "stop it first or use another --log-dir"
                )

    def check_security(self, hosts: Sequence[str]) -> list[str]:
        """Create the PKI and the first user when missing; require a complete PKI and a login."""
        lines = []
        try:
            created = provision(self.home, hosts=hosts)
        except (OSError, TanklabError) as e:
            raise PreflightError(f"{self.home.root}: cannot set up the PKI and users: {e}") from None
        if created is not None:
            lines.append(
                f"first run: created the PKI in {self.home.pki.root} and user 'engineer' (role Engineer); "
                f"its password is in {self.home.credentials_file} (0600)"
            )
        pki = self.home.pki
        files = [pki.ca_cert, pki.ca_key]
        for name in IDENTITIES:
            files += [pki.cert_path(name), pki.key_path(name)]
        missing = [str(f.relative_to(pki.root)) for f in files if not f.is_file()]
        if missing:
            raise PreflightError(
                f"{pki.root}: the PKI is incomplete: missing {', '.join(missing)} (tankctl pki init)"
            )
        try:
            self.identity = cli_identity(self.home)
        except TanklabError as e:
            raise PreflightError(str(e)) from None
        if self.identity.credentials is None:
            raise PreflightError(
                f"no login for the board: {self.home.credentials_file} is missing and "
                "TANKLAB_USER/TANKLAB_PASSWORD are not set"
            )
        return lines

    def claim(self) -> None:
        """After the preflight: replace stale pid files, write ``up.pid`` (PreflightError when
        the run directory cannot be written)."""
        try:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            for path in self.pid_files():
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
            self.pid_path.write_text(f"{os.getpid()}\n", encoding="utf-8")
        except OSError as e:
            raise PreflightError(
                f"{self.log_dir}: cannot write the run directory: {e.strerror or e}"
            ) from None

    def discard_saved(self) -> str:
        """``--fresh``: delete the plant's checkpoint and the PLC's and the supervisor's retentive
        memory; one line."""
        gone = []
        saved = (
            ("plant state", self.state_file),
            ("PLC retentive memory", self.retain_file),
            ("supervisor mode", self.supervisor_retain_file),
        )
        for what, path in saved:
            if path.exists():
                try:
                    path.unlink()
                except OSError as e:
                    raise PreflightError(f"--fresh: cannot discard {path}: {e.strerror or e}") from None
                gone.append(f"{what} {path}")
        if not gone:
            return "fresh start from the config's initial state (there was no saved state)"
        listed = ", ".join(gone[:-1]) + " and " + gone[-1] if len(gone) > 1 else gone[0]
        return f"fresh start from the config's initial state: discarded the saved {listed}"

    # ---- start ----------------------------------------------------------------------------

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
        identity = self.identity or cli_identity(self.home)
        return Link(self.tiers[tier].url, tags, name=name, setup=client_setup(identity), timeout_s=2.0)

    async def start(self, stop: asyncio.Event) -> bool:
        """Start the tiers bottom-up; each must answer a read before the next starts.

        Returns False as soon as ``stop`` is set (the caller stops what was started). Raises
        :class:`StartError` when a tier dies or does not answer. In lock-step the PLC waits for
        the supervisor's first heartbeat, so the supervisor is started right after the PLC has
        started listening.
        """
        for name in PROCESSES:
            tier = self.tiers.get(name)
            if tier is None:
                continue
            if stop.is_set():
                return False
            await tier.start(self.env())
            if not await self.wait_ready(tier, stop):
                return False
            self.say(f"{tier.name:10s} {tier.url}   (log {tier.log_path})")
        return True

    async def wait_ready(self, tier: Tier, stop: asyncio.Event) -> bool:
        """Until ``tier`` answers a read (True) or ``stop`` is set (False)."""
        probe = asyncio.create_task(self._probe(tier))
        stopper = asyncio.create_task(stop.wait())
        try:
            await asyncio.wait({probe, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (probe, stopper):
                task.cancel()
            # A cancelled probe closes its client; bounded, for a stop must not wait on it.
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await asyncio.wait_for(asyncio.gather(probe, stopper, return_exceptions=True), 2.0)
        if probe.done() and not probe.cancelled() and probe.exception() is not None:
            raise probe.exception()  # type: ignore[misc]
        return probe.done() and not probe.cancelled()

    async def _probe(self, tier: Tier) -> None:
        """Until the tier answers: an OPC UA tier a Read of its probe path, the HMI ``GET /healthz``."""
        if tier.name == "hmi":

            async def healthy() -> bool:
                return await _healthz_ok(self.host, tier.port)

            await self._until_ready(tier, healthy, f"{tier.url}/healthz")
            return
        path = paths.PROBE_PATHS[tier.name]
        builders = {
            "plant": plant_tags,
            "plc": plc_tags,
            "supervisor": supervisor_tags,
            "historian": historian_tags,
        }
        tags = builders[tier.name](self.site)
        link = self.link(tier.name, {path: tags_by_path(tags)[path]}, tier.name)

        async def answers() -> bool:
            if await link.ensure():
                with contextlib.suppress(Exception):
                    await link.read([path])
                    return True
            return False

        try:
            await self._until_ready(tier, answers, tier.url)
        finally:
            await link.close()

    async def _until_ready(self, tier: Tier, ready: Callable[[], Awaitable[bool]], where: str) -> None:
        """Poll ``ready`` every 0.1 s until it says so; StartError when the tier exits first or
        READY_TIMEOUT_S passes (naming the tier, ``where`` it was asked, and its log)."""
        deadline = time.monotonic() + READY_TIMEOUT_S
        while True:
            if not tier.running:
                await tier.wait(1.0)
                raise StartError(
                    f"{tier.name} exited during start-up (exit {tier.exit_code}): {tier.reason()}"
                    f"; log {tier.log_path}"
                )
            if await ready():
                return
            if time.monotonic() > deadline:
                raise StartError(
                    f"{tier.name} did not answer at {where} within {READY_TIMEOUT_S:.0f} s"
                    f"; log {tier.log_path}"
                )
            await asyncio.sleep(0.1)

    # ---- run and stop ---------------------------------------------------------------------

    def dead(self) -> list[Tier]:
        """Tiers whose process has exited."""
        out = []
        for tier in self.tiers.values():
            if tier.proc is not None and tier.proc.returncode is not None:
                tier.exit_code = tier.proc.returncode
                out.append(tier)
        return out

    async def stop(self) -> StopReport:
        """Stop every tier that was started, within ``STOP_BOUND_S``; the one stop path.

        SIGTERM to the PLC, which gets ``PLC_FIRST_S`` alone; then SIGTERM to the others; at
        ``STOP_GRACE_S`` SIGKILL to every process group still there. Pid files are removed.
        """
        t0 = time.monotonic()
        stop_started = time.time()
        started = [t for t in self.tiers.values() if t.proc is not None]
        hmi = self.tiers.get("hmi")
        if hmi is not None:  # first: its users' sessions close while the tiers still answer
            hmi.signal(signal.SIGTERM)
        plc = self.tiers.get("plc")
        if plc is not None and plc.running:
            plc.signal(signal.SIGTERM)
            await plc.wait(PLC_FIRST_S)
        killed = await terminate(started, t0 + STOP_GRACE_S - time.monotonic(), REAP_S)
        lines = self.saved_lines(started, stop_started) if started else []
        gone_at = {t.name: max(0.0, t.exited_at - t0) for t in started if t.exited_at is not None}
        return StopReport(killed, time.monotonic() - t0, lines, gone_at)

    def saved_lines(self, started: list[Tier], since: float) -> list[str]:
        """One line per saved thing: the plant's state file, the PLC's retentive memory."""
        lines = []
        plant = self.tiers["plant"]
        if plant in started:
            fresh = self.state_file.exists() and self.state_file.stat().st_mtime >= since - 1.0
            if fresh and not plant.killed:
                lines.append(
                    f"saved: plant state (levels, valves, leaks, faults, volumes) to {self.state_file}"
                )
            elif self.state_file.exists():
                how = "killed" if plant.killed else f"exit {plant.exit_code}"
                lines.append(
                    f"not saved at stop: plant state (plant {how}); "
                    f"its last checkpoint is in {self.state_file}"
                )
            else:
                lines.append(f"not saved: plant state (no state file {self.state_file})")
        if self.tiers.get("plc") in started:
            if self.retain_file.exists():
                lines.append(
                    "saved: PLC retentive memory (setpoints, modes, gains, latched trips) "
                    f"in {self.retain_file}"
                )
            else:
                lines.append(f"not saved: PLC retentive memory (no file {self.retain_file})")
        if self.tiers.get("supervisor") in started:
            if self.supervisor_retain_file.exists():
                lines.append(f"saved: supervisor mode in {self.supervisor_retain_file}")
            else:
                lines.append(f"not saved: supervisor mode (no file {self.supervisor_retain_file})")
        return lines

    def release(self) -> None:
        """Remove ``up.pid`` (the tiers' pid files go in :meth:`stop`)."""
        if running_pid(self.pid_path) in (None, os.getpid()):
            with contextlib.suppress(FileNotFoundError):
                self.pid_path.unlink()


async def run_stack(
    stack: LocalStack,
    *,
    board: bool,
    stop: asyncio.Event,
    restart: bool,
    max_restarts: int,
    console: Console | None = None,
    cause: Callable[[], str] = lambda: "signal",
) -> int:
    """Start the stack, run until ``stop`` or a tier's death, stop it; return the exit code.

    Every way out (stop, death, start-up failure, exception, cancellation) goes through
    :meth:`LocalStack.stop`. ``board``: the live board (a terminal only); else one line per event.
    ``cause()`` names why ``stop`` was set (the signal).
    """
    console = console or Console(soft_wrap=True, highlight=False)
    live: Live | None = None

    def say(line: str) -> None:
        (live.console if live is not None else console).print(line, markup=False, highlight=False)

    stack.say = say
    code = 0
    why = "exception"
    view: Board | None = None
    relay: Relay | None = None
    try:
        try:
            started = await stack.start(stop)
        except StartError as e:
            say(f"tankctl: {e}")
            why, code = "start-up failed", 1
            return code
        if not started:
            why = f"{cause()} during start-up"
            return code
        pids = ", ".join(f"{t.name} {t.proc.pid}" for t in stack.tiers.values() if t.proc is not None)
        relay = Relay(
            {t.name: t.url for t in stack.tiers.values() if t.name in TIERS}, stack.home, stack.log_dir, say
        )
        try:
            await relay.start()
            served = f"command relay: {relay.path}"
        except OSError as e:  # e.g. the run directory not writable: commands connect directly
            await relay.stop()
            relay = None
            served = f"command relay not started ({e.strerror or e}); operator commands connect directly"
        say(f"started: {stack.site.name}, pids {pids}; Ctrl-C or SIGTERM stops the stack")
        say(served)
        view = Board(stack)
        show = board and console.is_terminal
        live = Live(view.render([]), console=console, refresh_per_second=2, transient=False) if show else None
        with live if live is not None else contextlib.nullcontext():
            while not stop.is_set():
                dead = stack.dead()
                if dead:
                    for tier in dead:
                        say(f"{tier.name} died (exit {tier.exit_code}): {tier.reason()}; log {tier.log_path}")
                    if restart and all(t.restarts < max_restarts for t in dead):
                        for tier in dead:
                            tier.restarts += 1
                            await tier.start(stack.env())
                            say(f"{tier.name} restarted ({tier.restarts} of {max_restarts})")
                    else:
                        if live is not None:
                            await view.refresh()
                            live.update(view.render(dead))
                        why, code = f"{', '.join(t.name for t in dead)} died", 1
                        break
                if live is not None:
                    await view.refresh()
                    live.update(view.render([]))
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), 1.0)
            else:
                why = cause()
        live = None
        return code
    finally:
        live = None
        say(f"stopping ({why})")
        if relay is not None:  # first: its sessions close while the tiers still answer
            with contextlib.suppress(Exception):
                await asyncio.wait_for(relay.stop(), 3.0)
        if view is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(view.close(), 2.0)
        report = await asyncio.shield(stack.stop())
        for line in report.lines:
            say(line)
        killed = f"; killed after {STOP_GRACE_S:g} s: {', '.join(report.killed)}" if report.killed else ""
        each = ", ".join(f"{name} {s:.1f} s" for name, s in report.gone_at.items())
        say(f"stopped in {report.seconds:.1f} s{f' ({each})' if each else ''}{killed}")
        stack.release()


class StopSignals:
    """SIGINT and SIGTERM, recorded from the moment ``up`` begins.

    :meth:`install` runs before the preflight writes anything; :func:`run_up` hands over to
    asyncio's handlers and stops at once when a signal came before. ``first`` names the first
    signal received.
    """

    def __init__(self) -> None:
        self.got: list[str] = []
        self.stop: asyncio.Event | None = None

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, _frame: self.received(signal.Signals(signum)))

    def received(self, sig: signal.Signals) -> None:
        if not self.got:
            self.got.append(sig.name)
        if self.stop is not None:
            self.stop.set()

    def first(self) -> str:
        return self.got[0] if self.got else "stop"


def run_up(
    main: Callable[[asyncio.Event, Callable[[], str]], Awaitable[int]], signals: StopSignals | None = None
) -> int:
    """Run ``main(stop, cause)`` under asyncio with SIGINT/SIGTERM setting ``stop``.

    The handlers are installed before ``main`` starts any child (and ``signals`` may have
    recorded one earlier: ``stop`` is then set from the start); ``cause()`` names the first
    signal received. Returns ``main``'s exit code.
    """
    signals = signals or StopSignals()

    async def runner() -> int:
        signals.stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, signals.received, sig)
        if signals.got:
            signals.stop.set()
        return await main(signals.stop, signals.first)

    return asyncio.run(runner())


async def _healthz_ok(host: str, port: int, timeout_s: float = 2.0) -> bool:
    """Whether ``http://HOST:PORT/healthz`` answers 200 within ``timeout_s``."""
    try:
        async with asyncio.timeout(timeout_s):
            reader, writer = await asyncio.open_connection(host, port)
            try:
                writer.write(f"GET /healthz HTTP/1.0\r\nHost: {host}:{port}\r\n\r\n".encode())
                await writer.drain()
                status = await reader.readline()
            finally:
                writer.close()
                with contextlib.suppress(Exception):
                    await writer.wait_closed()
    except (OSError, TimeoutError):
        return False
    return status.split(b" ")[1:2] == [b"200"]
