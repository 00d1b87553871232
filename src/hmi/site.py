"""What the HMI knows of a site: its description for the browser, the live set it polls, and the
conversions between the contract's values and JSON (pure: a site config in, data out).

The **live set** (contract v1, docs/hmi.md) is every mimic binding's tag, every loop's SP, PV,
MV, Mode, ManualMV, RemoteMV, Kp, Ki, Kd, GainSource, every tank's Level, Leak, Disturbance,
every transmitter's PV and Fault, ``Plant.Sim.Time``, ``PLC.Status.*``, ``PLC.Interlock.*``,
``PLC.Alarms.*``, ``Supervisor.Mode``, ``Supervisor.MPC.{Status,SolveTime,Horizon,PlannedMV,
PredictedPV}``, each alarm tier's ``AlarmSummary.*`` and ``Historian.Status.StoreAvailable``
(so that every tier is in every poll): variables only, each on its tier.

A value goes to the browser as ``{"v": value, "q": status name, "t": source time [epoch s]}``,
an enumeration's value as its name (``"AUTO"``); a write's JSON value becomes the tag's type by
:func:`parse_value` (an enumeration by name or number), anything else is a :class:`ValueError`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hmi.mimic import mimic
from tanklab import paths
from tanklab.alarms.definitions import plc_alarms, supervisor_alarms
from tanklab.alarms.model import AlarmDefinition
from tanklab.config import SiteConfig
from tanklab.identity import SiteIdentity
from tanklab.tags import DataType, Tag, Tier, all_tags, tags_by_path

__all__ = ["SiteModel", "json_value", "parse_value"]

_LIVE_PREFIXES = (
    paths.plc.status + ".",
    paths.plc.interlocks_prefix,
    paths.plc.alarms_prefix,
    *(path for tier in ("plc", "supervisor") for path in paths.alarm_summary_paths(tier).values()),
)
_SUPERVISOR_LIVE = (
    paths.supervisor.mode,
    paths.supervisor.mpc_status,
    paths.supervisor.mpc_solve_time,
    paths.supervisor.mpc_horizon,
    paths.supervisor.mpc_planned_mv,
    paths.supervisor.mpc_predicted_pv,
)


@dataclass(frozen=True)
class SiteModel:
    """A site as the HMI serves it: its tags by path, the live set, its alarm definitions."""

    site: SiteConfig
    tags: dict[str, Tag]
    live: tuple[str, ...]
    alarms: dict[Tier, tuple[AlarmDefinition, ...]]
    description: dict[str, Any]

    @classmethod
    def of(cls, site: SiteConfig) -> SiteModel:
        tags = tags_by_path(all_tags(site))
        drawing = mimic(site)
        wanted: list[str] = [b.tag for b in drawing.bindings]
        for tank in site.plant.tanks:
            t = paths.plant.tank(tank.name)
            lt = paths.plant.lt(tank.name)
            wanted += [t.level, t.leak, t.disturbance, lt.pv, lt.fault]
        for pump in site.plant.pumps:
            p = paths.plant.pump(pump.name)
            wanted += [p.command, p.flow]
        wanted += [paths.plant.valve_opening(v.name) for v in site.plant.valves]
        wanted.append(paths.plant.sim_time)
        if site.plc is not None:
            for loop in site.plc.loops:
                lp = paths.plc.loop(loop.name)
                wanted += [
                    lp.sp,
                    lp.pv,
                    lp.mv,
                    lp.mode,
                    lp.manual_mv,
                    lp.remote_mv,
                    *lp.gains,
                    lp.gain_source,
                ]
        wanted += [p for p in tags if p.startswith(_LIVE_PREFIXES)]
        if site.supervisor is not None:
            wanted += list(_SUPERVISOR_LIVE)
        # the historian's store state: it puts the historian in every poll, so a historian that
        # stops answering is a ``link`` message like any tier's (the screen marks it unreachable)
        wanted.append(paths.historian.store_available)
        live = tuple(
            dict.fromkeys(
                p for p in wanted if p in tags and tags[p].kind == "variable" and _served(site, tags[p])
            )
        )
        alarms: dict[Tier, tuple[AlarmDefinition, ...]] = {}
        if site.plc is not None:
            alarms["plc"] = plc_alarms(site)
        if site.supervisor is not None:
            alarms["supervisor"] = supervisor_alarms(site)
        return cls(site, tags, live, alarms, _describe(site, tags, drawing.svg, drawing.bindings))

    def tier_of(self, path: str) -> Tier:
        return self.tags[path].tier

    def variable(self, path: str) -> Tag:
        """The contract variable ``path``; KeyError naming it for anything else."""
        tag = self.tags.get(path)
        if tag is None or tag.kind != "variable":
            raise KeyError(f"unknown path {path}")
        return tag


def _served(site: SiteConfig, tag: Tag) -> bool:
    return tag.tier != "supervisor" or site.supervisor is not None


def _describe(site: SiteConfig, tags: Mapping[str, Tag], svg: str, bindings: Any) -> dict[str, Any]:
    plant = site.plant
    pump_unit = {p.name: tags[paths.plant.pump(p.name).command].unit for p in plant.pumps}
    loops = []
    if site.plc is not None:
        for loop in site.plc.loops:
            lp = paths.plc.loop(loop.name)
            mv = tags[lp.manual_mv]
            loops.append(
                {
                    "name": loop.name,
                    "pv_tank": f"T{loop.pv[2:]}",
                    "pump": loop.actuator,
                    "sp_range_m": [loop.sp_min_m, loop.sp_max_m],
                    "mv_range": list(mv.eu_range) if mv.eu_range else None,
                    "mv_unit": mv.unit,
                    "has_gains": loop.block == "pid",
                }
            )
    return {
        "site": site.name,
        "digest": SiteIdentity.of(site).digest,
        "tanks": [{"name": t.name, "height_max_m": t.height_max_m} for t in plant.tanks],
        "pumps": [
            {
                "name": p.name,
                "unit": pump_unit[p.name],
                "range": [p.command_min, p.command_max],
                "tank": p.feeds,
            }
            for p in plant.pumps
        ],
        "valves": [
            {"name": v.name, "kind": "connecting" if v.downstream is not None else "outlet"}
            for v in plant.valves
        ],
        "transmitters": [{"name": paths.plant.lt(t.name).name, "tank": t.name} for t in plant.tanks],
        "loops": loops,
        "supervisor": site.supervisor is not None,
        "historian": True,
        "mimic": {
            "svg": svg,
            "bindings": [{"element": b.element_id, "tag": b.tag, "kind": b.kind} for b in bindings],
        },
    }


def json_value(tag: Tag | None, value: Any) -> Any:
    """A tag's value as JSON: an enumeration's name, arrays as lists, non-finite floats as None
    (JSON has no NaN), anything unknown as its text."""
    if value is None or isinstance(value, bool | str):
        return value
    if tag is not None and tag.enum is not None and isinstance(value, int):
        try:
            return tag.enum(value).name
        except ValueError:
            return value
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, list | tuple):
        return [json_value(None, v) for v in value]
    return str(value)


def _number(value: Any, path: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{path}: a number is wanted, got {type(value).__name__}")
    return float(value)


def parse_value(tag: Tag, value: Any) -> Any:
    """A write's JSON ``value`` as the Python value of ``tag``'s type (module docstring).

    Raises ValueError for a value of the wrong JSON type or an unknown enumeration name; the
    range is the tier's to check (it answers BadOutOfRange and keeps the old value).
    """
    dt = tag.data_type
    if tag.enum is not None:
        if isinstance(value, str):
            try:
                return int(tag.enum[value.strip().upper()])
            except KeyError:
                names = ", ".join(m.name for m in tag.enum)
                raise ValueError(f"{tag.path}: {value!r} is not one of {names}") from None
        number = _number(value, tag.path)
        if not number.is_integer():
            raise ValueError(f"{tag.path}: an enumeration value is an integer, got {value}")
        return int(number)
    if dt == DataType.DOUBLE:
        return _number(value, tag.path)
    if dt in (DataType.INT32, DataType.UINT32):
        number = _number(value, tag.path)
        if not number.is_integer():
            raise ValueError(f"{tag.path}: an integer is wanted, got {value}")
        return int(number)
    if dt == DataType.BOOLEAN:
        if not isinstance(value, bool):
            raise ValueError(f"{tag.path}: true or false is wanted, got {type(value).__name__}")
        return value
    if dt == DataType.STRING:
        if not isinstance(value, str):
            raise ValueError(f"{tag.path}: a string is wanted, got {type(value).__name__}")
        return value
    if dt == DataType.DOUBLE_ARRAY:
        if not isinstance(value, list):
            raise ValueError(f"{tag.path}: a list of numbers is wanted, got {type(value).__name__}")
        return [_number(v, tag.path) for v in value]
    raise ValueError(f"{tag.path}: not a writable value")
