"""The PLC's field link: an OPC UA client of the plant, read and written every scan.

Per scan the PLC reads every level transmitter (``Plant.LT{i}.PV``) in one Read, with the
plant's status code for each value, and writes every pump command (``Plant.P{j}.Command``) in
one Write. In lock-step it instead calls ``Plant.Sim.Advance(Ts, commands)``, which integrates
one scan period and answers the new readings in the same round trip.

A lost plant never raises out of here into the scan: :meth:`FieldLink.read_inputs` answers
``None`` and the scan runs with every PV bad (the blocks hold or substitute), while
:class:`tanklab_io.ua_client.Link` reconnects in the background of the following scans.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from asyncua import ua
from numpy.typing import NDArray

from tanklab import paths
from tanklab.config import SiteConfig
from tanklab.errors import LinkError
from tanklab.tags import plant_tags, tags_by_path
from tanklab_io.ua_client import ClientSetup, Link

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FieldReadings:
    """Levels [m] and their quality, in tank order."""

    levels_m: NDArray[np.float64]
    good: NDArray[np.bool_]


class FieldLink:
    """The PLC's client of the plant server."""

    def __init__(self, site: SiteConfig, url: str, *, setup: ClientSetup, timeout_s: float = 2.0) -> None:
        self.site = site
        contract = tags_by_path(plant_tags(site))
        self.lt_paths = [paths.plant.lt(t).pv for t in site.tank_names]
        self.cmd_paths = [paths.plant.pump(p).command for p in site.pump_names]
        needed = {p: contract[p] for p in [*self.lt_paths, *self.cmd_paths, paths.plant.sim_advance]}
        self.link = Link(
            url, needed, name="field", setup=setup, timeout_s=timeout_s, failure_level=logging.WARNING
        )

    @property
    def healthy(self) -> bool:
        return self.link.healthy

    async def ensure(self) -> bool:
        """Reconnect if needed (with backoff); whether the plant is reachable now."""
        return await self.link.ensure()

    async def read_inputs(self) -> FieldReadings | None:
        """All transmitter readings, or None when the plant cannot be read."""
        if not await self.link.ensure():
            return None
        try:
            dvs = await self.link.read(self.lt_paths)
        except LinkError as e:
            log.warning("%s", e)
            return None
        levels = np.array(
            [
                float(dv.Value.Value) if dv.Value is not None and dv.Value.Value is not None else np.nan
                for dv in dvs
            ]
        )
        good = np.array([dv.StatusCode is None or dv.StatusCode.is_good() for dv in dvs], dtype=bool)
        return FieldReadings(levels, good)

    async def read_state(self) -> tuple[NDArray[np.float64], FieldReadings] | None:
        """The plant's pump commands now (as last written, pump order; NaN where unreadable) and
        every transmitter reading, in one Read; None when the plant cannot be read (a warm
        restart's look at the process before its first scan)."""
        if not await self.link.ensure():
            return None
        try:
            dvs = await self.link.read(self.cmd_paths + self.lt_paths)
        except LinkError as e:
            log.warning("%s", e)
            return None
        good = [dv.StatusCode is None or dv.StatusCode.is_good() for dv in dvs]
        values = [
            float(dv.Value.Value) if ok and dv.Value is not None and dv.Value.Value is not None else np.nan
            for dv, ok in zip(dvs, good, strict=True)
        ]
        n = len(self.cmd_paths)
        levels = FieldReadings(np.array(values[n:]), np.array(good[n:], dtype=bool))
        return np.array(values[:n]), levels

    async def write_commands(self, commands: NDArray[np.float64]) -> bool:
        """Write every pump command; whether the plant took them all."""
        if not self.link.healthy:
            return False
        try:
            results = await self.link.write(
                dict(zip(self.cmd_paths, (float(c) for c in commands), strict=True))
            )
        except LinkError as e:
            log.warning("%s", e)
            return False
        bad = [(p, r.name) for p, r in zip(self.cmd_paths, results, strict=True) if not r.is_good()]
        for path, name in bad:
            log.warning("plant refused %s: %s", path, name)
        return not bad

    async def advance(
        self, seconds: float, commands: NDArray[np.float64]
    ) -> tuple[float, FieldReadings] | None:
        """Lock-step: write the commands and integrate one scan in one call; None if it failed."""
        if not await self.link.ensure():
            return None
        try:
            out = await self.link.call(
                paths.plant.sim_advance,
                ua.Variant(float(seconds), ua.VariantType.Double),
                ua.Variant([float(c) for c in commands], ua.VariantType.Double, is_array=True),
            )
        except (LinkError, ua.UaStatusCodeError) as e:
            log.warning("%s failed: %s", paths.plant.sim_advance, e)
            return None
        t, levels = float(out[0]), np.asarray(out[1], dtype=float)
        return t, FieldReadings(levels, np.ones(len(levels), dtype=bool))

    async def close(self) -> None:
        await self.link.close()
