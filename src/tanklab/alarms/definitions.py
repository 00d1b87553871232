"""The PLC's alarms from a site config (docs/alarms.md has the list and the defaults).

Per tank one exclusive level alarm (``T1Level``): HighHigh at the lowest interlock trip level of
the tank (none without an interlock), High and Low at the tank's switch levels
(``switch_levels()``), LowLow when configured (``low_low_m``); deadband 2 % of the transmitter
range (EEMUA 191) unless configured. Per loop a bad-PV alarm (``LIC1PvBad``, Discrete); the
field link's ``IoFault`` and the supervisor's ``SupervisorLost`` (OffNormal); per interlocked tank
its trip (``T1Trip``, OffNormal, latched, to be confirmed). Overrides come from
``plc.alarms.overrides`` (checked by the site config).

The supervisor's own alarms (:func:`supervisor_alarms`, docs/alarms.md section 9): ``MpcFailing``,
``AdaptationUnhealthy`` (only with a gain adapter) and ``PlcLinkLost``, all Discrete, with the
priorities of :data:`SUPERVISOR_PRIORITIES` unless ``supervisor.alarms.overrides`` says otherwise.
"""

from __future__ import annotations

from tanklab import paths
from tanklab.alarms import names
from tanklab.alarms.manager import DEFAULT_MAX_SHELVING_TIME_S, AlarmManager
from tanklab.alarms.model import AlarmDefinition, ConditionKind, Priority
from tanklab.config import SiteConfig
from tanklab.config.plc import AlarmOverride

__all__ = [
    "DEADBAND_FRACTION",
    "DEFAULT_LEVEL_PRIORITIES",
    "DEFAULT_PRIORITIES",
    "SUPERVISOR_PRIORITIES",
    "plc_alarms",
    "plc_manager",
    "supervisor_alarms",
    "supervisor_manager",
    "supervisor_max_shelving_time_s",
]

DEADBAND_FRACTION = 0.02
"""Default level deadband as a fraction of the transmitter range (EEMUA 191)."""

DEFAULT_LEVEL_PRIORITIES = (Priority.URGENT, Priority.MEDIUM, Priority.MEDIUM, Priority.HIGH)
"""HighHigh, High, Low, LowLow."""

DEFAULT_PRIORITIES = {
    "PvBad": Priority.HIGH,
    names.IO_FAULT: Priority.HIGH,
    names.SUPERVISOR_LOST: Priority.MEDIUM,
    "Trip": Priority.URGENT,
}
"""The discrete alarms' default priorities (by name, or by suffix for the per-loop / per-tank ones)."""

SUPERVISOR_PRIORITIES = {
    names.MPC_FAILING: Priority.MEDIUM,
    names.ADAPTATION_UNHEALTHY: Priority.LOW,
    names.PLC_LINK_LOST: Priority.HIGH,
}
"""The supervisor's alarms' priorities (ISA-18.2: by the consequence and the time to respond).

PlcLinkLost HIGH: the supervisor no longer sees or drives the process (MPC's pumps fall back
to the PLC's watchdog), the operator must act soon, as for the PLC's IoFault. MpcFailing
MEDIUM: the MPC holds its shifted last plan, the process is still controlled (the PLC's loops
and interlocks stand), the response is minutes away. AdaptationUnhealthy LOW: a rejected gain
set changes nothing (the PLC keeps the gains it applies); the engineer looks at it when convenient.
"""

_LIMIT_NAMES = ("HighHigh", "High", "Low", "LowLow")


def _level(site: SiteConfig, tank: str, o: AlarmOverride) -> AlarmDefinition:
    assert site.plc is not None
    spec = site.plant.tank(tank)
    sw = spec.switch_levels()
    trips = [il.high_high_m for il in site.plc.interlocks if il.tank == tank]
    limits = (min(trips) if trips else None, sw.high_m, sw.low_m, o.low_low_m)
    base = DEFAULT_LEVEL_PRIORITIES if o.priority is None else (Priority[o.priority],) * 4
    prios = tuple(
        Priority[o.limit_priorities[n]] if n in o.limit_priorities else p
        for n, p in zip(_LIMIT_NAMES, base, strict=True)
    )
    lo, hi = spec.transmitter_range()
    loop = next((lp.name for lp in site.plc.loops if lp.pv == "LT" + tank[1:]), None)
    io = paths.plc.io(tank)
    return AlarmDefinition(
        name=names.level(tank),
        kind=ConditionKind.EXCLUSIVE_LEVEL,
        source=io.root,
        message=f"{tank} level",
        priority=min(p for p, lim in zip(prios, limits, strict=True) if lim is not None),
        input_path=io.pv,
        limits_m=limits,
        limit_priorities=(prios[0], prios[1], prios[2], prios[3]),
        deadband_m=DEADBAND_FRACTION * (hi - lo) if o.deadband_m is None else o.deadband_m,
        on_delay_s=o.on_delay_s,
        off_delay_s=o.off_delay_s,
        suppress_when_manual=loop if o.suppress_when_manual else None,
        limit_boolean_paths=(
            paths.plc.alarm(tank, "HH"),
            paths.plc.alarm(tank, "H"),
            paths.plc.alarm(tank, "L"),
            None,
        ),
        enabled=o.enabled,
    )


def _discrete(
    name: str,
    kind: ConditionKind,
    default: Priority,
    o: AlarmOverride,
    *,
    source: str,
    message: str,
    input_path: str,
    boolean_path: str | None = None,
    suppress_when_manual: str | None = None,
    latched: bool = False,
    confirm: bool = False,
) -> AlarmDefinition:
    return AlarmDefinition(
        name=name,
        kind=kind,
        source=source,
        message=message,
        priority=default if o.priority is None else Priority[o.priority],
        input_path=input_path,
        on_delay_s=o.on_delay_s,
        off_delay_s=o.off_delay_s,
        latched=latched,
        confirm=confirm,
        suppress_when_manual=suppress_when_manual,
        boolean_path=boolean_path,
        enabled=o.enabled,
    )


def plc_alarms(site: SiteConfig) -> tuple[AlarmDefinition, ...]:
    """The PLC's alarm definitions, in order: levels (tank order), PvBad (loop order), IoFault,
    SupervisorLost, trips (tank order).

    Raises
    ------
    ValueError
        The site has no ``plc`` section.
    """
    if site.plc is None:
        raise ValueError(f"site {site.name!r} has no plc section")
    plc = site.plc
    over = plc.alarms.overrides
    none = AlarmOverride()
    out = [_level(site, t, over.get(names.level(t), none)) for t in site.tank_names]
    for lp in plc.loops:
        n = names.pv_bad(lp.name)
        o = over.get(n, none)
        tank = "T" + lp.pv[2:]
        out.append(
            _discrete(
                n,
                ConditionKind.DISCRETE,
                DEFAULT_PRIORITIES["PvBad"],
                o,
                source=paths.plc.loop(lp.name).root,
                message=f"{lp.name} PV bad",
                input_path=paths.plc.io(tank).good,
                suppress_when_manual=lp.name if o.suppress_when_manual else None,
                boolean_path=paths.plc.pv_bad_alarm(lp.name),
            )
        )
    out.append(
        _discrete(
            names.IO_FAULT,
            ConditionKind.OFF_NORMAL,
            DEFAULT_PRIORITIES[names.IO_FAULT],
            over.get(names.IO_FAULT, none),
            source=paths.plc.status,
            message="Field I/O fault",
            input_path=paths.plc.io_healthy,
            boolean_path=paths.plc.io_fault,
        )
    )
    out.append(
        _discrete(
            names.SUPERVISOR_LOST,
            ConditionKind.OFF_NORMAL,
            DEFAULT_PRIORITIES[names.SUPERVISOR_LOST],
            over.get(names.SUPERVISOR_LOST, none),
            source=paths.plc.supervisor,
            message="Supervisor lost",
            input_path=paths.plc.supervisor_alive,
            boolean_path=paths.plc.supervisor_lost,
        )
    )
    for tank in dict.fromkeys(il.tank for il in plc.interlocks):
        n = names.trip(tank)
        out.append(
            _discrete(
                n,
                ConditionKind.OFF_NORMAL,
                DEFAULT_PRIORITIES["Trip"],
                over.get(n, none),
                source=paths.plc.interlocks,
                message=f"{tank} high-high trip",
                input_path=paths.plc.interlock(tank),
                latched=True,
                confirm=True,
            )
        )
    return tuple(out)


def plc_manager(site: SiteConfig, *, event_prefix: bytes = b"") -> AlarmManager:
    """An :class:`AlarmManager` over :func:`plc_alarms` with the site's maximum shelving time."""
    defs = plc_alarms(site)
    assert site.plc is not None
    return AlarmManager(
        defs, event_prefix=event_prefix, max_shelving_time_s=site.plc.alarms.max_shelving_time_s
    )


def supervisor_alarms(site: SiteConfig, *, adaptation: bool | None = None) -> tuple[AlarmDefinition, ...]:
    """The supervisor's alarm definitions, in order: MpcFailing, AdaptationUnhealthy (only with
    ``adaptation``: the supervisor has a gain adapter, every loop a PID loop; None: as the site
    says, ``SiteConfig.supervisor_adapts_gains``), PlcLinkLost, with the overrides of
    ``supervisor.alarms.overrides`` (priority, delays, enabled; checked by the site config).

    Raises
    ------
    ValueError
        The site has no ``supervisor`` section.
    """
    if site.supervisor is None:
        raise ValueError(f"site {site.name!r} has no supervisor section")
    if adaptation is None:
        adaptation = site.supervisor_adapts_gains
    sup = paths.supervisor
    over = site.supervisor.alarms.overrides
    none = AlarmOverride()
    rows: list[tuple[str, str, str, str | None]] = [
        (names.MPC_FAILING, sup.mpc, "MPC failing (plan held)", sup.mpc_status)
    ]
    if adaptation:
        rows.append(
            (
                names.ADAPTATION_UNHEALTHY,
                sup.rls_root,
                "Gain adaptation unhealthy (last gain set rejected)",
                None,
            )
        )
    rows.append((names.PLC_LINK_LOST, sup.plc_link, "PLC link lost", sup.plc_connected))
    out = []
    for name, source, message, input_path in rows:
        o = over.get(name, none)
        out.append(
            AlarmDefinition(
                name=name,
                kind=ConditionKind.DISCRETE,
                source=source,
                message=message,
                priority=SUPERVISOR_PRIORITIES[name] if o.priority is None else Priority[o.priority],
                input_path=input_path,
                on_delay_s=o.on_delay_s,
                off_delay_s=o.off_delay_s,
                enabled=o.enabled,
            )
        )
    return tuple(out)


def supervisor_max_shelving_time_s(site: SiteConfig) -> float:
    """The supervisor's longest shelving [s]: ``supervisor.alarms.max_shelving_time_s``, else the
    ``plc.alarms`` one (one alarm philosophy per site), else the core's default."""
    own = site.supervisor.alarms.max_shelving_time_s if site.supervisor is not None else None
    if own is not None:
        return own
    return site.plc.alarms.max_shelving_time_s if site.plc is not None else DEFAULT_MAX_SHELVING_TIME_S


def supervisor_manager(
    site: SiteConfig, *, adaptation: bool | None = None, event_prefix: bytes = b""
) -> AlarmManager:
    """An :class:`AlarmManager` over :func:`supervisor_alarms` with
    :func:`supervisor_max_shelving_time_s`."""
    defs = supervisor_alarms(site, adaptation=adaptation)
    return AlarmManager(
        defs, event_prefix=event_prefix, max_shelving_time_s=supervisor_max_shelving_time_s(site)
    )
