"""The seeds digest's three-tank linearisation, written out independently of plant_sim.

Tests use it as an oracle (section 1.1): with k = Ap sqrt(2 g) / (2 At),
a13 = mu13 k / sqrt(h1 - h3), a32 = mu32 k / sqrt(h3 - h2), a20 = mu20 k / sqrt(h2),
A = [[-a13, 0, a13], [0, -(a32 + a20), a32], [a13, a32, -(a13 + a32)]], B = diag(1/At) on T1, T2.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

G = 9.81


def three_tank_continuous(
    at: float, ap: float, mu13: float, mu32: float, mu20: float, h: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (A, B) of the digest's formulas at levels h (h1 > h3 > h2)."""
    k = ap * math.sqrt(2 * G) / (2 * at)
    a13 = mu13 * k / math.sqrt(h[0] - h[2])
    a32 = mu32 * k / math.sqrt(h[2] - h[1])
    a20 = mu20 * k / math.sqrt(h[1])
    A = np.array([[-a13, 0, a13], [0, -(a32 + a20), a32], [a13, a32, -(a13 + a32)]])
    B = np.array([[1 / at, 0], [0, 1 / at], [0, 0]])
    return A, B


def zoh(A: np.ndarray, B: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order hold through the matrix exponential of [[A, B], [0, 0]] Ts."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A * ts
    M[:n, n:] = B * ts
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n:]
