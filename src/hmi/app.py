"""The HMI's web application: every route of the HMI contract v1 (docs/hmi.md), on Starlette.

Routes: ``GET /`` and ``/static/*`` (the front end shipped in the wheel), ``GET /healthz``,
``GET /api/session``, ``POST /api/login``, ``POST /api/logout``, ``GET /api/site``, ``GET /ws``
(WebSocket), the commands (``POST /api/write``, ``/api/loop/{loop}/manual``,
``/api/loop/{loop}/reset-gains``, ``/api/interlock/reset``, ``/api/alarms/{ack,confirm,comment,
shelve}``), ``GET /api/trend`` and ``GET /api/alarms/history``.

Security (decision 0047): the session cookie ``tanklab_hmi`` is an opaque id (HttpOnly,
SameSite=Strict, Path=/, Secure when served over https); every POST but the login carries the
session's CSRF token in ``X-CSRF-Token`` (403 otherwise); a session idle for ``idle_timeout_s``
without an open WebSocket is closed with its OPC UA sessions (:mod:`hmi.sessions`). The login is
checked by the tiers (:mod:`hmi.hub`): the app never judges a password or a role.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import math
import time
from collections.abc import AsyncIterator, Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.requests import HTTPConnection, Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from hmi.hub import QUEUE_MAX, CommandResult, LoginRefusedError, UnreachableError, UserHub
from hmi.sessions import Session, SessionTable
from hmi.site import SiteModel
from tanklab import paths
from tanklab.tags import Role
from tanklab_io.home import SecurityHome
from tanklab_io.ua_history import HistoryReadError
from tanklab_io.users import Credentials, UsersFile

__all__ = ["COOKIE", "CSRF_HEADER", "WS_MAX_BYTES", "HmiState", "create_app"]

log = logging.getLogger(__name__)

COOKIE = "tanklab_hmi"
CSRF_HEADER = "X-CSRF-Token"
STATIC_DIR = Path(__file__).parent / "static"
MAX_BODY_BYTES = 64 * 1024
"""Largest JSON body a command may have."""
WS_MAX_BYTES = 64 * 1024
"""Largest WebSocket message a client may send (the page sends subscribes of a trend's paths, a
few hundred bytes); a larger one closes the socket with 1009 (message too big), unparsed."""
WS_NOT_LOGGED_IN = 4401
WS_FOREIGN_ORIGIN = 4403
MAX_TREND_PATHS = 32
MAX_TREND_POINTS = 20_000
EXPIRE_EVERY_S = 5.0
"""How often idle sessions are looked for [s]."""
PROBE_TIMEOUT_S = 1.0


class BadRequestError(Exception):
    """A malformed request: 400 with this message."""


@dataclass
class HmiState:
    """Everything the app serves from: the site, the tiers' URLs, the security home, the
    sessions and the users' hubs. ``now`` is the sessions' clock (monotonic seconds)."""

    model: SiteModel
    urls: dict[str, str]
    home: SecurityHome
    sessions: SessionTable = field(default_factory=SessionTable)
    now: Callable[[], float] = time.monotonic
    hub_factory: Callable[[SiteModel, Mapping[str, str], SecurityHome, Credentials], UserHub] = UserHub
    hubs: dict[str, UserHub] = field(default_factory=dict)
    login_lock: asyncio.Lock = field(default_factory=asyncio.Lock)

    def role_of(self, user: str) -> str:
        """The user's login role as the users file says (shown only: the tiers enforce theirs);
        Observer when the file does not name the user."""
        try:
            record = UsersFile.load(self.home.users_file).get(user)
        except (OSError, ValueError):
            record = None
        return str(record.role) if record is not None else str(Role.OBSERVER)

    async def release(self, gone: list[Session]) -> None:
        """Close the hubs of users left without a session."""
        for s in gone:
            if not self.sessions.of_user(s.user):
                hub = self.hubs.pop(s.user, None)
                if hub is not None:
                    await hub.close()

    async def expire(self) -> None:
        await self.release(self.sessions.expire(self.now()))

    async def close(self) -> None:
        hubs, self.hubs = list(self.hubs.values()), {}
        for hub in hubs:
            await hub.close()


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def _session_body(s: Session, state: HmiState) -> dict[str, Any]:
    return {
        "user": s.user,
        "role": s.role,
        "csrf": s.csrf,
        "idle_timeout_s": state.sessions.idle_timeout_s,
    }


def create_app(state: HmiState, *, https: bool = False) -> Starlette:
    """The ASGI app serving ``state`` (``https``: the cookie gets ``Secure``)."""

    def session_of(conn: HTTPConnection) -> Session | None:
        return state.sessions.get(conn.cookies.get(COOKIE), state.now())

    def posting_session(request: Request) -> Session | Response:
        """The session of a state-changing request, or its refusal: 401 without one, 403 when
        the CSRF header is missing or wrong."""
        s = session_of(request)
        if s is None:
            return _error(401, "not logged in")
        if not state.sessions.csrf_ok(s, request.headers.get(CSRF_HEADER)):
            return _error(403, "CSRF token missing or wrong")
        return s

    def hub_of(s: Session) -> UserHub:
        hub = state.hubs.get(s.user)
        if hub is None:  # the hub went with an expired twin session: this one is gone too
            raise _GoneError
        return hub

    async def body(request: Request) -> dict[str, Any]:
        raw = await request.body()
        if len(raw) > MAX_BODY_BYTES:
            raise BadRequestError(f"body larger than {MAX_BODY_BYTES} bytes")
        try:
            data = json.loads(raw or b"{}")
        except (ValueError, UnicodeDecodeError) as e:
            raise BadRequestError(f"body is not JSON: {e}") from None
        if not isinstance(data, dict):
            raise BadRequestError("body must be a JSON object")
        return data

    def command(handler: Callable[[Request, Session, UserHub, dict[str, Any]], Any]) -> Callable[..., Any]:
        """A POST route: logged in (401), CSRF token (403), JSON body (400), tier away (503)."""

        async def endpoint(request: Request) -> Response:
            s = posting_session(request)
            if isinstance(s, Response):
                return s
            try:
                hub = hub_of(s)
                result = await handler(request, s, hub, await body(request))
            except _GoneError:
                return _error(401, "not logged in")
            except (BadRequestError, ValueError, KeyError) as e:
                return _error(400, str(e).strip("'\""))
            except UnreachableError as e:
                return _error(503, str(e))
            if isinstance(result, Response):
                return result
            assert isinstance(result, CommandResult)
            return JSONResponse(result.as_json())

        return endpoint

    # ---- static and health ----------------------------------------------------------------

    async def index(request: Request) -> Response:
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"})

    async def healthz(request: Request) -> Response:
        names = list(state.urls)
        results = await asyncio.gather(*(_tcp_probe(state.urls[t]) for t in names))
        return JSONResponse({"ok": True, "tiers": dict(zip(names, results, strict=True))})

    # ---- auth -----------------------------------------------------------------------------

    async def get_session(request: Request) -> Response:
        s = session_of(request)
        if s is None:
            return _error(401, "not logged in")
        return JSONResponse(_session_body(s, state))

    async def login(request: Request) -> Response:
        try:
            data = await body(request)
        except BadRequestError as e:
            return _error(400, str(e))
        user, password = data.get("user"), data.get("password")
        if not isinstance(user, str) or not isinstance(password, str) or not user or not password:
            return _error(400, "user and password (strings) are wanted")
        async with state.login_lock:  # one login at a time: a user's hub is opened once
            old = state.hubs.get(user)
            if old is not None and hmac.compare_digest(old.credentials.password.encode(), password.encode()):
                hub = old  # the tiers accepted this very password for the open sessions
            else:
                hub = state.hub_factory(state.model, state.urls, state.home, Credentials(user, password))
                try:
                    await hub.open()
                except LoginRefusedError as e:
                    return _error(401, str(e))
                except UnreachableError as e:
                    return _error(503, str(e))
                if old is not None:  # the password changed: the new sessions replace the old
                    await old.close()
                state.hubs[user] = hub
            s = state.sessions.open(user, state.role_of(user), state.now())
        response = JSONResponse(_session_body(s, state))
        response.set_cookie(COOKIE, s.id, httponly=True, samesite="strict", secure=https, path="/")
        return response

    async def logout(request: Request) -> Response:
        s = posting_session(request)
        if isinstance(s, Response):
            return s
        state.sessions.close(s.id)
        await state.release([s])
        response = Response(status_code=204)
        response.delete_cookie(COOKIE, path="/", httponly=True, samesite="strict", secure=https)
        return response

    async def site(request: Request) -> Response:
        if session_of(request) is None:
            return _error(401, "not logged in")
        description = dict(state.model.description)
        description["historian"] = "historian" in state.urls
        return JSONResponse(description)

    # ---- live data ------------------------------------------------------------------------

    async def ws(websocket: WebSocket) -> None:
        s = session_of(websocket)
        await websocket.accept()
        if not _same_origin(websocket):
            # Another site's page (cross-site WebSocket hijacking): SameSite=Strict already keeps
            # the cookie away from it in current browsers; this refuses it in any browser.
            await websocket.close(code=WS_FOREIGN_ORIGIN)
            return
        hub = state.hubs.get(s.user) if s is not None else None
        if s is None or hub is None:
            await websocket.close(code=WS_NOT_LOGGED_IN)
            return
        state.sessions.socket_opened(s, state.now())
        client = hub.attach()
        try:
            await websocket.send_json({"type": "hello", "user": s.user, "role": s.role})
            await hub.first_poll()
            await websocket.send_json({"type": "values", "values": hub.snapshot(client)})
            for tier, up in hub.up.items():
                if not up:
                    reason = hub.reasons.get(tier) or "no session"
                    await websocket.send_json({"type": "link", "tier": tier, "up": False, "reason": reason})
            await websocket.send_json({"type": "alarms", "alarms": hub.alarms or []})
            while not client.queue.empty():  # already sent in the snapshot
                client.queue.get_nowait()

            async def receive() -> None:
                while True:
                    frame = await websocket.receive()
                    if frame["type"] == "websocket.disconnect":
                        raise WebSocketDisconnect(frame.get("code", 1000))
                    text = frame.get("text")
                    if text is None:  # a binary frame
                        answer: dict[str, Any] | None = {"type": "error", "error": "JSON text is wanted"}
                    else:
                        answer = _client_message(hub, client, text)
                    if answer is not None:
                        await websocket.send_json(answer)

            async def send() -> None:
                while not client.dropped:
                    try:
                        message = await asyncio.wait_for(client.queue.get(), 5.0)
                    except TimeoutError:
                        if state.sessions.get(s.id, state.now()) is None:
                            return  # logged out meanwhile
                        continue
                    await websocket.send_json(message)
                if client.dropped:
                    log.warning("hmi: dropped a websocket of %s (%d messages unsent)", s.user, QUEUE_MAX)

            tasks = [asyncio.ensure_future(receive()), asyncio.ensure_future(send())]
            try:
                done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for t in tasks:
                    t.cancel()
                for t in tasks:
                    with contextlib.suppress(BaseException):
                        await t
            for t in done:
                exc = t.exception()
                if exc is not None and not isinstance(exc, WebSocketDisconnect | RuntimeError):
                    log.warning("hmi: websocket of %s ended: %r", s.user, exc)
            logged_out = state.sessions.get(s.id, state.now()) is None
            with contextlib.suppress(Exception):
                await websocket.close(
                    code=WS_NOT_LOGGED_IN if logged_out else 1011 if client.dropped else 1000
                )
        except WebSocketDisconnect:
            pass
        finally:
            hub.detach(client)
            state.sessions.socket_closed(s, state.now())

    # ---- commands -------------------------------------------------------------------------

    async def write(request: Request, s: Session, hub: UserHub, data: dict[str, Any]) -> CommandResult:
        path = data.get("path")
        if not isinstance(path, str):
            raise BadRequestError("path (a string) is wanted")
        if "value" not in data:
            raise BadRequestError("value is wanted")
        try:
            hub.model.variable(path)
        except KeyError:
            raise BadRequestError(f"{path} is not a contract path") from None
        return await hub.write(path, data["value"])

    def known_loop(hub: UserHub, name: str) -> str:
        loops = [lp.name for lp in hub.model.site.plc.loops] if hub.model.site.plc is not None else []
        if name not in loops:
            raise BadRequestError(f"unknown loop {name} (the site has {', '.join(loops) or 'none'})")
        return name

    async def manual(request: Request, s: Session, hub: UserHub, data: dict[str, Any]) -> CommandResult:
        loop = known_loop(hub, request.path_params["loop"])
        if "percent" not in data:
            raise BadRequestError("percent is wanted")
        return await hub.manual_percent(loop, data["percent"])

    async def reset_gains(request: Request, s: Session, hub: UserHub, data: dict[str, Any]) -> CommandResult:
        loop = known_loop(hub, request.path_params["loop"])
        return await hub.call("plc", paths.plc.loop(loop).reset_gains)

    async def interlock_reset(
        request: Request, s: Session, hub: UserHub, data: dict[str, Any]
    ) -> CommandResult:
        return await hub.call("plc", paths.plc.interlock_reset)

    def comment_of(data: dict[str, Any]) -> str:
        comment = data.get("comment", "")
        if not isinstance(comment, str):
            raise BadRequestError("comment must be a string")
        return comment

    def alarm_method(method: str) -> Callable[..., Any]:
        async def handler(request: Request, s: Session, hub: UserHub, data: dict[str, Any]) -> CommandResult:
            return await hub.alarm_method(data.get("id"), method, comment_of(data))

        return handler

    async def shelve(request: Request, s: Session, hub: UserHub, data: dict[str, Any]) -> CommandResult:
        return await hub.shelve(data.get("id"), data.get("kind"), data.get("duration_s"))

    # ---- history --------------------------------------------------------------------------

    def span(request: Request) -> tuple[float, float]:
        try:
            start, end = float(request.query_params["start"]), float(request.query_params["end"])
        except KeyError as e:
            raise BadRequestError(f"{e.args[0]} (epoch s) is wanted") from None
        except ValueError:
            raise BadRequestError("start and end are epoch seconds") from None
        if not (math.isfinite(start) and math.isfinite(end) and end > start):
            raise BadRequestError("start < end, both finite, are wanted")
        return start, end

    def count(request: Request, name: str, default: int, high: int) -> int:
        text = request.query_params.get(name)
        if text is None:
            return default
        try:
            n = int(text)
        except ValueError:
            raise BadRequestError(f"{name} must be an integer") from None
        if not 1 <= n <= high:
            raise BadRequestError(f"{name} must be 1..{high}")
        return n

    async def history(request: Request, reader: Callable[[UserHub], Any]) -> Response:
        s = session_of(request)
        if s is None:
            return _error(401, "not logged in")
        try:
            return JSONResponse(await reader(hub_of(s)))
        except _GoneError:
            return _error(401, "not logged in")
        except BadRequestError as e:
            return _error(400, str(e))
        except UnreachableError as e:
            return _error(503, str(e))
        except HistoryReadError as e:
            return _error(502, str(e))

    async def trend(request: Request) -> Response:
        async def read(hub: UserHub) -> dict[str, Any]:
            tags = request.query_params.getlist("path")
            if not tags or len(tags) > MAX_TREND_PATHS:
                raise BadRequestError(f"1 to {MAX_TREND_PATHS} paths are wanted")
            for t in tags:
                if t not in hub.model.tags or hub.model.tags[t].kind != "variable":
                    raise BadRequestError(f"unknown path {t}")
            start, end = span(request)
            points = count(request, "points", 2000, MAX_TREND_POINTS)
            series, aggregate = await hub.trend(tags, start, end, points)
            return {"series": series, "aggregate": aggregate}

        return await history(request, read)

    async def alarm_history(request: Request) -> Response:
        async def read(hub: UserHub) -> dict[str, Any]:
            start, end = span(request)
            limit = count(request, "limit", 500, 10_000)
            return {"events": await hub.alarm_history(start, end, limit)}

        return await history(request, read)

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        async def expire_forever() -> None:
            while True:
                await asyncio.sleep(EXPIRE_EVERY_S)
                try:
                    await state.expire()
                except Exception:
                    log.exception("hmi: expiring sessions failed")

        task = asyncio.get_running_loop().create_task(expire_forever())
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            await state.close()

    routes = [
        Route("/", index),
        Route("/healthz", healthz),
        Route("/api/session", get_session),
        Route("/api/login", login, methods=["POST"]),
        Route("/api/logout", logout, methods=["POST"]),
        Route("/api/site", site),
        WebSocketRoute("/ws", ws),
        Route("/api/write", command(write), methods=["POST"]),
        Route("/api/loop/{loop}/manual", command(manual), methods=["POST"]),
        Route("/api/loop/{loop}/reset-gains", command(reset_gains), methods=["POST"]),
        Route("/api/interlock/reset", command(interlock_reset), methods=["POST"]),
        Route("/api/alarms/ack", command(alarm_method("Acknowledge")), methods=["POST"]),
        Route("/api/alarms/confirm", command(alarm_method("Confirm")), methods=["POST"]),
        Route("/api/alarms/comment", command(alarm_method("AddComment")), methods=["POST"]),
        Route("/api/alarms/shelve", command(shelve), methods=["POST"]),
        Route("/api/trend", trend),
        Route("/api/alarms/history", alarm_history),
        Mount("/static", app=StaticFiles(directory=STATIC_DIR, check_dir=False), name="static"),
    ]
    return Starlette(routes=routes, lifespan=lifespan)


class _GoneError(Exception):
    """The session's user has no hub any more (expired meanwhile)."""


def _client_message(hub: UserHub, client: Any, text: str) -> dict[str, Any] | None:
    """The answer to one client message (None: nothing to say); malformed ones are an error
    message, never a closed socket."""
    try:
        message = json.loads(text)
    except ValueError:
        return {"type": "error", "error": "message is not JSON"}
    if not isinstance(message, dict):
        return {"type": "error", "error": "message must be a JSON object"}
    if message.get("type") != "subscribe":
        return {"type": "error", "error": f"unknown message type {message.get('type')!r}"}
    wanted = message.get("paths")
    if not isinstance(wanted, list) or not all(isinstance(p, str) for p in wanted):
        return {"type": "error", "error": "paths must be a list of strings"}
    unknown = hub.subscribe(client, wanted)
    if unknown:
        return {"type": "error", "error": f"unknown path {', '.join(unknown)}"}
    return None


def _same_origin(conn: HTTPConnection) -> bool:
    """Whether the request's ``Origin`` (sent by every browser on a WebSocket) names this server's
    own host and port; a request without one (not a browser) passes."""
    origin = conn.headers.get("origin")
    if origin is None:
        return True
    host = conn.headers.get("host", "")
    return origin.split("://", 1)[-1].rstrip("/").lower() == host.lower()


async def _tcp_probe(url: str) -> bool:
    """Whether ``opc.tcp://HOST:PORT/...`` accepts a TCP connection within a second."""
    rest = url.split("://", 1)[-1].split("/", 1)[0]
    host, _, port = rest.rpartition(":")
    try:
        _, writer = await asyncio.wait_for(
            asyncio.open_connection(host.strip("[]"), int(port)), PROBE_TIMEOUT_S
        )
    except (OSError, TimeoutError, ValueError):
        return False
    writer.close()
    with contextlib.suppress(Exception):
        await writer.wait_closed()
    return True
