"""Linearization of the tank network and zero-order-hold discretization.

Around levels ``h0`` and pump flows ``Q0`` (valves and leaks held at their openings), the level
dynamics ``dh/dt = f(h, Q)`` of :mod:`plant_sim.models` give

    d(dh)/dt = A dh + B dQ,    y = C dh + D dQ,    C = I (every level measured), D = 0

with the analytic Jacobian: an orifice of conductance ``c`` and opening ``s`` between tanks m
and n carries ``q = s c sign(h_m - h_n) sqrt|h_m - h_n|``, so

    dq/dh_m = s c / (2 sqrt|h_m - h_n|) = -dq/dh_n,      A = diag(1/A_i) d(net inflow)/dh

(for the three-tank plant this is the digest's A with ``a_mn = mu_mn k / sqrt(h_m - h_n)``,
``k = Ap sqrt(2 g) / (2 At)``) and ``B = diag(1/A_i) P`` with P the pump incidence. B is taken
with respect to the pump FLOWS in m^3/s, also for speed-commanded pumps (multiply by the pump
map's slope for rpm). Pump lags are not part of the linear model.

Discretization with a zero-order hold over ``Ts``:

    [[Ad, Bd], [0, I]] = expm([[A, B], [0, 0]] Ts)

Equilibria: :func:`equilibrium_flows` finds the pump flows (and the levels of tanks without a
pump) that hold the levels of the pump-fed tanks; :func:`steady_levels` finds the levels that
given flows settle at.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm
from scipy.optimize import root

from plant_sim.models import DRAIN, FloatArray, HeldRhs, PlantInputs, TankNetwork, signed_sqrt_slope
from tanklab.config import PlantConfig


@dataclass(frozen=True)
class LinearModel:
    """A linear state-space model of the levels, in deviations around an operating point.

    Attributes
    ----------
    A : (n, n); B : (n, p) per m^3/s of pump flow; C : (n, n); D : (n, p).
    ts_s : sample time [s] of a discrete model, ``None`` for a continuous one.
    levels_op_m : (n,) levels of the operating point [m].
    flows_op_m3_s : (p,) pump flows of the operating point [m^3/s].
    state_names, input_names, output_names : labels.
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray
    ts_s: float | None
    levels_op_m: FloatArray
    flows_op_m3_s: FloatArray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]

    @property
    def discrete(self) -> bool:
        return self.ts_s is not None


def level_rhs(net: TankNetwork, h: FloatArray, q: FloatArray, u: PlantInputs) -> FloatArray:
    """dh/dt [m/s] of the level dynamics with pump flows ``q`` [m^3/s] given directly (no spill,
    no lag): the reference right-hand side (:class:`~plant_sim.models.HeldRhs`) with every pump
    held at its flow, its net inflows before spilling over the tanks' areas."""
    f = HeldRhs(net, u, pump_flows_m3_s=np.asarray(q, dtype=float).tolist())
    flows = f.flows(net.initial_state(np.asarray(h, dtype=float)).tolist())
    return (flows.net + flows.spill) / net.area_m2


def jacobian(net: TankNetwork, levels_m: FloatArray, u: PlantInputs) -> tuple[FloatArray, FloatArray]:
    """Analytic (A, B) of the level dynamics at ``levels_m`` (continuous time).

    Returns
    -------
    A : (n, n) [1/s]; B : (n, p) [1/m^2] (per m^3/s of pump flow).
    """
    n = net.n_tanks
    h = np.maximum(np.asarray(levels_m, dtype=float), 0.0)
    dnet = np.zeros((n, n))
    for k in range(net.n_valves):
        m, d = int(net.valve_up[k]), int(net.valve_down[k])
        hd = 0.0 if d == DRAIN else h[d]
        g = u.valve_openings[k] * net.valve_conductance[k] * float(signed_sqrt_slope(np.array(h[m] - hd)))
        dnet[m, m] -= g
        if d != DRAIN:
            dnet[m, d] += g
            dnet[d, d] -= g
            dnet[d, m] += g
    leak_g = u.leak_openings * net.leak_conductance * signed_sqrt_slope(h)
    dnet -= np.diag(leak_g)
    A = dnet / net.area_m2[:, None]
    B = net.pump_matrix / net.area_m2[:, None]
    return A, B


def discretize_zoh(A: FloatArray, B: FloatArray, ts_s: float) -> tuple[FloatArray, FloatArray]:
    """Zero-order-hold discretization: (Ad, Bd) = blocks of expm([[A, B], [0, 0]] Ts)."""
    if not ts_s > 0:
        raise ValueError(f"ts_s must be > 0, got {ts_s}")
    n, p = B.shape
    M = np.zeros((n + p, n + p))
    M[:n, :n] = A
    M[:n, n:] = B
    E = expm(M * ts_s)
    return E[:n, :n], E[:n, n:]


def equilibrium_flows(
    net: TankNetwork, levels_m: FloatArray, u: PlantInputs
) -> tuple[FloatArray, FloatArray]:
    """Pump flows holding the levels of the pump-fed tanks at ``levels_m``.

    The levels of tanks without a pump are unknowns too (seeded from ``levels_m``).

    Returns
    -------
    flows : (p,) [m^3/s]; levels : (n,) the equilibrium levels [m].

    Raises
    ------
    ValueError
        If no equilibrium with non-negative flows exists near the guess.
    """
    fed = sorted({int(i) for i in net.pump_tank})
    free = [i for i in range(net.n_tanks) if i not in fed]
    h_fixed = np.asarray(levels_m, dtype=float)

    # Flows are solved in units of the pumps' maximum flow so that every unknown is O(1).
    q_scale = net.pump_max_flow_m3_s

    def unpack(z: FloatArray) -> tuple[FloatArray, FloatArray]:
        h = h_fixed.copy()
        h[free] = z[net.n_pumps :]
        return z[: net.n_pumps] * q_scale, h

    def residual(z: FloatArray) -> FloatArray:
        q, h = unpack(z)
        return level_rhs(net, h, q, u) * net.area_m2 / q_scale.max()

    z0 = np.concatenate([np.full(net.n_pumps, 0.3), h_fixed[free]])
    sol = root(residual, z0, method="hybr", options={"xtol": 1e-14})
    q, h = unpack(sol.x)
    # Judged by the residual: hybr may stop with "not making good progress" once at rounding.
    if np.max(np.abs(residual(sol.x))) > 1e-10 or np.any(q < -1e-15):
        raise ValueError(f"no equilibrium with non-negative pump flows holds levels {levels_m}")
    return np.maximum(q, 0.0), h


def steady_levels(
    net: TankNetwork, flows_m3_s: FloatArray, u: PlantInputs, guess_m: FloatArray
) -> FloatArray:
    """Levels [m] at which constant pump flows settle (overflow ignored).

    Raises
    ------
    ValueError
        If the solver does not converge.
    """
    q = np.asarray(flows_m3_s, dtype=float)

    scale = net.pump_max_flow_m3_s.max()

    def residual(h: FloatArray) -> FloatArray:
        return level_rhs(net, h, q, u) * net.area_m2 / scale

    sol = root(residual, np.asarray(guess_m, dtype=float), method="hybr", options={"xtol": 1e-14})
    if np.max(np.abs(residual(sol.x))) > 1e-10:
        raise ValueError(f"no steady state found for flows {flows_m3_s}: {sol.message}")
    return np.asarray(sol.x, dtype=float)


@dataclass(frozen=True)
class OperatingPoint:
    """Where a site is linearized.

    ``levels_m`` are the configured (printed) levels; ``flows_m3_s`` the configured flows or, if
    none, the equilibrium flows holding the pump-fed levels; ``equilibrium_levels_m`` the levels
    those flows settle at (equal to ``levels_m`` when the configuration is consistent).
    """

    levels_m: FloatArray
    flows_m3_s: FloatArray
    equilibrium_levels_m: FloatArray
    commands: FloatArray


def operating_point(net: TankNetwork, plant: PlantConfig, u: PlantInputs) -> OperatingPoint:
    """The operating point of a plant config (flows computed when not given)."""
    levels = np.array(plant.operating_point.levels_m, dtype=float)
    if plant.operating_point.flows_m3_s is None:
        flows, eq = equilibrium_flows(net, levels, u)
    else:
        flows = np.array(plant.operating_point.flows_m3_s, dtype=float)
        eq = steady_levels(net, flows, u, levels)
    return OperatingPoint(levels, flows, eq, net.pump_commands_for(flows))


def linearize(
    net: TankNetwork,
    levels_m: FloatArray,
    flows_m3_s: FloatArray,
    u: PlantInputs,
    ts_s: float | None = None,
) -> LinearModel:
    """Linear model at (levels, flows); ZOH-discretized when ``ts_s`` is given."""
    A, B = jacobian(net, levels_m, u)
    if ts_s is not None:
        A, B = discretize_zoh(A, B, ts_s)
    n, p = B.shape
    return LinearModel(
        A=A,
        B=B,
        C=np.eye(n),
        D=np.zeros((n, p)),
        ts_s=ts_s,
        levels_op_m=np.asarray(levels_m, dtype=float),
        flows_op_m3_s=np.asarray(flows_m3_s, dtype=float),
        state_names=tuple(f"h{name[1:]}" for name in net.tank_names),
        input_names=tuple(f"Q{name[1:]}" for name in net.pump_names),
        output_names=tuple(f"h{name[1:]}" for name in net.tank_names),
    )
