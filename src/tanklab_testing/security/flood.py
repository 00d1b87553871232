"""Write-flood generators and watchers: engineer sessions writing valid and invalid values to
SP, ManualMV and Mode as fast as they can, while the PLC's status and the plant's model time
are watched (valid writes keep the loops regulating: SP within 2 cm of its setpoint, AUTO).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from asyncua import Client, ua

from tanklab.enums import LoopMode
from tanklab.tags import Tag
from tanklab_io.ua_client import namespace_index
from tanklab_testing.logins import Logins, session
from tanklab_testing.security.draws import pick
from tanklab_testing.sites import PLC_TAGS, SITE

VT = ua.VariantType
FLOOD_TARGETS = (
    "PLC.LIC1.SP",
    "PLC.LIC2.SP",
    "PLC.LIC1.ManualMV",
    "PLC.LIC2.ManualMV",
    "PLC.LIC1.Mode",
    "PLC.LIC2.Mode",
)


def flood_value(rng: np.random.Generator, tag: Tag) -> tuple[ua.Variant, bool]:
    """A flood write's value for ``tag`` and whether it is valid: valid SPs stay within 2 cm of
    the configured setpoint, the valid Mode is AUTO (the loops keep regulating); invalid values
    are NaN, outside EURange, non-members or of the wrong type."""
    valid = rng.random() < 0.5
    if tag.name == "Mode":
        if valid:
            return ua.Variant(int(LoopMode.AUTO), VT.Int32), True
        return pick(
            rng, (ua.Variant(7, VT.Int32), ua.Variant(-1, VT.Int32), ua.Variant(1.0, VT.Double))
        ), False
    assert tag.eu_range is not None
    lo, hi = tag.eu_range
    if valid:
        if tag.name == "SP":
            assert SITE.plc is not None
            sp0 = next(lp.setpoint_m for lp in SITE.plc.loops if lp.name == tag.path.split(".")[1])
            return ua.Variant(float(rng.uniform(sp0 - 0.02, sp0 + 0.02)), VT.Double), True
        return ua.Variant(float(rng.uniform(lo, hi)), VT.Double), True
    return pick(
        rng,
        (
            ua.Variant(math.nan, VT.Double),
            ua.Variant(hi + 1.0, VT.Double),
            ua.Variant(lo - 1.0, VT.Double),
            ua.Variant(1, VT.Int32),
        ),
    ), False


@dataclass
class FloodCounts:
    """Writes of a flood: sent, accepted, refused by status, and the oracle's violations."""

    sent: int = 0
    accepted: int = 0
    statuses: Counter[str] = field(default_factory=Counter)
    violations: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)


async def flood_writes(
    url: str,
    logins: Logins,
    *,
    seconds: float,
    clients: int,
    seed: int = 0,
    who: str = "engineer",
    on_start: Callable[[], Awaitable[None]] | None = None,
) -> FloodCounts:
    """``clients`` sessions writing single values back to back for ``seconds`` of wall time.

    The sessions log in first (a password login costs the server one scrypt, ~70 ms); the flood
    starts when all are in, after ``on_start`` (where a watcher takes its "before" reading).
    """
    tags = {t.path: t for t in PLC_TAGS}
    counts = FloodCounts()
    ready = asyncio.Barrier(clients + 1)
    go = asyncio.Event()
    end = [math.inf]

    async def writer(k: int) -> None:
        rng = np.random.default_rng([seed, k])
        try:
            async with session(url, logins, who) as client:
                idx = await namespace_index(client)
                await ready.wait()
                await go.wait()
                while time.monotonic() < end[0]:
                    path = pick(rng, FLOOD_TARGETS)
                    tag = tags[path]
                    value, valid = flood_value(rng, tag)
                    wv = ua.WriteValue(
                        NodeId=ua.NodeId(path, idx),
                        AttributeId=ua.AttributeIds.Value,
                        Value=ua.DataValue(value),
                    )
                    counts.sent += 1
                    try:
                        status = (await client.uaclient.write(ua.WriteParameters(NodesToWrite=[wv])))[0]
                    except ua.UaStatusCodeError as e:
                        status = ua.StatusCode(e.code)
                    counts.statuses[status.name] += 1
                    if status.is_good():
                        counts.accepted += 1
                        if not valid:
                            counts.violations.append(f"{path} = {value!r} accepted")
        except Exception as e:
            counts.errors.append(f"writer {k}: {type(e).__name__}: {e}")
            await ready.abort()

    async def release() -> None:
        with contextlib.suppress(asyncio.BrokenBarrierError):
            await ready.wait()
        if on_start is not None:
            await on_start()
        end[0] = time.monotonic() + seconds
        go.set()

    await asyncio.gather(release(), *(writer(k) for k in range(clients)))
    return counts


STATUS_PATHS = (
    "PLC.Status.Scan",
    "PLC.Status.ModelTime",
    "PLC.Status.Overruns",
    "PLC.Status.LastScanDuration",
)


async def plc_status(client: Client) -> dict[str, Any]:
    """Scan, model time, overruns and last scan duration in one Read."""
    idx = await namespace_index(client)
    dvs = await client.read_attributes([client.get_node(ua.NodeId(p, idx)) for p in STATUS_PATHS])
    return {p.rsplit(".", 1)[1]: dv.Value.Value for p, dv in zip(STATUS_PATHS, dvs, strict=True)}


async def status_after_scans(client: Client, scans: int, limit_s: float = 30.0) -> dict[str, Any]:
    """:func:`plc_status` once the scan counter has advanced by ``scans`` (bounded wait)."""
    first = await plc_status(client)
    deadline = time.monotonic() + limit_s
    while True:
        now = await plc_status(client)
        if int(now["Scan"]) >= int(first["Scan"]) + scans or time.monotonic() > deadline:
            return now
        await asyncio.sleep(0.02)


async def plant_time(client: Client) -> float:
    idx = await namespace_index(client)
    return float(await client.get_node(ua.NodeId("Plant.Sim.Time", idx)).read_value())


@dataclass
class FloodWatch:
    """The PLC and the plant seen by a watching session during a flood."""

    before: dict[str, Any] = field(default_factory=dict)
    after: dict[str, Any] = field(default_factory=dict)
    plant_before: float = math.nan
    plant_after: float = math.nan
    max_scan_duration_s: float = 0.0
    samples: int = 0

    @property
    def model_lag_s(self) -> float:
        """How much less model time the PLC ran than the plant over the flood [model s]."""
        plc = float(self.after["ModelTime"]) - float(self.before["ModelTime"])
        return (self.plant_after - self.plant_before) - plc


async def watched_flood(
    plc_url: str, plant_url: str, logins: Logins, *, seconds: float, clients: int, seed: int = 0
) -> tuple[FloodCounts, FloodWatch]:
    """A flood with a watching session on the PLC (status every 100 ms) and one on the plant;
    "before" is read once every flooding session is logged in, "after" when the writes stop."""
    watch = FloodWatch()
    async with session(plc_url, logins, "engineer") as plc, session(plant_url, logins, "engineer") as plant:

        async def before() -> None:
            # Overruns of a scan are published with the next scan: let the logins' scans go by.
            watch.before = await status_after_scans(plc, 2)
            watch.plant_before = await plant_time(plant)

        flood_task = asyncio.create_task(
            flood_writes(plc_url, logins, seconds=seconds, clients=clients, seed=seed, on_start=before)
        )
        while not flood_task.done():
            if watch.before:
                st = await plc_status(plc)
                watch.samples += 1
                watch.max_scan_duration_s = max(watch.max_scan_duration_s, float(st["LastScanDuration"]))
            await asyncio.wait({flood_task}, timeout=0.1)
        counts = flood_task.result()
        watch.plant_after = await plant_time(plant)
        watch.after = await plc_status(plc)
        late = await status_after_scans(plc, 2)
        watch.after["Overruns"] = late["Overruns"]
    return counts, watch
