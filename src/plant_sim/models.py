"""Nonlinear tank-network models: the three-tank benchmark, one tank, two interacting tanks.

Every plant of the seeds digest is a network of cylindrical tanks joined by orifices. With
``h`` the levels [m], tank cross-sections ``A`` [m^2], and an orifice of conductance
``c = mu * a * sqrt(2 g)`` [m^2.5/s] and opening ``s`` in [0, 1] between tanks m and n (n may be
the drain, level 0), Torricelli's law gives the signed flow

    q_mn = s * c * sign(h_m - h_n) * sqrt(|h_m - h_n|)            [m^3/s]

so a reversed level order reverses the flow. Each tank i has a leak valve to the drain,
``q_Li = s_Li * c_Li * sqrt(h_i)``, pumps feeding it (flows ``Q_j``), and a disturbance flow
``d_i`` (inflow if positive, outflow if negative; an outflow stops when the tank is empty):

    A_i dh_i/dt = sum_j Q_j[feeds i] + d_i + sum_m q_mi - sum_n q_in - q_Li - spill_i

Above the overflow height ``Hmax`` the surplus net inflow spills over the top: while
``h_i >= Hmax`` and the net inflow is positive, ``spill_i`` equals it and the level holds.

Near zero head the square root has an infinite slope; below ``H_LAMINAR_M`` (0.1 mm) the
orifice law is continued linearly, ``sign(dh) sqrt(|dh|) -> dh / sqrt(H_LAMINAR_M)`` (laminar
regime), which keeps the Jacobian finite, the outflow of a nearly empty tank decaying instead of
crossing zero, and changes nothing above 0.1 mm of head.

Pumps: the actual flow either equals the target flow of the command (``lag_s = 0``) or follows
it through ``tau dQ/dt = Q_target - Q``.

State vector (python-control's shape, ``f(t, x, u) -> dx/dt``), with n tanks and p pumps:

    x = [h_1..h_n, Q_1..Q_p, V_in, V_out, V_leaked, V_spilled]

The cumulative volumes are states of the same ODE, so the volume balance

    sum_i A_i h_i + V_out + V_leaked + V_spilled - V_in - V_stored(0) = 0

is a linear invariant of the ODE and every Runge-Kutta step preserves it to rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from tanklab.config import PlantConfig

FloatArray = NDArray[np.float64]

H_LAMINAR_M = 1e-4
"""Head below which the orifice law is continued linearly [m]."""

_SQRT_LAM = math.sqrt(H_LAMINAR_M)
DRAIN = -1
"""Index used for the drain as the downstream end of an orifice."""


def signed_sqrt(dh: FloatArray) -> FloatArray:
    """sign(dh) sqrt(|dh|), continued linearly below ``H_LAMINAR_M`` [m^0.5]."""
    a = np.abs(dh)
    return np.where(a >= H_LAMINAR_M, np.sign(dh) * np.sqrt(a), dh / _SQRT_LAM)


def signed_sqrt_slope(dh: FloatArray) -> FloatArray:
    """Derivative of :func:`signed_sqrt`: 1 / (2 sqrt|dh|), or 1/sqrt(H_LAMINAR_M) below it."""
    a = np.abs(dh)
    return np.where(a >= H_LAMINAR_M, 0.5 / np.sqrt(np.maximum(a, H_LAMINAR_M)), 1.0 / _SQRT_LAM)


@dataclass(frozen=True)
class PlantInputs:
    """Inputs of the plant model, all in SI units.

    Attributes
    ----------
    pump_commands : (p,) commands in each pump's own unit (m^3/s, rpm or fraction).
    valve_openings : (k,) openings 0..1 of the connecting and outlet valves.
    leak_openings : (n,) openings 0..1 of the tanks' leak valves.
    disturbances_m3_s : (n,) extra inflow (+) or outflow (-) per tank [m^3/s].
    """

    pump_commands: FloatArray
    valve_openings: FloatArray
    leak_openings: FloatArray
    disturbances_m3_s: FloatArray


@dataclass(frozen=True)
class Flows:
    """Instantaneous flows [m^3/s] at a state, for diagnostics and the balance."""

    valves: FloatArray
    """(k,) signed flows through the valves, positive from upstream to downstream."""
    leaks: FloatArray
    """(n,) leak flows."""
    pumps: FloatArray
    """(p,) actual pump flows."""
    spill: FloatArray
    """(n,) flows spilling over the tops."""
    net: FloatArray
    """(n,) net inflow of each tank after spilling (A dh/dt)."""


@dataclass(frozen=True)
class TankNetwork:
    """Compiled parameters of a tank network (arrays, for fast evaluation).

    Build it with :meth:`from_config`. Index order: tanks, valves and pumps as in the config.
    """

    tank_names: tuple[str, ...]
    area_m2: FloatArray
    hmax_m: FloatArray
    leak_conductance: FloatArray
    valve_names: tuple[str, ...]
    valve_up: NDArray[np.int64]
    valve_down: NDArray[np.int64]
    valve_conductance: FloatArray
    pump_names: tuple[str, ...]
    pump_tank: NDArray[np.int64]
    pump_slope: FloatArray
    pump_offset_m3_s: FloatArray
    pump_cmd_min: FloatArray
    pump_cmd_max: FloatArray
    pump_max_flow_m3_s: FloatArray
    pump_lag_s: FloatArray
    _pump_matrix: FloatArray = field(repr=False)

    @classmethod
    def from_config(cls, plant: PlantConfig) -> TankNetwork:
        """Compile a :class:`~tanklab.config.PlantConfig`."""
        names = tuple(t.name for t in plant.tanks)
        idx = {name: i for i, name in enumerate(names)}
        n = len(names)
        p = len(plant.pumps)
        pump_tank = np.array([idx[pp.feeds] for pp in plant.pumps], dtype=np.int64)
        pump_matrix = np.zeros((n, p))
        pump_matrix[pump_tank, np.arange(p)] = 1.0
        return cls(
            tank_names=names,
            area_m2=np.array([t.area_m2 for t in plant.tanks]),
            hmax_m=np.array([t.height_max_m for t in plant.tanks]),
            leak_conductance=np.array([t.leak_conductance for t in plant.tanks]),
            valve_names=tuple(v.name for v in plant.valves),
            valve_up=np.array([idx[v.upstream] for v in plant.valves], dtype=np.int64),
            valve_down=np.array(
                [idx[v.downstream] if v.downstream else DRAIN for v in plant.valves], dtype=np.int64
            ),
            valve_conductance=np.array([v.conductance for v in plant.valves]),
            pump_names=tuple(pp.name for pp in plant.pumps),
            pump_tank=pump_tank,
            pump_slope=np.array([pp.slope for pp in plant.pumps]),
            pump_offset_m3_s=np.array([pp.offset_m3_s for pp in plant.pumps]),
            pump_cmd_min=np.array([pp.command_min for pp in plant.pumps]),
            pump_cmd_max=np.array([pp.command_max for pp in plant.pumps]),
            pump_max_flow_m3_s=np.array([pp.max_flow_m3_s for pp in plant.pumps]),
            pump_lag_s=np.array([pp.lag_s for pp in plant.pumps]),
            _pump_matrix=pump_matrix,
        )

    # ---- sizes and layout ---------------------------------------------------------------

    @property
    def n_tanks(self) -> int:
        return len(self.tank_names)

    @property
    def n_pumps(self) -> int:
        return len(self.pump_names)

    @property
    def n_valves(self) -> int:
        return len(self.valve_names)

    @property
    def n_states(self) -> int:
        """Length of the state vector: levels, pump flows and four cumulative volumes."""
        return self.n_tanks + self.n_pumps + 4

    @property
    def pump_matrix(self) -> FloatArray:
        """(n, p) incidence of pumps on tanks: 1 where pump j feeds tank i."""
        return self._pump_matrix

    def levels(self, x: FloatArray) -> FloatArray:
        """Levels [m] from a state vector."""
        return x[: self.n_tanks]

    def pump_flows(self, x: FloatArray) -> FloatArray:
        """Actual pump flows [m^3/s] from a state vector."""
        return x[self.n_tanks : self.n_tanks + self.n_pumps]

    def volumes(self, x: FloatArray) -> FloatArray:
        """Cumulative (in, out, leaked, spilled) volumes [m^3] from a state vector."""
        return x[self.n_tanks + self.n_pumps :]

    def initial_state(self, levels_m: FloatArray, pump_flows_m3_s: FloatArray | None = None) -> FloatArray:
        """State vector with the given levels, pump flows (default 0) and zero volumes."""
        x = np.zeros(self.n_states)
        x[: self.n_tanks] = levels_m
        if pump_flows_m3_s is not None:
            x[self.n_tanks : self.n_tanks + self.n_pumps] = pump_flows_m3_s
        return x

    def stored_volume(self, x: FloatArray) -> float:
        """Water in the tanks [m^3]."""
        return float(self.area_m2 @ self.levels(x))

    def balance_error(self, x: FloatArray, stored0_m3: float) -> float:
        """stored + out + leaked + spilled - in - stored0 [m^3] (zero up to rounding)."""
        v_in, v_out, v_leak, v_spill = self.volumes(x)
        return float(self.stored_volume(x) + v_out + v_leak + v_spill - v_in - stored0_m3)

    # ---- pumps --------------------------------------------------------------------------

    def pump_target_flows(self, commands: FloatArray) -> FloatArray:
        """Steady flows [m^3/s] for commands in the pumps' units: saturated, dead zone applied."""
        cmd = np.clip(commands, self.pump_cmd_min, self.pump_cmd_max)
        return np.clip(self.pump_slope * cmd + self.pump_offset_m3_s, 0.0, self.pump_max_flow_m3_s)

    def pump_commands_for(self, flows_m3_s: FloatArray) -> FloatArray:
        """Commands that produce the given flows (inverse map inside the pumps' ranges)."""
        q = np.clip(flows_m3_s, 0.0, self.pump_max_flow_m3_s)
        cmd = np.where(q > 0, (q - self.pump_offset_m3_s) / self.pump_slope, self.pump_cmd_min)
        return np.clip(cmd, self.pump_cmd_min, self.pump_cmd_max)

    # ---- flows and dynamics -------------------------------------------------------------

    def valve_flows(self, h: FloatArray, openings: FloatArray) -> FloatArray:
        """(k,) signed valve flows [m^3/s] at levels ``h`` (negative levels count as 0)."""
        hp = np.maximum(h, 0.0)
        up = hp[self.valve_up]
        down = np.where(self.valve_down == DRAIN, 0.0, hp[self.valve_down])
        return openings * self.valve_conductance * signed_sqrt(up - down)

    def leak_flows(self, h: FloatArray, openings: FloatArray) -> FloatArray:
        """(n,) leak flows [m^3/s] at levels ``h``."""
        return openings * self.leak_conductance * signed_sqrt(np.maximum(h, 0.0))

    def disturbance_flows(self, h: FloatArray, d: FloatArray) -> FloatArray:
        """(n,) effective disturbances: an outflow fades out as the tank empties (below 0.1 mm)."""
        fade = np.clip(h / H_LAMINAR_M, 0.0, 1.0)
        return np.where(d < 0, d * fade, d)

    def flows(self, x: FloatArray, u: PlantInputs) -> Flows:
        """All flows at state ``x`` with inputs ``u``."""
        n = self.n_tanks
        h = x[:n]
        q_pump = self._actual_pump_flows(x, u)
        qv = self.valve_flows(h, u.valve_openings)
        ql = self.leak_flows(h, u.leak_openings)
        dist = self.disturbance_flows(h, u.disturbances_m3_s)
        net = self.pump_matrix @ q_pump + dist - ql
        np.subtract.at(net, self.valve_up, qv)
        into = self.valve_down != DRAIN
        np.add.at(net, self.valve_down[into], qv[into])
        spill = np.where((h >= self.hmax_m) & (net > 0), net, 0.0)
        return Flows(valves=qv, leaks=ql, pumps=q_pump, spill=spill, net=net - spill)

    def _actual_pump_flows(self, x: FloatArray, u: PlantInputs) -> FloatArray:
        target = self.pump_target_flows(u.pump_commands)
        lagged = self.pump_flows(x)
        return np.where(self.pump_lag_s > 0, lagged, target)

    def rhs(self, t: float, x: FloatArray, u: PlantInputs) -> FloatArray:
        """dx/dt of the full state (levels, lagged pump flows, cumulative volumes).

        Parameters
        ----------
        t : model time [s] (the model is time-invariant; kept for the python-control shape).
        x : (n + p + 4,) state.
        u : inputs, held over the step.
        """
        n, p = self.n_tanks, self.n_pumps
        f = self.flows(x, u)
        dx = np.empty_like(x)
        dx[:n] = f.net / self.area_m2
        target = self.pump_target_flows(u.pump_commands)
        lag = self.pump_lag_s
        dx[n : n + p] = np.where(lag > 0, (target - self.pump_flows(x)) / np.where(lag > 0, lag, 1.0), 0.0)
        h = x[:n]
        dist = self.disturbance_flows(h, u.disturbances_m3_s)
        drain_flow = f.valves[self.valve_down == DRAIN]
        dx[n + p] = f.pumps.sum() + dist[dist > 0].sum()  # V_in
        dx[n + p + 1] = drain_flow.sum() - dist[dist < 0].sum()  # V_out
        dx[n + p + 2] = f.leaks.sum()  # V_leaked
        dx[n + p + 3] = f.spill.sum()  # V_spilled
        return dx

    def project(self, x: FloatArray) -> FloatArray:
        """Keep levels in [0, Hmax] after a step without breaking the volume balance.

        A level above Hmax (a Runge-Kutta stage overshooting the overflow edge) is moved to the
        spilled volume; a level below zero (an outflow overshooting an emptying tank, at most the
        laminar regime's rounding) is returned from the outflow account. Both are transfers
        between terms of the balance, so it still closes exactly.
        """
        n, p = self.n_tanks, self.n_pumps
        h = x[:n]
        over = np.maximum(h - self.hmax_m, 0.0)
        under = np.maximum(-h, 0.0)
        if not (over.any() or under.any()):
            return x
        y = x.copy()
        y[:n] = np.clip(h, 0.0, self.hmax_m)
        y[n + p + 3] += float(self.area_m2 @ over)
        y[n + p + 1] -= float(self.area_m2 @ under)
        return y


def default_inputs(net: TankNetwork, plant: PlantConfig) -> PlantInputs:
    """Inputs at start: initial pump commands, valve and leak openings from the config, no disturbance."""
    return PlantInputs(
        pump_commands=np.array([pp.initial_command for pp in plant.pumps], dtype=float),
        valve_openings=np.array([v.initial_opening for v in plant.valves], dtype=float),
        leak_openings=np.array([t.initial_leak_opening for t in plant.tanks], dtype=float),
        disturbances_m3_s=np.zeros(net.n_tanks),
    )


def _ssqrt(dh: float) -> float:
    """Scalar :func:`signed_sqrt`."""
    if dh >= H_LAMINAR_M:
        return math.sqrt(dh)
    if dh <= -H_LAMINAR_M:
        return -math.sqrt(-dh)
    return dh / _SQRT_LAM


class ScalarRhs:
    """The same right-hand side as :meth:`TankNetwork.rhs`, on Python floats, for one input set.

    The RK4 hot loop calls the right-hand side tens of times per scan on a handful of states,
    where numpy's per-call overhead (about 50 us) dominates; plain float arithmetic on lists is
    about ten times faster. Built once per step (inputs are held over it); a test checks it
    against :meth:`TankNetwork.rhs` on random states and inputs.
    """

    def __init__(self, net: TankNetwork, u: PlantInputs) -> None:
        self.n = net.n_tanks
        self.p = net.n_pumps
        self.inv_area = [1.0 / a for a in net.area_m2.tolist()]
        self.hmax = net.hmax_m.tolist()
        self.valves = [
            (int(up), int(down), float(s * c))
            for up, down, s, c in zip(
                net.valve_up, net.valve_down, u.valve_openings, net.valve_conductance, strict=True
            )
        ]
        self.leaks = (u.leak_openings * net.leak_conductance).tolist()
        self.dist = u.disturbances_m3_s.tolist()
        self.target = net.pump_target_flows(u.pump_commands).tolist()
        self.lag = net.pump_lag_s.tolist()
        self.pump_tank = [int(i) for i in net.pump_tank]

    def __call__(self, x: list[float]) -> list[float]:
        n, p = self.n, self.p
        h = [v if v > 0.0 else 0.0 for v in x[:n]]
        net = [0.0] * n
        v_in = 0.0
        v_out = 0.0
        pumps = [x[n + j] if self.lag[j] > 0.0 else self.target[j] for j in range(p)]
        for j, tank in enumerate(self.pump_tank):
            net[tank] += pumps[j]
            v_in += pumps[j]
        for i in range(n):
            d = self.dist[i]
            if d < 0.0:
                fade = min(max(x[i] / H_LAMINAR_M, 0.0), 1.0)
                d *= fade
                v_out -= d
            else:
                v_in += d
            net[i] += d
        leaked = 0.0
        for i in range(n):
            q = self.leaks[i] * _ssqrt(h[i])
            net[i] -= q
            leaked += q
        for up, down, cs in self.valves:
            if down == DRAIN:
                q = cs * _ssqrt(h[up])
                v_out += q
            else:
                q = cs * _ssqrt(h[up] - h[down])
                net[down] += q
            net[up] -= q
        spilled = 0.0
        dx = [0.0] * (n + p + 4)
        for i in range(n):
            f = net[i]
            if x[i] >= self.hmax[i] and f > 0.0:
                spilled += f
                f = 0.0
            dx[i] = f * self.inv_area[i]
        for j in range(p):
            if self.lag[j] > 0.0:
                dx[n + j] = (self.target[j] - x[n + j]) / self.lag[j]
        dx[n + p] = v_in
        dx[n + p + 1] = v_out
        dx[n + p + 2] = leaked
        dx[n + p + 3] = spilled
        return dx
