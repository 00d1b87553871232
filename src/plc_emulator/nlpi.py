"""Feedback-linearized 2-DOF PI for one tank, fixed and adaptive (digest 2.2, 2.3).

Plant: dh/dt = b u - a' sqrt(h) with h the level [m], u the pump command [MV unit],
b [m/s per MV unit], a' [sqrt(m)/s]. Control law at scan k (scan period Ts [s])::

    I(k) = I(k-1) + Ts (r(k) - h(k))                 [m s]   (the paper's "/ Ts" is a slip)
    u(k) = sat_[u_min, u_max]( Ki I(k) - Kp h(k) + Kl sqrt(max(h(k), 0)) )
    Kp = 2 zeta wn / b,   Ki = wn^2 / b,   Kl = a' / b

The sqrt term cancels the outflow, so in continuous time the closed loop is
wn^2 / (s^2 + 2 zeta wn s + wn^2) at every level; sampled, the cancellation is exact only as Ts
becomes small against the closed-loop dynamics (a 1 s scan overshoots the first step from empty
several times more than a 0.01 s scan).

Anti-windup: **back-calculation to the limit**. When the unclamped u leaves [u_min, u_max], the
integrator is recomputed so that the law gives exactly the applied value:
I(k) = (u_sat + Kp h(k) - Kl sqrt(h(k))) / Ki. The integrator therefore always matches the
applied output (like the velocity-form PID), and the output leaves the limit on the first scan the
error's sign lets it.

Bumpless transfer and gain changes: on the first AUTO scan after MANUAL (or after a bad PV), the
integrator is initialised so that the law reproduces the applied MV at the current level,
I(k-1) = (u(k-1) + Kp h(k) - Kl sqrt(h(k))) / Ki; the first AUTO move is then just Ki Ts e(k).
A gain change rescales I(k-1) the same way, so the output is continuous across it.

Adaptive variant: exponentially weighted RLS (``tanklab.rls.ExpForgettingRls``) on the
integrated form of the model, regressed once per scan before the law runs::

    y(k) = (h(k) - h(k-1)) / Ts
    x(k) = [u(k-1), -(sqrt(h(k)) + sqrt(h(k-1))) / 2]
    theta = [b, a']          (y = x' theta exactly for held u, up to the trapezoid rule on sqrt(h))

with forgetting per unit time lambda = exp(-Ts / Tmem), updates only when the regressor moved
(the RLS's dead zone), P symmetric and trace-capped, and theta projected onto b >= b_min > 0,
a' >= 0. Kp, Ki and Kl are recomputed from the estimates every scan once ``min_updates`` updates
have been applied (before that the prior b0, a'0 are used).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plc_emulator.manual_auto import ManualAutoOutput, check_limits, check_two_modes
from plc_emulator.tuning import NlPiGains, nlpi_gains
from tanklab.checks import finite as _finite
from tanklab.checks import positive as _positive
from tanklab.checks import real as _real
from tanklab.enums import LoopMode
from tanklab.rls import ExpForgettingRls

__all__ = [
    "AdaptiveNlPi",
    "AdaptiveNlPiConfig",
    "AdaptiveNlPiStepResult",
    "NlPi",
    "NlPiConfig",
    "NlPiStepResult",
]


@dataclass(frozen=True)
class NlPiConfig:
    """Configuration of a `NlPi` block.

    Attributes
    ----------
    ts_s : float
        Scan period Ts [s], > 0.
    gains : NlPiGains
        Kp [MV per m], Ki [MV per m s], Kl [MV per sqrt(m)] (see `plc_emulator.tuning.nlpi_gains`).
        Kl = 0 gives a plain linear 2-DOF PI (P on the measurement).
    u_min, u_max : float
        Output limits [MV unit], finite, u_min < u_max.
    initial_mv : float
        u(-1) [MV unit], within the limits.
    initial_mode : LoopMode
        MANUAL or AUTO.
    """

    ts_s: float
    gains: NlPiGains
    u_min: float
    u_max: float
    initial_mv: float = 0.0
    initial_mode: LoopMode = LoopMode.AUTO

    def __post_init__(self) -> None:
        _positive("ts_s", self.ts_s)
        if not isinstance(self.gains, NlPiGains):
            raise TypeError(f"gains must be a NlPiGains, got {type(self.gains).__name__}")
        check_limits(self.u_min, self.u_max, self.initial_mv)
        check_two_modes(self.initial_mode)


@dataclass(frozen=True)
class NlPiStepResult:
    """Outcome and diagnostics of one `NlPi` scan.

    Attributes
    ----------
    mv : float
        Applied output u(k) [MV unit].
    error : float
        r(k) - h(k) [m] (NaN when the PV was bad).
    integral : float
        I(k) after anti-windup [m s].
    i_term, p_term, l_term : float
        Ki I(k), -Kp h(k) and Kl sqrt(h(k)) [MV unit] (the unclamped u is their sum; zeros
        outside AUTO).
    saturated : bool
        The output limits bound this scan (the integrator was back-calculated).
    pv_good : bool
        Whether the PV was used.
    mode : LoopMode
        Mode during this scan.
    """

    mv: float
    error: float
    integral: float
    i_term: float
    p_term: float
    l_term: float
    saturated: bool
    pv_good: bool
    mode: LoopMode


class NlPi(ManualAutoOutput):
    """Feedback-linearized 2-DOF PI for one tank (see the module docstring for the law).

    Parameters
    ----------
    config : NlPiConfig
        Scan period, gains, limits, initial output and mode.

    Notes
    -----
    A bad PV (``pv_good`` False or non-finite) holds the applied MV in AUTO and freezes the
    integrator; the first good scan re-initialises it bumplessly.
    """

    def __init__(self, config: NlPiConfig) -> None:
        if not isinstance(config, NlPiConfig):
            raise TypeError(f"config must be a NlPiConfig, got {type(config).__name__}")
        self._config = config
        self._ts = float(config.ts_s)
        self._lo = float(config.u_min)
        self._hi = float(config.u_max)
        self._gains = config.gains  # applied from the next step
        self._gains_used = config.gains  # the gains that produced the last AUTO output
        self._u = float(config.initial_mv)
        self._manual = self._u
        self._mode = config.initial_mode
        self._integral = 0.0
        self._needs_init = True

    @property
    def config(self) -> NlPiConfig:
        """The block's configuration."""
        return self._config

    @property
    def gains(self) -> NlPiGains:
        """Gains the next step applies."""
        return self._gains

    @property
    def integral(self) -> float:
        """Integrator state I [m s] (meaningful in AUTO)."""
        return self._integral

    def set_gains(self, gains: NlPiGains) -> None:
        """Use new gains from the next step on; the integrator is rescaled there (bumpless)."""
        if not isinstance(gains, NlPiGains):
            raise TypeError(f"gains must be a NlPiGains, got {type(gains).__name__}")
        self._gains = gains

    def step(self, sp: float, h: float, pv_good: bool = True) -> NlPiStepResult:
        """Run one scan.

        Parameters
        ----------
        sp : float
            Setpoint r(k) [m], finite.
        h : float
            Measured level h(k) [m]; negative values count as 0 inside the sqrt.
        pv_good : bool
            PV quality; False (or a non-finite h) holds the MV in AUTO.

        Returns
        -------
        NlPiStepResult
        """
        r = _finite("sp", sp)
        hv = _real("h", h)
        good = bool(pv_good) and math.isfinite(hv)
        mode = self._mode
        if mode is LoopMode.MANUAL:
            self._u = self._manual
            self._needs_init = True
            return NlPiStepResult(
                mv=self._u,
                error=r - hv if good else math.nan,
                integral=self._integral,
                i_term=0.0,
                p_term=0.0,
                l_term=0.0,
                saturated=False,
                pv_good=good,
                mode=mode,
            )
        if not good:
            self._needs_init = True
            return NlPiStepResult(
                mv=self._u,
                error=math.nan,
                integral=self._integral,
                i_term=0.0,
                p_term=0.0,
                l_term=0.0,
                saturated=False,
                pv_good=False,
                mode=mode,
            )

        g = self._gains
        sq = math.sqrt(max(hv, 0.0))
        if self._needs_init:
            # Bumpless entry: the law with I(k-1) reproduces the applied MV at this level.
            self._integral = (self._u + g.Kp * hv - g.Kl * sq) / g.Ki
            self._needs_init = False
        elif g is not self._gains_used:
            old = self._gains_used
            u_old = old.Ki * self._integral - old.Kp * hv + old.Kl * sq
            self._integral = (u_old + g.Kp * hv - g.Kl * sq) / g.Ki
        self._gains_used = g

        e = r - hv
        self._integral += self._ts * e
        i_term = g.Ki * self._integral
        p_term = -g.Kp * hv
        l_term = g.Kl * sq
        u_raw = i_term + p_term + l_term
        u = self._clamp(u_raw)
        saturated = u != u_raw
        if saturated:
            self._integral = (u + g.Kp * hv - g.Kl * sq) / g.Ki
        self._u = u
        return NlPiStepResult(
            mv=u,
            error=e,
            integral=self._integral,
            i_term=i_term,
            p_term=p_term,
            l_term=l_term,
            saturated=saturated,
            pv_good=True,
            mode=mode,
        )

    def _clamp(self, value: float) -> float:
        if math.isnan(value):
            return self._u
        return min(max(value, self._lo), self._hi)


@dataclass(frozen=True)
class AdaptiveNlPiConfig:
    """Configuration of an `AdaptiveNlPi` block.

    Attributes
    ----------
    ts_s : float
        Scan period Ts [s], > 0.
    zeta, wn : float
        Closed-loop damping [-] and natural frequency [rad/s], > 0.
    b0, a_prime0 : float
        Prior estimates of b [m/s per MV unit] (>= b_min) and a' [sqrt(m)/s] (>= 0).
    u_min, u_max : float
        Output limits [MV unit].
    initial_mv : float
        u(-1) [MV unit].
    initial_mode : LoopMode
        MANUAL or AUTO.
    memory_s : float
        RLS memory Tmem [s], > 0: forgetting lambda = exp(-Ts / Tmem) per scan (digest: 30 to 100 s).
    p0 : float
        Initial covariance P(0) = p0 I (default 1e6: the regressor entries are about 0.01 to 0.5, so
        a weaker prior than the RLS's usual 1e3 is needed for the estimates to leave it within a
        few setpoint steps; with 1e3 the simulation tank's b stays 5 % off after 150 s).
    trace_cap : float, optional
        Cap on trace P (default 2 p0, the initial trace).
    excitation_threshold : float
        RLS dead zone on the regressor's change since its last applied update
        [MV unit and sqrt(m) mixed, Euclidean], >= 0.
    b_min : float
        Lower projection bound on b, > 0.
    b_max, a_prime_max : float
        Upper projection bounds (inf allowed).
    min_updates : int
        Applied RLS updates needed before the estimates replace the prior in the gains (>= 0).
    """

    ts_s: float
    zeta: float
    wn: float
    b0: float
    a_prime0: float
    u_min: float
    u_max: float
    initial_mv: float = 0.0
    initial_mode: LoopMode = LoopMode.AUTO
    memory_s: float = 60.0
    p0: float = 1e6
    trace_cap: float | None = None
    excitation_threshold: float = 1e-4
    b_min: float = 1e-6
    b_max: float = math.inf
    a_prime_max: float = math.inf
    min_updates: int = 10

    def __post_init__(self) -> None:
        _positive("ts_s", self.ts_s)
        _positive("zeta", self.zeta)
        _positive("wn", self.wn)
        b_min = _positive("b_min", self.b_min)
        b_max = _real("b_max", self.b_max)
        a_max = _real("a_prime_max", self.a_prime_max)
        if math.isnan(b_max) or b_max < b_min:
            raise ValueError(f"b_max must be >= b_min = {b_min}, got {b_max}")
        if math.isnan(a_max) or a_max < 0.0:
            raise ValueError(f"a_prime_max must be >= 0, got {a_max}")
        b0 = _finite("b0", self.b0)
        if not b_min <= b0 <= b_max:
            raise ValueError(f"b0 must lie within [b_min, b_max] = [{b_min}, {b_max}], got {b0}")
        a0 = _finite("a_prime0", self.a_prime0)
        if not 0.0 <= a0 <= a_max:
            raise ValueError(f"a_prime0 must lie within [0, a_prime_max] = [0, {a_max}], got {a0}")
        check_limits(self.u_min, self.u_max, self.initial_mv)
        check_two_modes(self.initial_mode)
        _positive("memory_s", self.memory_s)
        if isinstance(self.min_updates, bool) or not isinstance(self.min_updates, int):
            raise TypeError(f"min_updates must be an int, got {type(self.min_updates).__name__}")
        if self.min_updates < 0:
            raise ValueError(f"min_updates must be >= 0, got {self.min_updates}")
        # The remaining RLS arguments (p0, trace_cap, excitation_threshold) are validated by
        # ExpForgettingRls itself when the block is built.


@dataclass(frozen=True)
class AdaptiveNlPiStepResult:
    """Outcome of one `AdaptiveNlPi` scan.

    Attributes
    ----------
    control : NlPiStepResult
        The law's result with the gains used this scan.
    b_hat, a_prime_hat : float
        Current estimates (after this scan's RLS update).
    updated : bool
        Whether the RLS applied an update this scan.
    gains : NlPiGains
        Gains used this scan.
    covariance_trace : float
        trace P of the RLS.
    """

    control: NlPiStepResult
    b_hat: float
    a_prime_hat: float
    updated: bool
    gains: NlPiGains
    covariance_trace: float

    @property
    def mv(self) -> float:
        """Applied output u(k) [MV unit]."""
        return self.control.mv


class AdaptiveNlPi:
    """Feedback-linearized PI whose b and a' are estimated online by RLS (integrated form).

    Parameters
    ----------
    config : AdaptiveNlPiConfig
        Spec, prior, limits and RLS settings.
    """

    def __init__(self, config: AdaptiveNlPiConfig) -> None:
        if not isinstance(config, AdaptiveNlPiConfig):
            raise TypeError(f"config must be an AdaptiveNlPiConfig, got {type(config).__name__}")
        self._config = config
        self._ts = float(config.ts_s)
        self._rls = ExpForgettingRls(
            2,
            forgetting=ExpForgettingRls.forgetting_from_memory(config.ts_s, config.memory_s),
            p0=config.p0,
            theta0=[config.b0, config.a_prime0],
            trace_cap=config.trace_cap,
            excitation_threshold=config.excitation_threshold,
            lower=[config.b_min, 0.0],
            upper=[config.b_max, config.a_prime_max],
        )
        gains = nlpi_gains(config.b0, config.a_prime0, config.zeta, config.wn)
        self._pi = NlPi(
            NlPiConfig(
                ts_s=config.ts_s,
                gains=gains,
                u_min=config.u_min,
                u_max=config.u_max,
                initial_mv=config.initial_mv,
                initial_mode=config.initial_mode,
            )
        )
        self._h_prev: float | None = None

    @property
    def config(self) -> AdaptiveNlPiConfig:
        """The block's configuration."""
        return self._config

    @property
    def controller(self) -> NlPi:
        """The inner law (for its mode, MV and integrator)."""
        return self._pi

    @property
    def estimates(self) -> tuple[float, float]:
        """Current (b_hat, a_prime_hat)."""
        theta = self._rls.theta
        return float(theta[0]), float(theta[1])

    @property
    def rls(self) -> ExpForgettingRls:
        """The estimator (read its trace, counters, covariance)."""
        return self._rls

    @property
    def mv(self) -> float:
        """Applied MV u(k-1) [MV unit]."""
        return self._pi.mv

    @property
    def mode(self) -> LoopMode:
        """Current mode."""
        return self._pi.mode

    def set_mode(self, mode: LoopMode, mv: float | None = None) -> None:
        """Switch between MANUAL and AUTO bumplessly (see `NlPi.set_mode`); RLS runs in both."""
        self._pi.set_mode(mode, mv)

    def set_manual_mv(self, mv: float) -> None:
        """Set the manual value [MV unit]."""
        self._pi.set_manual_mv(mv)

    def track(self, mv: float) -> None:
        """Set the applied-MV memory to an external value (see `NlPi.track`)."""
        self._pi.track(mv)

    def step(self, sp: float, h: float, pv_good: bool = True) -> AdaptiveNlPiStepResult:
        """Run one scan: RLS update from (h(k-1), h(k), u(k-1)), gains from the estimates, law.

        Parameters
        ----------
        sp : float
            Setpoint [m].
        h : float
            Measured level [m].
        pv_good : bool
            PV quality; a bad PV skips the RLS update and breaks the regressor chain.

        Returns
        -------
        AdaptiveNlPiStepResult
        """
        hv = _real("h", h)
        good = bool(pv_good) and math.isfinite(hv)
        updated = False
        if good and self._h_prev is not None:
            sq, sq_prev = math.sqrt(max(hv, 0.0)), math.sqrt(max(self._h_prev, 0.0))
            x = np.array([self._pi.mv, -0.5 * (sq + sq_prev)])
            updated = self._rls.update(x, (hv - self._h_prev) / self._ts)
        self._h_prev = hv if good else None

        c = self._config
        if self._rls.n_updates >= c.min_updates:
            b_hat, a_hat = self.estimates
            gains = nlpi_gains(b_hat, a_hat, c.zeta, c.wn)
            if gains != self._pi.gains:
                self._pi.set_gains(gains)
        result = self._pi.step(sp, hv, good)
        b_hat, a_hat = self.estimates
        return AdaptiveNlPiStepResult(
            control=result,
            b_hat=b_hat,
            a_prime_hat=a_hat,
            updated=updated,
            gains=self._pi.gains,
            covariance_trace=self._rls.trace,
        )
