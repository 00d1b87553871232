"""The supervisor's link to the PLC: one Read per cycle, ordered writes, SetGains calls.

The OPC UA transport of :class:`supervisor.port.PlcPort`. ``snapshot`` reads, in one Read, the
scan counter, the model time, every loop's SP, PV, MV, mode and applied gains, and every level the
PLC reads with its quality, so that errors and MVs belong to the same scan (architecture: RLS
data). ``apply`` sends a :class:`supervisor.port.PlcRequest` in its order (RemoteMV before Mode,
then SetGains, the heartbeat last: in lock-step it is the PLC's permission to scan again), in as
few round trips as that order allows.
"""

from __future__ import annotations

import logging
from typing import Any

from asyncua import ua

from supervisor.cycle import PlcSnapshot
from supervisor.port import PlcRequest
from tanklab import paths
from tanklab.config import SiteConfig
from tanklab.errors import LinkError
from tanklab.tags import plc_tags, tags_by_path
from tanklab_io.ua_client import ClientSetup, Link

log = logging.getLogger(__name__)


class PlcLink:
    """The supervisor's OPC UA client of the PLC."""

    def __init__(self, site: SiteConfig, url: str, *, setup: ClientSetup, timeout_s: float = 2.0) -> None:
        self.site = site
        self.loops = site.loop_names
        self.tanks = site.tank_names
        contract = tags_by_path(plc_tags(site))
        self.read_paths = PlcSnapshot.read_paths(self.loops, self.tanks)
        writes = [paths.plc.heartbeat]
        for lp in self.loops:
            loop = paths.plc.loop(lp)
            writes += [loop.remote_mv, loop.mode, loop.set_gains]
        self.link = Link(
            url,
            {p: contract[p] for p in self.read_paths + writes},
            name="plc",
            setup=setup,
            timeout_s=timeout_s,
            failure_level=logging.WARNING,
        )

    @property
    def healthy(self) -> bool:
        return self.link.healthy

    async def ensure(self) -> bool:
        return await self.link.ensure()

    async def snapshot(self) -> PlcSnapshot | None:
        """One Read of everything a cycle needs; None when the PLC cannot be read."""
        if not await self.link.ensure():
            return None
        try:
            dvs = await self.link.read(self.read_paths)
        except LinkError as e:
            log.warning("%s", e)
            return None
        if any(dv.StatusCode is not None and not dv.StatusCode.is_good() for dv in dvs):
            return None
        values: dict[str, Any] = {}
        for path, dv in zip(self.read_paths, dvs, strict=True):
            if dv.Value is None or dv.Value.Value is None:
                return None
            values[path] = dv.Value.Value
        return PlcSnapshot.from_values(values, self.loops, self.tanks)

    async def apply(self, request: PlcRequest) -> list[str]:
        """Send a request in its order (:class:`supervisor.port.PlcRequest`); return the loops
        whose gain push the PLC refused.

        The first Write carries RemoteMV and Mode (the PLC applies a Write's items in order) and,
        when no gains are pushed, the heartbeat: one round trip per cycle in the usual case.

        Raises
        ------
        LinkError
            When the PLC cannot be reached (nothing more is written).
        """
        if request.writes:
            await self._write(dict(request.writes))
        refused = []
        for lp, (kp, ki, kd) in request.gains:
            try:
                await self.link.call(
                    paths.plc.loop(lp).set_gains,
                    ua.Variant(kp, ua.VariantType.Double),
                    ua.Variant(ki, ua.VariantType.Double),
                    ua.Variant(kd, ua.VariantType.Double),
                )
                log.info("pushed gains to %s: Kp %.4g Ki %.4g Kd %.4g", lp, kp, ki, kd)
            except ua.UaStatusCodeError as e:
                log.warning("PLC refused gains for %s: %s", lp, type(e).__name__)
                refused.append(lp)
        if request.trailing:
            await self._write(dict(request.trailing))
        return refused

    async def _write(self, values: dict[str, object]) -> None:
        results = await self.link.write(values)
        for path, status in zip(values, results, strict=True):
            if not status.is_good():
                log.warning("PLC refused %s = %r: %s", path, values[path], status.name)

    async def close(self) -> None:
        await self.link.close()
