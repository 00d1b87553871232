"""Fault detection and isolation (FDI): a bank of windowed GLR tests on a nonlinear observer.

Method (docs/fdi.md, decision 0058). Pure: scan in, report out; no clock, no I/O.

**Residual.** A fixed-gain observer runs the supervisor's nonlinear plant model (the plant's own
:class:`plant_sim.models.TankNetwork`, RK4 over one PLC scan ``Ts``) with the pump commands the
PLC applied (the known inflows) and corrects each level with its reading:

    x(k|k-1) = F(x(k-1|k-1), u(k-1))                   (levels h, lagged pump flows)
    eps(k)   = y(k) - x(k|k-1)                         innovation [m], per transmitter
    x(k|k)   = x(k|k-1) + L eps(k)                     L = diag(l), 0 < l < 1

Without a fault and with white transmitter noise ``v ~ N(0, s^2)`` (``s^2 = sigma^2 + q^2/12``,
the configured noise and quantization) the innovation has the variance
``s_e^2 = s^2 (1 + l / (2 - l))`` (the observer error ``e = (1 - l) e - l v`` has the variance
``l s^2 / (2 - l)`` for ``J ~ I``); its spectrum vanishes at zero frequency (the observer is an
integrator of the innovations), so sums of innovations have less variance than white noise
of that variance: the thresholds below, set for white noise, are conservative.

**Fault signatures.** Each hypothesis ``f`` with an unknown size ``theta`` (scalar) and onset
``tau`` changes the innovations' mean by ``theta g_f(k; tau)``. With ``e(k|k-1)`` the observer's
state error, ``m(k)`` a measurement fault and ``w(k)`` a process fault per scan, to first order
(``J = dF/dh`` at the estimate, by finite differences every scan):

    g(k)       = e(k|k-1) + m(k)
    e(k+1|k)   = J ((I - L) e(k|k-1) - L m(k)) + w(k),         e(tau|tau-1) = 0

- leak in tank i (theta = leak opening 0..1): ``w = -Ts c_Li sqrt(h_i) / A_i`` on tank i;
- clog of valve V from tank i to j or the drain (theta = fraction of its nominal opening lost):
  ``w = +Ts q_V / A_i`` on i and ``-Ts q_V / A_j`` on j (``q_V`` the nominal valve flow);
- pump degradation of pump p into tank i (theta = fraction of its flow lost, the delivered
  fraction is 1 - theta): ``w = -Ts Q_p / A_i``;
- transmitter bias on LTi (theta = b [m]): ``m = e_i``;
- transmitter drift on LTi (theta = rate [m/s]): ``m = (k - tau + 1) Ts e_i``.

**Test (GLR, Willsky and Jones 1976).** For each hypothesis and each onset in a sliding window
of ``N`` scans, with ``W = diag(1 / s_e^2)``:

    S1 = sum_{k >= tau} g' W eps,      S2 = sum_{k >= tau} g' W g
    theta_hat = S1 / S2,  sd(theta_hat) = 1 / sqrt(S2),  lambda = S1^2 / S2   (= 2 ln LR)

maximised over the onsets; leaks, clogs and pump degradation are one-sided (theta >= 0). Under
no fault and a fixed onset lambda is chi-square with one degree of freedom. **Threshold:** a
target of ``a`` false alarms per day gives a per-scan rate ``alpha = a Ts / 86400 s``; shared
over the ``H`` hypotheses and ``N`` onsets (Bonferroni, conservative):

    lambda_thr = chi2_1.isf(alpha / (H N))          (a = 1/day, Ts = 1 s, H = 17, N = 60: 32.5)

**Isolation.** A fault is *detected* when some lambda reaches the threshold; it is *isolated*
when the same hypothesis keeps the configured posterior confidence (equal priors, the GLR as the
likelihood, ``p_f = exp(lambda_f / 2) / sum_g exp(lambda_g / 2)``) for ``confirm_scans`` scans in
a row. The model is not exact to first order for large faults (the signatures are linearised
at the estimate), so the likelihoods are tempered by the evidence: ``p_f ~ exp(lambda_f / (2 T))``
with ``T = max(1, lambda_max / (4 lambda_thr))``: near the threshold the plain posterior, far
above it hypotheses must differ in proportion (a leak in a pumped tank and its pump's loss, both
a constant outflow at a steady state, stay *detected* and unnamed until the flows move). Its
size is ``theta_hat`` of the best onset, with ``sd(theta_hat)``. The diagnosis is
latched until a restart (a bias's onset leaves the window after N scans, and what remains of it,
the model's outflow computed from a biased level, looks like a clog: re-deciding then would
rename a diagnosed bias).

**Stuck and bad readings.** A stuck transmitter repeats its reading exactly. Two noisy readings
of a constant level repeat with probability at most ``p = P(|v1 - v2| < q) = 2 Phi(q / (sqrt 2 sigma)) - 1``
(``q > 0``; with ``q = 0``, zero), so a run of ``n_s = ceil(ln(alpha / n) / ln p)`` repeats (at
least 3) has a false-alarm rate below ``alpha / n`` per transmitter; a non-finite or bad reading
for ``n_bad`` scans in a row is the same fault (the reading is unusable). A missing reading is not
fed to the observer (that tank runs open loop) and contributes nothing to the tests.

**Warm-up.** The observer starts at the first readings; for ``warmup_s`` nothing is declared
(a restarted supervisor starts afresh: no false alarm on start). A hypothesis the site cannot
have (no V32 on a two-tank site, no leak valve) is simply absent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2, norm

from plant_sim.integrate import step_rk4
from plant_sim.models import DRAIN, PlantInputs, TankNetwork, default_inputs
from tanklab.config import SiteConfig
from tanklab.fdi_model import FaultKind, FdiState, hypothesis_name, site_hypotheses, transmitter_of

__all__ = ["Diagnosis", "FaultKind", "FdiConfig", "FdiCore", "FdiReport", "FdiState", "Hypothesis"]

FloatArray = NDArray[np.float64]
SECONDS_PER_DAY = 86400.0


SIZE_UNIT = {
    FaultKind.LEAK: "opening",
    FaultKind.CLOG: "fraction lost",
    FaultKind.PUMP: "fraction delivered",
    FaultKind.BIAS: "m",
    FaultKind.DRIFT: "m/s",
    FaultKind.STUCK: "m",
}
"""The unit of each fault class's size."""


@dataclass(frozen=True)
class FdiConfig:
    """Settings of the diagnosis (defaults: docs/fdi.md).

    Attributes
    ----------
    observer_gain : l, the observer's correction gain per scan (0..1): 0.1 averages about 10
        scans, so a leak's innovation builds up within 10 to 20 s.
    window_scans : N, onsets searched (scans): 60, one minute at Ts = 1 s.
    false_alarms_per_day : a, target false-alarm rate of the whole bank [1/day].
    confidence : posterior needed to isolate (0..1).
    warmup_s : nothing is declared for this long after a (re)start [s].
    noise_floor_m : lower bound of the transmitter noise used (a noise-free simulated transmitter
        would give an infinite weight to rounding) [m].
    bad_scans : bad or non-finite readings in a row that diagnose a transmitter as stuck/bad.
    confirm_scans : scans in a row the same hypothesis must keep the confidence to be isolated
        (a leak and a pump's loss in the same tank look alike until the flows move: a momentary
        lead of one of them is not a diagnosis).
    """

    observer_gain: float = 0.1
    window_scans: int = 60
    false_alarms_per_day: float = 1.0
    confidence: float = 0.95
    warmup_s: float = 30.0
    noise_floor_m: float = 1e-4
    bad_scans: int = 3
    confirm_scans: int = 10

    def __post_init__(self) -> None:
        if not 0.0 < self.observer_gain < 1.0:
            raise ValueError(f"fdi observer_gain must lie in (0, 1), got {self.observer_gain}")
        if self.window_scans < 2:
            raise ValueError(f"fdi window_scans must be at least 2, got {self.window_scans}")
        if not self.false_alarms_per_day > 0.0:
            raise ValueError(f"fdi false_alarms_per_day must be positive, got {self.false_alarms_per_day}")
        if not 0.5 <= self.confidence < 1.0:
            raise ValueError(f"fdi confidence must lie in [0.5, 1), got {self.confidence}")


@dataclass(frozen=True)
class Hypothesis:
    """One fault hypothesis: its class, the element it names (tank, valve, pump, transmitter)."""

    kind: FaultKind
    element: str

    @property
    def name(self) -> str:
        """``Leak_T1``, ``Clog_V13``, ``Pump_P1``, ``Bias_LT1``, ``Drift_LT1``, ``Stuck_LT1``."""
        return hypothesis_name(self.kind, self.element)


@dataclass(frozen=True)
class HypothesisStatus:
    """One hypothesis' test: statistic lambda (2 ln LR), threshold, state (0 normal, 1 alarm),
    size estimate and its standard deviation (units: :data:`SIZE_UNIT`)."""

    hypothesis: Hypothesis
    statistic: float
    threshold: float
    alarm: bool
    size: float
    size_std: float


@dataclass(frozen=True)
class Diagnosis:
    """The isolated fault: hypothesis, size (units: :data:`SIZE_UNIT`) with its standard
    deviation, the posterior confidence 0..1, and the model time it was isolated [s]."""

    hypothesis: Hypothesis
    size: float
    size_std: float
    confidence: float
    t_s: float

    @property
    def message(self) -> str:
        """A condition's message, e.g. ``FDI leak T1 est. opening 0.21 +- 0.02``."""
        unit = SIZE_UNIT[self.hypothesis.kind]
        kind = self.hypothesis.kind.name.lower()
        if self.hypothesis.kind is FaultKind.PUMP:
            value = f"{unit} {self.size:.2f} +- {self.size_std:.2f}"
        elif unit in ("m", "m/s"):
            value = f"{self.size:.3g} {unit} +- {self.size_std:.2g}"
        else:
            value = f"{unit} {self.size:.2f} +- {self.size_std:.2f}"
        return f"FDI {kind} {self.hypothesis.element} est. {value} (confidence {self.confidence:.2f})"


@dataclass(frozen=True)
class FdiReport:
    """What the diagnosis publishes after a scan: per hypothesis its test, the state, the best
    hypothesis and its confidence, and the latched diagnosis (None: none)."""

    t_s: float
    state: FdiState
    hypotheses: tuple[HypothesisStatus, ...]
    best: Hypothesis | None
    confidence: float
    diagnosis: Diagnosis | None


def glr_threshold(false_alarms_per_day: float, ts_s: float, n_hypotheses: int, window: int) -> float:
    """lambda_thr = chi2_1.isf(a Ts / 86400 / (H N)) (module docstring)."""
    alpha = false_alarms_per_day * ts_s / SECONDS_PER_DAY
    return float(chi2.isf(alpha / (n_hypotheses * window), df=1))


def stuck_run(noise_std_m: float, quantization_m: float, alpha: float) -> int | None:
    """Repeats of an exact reading that diagnose a stuck transmitter with a false-alarm rate below
    ``alpha`` per scan (module docstring); None when the noise cannot tell (no noise)."""
    if noise_std_m <= 0.0:
        return None
    if quantization_m <= 0.0:
        return 3
    p = float(2.0 * norm.cdf(quantization_m / (math.sqrt(2.0) * noise_std_m)) - 1.0)
    if p >= 0.999:
        return None
    return max(3, math.ceil(math.log(alpha) / math.log(p)))


class FdiCore:
    """The diagnosis of a site, fed every PLC scan (:meth:`step`).

    Parameters
    ----------
    site : the site (its plant section is the model; its PLC loops say which pump each MV drives).
    config : the settings (:class:`FdiConfig`).
    """

    def __init__(self, site: SiteConfig, config: FdiConfig | None = None) -> None:
        if site.plc is None:
            raise ValueError(f"site {site.name!r} has no plc section")
        self.site = site
        self.cfg = config or FdiConfig()
        self.net = TankNetwork.from_config(site.plant)
        self.ts_s = site.plc.scan_period_s
        net = self.net
        self.n = net.n_tanks
        inputs = default_inputs(net, site.plant)
        self._valves = inputs.valve_openings.copy()  # nominal openings (the model's)
        self._leaks = np.zeros(self.n)
        self._dist = np.zeros(self.n)
        self._cmd0 = inputs.pump_commands.copy()
        pumps = list(net.pump_names)
        self.loop_pump = [pumps.index(lp.actuator) for lp in site.plc.loops]
        tx = [t.transmitter for t in site.plant.tanks]
        sigma = np.array([max(t.noise_std_m, self.cfg.noise_floor_m) for t in tx])
        q = np.array([t.quantization_m for t in tx])
        s2 = sigma**2 + q**2 / 12.0
        lg = self.cfg.observer_gain
        self.innovation_var_m2 = s2 * (1.0 + lg / (2.0 - lg))
        self._w = 1.0 / self.innovation_var_m2
        # the hypotheses the site can have (tanklab.fdi_model, shared with the tag contract)
        every = [Hypothesis(k, e) for k, e in site_hypotheses(site)]
        self.transmitters = [transmitter_of(t) for t in net.tank_names]
        hyp = [h for h in every if h.kind is not FaultKind.STUCK]
        self.glr = hyp
        self.stuck = [h for h in every if h.kind is FaultKind.STUCK]
        self.hypotheses = tuple(hyp + self.stuck)
        self.threshold = glr_threshold(
            self.cfg.false_alarms_per_day, self.ts_s, len(hyp), self.cfg.window_scans
        )
        alpha = self.cfg.false_alarms_per_day * self.ts_s / SECONDS_PER_DAY / self.n
        self.stuck_runs = [stuck_run(float(t.noise_std_m), float(t.quantization_m), alpha) for t in tx]
        self._one_sided = np.array([h.kind in (FaultKind.LEAK, FaultKind.CLOG, FaultKind.PUMP) for h in hyp])
        # measurement-fault directions: bias m = e_i, drift m = age Ts e_i
        self._m_dir = np.zeros((len(hyp), self.n))
        self._is_drift = np.zeros(len(hyp), dtype=bool)
        for k, h in enumerate(hyp):
            if h.kind in (FaultKind.BIAS, FaultKind.DRIFT):
                self._m_dir[k, self.transmitters.index(h.element)] = 1.0
                self._is_drift[k] = h.kind is FaultKind.DRIFT
        self.reset()

    # ---- state --------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget everything (a restart): the observer restarts at the next readings, warm-up."""
        h_n, w_n = len(self.glr), self.cfg.window_scans
        self.x: FloatArray | None = None
        self.u: FloatArray = self._cmd0.copy()
        self.last_scan: int | None = None
        self.t0_s: float | None = None
        self.e = np.zeros((h_n, w_n, self.n))  # e(k|k-1) per hypothesis and onset (unit size)
        self.age = np.full(w_n, -1, dtype=np.int64)  # scans since each onset (-1: empty slot)
        self.steps = 0  # onsets started (the ring buffer's write position)
        self.s1 = np.zeros((h_n, w_n))
        self.s2 = np.zeros((h_n, w_n))
        self.last_y = np.full(self.n, np.nan)
        self.repeats = np.zeros(self.n, dtype=np.int64)
        self.bad = np.zeros(self.n, dtype=np.int64)
        self.diagnosis: Diagnosis | None = None
        self.leader: int | None = None  # the hypothesis confidently ahead, and for how many scans
        self.lead_scans = 0
        self.report: FdiReport | None = None

    # ---- the model ----------------------------------------------------------------------

    def _inputs(self, commands: FloatArray) -> PlantInputs:
        return PlantInputs(commands, self._valves, self._leaks, self._dist)

    def _predict(self, x: FloatArray, commands: FloatArray, scans: int) -> FloatArray:
        return step_rk4(self.net, x, self._inputs(commands), scans * self.ts_s)

    def _jacobian(self, x: FloatArray, x_next: FloatArray, commands: FloatArray) -> FloatArray:
        """J = d h(k+1) / d h(k) of the one-scan map, by forward differences (1 mm)."""
        n = self.n
        jac = np.empty((n, n))
        for i in range(n):
            xi = x.copy()
            dh = 1e-3 if x[i] + 1e-3 <= self.net.hmax_m[i] else -1e-3
            xi[i] += dh
            jac[:, i] = (self._predict(xi, commands, 1)[:n] - x_next[:n]) / dh
        return jac

    def _process_directions(self, x: FloatArray) -> FloatArray:
        """w per unit fault size for every hypothesis (rows), levels per scan [m]."""
        net, n = self.net, self.n
        h = np.maximum(x[:n], 0.0)
        w = np.zeros((len(self.glr), n))
        q_v = net.valve_flows(h, self._valves)
        q_p = np.where(net.pump_lag_s > 0.0, net.pump_flows(x), net.pump_target_flows(self.u))
        ts_a = self.ts_s / net.area_m2
        for k, hy in enumerate(self.glr):
            if hy.kind is FaultKind.LEAK:
                i = net.tank_names.index(hy.element)
                w[k, i] = -ts_a[i] * net.leak_conductance[i] * math.sqrt(h[i])
            elif hy.kind is FaultKind.CLOG:
                v = net.valve_names.index(hy.element)
                up, down = int(net.valve_up[v]), int(net.valve_down[v])
                w[k, up] = ts_a[up] * q_v[v]
                if down != DRAIN:
                    w[k, down] = -ts_a[down] * q_v[v]
            elif hy.kind is FaultKind.PUMP:
                p = net.pump_names.index(hy.element)
                i = int(net.pump_tank[p])
                w[k, i] = -ts_a[i] * q_p[p]
        return w

    # ---- one scan -----------------------------------------------------------------------

    def step(
        self, scan: int, t_s: float, levels_m: FloatArray, good: NDArray[np.bool_], mv: FloatArray
    ) -> FdiReport:
        """Fold one PLC scan in: the levels it read (with their quality) and the MVs it applied
        (loop order, pump units; they act until the next scan). Returns the report."""
        y = np.asarray(levels_m, dtype=float)
        ok = np.asarray(good, dtype=bool) & np.isfinite(y)
        self._stuck_counts(y, ok)
        if self.x is None:
            if not bool(np.all(ok)):
                self._remember(scan, t_s, mv)
                return self._publish(t_s)
            self.x = self.net.initial_state(y, self.net.pump_target_flows(self.u))
            self.t0_s = t_s
        else:
            gap = 1 if self.last_scan is None else max(1, scan - self.last_scan)
            x_prev = self.x
            x_pred = self._predict(x_prev, self.u, gap)
            jac = self._jacobian(x_prev, x_pred, self.u) if gap == 1 else None
            eps = np.where(ok, y - x_pred[: self.n], 0.0)
            self._glr_update(eps, ok, x_prev, jac)
            lg = self.cfg.observer_gain
            x_pred[: self.n] += np.where(ok, lg * eps, 0.0)
            self.x = x_pred
        self._remember(scan, t_s, mv)
        return self._publish(t_s)

    def _remember(self, scan: int, t_s: float, mv: FloatArray) -> None:
        u = self._cmd0.copy()
        for j, p in enumerate(self.loop_pump):
            if math.isfinite(float(mv[j])):
                u[p] = float(mv[j])
        self.u = u
        self.last_scan = scan

    def _stuck_counts(self, y: FloatArray, ok: NDArray[np.bool_]) -> None:
        same = ok & (y == self.last_y)
        self.repeats = np.where(same, self.repeats + 1, 0)
        self.bad = np.where(ok, 0, self.bad + 1)
        self.last_y = np.where(ok, y, self.last_y)

    def _glr_update(
        self, eps: FloatArray, ok: NDArray[np.bool_], x_prev: FloatArray, jac: FloatArray | None
    ) -> None:
        """Advance every (hypothesis, onset) signature and its sums by one scan."""
        if jac is None:  # a gap in the scans: the signatures no longer hold; start the window afresh
            self.age[:] = -1
            self.e[:] = 0.0
            self.s1[:] = 0.0
            self.s2[:] = 0.0
            return
        # a new onset in the oldest slot
        slot = self.steps % self.cfg.window_scans
        self.steps += 1
        self.age[slot] = 0
        self.e[:, slot, :] = 0.0
        self.s1[:, slot] = 0.0
        self.s2[:, slot] = 0.0
        live = self.age >= 0
        ages = np.where(live, self.age, 0).astype(float)
        # measurement faults m (H, N, n)
        scale = np.where(self._is_drift[:, None], (ages[None, :] + 1.0) * self.ts_s, 1.0)
        m = self._m_dir[:, None, :] * scale[:, :, None]
        g = self.e + m
        w_ok = np.where(ok, self._w, 0.0)
        self.s1 += np.einsum("hwn,n->hw", g, w_ok * eps)
        self.s2 += np.einsum("hwn,n->hw", g * g, w_ok)
        self.s1[:, ~live] = 0.0
        self.s2[:, ~live] = 0.0
        lg = np.where(ok, self.cfg.observer_gain, 0.0)
        corr = (1.0 - lg) * self.e - lg * m
        w = self._process_directions(x_prev)
        self.e = np.einsum("ij,hwj->hwi", jac, corr) + w[:, None, :]
        self.age = np.where(live, self.age + 1, -1)

    # ---- the decision -------------------------------------------------------------------

    def _tests(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(lambda, theta_hat, sd) per GLR hypothesis, maximised over the onsets."""
        s2 = np.where(self.s2 > 0.0, self.s2, np.inf)
        theta = self.s1 / s2
        lam = self.s1 * theta
        lam = np.where(self._one_sided[:, None] & (theta < 0.0), 0.0, lam)
        best = np.argmax(lam, axis=1)
        rows = np.arange(len(self.glr))
        lam_b = lam[rows, best]
        th_b = theta[rows, best]
        sd_b = 1.0 / np.sqrt(s2[rows, best])
        return lam_b, th_b, sd_b

    def _publish(self, t_s: float) -> FdiReport:
        lam, theta, sd = self._tests()
        warm = self.t0_s is None or t_s - self.t0_s < self.cfg.warmup_s
        if warm:
            lam = np.zeros_like(lam)
        statuses: list[HypothesisStatus] = []
        for k, hy in enumerate(self.glr):
            size, size_sd = float(theta[k]), float(sd[k])
            if hy.kind is FaultKind.PUMP:
                size = 1.0 - size
            statuses.append(
                HypothesisStatus(
                    hy,
                    _fin(float(lam[k])),
                    self.threshold,
                    bool(lam[k] >= self.threshold),
                    _fin(size),
                    _fin(size_sd),
                )
            )
        stuck_diag: Diagnosis | None = None
        for i, hy in enumerate(self.stuck):
            run = self.stuck_runs[i]
            rep = int(self.repeats[i]) + 1
            alarm = (run is not None and rep >= run) or int(self.bad[i]) >= self.cfg.bad_scans
            limit = float(run if run is not None else self.cfg.bad_scans)
            stat = float(max(rep if run is not None else 0, int(self.bad[i])))
            value = float(self.last_y[i]) if math.isfinite(float(self.last_y[i])) else 0.0
            statuses.append(HypothesisStatus(hy, stat, limit, bool(alarm and not warm), value, 0.0))
            if alarm and stuck_diag is None and self.t0_s is not None and not warm:
                stuck_diag = Diagnosis(hy, value, 0.0, 1.0, t_s)
        # posterior over the GLR hypotheses (equal priors)
        # tempered by the evidence (module docstring): temp = max(1, lambda_best / (4 lambda_thr))
        temp = max(1.0, float(np.max(lam)) / (4.0 * self.threshold))
        z = (lam - float(np.max(lam))) / (2.0 * temp)
        post = np.exp(z) / float(np.sum(np.exp(z)))
        b = int(np.argmax(lam))
        detected = bool(lam[b] >= self.threshold)
        conf = float(post[b]) if detected else 0.0
        if detected and conf >= self.cfg.confidence:
            self.lead_scans = self.lead_scans + 1 if self.leader == b else 1
            self.leader = b
        else:
            self.leader, self.lead_scans = None, 0
        if self.diagnosis is None:
            if stuck_diag is not None:
                self.diagnosis = stuck_diag
            elif self.lead_scans >= self.cfg.confirm_scans:
                st = statuses[b]
                self.diagnosis = Diagnosis(self.glr[b], st.size, st.size_std, conf, t_s)
        if warm:
            state = FdiState.WARMUP
        elif self.diagnosis is not None:
            state = FdiState.ISOLATED
        elif detected:
            state = FdiState.DETECTED
        else:
            state = FdiState.NORMAL
        self.report = FdiReport(
            t_s=t_s,
            state=state,
            hypotheses=tuple(statuses),
            best=self.glr[b] if detected else None,
            confidence=conf,
            diagnosis=self.diagnosis,
        )
        return self.report


def _fin(x: float) -> float:
    """A finite value for OPC UA (NaN and infinities as 0)."""
    return x if math.isfinite(x) else 0.0
