"""Pure tuning rules for the soft PLC's blocks.

All times are in seconds; process gains are in PV units per MV unit (e.g. m per m^3/s).

IMC PI / PID for a second-order lag with an IMC filter 1 / (lambda s + 1) (digest 2.7)::

    g(s) = K / ((tau1 s + 1)(tau2 s + 1))
    Kc = (tau1 + tau2) / (K lambda),   Ti = tau1 + tau2,   Td = tau1 tau2 / (tau1 + tau2)   (PI: Td = 0)

A denominator a2 s^2 + a1 s + a0 (a0 != 0) with numerator ``num`` is normalised to
K = num / a0 and (tau1 s + 1)(tau2 s + 1) with tau1 + tau2 = a1 / a0 and tau1 tau2 = a2 / a0;
complex or unstable roots have no such factorisation and raise ``ValueError``.
For 28.82 / (29.6 s^2 + 14.7 s + 1) and lambda = 1: tau = 2.408 and 12.292 s, Kc = 0.5101,
Ti = 14.700 s, Td = 2.014 s (the paper's 0.5091 / 14.714 come from using 28.89 in one equation).

Nonlinear (feedback-linearized) PI for dh/dt = b u - a' sqrt(h) (digest 2.2)::

    Kp = 2 zeta wn / b,   Ki = wn^2 / b,   Kl = a' / b
    zeta = -ln(OS) / sqrt(pi^2 + ln(OS)^2)      (OS: fractional overshoot)
    wn = 4.6 / (zeta ts)                        (ts: 1 % settling time; the paper's "4.6/(zeta wn)" is a slip)

Ziegler-Nichols open loop (reaction curve) for a FOPDT model K e^{-theta s} / (tau s + 1)::

    P:   Kc = tau / (K theta)
    PI:  Kc = 0.9 tau / (K theta),  Ti = 3.33 theta
    PID: Kc = 1.2 tau / (K theta),  Ti = 2 theta,  Td = 0.5 theta

Ideal (Kc, Ti, Td) to the velocity-form gains of ``plc_emulator.pid`` (``tanklab.gains.LoopGains``)::

    Kp = Kc,   Ki = Kc / Ti,   Kd = Kc Td        (Ti = inf gives Ki = 0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from tanklab.checks import finite as _finite
from tanklab.checks import non_negative as _non_negative
from tanklab.checks import positive as _positive
from tanklab.gains import LoopGains

__all__ = [
    "ImcTuning",
    "NlPiGains",
    "PidParams",
    "SecondOrderSpec",
    "VelocityGains",
    "imc_from_denominator",
    "imc_from_taus",
    "nlpi_gains",
    "nlpi_gains_from_spec",
    "spec_to_zeta_wn",
    "velocity_gains",
    "ziegler_nichols_open_loop",
]

ZnKind = Literal["p", "pi", "pid"]


VelocityGains = LoopGains
"""The velocity-form gains the rules produce: the kernel's `tanklab.gains.LoopGains` (this name
is kept for callers; decision 0030)."""


@dataclass(frozen=True)
class PidParams:
    """Ideal (ISA) PID parameters ``Kc (e + (1/Ti) int e dt + Td de/dt)``.

    Attributes
    ----------
    Kc : float
        Controller gain [MV unit per PV unit].
    Ti : float
        Integral time [s]; ``math.inf`` for no integral action.
    Td : float
        Derivative time [s]; 0 for no derivative action.
    """

    Kc: float
    Ti: float
    Td: float

    def to_velocity(self) -> LoopGains:
        """Return the velocity-form gains (Kp, Ki, Kd) = (Kc, Kc / Ti, Kc Td)."""
        return velocity_gains(self.Kc, self.Ti, self.Td)


@dataclass(frozen=True)
class ImcTuning:
    """IMC PI / PID tuning of K / ((tau1 s + 1)(tau2 s + 1)) with filter 1 / (lambda s + 1).

    Attributes
    ----------
    Kc : float
        Controller gain [MV unit per PV unit].
    Ti : float
        Integral time [s].
    Td : float
        Derivative time [s] (0 for the PI).
    tau1, tau2 : float
        Time constants of the model [s], ``tau1 <= tau2`` (``tau1`` is 0 for a first-order model).
    K : float
        Steady-state gain of the model [PV unit per MV unit].
    lam : float
        IMC filter time constant lambda [s].
    """

    Kc: float
    Ti: float
    Td: float
    tau1: float
    tau2: float
    K: float
    lam: float

    @property
    def params(self) -> PidParams:
        """The (Kc, Ti, Td) triple."""
        return PidParams(self.Kc, self.Ti, self.Td)


@dataclass(frozen=True)
class SecondOrderSpec:
    """Damping ratio and natural frequency of wn^2 / (s^2 + 2 zeta wn s + wn^2).

    Attributes
    ----------
    zeta : float
        Damping ratio [-].
    wn : float
        Natural frequency [rad/s].
    """

    zeta: float
    wn: float


@dataclass(frozen=True)
class NlPiGains:
    """Gains of the feedback-linearized PI ``u = Ki I - Kp h + Kl sqrt(h)``.

    Attributes
    ----------
    Kp : float
        Gain on the level [MV unit per m], >= 0.
    Ki : float
        Gain on the integrated error [MV unit per (m s)], > 0.
    Kl : float
        Gain of the outflow cancellation [MV unit per sqrt(m)], >= 0.
    """

    Kp: float
    Ki: float
    Kl: float

    def __post_init__(self) -> None:
        _non_negative("Kp", self.Kp)
        _positive("Ki", self.Ki)
        _non_negative("Kl", self.Kl)


def velocity_gains(Kc: float, Ti: float, Td: float = 0.0) -> LoopGains:
    """Convert ideal PID parameters to velocity-form gains.

    Parameters
    ----------
    Kc : float
        Controller gain [MV unit per PV unit] (any finite sign: the sign sets the action).
    Ti : float
        Integral time [s], > 0; ``math.inf`` gives Ki = 0.
    Td : float
        Derivative time [s], >= 0.

    Returns
    -------
    LoopGains
        ``Kp = Kc``, ``Ki = Kc / Ti``, ``Kd = Kc Td``.
    """
    kc = _finite("Kc", Kc)
    if isinstance(Ti, bool) or not isinstance(Ti, int | float):
        raise TypeError(f"Ti must be a real number, got {type(Ti).__name__}")
    ti = float(Ti)
    if math.isnan(ti) or ti <= 0.0:
        raise ValueError(f"Ti must be > 0 (inf for no integral action), got {ti}")
    td = _non_negative("Td", Td)
    return LoopGains(kp=kc, ki=0.0 if math.isinf(ti) else kc / ti, kd=kc * td)


def imc_from_taus(K: float, tau1: float, tau2: float, lam: float, *, pid: bool = True) -> ImcTuning:
    """IMC PI / PID for K / ((tau1 s + 1)(tau2 s + 1)).

    Parameters
    ----------
    K : float
        Steady-state gain, nonzero [PV unit per MV unit].
    tau1, tau2 : float
        Time constants [s], >= 0 with tau1 + tau2 > 0 (one of them 0 is a first-order model).
    lam : float
        IMC filter time constant [s], > 0.
    pid : bool
        True for the PID, False for the PI (Td = 0).

    Returns
    -------
    ImcTuning
        With ``tau1 <= tau2``.
    """
    k = _finite("K", K)
    if k == 0.0:
        raise ValueError("K must be nonzero")
    t1 = _non_negative("tau1", tau1)
    t2 = _non_negative("tau2", tau2)
    if t1 + t2 <= 0.0:
        raise ValueError("tau1 + tau2 must be > 0")
    lam_ = _positive("lam", lam)
    t1, t2 = sorted((t1, t2))
    ti = t1 + t2
    td = t1 * t2 / ti if pid else 0.0
    return ImcTuning(Kc=ti / (k * lam_), Ti=ti, Td=td, tau1=t1, tau2=t2, K=k, lam=lam_)


def imc_from_denominator(num: float, den: tuple[float, ...], lam: float, *, pid: bool = True) -> ImcTuning:
    """IMC PI / PID for num / (a2 s^2 + a1 s + a0) (or num / (a1 s + a0)).

    Parameters
    ----------
    num : float
        Numerator (a constant), nonzero.
    den : tuple of float, length 2 or 3
        Denominator coefficients, highest power first: ``(a2, a1, a0)`` or ``(a1, a0)``, a0 != 0.
    lam : float
        IMC filter time constant [s], > 0.
    pid : bool
        True for the PID, False for the PI.

    Returns
    -------
    ImcTuning
        K = num / a0 and the factorised time constants.

    Raises
    ------
    ValueError
        If the roots are complex (no real time constants), a root is unstable or at the origin,
        or a coefficient is not finite.
    """
    n = _finite("num", num)
    if len(den) not in {2, 3}:
        raise ValueError(f"den must have 2 or 3 coefficients (highest power first), got {len(den)}")
    coeffs = [_finite(f"den[{i}]", c) for i, c in enumerate(den)]
    if len(coeffs) == 2:
        coeffs.insert(0, 0.0)
    a2, a1, a0 = coeffs
    if a0 == 0.0:
        raise ValueError("den's constant term a0 must be nonzero (a pole at s = 0 has no IMC PI/PID here)")
    s_sum, s_prod = a1 / a0, a2 / a0  # tau1 + tau2, tau1 tau2
    if s_prod < 0.0 or s_sum <= 0.0:
        raise ValueError(
            f"den {tuple(den)} has a root in the right half plane: need tau1 + tau2 = {s_sum:g} > 0 "
            f"and tau1 tau2 = {s_prod:g} >= 0"
        )
    disc = s_sum * s_sum - 4.0 * s_prod
    if disc < 0.0:
        raise ValueError(
            f"den {tuple(den)} has complex roots (discriminant {disc * a0 * a0:g} < 0): "
            "no real time constants tau1, tau2 exist"
        )
    root = math.sqrt(disc)
    tau2 = 0.5 * (s_sum + root)
    # tau1 from the product avoids cancellation when tau1 << tau2.
    tau1 = s_prod / tau2
    return imc_from_taus(n / a0, tau1, tau2, lam, pid=pid)


def ziegler_nichols_open_loop(K: float, theta: float, tau: float, kind: ZnKind = "pi") -> PidParams:
    """Ziegler-Nichols reaction-curve tuning from a FOPDT model K e^{-theta s} / (tau s + 1).

    Parameters
    ----------
    K : float
        Process gain, nonzero [PV unit per MV unit].
    theta : float
        Dead time [s], > 0.
    tau : float
        Time constant [s], > 0.
    kind : {"p", "pi", "pid"}
        Controller type.

    Returns
    -------
    PidParams
        ``Ti = inf`` for the P controller, ``Td = 0`` for P and PI.
    """
    k = _finite("K", K)
    if k == 0.0:
        raise ValueError("K must be nonzero")
    th = _positive("theta", theta)
    ta = _positive("tau", tau)
    base = ta / (k * th)
    if kind == "p":
        return PidParams(Kc=base, Ti=math.inf, Td=0.0)
    if kind == "pi":
        return PidParams(Kc=0.9 * base, Ti=3.33 * th, Td=0.0)
    if kind == "pid":
        return PidParams(Kc=1.2 * base, Ti=2.0 * th, Td=0.5 * th)
    raise ValueError(f"kind must be 'p', 'pi' or 'pid', got {kind!r}")


def spec_to_zeta_wn(overshoot_pct: float, settling_time_s: float) -> SecondOrderSpec:
    """Damping and natural frequency from a step-response specification.

    Parameters
    ----------
    overshoot_pct : float
        Percent overshoot, in (0, 100).
    settling_time_s : float
        Settling time [s] (the 4.6 / (zeta wn) rule, about a 1 % band), > 0.

    Returns
    -------
    SecondOrderSpec
        ``zeta = -ln(OS) / sqrt(pi^2 + ln(OS)^2)``, ``wn = 4.6 / (zeta ts)``.
    """
    os_pct = _finite("overshoot_pct", overshoot_pct)
    if not 0.0 < os_pct < 100.0:
        raise ValueError(f"overshoot_pct must be in (0, 100), got {os_pct}")
    ts = _positive("settling_time_s", settling_time_s)
    ln_os = math.log(os_pct / 100.0)
    zeta = -ln_os / math.sqrt(math.pi**2 + ln_os**2)
    return SecondOrderSpec(zeta=zeta, wn=4.6 / (zeta * ts))


def nlpi_gains(b: float, a_prime: float, zeta: float, wn: float) -> NlPiGains:
    """Gains of the feedback-linearized PI for dh/dt = b u - a' sqrt(h).

    Parameters
    ----------
    b : float
        Input gain [m/s per MV unit], > 0.
    a_prime : float
        Outflow coefficient a' [sqrt(m)/s], >= 0.
    zeta : float
        Desired damping ratio, > 0.
    wn : float
        Desired natural frequency [rad/s], > 0.

    Returns
    -------
    NlPiGains
        ``Kp = 2 zeta wn / b``, ``Ki = wn^2 / b``, ``Kl = a' / b``.
    """
    b_ = _positive("b", b)
    a_ = _non_negative("a_prime", a_prime)
    z = _positive("zeta", zeta)
    w = _positive("wn", wn)
    return NlPiGains(Kp=2.0 * z * w / b_, Ki=w * w / b_, Kl=a_ / b_)


def nlpi_gains_from_spec(b: float, a_prime: float, overshoot_pct: float, settling_time_s: float) -> NlPiGains:
    """Nonlinear-PI gains from an overshoot [%] and settling time [s] (see `spec_to_zeta_wn`)."""
    spec = spec_to_zeta_wn(overshoot_pct, settling_time_s)
    return nlpi_gains(b, a_prime, spec.zeta, spec.wn)
