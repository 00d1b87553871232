"""The admissibility guards a candidate gain set must pass before it is pushed (pure).

Guards, in the order they are reported (:class:`~supervisor.adaptation.decisions.RejectReason`):
finite; inside the gain box; signs (own loop ``Kp >= 0``, ``Ki >= Ki_min > 0``); rate limit per
push ``|g - g_applied| <= max(max_change_fraction |g_applied|, floor)``; closed-loop spectral
radius of the ZOH model with the candidate PID below ``max_spectral_radius``; and the unclamped
input of the linear closed loop, simulated from the current state over ``horizon_steps`` scans,
inside ``[u_min, u_max]`` (excursions beyond a bound the MPC is pinned at in that scan are the
teacher's own saturation and are not counted). Gains in the PID's units, inputs in pump units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from supervisor.adaptation._validate import FloatArray
from supervisor.adaptation.closed_loop import (
    closed_loop_spectral_radius,
    input_bound_violation,
    simulate_pid_inputs,
)
from supervisor.adaptation.decisions import Decision, RejectReason
from supervisor.adaptation.model import LoopModel
from tanklab.gains import GainBox, PidGains

__all__ = ["GainGuards", "HorizonState", "sign_check"]

#: Relative tolerance on the rate limit and on the input-bound comparison (rounding only).
_REL_TOL = 1e-9
_GAIN_NAMES = ("Kp", "Ki", "Kd")  # as the rejection messages name them


@dataclass(frozen=True)
class HorizonState:
    """Where the input-bound simulation starts: the last formed sample's readings.

    ``x`` the measured state [m], ``u`` the applied MV [pump unit], ``e`` and ``e_prev`` the
    PID's last two errors and ``r`` the setpoints [m]; ``mpc_at_max`` / ``mpc_at_min`` per pump:
    the MPC's input of that scan sat at ``u_max`` / ``u_min``.
    """

    x: FloatArray
    u: FloatArray
    e: FloatArray
    e_prev: FloatArray
    r: FloatArray
    mpc_at_max: NDArray[np.bool_]
    mpc_at_min: NDArray[np.bool_]


def sign_check(gains: PidGains, own: tuple[int, ...], ki_min: FloatArray) -> tuple[bool, str]:
    """Own-loop ``Kp_i >= 0`` and ``Ki_i >= ki_min_i`` for every pump ``i``; (ok, first failure)."""
    m = len(own)
    idx = (np.arange(m), np.asarray(own))
    kp_own = gains.kp[idx]
    ki_own = gains.ki[idx]
    for i in range(m):
        if not kp_own[i] >= 0.0:
            return False, f"Kp[{i},{own[i]}] = {kp_own[i]:.6g} < 0"
        if not ki_own[i] >= ki_min[i]:
            return False, f"Ki[{i},{own[i]}] = {ki_own[i]:.6g} < Ki_min = {ki_min[i]:.6g}"
    return True, ""


@dataclass(frozen=True, eq=False)
class GainGuards:
    """The guards of one adapter, with the limits it derived (box, own loops, Ki_min, floor).

    Attributes
    ----------
    model : LoopModel
    box : GainBox
        Admissible gains.
    own : tuple of int
        Loop of each pump.
    ki_min : ndarray, shape (n_u,)
        Own-loop Ki lower bound per pump.
    floor : ndarray, shape (3, n_u, n_loops)
        The rate limit's absolute floor per gain ``[Kp, Ki, Kd]``.
    max_change_fraction, max_spectral_radius : float
    horizon_steps : int
        As in :class:`~supervisor.adaptation.config.AdaptationConfig`.
    """

    model: LoopModel
    box: GainBox
    own: tuple[int, ...]
    ki_min: FloatArray
    floor: FloatArray
    max_change_fraction: float
    max_spectral_radius: float
    horizon_steps: int

    def step_limit(self, applied: FloatArray) -> FloatArray:
        """Largest change per push of each gain from ``applied`` (shape (3, n_u, n_loops))."""
        return np.maximum(self.max_change_fraction * np.abs(applied), self.floor)

    def evaluate(
        self, candidate: PidGains, applied: PidGains, horizon: HorizonState | None, t_s: float = math.nan
    ) -> Decision:
        """Judge ``candidate`` against every guard (pure).

        Guards (all evaluated; ``reasons`` lists every failure in this order):

        * ``non_finite``: every gain finite (if not, nothing else is evaluated);
        * ``outside_box``: ``box.lower <= g <= box.upper`` element-wise;
        * ``sign``: own-loop ``Kp_i >= 0`` and ``Ki_i >= Ki_min,i > 0``;
        * ``rate_limit``: ``|g - g_applied| <= max(max_change_fraction |g_applied|, floor)``;
        * ``unstable``: ``rho(M(candidate)) < max_spectral_radius`` (:func:`closed_loop_matrix`);
        * ``input_bounds``: :func:`simulate_pid_inputs` from the current state (``horizon``, the last formed
          sample: measured state, applied MV, the PID's last two errors, setpoints held) over
          ``horizon_steps``; the peak excursion beyond ``[u_min, u_max]`` (fraction of range)
          must be 0, or, when the applied gains' own simulation already leaves the bounds (a large
          setpoint error that saturates any sensible gains), no larger than theirs. Excursions of
          pump i above ``u_max`` (below ``u_min``) are not counted when the MPC's input of that
          sample sat at ``u_max`` (``u_min``): the teacher saturates there itself. Skipped
          (``input_violation`` NaN) before the first formed sample.

        Parameters
        ----------
        candidate : PidGains
            Shape (n_u, n_loops).
        applied : PidGains
            The gains the PLC applies: the rate limit's and the input-bound guard's reference.
        horizon : HorizonState or None
            The state the input-bound simulation starts from (None: guard skipped).
        t_s : float, optional
            Model time recorded in the decision [s].
        """
        model = self.model
        if candidate.shape != (model.n_u, model.n_loops):
            raise ValueError(f"candidate must have shape {(model.n_u, model.n_loops)}, got {candidate.shape}")
        changed = not candidate.allclose(applied, rtol=0.0)
        if not candidate.is_finite():
            return Decision(
                t_s,
                candidate,
                False,
                (RejectReason.NON_FINITE,),
                "a gain is not finite",
                math.nan,
                math.nan,
                changed,
            )
        reasons: list[RejectReason] = []
        details: list[str] = []
        g = candidate.stacked()
        lo, hi = self.box.lower.stacked(), self.box.upper.stacked()
        outside = (g < lo) | (g > hi)
        if outside.any():
            t, i, j = (int(v) for v in np.argwhere(outside)[0])
            reasons.append(RejectReason.OUTSIDE_BOX)
            details.append(
                f"{_GAIN_NAMES[t]}[{i},{j}] = {g[t, i, j]:.6g} outside [{lo[t, i, j]:.6g}, {hi[t, i, j]:.6g}]"
            )
        sign_ok, sign_detail = sign_check(candidate, self.own, self.ki_min)
        if not sign_ok:
            reasons.append(RejectReason.SIGN)
            details.append(sign_detail)
        a = applied.stacked()
        limit = self.step_limit(a)
        too_fast = np.abs(g - a) > limit * (1.0 + _REL_TOL)
        if too_fast.any():
            t, i, j = (int(v) for v in np.argwhere(too_fast)[0])
            reasons.append(RejectReason.RATE_LIMIT)
            step = g[t, i, j] - a[t, i, j]
            details.append(f"{_GAIN_NAMES[t]}[{i},{j}] changes by {step:.6g}, limit {limit[t, i, j]:.6g}")
        rho = closed_loop_spectral_radius(
            model.A, model.B, model.C, candidate.kp, candidate.ki, candidate.kd, model.ts_s
        )
        if not rho < self.max_spectral_radius:
            reasons.append(RejectReason.UNSTABLE)
            details.append(f"spectral radius {rho:.6f} >= {self.max_spectral_radius}")
        violation = math.nan
        hs = horizon
        if hs is not None:
            kwargs = {"x0": hs.x, "u0": hs.u, "e0": hs.e, "e_prev": hs.e_prev, "r": hs.r}
            n = self.horizon_steps
            allow = {"allow_above": hs.mpc_at_max, "allow_below": hs.mpc_at_min}
            violation = input_bound_violation(
                simulate_pid_inputs(model, candidate, n_steps=n, **kwargs), model.u_min, model.u_max, **allow
            )
            if violation > 0.0:
                reference = input_bound_violation(
                    simulate_pid_inputs(model, applied, n_steps=n, **kwargs),
                    model.u_min,
                    model.u_max,
                    **allow,
                )
                if violation > reference * (1.0 + _REL_TOL):
                    reasons.append(RejectReason.INPUT_BOUNDS)
                    details.append(
                        f"simulated input leaves its bounds by {violation:.4g} of its range "
                        f"(applied gains: {reference:.4g})"
                    )
        return Decision(
            t_s,
            candidate,
            not reasons,
            tuple(reasons),
            details[0] if details else "",
            rho,
            violation,
            changed,
        )
