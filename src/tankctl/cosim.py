"""In-process co-simulation: the plant and the PLC program stepped on a virtual clock.

The same pure cores the processes run (:class:`plant_sim.plant.PlantSimulator`,
:class:`plc_emulator.program.PlcProgram`) are wired in one process, scan by scan:

    readings(t) -> PLC scan -> pump commands -> plant advances Ts -> readings(t + Ts)

exactly the order of the distributed stack in lock-step (the PLC scans, then advances the plant
by one scan period). Deterministic: the plant's noise is seeded and no clock is read, so two runs
give identical traces. An optional ``before_scan`` hook lets a caller (a test, a scenario, the
supervisor) act between scans, as an operator or an OPC UA client would.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from plant_sim.plant import PlantSimulator
from plc_emulator.program import GainStatus, PlcProgram, ScanInputs
from plc_emulator.publish import status_values
from plc_emulator.status import PlcStatus
from plc_emulator.writes import apply_write
from supervisor.controller import SupervisoryController
from supervisor.cycle import PlcSnapshot, SupervisorCore
from supervisor.host import ControllerHost, build_host
from supervisor.port import PlcRequest, SupervisorDriver
from tanklab.config import PidGainsSpec, SiteConfig
from tanklab.enums import LoopMode, SensorFault, SupervisorMode

FloatArray = NDArray[np.float64]


@dataclass
class Trace:
    """Per-scan record of a co-simulation run (arrays grow along the first axis)."""

    t_s: list[float] = field(default_factory=list)
    levels_m: list[FloatArray] = field(default_factory=list)
    readings_m: list[FloatArray] = field(default_factory=list)
    commands: list[FloatArray] = field(default_factory=list)
    setpoints_m: list[FloatArray] = field(default_factory=list)
    flows_m3_s: list[FloatArray] = field(default_factory=list)
    gains: list[FloatArray] = field(default_factory=list)
    """Applied (Kp, Ki, Kd) per loop, (n_loops, 3) per scan."""
    modes: list[FloatArray] = field(default_factory=list)
    """Loop modes per scan (LoopMode values)."""
    trips: list[FloatArray] = field(default_factory=list)
    """Latched interlock trips after each scan (1.0 tripped), one per ``PlcProgram.interlocks``."""
    mpc_solve_s: list[float] = field(default_factory=list)
    """OSQP solve time of the supervisor's MPC step after each scan [s] (NaN when none ran)."""

    def array(self, name: str) -> FloatArray:
        """One recorded quantity as an array (scans x items)."""
        return np.asarray(getattr(self, name), dtype=float)


def _setpoint_row(sps: tuple[float, ...]) -> FloatArray:
    return np.array(sps)


def _gain_rows(applied: tuple[PidGainsSpec | None, ...]) -> FloatArray:
    return np.array([[g.kp, g.ki, g.kd] if g else [0.0, 0.0, 0.0] for g in applied])


def _mode_row(modes: tuple[LoopMode, ...]) -> FloatArray:
    return np.array([int(m) for m in modes], dtype=float)


def _trip_row(trips: tuple[bool, ...]) -> FloatArray:
    return np.array(trips, dtype=float)


class _LastRows:
    """The trace row of each rarely changing quantity, rebuilt only when its value changes."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[tuple[Any, ...], FloatArray]] = {}

    def get(self, name: str, key: tuple[Any, ...], build: Callable[[Any], FloatArray]) -> FloatArray:
        last = self._last.get(name)
        if last is not None and last[0] == key:
            return last[1]
        row = build(key)
        row.flags.writeable = False  # shared by consecutive scans of the trace
        self._last[name] = (key, row)
        return row


class ProgramPort:
    """The in-process PLC port (:class:`supervisor.port.PlcPort`) on a :class:`PlcProgram`.

    A snapshot is made of the program's status at its last scan, mapped to the PLC's nodes as
    the server publishes them (:func:`plc_emulator.publish.status_values`) and read as the
    supervisor's one Read sees them; a request's writes go through the same dispatch as the PLC
    server's (:func:`plc_emulator.writes.apply_write`), its SetGains calls through
    ``stage_gains``. A write the program refuses is counted (``refused_writes``) and the rest of
    the request goes on, as a Bad status in a Write's results would.
    """

    def __init__(self, program: PlcProgram, site: SiteConfig) -> None:
        self.program = program
        self.loops = site.loop_names
        self.tanks = site.tank_names
        self.status: PlcStatus | None = None
        self.refused_writes = 0

    def snapshot(self) -> PlcSnapshot | None:
        if self.status is None:
            return None
        return PlcSnapshot.from_values(status_values(self.status), self.loops, self.tanks)

    def apply(self, request: PlcRequest) -> list[str]:
        self._write(request.writes)
        refused = [
            lp
            for lp, (kp, ki, kd) in request.gains
            if self.program.stage_gains(lp, kp, ki, kd) is not GainStatus.STAGED
        ]
        self._write(request.trailing)
        return refused

    def _write(self, items: tuple[tuple[str, object], ...]) -> None:
        for path, value in items:
            try:
                applied = apply_write(self.program, path, value)
            except (ValueError, KeyError):
                applied = False
            if not applied:
                self.refused_writes += 1


class CoSimEvents:
    """The scenario verbs (:class:`tankctl.events.EventTarget`) on a co-simulation, between
    scans, as the operator's OPC UA client writes them to the processes (same order, same
    conversions: a manual output in percent of the loop's MV range)."""

    def __init__(self, cs: CoSimulation) -> None:
        self.cs = cs

    def setpoint(self, loop: str, value_m: float) -> None:
        self.cs.plc.set_sp(loop, value_m)

    def leak(self, tank: str, opening: float) -> None:
        self.cs.plant.set_leak(tank, opening)

    def valve(self, valve: str, opening: float) -> None:
        self.cs.plant.set_valve(valve, opening)

    def disturbance(self, tank: str, flow_m3_s: float) -> None:
        self.cs.plant.set_disturbance(tank, flow_m3_s)

    def fault(self, transmitter: str, fault: SensorFault, value: float) -> None:
        self.cs.plant.set_fault(transmitter, fault, value)

    def loop_mode(self, loop: str, mode: LoopMode, mv_percent: float | None) -> None:
        # Mode first, then the output (the MANUAL switch is bumpless and starts from the MV).
        self.cs.plc.set_mode(loop, mode)
        if mv_percent is not None:
            lp = self.cs.plc.loop(loop)
            self.cs.plc.set_manual_mv(loop, lp.mv_min + mv_percent / 100.0 * (lp.mv_max - lp.mv_min))

    def supervisor_mode(self, mode: SupervisorMode) -> None:
        if self.cs.supervisor is None:
            raise ValueError("the site has no supervisor")
        self.cs.supervisor.request_mode(mode)


class CoSimulation:
    """Plant + PLC on model time.

    Parameters
    ----------
    site : the site config (plant and plc sections).
    scan_period_s : overrides the PLC's scan period (e.g. 0.01 s to reproduce a continuous-time
        paper); default: the config's.
    integrator, max_substep_s : the plant's integrator (``"rk4"`` with the plant's automatic
        sub-steps, or fixed ones of at most ``max_substep_s`` [s]; or ``"adaptive"`` solve_ivp),
        see :class:`PlantSimulator`.
    supervisor_mode : run the supervisor (:class:`supervisor.cycle.SupervisorCore`) in this mode;
        None: the PLC alone. Entering MPC at start goes through the same bumpless switch as at run
        time (the loops are put in REMOTE at the first cycle).
    controller : the supervisory controller (decision 0054): an instance, or the dotted path
        ``package.module:Class`` of one (built with the site's ``supervisor.controller.params``);
        default: the site's ``supervisor.controller``, else the shipped MPC and adaptive PID. Given
        without ``supervisor_mode``, the supervisor runs in the config's mode.
    cpu_clock : CPU seconds for the controller's budget (default ``time.thread_time``; tests
        pass a fake clock).

    The supervisor sees every PLC scan's published values (as its one Read would see them)
    through the same :class:`supervisor.port.SupervisorDriver` as the supervisor process, and
    its requests reach the PLC through :class:`ProgramPort` before the next scan, in the order the
    OPC UA link sends them (:class:`supervisor.port.PlcRequest`). Setting ``supervisor_alive =
    False`` stops the supervisor (no cycles, no heartbeat), as a killed process would.
    """

    def __init__(
        self,
        site: SiteConfig,
        *,
        scan_period_s: float | None = None,
        integrator: Literal["rk4", "adaptive"] = "rk4",
        max_substep_s: float | None = None,
        supervisor_mode: Literal["OFF", "ADVISORY", "ADAPTIVE_PID", "MPC"] | None = None,
        controller: str | SupervisoryController | None = None,
        cpu_clock: Callable[[], float] = time.thread_time,
    ) -> None:
        if site.plc is None:
            raise ValueError(f"site {site.name!r} has no plc section")
        if scan_period_s is not None:
            site = site.model_copy(deep=True)
            assert site.plc is not None
            site.plc.scan_period_s = scan_period_s
        self.site = site
        self.plant = PlantSimulator(site.plant, integrator=integrator, max_substep_s=max_substep_s)
        # The co-simulation always commands the pumps; the plant's watchdog is for lost links.
        self.plant.command_timeout_s = float("inf")
        self.plc = PlcProgram(site)
        self.ts_s = self.plc.ts_s
        self.trace = Trace()
        self._rows = _LastRows()
        n_tanks = self.plant.net.n_tanks
        self._good = {ok: np.full(n_tanks, ok) for ok in (False, True)}  # the transmitters' quality
        for flags in self._good.values():
            flags.flags.writeable = False
        self.io_healthy = True
        self.supervisor: SupervisorCore | None = None
        self.driver: SupervisorDriver | None = None
        self.port = ProgramPort(self.plc, site)
        self.supervisor_alive = True
        self.preview: Callable[[CoSimulation], FloatArray | None] | None = None
        self.host: ControllerHost | None = None
        if supervisor_mode is not None or controller is not None:
            if site.supervisor is None:
                raise ValueError(f"site {site.name!r} has no supervisor section")
            path = controller if isinstance(controller, str) else None
            instance = None if isinstance(controller, str) else controller
            self.supervisor, self.host = build_host(site, path, controller=instance, cpu_clock=cpu_clock)
            if supervisor_mode is not None:
                self.supervisor.request_mode(SupervisorMode[supervisor_mode])
            self.driver = SupervisorDriver(self.supervisor, self.host)

    @property
    def t_s(self) -> float:
        """Model time [s]."""
        return self.plant.t_s

    def step(self) -> None:
        """One scan: read the transmitters, scan, command the pumps, advance the plant by Ts."""
        # one read-only copy of the readings: the scan's input and the trace's row
        readings = self.plant.readings.copy()
        readings.flags.writeable = False
        out = self.plc.scan(
            ScanInputs(self.plant.t_s, readings, self._good[self.io_healthy], self.io_healthy),
            publish=self.supervisor is not None,  # only the supervisor reads the PLC's nodes
        )
        commands = out.commands  # the scan's own copy: the trace keeps it, read-only
        commands.flags.writeable = False
        if self.io_healthy:
            # within the pumps' ranges already: the PLC clamps its outputs to the same
            # site.plant.pumps ranges as the plant's (and set_commands refuses anything else)
            self.plant.set_commands(commands)
        self._record(commands, readings)
        self._supervise(out.status)
        self.plant.advance(self.ts_s)

    @property
    def heartbeat(self) -> int:
        """The supervisor's heartbeat count (0 without a supervisor)."""
        return self.driver.heartbeat if self.driver is not None else 0

    def _supervise(self, status: PlcStatus | None) -> None:
        sup, driver = self.supervisor, self.driver
        solve = float("nan")
        if sup is not None and driver is not None and self.supervisor_alive:
            self.port.status = status
            snap = self.port.snapshot()
            assert snap is not None
            preview = self.preview
            request = driver.on_snapshot(snap, (lambda: preview(self)) if preview is not None else None)
            if request is not None:
                driver.refused(self.port.apply(request))
                if driver.sampled and sup.result is not None:
                    solve = sup.result.solve_time_s
        self.trace.mpc_solve_s.append(solve)

    def _record(self, commands: FloatArray, readings: FloatArray) -> None:
        tr = self.trace
        plant = self.plant
        loops = self.plc.loops
        tr.t_s.append(plant.t_s)
        tr.levels_m.append(plant.x[: plant.net.n_tanks].copy())  # plant.levels, one call less
        tr.readings_m.append(readings)
        tr.commands.append(commands)
        tr.flows_m3_s.append(plant.pump_flows)
        # setpoints, gains and modes change rarely: one read-only array per distinct value (the
        # keys built from lists: a generator's frames cost more than the tuple, every scan)
        tr.setpoints_m.append(self._rows.get("sp", tuple([lp.sp_m for lp in loops]), _setpoint_row))
        tr.gains.append(self._rows.get("gains", tuple([lp.applied for lp in loops]), _gain_rows))
        tr.modes.append(self._rows.get("modes", tuple([lp.mode for lp in loops]), _mode_row))
        tr.trips.append(self._rows.get("trips", tuple([il.tripped for il in self.plc.interlocks]), _trip_row))

    def run(self, duration_s: float, before_scan: Callable[[CoSimulation], None] | None = None) -> Trace:
        """Run for ``duration_s`` of model time (whole scans); return the trace."""
        n = round(duration_s / self.ts_s)
        for _ in range(n):
            if before_scan is not None:
                before_scan(self)
            self.step()
        return self.trace
