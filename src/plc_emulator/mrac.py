"""Model-reference adaptive control for one tank loop, MIT rule, normalised (digest 2.6).

Reference model and model error (u_c the setpoint, y the PV, both in the PV's unit)::

    y_m / u_c = wn^2 / (s^2 + 2 delta wn s + wn^2),      e = y - y_m

Two laws (theta = (theta1, theta2) or (kp, ki), u in the MV's unit)::

    MIT:  u = theta1 u_c - theta2 y,              phi = [ G_m u_c, -G_m y ]
    PI:   u = kp (u_c - y) + ki I,  dI/dt = u_c - y,
          phi = [ s / (s^2 + 2 delta wn s + wn^2) (u_c - y),  1 / (s^2 + 2 delta wn s + wn^2) (u_c - y) ]

with G_m = wn^2 / (s^2 + 2 delta wn s + wn^2), and the normalised MIT rule with projection::

    dtheta/dt = -gamma e phi / (alpha + phi' phi),     theta in [theta_min, theta_max]

(so dtheta1/dt = -gamma e G_m u_c and dtheta2/dt = +gamma e G_m y before normalisation: the
digest's signs, which reduce |e| for a positive plant gain). Note that here the sensitivity filter
of the MIT law has numerator wn^2, so this gamma is the MRAC paper's gamma / wn^2.

Discretisation at the scan Ts [s]: every filter (reference model and sensitivity filters) is the
LTI system x' = A x + [0, 1]' v with A = [[0, 1], [-wn^2, -2 delta wn]], whose state holds
(1/(s^2 + ...)) v and (s/(s^2 + ...)) v. Its input is held over the scan (zero-order hold), so
the exact discretisation x(k+1) = Phi x(k) + Gamma v(k), Phi = expm(A Ts),
Gamma = int_0^Ts expm(A t) dt [0, 1]', is computed once at construction (scipy.linalg.expm of the
augmented matrix [[A, B], [0, 0]] Ts). The parameter law is integrated by forward Euler at the scan,
theta(k) = proj(theta(k-1) - Ts gamma e(k) phi(k) / (alpha + phi(k)' phi(k))); the normalisation
bounds each step by Ts gamma |e| / (2 sqrt(alpha)). The integral is I(k) = I(k-1) + Ts (u_c(k) - y(k)).

Scan order: y_m(k) and phi(k) come from the filter states (inputs up to k-1); theta is updated
with e(k); the law gives u(k), clamped to [u_min, u_max]; then the filters advance with u_c(k)
and y(k). Adaptation is frozen on a scan whose previous output was clamped (the plant did not
receive the commanded value, so the gradient would be wrong), and in MANUAL.

Anti-windup (PI law): back-calculation to the limit, I(k) = (u_sat - kp (u_c - y)) / ki; with
ki = 0 the scan's integration is undone instead.

Modes MANUAL / AUTO. The sensitivity filters run in both. On entering AUTO the reference model
starts at rest at the current PV (y_m = y, dy_m/dt = 0, so e = 0), and the law is initialised so
that its first output equals the applied MV: the PI's integral I(k-1) = (u(k-1) - kp (u_c - y)) / ki
(then the first AUTO move is ki Ts (u_c - y)); the MIT law has no state, so its feedforward gain
theta1 = (u(k-1) + theta2 y) / u_c is set instead (projected onto its bounds; not done when
|u_c| is below 1e-12, in which case the first AUTO output is theta1 u_c - theta2 y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from plc_emulator.manual_auto import ManualAutoOutput, check_limits, check_two_modes
from tanklab.checks import finite as _finite
from tanklab.checks import positive as _positive
from tanklab.checks import real as _real
from tanklab.enums import LoopMode

__all__ = ["DiscreteSecondOrder", "Mrac", "MracConfig", "MracLaw", "MracStepResult"]

FloatArray = NDArray[np.float64]
MracLaw = Literal["mit", "pi"]

_TINY = 1e-12


def _pair(name: str, value: tuple[float, float], *, finite: bool) -> tuple[float, float]:
    if not isinstance(value, tuple | list) or len(value) != 2:
        raise TypeError(f"{name} must be a pair of real numbers")
    a, b = _real(f"{name}[0]", value[0]), _real(f"{name}[1]", value[1])
    for i, x in enumerate((a, b)):
        if math.isnan(x) or (finite and not math.isfinite(x)):
            raise ValueError(f"{name}[{i}] must be {'finite' if finite else 'a number (not NaN)'}, got {x}")
    return a, b


class DiscreteSecondOrder:
    """Exact (zero-order-hold) discretisation of x' = A x + [0, 1]' v at the scan.

    A = [[0, 1], [-wn^2, -2 delta wn]]; the state is x = (v / (s^2 + 2 delta wn s + wn^2),
    s v / (s^2 + 2 delta wn s + wn^2)), so wn^2 x[0] is the output of the unit-gain reference
    model wn^2 / (s^2 + 2 delta wn s + wn^2) driven by v and wn^2 x[1] its time derivative.

    Parameters
    ----------
    wn : float
        Natural frequency [rad/s], > 0.
    delta : float
        Damping ratio, > 0.
    ts_s : float
        Scan period [s], > 0.

    Attributes
    ----------
    Phi : ndarray, shape (2, 2)
        expm(A Ts).
    Gamma : ndarray, shape (2,)
        int_0^Ts expm(A t) dt [0, 1]'.
    """

    def __init__(self, wn: float, delta: float, ts_s: float) -> None:
        self.wn = _positive("wn", wn)
        self.delta = _positive("delta", delta)
        self.ts_s = _positive("ts_s", ts_s)
        A = np.array([[0.0, 1.0], [-(self.wn**2), -2.0 * self.delta * self.wn]])
        M = np.zeros((3, 3))
        M[:2, :2] = A
        M[1, 2] = 1.0
        E = scipy.linalg.expm(M * self.ts_s)
        self.Phi: FloatArray = np.ascontiguousarray(E[:2, :2])
        self.Gamma: FloatArray = np.ascontiguousarray(E[:2, 2])
        self.x: FloatArray = np.zeros(2)

    def rest_at(self, v: float) -> None:
        """Set the state to rest for a constant input v: x = (v / wn^2, 0)."""
        self.x = np.array([v / self.wn**2, 0.0])

    def advance(self, v: float) -> None:
        """x(k+1) = Phi x(k) + Gamma v(k)."""
        self.x = self.Phi @ self.x + self.Gamma * v


@dataclass(frozen=True)
class MracConfig:
    """Configuration of an `Mrac` block.

    Attributes
    ----------
    ts_s : float
        Scan period Ts [s], > 0.
    law : {"mit", "pi"}
        MIT feedforward/feedback law or adaptive PI.
    wn : float
        Reference-model natural frequency [rad/s], > 0 (digest default 4.6 / (delta 60 s)).
    delta : float
        Reference-model damping, > 0 (paper: 0.7, 1, 2).
    gamma : float
        Adaptation gain, >= 0 [theta unit per (PV unit s)] (0 freezes theta).
    alpha : float
        Normalisation constant of the MIT rule [PV unit^2], > 0.
    theta0 : pair of float
        Initial (theta1, theta2) for "mit" (digest: (1, 0)) or (kp, ki) for "pi".
    theta_min, theta_max : pair of float
        Projection bounds, theta_min <= theta0 <= theta_max (infinite allowed, NaN not).
    u_min, u_max : float
        Output limits [MV unit], finite, u_min < u_max.
    initial_mv : float
        u(-1) [MV unit], within the limits.
    initial_mode : LoopMode
        MANUAL or AUTO.
    freeze_when_saturated : bool
        Skip the parameter update on a scan whose previous output was clamped (default True).
    """

    ts_s: float
    law: MracLaw
    wn: float
    delta: float
    gamma: float
    alpha: float
    theta0: tuple[float, float]
    theta_min: tuple[float, float]
    theta_max: tuple[float, float]
    u_min: float
    u_max: float
    initial_mv: float = 0.0
    initial_mode: LoopMode = LoopMode.AUTO
    freeze_when_saturated: bool = True

    def __post_init__(self) -> None:
        _positive("ts_s", self.ts_s)
        if self.law not in ("mit", "pi"):
            raise ValueError(f"law must be 'mit' or 'pi', got {self.law!r}")
        _positive("wn", self.wn)
        _positive("delta", self.delta)
        if _finite("gamma", self.gamma) < 0.0:
            raise ValueError(f"gamma must be >= 0, got {self.gamma}")
        _positive("alpha", self.alpha)
        t0 = _pair("theta0", self.theta0, finite=True)
        lo = _pair("theta_min", self.theta_min, finite=False)
        hi = _pair("theta_max", self.theta_max, finite=False)
        for i in range(2):
            if not lo[i] <= t0[i] <= hi[i]:
                raise ValueError(
                    f"theta0[{i}] = {t0[i]} must lie within [theta_min[{i}], theta_max[{i}]] "
                    f"= [{lo[i]}, {hi[i]}]"
                )
        if self.law == "pi" and lo[1] < 0.0:
            raise ValueError("for the 'pi' law theta_min[1] (ki) must be >= 0")
        check_limits(self.u_min, self.u_max, self.initial_mv)
        check_two_modes(self.initial_mode, "initial_mode")
        if not isinstance(self.freeze_when_saturated, bool):
            raise TypeError("freeze_when_saturated must be a bool")


@dataclass(frozen=True)
class MracStepResult:
    """Outcome and diagnostics of one `Mrac` scan.

    Attributes
    ----------
    mv : float
        Applied output u(k) [MV unit].
    y_m : float
        Reference-model output y_m(k) [PV unit].
    model_error : float
        e(k) = y(k) - y_m(k) [PV unit].
    theta : ndarray, shape (2,)
        (theta1, theta2) or (kp, ki) used this scan (after the update).
    phi : ndarray, shape (2,)
        Sensitivity regressor phi(k).
    adapted : bool
        Whether theta was updated this scan.
    saturated : bool
        The output limits bound this scan.
    integral : float
        PI law's integral I(k) [PV unit s] (0 for the MIT law).
    mode : LoopMode
        Mode during this scan.
    """

    mv: float
    y_m: float
    model_error: float
    theta: FloatArray
    phi: FloatArray
    adapted: bool
    saturated: bool
    integral: float
    mode: LoopMode


class Mrac(ManualAutoOutput):
    """MRAC (normalised MIT rule) for one loop; see the module docstring for the laws.

    Parameters
    ----------
    config : MracConfig
        Law, reference model, adaptation and limits.

    Notes
    -----
    There is deliberately no ``set_gains``: MRAC has no PID gains (the OPC UA layer answers
    SetGains with BadInvalidState).
    """

    def __init__(self, config: MracConfig) -> None:
        if not isinstance(config, MracConfig):
            raise TypeError(f"config must be an MracConfig, got {type(config).__name__}")
        self._c = config
        self._ts = float(config.ts_s)
        self._wn2 = float(config.wn) ** 2
        self._lo = float(config.u_min)
        self._hi = float(config.u_max)
        self._theta_lo = np.array(config.theta_min, dtype=np.float64)
        self._theta_hi = np.array(config.theta_max, dtype=np.float64)
        self._theta = np.array(config.theta0, dtype=np.float64)
        self._model = DiscreteSecondOrder(config.wn, config.delta, config.ts_s)  # input u_c, y_m = wn^2 x0
        self._f_uc = DiscreteSecondOrder(config.wn, config.delta, config.ts_s)  # MIT: G_m u_c = wn^2 x0
        self._f_y = DiscreteSecondOrder(config.wn, config.delta, config.ts_s)  # MIT: G_m y = wn^2 x0
        self._f_e = DiscreteSecondOrder(config.wn, config.delta, config.ts_s)  # PI: (x0, x1) of u_c - y
        self._u = float(config.initial_mv)
        self._manual = self._u
        self._mode = config.initial_mode
        self._integral = 0.0
        self._needs_init = True
        self._started = False
        self._saturated_prev = False

    @property
    def config(self) -> MracConfig:
        """The block's configuration."""
        return self._c

    @property
    def theta(self) -> FloatArray:
        """Current (theta1, theta2) or (kp, ki) (copy)."""
        return self._theta.copy()

    @property
    def y_m(self) -> float:
        """Reference-model output for the next scan, wn^2 x0 [PV unit]."""
        return float(self._wn2 * self._model.x[0])

    @property
    def integral(self) -> float:
        """PI law's integral I [PV unit s]."""
        return self._integral

    def step(self, sp: float, y: float, pv_good: bool = True) -> MracStepResult:
        """Run one scan.

        Parameters
        ----------
        sp : float
            Command u_c(k) (setpoint) [PV unit], finite.
        y : float
            Measured PV y(k) [PV unit], finite when ``pv_good``.
        pv_good : bool
            PV quality. MRAC needs a PV: on a bad one the block holds its output (MANUAL: the
            manual value), the filters and parameters stand still, and the law re-initialises
            from the applied MV when the PV returns.

        Returns
        -------
        MracStepResult
        """
        uc = _finite("sp", sp)
        if not pv_good:
            self._u = self._manual if self._mode is LoopMode.MANUAL else self._u
            self._needs_init = True
            return MracStepResult(
                mv=self._u,
                y_m=self.y_m,
                model_error=math.nan,
                theta=self._theta.copy(),
                phi=np.zeros(2),
                adapted=False,
                saturated=False,
                integral=self._integral if self._c.law == "pi" else 0.0,
                mode=self._mode,
            )
        yv = _finite("y", y)
        c = self._c
        if not self._started:
            # Filters start at rest for their first inputs (no start-up transient).
            self._f_uc.rest_at(uc)
            self._f_y.rest_at(yv)
            self._f_e.rest_at(uc - yv)
            self._started = True
        auto = self._mode is LoopMode.AUTO
        entering = auto and self._needs_init
        if entering or not auto:
            self._model.rest_at(yv)  # y_m starts (or waits) at the PV
        y_m = float(self._wn2 * self._model.x[0])
        e = yv - y_m
        if c.law == "mit":
            phi = np.array([self._wn2 * self._f_uc.x[0], -self._wn2 * self._f_y.x[0]])
        else:
            phi = np.array([self._f_e.x[1], self._f_e.x[0]])

        adapted = False
        saturated = False
        err = uc - yv
        if auto:
            if entering:
                self._init_law(uc, yv)
                self._needs_init = False
            elif not (c.freeze_when_saturated and self._saturated_prev) and c.gamma > 0.0:
                step = self._ts * c.gamma * e / (c.alpha + float(phi @ phi))
                self._theta = np.clip(self._theta - step * phi, self._theta_lo, self._theta_hi)
                adapted = True
            t1, t2 = float(self._theta[0]), float(self._theta[1])
            if c.law == "mit":
                u_raw = t1 * uc - t2 * yv
            else:
                self._integral += self._ts * err
                u_raw = t1 * err + t2 * self._integral
            u = self._clamp(u_raw)
            saturated = u != u_raw
            if saturated and c.law == "pi":
                if abs(t2) > _TINY:
                    self._integral = (u - t1 * err) / t2
                else:
                    self._integral -= self._ts * err
        else:
            u = self._manual
            self._needs_init = True
        self._u = u
        self._saturated_prev = saturated

        self._model.advance(uc)
        self._f_uc.advance(uc)
        self._f_y.advance(yv)
        self._f_e.advance(err)
        return MracStepResult(
            mv=u,
            y_m=y_m,
            model_error=e,
            theta=self._theta.copy(),
            phi=phi,
            adapted=adapted,
            saturated=saturated,
            integral=self._integral if c.law == "pi" else 0.0,
            mode=self._mode,
        )

    def _init_law(self, uc: float, y: float) -> None:
        """Make the law reproduce the applied MV at this scan (bumpless entry into AUTO)."""
        t1, t2 = float(self._theta[0]), float(self._theta[1])
        if self._c.law == "pi":
            if abs(t2) > _TINY:
                self._integral = (self._u - t1 * (uc - y)) / t2
            else:
                self._integral = 0.0
        elif abs(uc) > _TINY:
            t1_new = (self._u + t2 * y) / uc
            self._theta[0] = min(max(t1_new, self._theta_lo[0]), self._theta_hi[0])

    def _clamp(self, value: float) -> float:
        if math.isnan(value):
            return self._u
        return min(max(value, self._lo), self._hi)
