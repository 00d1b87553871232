"""Integrators for the plant ODE: fixed-step RK4 with sub-steps, and an adaptive solver.

Both advance ``x' = f(t, x, u)`` over any ``dt`` with the inputs ``u`` held (zero-order hold,
as a PLC output is held between scans), then project the levels into [0, Hmax] with
:meth:`TankNetwork.project`, which keeps the volume balance exact.

- :func:`step_rk4` runs classical RK4 sub-steps on Python floats through the fast path
  (:mod:`plant_sim.kernel`: the reference right-hand side
  :meth:`~plant_sim.models.HeldRhs.derivative` and the RK4 step :func:`rk4_step` traced into
  straight-line code, bit-identical to them). The coarse sub-step is the
  plant's own (:func:`rk4_substep_s`: ``min(1 s, 0.5 / lambda_smooth)`` with ``lambda_smooth`` a
  bound on every eigenvalue of the Jacobian at states at least ``SMOOTH_ZONE_M`` from a
  non-smooth point, so every mode a coarse step meets is integrated stably and accurately),
  and a sub-step that comes near a non-smooth point of the right-hand side (an empty or full
  tank, equal levels across a valve) is redone in sub-steps of at most :func:`event_substep_s`
  (``EVENT_SUBSTEP_S``, or less where the laminar band's modes need it); a caller may fix the
  sub-step instead (``max_substep_s``). Runge-Kutta methods preserve linear invariants, so the
  balance closes to rounding. Validated against the adaptive solver at tight tolerance in the
  tests: within 1e-6 m on the shipped three-tank sets and a two-tank plant (docs/plant.md). This
  is the fast path (co-simulation).
- :func:`step_adaptive` calls :func:`scipy.integrate.solve_ivp` (RK45 by default, tolerances
  ``rtol``, ``atol``) and raises :class:`~tanklab.errors.IntegrationError` when the solver fails or
  the state is not finite.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from plant_sim.kernel import RhsAtFn, RhsFn, bind
from plant_sim.models import FloatArray, HeldRhs, PlantInputs, TankNetwork
from plant_sim.stiffness import fastest_rate_1_s, rate_bound_1_s
from tanklab.errors import IntegrationError

RK4_STABLE_H_LAMBDA = 2.0
"""Largest ``h * lambda_max`` of a fine sub-step, ``lambda_max`` the fastest mode anywhere (RK4's
real stability interval is 2.785; at 2.0 its amplification factor is 1/3, so even the stiffest
mode, met only in the laminar band near an empty tank or a zero head, is damped)."""

RK4_COARSE_H_LAMBDA = 0.5
"""Largest ``h * lambda_smooth`` of a coarse sub-step, ``lambda_smooth`` the fastest mode outside
the smooth zone: well inside the stability interval, and accurate for that mode too (RK4's
amplification factor differs from ``exp(-0.5)`` by 2.4e-4; the mode is that fast only at the
zone's edge, and ``(h lambda)^5 / 120`` smaller wherever heads are larger)."""

MAX_SUBSTEP_S = 1.0
"""Cap on the automatic sub-step [s] (slow plants: the fastest mode then needs no bound)."""

EVENT_SUBSTEP_S = 0.05
"""Sub-step near the orifice law's and the tanks' non-smooth points [s] (the former fixed
default, validated against solve_ivp to 1e-7 m on a 200 s transient)."""

SMOOTH_ZONE_M = 5e-3
"""Levels and heads closer than this to a non-smooth point take :data:`EVENT_SUBSTEP_S` [m]."""


def rk4_substep_s(net: TankNetwork) -> float:
    """The automatic coarse RK4 sub-step of a plant [s]: ``min(MAX_SUBSTEP_S, 0.5 / lambda_smooth)``.

    ``lambda_smooth`` (:func:`~plant_sim.stiffness.rate_bound_1_s` at ``SMOOTH_ZONE_M``)
    bounds every eigenvalue of the Jacobian at the states where coarse steps are kept: a step
    whose start or end comes within ``SMOOTH_ZONE_M`` of a non-smooth point (an empty tank, a head
    across a valve near zero, where the orifice law is steepest) is redone in
    :func:`event_substep_s` steps. So every mode a coarse step meets is integrated stably and
    accurately (:data:`RK4_COARSE_H_LAMBDA`).
    """
    rate = rate_bound_1_s(net, SMOOTH_ZONE_M)
    return MAX_SUBSTEP_S if rate <= 0.0 else min(MAX_SUBSTEP_S, RK4_COARSE_H_LAMBDA / rate)


def event_substep_s(net: TankNetwork) -> float:
    """The longest fine sub-step near a non-smooth point [s]: ``EVENT_SUBSTEP_S``, shortened to
    ``2.0 / lambda_max`` if the plant's fastest mode anywhere
    (:func:`~plant_sim.stiffness.fastest_rate_1_s`, the laminar band included) needs it."""
    rate = fastest_rate_1_s(net)
    return EVENT_SUBSTEP_S if rate <= 0.0 else min(EVENT_SUBSTEP_S, RK4_STABLE_H_LAMBDA / rate)


def rk4_step(rhs: RhsFn, rhs_at: RhsAtFn, y: list[float], h: float) -> tuple[list[float], float]:
    """One classical RK4 step of ``h`` [s] from ``y``, and the stages' summed dV_spilled/dt [m^3/s].

    ``k1 = f(y)``, ``k2 = f(y + h/2 k1)``, ``k3 = f(y + h/2 k2)``, ``k4 = f(y + h k3)`` (``rhs_at``
    forms the stage point), then ``y + h/6 (k1 + 2 (k2 + k3) + k4)`` entry by entry. Spill rates
    are never negative, so the sum is positive exactly when a stage spilled over a top. The fast
    path runs this step traced (:func:`plant_sim.kernel.bind`).
    """
    hh = 0.5 * h
    k1 = rhs(y)
    k2 = rhs_at(y, k1, hh)
    k3 = rhs_at(y, k2, hh)
    k4 = rhs_at(y, k3, h)
    h6 = h / 6.0
    stages = zip(y, k1, k2, k3, k4, strict=True)
    y_new = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in stages]
    return y_new, k1[-1] + k2[-1] + k3[-1] + k4[-1]


def reference_rhs(held: HeldRhs) -> tuple[RhsFn, RhsAtFn]:
    """``(rhs, rhs_at)`` of the reference itself (what the fast path's kernel is tested against)."""
    m = held.n + held.p

    def rhs_at(y: list[float], k: list[float], c: float) -> list[float]:
        return held([a + c * b for a, b in zip(y[:m], k, strict=False)])

    return held, rhs_at


def _outside(y: list[float], hmax: list[float]) -> bool:
    """Whether a level is below 0 or above its Hmax (then :meth:`TankNetwork.project`)."""
    for h, top in zip(y, hmax, strict=False):  # noqa: SIM110 (any() of a generator: a frame per sub-step)
        if h < 0.0 or h > top:
            return True
    return False


def _near_event(f: HeldRhs, a: list[float], b: list[float]) -> bool:
    """Whether a step from ``a`` to ``b`` comes near a point where the right-hand side is not smooth.

    Those points: an empty tank (the orifice law's square root, its laminar continuation, an
    outflow fading out), a full one (spilling starts), and equal levels across a valve (the
    signed square root of the head). Closer than ``SMOOTH_ZONE_M`` at either end, or a head
    changing sign, counts.
    """
    z = SMOOTH_ZONE_M
    for i, top in enumerate(f.hmax):
        if a[i] < z or b[i] < z or a[i] > top - z or b[i] > top - z:
            return True
    for _k, up, down, _cs in f.links:
        da = a[up] - a[down]
        db = b[up] - b[down]
        if -z < da < z or -z < db < z or (da > 0.0) != (db > 0.0):
            return True
    return False


_STEP_PLANS_KEPT = 64
"""Sub-step plans kept per network (a caller stepping by ever new lengths starts over)."""


def _step_plan(net: TankNetwork, dt_s: float, max_substep_s: float | None) -> tuple[int, float, int]:
    """(coarse sub-steps, their length [s], fine sub-steps per coarse one near an event) of a
    step of ``dt_s`` (0 sub-steps for ``dt_s == 0``); validated and memoised per network, since a
    co-simulation steps by the same scan period every time.

    Raises
    ------
    ValueError
        If ``dt_s`` is negative or not finite.
    """
    plans = net._step_plans
    key = (dt_s, max_substep_s)
    plan = plans.get(key)
    if plan is not None:
        return plan
    if not dt_s >= 0 or not math.isfinite(dt_s):
        raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
    if dt_s == 0:
        plan = (0, 0.0, 1)
    else:
        coarse = rk4_substep_s(net) if max_substep_s is None else max_substep_s
        n_sub = max(1, math.ceil(dt_s / coarse - 1e-9))
        h = dt_s / n_sub
        # near a non-smooth point the error of a long step is of low order in h, and the orifice
        # law is at its steepest: redo it finely (automatic sub-steps only)
        n_fine = math.ceil(h / event_substep_s(net) - 1e-9) if max_substep_s is None else 1
        plan = (n_sub, h, n_fine)
    if len(plans) >= _STEP_PLANS_KEPT:
        plans.clear()
    plans[key] = plan
    return plan


def step_rk4(
    net: TankNetwork,
    x: FloatArray,
    u: PlantInputs,
    dt_s: float,
    *,
    t_s: float = 0.0,
    max_substep_s: float | None = None,
) -> FloatArray:
    """Advance the state by ``dt_s`` with classical RK4 sub-steps.

    Parameters
    ----------
    net : the compiled plant.
    x : (n + p + 4,) state at ``t_s``.
    u : inputs held over the step.
    dt_s : step length [s], >= 0.
    max_substep_s : fixed sub-steps of at most this length [s]; None (default): automatic, the
        plant's :func:`rk4_substep_s`, with any sub-step that comes near a non-smooth point
        (empty or full tank, equal levels across a valve) redone in sub-steps of at most
        :func:`event_substep_s`.

    Returns
    -------
    The state at ``t_s + dt_s``, levels projected into [0, Hmax].
    """
    n_sub, h, n_fine = _step_plan(net, dt_s, max_substep_s)
    if n_sub == 0:
        return x.copy()
    f = HeldRhs(net, u)
    rk4 = bind(f, rk4_step).step
    hmax = f.hmax
    y = x.tolist()
    for _ in range(n_sub):
        # One check of both ends decides, as first checking the start alone and then both would:
        # a start near an event fails either way (the coarse step is then wasted, rarely).
        y_new, spilled = rk4(y, h)
        if n_fine > 1 and (spilled > 0.0 or _near_event(f, y, y_new)):
            steps, hs = n_fine, h / n_fine
        else:
            steps, hs = 0, h
            y = y_new
            if _outside(y, hmax):
                y = net.project(np.array(y)).tolist()
        for _ in range(steps):
            y = rk4(y, hs)[0]
            if _outside(y, hmax):
                y = net.project(np.array(y)).tolist()
    if not math.isfinite(sum(y)):  # NaN or inf anywhere makes the sum non-finite
        raise IntegrationError(f"RK4 produced a non-finite state at t = {t_s + dt_s:.6g} s")
    return np.array(y)


def step_adaptive(
    net: TankNetwork,
    x: FloatArray,
    u: PlantInputs,
    dt_s: float,
    *,
    t_s: float = 0.0,
    rtol: float = 1e-8,
    atol: float = 1e-12,
    method: str = "RK45",
) -> FloatArray:
    """Advance the state by ``dt_s`` with :func:`scipy.integrate.solve_ivp`.

    Raises
    ------
    IntegrationError
        If the solver reports failure or returns a non-finite state.
    """
    if not dt_s >= 0 or not math.isfinite(dt_s):
        raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
    if dt_s == 0:
        return x.copy()
    # solve_ivp shrinks its step forever on a non-finite derivative: refuse it up front.
    f = HeldRhs(net, u)
    if not np.all(np.isfinite(f(x.tolist()))):
        raise IntegrationError(f"non-finite state derivative at t = {t_s:.6g} s (inputs or state not finite)")
    sol = solve_ivp(
        lambda t, y: np.array(f(y.tolist())),
        (t_s, t_s + dt_s),
        x,
        method=method,
        rtol=rtol,
        atol=atol,
        t_eval=[t_s + dt_s],
    )
    if not sol.success:
        raise IntegrationError(f"solve_ivp ({method}) failed at t = {t_s:.6g} s: {sol.message}")
    y = np.asarray(sol.y[:, -1], dtype=float)
    if not np.all(np.isfinite(y)):
        raise IntegrationError(f"solve_ivp ({method}) returned a non-finite state at t = {t_s + dt_s:.6g} s")
    return net.project(y)
