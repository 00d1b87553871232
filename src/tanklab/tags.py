"""The OPC UA address-space contract: every node of the three tiers, in one place.

All three servers register the namespace URI ``urn:tanklab`` and use string NodeIds
``ns=<index of urn:tanklab>;s=<path>``; browse names equal the last path element and objects
nest along the dots. Tags are numbered per site config (the single tank has T1, LT1, P1 and
LIC1 only), so the contract is a function of the :class:`~tanklab.config.SiteConfig`:
:func:`plant_tags`, :func:`plc_tags` and :func:`supervisor_tags` list the nodes of each tier.

Each :class:`Tag` carries its data type, engineering unit, EURange, which roles may write it,
and a description. Analog values (a unit and a range) become AnalogItemType variables;
enumerations become Int32 MultiStateDiscreteType variables with EnumStrings; methods carry
their argument lists. This module is pure data; :mod:`tanklab_io.ua` builds the nodes on an
asyncua server and resolves them on a client.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from tanklab.config import SiteConfig
from tanklab.enums import GainSource, LoopMode, MpcStatus, RemoteSource, SensorFault, SupervisorMode
from tanklab.fdi_model import FaultKind, FdiState, hypothesis_name, site_hypotheses
from tanklab.identity import SiteIdentity, canonical_json
from tanklab.paths import (
    ALARM_SUMMARY_ITEMS,
    IDENTITY_ITEMS,
    LINK_STATUS_ITEMS,
    SOURCE_TIERS,
    TIER_ROOTS,
    AlarmKind,
    AlarmSummaryItem,
    BalanceItem,
    Tier,
    alarm_summary_paths,
    historian,
    identity_paths,
    link_status_paths,
    plant,
    plc,
    supervisor,
)
from tanklab.tag_model import (
    ENGINEER_ONLY,
    NOBODY,
    OPERATOR_UP,
    Argument,
    DataType,
    Role,
    Tag,
    TagList,
    enum_name,
    enum_range,
)

__all__ = [
    "ALARM_SUMMARY_ITEMS",
    "APPLICATION_URIS",
    "ENGINEER_ONLY",
    "HEARTBEAT_PATH",
    "IDENTITY_ITEMS",
    "LINK_STATUS_ITEMS",
    "NAMESPACE_URI",
    "NOBODY",
    "OPERATOR_UP",
    "TIER_ROOTS",
    "Argument",
    "DataType",
    "Diagnostic",
    "Role",
    "Tag",
    "Tier",
    "alarm_summary_paths",
    "all_tags",
    "historian_tags",
    "identity_paths",
    "link_status_paths",
    "plant",
    "plant_tags",
    "plc",
    "plc_tags",
    "render_markdown",
    "supervisor",
    "supervisor_tags",
    "tags_by_path",
]

NAMESPACE_URI = "urn:tanklab"
"""Namespace URI of every tanklab node; clients look its index up, never hard-code it."""

HEARTBEAT_PATH = plc.heartbeat
"""The supervisor's heartbeat (UInt32): written every scan it acknowledges, checked by the PLC."""

APPLICATION_URIS = {
    "plant": "urn:tanklab:plant",
    "plc": "urn:tanklab:plc",
    "supervisor": "urn:tanklab:supervisor",
    "historian": "urn:tanklab:historian",
    "cli": "urn:tanklab:cli",
}
"""ApplicationUri of each tier (and of the CLI as a client)."""


def _link_status(b: TagList, prefix: str, peer: str) -> None:
    paths = link_status_paths(prefix)
    b.var(
        paths["Attempts"],
        DataType.UINT32,
        f"Failed connection attempts to the {peer} since the link was last up (0 while up).",
    )
    b.var(paths["Connects"], DataType.UINT32, f"Successful connections to the {peer} since start.")
    b.var(
        paths["LastError"],
        DataType.STRING,
        f"Why the last connection attempt or request to the {peer} failed: exception class and "
        "message (empty until the first failure; kept after a recovery).",
    )
    b.var(
        paths["RetryDelay"],
        DataType.DOUBLE,
        "Wait before the next connection attempt after the last failure: capped exponential "
        "backoff with jitter (0 while up) [s].",
        unit="s",
        eu_range=(0.0, 60.0),
    )


def _identity(b: TagList, site: SiteConfig) -> None:
    """The identity nodes: constant for the life of the process, so their initial values."""
    paths = identity_paths(b.tier)
    ident = SiteIdentity.of(site)
    b.var(
        paths["SiteName"],
        DataType.STRING,
        "Name of the site this tier runs (the config's name).",
        initial=ident.name,
    )
    b.var(
        paths["ConfigDigest"],
        DataType.STRING,
        "sha256 (64 hex digits) of the canonical JSON of the site config this tier was started with, "
        "without endpoints, stack, plant.state_file and plc.retain_file; operator commands compare it "
        "with their --config's and show its first 16 digits.",
        initial=ident.digest,
    )
    b.var(
        paths["Config"],
        DataType.STRING,
        "That canonical JSON itself: an operator command given no --config takes the site from it.",
        initial=canonical_json(site),
    )


def _alarm_summary(b: TagList) -> None:
    """The tier's alarm summary nodes (:mod:`tanklab.alarms.summary`; docs/alarms.md)."""
    p = alarm_summary_paths(b.tier)
    counts: dict[AlarmSummaryItem, str] = {
        "Active": "Enabled conditions that are active (shelved and suppressed ones included).",
        "Unacknowledged": "Enabled conditions not acknowledged.",
        "Shelved": "Enabled conditions shelved (one-shot or timed).",
        "Suppressed": "Enabled conditions suppressed (their loop out of service, MANUAL).",
        "Disabled": "Disabled conditions (counted in no other figure).",
    }
    for item, text in counts.items():
        b.var(p[item], DataType.UINT32, text)
    b.var(
        p["RatePer10Min"],
        DataType.UINT32,
        "ISA-18.2 alarm rate of this tier (one operator position): annunciated alarms (new activations "
        "and new limits, neither shelved nor suppressed) in the last 600 s of model time.",
    )
    b.var(
        p["PeakRatePer10Min"],
        DataType.UINT32,
        "The largest RatePer10Min since the tier started.",
    )
    b.var(p["Flood"], DataType.BOOLEAN, "Alarm flood: RatePer10Min > 10 (ISA-18.2, EEMUA 191).")


def plant_tags(site: SiteConfig) -> list[Tag]:
    """Nodes of the plant simulator for ``site``."""
    b = TagList("plant")
    _identity(b, site)
    plant_cfg = site.plant
    for tank in plant_cfg.tanks:
        i = tank.name[1:]
        tp, lt = plant.tank(tank.name), plant.lt(tank.name)
        hmax = tank.height_max_m
        sw = tank.switch_levels()
        lo, hi = tank.transmitter_range()
        b.var(
            tp.level,
            DataType.DOUBLE,
            f"True level of {tank.name} [m].",
            unit="m",
            eu_range=(0.0, hmax),
            initial=tank.initial_level_m,
        )
        b.var(
            tp.lsh,
            DataType.BOOLEAN,
            f"High level switch of {tank.name}: true at or above {sw.high_m:g} m.",
        )
        b.var(
            tp.lsl,
            DataType.BOOLEAN,
            f"Low level switch of {tank.name}: true at or below {sw.low_m:g} m.",
        )
        b.var(
            tp.leak,
            DataType.DOUBLE,
            f"Opening of the leak valve of {tank.name} to the drain, 0 (closed) .. 1.",
            unit="1",
            eu_range=(0.0, 1.0),
            writers=OPERATOR_UP,
            initial=tank.initial_leak_opening,
        )
        b.var(
            tp.disturbance,
            DataType.DOUBLE,
            f"Extra inflow (+) or outflow (-) of {tank.name} [m^3/s]; an outflow stops at an empty tank.",
            unit="m^3/s",
            eu_range=(-plant_cfg.disturbance_limit_m3_s, plant_cfg.disturbance_limit_m3_s),
            writers=OPERATOR_UP,
        )
        b.var(
            lt.pv,
            DataType.DOUBLE,
            f"Measured level of {tank.name} (noise, quantization, faults) [m]; what the PLC reads.",
            unit="m",
            eu_range=(lo, hi),
            initial=tank.initial_level_m,
        )
        b.var(
            lt.fault,
            DataType.INT32,
            f"Injected fault of LT{i}: NONE, BIAS (+FaultValue m), STUCK (frozen), DRIFT (+FaultValue m/s).",
            eu_range=enum_range(SensorFault),
            writers=OPERATOR_UP,
            enum=SensorFault,
            initial=int(SensorFault.NONE),
        )
        b.var(
            lt.fault_value,
            DataType.DOUBLE,
            f"Size of the LT{i} fault: bias [m] or drift rate [m/s].",
            unit="m or m/s",
            eu_range=(-1.0, 1.0),
            writers=OPERATOR_UP,
        )
    for valve in plant_cfg.valves:
        dest = valve.downstream or "the drain"
        b.var(
            plant.valve_opening(valve.name),
            DataType.DOUBLE,
            f"Opening of valve {valve.name} ({valve.upstream} -> {dest}), 0 (clogged) .. 1.",
            unit="1",
            eu_range=(0.0, 1.0),
            writers=OPERATOR_UP,
            initial=valve.initial_opening,
        )
    for pump in plant_cfg.pumps:
        b.var(
            plant.pump(pump.name).command,
            DataType.DOUBLE,
            f"Command of pump {pump.name} into {pump.feeds} [{pump.unit}] ({pump.command_kind}).",
            unit=pump.unit,
            eu_range=(pump.command_min, pump.command_max),
            writers=frozenset({Role.PLC}),
            initial=pump.initial_command,
        )
        b.var(
            plant.pump(pump.name).flow,
            DataType.DOUBLE,
            f"Actual flow of pump {pump.name} [m^3/s].",
            unit="m^3/s",
            eu_range=(0.0, pump.max_flow_m3_s),
            initial=pump.flow_of(pump.initial_command),
        )
        b.var(
            plant.pump(pump.name).delivered,
            DataType.DOUBLE,
            f"Fraction 0..1 of its command's flow pump {pump.name} delivers (1 healthy; below 1: "
            "pump degradation, a plant fault).",
            unit="1",
            eu_range=(0.0, 1.0),
            writers=OPERATOR_UP,
            initial=1.0,
        )
    b.var(plant.sim_time, DataType.DOUBLE, "Model time since start [s].", unit="s", eu_range=(0.0, 1e12))
    b.var(
        plant.sim_speed,
        DataType.DOUBLE,
        "Model seconds per wall second (0 in lock-step).",
        unit="1",
        eu_range=(0.0, 1e6),
        initial=1.0,
    )
    b.var(
        plant.sim_watchdog,
        DataType.BOOLEAN,
        "True while the pumps are in their safe state because no command came in time.",
    )
    n_t, n_p = len(plant_cfg.tanks), len(plant_cfg.pumps)
    b.method(
        plant.sim_advance,
        "Lock-step only: write the pump commands, integrate `seconds` of model time, return the new "
        "time and the transmitter readings (one round trip).",
        writers=frozenset({Role.PLC}),
        inputs=(
            Argument("seconds", DataType.DOUBLE, "Model time to advance [s], > 0.", "s"),
            Argument(
                "commands",
                DataType.DOUBLE_ARRAY,
                f"Pump commands in pump order ({n_p} values, each in its pump's unit).",
            ),
        ),
        outputs=(
            Argument("time", DataType.DOUBLE, "Model time after the step [s].", "s"),
            Argument("levels", DataType.DOUBLE_ARRAY, f"LT readings in tank order ({n_t} values) [m].", "m"),
        ),
    )
    balance: tuple[tuple[BalanceItem, str], ...] = (
        ("In", "Volume pumped in (plus positive disturbances)"),
        ("Out", "Volume out of the outlets (plus negative disturbances)"),
        ("Leaked", "Volume lost through the leak valves"),
        ("Spilled", "Volume spilled over the tank tops"),
        ("Stored", "Volume in the tanks now"),
        ("Error", "Stored + Out + Leaked + Spilled - In - initial stored (zero up to rounding)"),
    )
    for item, text in balance:
        b.var(plant.balance(item), DataType.DOUBLE, f"{text} [m^3].", unit="m^3", eu_range=(-1e6, 1e6))
    return b.tags


def plc_tags(site: SiteConfig) -> list[Tag]:
    """Nodes of the soft PLC for ``site`` (needs a ``plc`` section)."""
    if site.plc is None:
        raise ValueError(f"site {site.name!r} has no plc section")
    b = TagList("plc")
    _identity(b, site)
    plc_cfg = site.plc
    for lp in plc_cfg.loops:
        pump = site.plant.pump(lp.actuator)
        mv_lo = lp.mv_min if lp.mv_min is not None else pump.command_min
        mv_hi = lp.mv_max if lp.mv_max is not None else pump.command_max
        tank = site.plant.tank("T" + lp.pv[2:])
        lpp = plc.loop(lp.name)
        b.var(
            lpp.sp,
            DataType.DOUBLE,
            f"Setpoint of {tank.name}'s level [m]; range-checked.",
            unit="m",
            eu_range=(lp.sp_min_m, lp.sp_max_m),
            writers=OPERATOR_UP,
            initial=lp.setpoint_m,
        )
        b.var(
            lpp.pv,
            DataType.DOUBLE,
            f"Process value: {lp.pv} as the loop used it this scan [m].",
            unit="m",
            eu_range=tank.transmitter_range(),
        )
        b.var(
            lpp.mv,
            DataType.DOUBLE,
            f"Output written to {pump.name} this scan [{pump.unit}].",
            unit=pump.unit,
            eu_range=(mv_lo, mv_hi),
        )
        b.var(
            lpp.mode,
            DataType.INT32,
            "MANUAL (ManualMV drives), AUTO (the block drives), REMOTE (RemoteMV drives). The "
            "supervisor, or the External identity on a loop handed to it (RemoteSource), switches "
            "between AUTO and REMOTE only.",
            eu_range=enum_range(LoopMode),
            writers=OPERATOR_UP | {Role.SUPERVISOR, Role.EXTERNAL},
            restricted=(
                (Role.SUPERVISOR, frozenset({int(LoopMode.AUTO), int(LoopMode.REMOTE)})),
                (Role.EXTERNAL, frozenset({int(LoopMode.AUTO), int(LoopMode.REMOTE)})),
            ),
            enum=LoopMode,
            initial=int(lp.mode_enum),
        )
        for path, low, text in ((lpp.sp_low, True, "lowest"), (lpp.sp_high, False, "highest")):
            b.var(
                path,
                DataType.DOUBLE,
                f"Program limit (engineer): the {text} setpoint an operator may write [m]; inside the "
                f"config's {lp.sp_min_m:g} .. {lp.sp_max_m:g} m, and the current SP must stay inside.",
                unit="m",
                eu_range=(lp.sp_min_m, lp.sp_max_m),
                writers=ENGINEER_ONLY,
                initial=lp.sp_min_m if low else lp.sp_max_m,
            )
        b.var(
            lpp.manual_mv,
            DataType.DOUBLE,
            f"Operator's output in MANUAL [{pump.unit}].",
            unit=pump.unit,
            eu_range=(mv_lo, mv_hi),
            writers=OPERATOR_UP,
            initial=lp.manual_mv if lp.manual_mv is not None else pump.initial_command,
        )
        b.var(
            lpp.remote_mv,
            DataType.DOUBLE,
            f"Output in REMOTE [{pump.unit}]: written by the supervisor, or by the External "
            "identity when RemoteSource is EXTERNAL (the other one is refused).",
            unit=pump.unit,
            eu_range=(mv_lo, mv_hi),
            writers=frozenset({Role.SUPERVISOR, Role.EXTERNAL}),
        )
        b.var(
            lpp.remote_source,
            DataType.INT32,
            "Who drives the loop in REMOTE (engineer; retentive): SUPERVISOR (the supervisor's "
            "identity and heartbeat) or EXTERNAL (an External certificate identity and "
            "PLC.External.Heartbeat). Changed only while the loop is not in REMOTE "
            "(BadInvalidState).",
            eu_range=enum_range(RemoteSource),
            writers=ENGINEER_ONLY,
            enum=RemoteSource,
            initial=int(RemoteSource.SUPERVISOR),
        )
        g = lp.gains
        for gain, text, val in (
            (lpp.kp, "Applied proportional gain [MV unit per error unit]", g.kp if g else 0.0),
            (lpp.ki, "Applied integral gain [MV unit per error unit per s]", g.ki if g else 0.0),
            (lpp.kd, "Applied derivative gain [MV unit s per error unit]", g.kd if g else 0.0),
        ):
            b.var(gain, DataType.DOUBLE, f"{text}; changed only through SetGains.", initial=val)
        b.var(
            lpp.gain_source,
            DataType.INT32,
            "Where the applied gains came from: FIXED (configured, or kept by ReleaseGains), SUPERVISOR, "
            "FALLBACK (supervisor lost), ENGINEER (an engineer's SetGains; the supervisor's SetGains "
            "is refused until ReleaseGains or ResetGains).",
            eu_range=enum_range(GainSource),
            enum=GainSource,
            initial=int(GainSource.FIXED),
        )
        b.var(lpp.block, DataType.STRING, "Control block of the loop: pid, nlpi or mrac.", initial=lp.block)
        b.method(
            lpp.set_gains,
            "Stage (Kp, Ki, Kd) for the next scan boundary. All finite and inside the gain box, or the "
            "whole call is refused (BadOutOfRange / BadTypeMismatch); BadInvalidState for a block "
            "without PID gains. An engineer's call is labelled ENGINEER and works whatever the "
            "supervisor's state; the supervisor's is labelled SUPERVISOR and refused (BadInvalidState) "
            "while the supervisor is not trusted or the loop is ENGINEER.",
            writers=frozenset({Role.ENGINEER, Role.SUPERVISOR}),
            inputs=(
                Argument("Kp", DataType.DOUBLE, "Proportional gain."),
                Argument("Ki", DataType.DOUBLE, "Integral gain [per s]."),
                Argument("Kd", DataType.DOUBLE, "Derivative gain [s]."),
            ),
        )
        b.method(
            lpp.reset_gains,
            "Return the loop to its configured (FIXED) gains at the next scan boundary, bumplessly; "
            "GainSource FIXED (releases an ENGINEER hold). BadInvalidState for a block without PID "
            "gains or while a mode change of the loop is pending (written since the last scan).",
            writers=OPERATOR_UP,
        )
        b.method(
            lpp.release_gains,
            "Hand an ENGINEER loop back to adaptation: the applied gains stay, GainSource FIXED until "
            "the supervisor pushes again. No change on a loop not held; BadInvalidState for a block "
            "without PID gains.",
            writers=OPERATOR_UP,
        )
    b.var(plc.scan, DataType.UINT32, "Scan counter, +1 per completed scan.")
    b.var(
        plc.scan_period,
        DataType.DOUBLE,
        "Scan period in model time [s].",
        unit="s",
        eu_range=(0.0, 3600.0),
        initial=plc_cfg.scan_period_s,
    )
    b.var(
        plc.last_scan_duration,
        DataType.DOUBLE,
        "Wall time the last scan's work took [s].",
        unit="s",
        eu_range=(0.0, 3600.0),
    )
    b.var(plc.overruns, DataType.UINT32, "Scans whose work ran past the next deadline.")
    b.var(plc.io_healthy, DataType.BOOLEAN, "True while the field link to the plant works.")
    _link_status(b, plc.plant_link, "plant")
    b.var(
        plc.model_time,
        DataType.DOUBLE,
        "Model time of the last scan [s].",
        unit="s",
        eu_range=(0.0, 1e12),
    )
    b.var(
        HEARTBEAT_PATH,
        DataType.UINT32,
        "Written by the supervisor every cycle (any change counts as alive).",
        writers=frozenset({Role.SUPERVISOR}),
    )
    b.var(
        plc.supervisor_timeout,
        DataType.DOUBLE,
        "Heartbeat timeout in model time [s].",
        unit="s",
        eu_range=(0.0, 3600.0),
        initial=plc_cfg.watchdog.timeout_s,
    )
    b.var(plc.supervisor_alive, DataType.BOOLEAN, "False once no heartbeat change came within Timeout.")
    b.var(
        plc.external_heartbeat,
        DataType.UINT32,
        "Written by the external controller (role External) every period (any change counts as "
        "alive); loops in REMOTE with RemoteSource EXTERNAL shed to AUTO when it stops.",
        writers=frozenset({Role.EXTERNAL}),
    )
    b.var(
        plc.external_timeout,
        DataType.DOUBLE,
        "External heartbeat timeout in model time [s] (the supervisor's).",
        unit="s",
        eu_range=(0.0, 3600.0),
        initial=plc_cfg.watchdog.timeout_s,
    )
    b.var(
        plc.external_alive, DataType.BOOLEAN, "False once no external heartbeat change came within Timeout."
    )
    for tank in site.plant.tanks:
        i = tank.name[1:]
        b.var(
            plc.io(tank.name).pv,
            DataType.DOUBLE,
            f"LT{i} as the PLC read it this scan [m].",
            unit="m",
            eu_range=tank.transmitter_range(),
        )
        b.var(plc.io(tank.name).good, DataType.BOOLEAN, f"The PLC's quality for LT{i}: true when usable.")
    tripped_tanks = [il.tank for il in plc_cfg.interlocks]
    for tank_name in tripped_tanks:
        b.var(
            plc.interlock(tank_name),
            DataType.BOOLEAN,
            f"High-high trip of {tank_name} (latched): its pump is stopped.",
        )
    b.method(
        plc.interlock_reset,
        "Reset latched trips whose level is back below the reset level.",
        writers=OPERATOR_UP,
    )
    alarms: tuple[tuple[AlarmKind, str], ...] = (("H", "high"), ("L", "low"), ("HH", "high-high"))
    for tank in site.plant.tanks:
        for kind, text in alarms:
            b.var(plc.alarm(tank.name, kind), DataType.BOOLEAN, f"{tank.name} level {text} alarm.")
    for lp in plc_cfg.loops:
        b.var(plc.pv_bad_alarm(lp.name), DataType.BOOLEAN, f"{lp.name}'s PV is bad (substitute output).")
    b.var(plc.io_fault, DataType.BOOLEAN, "The field link to the plant is lost.")
    b.var(plc.supervisor_lost, DataType.BOOLEAN, "The supervisor's heartbeat timed out.")
    _alarm_summary(b)
    return b.tags


DIAGNOSTIC_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")
"""A controller diagnostic's name: a browse name of letters, digits and underscores."""

DIAGNOSTIC_TYPES = {float: DataType.DOUBLE, bool: DataType.BOOLEAN, str: DataType.STRING}


@dataclass(frozen=True)
class Diagnostic:
    """One diagnostic a supervisory controller declares (decision 0054): published as
    ``Supervisor.Controller.Diagnostics.<name>``.

    Attributes
    ----------
    name : browse name (letters, digits, underscores; starts with a letter).
    kind : float (a Double, finite), bool or str.
    description : what it shows, with its unit.  unit : the unit of a float ("" for none).
    """

    name: str
    kind: type[float] | type[bool] | type[str] = float
    description: str = ""
    unit: str = ""

    def __post_init__(self) -> None:
        if not DIAGNOSTIC_NAME.match(self.name):
            raise ValueError(
                f"diagnostic name {self.name!r}: letters, digits and underscores, starting with a letter"
            )
        if self.kind not in DIAGNOSTIC_TYPES:
            raise ValueError(f"diagnostic {self.name}: kind must be float, bool or str, not {self.kind!r}")


def controller_tags(b: TagList, diagnostics: Sequence[Diagnostic]) -> None:
    """The supervisory controller's fixed nodes and its declared diagnostics."""
    sup = supervisor
    b.var(sup.controller_class, DataType.STRING, "The supervisory controller's class (package.module:Class).")
    b.var(sup.controller_cycles, DataType.UINT32, "Steps of the controller called.")
    b.var(
        sup.controller_errors,
        DataType.UINT32,
        "Steps whose output was discarded: the controller raised, returned a non-finite or out-of-range "
        "value or a malformed output (the last safe action held).",
    )
    b.var(sup.controller_last_error, DataType.STRING, "The last error: kind and message (empty until one).")
    b.var(
        sup.controller_overruns,
        DataType.UINT32,
        "Steps that took more CPU time than the budget (their output discarded, the last safe action held).",
    )
    seen: set[str] = set()
    for d in diagnostics:
        if d.name in seen:
            raise ValueError(f"diagnostic {d.name} declared twice")
        seen.add(d.name)
        analog = d.kind is float  # every Double is an AnalogItemType (unit "1": dimensionless)
        b.var(
            sup.controller_diagnostic(d.name),
            DIAGNOSTIC_TYPES[d.kind],
            d.description or f"The controller's diagnostic {d.name}.",
            unit=(d.unit or "1") if analog else None,
            eu_range=(-1e300, 1e300) if analog else None,
        )


def _fdi_tags(b: TagList, site: SiteConfig) -> None:
    """The fault diagnosis' nodes (``Supervisor.FDI.*``, docs/fdi.md): per hypothesis the GLR
    statistic, its threshold, alarm and size estimate; the diagnosis, its size and confidence."""
    b.var(
        supervisor.fdi_state,
        DataType.INT32,
        "WARMUP, NORMAL, DETECTED (a test over its threshold, not isolated), ISOLATED.",
        eu_range=enum_range(FdiState),
        enum=FdiState,
    )
    b.var(
        supervisor.fdi_diagnosis,
        DataType.STRING,
        "The isolated fault (Leak_T1, Bias_LT2, ...), empty if none.",
    )
    b.var(
        supervisor.fdi_kind,
        DataType.INT32,
        "Class of the isolated fault (NONE if none).",
        eu_range=enum_range(FaultKind),
        enum=FaultKind,
    )
    b.var(
        supervisor.fdi_size,
        DataType.DOUBLE,
        "Estimated size: leak opening, clog fraction lost, pump fraction delivered, bias [m], drift [m/s], "
        "stuck value [m].",
    )
    b.var(supervisor.fdi_size_std, DataType.DOUBLE, "Standard deviation of the size estimate (same unit).")
    b.var(
        supervisor.fdi_confidence,
        DataType.DOUBLE,
        "Posterior confidence of the best hypothesis (0 when nothing is detected).",
        unit="1",
        eu_range=(0.0, 1.0),
    )
    b.var(supervisor.fdi_best, DataType.STRING, "The leading hypothesis while a test is over its threshold.")
    b.var(
        supervisor.fdi_message,
        DataType.STRING,
        "The diagnosis as a sentence (FDI leak T3 est. opening 0.21 ...).",
    )
    for kind, element in site_hypotheses(site):
        name = hypothesis_name(kind, element)
        hp = supervisor.fdi_hypothesis(name)
        what = "repeats (or bad readings) in a row" if kind is FaultKind.STUCK else "GLR statistic 2 ln LR"
        b.var(hp.statistic, DataType.DOUBLE, f"{name}: {what}.")
        b.var(hp.threshold, DataType.DOUBLE, f"{name}: threshold of the statistic.")
        b.var(hp.alarm, DataType.BOOLEAN, f"{name}: the statistic is at or over its threshold.")
        b.var(hp.size, DataType.DOUBLE, f"{name}: size estimate at the best onset.")


def supervisor_tags(site: SiteConfig, diagnostics: Sequence[Diagnostic] = ()) -> list[Tag]:
    """Nodes of the supervisor for ``site`` (needs ``plc`` and ``supervisor`` sections), with the
    declared ``diagnostics`` of its supervisory controller (the shipped one declares none)."""
    if site.supervisor is None or site.plc is None:
        raise ValueError(f"site {site.name!r} has no supervisor section")
    b = TagList("supervisor")
    _identity(b, site)
    sup = site.supervisor
    pumps = ", ".join(site.pump_names)
    zs = ", ".join(sup.mpc.controlled)
    b.var(
        supervisor.mode,
        DataType.INT32,
        "OFF, ADVISORY (compute and publish), ADAPTIVE_PID (push PID gains), MPC (drive the pumps).",
        eu_range=enum_range(SupervisorMode),
        writers=ENGINEER_ONLY,
        enum=SupervisorMode,
        initial=int(sup.mode_enum),
    )
    b.var(supervisor.cycle, DataType.UINT32, "Supervisor cycles run.")
    b.var(supervisor.plc_connected, DataType.BOOLEAN, "True while the PLC link is up and fresh.")
    _link_status(b, supervisor.plc_link, "PLC")
    b.var(
        supervisor.mpc_solve_time,
        DataType.DOUBLE,
        "QP solve time of the last step (OSQP's) [s].",
        unit="s",
        eu_range=(0.0, 60.0),
    )
    b.var(supervisor.mpc_iterations, DataType.UINT32, "Solver iterations of the last step.")
    b.var(
        supervisor.mpc_status,
        DataType.INT32,
        "Outcome of the last MPC step.",
        eu_range=enum_range(MpcStatus),
        enum=MpcStatus,
        initial=int(MpcStatus.NOT_RUN),
    )
    b.var(supervisor.mpc_failures, DataType.UINT32, "Steps whose QP failed (shifted plan used).")
    b.var(
        supervisor.mpc_horizon, DataType.UINT32, "Prediction horizon Np [samples].", initial=sup.mpc.horizon
    )
    b.var(
        supervisor.mpc_planned_mv,
        DataType.DOUBLE_ARRAY,
        f"Planned pump flows [m^3/s], step-major, pumps inner ({pumps}); Np x pumps values.",
    )
    b.var(
        supervisor.mpc_predicted_pv,
        DataType.DOUBLE_ARRAY,
        f"Predicted controlled levels [m], step-major, levels inner ({zs}); Np x levels values.",
    )
    _fdi_tags(b, site)
    for lp in site.plc.loops:
        rp = supervisor.rls(lp.name)
        b.var(
            rp.theta,
            DataType.DOUBLE_ARRAY,
            "Estimated gains [Kp, Ki, Kd] per loop used (own loop first in diagonal mode).",
        )
        b.var(
            rp.covariance_trace,
            DataType.DOUBLE,
            "Trace of the RLS covariance.",
            unit="1",
            eu_range=(0.0, 1e12),
        )
        b.var(rp.accepted, DataType.UINT32, "Gain sets pushed and accepted.")
        b.var(rp.rejected, DataType.UINT32, "Candidate gain sets rejected by a guard or the PLC.")
        b.var(rp.last_reason, DataType.STRING, "Why the last candidate was rejected (empty if accepted).")
        b.var(
            rp.excitation,
            DataType.DOUBLE,
            "Smallest eigenvalue of the remembered data's information matrix (dimensionless): how well "
            "the weakest gain direction is measured.",
            unit="1",
            eu_range=(0.0, 1e12),
        )
        b.var(
            rp.condition_number,
            DataType.DOUBLE,
            "Condition number of the estimator's information matrix (prior + data).",
            unit="1",
            eu_range=(1.0, 1e16),
            initial=1.0,
        )
        b.var(
            rp.box_distance,
            DataType.DOUBLE_ARRAY,
            "Distance of each estimated gain [Kp, Ki, Kd] to the nearest gain-box limit, as a fraction "
            "of the box width (0 on a limit, 0.5 in the middle).",
            unit="1",
            eu_range=(0.0, 0.5),
        )
        b.var(
            rp.on_box_limit,
            DataType.BOOLEAN,
            "Diagnostic: the estimate or the applied gains sit on a gain-box limit (the box, not the "
            "data, decides that gain).",
        )
        b.var(
            rp.prior,
            DataType.DOUBLE_ARRAY,
            "Model-based (SIMC) gains [Kp, Ki, Kd] the estimate is regularised toward.",
        )
        b.var(
            rp.noise_std,
            DataType.DOUBLE,
            "Estimated level-transmitter noise of the loop's PV [m] (from the model's prediction errors).",
            unit="m",
            eu_range=(0.0, 1.0),
        )
    b.var(
        supervisor.disturbance,
        DataType.DOUBLE_ARRAY,
        f"Estimated input disturbances [m^3/s], one per disturbance state (pumps: {pumps}).",
    )
    controller_tags(b, diagnostics)
    _alarm_summary(b)
    return b.tags


def historian_tags(site: SiteConfig) -> list[Tag]:
    """Status nodes of the historian for ``site`` (its own; the recorded tiers' NodeIds are served
    for HistoryRead by the historian's history service, not as live nodes)."""
    b = TagList("historian")
    _identity(b, site)
    for tier in SOURCE_TIERS:
        if (tier == "plc" and site.plc is None) or (tier == "supervisor" and site.supervisor is None):
            continue
        tp = historian.tier(tier)
        b.var(tp.connected, DataType.BOOLEAN, f"True while the {tier} is subscribed and its clock advances.")
        b.var(
            tp.last_sample,
            DataType.DOUBLE,
            f"Source time of the newest sample received from the {tier} (UTC seconds since 1970; 0 "
            "before the first) [s].",
            unit="s",
            eu_range=(0.0, 1e11),
        )
        b.var(tp.samples, DataType.UINT32, f"Samples received from the {tier} since start.")
        b.var(
            tp.gaps,
            DataType.UINT32,
            f"Gaps marked in the {tier}'s tags since start (its clock stopped advancing or its link "
            "dropped: one Bad sample per tag at the gap's start).",
        )
        _link_status(b, tp.link, tier)
    b.var(
        historian.buffered,
        DataType.UINT32,
        "Samples and events received and not yet stored (waiting in the bounded buffer).",
    )
    b.var(
        historian.dropped,
        DataType.UINT32,
        "Samples and events dropped since start because the buffer was full (the store was away).",
    )
    b.var(historian.stored, DataType.UINT32, "Samples stored since start (new rows; duplicates not counted).")
    b.var(historian.events, DataType.UINT32, "Events stored since start (new rows).")
    b.var(historian.store_kind, DataType.STRING, "The store's back end: sqlite or postgresql.")
    b.var(historian.store_available, DataType.BOOLEAN, "True while the last write to the store succeeded.")
    b.var(
        historian.store_error,
        DataType.STRING,
        "Why the last write to the store failed: exception class and message (empty until then).",
    )
    b.var(
        historian.retention_deleted,
        DataType.UINT32,
        "Samples and events deleted by retention since start.",
    )
    return b.tags


def all_tags(site: SiteConfig) -> list[Tag]:
    """Every node of every tier the site has."""
    tags = plant_tags(site)
    if site.plc is not None:
        tags += plc_tags(site)
    if site.supervisor is not None:
        tags += supervisor_tags(site)
    return tags + historian_tags(site)


def tags_by_path(tags: list[Tag]) -> dict[str, Tag]:
    """Index tags by path (paths are unique; a duplicate is a contract bug)."""
    out: dict[str, Tag] = {}
    for t in tags:
        if t.path in out:
            raise ValueError(f"duplicate tag path {t.path}")
        out[t.path] = t
    return out


def render_markdown(site: SiteConfig) -> str:
    """The address-space document (docs/address-space.md) for ``site``."""
    lines = [
        "# Address space",
        "",
        "<!-- Generated by `tankctl docs address-space` from `tanklab.tags`; a test fails when stale. -->",
        "",
        f"Namespace URI `{NAMESPACE_URI}`; NodeIds are `ns=<index of {NAMESPACE_URI}>;s=<path>`. Clients",
        "look the index up from the URI. Browse names equal the last path element; objects nest along",
        "the dots. Analog values are AnalogItemType (EngineeringUnits, EURange); enumerations are Int32",
        "MultiStateDiscreteType nodes with EnumStrings. Every write outside EURange, of the wrong type, NaN",
        "or infinite is refused with a Bad status code and the old value stays.",
        "",
        f"Tags are numbered per site; this listing is for `{site.name}` (the default config). The single",
        "tank has T1, LT1, P1 and LIC1 only; the two interacting tanks T1, T2, V12, V10, V20.",
        "",
        "ApplicationUris: " + ", ".join(f"`{u}`" for u in APPLICATION_URIS.values()) + ".",
        "",
        "Roles: Observer (read), Operator, Engineer, Supervisor (the supervisor's identity), PLC (the",
        "PLC's identity on the plant), External (an external controller's certificate identity: only",
        "on the loops whose RemoteSource is EXTERNAL). Reading is open to every role.",
        "",
    ]
    for title, tier, builder in (
        ("Plant", "plant", plant_tags),
        ("PLC", "plc", plc_tags),
        ("Supervisor", "supervisor", supervisor_tags),
        ("Historian", "historian", historian_tags),
    ):
        if (tier == "plc" and site.plc is None) or (tier == "supervisor" and site.supervisor is None):
            continue
        endpoint = getattr(site.endpoints, tier).url(tier)
        lines += [f"## {title} (`{endpoint}`)", ""]
        lines += ["| path | type | unit | EURange | writable by | description |", "|---|---|---|---|---|---|"]
        for t in builder(site):
            if t.kind == "method":
                args = ", ".join(f"{a.name}: {a.data_type.value}" for a in t.inputs)
                outs = ", ".join(f"{a.name}: {a.data_type.value}" for a in t.outputs)
                typ = f"method ({args})" + (f" -> ({outs})" if outs else "")
            else:
                typ = t.data_type.value if t.data_type else ""
                if t.enum is not None:
                    typ += " enum " + "/".join(f"{m.name}={int(m)}" for m in t.enum)
            rng = f"{t.eu_range[0]:g} .. {t.eu_range[1]:g}" if t.eu_range else ""
            limits = dict(t.restricted)
            who = (
                ", ".join(
                    r.value
                    + (
                        " (" + "/".join(enum_name(t, v) for v in sorted(limits[r])) + " only)"
                        if r in limits
                        else ""
                    )
                    for r in sorted(t.writers)
                )
                or "read-only"
            )
            lines.append(f"| `{t.path}` | {typ} | {t.unit or ''} | {rng} | {who} | {t.description} |")
        lines.append("")
    return "\n".join(lines)
