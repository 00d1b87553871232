"""A fleet's hosting process: the plant, PLC and supervisor of many sites in one asyncio loop.

One process per tier per site costs about 200 MB (an interpreter with numpy, scipy, asyncua
and the MPC's solver each); the sites of a fleet share one interpreter instead, ``K`` sites per
process (decision 0057). Each site runs the tiers' own runtimes (:func:`plant_sim.runtime.run_plant`,
:func:`plc_emulator.runtime.run_plc`, :func:`supervisor.runtime.run_supervisor`): the same
servers, scan loops, deadlines and retentive memory as ``tankctl up``'s processes, started
bottom-up (each serves before the next starts) and stopped PLC first.

Isolation: every site is one task (:func:`run_site`) that owns its tiers' tasks. An exception in
one of them (a scan that raises, a port that cannot be bound) is logged, in the site's log and
the process's, with the traceback; that site's other tiers are stopped and the site is marked
``failed``; every other site goes on. Nothing of a site is shared with another except the
interpreter, the event loop and the PKI's files: a site that overruns its scan delays the loop
for the others, which is what the fleet benchmark measures (docs/benchmarks.md section 17).

Logs: records are routed by a context variable set in each site's task (asyncio copies the
context into every task and callback a site's code creates, so its servers' connection
handlers log there too) to ``<site dir>/site.log``; warnings and errors also go to the
process's stderr, prefixed with the site's name.

Status: every :data:`tankctl.fleet_layout.STATUS_PERIOD_S` the process writes
``hosts/host-<j>.json``: per site its state (starting, up, failed, stopped), error, PLC scans,
overruns and field I/O failures, and the process's RSS [bytes] and CPU [% of one core] over the
last period.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import logging
import os
import sys
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plant_sim.runtime import run_plant
from plc_emulator.runtime import PlcRunStats, run_plc
from supervisor.runtime import run_supervisor
from tankctl.fleet_layout import STATUS_PERIOD_S, FleetLayout
from tanklab.config import SiteConfig
from tanklab.config.site import Endpoint, Endpoints
from tanklab_io.persist import write_json_atomic
from tanklab_io.ua_security import ServerSecurity

log = logging.getLogger(__name__)

CURRENT_SITE: contextvars.ContextVar[int | None] = contextvars.ContextVar("tanklab_fleet_site", default=None)
"""The index of the site whose task is running (None outside every site)."""
TIER_STOP_S = 15.0
"""How long a tier of a site gets to stop once asked before its task is cancelled [s]."""
SITE_READY_S = 300.0
"""How long a tier of a site gets to serve before the site counts as failed [s]."""
STARTING_AT_ONCE = 2
"""Sites of one process that start at the same time: a server's start-up is CPU-bound (its
address space, RSA), so starting all K at once only makes each slower than its bound."""


def fleet_site(base: SiteConfig, layout: FleetLayout, i: int) -> SiteConfig:
    """Site ``i`` of the fleet: ``base`` with its own name (so its own identity) and endpoints."""
    endpoints = Endpoints(
        plant=Endpoint(host=layout.host, port=layout.port(i, "plant")),
        plc=Endpoint(host=layout.host, port=layout.port(i, "plc")),
        supervisor=Endpoint(host=layout.host, port=layout.port(i, "supervisor")),
        historian=base.endpoints.historian,
    )
    return base.model_copy(update={"name": layout.site_name(i), "endpoints": endpoints})


@dataclass
class SiteState:
    """What the hosting process knows about one of its sites."""

    index: int
    name: str
    state: str = "starting"
    error: str = ""
    plc: PlcRunStats = field(default_factory=PlcRunStats)

    def as_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "state": self.state,
            "error": self.error,
            "scans": self.plc.scans,
            "overruns": self.plc.overruns,
            "io_failures": self.plc.io_failures,
        }


class SiteLogs(logging.Handler):
    """Routes each record to the log of the site whose task emitted it (:data:`CURRENT_SITE`);
    records of no site, and warnings and errors of every site, go to ``fallback`` too."""

    def __init__(self, files: dict[int, Path], fallback: logging.Handler) -> None:
        super().__init__()
        self.handlers = {i: logging.FileHandler(path, encoding="utf-8") for i, path in files.items()}
        self.fallback = fallback
        fmt = logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s")
        for h in self.handlers.values():
            h.setFormatter(fmt)

    def emit(self, record: logging.LogRecord) -> None:
        site = CURRENT_SITE.get()
        handler = self.handlers.get(site) if site is not None else None
        if handler is not None:
            handler.handle(record)
        if handler is None or record.levelno >= logging.WARNING:
            if handler is not None:
                record = logging.makeLogRecord(record.__dict__)
                record.msg, record.args = f"site {site}: {record.getMessage()}", None
            self.fallback.handle(record)

    def close(self) -> None:
        for h in self.handlers.values():
            h.close()
        super().close()


async def _started(ready: asyncio.Event, task: asyncio.Task[Any], tier: str) -> None:
    """Until ``tier``'s ``ready`` is set; its exception (or a RuntimeError) when it ends first."""
    waiter = asyncio.ensure_future(ready.wait())
    try:
        _done, _ = await asyncio.wait(
            {waiter, task}, timeout=SITE_READY_S, return_when=asyncio.FIRST_COMPLETED
        )
    finally:
        waiter.cancel()
    if ready.is_set():
        return
    if task.done():
        task.result()  # raises the tier's exception
        raise RuntimeError(f"{tier} ended during start-up")
    raise RuntimeError(f"{tier} did not serve within {SITE_READY_S:.0f} s")


async def _stop_tier(stop: asyncio.Event, task: asyncio.Task[Any] | None) -> None:
    if task is None:
        return
    stop.set()
    try:
        await asyncio.wait_for(asyncio.shield(task), TIER_STOP_S)
    except TimeoutError:
        task.cancel()
        with contextlib.suppress(BaseException):
            await task
    except BaseException:
        pass


TierRunner = Callable[..., Coroutine[Any, Any, Any]]


@dataclass
class SiteRunners:
    """The tiers' runtimes a site runs (the real ones; a test may wrap one to make it fail)."""

    plant: TierRunner = run_plant
    plc: TierRunner = run_plc
    supervisor: TierRunner = run_supervisor


async def run_site(
    site: SiteConfig,
    layout: FleetLayout,
    state: SiteState,
    security: ServerSecurity,
    stop: asyncio.Event,
    runners: SiteRunners | None = None,
    starting: asyncio.Semaphore | None = None,
) -> None:
    """Run site ``state.index`` until ``stop`` or a failure of one of its tiers; never raises.

    Starts plant, PLC and supervisor (if the site has one) bottom-up, each serving before the
    next starts (``starting`` bounds how many sites of the process start at once); stops the
    PLC first, then the supervisor and the plant.
    """
    CURRENT_SITE.set(state.index)
    runners = runners or SiteRunners()
    i = state.index
    d = layout.site_dir(i)
    stops = {t: asyncio.Event() for t in ("plant", "plc", "supervisor")}
    tasks: dict[str, asyncio.Task[Any]] = {}
    starting = starting or asyncio.Semaphore(1)
    holding = False
    try:
        await starting.acquire()
        holding = True
        ready = asyncio.Event()
        tasks["plant"] = asyncio.create_task(
            runners.plant(
                site,
                host=layout.host,
                port=layout.port(i, "plant"),
                security=security,
                speed=layout.speed,
                stop=stops["plant"],
                state_file=d / "plant-state.json",
                ready=ready,
            )
        )
        await _started(ready, tasks["plant"], "plant")
        ready = asyncio.Event()
        tasks["plc"] = asyncio.create_task(
            runners.plc(
                site,
                host=layout.host,
                port=layout.port(i, "plc"),
                plant_url=layout.url(i, "plant"),
                security=security,
                stop=stops["plc"],
                speed=layout.speed,
                ready=ready,
                stats=state.plc,
                retain_file=d / "plc-retain.json",
            )
        )
        await _started(ready, tasks["plc"], "plc")
        if site.supervisor is not None:
            ready = asyncio.Event()
            tasks["supervisor"] = asyncio.create_task(
                runners.supervisor(
                    site,
                    host=layout.host,
                    port=layout.port(i, "supervisor"),
                    plc_url=layout.url(i, "plc"),
                    security=security,
                    stop=stops["supervisor"],
                    speed=layout.speed,
                    ready=ready,
                    retain_file=d / "supervisor-retain.json",
                )
            )
            await _started(ready, tasks["supervisor"], "supervisor")
        starting.release()
        holding = False
        state.state = "up"
        log.info("site %s up: %s", site.name, ", ".join(layout.url(i, t) for t in tasks))
        stopper = asyncio.ensure_future(stop.wait())
        try:
            await asyncio.wait({stopper, *tasks.values()}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopper.cancel()
        ended = [name for name, task in tasks.items() if task.done()]
        if ended and not stop.is_set():
            task = tasks[ended[0]]
            exc = task.exception() if not task.cancelled() else None
            raise RuntimeError(f"{ended[0]} ended: {exc!r}" if exc else f"{ended[0]} ended") from exc
    except asyncio.CancelledError:
        state.error = state.error or "cancelled"
        raise
    except Exception as e:
        # Isolation: this site stops, the others go on.
        state.state, state.error = "failed", f"{type(e).__name__}: {e}"
        log.exception("site %s failed; the other sites go on", site.name)
    finally:
        if holding:
            starting.release()
        for name in ("plc", "supervisor", "plant"):
            await _stop_tier(stops[name], tasks.get(name))
        if state.state != "failed":
            state.state = "stopped" if stop.is_set() else state.state
        log.info("site %s stopped", site.name)


def _rss_bytes() -> int:
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, ValueError, IndexError):
        return 0
    return pages * os.sysconf("SC_PAGE_SIZE")


@dataclass
class Host:
    """Hosting process ``index`` of ``layout``: its sites, its status file."""

    layout: FleetLayout
    index: int
    base: SiteConfig
    security: ServerSecurity
    runners: SiteRunners | None = None
    states: dict[int, SiteState] = field(default_factory=dict)
    cpu_percent: float = 0.0

    def __post_init__(self) -> None:
        for i in self.layout.hosted(self.index):
            self.states[i] = SiteState(i, self.layout.site_name(i))

    def status(self) -> dict[str, Any]:
        return {
            "pid": os.getpid(),
            "time": time.time(),
            "rss_bytes": _rss_bytes(),
            "cpu_percent": self.cpu_percent,
            "sites": {str(i): s.as_json() for i, s in self.states.items()},
        }

    def write_status(self) -> None:
        try:
            write_json_atomic(self.layout.host_status_file(self.index), self.status())
        except OSError as e:
            log.warning("cannot write %s: %s", self.layout.host_status_file(self.index), e)

    async def run(self, stop: asyncio.Event) -> None:
        """Run every site of this process until ``stop``; write the status file meanwhile."""
        tasks = []
        starting = asyncio.Semaphore(STARTING_AT_ONCE)
        for i in self.states:
            self.layout.site_dir(i).mkdir(parents=True, exist_ok=True)
            site = fleet_site(self.base, self.layout, i)
            # Each site's task runs in a copy of the context: CURRENT_SITE set there stays there.
            tasks.append(
                asyncio.create_task(
                    run_site(site, self.layout, self.states[i], self.security, stop, self.runners, starting),
                    name=f"site-{i}",
                    context=contextvars.copy_context(),
                )
            )
        wall, cpu = time.monotonic(), time.process_time()
        try:
            while not all(t.done() for t in tasks):
                self.write_status()
                await asyncio.wait(tasks, timeout=STATUS_PERIOD_S)
                now_wall, now_cpu = time.monotonic(), time.process_time()
                if now_wall > wall:
                    self.cpu_percent = 100.0 * (now_cpu - cpu) / (now_wall - wall)
                wall, cpu = now_wall, now_cpu
        finally:
            if not stop.is_set():  # cancelled from outside: the sites stop now
                for t in tasks:
                    t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self.write_status()


def host_logging(layout: FleetLayout, index: int) -> SiteLogs:
    """Route the process's logging: each site to its ``site.log``, warnings also to stderr."""
    fallback = logging.StreamHandler(sys.stderr)
    fallback.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    files = {i: layout.site_dir(i) / "site.log" for i in layout.hosted(index)}
    for path in files.values():
        path.parent.mkdir(parents=True, exist_ok=True)
    router = SiteLogs(files, fallback)
    root = logging.getLogger()
    root.handlers[:] = [router]
    root.setLevel(logging.INFO)
    logging.getLogger("asyncua").setLevel(logging.WARNING)
    return router
