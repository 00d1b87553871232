"""Closed-loop performance metrics of a sampled run (pure: arrays in, numbers out).

A run is sampled once per PLC scan at times ``t_k = t_0 + k Ts``; ``y_k`` is a level [m] at the
start of scan k and ``r_k`` the setpoint the scan used, so the error is ``e_k = r_k - y_k`` (the
sign used everywhere in tanklab). Integrals are rectangle sums over the scans, as a PLC or the
papers' sampled data would compute them:

    IAE  = sum_k |e_k| Ts             [m s]
    ISE  = sum_k e_k^2 Ts             [m^2 s]
    ITAE = sum_k t_k |e_k| Ts         [m s^2]   (t_k from the start of the run)

Step metrics, for a setpoint step at ``t_s`` from ``y0`` (the setpoint before, or the initial level
for the initial fill) to ``r``, over a window ``[t_s, t_end)`` (until the next event of any kind,
so that a later disturbance is not counted as a failure to settle; it shows in the IAE):

    overshoot_pct   = 100 max(0, max_window (y - r) sign(r - y0)) / |r - y0|
    settling_time_s = t_{j+1} - t_s, j the last sample in the window with |y_j - r| > band |r - y0|
                      (the last exit from the band; 0 if no sample is outside; None if the last
                      sample of the window is outside: not settled within the window)

``max_du`` is the largest |u_k - u_{k-1}| over the scans in the pump's unit, u_{-1} the command
before the first scan. ``constraint_violations`` counts scans with a level at or above Hmax (the
plant holds an overflowing level at Hmax and spills, so "above" shows as "at") or below 0, a
command outside the pump's range, or a flow move beyond an MPC's rate bound.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "LoopMetrics",
    "Step",
    "StepMetrics",
    "constraint_violations",
    "find_steps",
    "iae",
    "ise",
    "itae",
    "loop_metrics",
    "max_du",
    "step_metrics",
]

_SP_CHANGE_M = 1e-12
"""Smallest setpoint change [m] that counts as a step (anything above rounding)."""

_DU_TOLERANCE = 1e-9
"""Relative slack on a rate bound before a move counts as a violation (solver rounding)."""


def _vec(x: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {a.shape}")
    return a


def _ts(ts_s: float) -> float:
    if not (math.isfinite(ts_s) and ts_s > 0):
        raise ValueError(f"ts_s must be a positive number of seconds, got {ts_s}")
    return float(ts_s)


def iae(e: ArrayLike, ts_s: float) -> float:
    """Integral of absolute error, sum |e_k| Ts [m s] for e in m."""
    return float(np.sum(np.abs(_vec(e, "e"))) * _ts(ts_s))


def ise(e: ArrayLike, ts_s: float) -> float:
    """Integral of squared error, sum e_k^2 Ts [m^2 s]."""
    a = _vec(e, "e")
    return float(np.sum(a * a) * _ts(ts_s))


def itae(t_s: ArrayLike, e: ArrayLike, ts_s: float) -> float:
    """Integral of time-weighted absolute error, sum t_k |e_k| Ts [m s^2]."""
    t, a = _vec(t_s, "t_s"), _vec(e, "e")
    if t.shape != a.shape:
        raise ValueError(f"t_s and e must have the same shape, got {t.shape} and {a.shape}")
    return float(np.sum(t * np.abs(a)) * _ts(ts_s))


def max_du(u: ArrayLike, u_before: float | None = None) -> float:
    """Largest |u_k - u_{k-1}| [pump unit]; ``u_before`` is u_{-1} (None: start from u_0)."""
    a = _vec(u, "u")
    if u_before is not None:
        a = np.concatenate([[float(u_before)], a])
    if a.size < 2:
        return 0.0
    return float(np.max(np.abs(np.diff(a))))


def constraint_violations(
    levels_m: ArrayLike,
    height_max_m: float,
    commands: ArrayLike,
    command_min: float,
    command_max: float,
    *,
    flows_m3_s: ArrayLike | None = None,
    flow_before_m3_s: float | None = None,
    du_max_m3_s: float | None = None,
    rate_checked: ArrayLike | None = None,
) -> int:
    """Number of scans with at least one violation (see the module docstring).

    Parameters
    ----------
    levels_m : (N,) level of the loop's tank at each scan [m].
    height_max_m : the tank's overflow height Hmax [m].
    commands : (N,) the pump's command [pump unit]; command_min, command_max its range.
    flows_m3_s, flow_before_m3_s, du_max_m3_s : the pump's flow per scan, before the first scan,
        and the MPC's rate bound per scan [m^3/s]; the rate check runs only when all are given.
    rate_checked : (N,) bool, the scans the rate bound applies to (the MPC drove the pump);
        default: every scan.
    """
    h = _vec(levels_m, "levels_m")
    u = _vec(commands, "commands")
    if h.shape != u.shape:
        raise ValueError(f"levels_m and commands must have the same shape, got {h.shape} and {u.shape}")
    bad = (h >= height_max_m) | (h < 0.0) | (u < command_min) | (u > command_max)
    if flows_m3_s is not None and du_max_m3_s is not None and flow_before_m3_s is not None:
        q = _vec(flows_m3_s, "flows_m3_s")
        if q.shape != h.shape:
            raise ValueError("flows_m3_s must have one value per scan")
        dq = np.abs(np.diff(np.concatenate([[float(flow_before_m3_s)], q])))
        over = dq > du_max_m3_s * (1.0 + _DU_TOLERANCE) + 1e-15
        if rate_checked is not None:
            mask = np.asarray(rate_checked, dtype=bool)
            if mask.shape != h.shape:
                raise ValueError("rate_checked must have one value per scan")
            over &= mask
        bad |= over
    return int(np.count_nonzero(bad))


@dataclass(frozen=True)
class Step:
    """A setpoint step of one loop: at scan ``index`` (time ``t_s``) from ``from_m`` to ``to_m``."""

    index: int
    t_s: float
    from_m: float
    to_m: float


def find_steps(setpoints_m: ArrayLike, t_s: ArrayLike, initial_level_m: float) -> list[Step]:
    """Every setpoint step of one loop, in time order.

    The first scan's setpoint counts as a step from the initial level (the fill from empty, or
    any start away from the setpoint); later ones wherever the setpoint changes between scans.
    """
    sp, t = _vec(setpoints_m, "setpoints_m"), _vec(t_s, "t_s")
    if sp.shape != t.shape:
        raise ValueError("setpoints_m and t_s must have the same shape")
    steps: list[Step] = []
    if sp.size == 0:
        return steps
    if abs(sp[0] - initial_level_m) > _SP_CHANGE_M:
        steps.append(Step(0, float(t[0]), float(initial_level_m), float(sp[0])))
    for k in np.nonzero(np.abs(np.diff(sp)) > _SP_CHANGE_M)[0] + 1:
        steps.append(Step(int(k), float(t[k]), float(sp[k - 1]), float(sp[k])))
    return steps


@dataclass(frozen=True)
class StepMetrics:
    """Overshoot [% of the step] and settling time [s from the step; None: not settled]."""

    overshoot_pct: float
    settling_time_s: float | None


def step_metrics(
    t_s: ArrayLike, y_m: ArrayLike, t_step_s: float, from_m: float, to_m: float, band: float
) -> StepMetrics:
    """Overshoot and settling of a step, on the samples ``t_s`` (the step's window).

    Parameters
    ----------
    t_s, y_m : (N,) sample times [s] and levels [m] of the window, starting at the step.
    t_step_s : time of the step [s].  from_m, to_m : setpoint before (or initial level) and after.
    band : settling band as a fraction of the step size |to - from|, in (0, 1).
    """
    t, y = _vec(t_s, "t_s"), _vec(y_m, "y_m")
    if t.shape != y.shape:
        raise ValueError("t_s and y_m must have the same shape")
    if not 0.0 < band < 1.0:
        raise ValueError(f"band must lie in (0, 1), got {band}")
    size = to_m - from_m
    if abs(size) <= _SP_CHANGE_M:
        raise ValueError("a step needs from_m != to_m")
    if y.size == 0:
        return StepMetrics(0.0, None)
    direction = 1.0 if size > 0 else -1.0
    peak = float(np.max((y - to_m) * direction))
    overshoot = 100.0 * max(0.0, peak) / abs(size)
    outside = np.nonzero(np.abs(y - to_m) > band * abs(size))[0]
    if outside.size == 0:
        settling: float | None = 0.0
    elif outside[-1] == y.size - 1:
        settling = None
    else:
        settling = float(t[outside[-1] + 1] - t_step_s)
    return StepMetrics(overshoot, settling)


@dataclass(frozen=True)
class LoopMetrics:
    """Metrics of one loop over a whole run (the JSON ``loops`` entry).

    ``overshoot_pct`` and ``settling_time_s`` are the worst over the loop's steps (settling None
    if any step did not settle, or if the loop had no step).
    """

    iae: float
    ise: float
    itae: float
    overshoot_pct: float | None
    settling_time_s: float | None
    max_du: float
    constraint_violations: int

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready mapping with the issue's keys."""
        return asdict(self)


def loop_metrics(
    t_s: ArrayLike,
    ts_s: float,
    y_m: ArrayLike,
    r_m: ArrayLike,
    step_results: list[StepMetrics],
    *,
    max_du_value: float,
    violations: int,
) -> LoopMetrics:
    """Assemble :class:`LoopMetrics` from the run and the loop's step results."""
    t, y, r = _vec(t_s, "t_s"), _vec(y_m, "y_m"), _vec(r_m, "r_m")
    e = r - y
    if step_results:
        overshoot: float | None = max(s.overshoot_pct for s in step_results)
        times = [s.settling_time_s for s in step_results]
        settling = None if any(x is None for x in times) else max(x for x in times if x is not None)
    else:
        overshoot, settling = None, None
    return LoopMetrics(
        iae=iae(e, ts_s),
        ise=ise(e, ts_s),
        itae=itae(t, e, ts_s),
        overshoot_pct=overshoot,
        settling_time_s=settling,
        max_du=max_du_value,
        constraint_violations=violations,
    )
