"""MIMO discrete PID in velocity form, two degrees of freedom, one loop per actuator (digest 2.1).

The positional law this block increments is the ISA (standard) form with setpoint weights b on
the proportional and c on the derivative term and a first-order filter on the derivative, for
loop j with working setpoint w_j and measured PV y_j (s_j = +1 reverse acting, -1 direct)::

    u_j(t) = Kp e_P(t) + Ki int e(t) dt + Kd D(t)
    e(t)   = s_j (w - y)          e_P(t) = s_j (b_j w - y)          e_D(t) = s_j (c_j w - y)
    Tf dD/dt + D = d e_D / dt                       (Tf: the filter's time constant [s])

The integral acts on the true error e, so the steady state has y = w whatever b and c are; b and
c only shape the response to setpoint changes: b = 0 puts no proportional kick on a setpoint step,
c = 0 (derivative on the measurement) no derivative kick. b = c = 1 is the one-degree-of-freedom
PID on the error (the digest's form). In the ISA notation Tf = Td / N with Td = Kd / Kp: the block
takes Tf, which does not move when a supervisor changes Kp or Kd (and stays defined for the
digest's negative Kd).

Per scan k (scan period Ts [s]) the block runs the incremental form of that law. Backward Euler on
the filter, D(k) = d_j(k), and the memory (w_j(k-1), y_j(k-1)) of the last good scan give::

    e_j(k)    = s_j (w_j(k) - y_j(k))
    De_P,j(k) = s_j (b_j w_j(k) - y_j(k)) - s_j (b_j w_j(k-1) - y_j(k-1))
    De_D,j(k) = s_j (c_j w_j(k) - y_j(k)) - s_j (c_j w_j(k-1) - y_j(k-1))
    d_j(k)    = alpha d_j(k-1) + (1 - alpha) De_D,j(k) / Ts        (filtered d e_D / dt)
    alpha     = Tf / (Tf + Ts)      (backward-Euler discretisation of 1 / (Tf s + 1); Tf = 0: alpha = 0)

and for actuator i::

    dP_i = sum_j Kp_ij De_P,j(k)
    dI_i = sum_j Ki_ij Ts e_j(k)
    dD_i = sum_j Kd_ij (d_j(k) - d_j(k-1))
    u_i(k) = sat_[u_min, u_max]( ratelimit_du_max( u_i(k-1) + dP_i + dI_i + dD_i ) )

Summed over scans at constant gains the increments give back the positional law (dP sums to
Kp e_P(k) - Kp e_P(-1), dD to Kd d(k) - Kd d(-1)), so the velocity form is that law up to its
initial condition.

Bumpless by construction: the memory is the pair (w(k-1), y(k-1)), not an error, and both weighted
errors of the previous scan are recomputed with the weights in force now, so changing b or c
between scans adds no step (a positional form would jump by Kp (b_new - b_old) w); new gains only
multiply increments, so a gain change at a scan boundary moves u by the new gains' increment and
never by a gain times an accumulated state (a positional form jumps by (Kp_new - Kp_old) e); mode
switches start from the applied MV (below).

With b = c = 1 and Tf = 0 the law is exactly the digest's u(k) = u(k-1) + Kp De + Ki Ts e
+ (Kd / Ts) D2e, bit for bit (1.0 w is w, and the recomputed e(k-1) is the same float as the
stored one was); the block's defaults are b = c = 1, and the site config's defaults (b = 1,
c = 0: the derivative on the measurement) are passed by the PLC program.

u_i(k-1) is always the value actually applied (after clamping and rate limiting, in every mode),
so clamping is anti-windup by itself.

Units: e and PV in the PV's unit (m), u in the actuator's unit (m^3/s or rpm), Kp in u per PV
unit, Ki in u per (PV unit s), Kd in u s per PV unit, Ts and Tf in s, b and c dimensionless, the
setpoint ramp rate in PV units per s, the output rate limit du_max in u per scan.

Loops are indexed 0..n-1; loop j drives actuator j (so gain matrices are n x n, diagonal for
decentralised PID, off-diagonal entries couple loop j's error into actuator i).

Modes (``tanklab.enums.LoopMode``), per loop: MANUAL applies the held manual value, AUTO the law
above, REMOTE the held remote value (written by the supervisor). The error memory is updated in
every mode; entering MANUAL or REMOTE without a value initialises the held value to the applied
MV; entering AUTO continues from the applied MV with the normal increment. Rate limit and clamping
apply in every mode.

PV quality: a loop whose PV is flagged bad (or is not finite) contributes no increment and its
error memory is frozen; after ``pv_bad_scans`` consecutive bad scans a loop in AUTO or REMOTE
applies its substitute (``hold``: keep the applied MV; ``value``: go to ``substitute_mv`` at the
rate limit). On the first good scan after a bad spell the loop's memory is re-initialised to the
current scan (w(k-1) = w(k), y(k-1) = y(k), so e(k-1) = e(k); filtered derivative 0), so it
resumes from the applied MV with an integral-only move.

Structure (decision 0029): the law above is `PidLaw`, a `plc_emulator.loop.Block` written once,
as plain loops over Python floats (for one loop, the scalar law itself; n x n products summed in
loop order). The working setpoint, modes, PV-bad substitute, rate limit and clamp are the
`plc_emulator.loop.LoopShell`'s, as for every block of the PLC; `Pid` is the shell around this
law with the PID's own verbs (gains, setpoint weights, warm restart) and array / float entry
points (`Pid.step`, `Pid.step_siso`: the same scan, different containers).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plc_emulator.loop import LoopShell, ShellConfig, Substitute, check_loop, finite_scalar
from plc_emulator.pid_config import InitMemory, PidConfig, Resolved, float_array
from tanklab.enums import LoopMode
from tanklab.gains import LoopLimits, PidGains

__all__ = [
    "InitMemory",
    "Pid",
    "PidConfig",
    "PidGains",
    "PidLaw",
    "PidLoopStep",
    "PidStepResult",
    "Substitute",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def _real_scalar(name: str, value: float) -> float:
    """A real number as a float (NaN and infinities allowed)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    return float(value)


def _gain_matrix(name: str, value: ArrayLike, n: int) -> FloatArray:
    """An (n, n) finite gain matrix (a 1-D input of length n is the diagonal), read-only."""
    arr = float_array(name, value)
    if arr.ndim == 1:
        arr = np.diag(arr)
    if arr.shape != (n, n):
        raise ValueError(f"{name} must have shape ({n}, {n}) or ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class PidStepResult:
    """Outcome and diagnostics of one scan. Arrays have shape (n,).

    Attributes
    ----------
    mv : ndarray
        Applied output u(k) per actuator [u].
    working_sp : ndarray
        Working setpoint w(k) per loop after limits and ramp [PV unit].
    error : ndarray
        e(k) per loop [PV unit] (sign-adjusted for direct action); NaN where the PV was bad.
    p, i, d : ndarray
        The P, I and D increments per actuator [u], computed in every mode (applied only in AUTO).
    clamped : ndarray of bool
        The output limits changed the value this scan.
    rate_limited : ndarray of bool
        The rate limit changed the value this scan.
    pv_good : ndarray of bool
        Whether each loop's PV was used this scan.
    substituted : ndarray of bool
        The loop's actuator applied the substitute output this scan.
    modes : tuple of LoopMode
        Mode of each loop during this scan.
    """

    mv: FloatArray
    working_sp: FloatArray
    error: FloatArray
    p: FloatArray
    i: FloatArray
    d: FloatArray
    clamped: BoolArray
    rate_limited: BoolArray
    pv_good: BoolArray
    substituted: BoolArray
    modes: tuple[LoopMode, ...]


class PidLoopStep(NamedTuple):
    """Outcome and diagnostics of one scan of a one-loop block (`Pid.step_siso`), as floats.

    The fields mean what the same-named arrays of `PidStepResult` mean, for the one loop.

    Attributes
    ----------
    mv : float
        Applied output u(k) [u].
    working_sp : float
        Working setpoint w(k) after limits and ramp [PV unit].
    error : float
        e(k) [PV unit] (sign-adjusted for direct action); NaN when the PV was bad.
    p, i, d : float
        The P, I and D increments [u], computed in every mode (applied only in AUTO).
    clamped : bool
        The output limits changed the value this scan.
    rate_limited : bool
        The rate limit changed the value this scan.
    pv_good : bool
        Whether the PV was used this scan.
    substituted : bool
        The substitute output was applied this scan.
    mode : LoopMode
        Mode of the loop during this scan.
    """

    mv: float
    working_sp: float
    error: float
    p: float
    i: float
    d: float
    clamped: bool
    rate_limited: bool
    pv_good: bool
    substituted: bool
    mode: LoopMode


_new_tuple = tuple.__new__


class PidLaw:
    """The velocity-form law of the module docstring for n loops, a `plc_emulator.loop.Block`.

    Memory: the last good scan's (w, y), the filtered derivative d(k-1), and whether the memory
    re-initialises on the next good scan; the applied u(k-1) comes from the shell each scan (so
    ``track`` needs nothing here). The P, I and D increments and e of the last step are kept in
    ``p``, ``i``, ``d`` and ``e`` (lists, per actuator resp. per loop) for diagnostics.
    """

    def __init__(self, r: Resolved, gains: PidGains) -> None:
        n = r.n
        self._n = n
        self._ts = r.ts
        self._alpha = r.alpha
        self._sign: list[float] = r.sign.tolist()
        self._b: list[float] = r.b.tolist()
        self._c: list[float] = r.c.tolist()
        self._w_mem: list[float] = [0.0] * n  # w(k-1), y(k-1) of the last good scan (zeros:
        self._y_mem: list[float] = [0.0] * n  # e(-1) = e(-2) = 0)
        self._d_prev: list[float] = [0.0] * n  # filtered derivative d(k-1)
        self._needs_init: list[bool] = [r.first_error] * n  # memory := this scan on the next good one
        self.e: list[float] = [math.nan] * n
        self._de_p, self._e_used, self._dd = [0.0] * n, [0.0] * n, [0.0] * n  # step's buffers
        self._raw: list[float] = [0.0] * n
        self.p: list[float] = [0.0] * n
        self.i: list[float] = [0.0] * n
        self.d: list[float] = [0.0] * n
        self.gains = gains
        self._kp: list[list[float]] = gains.kp.tolist()
        self._ki: list[list[float]] = gains.ki.tolist()
        self._kd: list[list[float]] = gains.kd.tolist()

    @property
    def n_loops(self) -> int:
        """Number of loops (= actuators)."""
        return self._n

    def use_gains(self, gains: PidGains) -> None:
        """Gains for the next step on (validated by the caller: n x n, finite)."""
        self.gains = gains
        self._kp, self._ki, self._kd = gains.kp.tolist(), gains.ki.tolist(), gains.kd.tolist()

    def set_weights(self, loop: int, b: float, c: float) -> None:
        """Setpoint weights of one loop (validated by the caller); bumpless by construction."""
        self._b[loop], self._c[loop] = b, c

    @property
    def weights(self) -> tuple[list[float], list[float]]:
        """(b, c) per loop (copies)."""
        return list(self._b), list(self._c)

    @property
    def memory(self) -> tuple[list[float], list[float]]:
        """(w(k-1), y(k-1)) of the last good scan per loop (copies)."""
        return list(self._w_mem), list(self._y_mem)

    def set_mode(self, loop: int, mode: LoopMode) -> None:
        """Nothing to do: the memory follows the process in every mode."""

    def track(self, loop: int, mv: float) -> None:
        """Nothing to do: the next increment starts from the u(k-1) the shell passes."""

    def resume(self, loop: int, mv: float, w: float, pv: float) -> None:
        """Memory of the last good scan := (w, pv), no derivative history; a non-finite ``pv``
        leaves the memory to re-initialise on the next good scan."""
        if math.isfinite(pv):
            self._w_mem[loop] = w
            self._y_mem[loop] = pv
            self._d_prev[loop] = 0.0
            self._needs_init[loop] = False

    def step(
        self, w: Sequence[float], pv: Sequence[float], good: Sequence[bool], u_prev: Sequence[float]
    ) -> list[float]:
        """One scan: u_i(k-1) + dP_i + dI_i + dD_i per actuator (before the shell's limits)."""
        n, ts, alpha = self._n, self._ts, self._alpha
        de_p, e_used, dd = self._de_p, self._e_used, self._dd  # per-loop buffers, reused
        w_mem, y_mem, d_mem, needs_init, e_out = (
            self._w_mem,
            self._y_mem,
            self._d_prev,
            self._needs_init,
            self.e,
        )
        for j in range(n):
            d_prev = d_mem[j]
            if good[j]:
                wj, y, sign = w[j], pv[j], self._sign[j]
                if needs_init[j]:
                    w_old, y_old = wj, y
                    d_prev = 0.0
                else:
                    w_old, y_old = w_mem[j], y_mem[j]
                b, c = self._b[j], self._c[j]
                e = sign * (wj - y)
                de_p[j] = sign * (b * wj - y) - sign * (b * w_old - y_old)
                de_d = sign * (c * wj - y) - sign * (c * w_old - y_old)
                d_new = alpha * d_prev + (1.0 - alpha) * de_d / ts
                e_used[j] = e
                w_mem[j], y_mem[j] = wj, y
                needs_init[j] = False
            else:
                e = math.nan
                de_p[j] = e_used[j] = 0.0
                d_new = d_prev
                needs_init[j] = True
            e_out[j] = e
            dd[j] = d_new - d_prev
            d_mem[j] = d_new
        raw = self._raw  # the shell reads it before the next step
        kp, ki, kd = self._kp, self._ki, self._kd
        p_out, i_out, d_out = self.p, self.i, self.d
        for i in range(n):
            kp_i, ki_i, kd_i = kp[i], ki[i], kd[i]
            p = kp_i[0] * de_p[0]  # sums in loop order, starting from the first product
            ii = ki_i[0] * (ts * e_used[0])
            d = kd_i[0] * dd[0]
            for j in range(1, n):
                p += kp_i[j] * de_p[j]
                ii += ki_i[j] * (ts * e_used[j])
                d += kd_i[j] * dd[j]
            p_out[i], i_out[i], d_out[i] = p, ii, d
            raw[i] = u_prev[i] + p + ii + d
        return raw


class Pid(LoopShell):
    """MIMO velocity-form PID with modes, limits, setpoint ramp and PV-bad substitution.

    The `PidLaw` inside a `plc_emulator.loop.LoopShell`.

    Parameters
    ----------
    config : PidConfig
        Static configuration (validated on construction).
    gains : PidGains
        Initial gains, n x n (n = ``config.n_loops``), finite.

    Notes
    -----
    Verbs: `step` once per scan (or `step_siso` on a one-loop block); `set_mode`,
    `set_manual_mv`, `set_remote_mv`, `set_gains`, `set_setpoint_weights`, `track` and `resume`
    between scans (they take effect at the next step, bumplessly).
    """

    def __init__(self, config: PidConfig, gains: PidGains) -> None:
        if not isinstance(config, PidConfig):
            raise TypeError(f"config must be a PidConfig, got {type(config).__name__}")
        if not isinstance(gains, PidGains):
            raise TypeError(f"gains must be a PidGains, got {type(gains).__name__}")
        r = config._resolved
        if gains.shape != (r.n, r.n):
            raise ValueError(f"gains must be {r.n} x {r.n} to match n_loops, got {gains.kp.shape}")
        self._config = config
        self.law = PidLaw(r, self._checked(gains.kp, gains.ki, gains.kd))
        super().__init__(
            self.law,
            ShellConfig(
                limits=tuple(
                    LoopLimits(lo, hi, du)
                    for lo, hi, du in zip(r.lo.tolist(), r.hi.tolist(), r.du_max.tolist(), strict=True)
                ),
                sp_min=tuple(r.sp_lo.tolist()),
                sp_max=tuple(r.sp_hi.tolist()),
                sp_step=tuple(r.sp_step.tolist()),
                pv_bad_scans=r.pv_bad_scans,
                substitute=tuple("value" if v else "hold" for v in r.subst_value.tolist()),
                substitute_mv=tuple(r.substitute_mv.tolist()),
                initial_mv=tuple(r.initial_mv.tolist()),
                initial_mode=r.modes,
            ),
        )

    def _checked(self, kp: ArrayLike, ki: ArrayLike, kd: ArrayLike) -> PidGains:
        n = self._config._resolved.n
        return PidGains(_gain_matrix("Kp", kp, n), _gain_matrix("Ki", ki, n), _gain_matrix("Kd", kd, n))

    # ------------------------------------------------------------------ state
    @property
    def config(self) -> PidConfig:
        """The block's configuration."""
        return self._config

    @property
    def gains(self) -> PidGains:
        """Gains that the next `step` applies."""
        return self.law.gains

    @property
    def setpoint_weights(self) -> tuple[FloatArray, FloatArray]:
        """(b, c) per loop: the setpoint weights of the P and D terms (copies)."""
        b, c = self.law.weights
        return np.array(b, dtype=np.float64), np.array(c, dtype=np.float64)

    # ------------------------------------------------------------------ verbs
    def set_gains(self, Kp: ArrayLike, Ki: ArrayLike, Kd: ArrayLike) -> None:
        """Replace the gains from the next `step` on (all three validated before any is applied).

        Parameters
        ----------
        Kp, Ki, Kd : array_like, shape (n, n) or (n,)
            Finite gain matrices (a 1-D input is the diagonal).

        Raises
        ------
        ValueError
            Wrong shape or a non-finite entry; the old gains stay.
        """
        self.law.use_gains(self._checked(Kp, Ki, Kd))

    def set_setpoint_weights(self, loop: int, b: float | None = None, c: float | None = None) -> None:
        """Change one loop's setpoint weights from the next `step` on, bumplessly.

        The error memory is (w(k-1), y(k-1)), and the next step recomputes the previous weighted
        errors with the new weights, so the change itself adds no increment.

        Parameters
        ----------
        loop : int
            Loop index in [0, n).
        b, c : float, optional
            New weight of the P term, of the D term, each in [0, 1]; None keeps the current one.

        Raises
        ------
        ValueError
            A weight outside [0, 1] or not finite; nothing changes.
        """
        j = check_loop(loop, self.n)
        b_now, c_now = self.law.weights
        new_b = b_now[j] if b is None else finite_scalar("b", b)
        new_c = c_now[j] if c is None else finite_scalar("c", c)
        if not (0.0 <= new_b <= 1.0 and 0.0 <= new_c <= 1.0):
            raise ValueError(f"setpoint weights must lie in [0, 1], got b = {new_b}, c = {new_c}")
        self.law.set_weights(j, new_b, new_c)

    def resume(self, loop: int, mv: float, sp: float, pv: float) -> None:
        """Continue a loop from a running process (a warm restart), bumplessly.

        The applied-MV memory u(k-1) becomes ``mv`` (clamped: the actuator's command now) and
        the memory of the last good scan becomes (w(k-1), y(k-1)) = (``sp`` clamped to
        [sp_min, sp_max], ``pv``), with no derivative history, as if the scan before had run
        on that reading. The next step is then an ordinary velocity-form increment from ``mv``:
        with the same SP and PV, ``Ki * Ts * e`` alone (no proportional or derivative kick).
        A non-finite ``pv`` only sets u(k-1) (the memory re-initialises on the next good scan).
        """
        super().resume(loop, mv, sp, pv)

    def step(self, sp: ArrayLike, pv: ArrayLike, pv_good: ArrayLike | None = None) -> PidStepResult:
        """Run one scan.

        Parameters
        ----------
        sp : array_like, shape (n,)
            Target setpoints [PV unit], finite (clamped to [sp_min, sp_max], then ramped).
        pv : array_like, shape (n,)
            Measured PVs [PV unit]; a non-finite PV counts as bad.
        pv_good : array_like of bool, shape (n,), optional
            PV quality from the scan engine (Bad status, frozen value, out of range: False).
            Default: all good.

        Returns
        -------
        PidStepResult
            Applied MV and diagnostics.
        """
        n = self.n
        sp_arr = float_array("sp", sp)
        if sp_arr.shape != (n,):
            raise ValueError(f"sp must have shape ({n},), got {sp_arr.shape}")
        if not np.all(np.isfinite(sp_arr)):
            raise ValueError("sp must be finite")
        pv_arr = float_array("pv", pv)
        if pv_arr.shape != (n,):
            raise ValueError(f"pv must have shape ({n},), got {pv_arr.shape}")
        if pv_good is None:
            good_in = [True] * n
        else:
            good_arr = np.asarray(pv_good)
            if good_arr.dtype.kind != "b":
                raise TypeError("pv_good must be booleans")
            if good_arr.shape != (n,):
                raise ValueError(f"pv_good must have shape ({n},), got {good_arr.shape}")
            good_in = good_arr.tolist()
        modes = tuple(self._modes)
        mv = self.scan(sp_arr.tolist(), pv_arr.tolist(), good_in)
        law = self.law
        return PidStepResult(
            mv=np.array(mv, dtype=np.float64),
            working_sp=np.array(self._w, dtype=np.float64),
            error=np.array(law.e, dtype=np.float64),
            p=np.array(law.p, dtype=np.float64),
            i=np.array(law.i, dtype=np.float64),
            d=np.array(law.d, dtype=np.float64),
            clamped=np.array(self.clamped, dtype=bool),
            rate_limited=np.array(self.rate_limited, dtype=bool),
            pv_good=np.array(self.good, dtype=bool),
            substituted=np.array(self.substituted, dtype=bool),
            modes=modes,
        )

    def step_siso(self, sp: float, pv: float, pv_good: bool | np.bool_ = True) -> PidLoopStep:
        """Run one scan of a one-loop block on floats: the same scan as `step`, without arrays.

        Parameters
        ----------
        sp : float
            Target setpoint [PV unit], finite (clamped to [sp_min, sp_max], then ramped).
        pv : float
            Measured PV [PV unit]; a non-finite PV counts as bad.
        pv_good : bool or numpy.bool_
            PV quality from the scan engine (default good).

        Returns
        -------
        PidLoopStep
            Applied MV and diagnostics.

        Raises
        ------
        ValueError
            The block has more than one loop, or ``sp`` is not finite.
        TypeError
            An argument of the wrong type.
        """
        if self.n != 1:
            raise ValueError(f"step_siso needs a one-loop block, this one has {self.n} loops")
        if type(sp) is not float:
            sp = finite_scalar("sp", sp)
        elif not math.isfinite(sp):
            raise ValueError("sp must be finite")
        if type(pv) is not float:
            pv = _real_scalar("pv", pv)
        if type(pv_good) is not bool:
            if not isinstance(pv_good, np.bool_):
                raise TypeError(f"pv_good must be a bool, got {type(pv_good).__name__}")
            pv_good = bool(pv_good)
        mode = self._modes[0]
        u = self.scan((sp,), (pv,), (pv_good,))[0]
        law = self.law
        return _new_tuple(
            PidLoopStep,
            (
                u,
                self._w[0],
                law.e[0],
                law.p[0],
                law.i[0],
                law.d[0],
                self.clamped[0],
                self.rate_limited[0],
                self.good[0],
                self.substituted[0],
                mode,
            ),
        )
