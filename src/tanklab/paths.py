"""Node paths of the contract, built in one place: ``plant.lt("T1").pv == "Plant.LT1.PV"``.

A node path is the dotted string NodeId of a tag (``ns=<urn:tanklab>;s=<path>``, see
:mod:`tanklab.tags`). Every module that names a node asks these builders for its path instead
of spelling it, so a path changes here or nowhere (a test fails on a node path literal
anywhere else in ``src``). The builders are typed (an attribute per node, a method per
numbered object) and cached: building a path in a scan costs a dictionary look-up.

Numbering follows the site config's names: tank ``T<i>`` has level transmitter ``LT<i>``
(``plant.lt("T1")``, ``plc.io("T1")``); loops, pumps and valves go by their own names
(``plc.loop("LIC1")``, ``plant.pump("P1")``, ``plant.valve("V12")``).

Only the path strings live here; what each node is (type, unit, range, writers) is
:mod:`tanklab.tags`.
"""

from __future__ import annotations

from functools import cache
from typing import Literal

Tier = Literal["plant", "plc", "supervisor", "historian"]

SourceTier = Literal["plant", "plc", "supervisor"]
"""The tiers the historian records (every tier but itself)."""

SOURCE_TIERS: tuple[SourceTier, ...] = ("plant", "plc", "supervisor")

TIER_ROOTS: dict[Tier, str] = {
    "plant": "Plant",
    "plc": "PLC",
    "supervisor": "Supervisor",
    "historian": "Historian",
}
"""The root object of each tier's nodes."""

LINK_STATUS_ITEMS = ("Attempts", "Connects", "LastError", "RetryDelay")
"""Diagnostics of a tier's link to the tier below (:class:`tanklab_io.ua_client.Link`), one node each."""

IDENTITY_ITEMS = ("SiteName", "ConfigDigest", "Config")
"""What each tier says about the site it runs (:mod:`tanklab.identity`), one node each."""

BALANCE_ITEMS = ("In", "Out", "Leaked", "Spilled", "Stored", "Error")
"""The plant's water-balance nodes (``Plant.Balance.<item>``, volumes in m^3)."""

AlarmSummaryItem = Literal[
    "Active",
    "Unacknowledged",
    "Shelved",
    "Suppressed",
    "Disabled",
    "RatePer10Min",
    "PeakRatePer10Min",
    "Flood",
]
ALARM_SUMMARY_ITEMS: tuple[AlarmSummaryItem, ...] = (
    "Active",
    "Unacknowledged",
    "Shelved",
    "Suppressed",
    "Disabled",
    "RatePer10Min",
    "PeakRatePer10Min",
    "Flood",
)
"""A tier's alarm summary nodes (``<Tier>.AlarmSummary.<item>``: counts, ISA-18.2 rates, flood)."""

BalanceItem = Literal["In", "Out", "Leaked", "Spilled", "Stored", "Error"]
AlarmKind = Literal["H", "L", "HH"]

PROBE_PATHS: dict[str, str] = {
    "plant": "Plant.Sim.Time",
    "plc": "PLC.Status.Scan",
    "supervisor": "Supervisor.Mode",
    "historian": "Historian.Status.StoreKind",
}
"""The node a readiness or health probe reads on each tier: one that every site has and that
the tier serves from its first second (``tankctl.health``, ``tankctl up``)."""


def link_status_paths(prefix: str) -> dict[str, str]:
    """Path of each :data:`LINK_STATUS_ITEMS` node under ``prefix`` (``PLC.Status.PlantLink``)."""
    return {item: f"{prefix}.{item}" for item in LINK_STATUS_ITEMS}


def identity_paths(tier: Tier) -> dict[str, str]:
    """Path of each :data:`IDENTITY_ITEMS` node of ``tier`` (``PLC.Identity.ConfigDigest``)."""
    return {item: f"{TIER_ROOTS[tier]}.Identity.{item}" for item in IDENTITY_ITEMS}


@cache
def alarm_summary_paths(tier: Tier) -> dict[AlarmSummaryItem, str]:
    """Path of each :data:`ALARM_SUMMARY_ITEMS` node of ``tier`` (``PLC.AlarmSummary.Active``).

    The returned mapping is shared (cached): do not change it."""
    return {item: f"{TIER_ROOTS[tier]}.AlarmSummary.{item}" for item in ALARM_SUMMARY_ITEMS}


def tier_root(tier: Tier) -> str:
    """The root object of ``tier``'s nodes (``PLC``); its notifier is the tier's event source."""
    return TIER_ROOTS[tier]


CONDITIONS = "Conditions"
"""The NodeId segment under a tier's root that holds its alarm conditions' ids."""


@cache
def condition(tier: Tier, name: str) -> str:
    """The NodeId string of ``tier``'s alarm condition ``name`` (``PLC.Conditions.T1Level``).

    A condition's id is derived from its definition's name alone, so a client that knows the
    name (``tankctl ack T1Level``) needs no browse; in the address space the condition is a
    component of its source node (``tanklab_io.conditions``), so unlike a tag its NodeId is not
    its browse path. Its children's ids follow asyncua's rule for string ids: the parent's id,
    a dot, the child's BrowseName (``PLC.Conditions.T1Level.AckedState.Id``).
    """
    return f"{TIER_ROOTS[tier]}.{CONDITIONS}.{name}"


# ---- plant ------------------------------------------------------------------------------


class TankPaths:
    """The nodes of one tank (``Plant.T1.*``): true level [m], switches, leak, disturbance."""

    __slots__ = ("disturbance", "leak", "level", "lsh", "lsl", "name")

    def __init__(self, name: str) -> None:
        root = f"Plant.{name}"
        self.name = name
        self.level = f"{root}.Level"
        self.lsh = f"{root}.LSH"
        self.lsl = f"{root}.LSL"
        self.leak = f"{root}.Leak"
        self.disturbance = f"{root}.Disturbance"


class TransmitterPaths:
    """The nodes of one level transmitter (``Plant.LT1.*``): reading [m], injected fault, size."""

    __slots__ = ("fault", "fault_value", "name", "pv")

    def __init__(self, tank: str) -> None:
        self.name = f"LT{tank[1:]}"
        root = f"Plant.{self.name}"
        self.pv = f"{root}.PV"
        self.fault = f"{root}.Fault"
        self.fault_value = f"{root}.FaultValue"


class PumpPaths:
    """The nodes of one pump (``Plant.P1.*``): command [pump unit], flow [m^3/s] and the
    fraction 0..1 of its command's flow it delivers (pump degradation, a plant fault)."""

    __slots__ = ("command", "delivered", "flow", "name")

    def __init__(self, name: str) -> None:
        self.name = name
        self.command = f"Plant.{name}.Command"
        self.flow = f"Plant.{name}.Flow"
        self.delivered = f"Plant.{name}.Delivered"


class PlantPaths:
    """Every plant node path (``Plant.*``); one instance, :data:`plant`."""

    sim_time = "Plant.Sim.Time"
    sim_speed = "Plant.Sim.Speed"
    sim_watchdog = "Plant.Sim.Watchdog"
    sim_advance = "Plant.Sim.Advance"
    """The lock-step method ``Advance(seconds, commands) -> (time, levels)``."""

    @staticmethod
    @cache
    def tank(name: str) -> TankPaths:
        """Tank ``name`` (``T1``)."""
        return TankPaths(name)

    @staticmethod
    @cache
    def lt(tank: str) -> TransmitterPaths:
        """The level transmitter of tank ``tank`` (``T1`` -> ``LT1``)."""
        return TransmitterPaths(tank)

    @staticmethod
    def transmitter(name: str) -> TransmitterPaths:
        """Level transmitter ``name`` (``LT1``), the same object as ``lt("T1")``."""
        return PlantPaths.lt(f"T{name[2:]}")

    @staticmethod
    @cache
    def pump(name: str) -> PumpPaths:
        """Pump ``name`` (``P1``)."""
        return PumpPaths(name)

    @staticmethod
    @cache
    def valve_opening(name: str) -> str:
        """Opening (0 .. 1) of valve ``name`` (``V12``)."""
        return f"Plant.{name}.Opening"

    @staticmethod
    def balance(item: BalanceItem) -> str:
        """A water-balance volume [m^3] (:data:`BALANCE_ITEMS`)."""
        return f"Plant.Balance.{item}"


# ---- PLC --------------------------------------------------------------------------------


class LoopPaths:
    """The nodes of one PLC loop (``PLC.LIC1.*``)."""

    __slots__ = (
        "block",
        "gain_source",
        "kd",
        "ki",
        "kp",
        "manual_mv",
        "mode",
        "mv",
        "name",
        "pv",
        "release_gains",
        "remote_mv",
        "remote_source",
        "reset_gains",
        "root",
        "set_gains",
        "sp",
        "sp_high",
        "sp_low",
    )

    def __init__(self, name: str) -> None:
        root = f"PLC.{name}"
        self.name = name
        self.root = root
        """The loop's object (the source node of its alarms)."""
        self.sp = f"{root}.SP"
        """Setpoint [m] (operator)."""
        self.pv = f"{root}.PV"
        self.mv = f"{root}.MV"
        self.mode = f"{root}.Mode"
        self.sp_low = f"{root}.SPLow"
        self.sp_high = f"{root}.SPHigh"
        self.manual_mv = f"{root}.ManualMV"
        self.remote_mv = f"{root}.RemoteMV"
        self.remote_source = f"{root}.RemoteSource"
        """Who drives the loop in REMOTE: SUPERVISOR or EXTERNAL (engineer, retentive)."""
        self.kp = f"{root}.Kp"
        self.ki = f"{root}.Ki"
        self.kd = f"{root}.Kd"
        self.gain_source = f"{root}.GainSource"
        self.block = f"{root}.Block"
        self.set_gains = f"{root}.SetGains"
        self.reset_gains = f"{root}.ResetGains"
        self.release_gains = f"{root}.ReleaseGains"

    @property
    def gains(self) -> tuple[str, str, str]:
        """The applied (Kp, Ki, Kd) nodes."""
        return (self.kp, self.ki, self.kd)


class IoPaths:
    """A level as the PLC read it (``PLC.IO.LT1.*``): value [m] and the PLC's quality."""

    __slots__ = ("good", "pv", "root")

    def __init__(self, tank: str) -> None:
        root = f"PLC.IO.LT{tank[1:]}"
        self.root = root
        """The reading's object (the source node of the tank's level alarm)."""
        self.pv = f"{root}.PV"
        self.good = f"{root}.Good"


class PlcPaths:
    """Every PLC node path (``PLC.*``); one instance, :data:`plc`."""

    scan = "PLC.Status.Scan"
    scan_period = "PLC.Status.ScanPeriod"
    last_scan_duration = "PLC.Status.LastScanDuration"
    overruns = "PLC.Status.Overruns"
    io_healthy = "PLC.Status.IoHealthy"
    model_time = "PLC.Status.ModelTime"
    plant_link = "PLC.Status.PlantLink"
    """Prefix of the field link's status nodes (:func:`link_status_paths`)."""
    heartbeat = "PLC.Supervisor.Heartbeat"
    """The supervisor's heartbeat (UInt32): written every scan it acknowledges, checked by the PLC."""
    supervisor_timeout = "PLC.Supervisor.Timeout"
    supervisor_alive = "PLC.Supervisor.Alive"
    external = "PLC.External"
    """The external controller's link object (decision 0055)."""
    external_heartbeat = "PLC.External.Heartbeat"
    """The external controller's heartbeat (UInt32, role External): any change counts as alive."""
    external_timeout = "PLC.External.Timeout"
    external_alive = "PLC.External.Alive"
    interlock_reset = "PLC.Interlock.Reset"
    status = "PLC.Status"
    """The status object (the source node of the IoFault alarm)."""
    supervisor = "PLC.Supervisor"
    """The supervisor link's object (the source node of the SupervisorLost alarm)."""
    interlocks = "PLC.Interlock"
    """The interlocks' object (the source node of the trip alarms)."""
    io_fault = "PLC.Alarms.IoFault"
    supervisor_lost = "PLC.Alarms.SupervisorLost"
    alarms_prefix = "PLC.Alarms."
    """What every alarm node's path starts with (the alarm's name follows it)."""
    interlocks_prefix = "PLC.Interlock."
    """What every interlock node's path starts with (``T1HH``, ``Reset`` follow it)."""

    @staticmethod
    @cache
    def loop(name: str) -> LoopPaths:
        """Loop ``name`` (``LIC1``)."""
        return LoopPaths(name)

    @staticmethod
    @cache
    def io(tank: str) -> IoPaths:
        """The PLC's reading of tank ``tank``'s transmitter (``T1`` -> ``PLC.IO.LT1``)."""
        return IoPaths(tank)

    @staticmethod
    def interlock(tank: str) -> str:
        """The latched high-high trip of tank ``tank`` (``PLC.Interlock.T1HH``)."""
        return f"PLC.Interlock.{tank}HH"

    @staticmethod
    def alarm(tank: str, kind: AlarmKind) -> str:
        """A level alarm of tank ``tank`` (``PLC.Alarms.T1HH``)."""
        return f"PLC.Alarms.{tank}{kind}"

    @staticmethod
    def pv_bad_alarm(loop: str) -> str:
        """Loop ``loop``'s bad-PV alarm (``PLC.Alarms.LIC1PvBad``)."""
        return f"PLC.Alarms.{loop}PvBad"


# ---- supervisor -------------------------------------------------------------------------


class RlsPaths:
    """The adaptation nodes of one loop (``Supervisor.RLS.LIC1.*``)."""

    __slots__ = (
        "accepted",
        "box_distance",
        "condition_number",
        "covariance_trace",
        "excitation",
        "last_reason",
        "noise_std",
        "on_box_limit",
        "prior",
        "rejected",
        "theta",
    )

    def __init__(self, loop: str) -> None:
        root = f"Supervisor.RLS.{loop}"
        self.theta = f"{root}.Theta"
        self.covariance_trace = f"{root}.CovarianceTrace"
        self.accepted = f"{root}.Accepted"
        self.rejected = f"{root}.Rejected"
        self.last_reason = f"{root}.LastReason"
        self.excitation = f"{root}.Excitation"
        self.condition_number = f"{root}.ConditionNumber"
        self.box_distance = f"{root}.BoxDistance"
        self.on_box_limit = f"{root}.OnBoxLimit"
        self.prior = f"{root}.Prior"
        self.noise_std = f"{root}.NoiseStd"


class SupervisorPaths:
    """Every supervisor node path (``Supervisor.*``); one instance, :data:`supervisor`."""

    mode = "Supervisor.Mode"
    cycle = "Supervisor.Cycle"
    plc_connected = "Supervisor.PlcConnected"
    plc_link = "Supervisor.PlcLink"
    """Prefix of the PLC link's status nodes (:func:`link_status_paths`)."""
    mpc = "Supervisor.MPC"
    """The MPC's object (the source node of the MpcFailing alarm)."""
    rls_root = "Supervisor.RLS"
    """The adaptation's object (the source node of the AdaptationUnhealthy alarm)."""
    mpc_solve_time = "Supervisor.MPC.SolveTime"
    mpc_iterations = "Supervisor.MPC.Iterations"
    mpc_status = "Supervisor.MPC.Status"
    mpc_failures = "Supervisor.MPC.Failures"
    mpc_horizon = "Supervisor.MPC.Horizon"
    mpc_planned_mv = "Supervisor.MPC.PlannedMV"
    mpc_predicted_pv = "Supervisor.MPC.PredictedPV"
    disturbance = "Supervisor.Estimator.Disturbance"
    controller = "Supervisor.Controller"
    """The supervisory controller's object (decision 0054)."""
    controller_class = "Supervisor.Controller.Class"
    controller_cycles = "Supervisor.Controller.Cycles"
    controller_errors = "Supervisor.Controller.Errors"
    controller_last_error = "Supervisor.Controller.LastError"
    controller_overruns = "Supervisor.Controller.Overruns"

    @staticmethod
    def controller_diagnostic(name: str) -> str:
        """The node of a controller's declared diagnostic ``name``."""
        return f"Supervisor.Controller.Diagnostics.{name}"

    fdi = "Supervisor.FDI"
    """The fault diagnosis' object (docs/fdi.md)."""
    fdi_state = "Supervisor.FDI.State"
    fdi_diagnosis = "Supervisor.FDI.Diagnosis"
    fdi_kind = "Supervisor.FDI.Kind"
    fdi_size = "Supervisor.FDI.Size"
    fdi_size_std = "Supervisor.FDI.SizeStd"
    fdi_confidence = "Supervisor.FDI.Confidence"
    fdi_message = "Supervisor.FDI.Message"
    fdi_best = "Supervisor.FDI.Best"

    @staticmethod
    @cache
    def rls(loop: str) -> RlsPaths:
        """The adaptation nodes of loop ``loop`` (``LIC1``)."""
        return RlsPaths(loop)

    @staticmethod
    @cache
    def fdi_hypothesis(name: str) -> FdiHypothesisPaths:
        """The test nodes of one fault hypothesis (``Leak_T1``)."""
        return FdiHypothesisPaths(name)


class FdiHypothesisPaths:
    """One FDI hypothesis' test (``Supervisor.FDI.Leak_T1.*``): statistic, threshold, alarm."""

    __slots__ = ("alarm", "size", "statistic", "threshold")

    def __init__(self, name: str) -> None:
        root = f"Supervisor.FDI.{name}"
        self.statistic = f"{root}.Statistic"
        self.threshold = f"{root}.Threshold"
        self.alarm = f"{root}.Alarm"
        self.size = f"{root}.Size"


# ---- historian --------------------------------------------------------------------------


class HistorianTierPaths:
    """The historian's view of one recorded tier (``Historian.Status.PLC.*``)."""

    __slots__ = ("connected", "gaps", "last_sample", "link", "root", "samples")

    def __init__(self, tier: SourceTier) -> None:
        root = f"Historian.Status.{TIER_ROOTS[tier]}"
        self.root = root
        self.connected = f"{root}.Connected"
        self.last_sample = f"{root}.LastSample"
        self.samples = f"{root}.Samples"
        self.gaps = f"{root}.Gaps"
        self.link = f"{root}.Link"
        """Prefix of the link's status nodes (:func:`link_status_paths`)."""


class HistorianPaths:
    """Every historian node path (``Historian.*``); one instance, :data:`historian`."""

    status = "Historian.Status"
    buffered = "Historian.Status.Buffered"
    dropped = "Historian.Status.Dropped"
    stored = "Historian.Status.Stored"
    events = "Historian.Status.Events"
    store_kind = "Historian.Status.StoreKind"
    store_available = "Historian.Status.StoreAvailable"
    store_error = "Historian.Status.StoreError"
    retention_deleted = "Historian.Status.RetentionDeleted"

    @staticmethod
    @cache
    def tier(name: SourceTier) -> HistorianTierPaths:
        """The status of the historian's collection from tier ``name`` (``plc``)."""
        return HistorianTierPaths(name)


plant = PlantPaths()
plc = PlcPaths()
supervisor = SupervisorPaths()
historian = HistorianPaths()
