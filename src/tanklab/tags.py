"""The OPC UA address-space contract: every node of the three tiers, in one place.

All three servers register the namespace URI ``urn:tanklab`` and use string NodeIds
``ns=<index of urn:tanklab>;s=<path>``; browse names equal the last path element and objects
nest along the dots. Tags are numbered per site config (the single tank has T1, LT1, P1 and
LIC1 only), so the contract is a function of the :class:`~tanklab.config.SiteConfig`:
:func:`plant_tags`, :func:`plc_tags` and :func:`supervisor_tags` list the nodes of each tier.

Each :class:`Tag` carries its data type, engineering unit, EURange, which roles may write it,
and a description. Analog values (a unit and a range) become AnalogItemType variables;
enumerations become Int32 MultiStateDiscreteType variables with EnumStrings; methods carry
their argument lists. This module is pure data; :mod:`tanklab.ua` builds the nodes on an
asyncua server and resolves them on a client.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum, StrEnum
from typing import Literal

from tanklab.config import SiteConfig
from tanklab.enums import GainSource, LoopMode, MpcStatus, SensorFault, SupervisorMode
from tanklab.identity import SiteIdentity, canonical_json

NAMESPACE_URI = "urn:tanklab"
"""Namespace URI of every tanklab node; clients look its index up, never hard-code it."""

HEARTBEAT_PATH = "PLC.Supervisor.Heartbeat"
"""The supervisor's heartbeat (UInt32): written every scan it acknowledges, checked by the PLC."""

APPLICATION_URIS = {
    "plant": "urn:tanklab:plant",
    "plc": "urn:tanklab:plc",
    "supervisor": "urn:tanklab:supervisor",
    "cli": "urn:tanklab:cli",
}
"""ApplicationUri of each tier (and of the CLI as a client)."""

Tier = Literal["plant", "plc", "supervisor"]


class Role(StrEnum):
    """Who may do what. Reading is open to every role; writes and calls are listed per tag."""

    OBSERVER = "Observer"
    OPERATOR = "Operator"
    ENGINEER = "Engineer"
    SUPERVISOR = "Supervisor"
    PLC = "PLC"


class DataType(StrEnum):
    """OPC UA built-in types used by the contract."""

    DOUBLE = "Double"
    INT32 = "Int32"
    UINT32 = "UInt32"
    BOOLEAN = "Boolean"
    STRING = "String"
    DOUBLE_ARRAY = "Double[]"


OPERATOR_UP = frozenset({Role.OPERATOR, Role.ENGINEER})
"""Operator-level writes: the operator and the engineer above them."""
ENGINEER_ONLY = frozenset({Role.ENGINEER})
NOBODY: frozenset[Role] = frozenset()


@dataclass(frozen=True)
class Argument:
    """One input or output argument of a method."""

    name: str
    data_type: DataType
    description: str
    unit: str | None = None


@dataclass(frozen=True)
class Tag:
    """One node of the contract.

    Attributes
    ----------
    path
        Dotted path, also the string NodeId (``Plant.T1.Level``).
    tier
        Which server hosts it.
    kind
        ``variable`` or ``method`` (objects are implied by the paths).
    data_type
        Value type of a variable (``None`` for a method).
    unit
        Engineering unit (``m``, ``m^3/s``, ``rpm``, ``s``, ``1``), or ``None``.
    eu_range
        (low, high) of the EURange; writes outside it are refused with BadOutOfRange.
    writers
        Roles that may write the variable or call the method; empty = read-only.
    restricted
        Pairs (role, values): that writer may only move the enumerated value between these
        values (old and new both among them), e.g. the supervisor switches a loop only between
        AUTO and REMOTE.
    description
        What the value means, with its array layout if it is an array.
    enum
        The enumeration of an Int32 enumerated node.
    inputs, outputs
        Method arguments.
    initial
        Value the node is created with.
    """

    path: str
    tier: Tier
    kind: Literal["variable", "method"]
    description: str
    data_type: DataType | None = None
    unit: str | None = None
    eu_range: tuple[float, float] | None = None
    writers: frozenset[Role] = NOBODY
    restricted: tuple[tuple[Role, frozenset[int]], ...] = ()
    enum: type[IntEnum] | None = None
    inputs: tuple[Argument, ...] = ()
    outputs: tuple[Argument, ...] = ()
    initial: float | int | bool | str | list[float] | None = None

    @property
    def name(self) -> str:
        """Browse name: the last path element."""
        return self.path.rsplit(".", 1)[-1]

    @property
    def parent(self) -> str:
        """Path of the object holding this node."""
        return self.path.rsplit(".", 1)[0]

    @property
    def writable(self) -> bool:
        """Whether any role may write (variables) or call (methods) it."""
        return bool(self.writers)

    @property
    def analog(self) -> bool:
        """AnalogItemType: a Double with an engineering unit and a range."""
        return self.data_type == DataType.DOUBLE and self.unit is not None and self.eu_range is not None

    def initial_value(self) -> float | int | bool | str | list[float]:
        """The value the node starts with (a type-appropriate zero unless given)."""
        if self.initial is not None:
            return self.initial
        zeros: dict[DataType, float | int | bool | str | list[float]] = {
            DataType.DOUBLE: 0.0,
            DataType.INT32: 0,
            DataType.UINT32: 0,
            DataType.BOOLEAN: False,
            DataType.STRING: "",
            DataType.DOUBLE_ARRAY: [],
        }
        return zeros[self.data_type or DataType.DOUBLE]


@dataclass
class _Builder:
    tier: Tier
    tags: list[Tag] = field(default_factory=list)

    def var(
        self,
        path: str,
        data_type: DataType,
        description: str,
        *,
        unit: str | None = None,
        eu_range: tuple[float, float] | None = None,
        writers: frozenset[Role] = NOBODY,
        restricted: tuple[tuple[Role, frozenset[int]], ...] = (),
        enum: type[IntEnum] | None = None,
        initial: float | int | bool | str | list[float] | None = None,
    ) -> None:
        self.tags.append(
            Tag(
                path=path,
                tier=self.tier,
                kind="variable",
                description=description,
                data_type=data_type,
                unit=unit,
                eu_range=eu_range,
                writers=writers,
                restricted=restricted,
                enum=enum,
                initial=initial,
            )
        )

    def method(
        self,
        path: str,
        description: str,
        *,
        writers: frozenset[Role],
        inputs: tuple[Argument, ...] = (),
        outputs: tuple[Argument, ...] = (),
    ) -> None:
        self.tags.append(
            Tag(
                path=path,
                tier=self.tier,
                kind="method",
                description=description,
                writers=writers,
                inputs=inputs,
                outputs=outputs,
            )
        )


def _enum_name(tag: Tag, value: int) -> str:
    return tag.enum(value).name if tag.enum is not None else str(value)


def _enum_range(enum: type[IntEnum]) -> tuple[float, float]:
    values = [int(m) for m in enum]
    return (float(min(values)), float(max(values)))


LINK_STATUS_ITEMS = ("Attempts", "Connects", "LastError", "RetryDelay")
"""Diagnostics of a tier's link to the tier below (:class:`tanklab.ua.Link`), one node each."""


def link_status_paths(prefix: str) -> dict[str, str]:
    """Path of each :data:`LINK_STATUS_ITEMS` node under ``prefix`` (``PLC.Status.PlantLink``)."""
    return {item: f"{prefix}.{item}" for item in LINK_STATUS_ITEMS}


def _link_status(b: _Builder, prefix: str, peer: str) -> None:
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


IDENTITY_ITEMS = ("SiteName", "ConfigDigest", "Config")
"""What each tier says about the site it runs (:mod:`tanklab.identity`), one node each."""

TIER_ROOTS: dict[Tier, str] = {"plant": "Plant", "plc": "PLC", "supervisor": "Supervisor"}
"""The root object of each tier's nodes."""


def identity_paths(tier: Tier) -> dict[str, str]:
    """Path of each :data:`IDENTITY_ITEMS` node of ``tier`` (``PLC.Identity.ConfigDigest``)."""
    return {item: f"{TIER_ROOTS[tier]}.Identity.{item}" for item in IDENTITY_ITEMS}


def _identity(b: _Builder, site: SiteConfig) -> None:
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


def plant_tags(site: SiteConfig) -> list[Tag]:
    """Nodes of the plant simulator for ``site``."""
    b = _Builder("plant")
    _identity(b, site)
    plant = site.plant
    for tank in plant.tanks:
        i = tank.name[1:]
        hmax = tank.height_max_m
        sw = tank.switch_levels()
        lo, hi = tank.transmitter_range()
        b.var(
            f"Plant.{tank.name}.Level",
            DataType.DOUBLE,
            f"True level of {tank.name} [m].",
            unit="m",
            eu_range=(0.0, hmax),
            initial=tank.initial_level_m,
        )
        b.var(
            f"Plant.{tank.name}.LSH",
            DataType.BOOLEAN,
            f"High level switch of {tank.name}: true at or above {sw.high_m:g} m.",
        )
        b.var(
            f"Plant.{tank.name}.LSL",
            DataType.BOOLEAN,
            f"Low level switch of {tank.name}: true at or below {sw.low_m:g} m.",
        )
        b.var(
            f"Plant.{tank.name}.Leak",
            DataType.DOUBLE,
            f"Opening of the leak valve of {tank.name} to the drain, 0 (closed) .. 1.",
            unit="1",
            eu_range=(0.0, 1.0),
            writers=OPERATOR_UP,
            initial=tank.initial_leak_opening,
        )
        b.var(
            f"Plant.{tank.name}.Disturbance",
            DataType.DOUBLE,
            f"Extra inflow (+) or outflow (-) of {tank.name} [m^3/s]; an outflow stops at an empty tank.",
            unit="m^3/s",
            eu_range=(-plant.disturbance_limit_m3_s, plant.disturbance_limit_m3_s),
            writers=OPERATOR_UP,
        )
        b.var(
            f"Plant.LT{i}.PV",
            DataType.DOUBLE,
            f"Measured level of {tank.name} (noise, quantization, faults) [m]; what the PLC reads.",
            unit="m",
            eu_range=(lo, hi),
            initial=tank.initial_level_m,
        )
        b.var(
            f"Plant.LT{i}.Fault",
            DataType.INT32,
            f"Injected fault of LT{i}: NONE, BIAS (+FaultValue m), STUCK (frozen), DRIFT (+FaultValue m/s).",
            eu_range=_enum_range(SensorFault),
            writers=OPERATOR_UP,
            enum=SensorFault,
            initial=int(SensorFault.NONE),
        )
        b.var(
            f"Plant.LT{i}.FaultValue",
            DataType.DOUBLE,
            f"Size of the LT{i} fault: bias [m] or drift rate [m/s].",
            unit="m or m/s",
            eu_range=(-1.0, 1.0),
            writers=OPERATOR_UP,
        )
    for valve in plant.valves:
        dest = valve.downstream or "the drain"
        b.var(
            f"Plant.{valve.name}.Opening",
            DataType.DOUBLE,
            f"Opening of valve {valve.name} ({valve.upstream} -> {dest}), 0 (clogged) .. 1.",
            unit="1",
            eu_range=(0.0, 1.0),
            writers=OPERATOR_UP,
            initial=valve.initial_opening,
        )
    for pump in plant.pumps:
        b.var(
            f"Plant.{pump.name}.Command",
            DataType.DOUBLE,
            f"Command of pump {pump.name} into {pump.feeds} [{pump.unit}] ({pump.command_kind}).",
            unit=pump.unit,
            eu_range=(pump.command_min, pump.command_max),
            writers=frozenset({Role.PLC}),
            initial=pump.initial_command,
        )
        b.var(
            f"Plant.{pump.name}.Flow",
            DataType.DOUBLE,
            f"Actual flow of pump {pump.name} [m^3/s].",
            unit="m^3/s",
            eu_range=(0.0, pump.max_flow_m3_s),
            initial=pump.flow_of(pump.initial_command),
        )
    b.var("Plant.Sim.Time", DataType.DOUBLE, "Model time since start [s].", unit="s", eu_range=(0.0, 1e12))
    b.var(
        "Plant.Sim.Speed",
        DataType.DOUBLE,
        "Model seconds per wall second (0 in lock-step).",
        unit="1",
        eu_range=(0.0, 1e6),
        initial=1.0,
    )
    b.var(
        "Plant.Sim.Watchdog",
        DataType.BOOLEAN,
        "True while the pumps are in their safe state because no command came in time.",
    )
    n_t, n_p = len(plant.tanks), len(plant.pumps)
    b.method(
        "Plant.Sim.Advance",
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
    for item, text in (
        ("In", "Volume pumped in (plus positive disturbances)"),
        ("Out", "Volume out of the outlets (plus negative disturbances)"),
        ("Leaked", "Volume lost through the leak valves"),
        ("Spilled", "Volume spilled over the tank tops"),
        ("Stored", "Volume in the tanks now"),
        ("Error", "Stored + Out + Leaked + Spilled - In - initial stored (zero up to rounding)"),
    ):
        b.var(f"Plant.Balance.{item}", DataType.DOUBLE, f"{text} [m^3].", unit="m^3", eu_range=(-1e6, 1e6))
    return b.tags


def plc_tags(site: SiteConfig) -> list[Tag]:
    """Nodes of the soft PLC for ``site`` (needs a ``plc`` section)."""
    if site.plc is None:
        raise ValueError(f"site {site.name!r} has no plc section")
    b = _Builder("plc")
    _identity(b, site)
    plc = site.plc
    for lp in plc.loops:
        pump = site.plant.pump(lp.actuator)
        mv_lo = lp.mv_min if lp.mv_min is not None else pump.command_min
        mv_hi = lp.mv_max if lp.mv_max is not None else pump.command_max
        tank = site.plant.tank("T" + lp.pv[2:])
        p = f"PLC.{lp.name}"
        b.var(
            f"{p}.SP",
            DataType.DOUBLE,
            f"Setpoint of {tank.name}'s level [m]; range-checked.",
            unit="m",
            eu_range=(lp.sp_min_m, lp.sp_max_m),
            writers=OPERATOR_UP,
            initial=lp.setpoint_m,
        )
        b.var(
            f"{p}.PV",
            DataType.DOUBLE,
            f"Process value: {lp.pv} as the loop used it this scan [m].",
            unit="m",
            eu_range=tank.transmitter_range(),
        )
        b.var(
            f"{p}.MV",
            DataType.DOUBLE,
            f"Output written to {pump.name} this scan [{pump.unit}].",
            unit=pump.unit,
            eu_range=(mv_lo, mv_hi),
        )
        b.var(
            f"{p}.Mode",
            DataType.INT32,
            "MANUAL (ManualMV drives), AUTO (the block drives), REMOTE (the supervisor's RemoteMV drives).",
            eu_range=_enum_range(LoopMode),
            writers=OPERATOR_UP | {Role.SUPERVISOR},
            restricted=((Role.SUPERVISOR, frozenset({int(LoopMode.AUTO), int(LoopMode.REMOTE)})),),
            enum=LoopMode,
            initial=int(lp.mode_enum),
        )
        for item, text in (("SPLow", "lowest"), ("SPHigh", "highest")):
            b.var(
                f"{p}.{item}",
                DataType.DOUBLE,
                f"Program limit (engineer): the {text} setpoint an operator may write [m]; inside the "
                f"config's {lp.sp_min_m:g} .. {lp.sp_max_m:g} m, and the current SP must stay inside.",
                unit="m",
                eu_range=(lp.sp_min_m, lp.sp_max_m),
                writers=ENGINEER_ONLY,
                initial=lp.sp_min_m if item == "SPLow" else lp.sp_max_m,
            )
        b.var(
            f"{p}.ManualMV",
            DataType.DOUBLE,
            f"Operator's output in MANUAL [{pump.unit}].",
            unit=pump.unit,
            eu_range=(mv_lo, mv_hi),
            writers=OPERATOR_UP,
            initial=lp.manual_mv if lp.manual_mv is not None else pump.initial_command,
        )
        b.var(
            f"{p}.RemoteMV",
            DataType.DOUBLE,
            f"Supervisor's output in REMOTE [{pump.unit}].",
            unit=pump.unit,
            eu_range=(mv_lo, mv_hi),
            writers=frozenset({Role.SUPERVISOR}),
        )
        g = lp.gains
        for gain, text, val in (
            ("Kp", "Applied proportional gain [MV unit per error unit]", g.kp if g else 0.0),
            ("Ki", "Applied integral gain [MV unit per error unit per s]", g.ki if g else 0.0),
            ("Kd", "Applied derivative gain [MV unit s per error unit]", g.kd if g else 0.0),
        ):
            b.var(f"{p}.{gain}", DataType.DOUBLE, f"{text}; changed only through SetGains.", initial=val)
        b.var(
            f"{p}.GainSource",
            DataType.INT32,
            "Where the applied gains came from: FIXED (configured, or kept by ReleaseGains), SUPERVISOR, "
            "FALLBACK (supervisor lost), ENGINEER (an engineer's SetGains; the supervisor's SetGains "
            "is refused until ReleaseGains or ResetGains).",
            eu_range=_enum_range(GainSource),
            enum=GainSource,
            initial=int(GainSource.FIXED),
        )
        b.var(
            f"{p}.Block", DataType.STRING, "Control block of the loop: pid, nlpi or mrac.", initial=lp.block
        )
        b.method(
            f"{p}.SetGains",
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
            f"{p}.ResetGains",
            "Return the loop to its configured (FIXED) gains at the next scan boundary, bumplessly; "
            "GainSource FIXED (releases an ENGINEER hold). BadInvalidState for a block without PID "
            "gains or while a mode change of the loop is pending (written since the last scan).",
            writers=OPERATOR_UP,
        )
        b.method(
            f"{p}.ReleaseGains",
            "Hand an ENGINEER loop back to adaptation: the applied gains stay, GainSource FIXED until "
            "the supervisor pushes again. No change on a loop not held; BadInvalidState for a block "
            "without PID gains.",
            writers=OPERATOR_UP,
        )
    b.var("PLC.Status.Scan", DataType.UINT32, "Scan counter, +1 per completed scan.")
    b.var(
        "PLC.Status.ScanPeriod",
        DataType.DOUBLE,
        "Scan period in model time [s].",
        unit="s",
        eu_range=(0.0, 3600.0),
        initial=plc.scan_period_s,
    )
    b.var(
        "PLC.Status.LastScanDuration",
        DataType.DOUBLE,
        "Wall time the last scan's work took [s].",
        unit="s",
        eu_range=(0.0, 3600.0),
    )
    b.var("PLC.Status.Overruns", DataType.UINT32, "Scans whose work ran past the next deadline.")
    b.var("PLC.Status.IoHealthy", DataType.BOOLEAN, "True while the field link to the plant works.")
    _link_status(b, "PLC.Status.PlantLink", "plant")
    b.var(
        "PLC.Status.ModelTime",
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
        "PLC.Supervisor.Timeout",
        DataType.DOUBLE,
        "Heartbeat timeout in model time [s].",
        unit="s",
        eu_range=(0.0, 3600.0),
        initial=plc.watchdog.timeout_s,
    )
    b.var("PLC.Supervisor.Alive", DataType.BOOLEAN, "False once no heartbeat change came within Timeout.")
    for tank in site.plant.tanks:
        i = tank.name[1:]
        b.var(
            f"PLC.IO.LT{i}.PV",
            DataType.DOUBLE,
            f"LT{i} as the PLC read it this scan [m].",
            unit="m",
            eu_range=tank.transmitter_range(),
        )
        b.var(f"PLC.IO.LT{i}.Good", DataType.BOOLEAN, f"The PLC's quality for LT{i}: true when usable.")
    tripped_tanks = [il.tank for il in plc.interlocks]
    for tank_name in tripped_tanks:
        b.var(
            f"PLC.Interlock.{tank_name}HH",
            DataType.BOOLEAN,
            f"High-high trip of {tank_name} (latched): its pump is stopped.",
        )
    b.method(
        "PLC.Interlock.Reset",
        "Reset latched trips whose level is back below the reset level.",
        writers=OPERATOR_UP,
    )
    for tank in site.plant.tanks:
        for kind, text in (("H", "high"), ("L", "low"), ("HH", "high-high")):
            b.var(f"PLC.Alarms.{tank.name}{kind}", DataType.BOOLEAN, f"{tank.name} level {text} alarm.")
    for lp in plc.loops:
        b.var(f"PLC.Alarms.{lp.name}PvBad", DataType.BOOLEAN, f"{lp.name}'s PV is bad (substitute output).")
    b.var("PLC.Alarms.IoFault", DataType.BOOLEAN, "The field link to the plant is lost.")
    b.var("PLC.Alarms.SupervisorLost", DataType.BOOLEAN, "The supervisor's heartbeat timed out.")
    return b.tags


def supervisor_tags(site: SiteConfig) -> list[Tag]:
    """Nodes of the supervisor for ``site`` (needs ``plc`` and ``supervisor`` sections)."""
    if site.supervisor is None or site.plc is None:
        raise ValueError(f"site {site.name!r} has no supervisor section")
    b = _Builder("supervisor")
    _identity(b, site)
    sup = site.supervisor
    pumps = ", ".join(site.pump_names)
    zs = ", ".join(sup.mpc.controlled)
    b.var(
        "Supervisor.Mode",
        DataType.INT32,
        "OFF, ADVISORY (compute and publish), ADAPTIVE_PID (push PID gains), MPC (drive the pumps).",
        eu_range=_enum_range(SupervisorMode),
        writers=ENGINEER_ONLY,
        enum=SupervisorMode,
        initial=int(sup.mode_enum),
    )
    b.var("Supervisor.Cycle", DataType.UINT32, "Supervisor cycles run.")
    b.var("Supervisor.PlcConnected", DataType.BOOLEAN, "True while the PLC link is up and fresh.")
    _link_status(b, "Supervisor.PlcLink", "PLC")
    b.var(
        "Supervisor.MPC.SolveTime",
        DataType.DOUBLE,
        "QP solve time of the last step (OSQP's) [s].",
        unit="s",
        eu_range=(0.0, 60.0),
    )
    b.var("Supervisor.MPC.Iterations", DataType.UINT32, "Solver iterations of the last step.")
    b.var(
        "Supervisor.MPC.Status",
        DataType.INT32,
        "Outcome of the last MPC step.",
        eu_range=_enum_range(MpcStatus),
        enum=MpcStatus,
        initial=int(MpcStatus.NOT_RUN),
    )
    b.var("Supervisor.MPC.Failures", DataType.UINT32, "Steps whose QP failed (shifted plan used).")
    b.var(
        "Supervisor.MPC.Horizon", DataType.UINT32, "Prediction horizon Np [samples].", initial=sup.mpc.horizon
    )
    b.var(
        "Supervisor.MPC.PlannedMV",
        DataType.DOUBLE_ARRAY,
        f"Planned pump flows [m^3/s], step-major, pumps inner ({pumps}); Np x pumps values.",
    )
    b.var(
        "Supervisor.MPC.PredictedPV",
        DataType.DOUBLE_ARRAY,
        f"Predicted controlled levels [m], step-major, levels inner ({zs}); Np x levels values.",
    )
    for lp in site.plc.loops:
        p = f"Supervisor.RLS.{lp.name}"
        b.var(
            f"{p}.Theta",
            DataType.DOUBLE_ARRAY,
            "Estimated gains [Kp, Ki, Kd] per loop used (own loop first in diagonal mode).",
        )
        b.var(
            f"{p}.CovarianceTrace",
            DataType.DOUBLE,
            "Trace of the RLS covariance.",
            unit="1",
            eu_range=(0.0, 1e12),
        )
        b.var(f"{p}.Accepted", DataType.UINT32, "Gain sets pushed and accepted.")
        b.var(f"{p}.Rejected", DataType.UINT32, "Candidate gain sets rejected by a guard or the PLC.")
        b.var(f"{p}.LastReason", DataType.STRING, "Why the last candidate was rejected (empty if accepted).")
        b.var(
            f"{p}.Excitation",
            DataType.DOUBLE,
            "Smallest eigenvalue of the remembered data's information matrix (dimensionless): how well "
            "the weakest gain direction is measured.",
            unit="1",
            eu_range=(0.0, 1e12),
        )
        b.var(
            f"{p}.ConditionNumber",
            DataType.DOUBLE,
            "Condition number of the estimator's information matrix (prior + data).",
            unit="1",
            eu_range=(1.0, 1e16),
            initial=1.0,
        )
        b.var(
            f"{p}.BoxDistance",
            DataType.DOUBLE_ARRAY,
            "Distance of each estimated gain [Kp, Ki, Kd] to the nearest gain-box limit, as a fraction "
            "of the box width (0 on a limit, 0.5 in the middle).",
            unit="1",
            eu_range=(0.0, 0.5),
        )
        b.var(
            f"{p}.OnBoxLimit",
            DataType.BOOLEAN,
            "Diagnostic: the estimate or the applied gains sit on a gain-box limit (the box, not the "
            "data, decides that gain).",
        )
        b.var(
            f"{p}.Prior",
            DataType.DOUBLE_ARRAY,
            "Model-based (SIMC) gains [Kp, Ki, Kd] the estimate is regularised toward.",
        )
        b.var(
            f"{p}.NoiseStd",
            DataType.DOUBLE,
            "Estimated level-transmitter noise of the loop's PV [m] (from the model's prediction errors).",
            unit="m",
            eu_range=(0.0, 1.0),
        )
    b.var(
        "Supervisor.Estimator.Disturbance",
        DataType.DOUBLE_ARRAY,
        f"Estimated input disturbances [m^3/s], one per disturbance state (pumps: {pumps}).",
    )
    return b.tags


def all_tags(site: SiteConfig) -> list[Tag]:
    """Every node of every tier the site has."""
    tags = plant_tags(site)
    if site.plc is not None:
        tags += plc_tags(site)
    if site.supervisor is not None:
        tags += supervisor_tags(site)
    return tags


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
        "PLC's identity on the plant). Reading is open to every role.",
        "",
    ]
    for title, tier, builder in (
        ("Plant", "plant", plant_tags),
        ("PLC", "plc", plc_tags),
        ("Supervisor", "supervisor", supervisor_tags),
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
                        " (" + "/".join(_enum_name(t, v) for v in sorted(limits[r])) + " only)"
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
