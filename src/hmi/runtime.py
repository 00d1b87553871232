"""``tankctl hmi``'s runtime: the web app (:mod:`hmi.app`) served by uvicorn until told to stop.

The process owns the clock (the sessions' idle timeout runs on :func:`time.monotonic`) and the
sockets; a stop (SIGTERM, SIGINT: the CLI sets ``stop``) ends uvicorn's serving, closes every
WebSocket and every user's OPC UA sessions, then returns.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import socket
from collections.abc import Generator, Mapping

import uvicorn

from hmi.app import WS_MAX_BYTES, HmiState, create_app
from hmi.hub import POLL_S, UserHub
from hmi.sessions import SessionTable
from hmi.site import SiteModel
from tanklab.config import SiteConfig
from tanklab_io.home import SecurityHome

__all__ = ["run_hmi"]

log = logging.getLogger(__name__)


class _Server(uvicorn.Server):
    """uvicorn's server without its signal handlers: the CLI owns SIGINT and SIGTERM (they set
    ``stop``), and uvicorn's would re-raise the signal after its shutdown."""

    @contextlib.contextmanager
    def capture_signals(self) -> Generator[None, None, None]:
        yield


async def run_hmi(
    site: SiteConfig,
    *,
    host: str,
    port: int,
    urls: Mapping[str, str],
    home: SecurityHome,
    stop: asyncio.Event,
    ready: asyncio.Event | None = None,
    idle_timeout_s: float = 900.0,
    poll_s: float = POLL_S,
) -> None:
    """Serve the HMI of ``site`` at http://HOST:PORT until ``stop`` is set.

    ``urls``: the tiers' endpoints by tier (plant, plc, supervisor, historian); ``ready`` is set
    once the socket listens; ``poll_s`` is the poll of the live set [s] (:mod:`hmi.hub`). Raises
    OSError when the port cannot be bound.
    """
    state = HmiState(
        SiteModel.of(site),
        dict(urls),
        home,
        SessionTable(idle_timeout_s),
        hub_factory=functools.partial(UserHub, poll_s=poll_s),
    )
    config = uvicorn.Config(
        create_app(state),
        host=host,
        port=port,
        log_config=None,  # the process's logging (one line per event) is configured by the CLI
        access_log=False,
        lifespan="on",
        ws="websockets",
        ws_ping_interval=20.0,
        ws_max_size=WS_MAX_BYTES,
        timeout_graceful_shutdown=3,
    )
    # Bound here, not by uvicorn: a port in use is this OSError, not uvicorn's sys.exit.
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    server = _Server(config)
    loop = asyncio.get_running_loop()
    serving = loop.create_task(server.serve(sockets=[sock]))
    stopping = loop.create_task(stop.wait())
    try:
        while not server.started and not serving.done() and not stopping.done():
            await asyncio.wait({serving, stopping}, timeout=0.05)  # uvicorn has no "started" event
        if serving.done() and not server.started:
            serving.result()
            raise OSError(f"cannot serve on {host}:{port}")
        if ready is not None:
            ready.set()
        await asyncio.wait({serving, stopping}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        server.should_exit = True
        stopping.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await serving
        sock.close()
