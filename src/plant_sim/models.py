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

The RK4 fast path evaluates this right-hand side through :class:`ScalarRhs`, whose code is
generated per network and layout (:func:`_generate_rhs`: the loops over tanks, valves, leaks and
pumps unrolled into straight-line Python, compiled once and cached on the network) because the
loops cost more than the arithmetic on a handful of floats. It performs the same floating-point
operations in the same order as the loop form ``ScalarRhs.generic``, so the results are
bit-identical; tests/plant_sim/test_generated_rhs.py checks that bit for bit on every shipped
config. To read the generated code: ``print(ScalarRhs(net, u).code.source)``.
"""

from __future__ import annotations

import linecache
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

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
        # np.minimum / np.maximum: np.clip's result, at a third of its call overhead (every scan)
        cmd = np.minimum(np.maximum(commands, self.pump_cmd_min), self.pump_cmd_max)
        return np.minimum(
            np.maximum(self.pump_slope * cmd + self.pump_offset_m3_s, 0.0), self.pump_max_flow_m3_s
        )

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
        q_pump = self.actual_pump_flows(x, u)
        qv = self.valve_flows(h, u.valve_openings)
        ql = self.leak_flows(h, u.leak_openings)
        dist = self.disturbance_flows(h, u.disturbances_m3_s)
        net = self.pump_matrix @ q_pump + dist - ql
        np.subtract.at(net, self.valve_up, qv)
        into = self.valve_down != DRAIN
        np.add.at(net, self.valve_down[into], qv[into])
        spill = np.where((h >= self.hmax_m) & (net > 0), net, 0.0)
        return Flows(valves=qv, leaks=ql, pumps=q_pump, spill=spill, net=net - spill)

    def actual_pump_flows(self, x: FloatArray, u: PlantInputs) -> FloatArray:
        """(p,) pump flows [m^3/s]: the lagged state, or the commands' target flows without lag."""
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

    @cached_property
    def scalar_constants(self) -> _ScalarConstants:
        """The parameters as Python scalars, for :class:`ScalarRhs` (computed once)."""
        rates = [1.0 / lag if lag > 0.0 else 0.0 for lag in self.pump_lag_s.tolist()]
        tanks = self.pump_tank.tolist()
        return _ScalarConstants(
            n=self.n_tanks,
            p=self.n_pumps,
            inv_area=[1.0 / a for a in self.area_m2.tolist()],
            hmax=self.hmax_m.tolist(),
            valves=list(
                zip(
                    self.valve_up.tolist(),
                    self.valve_down.tolist(),
                    self.valve_conductance.tolist(),
                    strict=True,
                )
            ),
            leak=self.leak_conductance.tolist(),
            pump_tank=self.pump_tank.tolist(),
            slope=self.pump_slope.tolist(),
            offset=self.pump_offset_m3_s.tolist(),
            cmd_min=self.pump_cmd_min.tolist(),
            cmd_max=self.pump_cmd_max.tolist(),
            max_flow=self.pump_max_flow_m3_s.tolist(),
            lag_rate=rates,
            pumps=list(
                zip(
                    self.pump_cmd_min.tolist(),
                    self.pump_cmd_max.tolist(),
                    self.pump_slope.tolist(),
                    self.pump_offset_m3_s.tolist(),
                    self.pump_max_flow_m3_s.tolist(),
                    tanks,
                    rates,
                    strict=True,
                )
            ),
            lagged=tuple(
                (j, tank, r) for j, (tank, r) in enumerate(zip(tanks, rates, strict=True)) if r > 0.0
            ),
        )

    @cached_property
    def _generated(self) -> dict[_Layout, GeneratedRhs]:
        """Generated right-hand sides by layout (:func:`_generate_rhs`; a cache, not state)."""
        return {}

    @cached_property
    def _step_plans(self) -> dict[tuple[float, float | None], tuple[int, float, int]]:
        """RK4 sub-step plans by (step, fixed sub-step) (``plant_sim.integrate``; a cache, not state)."""
        return {}

    @cached_property
    def _fixed_memo(self) -> dict[str, _FixedPart]:
        """The last :func:`_fixed_part` (a cache, not state: it never changes a result)."""
        return {}

    @cached_property
    def fastest_rate_1_s(self) -> float:
        """Upper bound on the modulus of every eigenvalue of the plant's Jacobian, anywhere [1/s].

        :meth:`rate_bound_1_s` with no bound on the heads (the laminar band included).
        """
        return self.rate_bound_1_s(None)

    @cached_property
    def _rate_memo(self) -> dict[float | None, float]:
        """:meth:`rate_bound_1_s` by ``min_head_m`` (a cache, not state)."""
        return {}

    def rate_bound_1_s(self, min_head_m: float | None) -> float:
        """Upper bound on the modulus of every eigenvalue of the plant's Jacobian [1/s] at every
        state whose heads across open orifices are all at least ``min_head_m`` (None: any state).

        The level dynamics linearise to ``J = -A^-1 L`` with ``L`` the weighted Laplacian of the
        orifice graph (weight ``s c g`` per valve, slope ``g`` of the orifice law at the current head;
        leaks and drain valves on the diagonal, their head the tank's level). ``g`` is largest in the
        laminar region, ``1 / sqrt(H_LAMINAR_M)`` (the turbulent slope ``1 / (2 sqrt|dh|)`` is at most
        half of it); with every head at least ``min_head_m`` (>= ``H_LAMINAR_M``) it is at most
        ``1 / (2 sqrt(min_head_m))``. ``A^-1 L`` has the eigenvalues of the symmetric
        ``A^-1/2 L A^-1/2``, which only grow with the weights. So the eigenvalues of ``J`` at those
        states and any valve and leak openings lie in ``[-lambda_max, 0]`` with ``lambda_max`` the
        largest eigenvalue of ``A^-1/2 L A^-1/2`` with every valve and leak fully open at that slope.
        A lagged pump adds the rate ``1 / lag_s``.

        Not covered: an outflow disturbance fading out over the last ``H_LAMINAR_M`` of an emptying
        tank (the integrator projects levels onto [0, Hmax], so it cannot overshoot below empty).
        """
        if min_head_m is not None and not min_head_m >= H_LAMINAR_M:
            raise ValueError(f"min_head_m must be >= H_LAMINAR_M = {H_LAMINAR_M} m, got {min_head_m}")
        memo = self._rate_memo
        if min_head_m in memo:
            return memo[min_head_m]
        n = self.n_tanks
        # the orifice law's steepest slope at those heads
        g = 1.0 / _SQRT_LAM if min_head_m is None else 0.5 / math.sqrt(min_head_m)
        L = np.diag(self.leak_conductance * g)
        for up, down, c in zip(self.valve_up, self.valve_down, self.valve_conductance, strict=True):
            w = float(c) * g
            L[up, up] += w
            if down != DRAIN:
                L[down, down] += w
                L[up, down] -= w
                L[down, up] -= w
        d = 1.0 / np.sqrt(self.area_m2)
        sym = d[:, None] * L * d[None, :]
        rate = float(np.max(np.linalg.eigvalsh(0.5 * (sym + sym.T)))) if n else 0.0
        lags = self.pump_lag_s[self.pump_lag_s > 0]
        if lags.size:
            rate = max(rate, float(np.max(1.0 / lags)))
        memo[min_head_m] = rate
        return rate

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


_INV_SQRT_LAM = 1.0 / _SQRT_LAM


@dataclass(frozen=True)
class _ScalarConstants:
    """A network's parameters as Python floats and ints (what :class:`ScalarRhs` reads)."""

    n: int
    p: int
    inv_area: list[float]
    hmax: list[float]
    valves: list[tuple[int, int, float]]
    leak: list[float]
    pump_tank: list[int]
    slope: list[float]
    offset: list[float]
    cmd_min: list[float]
    cmd_max: list[float]
    max_flow: list[float]
    lag_rate: list[float]
    pumps: list[tuple[float, float, float, float, float, int, float]]
    """Per pump: cmd_min, cmd_max, slope, offset, max_flow, tank, lag_rate."""
    lagged: tuple[_Lagged, ...]
    """Lagged pumps: (j, tank, 1 / lag_s)."""


_PartLayout = tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...], tuple[tuple[int, int], ...]]
"""Outflow, leak and drain tanks and links (up, down) of a :class:`_FixedPart`."""
_Lagged = tuple[int, int, float]
"""A lagged pump: (j, tank, 1 / lag_s)."""


@dataclass(frozen=True)
class _FixedPart:
    """What :class:`ScalarRhs` folds in from the valve and leak openings and the disturbances."""

    key: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]
    inflows: list[tuple[int, float]]
    outflows: list[tuple[int, float]]
    drains: list[tuple[int, float]]
    links: list[tuple[int, int, float]]
    leaks: list[tuple[int, float]]
    layout: _PartLayout = ((), (), (), ())
    """Outflow, leak and drain tanks and links (up, down): what the generated code unrolls."""
    args: tuple[float, ...] = ()
    """The generated code's ``make`` arguments from this part: outflows, leaks, drains, links."""
    generated: list[GeneratedRhs] = field(default_factory=list, compare=False)
    """The generated code for this part's layout (filled by :class:`ScalarRhs`; a cache)."""


def _fixed_part(net: TankNetwork, u: PlantInputs) -> _FixedPart:
    """The openings' and disturbances' share of :class:`ScalarRhs`, memoised on the network.

    Between scans usually only the pump commands change, so the last result is kept (in
    ``net._fixed_memo``) and reused while the openings and disturbances are equal *in value*
    (compared as floats, so an array changed in place is noticed; NaN never matches and is
    rebuilt). The memo only skips recomputing the same floats: results are bit-identical
    (test_models.py: ``test_scalar_rhs_memo_*``).
    """
    key = (
        tuple(u.valve_openings.tolist()),
        tuple(u.leak_openings.tolist()),
        tuple(u.disturbances_m3_s.tolist()),
    )
    memo = net._fixed_memo
    last = memo.get("last")
    if last is not None and last.key == key:
        return last
    c = net.scalar_constants
    valves, leaks, dist = key
    inflows: list[tuple[int, float]] = []
    outflows: list[tuple[int, float]] = []
    for i, d in enumerate(dist):
        if d < 0.0:
            outflows.append((i, d))
        elif d > 0.0:
            inflows.append((i, d))
    drains: list[tuple[int, float]] = []
    links: list[tuple[int, int, float]] = []
    for (up, down, cond), s in zip(c.valves, valves, strict=True):
        cs = s * cond
        if cs == 0.0:
            continue  # a closed valve passes nothing
        if down == DRAIN:
            drains.append((up, cs))
        else:
            links.append((up, down, cs))
    leak = [(i, s * cond) for i, (s, cond) in enumerate(zip(leaks, c.leak, strict=True)) if s * cond != 0.0]
    part = _FixedPart(
        key,
        inflows,
        outflows,
        drains,
        links,
        leak,
        layout=(
            tuple(i for i, _ in outflows),
            tuple(i for i, _ in leak),
            tuple(up for up, _ in drains),
            tuple((up, down) for up, down, _ in links),
        ),
        args=(
            *(d for _, d in outflows),
            *(cs for _, cs in leak),
            *(cs for _, cs in drains),
            *(cs for _, _, cs in links),
        ),
    )
    memo["last"] = part
    return part


class ScalarRhs:
    """The same right-hand side as :meth:`TankNetwork.rhs`, on Python floats, for one input set.

    The RK4 hot loop calls the right-hand side a few times per scan on a handful of states, where
    numpy's per-call overhead (about 50 us) dominates; plain float arithmetic on lists is about
    ten times faster. Built once per step (inputs are held over it): whatever the held inputs fix
    is folded in here (unlagged pump flows and inflow disturbances as a constant inflow per tank;
    closed valves and leaks dropped), so a call only evaluates the orifices. A test checks it
    against :meth:`TankNetwork.rhs` on random states and inputs.

    A call runs generated code (:attr:`fn`; :attr:`fn_at` evaluates at an RK4 stage point
    ``y + c k``), compiled by :func:`_generate_rhs` once per layout (which valves, leaks and
    outflow disturbances are active) and cached on the network; :meth:`generic` is the loop
    form it is generated from and checked against bit for bit
    (tests/plant_sim/test_generated_rhs.py). ``print(f.code.source)`` shows the code.
    """

    __slots__ = (
        "code",
        "drains",
        "fn",
        "fn_at",
        "hmax",
        "inflow",
        "inv_area",
        "lagged",
        "leaks",
        "links",
        "n",
        "outflows",
        "p",
        "v_in0",
    )

    def __init__(self, net: TankNetwork, u: PlantInputs) -> None:
        c = net.scalar_constants
        self.n = c.n
        self.p = c.p
        self.inv_area = c.inv_area
        self.hmax = c.hmax
        fixed = _fixed_part(net, u)
        inflow = [0.0] * c.n
        v_in0 = 0.0
        self.lagged: list[tuple[int, int, float, float]] = []
        targets: list[float] = []
        for j, (cmd, (lo, hi, slope, offset, max_flow, tank, rate)) in enumerate(
            zip(u.pump_commands.tolist(), c.pumps, strict=True)
        ):
            # pump_target_flows on floats: the command saturated, then the flow
            q = slope * (lo if cmd < lo else hi if cmd > hi else cmd) + offset
            q = 0.0 if q < 0.0 else max_flow if q > max_flow else q
            if rate > 0.0:
                self.lagged.append((j, tank, q, rate))
                targets.append(q)
            else:
                inflow[tank] += q
                v_in0 += q
        # inflow disturbances after the pumps: the order of the sums is part of the result's bits
        for i, d in fixed.inflows:
            inflow[i] += d
            v_in0 += d
        self.inflow = inflow
        self.v_in0 = v_in0
        self.outflows = fixed.outflows
        self.drains = fixed.drains
        self.links = fixed.links
        self.leaks = fixed.leaks
        if not fixed.generated:
            layout: _Layout = (*fixed.layout, c.lagged)
            cache = net._generated
            found = cache.get(layout)
            if found is None:
                if len(cache) >= _GENERATED_CACHE_SIZE:
                    cache.clear()  # openings toggled through many layouts: start over, stay bounded
                found = cache[layout] = _generate_rhs(net, layout)
            fixed.generated.append(found)
        code = self.code = fixed.generated[0]
        self.fn, self.fn_at = code.make(*inflow, v_in0, *targets, *fixed.args)

    def __call__(self, x: list[float]) -> list[float]:
        """dx/dt at ``x`` (the generated code, :attr:`fn`)."""
        return self.fn(x)

    def generic(self, x: list[float]) -> list[float]:
        """dx/dt at ``x`` by the loops over the network (the oracle of the generated code)."""
        n, p = self.n, self.p
        lam = H_LAMINAR_M
        sqrt = math.sqrt
        net = self.inflow.copy()
        v_in = self.v_in0
        v_out = 0.0
        dx = [0.0] * (n + p + 4)
        for j, tank, target, rate in self.lagged:
            q = x[n + j]
            net[tank] += q
            v_in += q
            dx[n + j] = (target - q) * rate
        for i, d_full in self.outflows:
            h = x[i]
            # an outflow fades out over the last 0.1 mm of an emptying tank
            d = d_full if h >= lam else (d_full * h / lam if h > 0.0 else 0.0)
            net[i] += d
            v_out -= d
        leaked = 0.0
        for i, cs in self.leaks:
            h = x[i]
            q = cs * (sqrt(h) if h >= lam else (h * _INV_SQRT_LAM if h > 0.0 else 0.0))
            net[i] -= q
            leaked += q
        for up, cs in self.drains:
            h = x[up]
            q = cs * (sqrt(h) if h >= lam else (h * _INV_SQRT_LAM if h > 0.0 else 0.0))
            net[up] -= q
            v_out += q
        for up, down, cs in self.links:
            hu = x[up]
            hd = x[down]
            dh = (hu if hu > 0.0 else 0.0) - (hd if hd > 0.0 else 0.0)
            if dh >= lam:
                q = cs * sqrt(dh)
            elif dh <= -lam:
                q = -cs * sqrt(-dh)
            else:
                q = cs * dh * _INV_SQRT_LAM
            net[up] -= q
            net[down] += q
        spilled = 0.0
        hmax = self.hmax
        inv_area = self.inv_area
        for i in range(n):
            f = net[i]
            if f > 0.0 and x[i] >= hmax[i]:
                spilled += f
            else:
                dx[i] = f * inv_area[i]
        dx[n + p] = v_in
        dx[n + p + 1] = v_out
        dx[n + p + 2] = leaked
        dx[n + p + 3] = spilled
        return dx


# ---- generated right-hand side ------------------------------------------------------------

_GENERATED_CACHE_SIZE = 64
"""Layouts (sets of open valves, leaks, outflows) kept compiled per network."""

_Layout = tuple[
    tuple[int, ...], tuple[int, ...], tuple[int, ...], tuple[tuple[int, int], ...], tuple[_Lagged, ...]
]
"""What a generated right-hand side is unrolled for: outflow, leak and drain tanks, links (up, down),
lagged pumps (j, tank, 1 / lag_s)."""

RhsFn = Callable[[list[float]], list[float]]
"""``f(x) -> dx/dt`` on Python floats (the full state; only levels and pump flows are read)."""
RhsAtFn = Callable[[list[float], list[float], float], list[float]]
"""``f(y, k, c) -> dx/dt`` at the stage point ``y[i] + c * k[i]`` (levels and pump flows)."""

_GENERATED_DOC = '''"""Right-hand side of one tank network, generated by plant_sim.models._generate_rhs.

Why: the RK4 fast path (plant_sim.integrate.step_rk4) evaluates the right-hand side a few
times per scan on a handful of floats, where the loops, tuple unpacking and list allocations of
ScalarRhs.generic cost more than the arithmetic. This is the same code with the loops unrolled
for one layout (which valves, leaks and outflow disturbances are active) and the network's
constants as literals: the same floating-point operations in the same order, so the results
are bit-identical. The held inputs (pump flows, openings times conductances, disturbances)
are arguments of make(). rhs_at(y, k, c) is rhs at the RK4 stage point y + c * k, computed
inside it instead of as a new list.

Guarded by tests/plant_sim/test_generated_rhs.py (bit for bit against ScalarRhs.generic over
random states and inputs, every shipped config, the laminar band, empty and full tanks).
"""
'''


@dataclass(frozen=True)
class GeneratedRhs:
    """Straight-line Python right-hand side for one layout of a network (:func:`_generate_rhs`).

    ``make(*inflows, v_in0, *lagged_targets, *outflows, *leaks, *drains, *links)`` returns
    ``(rhs, rhs_at)`` for one set of held inputs; :class:`ScalarRhs` calls it. Print
    :attr:`source` (``print(ScalarRhs(net, u).code.source)``) to read the generated code;
    tracebacks show its lines too.
    """

    source: str
    make: Callable[..., tuple[RhsFn, RhsAtFn]]
    outside: Callable[[list[float]], bool]
    """Whether any level of a state is below 0 or above Hmax (then :meth:`TankNetwork.project`)."""


def _lit(v: float) -> str:
    """A float as a source literal that parses back to the same bits."""
    if math.isfinite(v):
        return repr(v) if v >= 0.0 and math.copysign(1.0, v) > 0 else f"({v!r})"
    return f"float('{v!r}')"


def _generate_rhs(net: TankNetwork, layout: _Layout) -> GeneratedRhs:
    """Generate and compile :meth:`ScalarRhs.generic` unrolled for one layout of ``net``.

    ``layout`` = (outflow tanks, leak tanks, drain valves' tanks, links (up, down), lagged pumps
    (j, tank, 1/lag_s)), as :class:`ScalarRhs` builds it. Every statement below mirrors one of
    ``generic``: the per-tank sums, ``v_in``, ``v_out``, ``leaked`` and ``spilled`` take their
    terms in the same order, so the generated code is bit-identical to it.
    """
    c = net.scalar_constants
    n, p = c.n, c.p
    outflows, leaks, drains, links, lagged = layout
    names = net.tank_names
    lam = _lit(H_LAMINAR_M)
    inv = _lit(_INV_SQRT_LAM)
    args = [f"inflow{i}" for i in range(n)] + ["v_in0"]
    args += [f"target{j}" for j, _, _ in lagged]
    args += [f"d{m}" for m in range(len(outflows))]
    args += [f"leak{m}" for m in range(len(leaks))]
    args += [f"drain{m}" for m in range(len(drains))]
    args += [f"link{m}" for m in range(len(links))]

    def sqrt_law(h: str) -> str:
        return f"(sqrt({h}) if {h} >= {lam} else ({h} * {inv} if {h} > 0.0 else 0.0))"

    body: list[str] = [f"net{i} = inflow{i}" for i in range(n)]
    body += ["v_in = v_in0", "v_out = 0.0"]
    for j, tank, rate in lagged:
        body += [
            f"# pump {net.pump_names[j]} (lagged) -> {names[tank]}",
            f"net{tank} += q{j}",
            f"v_in += q{j}",
            f"dq{j} = (target{j} - q{j}) * {_lit(rate)}",
        ]
    for m, i in enumerate(outflows):
        body += [
            f"# outflow disturbance of {names[i]}, fading out over the last 0.1 mm",
            f"d = d{m} if h{i} >= {lam} else (d{m} * h{i} / {lam} if h{i} > 0.0 else 0.0)",
            f"net{i} += d",
            "v_out -= d",
        ]
    body.append("leaked = 0.0")
    for m, i in enumerate(leaks):
        body += [
            f"# leak of {names[i]}",
            f"q = leak{m} * {sqrt_law(f'h{i}')}",
            f"net{i} -= q",
            "leaked += q",
        ]
    for m, up in enumerate(drains):
        body += [
            f"# outlet of {names[up]} to the drain",
            f"q = drain{m} * {sqrt_law(f'h{up}')}",
            f"net{up} -= q",
            "v_out += q",
        ]
    clamped = sorted({i for link in links for i in link})
    if clamped:
        body.append("# levels below zero count as empty across a valve")
        body += [f"p{i} = h{i} if h{i} > 0.0 else 0.0" for i in clamped]
    for m, (up, down) in enumerate(links):
        body += [
            f"# valve {names[up]} -> {names[down]}, signed",
            f"dh = p{up} - p{down}",
            f"if dh >= {lam}:",
            f"    q = link{m} * sqrt(dh)",
            f"elif dh <= -{lam}:",
            f"    q = -link{m} * sqrt(-dh)",
            "else:",
            f"    q = link{m} * dh * {inv}",
            f"net{up} -= q",
            f"net{down} += q",
        ]
    body += ["# spilling over the top: the level holds", "spilled = 0.0"]
    for i in range(n):
        body += [
            f"if net{i} > 0.0 and h{i} >= {_lit(c.hmax[i])}:",
            f"    spilled += net{i}",
            f"    r{i} = 0.0",
            "else:",
            f"    r{i} = net{i} * {_lit(c.inv_area[i])}",
        ]
    lagged_j = {j for j, _, _ in lagged}
    out = [f"r{i}" for i in range(n)] + [f"dq{j}" if j in lagged_j else "0.0" for j in range(p)]
    body.append(f"return [{', '.join([*out, 'v_in', 'v_out', 'leaked', 'spilled'])}]")

    reads = [f"h{i}" for i in range(n)] + [f"q{j}" for j in sorted(lagged_j)]
    index = list(range(n)) + [n + j for j in sorted(lagged_j)]
    pad = " " * 8
    lines = [_GENERATED_DOC, "", f"def make({', '.join(args)}):", "    def rhs(x):"]
    lines += [f"{pad}{v} = x[{k}]" for v, k in zip(reads, index, strict=True)]
    lines += [pad + b for b in body]
    lines += ["", "    def rhs_at(y, k, c):"]
    lines += [f"{pad}{v} = y[{k}] + c * k[{k}]" for v, k in zip(reads, index, strict=True)]
    lines += [pad + b for b in body]
    lines += ["", "    return rhs, rhs_at", "", "", "def outside(y):"]
    checks = " or ".join(f"y[{i}] < 0.0 or y[{i}] > {_lit(c.hmax[i])}" for i in range(n))
    lines += [f"    return {checks or 'False'}", ""]
    source = "\n".join(lines)
    filename = f"<plant_sim generated rhs {id(net):x} {len(net._generated)}>"
    namespace: dict[str, object] = {"sqrt": math.sqrt}
    exec(compile(source, filename, "exec"), namespace)  # our own generated source
    linecache.cache[filename] = (len(source), None, source.splitlines(keepends=True), filename)
    return GeneratedRhs(source=source, make=namespace["make"], outside=namespace["outside"])  # type: ignore[arg-type]
