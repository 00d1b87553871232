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

Single-loop fast path: a block of one loop (n = 1, every loop of a decentralised PID) runs the
law above on Python floats instead of 1-element numpy arrays. Numpy's per-call overhead (some
37 us per step: a dozen ufuncs and three matmuls on one element) made the PID blocks the
co-simulation's largest cost; the same IEEE operations on floats take about 1.6 us, and 0.8 us with
the clamps written out as comparisons (``lo if lo > x else x`` is what ``max(x, lo)`` does, NaN and
signed zeros included) and the result tuple built without the NamedTuple's Python-level
constructor. Both paths do the same floating-point operations in the same order (the 1 x 1
products are single multiplies), so they agree exactly (a zero's sign aside: the numpy product
adds to +0.0); ``tests/plc_emulator/test_pid.py::test_scalar_fast_path_matches_numpy_path``
runs random configurations, gains, modes, writes, rate limits, ramps, saturation and bad PVs
through both and compares every output, and ``test_float_path_is_bit_for_bit_its_first_form*``
hold the float path to its first form (builtin min / max) bit for bit, signed zeros included.
The state (u(k-1), the (w, y) memory, held values, counters) is kept in Python lists for every n, so
both paths share it; the n-loop path converts it to arrays per step. `Pid.step_siso` is the
scalar entry point the PLC program uses (no arrays at all); `Pid.step` on a one-loop block uses
the same core and wraps its results in arrays.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tanklab.enums import LoopMode

__all__ = ["InitMemory", "Pid", "PidConfig", "PidGains", "PidLoopStep", "PidStepResult", "Substitute"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
Substitute = Literal["hold", "value"]
InitMemory = Literal["zero", "first_error"]

_AUTO, _MANUAL, _REMOTE = LoopMode.AUTO, LoopMode.MANUAL, LoopMode.REMOTE  # bound once: hot path

_SUBSTITUTES = ("hold", "value")
_INIT_MEMORIES = ("zero", "first_error")


def _float_array(name: str, value: ArrayLike) -> FloatArray:
    """Convert to a float64 array; TypeError for non-numeric (or boolean) input."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be numeric, got dtype {arr.dtype}")
    return arr.astype(np.float64)


def _per_loop(name: str, value: float | Sequence[float], n: int) -> FloatArray:
    """Broadcast a scalar or a length-n sequence to a float64 array of shape (n,)."""
    arr = _float_array(name, value)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got shape {arr.shape}")
    return arr.copy()


def _weights(name: str, value: float | Sequence[float], n: int) -> FloatArray:
    """Setpoint weights per loop: finite, in [0, 1]."""
    arr = _per_loop(name, value, n)
    if np.any(~np.isfinite(arr)) or np.any(arr < 0.0) or np.any(arr > 1.0):
        raise ValueError(f"{name} must lie in [0, 1] for every loop")
    return arr


def _check_loop(loop: int, n: int) -> int:
    if isinstance(loop, bool) or not isinstance(loop, int | np.integer):
        raise TypeError(f"loop must be an int, got {type(loop).__name__}")
    if not 0 <= int(loop) < n:
        raise ValueError(f"loop must be in [0, {n - 1}], got {loop}")
    return int(loop)


def _check_mode(mode: LoopMode) -> LoopMode:
    if not isinstance(mode, LoopMode):
        raise TypeError(f"mode must be a tanklab.enums.LoopMode, got {type(mode).__name__}")
    return mode


def _finite_scalar(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    x = float(value)
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


def _real_scalar(name: str, value: float) -> float:
    """A real number as a float (NaN and infinities allowed)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    return float(value)


def _gain_matrix(name: str, value: ArrayLike, n: int | None) -> FloatArray:
    arr = _float_array(name, value)
    if arr.ndim == 1:
        arr = np.diag(arr)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(
            f"{name} must be a square (n, n) matrix or a length-n diagonal, got shape {arr.shape}"
        )
    if n is not None and arr.shape != (n, n):
        raise ValueError(f"{name} must have shape ({n}, {n}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class PidGains:
    """Velocity-form gain matrices, shape (n_actuators, n_loops) = (n, n).

    A 1-D input of length n is taken as the diagonal. Negative entries are allowed (the digest's
    fixed PID has a negative Kd); only shape and finiteness are checked. Stored read-only.

    Attributes
    ----------
    Kp : ndarray, shape (n, n)
        Proportional gains [u per PV unit].
    Ki : ndarray, shape (n, n)
        Integral gains [u per (PV unit s)].
    Kd : ndarray, shape (n, n)
        Derivative gains [u s per PV unit].
    """

    Kp: FloatArray
    Ki: FloatArray
    Kd: FloatArray

    def __post_init__(self) -> None:
        kp = _gain_matrix("Kp", self.Kp, None)
        n = kp.shape[0]
        object.__setattr__(self, "Kp", kp)
        object.__setattr__(self, "Ki", _gain_matrix("Ki", self.Ki, n))
        object.__setattr__(self, "Kd", _gain_matrix("Kd", self.Kd, n))

    @property
    def n_loops(self) -> int:
        """Number of loops (= actuators)."""
        return int(self.Kp.shape[0])

    @classmethod
    def diagonal(cls, kp: Sequence[float], ki: Sequence[float], kd: Sequence[float]) -> PidGains:
        """Decentralised gains: loop j's error drives only actuator j.

        Parameters
        ----------
        kp, ki, kd : sequence of float, length n
            Per-loop gains.
        """
        return cls(
            np.diag(_float_array("kp", kp)), np.diag(_float_array("ki", ki)), np.diag(_float_array("kd", kd))
        )


@dataclass(frozen=True)
class PidConfig:
    """Static configuration of a `Pid` block. Scalars broadcast to every loop.

    Attributes
    ----------
    n_loops : int
        Number of loops n (= actuators), >= 1.
    ts_s : float
        Scan period Ts [s], > 0.
    u_min, u_max : float or sequence of n floats
        Output limits per actuator [u], finite, u_min < u_max.
    du_max : float or sequence, optional
        Output rate limit |u(k) - u(k-1)| <= du_max per scan [u], > 0; None: no rate limit.
    d_filter_tf_s : float
        Derivative filter time constant Tf [s], >= 0 (0: unfiltered D). Tf = Td / N in the ISA
        notation (Td = Kd / Kp).
    setpoint_weight_p : float or sequence of n floats
        Setpoint weight b of the proportional term, in [0, 1] (default 1: P on the error; 0: P on
        the measurement only, no proportional kick on a setpoint step).
    setpoint_weight_d : float or sequence of n floats
        Setpoint weight c of the derivative term, in [0, 1] (default 1: D on the error, the
        digest's form; 0: D on the measurement, no derivative kick on a setpoint step).
    sp_min, sp_max : float or sequence
        Setpoint limits [PV unit], sp_min <= sp_max (infinite allowed). Targets outside are clamped.
    sp_rate : float or sequence, optional
        Setpoint ramp rate [PV unit per s], > 0: the working setpoint moves toward the target by at
        most sp_rate Ts per scan. None: the working setpoint jumps to the target.
    direct_acting : bool or sequence of bool
        True for a loop whose actuator lowers its PV (e = y - w); False (default): e = w - y.
    initial_mv : float or sequence
        u(-1) [u], within the limits (default 0).
    init_memory : {"zero", "first_error"}
        "zero": e(-1) = e(-2) = 0 (the digest's reference behaviour); "first_error": e(-1) =
        e(-2) = e(0), so the first scan makes an integral-only move.
    pv_bad_scans : int
        Consecutive bad-PV scans N (>= 1) after which a loop in AUTO/REMOTE applies its substitute.
    substitute : {"hold", "value"} or sequence
        Substitute output per loop: keep the applied MV, or drive to ``substitute_mv``.
    substitute_mv : float or sequence
        Safe MV for ``substitute == "value"`` [u], within the limits.
    initial_mode : LoopMode or sequence of LoopMode
        Mode of each loop at construction (default AUTO).
    """

    n_loops: int
    ts_s: float
    u_min: float | Sequence[float]
    u_max: float | Sequence[float]
    du_max: float | Sequence[float] | None = None
    d_filter_tf_s: float = 0.0
    setpoint_weight_p: float | Sequence[float] = 1.0
    setpoint_weight_d: float | Sequence[float] = 1.0
    sp_min: float | Sequence[float] = -np.inf
    sp_max: float | Sequence[float] = np.inf
    sp_rate: float | Sequence[float] | None = None
    direct_acting: bool | Sequence[bool] = False
    initial_mv: float | Sequence[float] = 0.0
    init_memory: InitMemory = "zero"
    pv_bad_scans: int = 3
    substitute: Substitute | Sequence[Substitute] = "hold"
    substitute_mv: float | Sequence[float] = 0.0
    initial_mode: LoopMode | Sequence[LoopMode] = LoopMode.AUTO
    _resolved: _Resolved = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_resolved", _resolve(self))


@dataclass(frozen=True, eq=False)
class _Resolved:
    """Per-loop arrays derived from a `PidConfig` (validated)."""

    n: int
    ts: float
    lo: FloatArray
    hi: FloatArray
    du_max: FloatArray  # inf where no rate limit
    alpha: float
    b: FloatArray
    c: FloatArray
    sp_lo: FloatArray
    sp_hi: FloatArray
    sp_step: FloatArray  # sp_rate * Ts, inf where no ramp
    sign: FloatArray
    initial_mv: FloatArray
    first_error: bool
    pv_bad_scans: int
    subst_value: BoolArray
    substitute_mv: FloatArray
    modes: tuple[LoopMode, ...]


def _resolve(c: PidConfig) -> _Resolved:
    if isinstance(c.n_loops, bool) or not isinstance(c.n_loops, int):
        raise TypeError(f"n_loops must be an int, got {type(c.n_loops).__name__}")
    n = c.n_loops
    if n < 1:
        raise ValueError(f"n_loops must be >= 1, got {n}")
    ts = _finite_scalar("ts_s", c.ts_s)
    if ts <= 0.0:
        raise ValueError(f"ts_s must be > 0, got {ts}")

    lo = _per_loop("u_min", c.u_min, n)
    hi = _per_loop("u_max", c.u_max, n)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("u_min and u_max must be finite")
    if np.any(lo >= hi):
        raise ValueError("u_min must be < u_max for every actuator")

    if c.du_max is None:
        du = np.full(n, np.inf)
    else:
        du = _per_loop("du_max", c.du_max, n)
        if np.any(np.isnan(du)) or np.any(du <= 0.0):
            raise ValueError("du_max must be > 0 (per scan) for every actuator")

    tf = _finite_scalar("d_filter_tf_s", c.d_filter_tf_s)
    if tf < 0.0:
        raise ValueError(f"d_filter_tf_s must be >= 0, got {tf}")

    b = _weights("setpoint_weight_p", c.setpoint_weight_p, n)
    cw = _weights("setpoint_weight_d", c.setpoint_weight_d, n)

    sp_lo = _per_loop("sp_min", c.sp_min, n)
    sp_hi = _per_loop("sp_max", c.sp_max, n)
    if np.any(np.isnan(sp_lo)) or np.any(np.isnan(sp_hi)) or np.any(sp_lo > sp_hi):
        raise ValueError("sp_min must be <= sp_max for every loop")

    if c.sp_rate is None:
        sp_step = np.full(n, np.inf)
    else:
        rate = _per_loop("sp_rate", c.sp_rate, n)
        if np.any(np.isnan(rate)) or np.any(rate <= 0.0):
            raise ValueError("sp_rate must be > 0 [PV unit/s] for every loop")
        sp_step = rate * ts

    direct = np.asarray(c.direct_acting)
    if direct.dtype.kind != "b":
        raise TypeError("direct_acting must be a bool or a sequence of bools")
    if direct.ndim == 0:
        direct = np.full(n, bool(direct))
    if direct.shape != (n,):
        raise ValueError(f"direct_acting must be a bool or have shape ({n},), got {direct.shape}")
    sign = np.where(direct, -1.0, 1.0)

    u0 = _per_loop("initial_mv", c.initial_mv, n)
    if np.any(~np.isfinite(u0)) or np.any(u0 < lo) or np.any(u0 > hi):
        raise ValueError("initial_mv must lie within [u_min, u_max] for every actuator")

    if c.init_memory not in _INIT_MEMORIES:
        raise ValueError(f"init_memory must be one of {_INIT_MEMORIES}, got {c.init_memory!r}")

    if isinstance(c.pv_bad_scans, bool) or not isinstance(c.pv_bad_scans, int):
        raise TypeError(f"pv_bad_scans must be an int, got {type(c.pv_bad_scans).__name__}")
    if c.pv_bad_scans < 1:
        raise ValueError(f"pv_bad_scans must be >= 1, got {c.pv_bad_scans}")

    subst_in: object = c.substitute
    subst: list[object]
    if isinstance(subst_in, str):
        subst = [subst_in] * n
    elif isinstance(subst_in, Sequence):
        subst = list(subst_in)
    else:
        raise TypeError(
            f"substitute must be a string or a sequence of strings, got {type(c.substitute).__name__}"
        )
    if len(subst) != n:
        raise ValueError(f"substitute must be a string or have {n} entries, got {len(subst)}")
    for s in subst:
        if s not in _SUBSTITUTES:
            raise ValueError(f"substitute must be one of {_SUBSTITUTES}, got {s!r}")
    smv = _per_loop("substitute_mv", c.substitute_mv, n)
    if np.any(~np.isfinite(smv)) or np.any(smv < lo) or np.any(smv > hi):
        raise ValueError("substitute_mv must lie within [u_min, u_max] for every actuator")

    if isinstance(c.initial_mode, LoopMode):
        modes_in = [c.initial_mode] * n
    elif isinstance(c.initial_mode, Sequence) and not isinstance(c.initial_mode, str):
        modes_in = list(c.initial_mode)
    else:
        raise TypeError(
            f"initial_mode must be a LoopMode or a sequence of them, got {type(c.initial_mode).__name__}"
        )
    if len(modes_in) != n:
        raise ValueError(f"initial_mode must be a LoopMode or have {n} entries, got {len(modes_in)}")
    modes = tuple(_check_mode(m) for m in modes_in)

    return _Resolved(
        n=n,
        ts=ts,
        lo=lo,
        hi=hi,
        du_max=du,
        alpha=tf / (tf + ts),
        b=b,
        c=cw,
        sp_lo=sp_lo,
        sp_hi=sp_hi,
        sp_step=sp_step,
        sign=sign,
        initial_mv=u0,
        first_error=c.init_memory == "first_error",
        pv_bad_scans=c.pv_bad_scans,
        subst_value=np.array([s == "value" for s in subst], dtype=bool),
        substitute_mv=smv,
        modes=modes,
    )


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


class Pid:
    """MIMO velocity-form PID with modes, limits, setpoint ramp and PV-bad substitution.

    Parameters
    ----------
    config : PidConfig
        Static configuration (validated on construction).
    gains : PidGains
        Initial gains; shape must match ``config.n_loops``.

    Notes
    -----
    Verbs: `step` once per scan (or `step_siso` on a one-loop block); `set_mode`,
    `set_manual_mv`, `set_remote_mv`, `set_gains`, `set_setpoint_weights` and `track` between
    scans (they take effect at the next step, bumplessly). A one-loop block computes on floats
    (the module's "single-loop fast path").
    """

    def __init__(self, config: PidConfig, gains: PidGains) -> None:
        if not isinstance(config, PidConfig):
            raise TypeError(f"config must be a PidConfig, got {type(config).__name__}")
        if not isinstance(gains, PidGains):
            raise TypeError(f"gains must be a PidGains, got {type(gains).__name__}")
        r = config._resolved
        if gains.n_loops != r.n:
            raise ValueError(f"gains must be {r.n} x {r.n} to match n_loops, got {gains.Kp.shape}")
        self._config = config
        self._r = r
        n = r.n
        # Per-loop state as Python lists (shared by both paths; see the module docstring).
        self._u: list[float] = r.initial_mv.tolist()  # u(k-1), the applied value
        # The memory of the last good scan, (w(k-1), y(k-1)), from which e(k-1) and both weighted
        # errors are recomputed with the weights in force (zeros: e(-1) = e(-2) = 0).
        self._w_mem: list[float] = [0.0] * n
        self._y_mem: list[float] = [0.0] * n
        self._d_prev: list[float] = [0.0] * n  # filtered derivative d(k-1)
        self._needs_init: list[bool] = [r.first_error] * n  # re-initialise memory to e(k) on next good scan
        self._w: list[float] = [0.0] * n  # working setpoint
        self._started = False
        self._modes = list(r.modes)
        self._manual: list[float] = r.initial_mv.tolist()
        self._remote: list[float] = r.initial_mv.tolist()
        self._bad_count: list[int] = [0] * n
        # The single-loop fast path; tests set it False to run the n-loop numpy path instead.
        self._scalar = n == 1
        self._lo: list[float] = r.lo.tolist()
        self._hi: list[float] = r.hi.tolist()
        if n == 1:
            # Per-scan constants of the fast path as floats, unpacked once per step.
            self._one = (
                float(r.lo[0]),
                float(r.hi[0]),
                float(r.du_max[0]),
                float(r.sp_lo[0]),
                float(r.sp_hi[0]),
                float(r.sp_step[0]),
                float(r.sign[0]),
                float(r.alpha),
                float(r.ts),
                int(r.pv_bad_scans),
                bool(r.subst_value[0]),
                float(r.substitute_mv[0]),
            )
        self._b: list[float] = r.b.tolist()
        self._c: list[float] = r.c.tolist()
        self._gains = gains
        self._one_gains = (0.0, 0.0, 0.0)
        self._use_gains(gains)

    # ------------------------------------------------------------------ state
    @property
    def config(self) -> PidConfig:
        """The block's configuration."""
        return self._config

    @property
    def n_loops(self) -> int:
        """Number of loops (= actuators)."""
        return self._r.n

    @property
    def gains(self) -> PidGains:
        """Gains that the next `step` applies."""
        return self._gains

    @property
    def mv(self) -> FloatArray:
        """Applied MV u(k-1) per actuator [u] (copy)."""
        return np.array(self._u, dtype=np.float64)

    @property
    def modes(self) -> tuple[LoopMode, ...]:
        """Current mode per loop."""
        return tuple(self._modes)

    @property
    def manual_mv(self) -> FloatArray:
        """Held manual value per loop [u] (copy)."""
        return np.array(self._manual, dtype=np.float64)

    @property
    def remote_mv(self) -> FloatArray:
        """Held remote value per loop [u] (copy)."""
        return np.array(self._remote, dtype=np.float64)

    @property
    def setpoint_weights(self) -> tuple[FloatArray, FloatArray]:
        """(b, c) per loop: the setpoint weights of the P and D terms (copies)."""
        return np.array(self._b, dtype=np.float64), np.array(self._c, dtype=np.float64)

    @property
    def working_sp(self) -> FloatArray:
        """Working setpoint per loop after the last step [PV unit] (copy; zeros before the first step)."""
        return np.array(self._w, dtype=np.float64)

    @property
    def pv_bad_count(self) -> NDArray[np.int64]:
        """Consecutive bad-PV scans per loop (copy)."""
        return np.array(self._bad_count, dtype=np.int64)

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
        n = self._r.n
        new = PidGains(_gain_matrix("Kp", Kp, n), _gain_matrix("Ki", Ki, n), _gain_matrix("Kd", Kd, n))
        self._use_gains(new)

    def _use_gains(self, gains: PidGains) -> None:
        self._gains = gains
        if self._r.n == 1:
            self._one_gains = (float(gains.Kp[0, 0]), float(gains.Ki[0, 0]), float(gains.Kd[0, 0]))

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
        j = _check_loop(loop, self._r.n)
        new_b = self._b[j] if b is None else _finite_scalar("b", b)
        new_c = self._c[j] if c is None else _finite_scalar("c", c)
        if not (0.0 <= new_b <= 1.0 and 0.0 <= new_c <= 1.0):
            raise ValueError(f"setpoint weights must lie in [0, 1], got b = {new_b}, c = {new_c}")
        self._b[j], self._c[j] = new_b, new_c

    def set_mode(self, loop: int, mode: LoopMode, mv: float | None = None) -> None:
        """Switch one loop's mode, bumplessly.

        Parameters
        ----------
        loop : int
            Loop index in [0, n).
        mode : LoopMode
            New mode.
        mv : float, optional
            For MANUAL / REMOTE: the held value to apply (clamped to the limits). Omitted: the held
            value is initialised to the applied MV (tracking), so the switch does not move the MV.
            Must be omitted for AUTO.
        """
        j = _check_loop(loop, self._r.n)
        mode = _check_mode(mode)
        if mode is LoopMode.AUTO:
            if mv is not None:
                raise ValueError("mv applies only to MANUAL and REMOTE; AUTO continues from the applied MV")
        else:
            held = self._u[j] if mv is None else self._clamp(j, _finite_scalar("mv", mv))
            if mode is LoopMode.MANUAL and (self._modes[j] is not LoopMode.MANUAL or mv is not None):
                self._manual[j] = held
            if mode is LoopMode.REMOTE and (self._modes[j] is not LoopMode.REMOTE or mv is not None):
                self._remote[j] = held
        self._modes[j] = mode

    def set_manual_mv(self, loop: int, mv: float) -> None:
        """Set the held manual value of one loop [u] (clamped to the limits; applied in MANUAL)."""
        j = _check_loop(loop, self._r.n)
        self._manual[j] = self._clamp(j, _finite_scalar("mv", mv))

    def set_remote_mv(self, loop: int, mv: float) -> None:
        """Set the held remote value of one loop [u] (clamped to the limits; applied in REMOTE)."""
        j = _check_loop(loop, self._r.n)
        self._remote[j] = self._clamp(j, _finite_scalar("mv", mv))

    def track(self, loop: int, mv: float) -> None:
        """Tell the block where an actuator really is (e.g. after an interlock forced it).

        The applied-MV memory u(k-1) becomes ``mv`` (clamped), so the next AUTO move is a normal
        increment from it and the rate limit counts from it. The held manual/remote values are
        not changed.
        """
        j = _check_loop(loop, self._r.n)
        self._u[j] = self._clamp(j, _finite_scalar("mv", mv))

    def resume(self, loop: int, mv: float, sp: float, pv: float) -> None:
        """Continue a loop from a running process (a warm restart), bumplessly.

        The applied-MV memory u(k-1) becomes ``mv`` (clamped: the actuator's command now) and
        the memory of the last good scan becomes (w(k-1), y(k-1)) = (``sp`` clamped to
        [sp_min, sp_max], ``pv``), with no derivative history, as if the scan before had run
        on that reading. The next step is then an ordinary velocity-form increment from ``mv``:
        with the same SP and PV, ``Ki * Ts * e`` alone (no proportional or derivative kick).
        A non-finite ``pv`` only sets u(k-1) (the memory re-initialises on the next good scan).
        """
        j = _check_loop(loop, self._r.n)
        self._u[j] = self._clamp(j, _finite_scalar("mv", mv))
        target = min(max(_finite_scalar("sp", sp), float(self._r.sp_lo[j])), float(self._r.sp_hi[j]))
        if math.isfinite(pv):
            self._w_mem[j] = target
            self._y_mem[j] = float(pv)
            self._d_prev[j] = 0.0
            self._needs_init[j] = False

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
        n = self._r.n
        sp_arr = _float_array("sp", sp)
        if sp_arr.shape != (n,):
            raise ValueError(f"sp must have shape ({n},), got {sp_arr.shape}")
        if not np.all(np.isfinite(sp_arr)):
            raise ValueError("sp must be finite")
        pv_arr = _float_array("pv", pv)
        if pv_arr.shape != (n,):
            raise ValueError(f"pv must have shape ({n},), got {pv_arr.shape}")
        if pv_good is None:
            good_in = np.ones(n, dtype=bool)
        else:
            good_in = np.asarray(pv_good)
            if good_in.dtype.kind != "b":
                raise TypeError("pv_good must be booleans")
            if good_in.shape != (n,):
                raise ValueError(f"pv_good must have shape ({n},), got {good_in.shape}")
        if self._scalar:
            s = self._step_one(float(sp_arr[0]), float(pv_arr[0]), bool(good_in[0]))
            return PidStepResult(
                mv=np.array([s.mv]),
                working_sp=np.array([s.working_sp]),
                error=np.array([s.error]),
                p=np.array([s.p]),
                i=np.array([s.i]),
                d=np.array([s.d]),
                clamped=np.array([s.clamped]),
                rate_limited=np.array([s.rate_limited]),
                pv_good=np.array([s.pv_good]),
                substituted=np.array([s.substituted]),
                modes=(s.mode,),
            )
        return self._step_arrays(sp_arr, pv_arr, good_in)

    def step_siso(self, sp: float, pv: float, pv_good: bool | np.bool_ = True) -> PidLoopStep:
        """Run one scan of a one-loop block on floats (the single-loop fast path).

        Same law, order of operations and state as `step` (see the module docstring), without
        building arrays: the PLC program's per-scan call.

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
        if not self._scalar:
            raise ValueError(f"step_siso needs a one-loop block, this one has {self._r.n} loops")
        if type(sp) is not float:
            sp = _finite_scalar("sp", sp)
        elif not math.isfinite(sp):
            raise ValueError("sp must be finite")
        if type(pv) is not float:
            pv = _real_scalar("pv", pv)
        if type(pv_good) is not bool:
            if not isinstance(pv_good, np.bool_):
                raise TypeError(f"pv_good must be a bool, got {type(pv_good).__name__}")
            pv_good = bool(pv_good)
        return self._step_one(sp, pv, pv_good)

    # ------------------------------------------------------------------ the two paths
    def _step_one(self, sp: float, pv: float, pv_good: bool) -> PidLoopStep:
        """The law of the module docstring for n = 1 on floats (validated inputs).

        Mirrors `_step_arrays` operation for operation (same order, so the same roundings).
        """
        lo, hi, du_max, sp_lo, sp_hi, sp_step, sign, alpha, ts, n_bad, subst_value, subst_mv = self._one
        kp, ki, kd = self._one_gains
        b, c = self._b[0], self._c[0]
        good = pv_good and math.isfinite(pv)

        # Working setpoint: clamp the target, then ramp toward it. Every min(max(x, lo), hi) of
        # this path is written out as the builtins evaluate it (max keeps x unless lo > x, min
        # keeps it unless hi < it; NaN and signed zeros alike), without their calls' cost.
        target = sp_lo if sp_lo > sp else sp
        target = sp_hi if sp_hi < target else target
        if self._started:
            w_prev = self._w[0]
            step = target - w_prev
            step = -sp_step if -sp_step > step else step
            w = w_prev + (sp_step if sp_step < step else step)
        else:
            w = target
            self._started = True
        self._w[0] = w

        # PV quality, errors; a bad loop contributes nothing and its memory is frozen.
        bad_count = 0 if good else self._bad_count[0] + 1
        self._bad_count[0] = bad_count
        d_prev = self._d_prev[0]
        if good:
            e = sign * (w - pv)
            if self._needs_init[0]:
                w_mem, y_mem = w, pv
                d_prev = 0.0
            else:
                w_mem, y_mem = self._w_mem[0], self._y_mem[0]
            e_used = e
            de_p = sign * (b * w - pv) - sign * (b * w_mem - y_mem)
            de_d = sign * (c * w - pv) - sign * (c * w_mem - y_mem)
            d_new = alpha * d_prev + (1.0 - alpha) * de_d / ts
        else:
            e = math.nan
            e_used = 0.0
            de_p = 0.0
            d_new = d_prev
        p = kp * de_p
        i = ki * (ts * e_used)
        d = kd * (d_new - d_prev)
        u_prev = self._u[0]

        # Select by mode; AUTO and REMOTE fall back to the substitute after N bad scans.
        mode = self._modes[0]
        if mode is _AUTO:
            raw = u_prev + p + i + d
        elif mode is _REMOTE:
            raw = self._remote[0]
        else:
            raw = self._manual[0]
        substituted = not good and bad_count >= n_bad and mode is not _MANUAL
        if substituted:
            raw = subst_mv if subst_value else u_prev
        if math.isnan(raw):  # overflowing products (inf - inf): hold
            raw = u_prev

        low, up = u_prev - du_max, u_prev + du_max
        limited = low if low > raw else raw
        limited = up if up < limited else limited
        u = lo if lo > limited else limited
        u = hi if hi < u else u

        self._u[0] = u
        if good:
            self._w_mem[0] = w
            self._y_mem[0] = pv
        self._d_prev[0] = d_new
        self._needs_init[0] = not good
        # tuple.__new__ skips the NamedTuple's Python-level __new__ (a third of this method's cost)
        return _new_tuple(
            PidLoopStep, (u, w, e, p, i, d, u != limited, limited != raw, good, substituted, mode)
        )

    def _step_arrays(self, sp_arr: FloatArray, pv_arr: FloatArray, good_in: BoolArray) -> PidStepResult:
        """The law of the module docstring for any n on arrays (validated inputs)."""
        r = self._r
        good = good_in & np.isfinite(pv_arr)
        g = self._gains
        ts = r.ts

        # Working setpoint: clamp the target, then ramp toward it.
        target = np.clip(sp_arr, r.sp_lo, r.sp_hi)
        if self._started:
            w_prev = np.array(self._w)
            w = w_prev + np.clip(target - w_prev, -r.sp_step, r.sp_step)
        else:
            w = target.copy()
            self._started = True

        # PV quality.
        bad_count = np.where(good, 0, np.array(self._bad_count, dtype=np.int64) + 1)
        subst_loop = (~good) & (bad_count >= r.pv_bad_scans)

        # Errors; a bad loop contributes nothing and its memory is frozen.
        y = np.where(good, pv_arr, 0.0)
        e = np.where(good, r.sign * (w - y), np.nan)
        needs_init = np.array(self._needs_init, dtype=bool)
        reinit = good & needs_init
        w_mem = np.where(reinit, w, np.array(self._w_mem))
        y_mem = np.where(reinit, y, np.array(self._y_mem))
        d_prev = np.where(reinit, 0.0, np.array(self._d_prev))

        b, c = np.array(self._b), np.array(self._c)
        e_used = np.where(good, e, 0.0)
        de_p = np.where(good, r.sign * (b * w - y) - r.sign * (b * w_mem - y_mem), 0.0)
        de_d = np.where(good, r.sign * (c * w - y) - r.sign * (c * w_mem - y_mem), 0.0)
        d_new = np.where(good, r.alpha * d_prev + (1.0 - r.alpha) * de_d / ts, d_prev)
        dd = d_new - d_prev

        p = g.Kp @ de_p
        i = g.Ki @ (ts * e_used)
        d = g.Kd @ dd
        u_prev = np.array(self._u)
        u_auto = u_prev + p + i + d

        # Select by mode; AUTO and REMOTE fall back to the substitute after N bad scans.
        modes = tuple(self._modes)
        auto = np.array([m is LoopMode.AUTO for m in modes])
        remote = np.array([m is LoopMode.REMOTE for m in modes])
        raw = np.where(auto, u_auto, np.where(remote, np.array(self._remote), np.array(self._manual)))
        substituted = subst_loop & (auto | remote)
        subst_out = np.where(r.subst_value, r.substitute_mv, u_prev)
        raw = np.where(substituted, subst_out, raw)
        raw = np.where(np.isnan(raw), u_prev, raw)  # overflowing products (inf - inf): hold

        limited = np.clip(raw, u_prev - r.du_max, u_prev + r.du_max)
        rate_limited = limited != raw
        u = np.clip(limited, r.lo, r.hi)
        clamped = u != limited

        self._w = w.tolist()
        self._bad_count = bad_count.tolist()
        self._u = u.tolist()
        self._w_mem = np.where(good, w, w_mem).tolist()
        self._y_mem = np.where(good, y, y_mem).tolist()
        self._d_prev = d_new.tolist()
        self._needs_init = (~good).tolist()

        return PidStepResult(
            mv=u.copy(),
            working_sp=w.copy(),
            error=e,
            p=p,
            i=i,
            d=d,
            clamped=clamped,
            rate_limited=rate_limited,
            pv_good=good,
            substituted=substituted,
            modes=modes,
        )

    # ------------------------------------------------------------------ helpers
    def _clamp(self, j: int, value: float) -> float:
        return float(min(max(value, self._lo[j]), self._hi[j]))
