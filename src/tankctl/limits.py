"""Physical limits of a level step: the minimum-time (bang-bang) settling time, and the IMC paper's
transfer-function experiment. Pure: values in, values out.

Minimum-time bound
------------------
For a setpoint step of one level, no controller can move the level faster than its pump at a
limit. On the nonlinear plant (:mod:`plant_sim.models`, levels only, pump lags ignored, inputs
held: valves, leaks and disturbance flows as at the step), the stepped pump runs **bang-bang**:

    phase 1:  Q_j = Q_max (step up)  or  Q_j = Q_min (step down),  until the switching time t_sw
    phase 2:  the flow that holds the target

and ``settling_time_s`` is the time to enter the band ``|h - r| <= band`` and stay in it, the same
definition as the controllers' (:mod:`tankctl.metrics`), over the same window. Phase 2 depends on
how the pump reaches the level:

- **hold** (the pump feeds the controlled tank, every plant here but one variant): phase 2 is the
  flow that makes dh/dt = 0 at the current levels, ``Q_j = -(net inflow of the tank without its
  pump)``, clipped to the pump's range. For one tank it is the constant equilibrium flow
  ``a' sqrt(r) A``; in a network it follows the neighbours while they fill, so the level stays at
  the target (a constant equilibrium flow would let it sag for as long as the slowest neighbour
  takes, which is not a property of the stepped loop). The switching time is the instant the level
  reaches the target (located by the ODE solver's bracketing root finder): switching earlier
  leaves the level short, later overshoots. The result is then a true lower bound on any
  controller's settling time with these inputs, up to the scan (the bound is continuous-time).
- **equilibrium** (the pump reaches the level only through another tank, e.g. h2 driven by qin1):
  phase 2 is the constant flow of the steady state with the level at the target; t_sw is the
  latest switching time whose trajectory does not overshoot the target, found by **bisection**.
  This is the textbook one-switch policy, an upper estimate of the true minimum time of a
  second-order path (which would brake with the pump off before holding).

Other pumps during the bound: a loop in AUTO or REMOTE whose pump feeds its tank holds its own
setpoint the same way (every pump does the best it can for its own level); every other pump keeps
its flow at the step. Simultaneous steps (the fill from empty of both loops) all run bang-bang.
Closed form checked in the tests: one tank, A dh/dt = Q - c sqrt(h), full flow Q from h0, with
w = Q - c sqrt(h):  t(h0 -> h1) = (2 A / c^2) [Q ln(w0 / w1) - (w0 - w1)].

IMC-PI transfer-function experiment (digest 2.7)
-------------------------------------------------
On the paper's own model g(s) = 28.82 / (29.6 s^2 + 14.7 s + 1) (dimensionless: its units are not
printed), with the ideal controller C(s) = Kc (1 + 1 / (Ti s) + Td s):

    y = [C g / (1 + C g)] r + [g / (1 + C g)] d

simulated with :func:`scipy.signal.lsim` for a unit setpoint step at t = 0 and an input
disturbance d of 10 % of the steady input 1 / K from t = 50 s. Controllers: the IMC PID
(lambda = 1 s), the same without Td (the paper's PI), and Ziegler-Nichols' open-loop PI from a
FOPDT fit of g by the tangent at the inflection point of its step response (the reaction-curve
method the rule was made for).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, root

from plant_sim.linearize import level_rhs
from plant_sim.models import PlantInputs, TankNetwork, default_inputs
from plc_emulator.tuning import PidParams, imc_from_denominator, ziegler_nichols_open_loop
from tanklab.config import PlantConfig

FloatArray = NDArray[np.float64]

__all__ = [
    "IMC_DEN",
    "IMC_NUM",
    "FopdtFit",
    "LevelStep",
    "MinTimeResult",
    "TfResponse",
    "fopdt_tangent_fit",
    "imc_tf_experiment",
    "min_time_step",
    "second_order_response",
]

_RTOL = 1e-9
_ATOL = 1e-12
_GRID = 20001
"""Samples of the solution searched for the last exit from the band (then refined by Brent)."""


@dataclass(frozen=True)
class LevelStep:
    """A step of one level for :func:`min_time_step`: ``pump`` moves ``tank`` to ``target_m``;
    settled within ``band_m`` of it [m]."""

    pump: str
    tank: str
    target_m: float
    band_m: float


@dataclass(frozen=True)
class MinTimeResult:
    """The bang-bang bound of one level step.

    Attributes
    ----------
    tank, pump : names.  from_m, target_m, band_m : start level, target and band [m].
    method : ``"hold"`` or ``"bang-bang"`` (see the module docstring).
    switch_time_s : when the pump leaves its limit [s from the step]; None if never.
    settling_time_s : time to enter and stay within the band [s from the step]; None if the
        target is not reached within the horizon (e.g. above what the pump can hold).
    """

    tank: str
    pump: str
    from_m: float
    target_m: float
    band_m: float
    method: Literal["hold", "bang-bang"]
    switch_time_s: float | None
    settling_time_s: float | None


class _Piecewise:
    """Dense solution of several consecutive solve_ivp segments."""

    def __init__(self) -> None:
        self.segments: list[tuple[float, float, Callable[[FloatArray], FloatArray]]] = []

    def add(self, t0: float, t1: float, sol: Callable[[FloatArray], FloatArray]) -> None:
        if t1 > t0:
            self.segments.append((t0, t1, sol))

    def __call__(self, t: FloatArray) -> FloatArray:
        out: FloatArray | None = None
        for t0, t1, sol in self.segments:
            mask = (t >= t0) & (t <= t1)
            if not mask.any():
                continue
            y = np.asarray(sol(t[mask]))
            if out is None:
                out = np.full((y.shape[0], t.size), np.nan)
            out[:, mask] = y
        if out is None:
            raise ValueError("no segment covers the requested times")
        return out

    @property
    def t_end(self) -> float:
        return self.segments[-1][1] if self.segments else 0.0


class _Network:
    """The level dynamics with per-pump policies."""

    def __init__(self, plant: PlantConfig, inputs: PlantInputs | None) -> None:
        self.net = TankNetwork.from_config(plant)
        self.u = inputs if inputs is not None else default_inputs(self.net, plant)
        self.q_min = self.net.pump_target_flows(self.net.pump_cmd_min)
        self.q_max = self.net.pump_target_flows(self.net.pump_cmd_max)
        self.zero = np.zeros(self.net.n_pumps)

    def pump(self, name: str) -> int:
        return self.net.pump_names.index(name)

    def tank(self, name: str) -> int:
        return self.net.tank_names.index(name)

    def feeds(self, j: int, i: int) -> bool:
        return int(self.net.pump_tank[j]) == i

    def rhs(self, h: FloatArray, q: FloatArray) -> FloatArray:
        return level_rhs(self.net, h, q, self.u)

    def hold_flows(self, h: FloatArray, holds: Mapping[int, int]) -> dict[int, float]:
        """Flows making dh/dt = 0 for each (pump -> tank it feeds), clipped to the pump range."""
        if not holds:
            return {}
        base = self.rhs(h, self.zero) * self.net.area_m2  # net inflow without any pump [m^3/s]
        return {j: float(np.clip(-base[i], self.q_min[j], self.q_max[j])) for j, i in holds.items()}


def _solve(
    f: Callable[[float, FloatArray], FloatArray],
    t0: float,
    t1: float,
    h0: FloatArray,
    events: list[Callable[[float, FloatArray], float]] | None = None,
) -> tuple[float, FloatArray, Callable[[FloatArray], FloatArray], bool]:
    """Integrate from t0 until t1 or a terminal event; return (t_end, h_end, dense, hit)."""
    sol = solve_ivp(f, (t0, t1), h0, method="RK45", rtol=_RTOL, atol=_ATOL, dense_output=True, events=events)
    if sol.status < 0:
        raise RuntimeError(f"min-time integration failed at t = {t0:g} s: {sol.message}")
    hit = sol.status == 1
    return float(sol.t[-1]), np.asarray(sol.y[:, -1], dtype=float), sol.sol, hit


def _last_exit(traj: _Piecewise, i: int, target: float, band: float, t_end: float) -> float | None:
    """Time of the last exit from |h_i - target| <= band on [0, t_end] (0 if never outside)."""
    t = np.linspace(0.0, t_end, _GRID)
    dev = np.abs(traj(t)[i] - target) - band
    outside = np.nonzero(dev > 0.0)[0]
    if outside.size == 0:
        return 0.0
    k = int(outside[-1])
    if k == t.size - 1:
        return None

    def g(s: float) -> float:
        return float(abs(traj(np.array([s]))[i, 0] - target) - band)

    return float(brentq(g, t[k], t[k + 1], xtol=1e-12, rtol=1e-12))


def min_time_step(
    plant: PlantConfig,
    levels0_m: ArrayLike,
    steps: Sequence[LevelStep],
    *,
    horizon_s: float,
    held: Mapping[str, tuple[str, float]] | None = None,
    flows_m3_s: Mapping[str, float] | None = None,
    inputs: PlantInputs | None = None,
) -> list[MinTimeResult]:
    """Bang-bang minimum-time settling of one or more simultaneous level steps.

    Parameters
    ----------
    plant : the plant section of a site.
    levels0_m : (n_tanks,) levels at the step [m].
    steps : the stepped levels (one per pump); an indirectly actuated step (the pump does not
        feed the tank) must be the only one.
    horizon_s : how long to look [s] (the step's window: a level not settled by then gives None).
    held : pump -> (tank it feeds, level to hold [m]) for the other controlled loops.
    flows_m3_s : pump -> constant flow [m^3/s] for every other pump (default 0).
    inputs : valve and leak openings and disturbance flows (default: the config's initial ones).

    Returns
    -------
    One :class:`MinTimeResult` per step, in order.
    """
    if not (math.isfinite(horizon_s) and horizon_s > 0):
        raise ValueError(f"horizon_s must be a positive number of seconds, got {horizon_s}")
    nw = _Network(plant, inputs)
    h0 = np.asarray(levels0_m, dtype=float)
    if h0.shape != (nw.net.n_tanks,):
        raise ValueError(f"levels0_m needs {nw.net.n_tanks} levels, got shape {h0.shape}")
    const = nw.zero.copy()
    for name, q in (flows_m3_s or {}).items():
        const[nw.pump(name)] = q
    holds = {nw.pump(p): nw.tank(t) for p, (t, _) in (held or {}).items()}
    for p, (t, _) in (held or {}).items():
        if not nw.feeds(nw.pump(p), nw.tank(t)):
            raise ValueError(f"held pump {p} does not feed tank {t}")
    idx = [(nw.pump(s.pump), nw.tank(s.tank), s) for s in steps]
    if len({j for j, _, _ in idx}) != len(idx):
        raise ValueError("one step per pump")
    indirect = [s for j, i, s in idx if not nw.feeds(j, i)]
    if indirect and len(idx) > 1:
        raise ValueError("an indirectly actuated step must be the only step at its time")
    if indirect:
        j, i, s = idx[0]
        return [_bang_bang_bound(nw, h0, j, i, s, horizon_s, holds, const)]
    return _hold_bound(nw, h0, idx, horizon_s, holds, const)


def _hold_bound(
    nw: _Network,
    h0: FloatArray,
    idx: list[tuple[int, int, LevelStep]],
    horizon_s: float,
    holds: dict[int, int],
    const: FloatArray,
) -> list[MinTimeResult]:
    direction = {j: (1.0 if s.target_m > h0[i] else -1.0) for j, i, s in idx}
    bang = {j for j, i, s in idx if abs(h0[i] - s.target_m) > 0.0}
    switched: dict[int, float] = {}
    for j, i, _ in idx:
        if j not in bang:
            holds[j] = i
            switched[j] = 0.0

    def flows(h: FloatArray) -> FloatArray:
        q = const.copy()
        for j, v in nw.hold_flows(h, holds).items():
            q[j] = v
        for j in bang:
            q[j] = nw.q_max[j] if direction[j] > 0 else nw.q_min[j]
        return q

    def f(_t: float, h: FloatArray) -> FloatArray:
        return nw.rhs(h, flows(h))

    traj = _Piecewise()
    t, h = 0.0, h0.copy()
    while t < horizon_s:
        live = [(j, i, s) for j, i, s in idx if j in bang]
        events: list[Callable[[float, FloatArray], float]] = []
        for _j, i, s in live:

            def ev(_t: float, y: FloatArray, i: int = i, r: float = s.target_m) -> float:
                return float(y[i] - r)

            ev.terminal = True  # type: ignore[attr-defined]
            events.append(ev)
        t1, h1, dense, hit = _solve(f, t, horizon_s, h, events or None)
        traj.add(t, t1, dense)
        t, h = t1, h1
        if not hit:
            break
        for j, i, s in live:  # the level(s) at the target switch to holding it
            if abs(h[i] - s.target_m) <= 1e-9 * max(1.0, abs(s.target_m)):
                h[i] = s.target_m
                bang.discard(j)
                holds[j] = i
                switched[j] = t
    out = []
    for j, i, s in idx:
        settle = _last_exit(traj, i, s.target_m, s.band_m, traj.t_end) if traj.segments else 0.0
        out.append(
            MinTimeResult(
                tank=s.tank,
                pump=s.pump,
                from_m=float(h0[i]),
                target_m=s.target_m,
                band_m=s.band_m,
                method="hold",
                switch_time_s=switched.get(j),
                settling_time_s=settle,
            )
        )
    return out


def _equilibrium(
    nw: _Network, h0: FloatArray, j: int, i: int, target: float, holds: dict[int, int], const: FloatArray
) -> tuple[float, FloatArray]:
    """Constant flow of pump j whose steady state has h_i = target (others in their policies),
    and the levels of that steady state."""
    pinned = {i: target} | {t: float(h0[t]) for t in holds.values()}
    free = [k for k in range(nw.net.n_tanks) if k not in pinned]
    unknown_pumps = [j, *holds.keys()]
    scale = float(nw.q_max.max())

    def unpack(z: FloatArray) -> tuple[FloatArray, FloatArray]:
        q = const.copy()
        q[unknown_pumps] = z[: len(unknown_pumps)] * scale
        h = h0.copy()
        for k, v in pinned.items():
            h[k] = v
        h[free] = z[len(unknown_pumps) :]
        return q, h

    def residual(z: FloatArray) -> FloatArray:
        q, h = unpack(z)
        return nw.rhs(h, q) * nw.net.area_m2 / scale

    z0 = np.concatenate([np.full(len(unknown_pumps), 0.3), h0[free]])
    sol = root(residual, z0, method="hybr", options={"xtol": 1e-14})
    q, h = unpack(sol.x)
    if np.max(np.abs(residual(sol.x))) > 1e-9:
        raise ValueError(f"no steady state holds tank {nw.net.tank_names[i]} at {target} m")
    return float(q[j]), h


def _bang_bang_bound(
    nw: _Network,
    h0: FloatArray,
    j: int,
    i: int,
    s: LevelStep,
    horizon_s: float,
    holds: dict[int, int],
    const: FloatArray,
) -> MinTimeResult:
    """Level i reached through tank m (fed by pump j): on until t_sw, off until h_m = its
    equilibrium value, then the equilibrium flow; t_sw by bisection so that h_i arrives at the
    target exactly when h_m arrives at its equilibrium (earlier: short; later: overshoot)."""
    m = int(nw.net.pump_tank[j])
    up = s.target_m > h0[i]
    q_first = nw.q_max[j] if up else nw.q_min[j]
    q_second = nw.q_min[j] if up else nw.q_max[j]
    result = MinTimeResult(s.tank, s.pump, float(h0[i]), s.target_m, s.band_m, "bang-bang", None, None)
    try:
        q_eq, h_eq = _equilibrium(nw, h0, j, i, s.target_m, holds, const)
    except ValueError:
        return result
    if not nw.q_min[j] <= q_eq <= nw.q_max[j]:
        return result

    def field(q_j: float) -> Callable[[float, FloatArray], FloatArray]:
        def f(_t: float, y: FloatArray) -> FloatArray:
            q = const.copy()
            for k, v in nw.hold_flows(y, holds).items():
                q[k] = v
            q[j] = q_j
            return nw.rhs(y, q)

        return f

    def at(index: int, value: float) -> Callable[[float, FloatArray], float]:
        def ev(_t: float, y: FloatArray) -> float:
            return float(y[index] - value)

        ev.terminal = True  # type: ignore[attr-defined]
        return ev

    def run(t_sw: float, *, finish: bool) -> tuple[_Piecewise, float, float]:
        """Trajectory for switching time t_sw; (traj, h_i when h_m reaches h_eq[m], that time)."""
        traj = _Piecewise()
        t1, h, dense, _ = _solve(field(q_first), 0.0, min(t_sw, horizon_s), h0.copy())
        traj.add(0.0, t1, dense)
        arrive, t_arrive = math.nan, math.nan
        if t1 < horizon_s:
            t2, h, dense, hit = _solve(field(q_second), t1, horizon_s, h, [at(m, float(h_eq[m]))])
            traj.add(t1, t2, dense)
            if hit:
                arrive, t_arrive = float(h[i]), t2
                if finish and t2 < horizon_s:
                    t3, _, dense, _ = _solve(field(q_eq), t2, horizon_s, h)
                    traj.add(t2, t3, dense)
        return traj, arrive, t_arrive

    # The first phase alone must be able to reach the target: the latest useful switch.
    _, _, _, hit = _solve(field(q_first), 0.0, horizon_s, h0.copy(), [at(i, s.target_m)])
    if not hit:
        return result
    sign = 1.0 if up else -1.0
    lo, hi = 0.0, horizon_s
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        _, arrive, _ = run(mid, finish=False)
        short = math.isnan(arrive) or (arrive - s.target_m) * sign < 0.0
        if short:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-9 * max(hi, 1.0):
            break
    traj, _, _ = run(lo, finish=True)
    settle = _last_exit(traj, i, s.target_m, s.band_m, traj.t_end)
    return MinTimeResult(s.tank, s.pump, float(h0[i]), s.target_m, s.band_m, "bang-bang", lo, settle)


# --------------------------------------------------------------------------------------------
# The IMC-PI paper's transfer-function experiment
# --------------------------------------------------------------------------------------------

IMC_NUM = 28.82
"""Numerator of the IMC-PI paper's h2/qin1 model (digest 2.7)."""
IMC_DEN = (29.6, 14.7, 1.0)
"""Denominator of that model, highest power first."""


@dataclass(frozen=True)
class FopdtFit:
    """K e^{-theta s} / (tau s + 1) fitted by the inflection tangent of a step response.

    Attributes
    ----------
    K : gain.  theta : apparent dead time [s].  tau : time constant [s].
    t_inflection : time of the inflection point [s].
    """

    K: float
    theta: float
    tau: float
    t_inflection: float


def fopdt_tangent_fit(K: float, tau1: float, tau2: float) -> FopdtFit:
    """FOPDT fit of K / ((tau1 s + 1)(tau2 s + 1)) by the tangent at the inflection point.

    The step response y(t) = K [1 - (tau2 e^{-t/tau2} - tau1 e^{-t/tau1}) / (tau2 - tau1)] has its
    inflection at t_i = tau1 tau2 ln(tau2 / tau1) / (tau2 - tau1); the tangent there, of slope
    R = y'(t_i), crosses 0 at theta = t_i - y(t_i) / R and K at theta + tau with tau = K / R.
    """
    if not (tau1 > 0 and tau2 > 0 and tau1 != tau2):
        raise ValueError("need two distinct positive time constants")
    a, b = sorted((tau1, tau2))
    ti = a * b * math.log(b / a) / (b - a)
    y = K * (1.0 - (b * math.exp(-ti / b) - a * math.exp(-ti / a)) / (b - a))
    slope = K * (math.exp(-ti / b) - math.exp(-ti / a)) / (b - a)
    theta = ti - y / slope
    return FopdtFit(K=K, theta=theta, tau=K / slope, t_inflection=ti)


@dataclass(frozen=True)
class TfResponse:
    """One controller on the transfer function.

    Attributes
    ----------
    name : label.  Kc, Ti, Td : ideal PID parameters (Ti, Td in s).
    overshoot_pct : of the unit setpoint step.  settling_time_s : 2 % band, setpoint step.
    disturbance_peak : largest |y - 1| after the input disturbance (output units).
    iae : integral of |r - y| over the run (output units x s).
    t, y : the response (for plots).
    """

    name: str
    Kc: float
    Ti: float
    Td: float
    overshoot_pct: float
    settling_time_s: float | None
    disturbance_peak: float
    iae: float
    t: FloatArray
    y: FloatArray


def second_order_response(
    params: PidParams,
    *,
    num: float = IMC_NUM,
    den: tuple[float, float, float] = IMC_DEN,
    duration_s: float = 100.0,
    disturbance_at_s: float = 50.0,
    disturbance_fraction: float = 0.1,
    dt_s: float = 0.005,
    name: str = "",
) -> TfResponse:
    """Closed loop of C(s) = Kc (1 + 1/(Ti s) + Td s) with num / den (see the module docstring)."""
    kc, ti, td = params.Kc, params.Ti, params.Td
    # C = Kc (Ti Td s^2 + Ti s + 1) / (Ti s); g = num / den.
    c_num = kc * np.array([ti * td, ti, 1.0])
    c_den = np.array([ti, 0.0])
    g_num = np.array([num])
    g_den = np.array(den, dtype=float)
    char = np.polyadd(np.polymul(c_den, g_den), np.polymul(c_num, g_num))
    t = np.arange(0.0, duration_s + dt_s / 2, dt_s)
    r = np.ones_like(t)
    d = np.where(t >= disturbance_at_s, disturbance_fraction / num * den[-1], 0.0)
    _, y_r, _ = signal.lsim((np.polymul(c_num, g_num), char), r, t)
    _, y_d, _ = signal.lsim((np.polymul(g_num, c_den), char), d, t)
    y = np.asarray(y_r + y_d, dtype=float)
    before = t < disturbance_at_s
    overshoot = 100.0 * max(0.0, float(np.max(y[before])) - 1.0)
    outside = np.nonzero(np.abs(y[before] - 1.0) > 0.02)[0]
    settling = None if outside.size == 0 or outside[-1] == before.sum() - 1 else float(t[outside[-1] + 1])
    if outside.size == 0:
        settling = 0.0
    return TfResponse(
        name=name,
        Kc=kc,
        Ti=ti,
        Td=td,
        overshoot_pct=overshoot,
        settling_time_s=settling,
        disturbance_peak=float(np.max(np.abs(y[~before] - 1.0))) if (~before).any() else 0.0,
        iae=float(np.sum(np.abs(1.0 - y)) * dt_s),
        t=t,
        y=y,
    )


def imc_tf_experiment(lam: float = 1.0) -> list[TfResponse]:
    """The IMC paper's experiment on its own transfer function: IMC PID, IMC PI (no Td), ZN PI."""
    pid = imc_from_denominator(IMC_NUM, IMC_DEN, lam, pid=True)
    pi = imc_from_denominator(IMC_NUM, IMC_DEN, lam, pid=False)
    fit = fopdt_tangent_fit(pid.K, pid.tau1, pid.tau2)
    zn = ziegler_nichols_open_loop(fit.K, fit.theta, fit.tau, "pi")
    return [
        second_order_response(pid.params, name=f"IMC PID (lambda = {lam:g} s)"),
        second_order_response(pi.params, name=f"IMC PI, Td dropped (lambda = {lam:g} s)"),
        second_order_response(zn, name="Ziegler-Nichols PI (tangent FOPDT fit)"),
    ]
