"""The machinery of the pytest plugin's ``tanklab_stack``: a site's real tiers and clients of them.

:func:`running_stack` starts the plant, the PLC and (when the site has one) the supervisor, and
optionally the historian, as ``python -m tankctl`` processes on consecutive free loopback ports
(a :class:`~tankctl.testing.stack.Stack`, the same one the repository's own tests use), secured
by a security home with one user per login role (:func:`~tankctl.testing.logins.provision_users`),
and yields a :class:`RunningStack`. Everything it started is stopped when the ``with`` block is
left, on every path; should the interpreter end without leaving it (an interrupted run), an
``atexit`` hook SIGKILLs, by id, the tier processes still running.

Two clocks (:data:`CLOCKS`):

``lockstep``
    Every tier runs with ``--lockstep``: the PLC calls ``Plant.Sim.Advance(Ts, commands)`` once
    per scan and waits (bounded) for the supervisor's acknowledgement, so model time runs as fast
    as the processes can go and a run is repeatable. The default.
``realtime``
    Every tier follows its wall clock times ``speed`` (model seconds per wall second).

Clients address nodes by tag path (``PLC.LIC1.SP``): :class:`TagSession` (async, in the caller's
event loop: :meth:`RunningStack.connect`) and :class:`TagClient` (sync, the same session run in
the stack's own event loop: :meth:`RunningStack.client`). A write is typed from the tag contract
(:mod:`tanklab.tags`); a refused write raises :class:`StackError` naming the path and the status.
:meth:`TagSession.advance` waits (bounded) until the PLC's model time ``PLC.Status.ModelTime``
has moved on by the given model seconds.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import signal
from collections.abc import AsyncIterator, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from asyncua import Client, ua

from tankctl.testing.logins import LOGIN_ROLES, Logins, session
from tankctl.testing.procs import free_base_port
from tankctl.testing.stack import TIERS, UP_TIMEOUT_S, Stack
from tankctl.testing.waits import hang_bound, wait_until
from tanklab.config import SiteConfig
from tanklab.paths import plc as plc_paths
from tanklab.tags import Tag, all_tags
from tanklab_io.ua_client import namespace_index, read_values, write_value

__all__ = [
    "CLOCKS",
    "Clock",
    "RunningStack",
    "StackError",
    "StackOptions",
    "TagClient",
    "TagSession",
    "running_stack",
]

Clock = Literal["lockstep", "realtime"]
CLOCKS: tuple[Clock, ...] = ("lockstep", "realtime")
"""How model time runs in a stack: as fast as possible in lock-step, or the wall clock x speed."""
ADVANCE_BOUND_S = 120.0
"""Hang bound of :meth:`TagSession.advance` on an idle machine [s of wall time] (stretched with
the load, :func:`~tankctl.testing.waits.hang_bound`)."""
CLIENT_TIMEOUT_S = 10.0
"""Request timeout of the clients [s]."""


class StackError(RuntimeError):
    """A stack's option, a tag path or a refused request (one line naming the problem)."""


@dataclass(frozen=True)
class StackOptions:
    """How a stack runs: its clock, the speed of a realtime one (None: the tiers' default 1),
    whether the historian runs too, and the login role clients act as by default."""

    clock: Clock = "lockstep"
    speed: float | None = None
    historian: bool = False
    role: str = "operator"

    def __post_init__(self) -> None:
        if self.clock not in CLOCKS:
            raise StackError(f"tanklab_stack: clock must be one of {', '.join(CLOCKS)}, got {self.clock!r}")
        if self.speed is not None and not self.speed > 0:
            raise StackError(f"tanklab_stack: speed must be a positive number, got {self.speed!r}")
        if self.speed is not None and self.clock == "lockstep":
            raise StackError(
                "tanklab_stack: speed is for clock='realtime' (lock-step runs as fast as it can)"
            )
        if self.role not in LOGIN_ROLES:
            raise StackError(
                f"tanklab_stack: role must be one of {', '.join(LOGIN_ROLES)}, got {self.role!r}"
            )


class TagSession:
    """An authenticated session on one tier, by tag path (async, in the caller's event loop)."""

    def __init__(self, client: Client, tier: str, tags: dict[str, Tag], ns: int) -> None:
        self.client = client
        """The connected asyncua client, for what the façade does not cover."""
        self.tier = tier
        self._tags = tags
        self._ns = ns

    def _tag(self, path: str) -> Tag:
        tag = self._tags.get(path)
        if tag is None:
            raise StackError(f"tanklab_stack: {self.tier} has no tag {path!r}")
        return tag

    def node(self, path: str) -> Any:
        """The asyncua node of tag ``path``."""
        self._tag(path)
        return self.client.get_node(ua.NodeId(path, self._ns))

    async def read(self, path: str) -> Any:
        """The value of tag ``path``."""
        return (await self.read_many([path]))[path]

    async def read_many(self, paths: Sequence[str]) -> dict[str, Any]:
        """The values of ``paths`` in one Read (values of the same instant)."""
        return dict(zip(paths, await read_values(self.client, [self.node(p) for p in paths]), strict=True))

    async def write(self, path: str, value: Any) -> None:
        """Write ``value`` with the tag's data type; :class:`StackError` when it is refused."""
        status = await write_value(self.node(path), self._tag(path), value)
        if not status.is_good():
            raise StackError(f"tanklab_stack: write {path} = {value!r} refused: {status.name}")

    async def call(self, path: str, *args: Any) -> Any:
        """Call method ``path`` (``PLC.LIC1.SetGains``) on its object with ``args``."""
        if self._tag(path).kind != "method":
            raise StackError(f"tanklab_stack: {path} is not a method")
        parent = self.client.get_node(ua.NodeId(path.rsplit(".", 1)[0], self._ns))
        return await parent.call_method(ua.NodeId(path, self._ns), *args)

    async def advance(self, model_s: float) -> float:
        """Wait until the PLC's model time has moved on by ``model_s`` model seconds (bounded);
        the model time then [s]. Works on a PLC session only."""
        if self.tier != "plc":
            raise StackError(f"tanklab_stack: advance needs a PLC session, not {self.tier}")
        if not model_s >= 0:
            raise StackError(f"tanklab_stack: advance by {model_s!r}: must be >= 0 model seconds")
        target = float(await self.read(plc_paths.model_time)) + model_s
        now = target - model_s

        async def reached() -> bool:
            nonlocal now
            now = float(await self.read(plc_paths.model_time))
            return now >= target

        try:
            await wait_until(reached, ADVANCE_BOUND_S, what=f"PLC model time {target:g} s", poll_s=0.01)
        except AssertionError as e:
            raise StackError(f"tanklab_stack: model time {now:g} s did not reach {target:g} s ({e})") from e
        return now


class TagClient:
    """The synchronous form of a :class:`TagSession`: each call runs in the stack's event loop."""

    def __init__(self, stack: Stack, inner: TagSession) -> None:
        self._stack = stack
        self.session = inner

    @property
    def tier(self) -> str:
        return self.session.tier

    def read(self, path: str) -> Any:
        """The value of tag ``path``."""
        return self._stack.run_sync(self.session.read(path), CLIENT_TIMEOUT_S * 2)

    def read_many(self, paths: Sequence[str]) -> dict[str, Any]:
        """The values of ``paths`` in one Read."""
        return self._stack.run_sync(self.session.read_many(paths), CLIENT_TIMEOUT_S * 2)

    def write(self, path: str, value: Any) -> None:
        """Write ``value`` with the tag's type; :class:`StackError` when it is refused."""
        self._stack.run_sync(self.session.write(path, value), CLIENT_TIMEOUT_S * 2)

    def call(self, path: str, *args: Any) -> Any:
        """Call method ``path`` with ``args``."""
        return self._stack.run_sync(self.session.call(path, *args), CLIENT_TIMEOUT_S * 2)

    def advance(self, model_s: float) -> float:
        """Wait until the PLC's model time has moved on by ``model_s`` [s]; the model time then."""
        return self._stack.run_sync(self.session.advance(model_s), hang_bound(ADVANCE_BOUND_S) + 30.0)


@dataclass
class RunningStack:
    """A site's tiers serving on loopback, and clients of them (see the module docstring)."""

    site: SiteConfig
    config: Path
    """The site file the tiers read."""
    options: StackOptions
    stack: Stack
    logins: Logins
    tiers: tuple[str, ...]
    """The tiers running, in port order."""
    _clients: dict[tuple[str, str], TagClient] = field(default_factory=dict, repr=False)
    _exits: contextlib.AsyncExitStack | None = field(default=None, repr=False)

    @property
    def base(self) -> int:
        """The plant's port; the PLC's is ``base + 1``, the supervisor's ``+ 2``, the historian's ``+ 3``."""
        return self.stack.base

    def url(self, tier: str) -> str:
        """The endpoint of ``tier`` (``opc.tcp://127.0.0.1:PORT/tanklab/TIER``)."""
        self._check_tier(tier)
        return self.stack.url(tier)

    def _check_tier(self, tier: str) -> None:
        if tier not in self.tiers:
            raise StackError(f"tanklab_stack: no {tier} in this stack (it runs {', '.join(self.tiers)})")

    def _check_role(self, role: str) -> None:
        if role not in self.logins.credentials:
            raise StackError(
                f"tanklab_stack: no login {role!r} (one of {', '.join(self.logins.credentials)})"
            )

    @contextlib.asynccontextmanager
    async def connect(self, tier: str = "plc", role: str | None = None) -> AsyncIterator[TagSession]:
        """An authenticated :class:`TagSession` on ``tier`` as ``role`` (default: the stack's) in
        the running event loop (an async test); disconnected when the block ends."""
        who = role or self.options.role
        self._check_tier(tier)
        self._check_role(who)
        async with session(self.url(tier), self.logins, who, CLIENT_TIMEOUT_S) as client:
            yield TagSession(client, tier, _tags_of(self.site), await namespace_index(client))

    def client(self, tier: str = "plc", role: str | None = None) -> TagClient:
        """A synchronous :class:`TagClient` on ``tier`` as ``role`` (default: the stack's), one
        per tier and role, connected on first use and disconnected when the stack stops."""
        who = role or self.options.role
        self._check_tier(tier)
        self._check_role(who)
        key = (tier, who)
        if key not in self._clients:
            self._clients[key] = TagClient(self.stack, self.stack.run_sync(self._open(tier, who), 60.0))
        return self._clients[key]

    async def _open(self, tier: str, who: str) -> TagSession:
        if self._exits is None:
            self._exits = contextlib.AsyncExitStack()
        return await self._exits.enter_async_context(self.connect(tier, who))

    async def _close_clients(self) -> None:
        exits, self._exits = self._exits, None
        self._clients.clear()
        if exits is not None:
            with contextlib.suppress(Exception):
                await exits.aclose()

    @property
    def plc(self) -> TagClient:
        """The PLC as the stack's role."""
        return self.client("plc")

    @property
    def plant(self) -> TagClient:
        """The plant as the stack's role."""
        return self.client("plant")

    @property
    def supervisor(self) -> TagClient:
        """The supervisor as the stack's role (a site with a supervisor only)."""
        return self.client("supervisor")

    def advance(self, model_s: float) -> float:
        """Wait until the PLC's model time has moved on by ``model_s`` [s]; the model time then."""
        return self.plc.advance(model_s)


def _tags_of(site: SiteConfig) -> dict[str, Tag]:
    return {t.path: t for t in all_tags(site)}


def tier_args(options: StackOptions, tiers: Sequence[str], scratch: Path) -> dict[str, tuple[str, ...]]:
    """Each tier's extra arguments: ``--lockstep`` for the control tiers of a lock-step stack,
    the historian's SQLite store in ``scratch``."""
    args: dict[str, tuple[str, ...]] = {}
    if options.clock == "lockstep":
        args.update({t: ("--lockstep",) for t in tiers if t in TIERS})
    if "historian" in tiers:
        args["historian"] = ("--store", str(scratch / "history.db"))
    return args


@contextlib.contextmanager
def running_stack(
    site: SiteConfig, config: Path, logins: Logins, scratch: Path, options: StackOptions | None = None
) -> Iterator[RunningStack]:
    """``site``'s tiers (read from ``config``) serving on free loopback ports while the block
    runs, secured by ``logins``' home; ``scratch`` takes the logs and the historian's store."""
    opts = options or StackOptions()
    tiers = [t for t in TIERS if t != "supervisor" or site.supervisor is not None]
    if opts.historian:
        tiers.append("historian")
    log_dir = scratch / "logs"
    stack = Stack(
        config,
        free_base_port(4),
        speed=opts.speed if opts.clock == "realtime" else None,
        home=logins.home.root,
        log_dir=log_dir,
        env={k: v for k, v in os.environ.items() if not k.startswith("TANKLAB_")},
        tier_args=tier_args(opts, tiers, scratch),
        logins=logins,
    )
    running = RunningStack(site, config, opts, stack, logins, tuple(tiers))
    guard = _killer(stack)
    atexit.register(guard)
    try:
        with stack.serving(tiers, UP_TIMEOUT_S):
            try:
                yield running
            finally:
                stack.run_sync(running._close_clients(), 30.0)
    finally:
        atexit.unregister(guard)
        guard()


def _killer(stack: Stack) -> Any:
    """SIGKILL, by id, every tier process of ``stack`` still running (the last resort)."""

    def kill() -> None:
        for proc in stack.procs.values():
            if proc.proc is not None and proc.proc.returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(proc.proc.pid, signal.SIGKILL)

    return kill
