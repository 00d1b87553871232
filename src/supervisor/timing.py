r"""The supervisor's timing on the PLC's scan grid: what was applied when, and what is committed.

The PLC scans every Ts; scan j reads the levels y(t_j) and applies MV(j) over [t_j, t_j + Ts].
The supervisor samples every T = N Ts (``supervisor.sample_time_s``, N >= 1 scans). It reads a
snapshot after PLC scan k (y(t_k) and MV(k), from the same scan) and what it writes is applied
from scan k + 1 on (architecture, "Supervisor timing"). Drawn for N = 2::

    PLC scan        k-2        k-1         k          k+1        k+2        k+3
    t               |----------|-----------|----------|----------|----------|--->
    applied         MV(k-2)    MV(k-1)     MV(k)      u_k        u_k        u_{k+1}
    supervisor      sample k-1 ^                      ^ sample k: reads y(t_k), MV(k)
                                                        and writes u_k, applied from scan k+1
                    filter:  prior at t_k from x(t_{k-N}|t_{k-N}) and MV(k-N) .. MV(k-1)
                    plan:    from x(t_k + Ts | t_k), the state MV(k) (committed) leads to;
                             u(-1) = MV(k); the plan's samples are t_k + Ts + i T

**Filter.** Between two samples the estimate is propagated scan by scan with the MV the PLC
applied in each scan, read back with its scan counter (never the MV being applied now taken for
the last one): with the linear model discretised at the PLC scan (A_s, B_s) around the operating
point (x_op, u_op) and the integrating input disturbance eta (Bd = B, so eta is a flow [m^3/s])::

    x(t_{j+1}) = x_op + A_s (x(t_j) - x_op) + B_s (MV(j) - u_op + eta)        (one scan)

N such scans compose exactly to the MPC's model at T (A_T = A_s^N, B_T = sum_i A_s^i B_s), so the
prior at a sample is the T-grid prediction with the inputs really applied, whatever they were
(a PID moving every scan in ADVISORY, the MPC's committed move in MPC). The MPC's steady-state
Kalman gain (designed on the T grid) then folds y(t_k) in. A snapshot missed in a realtime run (a
gap in the scan counter) is bridged with the last MV seen held, and counted.

**Delay.** In MPC mode the move computed at sample k reaches the pumps one PLC scan later, and the
move for [t_k, t_k + Ts] is already committed (MV(k)): the plan starts from the look-ahead state
x(t_k + Ts | t_k) (one scan with MV(k)) with u(-1) = MV(k). In ADVISORY and ADAPTIVE_PID the
MPC is a shadow of the PLC's PID, whose MV(k) acts at once: it plans from x(t_k|t_k) with
u(-1) = MV(k-1), the input applied over the scan before, which is what the adapter compares.

The module is pure: no clock, no I/O.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


class ScanPredictor:
    """The state estimate carried from scan to scan with the inputs the PLC applied.

    Parameters
    ----------
    A_scan : array_like, shape (n, n)
        Deviation model over one PLC scan (ZOH at Ts).
    B_scan : array_like, shape (n, m)
        Input matrix over one scan [m per (m^3/s)].
    x_op : array_like, shape (n,)
        Operating-point levels [m].
    u_op : array_like, shape (m,)
        Operating-point pump flows [m^3/s].

    Notes
    -----
    The estimate is kept in absolute levels, so a new operating point (:meth:`set_model`) leaves
    it where it is. Before :meth:`start` nothing is known.
    """

    def __init__(self, A_scan: ArrayLike, B_scan: ArrayLike, x_op: ArrayLike, u_op: ArrayLike) -> None:
        self.set_model(A_scan, B_scan, x_op, u_op)
        self.scan: int | None = None
        self.x_m: FloatArray = self._x_op.copy()
        self.eta_m3_s: FloatArray = np.zeros(self._B.shape[1])
        self.u_m3_s: FloatArray = self._u_op.copy()
        self.bridged_scans = 0
        """Scans whose snapshot was never seen, propagated with the last MV held."""

    def set_model(self, A_scan: ArrayLike, B_scan: ArrayLike, x_op: ArrayLike, u_op: ArrayLike) -> None:
        """Replace the one-scan model and its operating point (re-linearisation)."""
        A = np.array(A_scan, dtype=float)
        B = np.array(B_scan, dtype=float)
        n, m = B.shape
        if A.shape != (n, n):
            raise ValueError(f"A_scan must have shape ({n}, {n}), got {A.shape}")
        x0 = np.array(x_op, dtype=float).reshape(-1)
        u0 = np.array(u_op, dtype=float).reshape(-1)
        if x0.shape != (n,) or u0.shape != (m,):
            raise ValueError(f"x_op must have shape ({n},) and u_op ({m},)")
        if not (
            np.isfinite(A).all() and np.isfinite(B).all() and np.isfinite(x0).all() and np.isfinite(u0).all()
        ):
            raise ValueError("the scan model must be finite")
        self._A, self._B, self._x_op, self._u_op = A, B, x0, u0

    @property
    def started(self) -> bool:
        """Whether a first snapshot has been seen."""
        return self.scan is not None

    def start(self, scan: int, u_m3_s: ArrayLike) -> None:
        """Begin at ``scan`` with the operating point as prior and ``u_m3_s`` as the input applied so far."""
        self.scan = int(scan)
        self.x_m = self._x_op.copy()
        self.eta_m3_s = np.zeros(self._B.shape[1])
        self.u_m3_s = np.array(u_m3_s, dtype=float)

    def _one_scan(self, x: FloatArray, u: FloatArray) -> FloatArray:
        return self._x_op + self._A @ (x - self._x_op) + self._B @ (u - self._u_op + self.eta_m3_s)

    def advance_to(self, scan: int) -> int:
        """Propagate the estimate to the time of ``scan`` with the inputs applied since.

        The last scan seen applied :attr:`u_m3_s` (see :meth:`applied`); a scan whose snapshot was
        missed is taken to have held it. Returns the number of scans propagated (0 if ``scan`` is
        the current one; a scan counter that went back, a restarted PLC, starts over from the
        current estimate without propagating).
        """
        if self.scan is None:
            raise ValueError("advance_to needs a first snapshot: call start() first")
        steps = int(scan) - self.scan
        if steps < 0:
            self.scan = int(scan)
            return 0
        x = self.x_m
        for _ in range(steps):
            x = self._one_scan(x, self.u_m3_s)
        self.bridged_scans += max(0, steps - 1)
        self.x_m = x
        self.scan = int(scan)
        return steps

    def corrected(self, x_m: ArrayLike, eta_m3_s: ArrayLike) -> None:
        """Replace the estimate at the current scan by the filter's corrected one."""
        self.x_m = np.array(x_m, dtype=float)
        self.eta_m3_s = np.array(eta_m3_s, dtype=float)

    def applied(self, u_m3_s: ArrayLike) -> None:
        """The input the PLC applies from the current scan on (its MV, as pump flows)."""
        self.u_m3_s = np.array(u_m3_s, dtype=float)

    def look_ahead(self, scans: int = 1) -> FloatArray:
        """The state ``scans`` scans ahead with the current input held (the committed move)."""
        x = self.x_m
        for _ in range(scans):
            x = self._one_scan(x, self.u_m3_s)
        return x
