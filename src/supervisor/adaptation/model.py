"""The linear loop model the adaptation's guards and model-based tuning use.

A discrete (ZOH) model around an equilibrium ``(x_op, u_op)``: levels ``x`` [m], pump inputs
``u`` [pump unit], loop outputs ``y = C x`` [m], sample time ``Ts`` [s] (the PLC scan)::

    x(k+1) - x_op = A (x(k) - x_op) + B (u(k) - u_op),   u_min <= u <= u_max
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from supervisor.adaptation._validate import FloatArray, finite, matrix, positive, state_space

__all__ = ["LoopModel"]


@dataclass(frozen=True, eq=False)
class LoopModel:
    """Discrete (ZOH) linear model of the plant around an equilibrium, with the loops' outputs.

    ``x(k+1) - x_op = A (x(k) - x_op) + B (u(k) - u_op)``, loop outputs ``y = C x``.

    Attributes
    ----------
    A : ndarray, shape (n_x, n_x)
        State matrix (levels [m]).
    B : ndarray, shape (n_x, n_u)
        Input matrix [m per pump unit].
    C : ndarray, shape (n_loops, n_x)
        Loop output matrix: row j selects the PV of loop j.
    ts_s : float
        Sample time [s], the PLC scan the PID runs at.
    u_min, u_max : ndarray, shape (n_u,)
        Actuator bounds [pump unit], finite, ``u_min < u_max``.
    x_op : ndarray, shape (n_x,)
        Equilibrium state; zeros by default (an empty array means the default).
    u_op : ndarray, shape (n_u,)
        Equilibrium input; zeros by default (an empty array means the default).
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    ts_s: float
    u_min: FloatArray
    u_max: FloatArray
    x_op: FloatArray = field(default_factory=lambda: np.zeros(0))
    u_op: FloatArray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        A, B, C = state_space(self.A, self.B, self.C)
        n, m = A.shape[0], B.shape[1]
        ts = positive(self.ts_s, "ts_s")
        u_min = finite(matrix(self.u_min, "u_min", (m,)), "u_min")
        u_max = finite(matrix(self.u_max, "u_max", (m,)), "u_max")
        if not (u_min < u_max).all():
            raise ValueError("u_min must be < u_max for every pump")
        x_op = np.zeros(n) if np.size(self.x_op) == 0 else finite(matrix(self.x_op, "x_op", (n,)), "x_op")
        u_op = np.zeros(m) if np.size(self.u_op) == 0 else finite(matrix(self.u_op, "u_op", (m,)), "u_op")
        for name, arr in (
            ("A", A),
            ("B", B),
            ("C", C),
            ("u_min", u_min),
            ("u_max", u_max),
            ("x_op", x_op),
            ("u_op", u_op),
        ):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "ts_s", ts)

    @property
    def n_x(self) -> int:
        """Number of states."""
        return int(self.A.shape[0])

    @property
    def n_u(self) -> int:
        """Number of pumps."""
        return int(self.B.shape[1])

    @property
    def n_loops(self) -> int:
        """Number of loops (PID errors)."""
        return int(self.C.shape[0])
