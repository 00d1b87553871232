"""The path a gain proposal takes from the applied gains toward the estimate (pure function).

Per pump, gains ``a`` (applied) and ``target`` of shape (3, n_loops) ``[Kp, Ki, Kd]`` move by one
step fraction ``alpha <= 1``, the largest that keeps every gain within its rate limit
``|g - a| <= limit`` (same units as the gains). Clipping each gain on its own would bend the
path, and a bent path between two admissible sets can cross unstable ones (docs/adaptation.md).
"""

from __future__ import annotations

import numpy as np

from supervisor.adaptation._validate import FloatArray
from supervisor.adaptation.config import GainPath

__all__ = ["gain_path_step"]


def gain_path_step(a: FloatArray, target: FloatArray, limit: FloatArray, path: GainPath) -> FloatArray:
    """One pump's step from ``a`` toward ``target`` (shape (3, n_loops)) under ``limit``.

    ``linear``: ``g = a + alpha (target - a)``. ``geometric``: gains whose applied value and
    target are non-zero and of one sign move as ``g = a (target / a)^alpha`` (a straight line
    in log space: every such gain covers the same fraction of its log-distance), the others
    linearly; ``alpha <= 1`` is the largest step that keeps every gain inside its limit
    ``|g - a| <= limit``: ``alpha |ln(target / a)| <= ln(1 + limit / |a|)`` upward,
    ``<= -ln(1 - limit / |a|)`` downward, ``alpha |target - a| <= limit`` on the linear part.
    """
    delta = target - a
    moving = delta != 0.0
    if not moving.any():
        return a.copy()
    geometric = np.zeros(a.shape, dtype=bool)
    if path == "geometric":
        geometric = moving & (a * target > 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_d = np.where(geometric, np.log(np.where(geometric, target / a, 1.0)), 0.0)
        rel = np.where(geometric, limit / np.abs(a), 0.0)
        up = np.log1p(rel)
        down = -np.log1p(-np.minimum(rel, 1.0 - 1e-12))
        room = np.where(log_d > 0.0, up, down)
        alphas = np.where(geometric, room / np.abs(log_d), limit / np.abs(delta))
    alpha = min(1.0, float(alphas[moving].min()))
    if alpha >= 1.0:
        return target.copy()
    with np.errstate(over="ignore", invalid="ignore"):
        g_geo = a * np.exp(alpha * log_d)
    return np.where(geometric, g_geo, a + alpha * delta)
