"""The fuzz driver and its post-conditions: seeded raw and typed cases against a PLC server,
then the server must still serve, every stored value must be in contract, the scan must advance.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from asyncua import Client, ua

from tanklab.tags import DataType, Tag
from tanklab_io.ua_client import namespace_index
from tanklab_testing.logins import ROLE_OF, Logins, session
from tanklab_testing.security.draws import pick
from tanklab_testing.security.raw import RAW_KINDS, RawCase, raw_case, run_raw_case
from tanklab_testing.security.typed import VARIANT_OF, FuzzCounts, SessionTargets, session_case
from tanklab_testing.sites import PLC_TAGS

SESSION_KINDS = ("write", "call", "node_management", "subscription")
"""Typed case kinds, through an authenticated session."""
RAW_SHARE = 0.6
"""Share of raw-transport cases among all cases (the rest go through sessions)."""


async def stored_violations(client: Client, tags: Sequence[Tag]) -> list[str]:
    """Every stored value that breaks the contract: not Good, wrong type, not finite, outside
    EURange, not a member of its enumeration; and every EURange property that changed."""
    idx = await namespace_index(client)
    variables = [t for t in tags if t.kind == "variable" and t.data_type is not None]
    nodes = [client.get_node(ua.NodeId(t.path, idx)) for t in variables]
    out: list[str] = []
    for t, dv in zip(variables, await client.read_attributes(nodes), strict=True):
        assert t.data_type is not None
        if dv.StatusCode is not None and not dv.StatusCode.is_good():
            out.append(f"{t.path}: status {dv.StatusCode.name}")
            continue
        v = dv.Value
        want = VARIANT_OF[t.data_type]
        is_list = isinstance(v.Value, list) if v is not None else False
        if v is None or v.VariantType != want or is_list != (t.data_type == DataType.DOUBLE_ARRAY):
            out.append(f"{t.path}: stored {v!r}, not a {t.data_type.value}")
            continue
        for x in v.Value if is_list else [v.Value]:
            if isinstance(x, float) and not math.isfinite(x):
                out.append(f"{t.path}: stored {x!r}")
            elif (
                t.eu_range is not None
                and isinstance(x, int | float)
                and not t.eu_range[0] <= x <= t.eu_range[1]
            ):
                out.append(f"{t.path}: stored {x!r} outside EURange {t.eu_range}")
            elif t.enum is not None and int(x) not in {int(m) for m in t.enum}:
                out.append(f"{t.path}: stored {x!r}, not a member of {t.enum.__name__}")
    ranged = [t for t in variables if t.eu_range is not None]
    props = [client.get_node(ua.NodeId(f"{t.path}.EURange", idx)) for t in ranged]
    for t, dv in zip(ranged, await client.read_attributes(props), strict=True):
        assert t.eu_range is not None
        rng = dv.Value.Value if dv.Value is not None else None
        if not isinstance(rng, ua.Range) or (rng.Low, rng.High) != tuple(float(x) for x in t.eu_range):
            out.append(f"{t.path}.EURange: now {rng!r}, contract {t.eu_range}")
    return out


async def read_scan(client: Client) -> int:
    """``PLC.Status.Scan`` (raises unless the read is Good)."""
    idx = await namespace_index(client)
    dv = (await client.read_attributes([client.get_node(ua.NodeId("PLC.Status.Scan", idx))]))[0]
    if dv.StatusCode is not None and not dv.StatusCode.is_good():
        raise ua.UaStatusCodeError(dv.StatusCode.value)
    return int(dv.Value.Value)


@dataclass
class PostConditions:
    """The server after the fuzz."""

    alive: bool = False
    read_good: bool = False
    out_of_contract: list[str] = field(default_factory=list)
    scan_before: int = -1
    scan_after: int = -1
    error: str = ""

    @property
    def ok(self) -> bool:
        return (
            self.alive
            and self.read_good
            and not self.out_of_contract
            and self.scan_after > self.scan_before
            and not self.error
        )


async def post_conditions(
    url: str, logins: Logins, who: str = "engineer", scan_wait_s: float = 30.0
) -> PostConditions:
    """A new secure session reads Good, every stored value keeps its contract, and the scan
    counter advances (within ``scan_wait_s`` of wall time)."""
    post = PostConditions()
    try:
        async with session(url, logins, who) as client:
            post.alive = True
            post.scan_before = await read_scan(client)
            post.read_good = True
            post.out_of_contract = await stored_violations(client, PLC_TAGS)
            deadline = time.monotonic() + scan_wait_s
            while time.monotonic() < deadline:
                post.scan_after = await read_scan(client)
                if post.scan_after > post.scan_before:
                    break
                await asyncio.sleep(0.05)
    except Exception as e:
        post.error = f"{type(e).__name__}: {e}"
    return post


async def fuzz_server(
    url: str,
    logins: Logins,
    *,
    n_cases: int,
    seed: int,
    concurrency: int = 8,
    sessions: Sequence[str] = ("engineer", "supervisor"),
) -> FuzzCounts:
    """Run ``n_cases`` seeded cases against the PLC server at ``url``: about
    :data:`RAW_SHARE` of them raw-transport cases (``concurrency`` connections at a time,
    interleaved with the session cases), the rest typed cases spread over ``sessions``."""
    host_port = url.split("//", 1)[1].split("/", 1)[0]
    host, port = host_port.rsplit(":", 1)
    rng = np.random.default_rng(seed)
    counts = FuzzCounts()
    n_raw = round(n_cases * RAW_SHARE)
    raw_cases = [raw_case(pick(rng, RAW_KINDS), rng, url) for _ in range(n_raw)]
    n_session = n_cases - n_raw
    seeds = rng.integers(0, 2**63, size=len(sessions))
    sem = asyncio.Semaphore(concurrency)

    async def one_raw(case: RawCase) -> None:
        async with sem:
            counts.merge_raw(await run_raw_case(case, host, int(port), url))

    async def typed(who: str, n: int, s: int) -> None:
        sub = np.random.default_rng(s)
        async with session(url, logins, who) as client:
            idx = await namespace_index(client)
            targets = SessionTargets.build(idx, PLC_TAGS)
            for _ in range(n):
                await session_case(client, ROLE_OF[who], targets, sub, counts)

    shares = [
        n_session // len(sessions) + (1 if k < n_session % len(sessions) else 0) for k in range(len(sessions))
    ]
    await asyncio.gather(
        *(one_raw(c) for c in raw_cases),
        *(typed(who, n, int(s)) for who, n, s in zip(sessions, shares, seeds, strict=True)),
    )
    return counts
