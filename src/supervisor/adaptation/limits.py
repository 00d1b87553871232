"""The admissible region of one adapter's gains, derived once from the fixed gains and the config.

Gains are stacked ``[Kp, Ki, Kd]`` of shape (3, n_u, n_loops) in the PID's units. The region is
the gain box (default: per pump row and gain type ``+-10 x`` the largest fixed gain, the entries a
pump does not adapt pinned to their fixed values) intersected with the sign region (own loop
``Kp >= 0``, ``Ki >= Ki_min > 0``, Kd between 0 and its fixed value with ``kd_keep_sign``); the
model-based prior (:func:`~supervisor.adaptation.closed_loop.model_based_gains`, SIMC with
``tau_c`` default ``4 Ts``) is clipped into it. The rate limit's floor defaults to
``max_change_fraction * 0.1 x`` the row's largest fixed gain of the type, and with the prior
estimator at least ``max_change_fraction`` of the gain's natural scale (the larger of its fixed
and model-based values).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from supervisor.adaptation._validate import FloatArray
from supervisor.adaptation.closed_loop import model_based_gains
from supervisor.adaptation.config import AdaptationConfig
from supervisor.adaptation.guards import sign_check
from supervisor.adaptation.model import LoopModel
from tanklab.gains import GainBox, PidGains

__all__ = ["GainLimits", "gain_limits"]


@dataclass(frozen=True, eq=False)
class GainLimits:
    """One adapter's limits (see the module doc); arrays stacked (3, n_u, n_loops) unless noted.

    Attributes
    ----------
    ki_min : ndarray, shape (n_u,)
        Own-loop Ki lower bound per pump.
    box : GainBox
        The gain box in force (configured or default).
    lower, upper : ndarray
        Projection bounds of the estimators: the box intersected with the sign region.
    prior : ndarray
        The model-based tuning clipped into ``[lower, upper]`` (cross gains: the fixed ones).
    floor : ndarray
        The rate limit's absolute floor per gain.
    row_scale : ndarray, shape (3, n_u, 1)
        Largest fixed gain of each type per pump row.
    """

    ki_min: FloatArray
    box: GainBox
    lower: FloatArray
    upper: FloatArray
    prior: FloatArray
    floor: FloatArray
    row_scale: FloatArray


def gain_limits(
    model: LoopModel,
    fixed: PidGains,
    cfg: AdaptationConfig,
    own: tuple[int, ...],
    own_mask: NDArray[np.bool_],
    adapt_mask: NDArray[np.bool_],
) -> GainLimits:
    """Derive the limits; ``own_mask`` / ``adapt_mask`` (n_u, n_loops) mark own and fitted gains.

    Raises
    ------
    ValueError
        On an invalid ``ki_min``, box or ``change_floor``, fixed gains outside the box or
        violating the sign guard, or a box that leaves no room for the sign region.
    """
    m, nl = model.n_u, model.n_loops
    g_fixed = fixed.stacked()  # (3, m, nl)
    row_scale = np.abs(g_fixed).max(axis=2, keepdims=True)  # (3, m, 1)

    # ki_min per pump
    if cfg.ki_min is None:
        ki_min = 0.1 * fixed.ki[np.arange(m), own]
    else:
        ki_min = np.broadcast_to(np.asarray(cfg.ki_min, dtype=np.float64), (m,)).copy()
    if not (np.isfinite(ki_min).all() and (ki_min > 0).all()):
        raise ValueError("ki_min must be finite and > 0 for every pump (the own-loop Ki must be > 0)")

    # Gain box
    if cfg.box is None:
        bound = 10.0 * np.broadcast_to(row_scale, g_fixed.shape)
        lo = np.where(adapt_mask, -bound, g_fixed)
        hi = np.where(adapt_mask, bound, g_fixed)
        box = GainBox(PidGains.from_stacked(lo), PidGains.from_stacked(hi))
    else:
        box = cfg.box
        if box.lower.shape != (m, nl):
            raise ValueError(f"box must have shape {(m, nl)}, got {box.lower.shape}")
    if not box.contains(fixed):
        raise ValueError("fixed gains must lie inside the gain box")
    sign_ok, detail = sign_check(fixed, own, ki_min)
    if not sign_ok:
        raise ValueError(f"fixed gains violate the sign guard: {detail}")

    # Projection bounds in physical units = box intersected with the sign region.
    lo_phys = box.lower.stacked().copy()
    lo_phys[0][own_mask] = np.maximum(lo_phys[0][own_mask], 0.0)
    own_ki_lo = lo_phys[1][np.arange(m), own]
    lo_phys[1][np.arange(m), own] = np.maximum(own_ki_lo, ki_min)
    hi_phys = box.upper.stacked().copy()
    if cfg.kd_keep_sign:
        # Kd between 0 and its fixed value (ADR 0014): it may shrink to 0, never flip sign.
        kd_f = g_fixed[2]
        keep = own_mask
        lo_phys[2][keep] = np.maximum(lo_phys[2][keep], np.minimum(kd_f[keep], 0.0))
        hi_phys[2][keep] = np.minimum(hi_phys[2][keep], np.maximum(kd_f[keep], 0.0))
    if (lo_phys > hi_phys).any():
        raise ValueError("the gain box leaves no room for the sign guard (Kp >= 0, Ki >= ki_min)")

    # The model-based tuning: the prior of the estimator (and the nodes' reference).
    tau_c = cfg.prior_closed_loop_s if cfg.prior_closed_loop_s is not None else 4.0 * model.ts_s
    prior_g = model_based_gains(model, own, tau_c).stacked()
    prior_g = np.where(own_mask, prior_g, g_fixed)  # cross gains: the fixed ones
    prior_g = np.clip(prior_g, lo_phys, hi_phys)

    # Rate-limit floor
    frac = cfg.max_change_fraction
    if cfg.change_floor is None:
        floor = frac * 0.1 * np.broadcast_to(row_scale, g_fixed.shape)
        if cfg.estimator == "prior":
            # A gain's natural scale is the larger of its fixed and its model-based value: a
            # push may move it by max_change_fraction of that scale, or of its applied value.
            natural = np.maximum(np.abs(prior_g), np.abs(g_fixed)) * adapt_mask
            floor = np.maximum(floor, frac * natural)
    else:
        if cfg.change_floor.shape != (m, nl):
            raise ValueError(f"change_floor must have shape {(m, nl)}")
        floor = cfg.change_floor.stacked()
        if not (np.isfinite(floor).all() and (floor >= 0).all()):
            raise ValueError("change_floor must be finite and >= 0")
    return GainLimits(ki_min, box, lo_phys, hi_phys, prior_g, np.array(floor, dtype=np.float64), row_scale)
