"""The simulated plant as one object: state, inputs, transmitters, switches and watchdog.

:class:`PlantSimulator` is pure: it advances model time only when told (``advance(dt_s)``),
never reads a clock, and draws noise from a seeded generator. The OPC UA server and the
co-simulation both drive it. Setters validate their values (``ValueError`` naming the rule)
and leave the state untouched on refusal.

Pump-command watchdog: when no command has arrived for ``command_timeout_s`` of model time,
each pump goes to its own safe state (``pumps[].watchdog_safe_state``, by default the plant
watchdog's ``safe_state``; ``off``: the lowest command; ``hold``: keep the last one) until the
next command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from plant_sim.integrate import step_adaptive, step_rk4
from plant_sim.models import FloatArray, Flows, PlantInputs, TankNetwork, default_inputs, pump_flow
from plant_sim.sensors import TransmitterBank, switch_states
from tanklab.config import PlantConfig
from tanklab.enums import SensorFault


@dataclass(frozen=True)
class Balance:
    """Cumulative volumes since start [m^3]."""

    v_in: float
    v_out: float
    v_leaked: float
    v_spilled: float
    v_stored: float
    error: float


class PlantSimulator:
    """A plant of the seeds digest, stepped on model time.

    Parameters
    ----------
    config : the plant section of a site config.
    integrator : ``"rk4"`` (fixed sub-steps, fast) or ``"adaptive"`` (solve_ivp).
    max_substep_s : fixed RK4 sub-steps of at most this length [s]; None (default): the plant's
        automatic sub-step (:func:`plant_sim.integrate.step_rk4`).
    """

    def __init__(
        self,
        config: PlantConfig,
        *,
        integrator: Literal["rk4", "adaptive"] = "rk4",
        max_substep_s: float | None = None,
    ) -> None:
        self.config = config
        self.net = TankNetwork.from_config(config)
        self.integrator = integrator
        self.max_substep_s = max_substep_s
        self.inputs = default_inputs(self.net, config)
        levels0 = np.array([t.initial_level_m for t in config.tanks])
        self.x = self.net.initial_state(levels0, self.net.pump_target_flows(self.inputs.pump_commands))
        self.stored0_m3 = self.net.stored_volume(self.x)
        self.t_s = 0.0
        self.transmitters = TransmitterBank.from_config(config)
        sw = [t.switch_levels() for t in config.tanks]
        self._sw_high = np.array([s.high_m for s in sw])
        self._sw_low = np.array([s.low_m for s in sw])
        self.readings = self.transmitters.read(self.levels, self.t_s)
        self.command_timeout_s = config.watchdog.command_timeout_s
        self.safe_states = tuple(config.pump_safe_state(p.name) for p in config.pumps)
        """Each pump's watchdog safe state (pump order): ``off`` or ``hold``."""
        self._safe_off = np.array([s == "off" for s in self.safe_states])
        self.last_command_s = 0.0
        self.watchdog_tripped = False
        self._commanded = self.inputs.pump_commands.copy()
        self.pump_fractions = np.ones(self.net.n_pumps)
        """Pump degradation per pump: the fraction 0..1 of its command's flow a pump delivers
        (1: healthy). Applied to the command: ``cmd' = pump_commands_for(f * pump_flow(cmd))``."""
        # the command ranges as Python floats, for set_commands' fast path
        self._cmd_shape = (self.net.n_pumps,)
        self._cmd_lo = self.net.pump_cmd_min.tolist()
        self._cmd_hi = self.net.pump_cmd_max.tolist()

    # ---- views --------------------------------------------------------------------------

    @property
    def levels(self) -> FloatArray:
        """True levels [m]."""
        return self.net.levels(self.x).copy()

    @property
    def pump_flows(self) -> FloatArray:
        """Actual pump flows [m^3/s]: a lagged pump's state, else its command's :func:`pump_flow`.

        On Python floats, not through :meth:`TankNetwork.actual_pump_flows` (which evaluates the
        whole model): the co-simulation reads it every scan; a test checks both agree bit for bit.
        """
        net = self.net
        n = net.n_tanks
        x = self.x
        return np.array(
            [
                float(x[n + j]) if rate > 0.0 else pump_flow(cmd, *law)
                for j, (cmd, law, rate) in enumerate(
                    zip(self.inputs.pump_commands.tolist(), net.pump_laws, net.pump_rates_1_s, strict=True)
                )
            ]
        )

    @property
    def commands(self) -> FloatArray:
        """Pump commands as last written (before any watchdog safe state) [pump units]."""
        return self._commanded.copy()

    def flows(self) -> Flows:
        """All flows at the current state."""
        return self.net.flows(self.x, self.inputs)

    def switches(self) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """(LSH, LSL) per tank."""
        return switch_states(self.levels, self._sw_high, self._sw_low)

    def balance(self) -> Balance:
        """The volume balance since start."""
        v_in, v_out, v_leak, v_spill = (float(v) for v in self.net.volumes(self.x))
        stored = self.net.stored_volume(self.x)
        return Balance(v_in, v_out, v_leak, v_spill, stored, self.net.balance_error(self.x, self.stored0_m3))

    # ---- inputs (validated) -------------------------------------------------------------

    def _index(self, names: tuple[str, ...], name: str, what: str) -> int:
        try:
            return names.index(name)
        except ValueError:
            raise KeyError(f"unknown {what} {name!r}; known: {', '.join(names)}") from None

    @staticmethod
    def _finite(value: float, what: str) -> float:
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"{what} must be finite, got {value!r}")
        return v

    def set_command(self, pump: str, command: float) -> None:
        """Command pump ``pump`` in its unit; must lie in [command_min, command_max]."""
        j = self._index(self.net.pump_names, pump, "pump")
        v = self._finite(command, f"{pump} command")
        lo, hi = self.net.pump_cmd_min[j], self.net.pump_cmd_max[j]
        if not lo <= v <= hi:
            raise ValueError(f"{pump} command {v:g} outside [{lo:g}, {hi:g}]")
        self._commanded[j] = v
        self.last_command_s = self.t_s
        self.watchdog_tripped = False
        self._apply_commands()

    def set_commands(self, commands: FloatArray) -> None:
        """Command every pump at once (validated as a whole: all or nothing).

        Fast path (every co-simulation scan): a float64 array of the right shape is checked
        element by element on Python floats (``lo <= v <= hi`` is false for NaN; ``isfinite``
        catches an infinite command against an infinite bound); anything else, or a refusal,
        goes through the array checks below, which raise the same errors as before.
        ``tests/plant_sim/test_plant_fast.py`` checks both paths accept and refuse alike.
        """
        if (
            type(commands) is np.ndarray
            and commands.dtype == np.float64
            and commands.shape == self._cmd_shape
            and all(
                [
                    lo <= v <= hi and math.isfinite(v)
                    for v, lo, hi in zip(commands.tolist(), self._cmd_lo, self._cmd_hi, strict=True)
                ]
            )
        ):
            self._commanded = commands.copy()
        else:
            c = np.asarray(commands, dtype=float)
            if c.shape != (self.net.n_pumps,):
                raise ValueError(f"commands need {self.net.n_pumps} values, got shape {c.shape}")
            if not np.all(np.isfinite(c)):
                raise ValueError("commands must be finite")
            if np.any(c < self.net.pump_cmd_min) or np.any(c > self.net.pump_cmd_max):
                raise ValueError("a command lies outside its pump's range")
            self._commanded = c.copy()
        self.last_command_s = self.t_s
        self.watchdog_tripped = False
        self._apply_commands()

    def _apply_commands(self) -> None:
        cmd = self._commanded
        if self.watchdog_tripped:
            # per pump: ``off`` goes to its lowest command, ``hold`` keeps the last one
            cmd = np.where(self._safe_off, self.net.pump_cmd_min, cmd)
        if self._degraded:
            # a degraded pump delivers the fraction f of the flow its command asks for
            cmd = self.net.pump_commands_for(self.pump_fractions * self.net.pump_target_flows(cmd))
        u = self.inputs
        # a new inputs object (callers may hold the old one), built directly: what
        # dataclasses.replace does, without its field introspection (every scan)
        self.inputs = PlantInputs(cmd.copy(), u.valve_openings, u.leak_openings, u.disturbances_m3_s)

    def _opening(self, value: float, what: str) -> float:
        v = self._finite(value, what)
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"{what} {v:g} outside [0, 1]")
        return v

    def set_valve(self, valve: str, opening: float) -> None:
        """Set the opening 0..1 of valve ``valve`` (V13, V32, V20, ...)."""
        k = self._index(self.net.valve_names, valve, "valve")
        v = self._opening(opening, f"{valve} opening")
        op = self.inputs.valve_openings.copy()
        op[k] = v
        self.inputs = replace(self.inputs, valve_openings=op)

    def set_leak(self, tank: str, opening: float) -> None:
        """Set the leak valve opening 0..1 of tank ``tank``."""
        i = self._index(self.net.tank_names, tank, "tank")
        v = self._opening(opening, f"{tank} leak opening")
        op = self.inputs.leak_openings.copy()
        op[i] = v
        self.inputs = replace(self.inputs, leak_openings=op)

    @property
    def _degraded(self) -> bool:
        return bool(np.any(self.pump_fractions != 1.0))

    def set_pump_fraction(self, pump: str, fraction: float) -> None:
        """Degrade pump ``pump``: it delivers ``fraction`` 0..1 of its command's flow (1: healthy)."""
        j = self._index(self.net.pump_names, pump, "pump")
        v = self._opening(fraction, f"{pump} delivered fraction")
        self.pump_fractions[j] = v
        self._apply_commands()

    def set_disturbance(self, tank: str, flow_m3_s: float) -> None:
        """Set the extra inflow (+) or outflow (-) of tank ``tank`` [m^3/s]."""
        i = self._index(self.net.tank_names, tank, "tank")
        v = self._finite(flow_m3_s, f"{tank} disturbance")
        limit = self.config.disturbance_limit_m3_s
        if abs(v) > limit:
            raise ValueError(f"{tank} disturbance {v:g} outside [-{limit:g}, {limit:g}]")
        d = self.inputs.disturbances_m3_s.copy()
        d[i] = v
        self.inputs = replace(self.inputs, disturbances_m3_s=d)

    def set_fault(self, transmitter: str, fault: SensorFault | int, value: float | None = None) -> None:
        """Inject a fault on ``LT{i}``; ``value`` is the bias [m] or drift rate [m/s]."""
        i = self._index(tuple(f"LT{n[1:]}" for n in self.net.tank_names), transmitter, "transmitter")
        try:
            f = SensorFault(int(fault))
        except ValueError:
            raise ValueError(
                f"unknown fault {fault!r}; known: {', '.join(m.name for m in SensorFault)}"
            ) from None
        v = self.transmitters.fault_value[i] if value is None else self._finite(value, "fault value")
        self.transmitters.set_fault(i, f, v, self.t_s)

    # ---- time ---------------------------------------------------------------------------

    def advance(self, dt_s: float) -> FloatArray:
        """Integrate ``dt_s`` seconds of model time; return the new transmitter readings [m]."""
        if self.t_s - self.last_command_s >= self.command_timeout_s and not self.watchdog_tripped:
            self.watchdog_tripped = True
            self._apply_commands()
        if self.integrator == "rk4":
            self.x = step_rk4(
                self.net, self.x, self.inputs, dt_s, t_s=self.t_s, max_substep_s=self.max_substep_s
            )
        else:
            self.x = step_adaptive(self.net, self.x, self.inputs, dt_s, t_s=self.t_s)
        self.t_s += dt_s
        self.readings = self.transmitters.read(self.x[: self.net.n_tanks], self.t_s)
        return self.readings.copy()

    # ---- checkpoints --------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """A JSON-able checkpoint: time, state vector, inputs, stored volume at start."""
        return {
            "t_s": self.t_s,
            "x": self.x.tolist(),
            "stored0_m3": self.stored0_m3,
            "pump_commands": self._commanded.tolist(),
            "valve_openings": self.inputs.valve_openings.tolist(),
            "leak_openings": self.inputs.leak_openings.tolist(),
            "disturbances_m3_s": self.inputs.disturbances_m3_s.tolist(),
            "faults": [SensorFault(f).name for f in self.transmitters.fault],
            "fault_values": self.transmitters.fault_value.tolist(),
            "fault_since_s": self.transmitters.fault_since_s.tolist(),
            "last_readings": self.transmitters.last.tolist(),
            "last_command_s": self.last_command_s,
            "watchdog_tripped": self.watchdog_tripped,
            "pump_fractions": self.pump_fractions.tolist(),
        }

    def restore(self, snap: dict[str, Any]) -> None:
        """Resume from :meth:`snapshot` output.

        Shapes and values are checked before anything changes (a mismatch raises ValueError and
        the simulator is left as it was). The sensor faults are optional (files written before
        they were checkpointed resume without faults). The pump watchdog resumes as it was (the time
        of the last command, tripped or not; older files: a fresh timeout from the restored time).
        """
        n, nv, np_ = self.net.n_tanks, self.net.n_valves, self.net.n_pumps

        def vector(key: str, size: int, default: list[float] | None = None) -> FloatArray:
            v = np.asarray(snap.get(key, default) if default is not None else snap[key], dtype=float)
            if v.shape != (size,) or not np.all(np.isfinite(v)):
                raise ValueError(f"checkpoint {key} must be {size} finite values, got {v.tolist()}")
            return v

        x = vector("x", self.net.n_states)
        commands = vector("pump_commands", np_)
        valves, leaks = vector("valve_openings", nv), vector("leak_openings", n)
        disturbances = vector("disturbances_m3_s", n)
        if np.any(valves < 0) or np.any(valves > 1) or np.any(leaks < 0) or np.any(leaks > 1):
            raise ValueError("checkpoint openings must lie in [0, 1]")
        faults = [SensorFault[str(f)] for f in snap.get("faults", ["NONE"] * n)]
        if len(faults) != n:
            raise ValueError(f"checkpoint faults must be {n} names, got {faults}")
        fault_values = vector("fault_values", n, [0.0] * n)
        fault_since = vector("fault_since_s", n, [0.0] * n)
        last = vector("last_readings", n, self.transmitters.last.tolist())
        fractions = vector("pump_fractions", np_, [1.0] * np_)
        if np.any(fractions < 0) or np.any(fractions > 1):
            raise ValueError("checkpoint pump_fractions must lie in [0, 1]")
        self.x = x
        self.t_s = float(snap["t_s"])
        self.stored0_m3 = float(snap["stored0_m3"])
        self._commanded = commands
        self.inputs = PlantInputs(commands.copy(), valves, leaks, disturbances)
        self.transmitters.fault = faults
        self.transmitters.fault_value = fault_values
        self.transmitters.fault_since_s = fault_since
        self.transmitters.last = last
        self.last_command_s = float(snap.get("last_command_s", self.t_s))
        self.watchdog_tripped = bool(snap.get("watchdog_tripped", False))
        self.pump_fractions = fractions
        self._apply_commands()
        self.readings = self.transmitters.read(self.levels, self.t_s)
