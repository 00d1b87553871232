"""The MPC-taught PID gain adapter: regression, estimator, proposals (seeds digest 2.1, 2.3, 2.4).

The PLC runs, every scan ``k`` of period ``Ts`` [s], the velocity-form MIMO PID (digest 2.1) with
``e_j = r_j - y_j`` (setpoint minus measured level, [m])::

    u_i(k) = u_i(k-1) + sum_j [ Kp_ij De_j(k) + Ki_ij Ts e_j(k) + (Kd_ij / Ts) D2e_j(k) ]
    De_j(k)  = e_j(k) - e_j(k-1),   D2e_j(k) = e_j(k) - 2 e_j(k-1) + e_j(k-2)

with ``u(k-1)`` the clamped, applied output. The supervisor's MPC runs in the shadow from the
measured state and proposes ``u_MPC(k)``. For each pump ``i`` an :class:`~tanklab.rls.ExpForgettingRls`
fits that pump's gains so that the PID increment reproduces the MPC's move from where the actuator
really is::

    y_i(k)   = u_i,MPC(k) - u_i,applied(k-1)                                  [pump unit]
    psi_i(k) = [ De_j, Ts e_j, D2e_j / Ts  for each loop j the pump uses ]
    theta_i  = [ Kp_ij, Ki_ij, Kd_ij       for each loop j the pump uses ]
    y_i(k)   = psi_i(k)' theta_i

Two corrections to the paper (digest 2.4): the third regressor slot is ``D2e / Ts`` (the paper's
``De / Ts`` makes the Kp and Kd columns proportional), and the target is the MPC input minus the
*applied* input (the paper's ``u_MPC(k) - u_MPC(k-1)`` is right only when the MPC drives).
Diagonal mode (default, the paper's and the PLC's ``SetGains(Kp, Ki, Kd)`` per loop) uses only the
pump's own loop; full MIMO uses every loop (``3 * n_loops`` parameters per pump).

The RLS runs on dimensionless parameters so one set of defaults fits every unit system: with
``E`` the error scale (config, units of ``e``) and ``U_i = u_max,i - u_min,i``::

    theta_hat = [Kp, Ki Ts, Kd / Ts] * E / U_i      x_hat = [De, e, D2e] / E      y_hat = y / U_i

so that ``x_hat' theta_hat = y_hat`` exactly.

The estimator (``estimator="prior"``, the default; ADR 0014, docs/adaptation.md 2.10) is
:class:`~supervisor.prior_rls.PriorRls`: least squares with a persistent prior at the model-based
tuning and directional forgetting::

    theta_i = argmin  sum_s w(s) (y_hat(s) - x_hat(s)' theta)^2 + (theta - theta_p)' L0 (theta - theta_p)
    L0      = diag(prior_weight / sigma^2),  sigma = max(|theta_p|, |theta_fixed|, floors)

so its information matrix is never below ``L0`` (bounded condition number) and where the data say
nothing the estimate is the prior. The prior ``theta_p`` is the SIMC PI of each own tank's
first-order model (:func:`model_based_gains`)::

    Kp = tau / (K (tau_c + Ts / 2)),   Ki = Kp / min(tau, 4 (tau_c + Ts / 2)),   Kd = 0

``estimator="rls"`` keeps the former :class:`~tanklab.rls.ExpForgettingRls` from the fixed gains.

When ``u_MPC,i`` sits at a bound of its input range (within ``saturation_band``), the sample is
an inequality, not an equality: the clamped MPC wants *at least* ``u_MPC,i`` (at ``u_min``: at
most), so the PID's move must satisfy ``psi_i' theta_i >= y_i`` (``<= y_i`` at ``u_min``). With
``saturated="one_sided"`` (default) an estimate that already satisfies it learns nothing, and one
that violates it is projected onto the boundary ``psi_i' theta_i = y_i`` in the metric of the RLS
covariance, ``P`` itself left unchanged (:meth:`tanklab.rls.ExpForgettingRls.constrain`): an
inequality bounds the parameters without measuring them. Dropping these samples (``"drop"``, the
former default) starves the fit while the MPC fills a tank at Qmax; fitting them as equalities
(``"equality"``) drags the gains toward the clamped move (digest 2.4's collapse).

With the prior estimator a violated inequality is absorbed as an equality sample instead (it is
weighed against the prior; a projection would override it).

Transmitter noise, estimated per loop (:mod:`supervisor.adaptation.noise`), limits each pump's
loop gain to ``Kp <= noise_move_budget U / (sqrt(2) sigma)`` (the whole own-loop target is
scaled) and raises the dead zone to ``17 sigma / E``.

A candidate gain set (all pumps) is proposed every push period: each ready pump moves from its
applied gains toward its estimate along one path (:mod:`supervisor.adaptation.path`), as far as
the rate limit lets every one of its gains go. It is returned for pushing only when it passes
every admissibility guard (:mod:`supervisor.adaptation.guards`), which replace the paper's
vacuous "u inside the input set" condition.

This module is pure: model time ``t_s`` [s] and the PLC scan counter are arguments; no clock, no
I/O, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from supervisor.adaptation._validate import FloatArray, matrix
from supervisor.adaptation.config import AdaptationConfig
from supervisor.adaptation.decisions import (
    AdapterDiagnostics,
    Decision,
    PumpDiagnostics,
    RejectReason,
    SampleStatus,
)
from supervisor.adaptation.guards import GainGuards, HorizonState
from supervisor.adaptation.limits import gain_limits
from supervisor.adaptation.model import LoopModel
from supervisor.adaptation.noise import NOISE_DEAD_ZONE, NoiseEstimate, hold_gain_limit
from supervisor.adaptation.path import gain_path_step
from supervisor.prior_rls import PriorRls
from tanklab.gains import GainBox, PidGains
from tanklab.rls import ExpForgettingRls

__all__ = ["PidGainAdapter"]


@dataclass
class _Reading:
    scan: int
    e: FloatArray  # (n_loops,)
    sp: FloatArray  # (n_loops,)
    mv: FloatArray  # (n_u,)
    x: FloatArray  # (n_x,)


@dataclass
class _Counters:
    formed: int = 0
    gap: int = 0
    invalid: int = 0
    duplicates: int = 0
    accepted: int = 0
    rejected: int = 0
    by_reason: dict[str, int] = field(default_factory=dict)
    last_reject: RejectReason | None = None


class PidGainAdapter:
    """MPC-taught PID gains for every pump, with admissibility guards (see the module doc).

    Call :meth:`observe` once per PLC scan with the readings of that scan (SP, PV, MV and the scan
    counter read together, and the MPC's input computed from the same state), and
    :meth:`propose` with the model time; a returned, accepted :class:`Decision` carries the gain
    set to push (the adapter then takes it as applied; call :meth:`set_applied` if the PLC
    refused it or holds other gains).

    Parameters
    ----------
    model : LoopModel
        ZOH linear model with the loops' output matrix and input bounds.
    fixed : PidGains
        The PLC's fixed gains, shape (n_u, n_loops): initial estimate and applied gains. Must pass
        the box and sign guards.
    config : AdaptationConfig, optional
        Defaults as documented there.

    Raises
    ------
    ValueError
        On inconsistent shapes, fixed gains outside the box or violating the sign guard, a box
        that excludes the sign guard's region, or an invalid ``own_loop``.
    """

    def __init__(self, model: LoopModel, fixed: PidGains, config: AdaptationConfig | None = None) -> None:
        if not isinstance(model, LoopModel):
            raise TypeError("model must be a LoopModel")
        if not isinstance(fixed, PidGains):
            raise TypeError("fixed must be PidGains")
        cfg = AdaptationConfig() if config is None else config
        self._model = model
        self._cfg = cfg
        m, nl = model.n_u, model.n_loops
        if fixed.shape != (m, nl):
            raise ValueError(f"fixed gains must have shape (n_u, n_loops) = {(m, nl)}, got {fixed.shape}")
        if not fixed.is_finite():
            raise ValueError("fixed gains must be finite")

        if cfg.own_loop is None:
            if m > nl:
                raise ValueError("own_loop must be given when there are more pumps than loops")
            own = tuple(range(m))
        else:
            own = tuple(int(j) for j in cfg.own_loop)
            if len(own) != m or any(not 0 <= j < nl for j in own):
                raise ValueError(f"own_loop must give one loop index in [0, {nl}) per pump ({m})")
        self._own = own
        # Loops each pump's RLS uses.
        self._loops: tuple[tuple[int, ...], ...] = tuple(
            tuple(range(nl)) if cfg.full_mimo else (own[i],) for i in range(m)
        )
        self._own_mask = np.zeros((m, nl), dtype=bool)
        self._own_mask[np.arange(m), own] = True
        self._adapt_mask = np.zeros((m, nl), dtype=bool)
        for i, loops in enumerate(self._loops):
            self._adapt_mask[i, list(loops)] = True

        lim = gain_limits(model, fixed, cfg, own, self._own_mask, self._adapt_mask)
        self._ki_min, self._box, self._prior = lim.ki_min, lim.box, PidGains.from_stacked(lim.prior)
        lo_phys, hi_phys, prior_g, row_scale = lim.lower, lim.upper, lim.prior, lim.row_scale
        g_fixed = fixed.stacked()  # (3, m, nl)
        self._guards = GainGuards(
            model,
            lim.box,
            own,
            lim.ki_min,
            lim.floor,
            cfg.max_change_fraction,
            cfg.max_spectral_radius,
            cfg.horizon_steps,
        )

        # One estimator per pump on dimensionless parameters.
        ts = model.ts_s
        lam = ExpForgettingRls.forgetting_from_memory(ts, cfg.memory_s)
        E = cfg.error_scale
        self._scale: list[FloatArray] = []
        self._rls: list[ExpForgettingRls | PriorRls] = []
        for i in range(m):
            U = float(model.u_max[i] - model.u_min[i])
            per_loop = np.array([E / U, ts * E / U, E / (ts * U)])
            s = np.tile(per_loop, len(self._loops[i]))
            self._scale.append(s)
            lower = self._pack(lo_phys, i) * s
            upper = self._pack(hi_phys, i) * s
            if cfg.estimator == "prior":
                theta_p = self._pack(prior_g, i) * s
                # Prior scale per parameter: the larger of the prior's and the fixed gain's size,
                # floored at a tenth of the row's scale of that gain type and at a tenth of the
                # pump's largest (the dimensionless parameters are comparable): a zero Kd with a
                # zero fixed Kd still has a scale.
                sigma = np.maximum.reduce(
                    [
                        np.abs(theta_p),
                        np.abs(self._pack(g_fixed, i) * s),
                        self._pack(0.1 * np.broadcast_to(row_scale, g_fixed.shape), i) * s,
                    ]
                )
                sigma = np.maximum(sigma, max(0.1 * float(sigma.max()), 1e-12))
                self._rls.append(
                    PriorRls(
                        theta_p,
                        cfg.prior_weight / sigma**2,
                        forgetting=lam,
                        excitation_threshold=cfg.excitation_threshold,
                        lower=lower,
                        upper=upper,
                    )
                )
            else:
                self._rls.append(
                    ExpForgettingRls(
                        s.size,
                        forgetting=lam,
                        p0=cfg.p0,
                        theta0=self._pack(g_fixed, i) * s,
                        trace_cap=cfg.trace_cap,
                        excitation_threshold=cfg.excitation_threshold,
                        lower=lower,
                        upper=upper,
                    )
                )

        self._fixed = fixed
        self._applied = fixed
        self._natural = np.maximum(np.abs(prior_g), np.abs(g_fixed))
        self._noise = NoiseEstimate(model, cfg.memory_s)
        self._kp_noise: list[float | None] = [None] * m
        self._history: list[_Reading] = []
        self._after_gap = False
        self._last_scan: int | None = None
        self._horizon: HorizonState | None = None
        self._t_start: float | None = None
        self._t_last_proposal: float | None = None
        self._counters = _Counters()
        self._saturated = [0] * m
        self._one_sided = [0] * m
        self._last_decision: Decision | None = None

    # ------------------------------------------------------------------ packing
    def _pack(self, g: FloatArray, i: int) -> FloatArray:
        """Pump i's parameters ``[Kp_ij, Ki_ij, Kd_ij for j in its loops]`` from (3, m, nl)."""
        return np.concatenate([g[:, i, j] for j in self._loops[i]])

    def _unpack_into(self, g: FloatArray, i: int, theta: FloatArray) -> None:
        for k, j in enumerate(self._loops[i]):
            g[:, i, j] = theta[3 * k : 3 * k + 3]

    # ------------------------------------------------------------------ properties
    @property
    def model(self) -> LoopModel:
        """The linear model the guards use."""
        return self._model

    @property
    def config(self) -> AdaptationConfig:
        """The settings."""
        return self._cfg

    @property
    def applied(self) -> PidGains:
        """Gains the adapter believes the PLC applies (rate-limit reference)."""
        return self._applied

    @property
    def fixed(self) -> PidGains:
        """The PLC's fixed gains."""
        return self._fixed

    @property
    def box(self) -> GainBox:
        """The gain box in force (the configured one or the default)."""
        return self._box

    @property
    def change_floor(self) -> PidGains:
        """The rate limit's absolute floor in force per gain (configured, or the default)."""
        return PidGains.from_stacked(self._guards.floor)

    @property
    def ki_min(self) -> FloatArray:
        """Own-loop Ki lower bound per pump, shape (n_u,)."""
        return self._ki_min.copy()

    @property
    def last_decision(self) -> Decision | None:
        """The last decision taken by :meth:`propose` or :meth:`submit`."""
        return self._last_decision

    def _ready(self, i: int) -> bool:
        """Pump i's estimate has absorbed as many informative samples as it has parameters.

        Informative: an applied RLS update, or a one-sided correction that moved the estimate.
        """
        rls = self._rls[i]
        if isinstance(rls, PriorRls):
            return True  # its estimate starts at the model-based tuning, usable from the start
        return rls.n_updates + rls.n_constrained >= rls.n_params

    def estimate(self) -> PidGains:
        """Current RLS estimates as gains (entries a pump does not fit: the applied values)."""
        g = self._applied.stacked().copy()
        for i, rls in enumerate(self._rls):
            self._unpack_into(g, i, rls.theta / self._scale[i])
        return PidGains.from_stacked(g)

    def _packed_box(self, i: int) -> tuple[FloatArray, FloatArray]:
        """Pump i's box limits (packed like its parameters)."""
        return self._pack(self._box.lower.stacked(), i), self._pack(self._box.upper.stacked(), i)

    def _box_distance(self, g: FloatArray, i: int) -> FloatArray:
        """Fraction of the box width from each of pump i's gains (packed) to the nearest limit."""
        lo, hi = self._packed_box(i)
        width = hi - lo
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.minimum(g - lo, hi - g) / width
        return np.where(width > 0.0, np.clip(d, 0.0, 0.5), math.nan)

    def _health(self, i: int) -> tuple[float, float]:
        """Pump i's (excitation, condition number) of its information matrix."""
        rls = self._rls[i]
        if isinstance(rls, PriorRls):
            return rls.excitation, rls.condition_number
        w = np.linalg.eigvalsh(rls.covariance)
        return float(1.0 / w[-1]), float(w[-1] / w[0])

    def on_box_limit(self, i: int) -> bool:
        """Pump i's estimate or applied gains sit on a limit of the gain box.

        A gain is on a limit when it is within ``box_limit_fraction`` of the smaller of the box
        width and the gain's natural scale (the larger of its fixed and model-based values) from
        it: a Ki of 6.5e-6 in a box [0, 1e-3] is 0.65 % of the width from 0, yet three times its
        tolerance (0.01 x 1.9e-4) away, and not decided by the box.
        """
        lo, hi = self._packed_box(i)
        natural = self._pack(self._natural, i)
        tol = self._cfg.box_limit_fraction * np.minimum(hi - lo, natural)
        adapted = (hi - lo) > 0.0
        for g in (self._rls[i].theta / self._scale[i], self._pack(self._applied.stacked(), i)):
            near = (np.abs(g - lo) <= tol) | (np.abs(hi - g) <= tol)
            if (near & adapted).any():
                return True
        return False

    @property
    def prior(self) -> PidGains:
        """The model-based tuning (:func:`model_based_gains`, clipped into the box and sign region)."""
        return self._prior

    def diagnostics(self) -> AdapterDiagnostics:
        """Counters and per-pump estimator state (for the ``Supervisor.RLS.*`` nodes)."""
        pumps = []
        for i, rls in enumerate(self._rls):
            theta = rls.theta / self._scale[i]
            excitation, cond = self._health(i)
            pumps.append(
                PumpDiagnostics(
                    theta=theta,
                    covariance_trace=rls.trace,
                    samples_used=rls.n_updates,
                    skipped_unexcited=rls.n_skipped_unexcited,
                    skipped_nonfinite=rls.n_skipped_nonfinite,
                    dropped_saturated=self._saturated[i],
                    one_sided_updates=self._one_sided[i],
                    ready=self._ready(i),
                    excitation=excitation,
                    condition_number=cond,
                    box_distance=self._box_distance(theta, i),
                    on_box_limit=self.on_box_limit(i),
                    prior=self._pack(self._prior.stacked(), i),
                )
            )
        c = self._counters
        return AdapterDiagnostics(
            pumps=tuple(pumps),
            samples_formed=c.formed,
            dropped_gap=c.gap,
            dropped_invalid=c.invalid,
            duplicates=c.duplicates,
            accepted_pushes=c.accepted,
            rejected_pushes=c.rejected,
            rejected_by_reason=dict(c.by_reason),
            last_reject_reason=c.last_reject,
            applied=self._applied,
        )

    # ------------------------------------------------------------------ data
    def observe(
        self,
        *,
        scan: int,
        t_s: float,
        sp: ArrayLike,
        pv: ArrayLike,
        mv: ArrayLike,
        u_mpc: ArrayLike,
        x: ArrayLike | None = None,
    ) -> SampleStatus:
        """Take one PLC scan's readings and, when three contiguous scans exist, learn from them.

        Parameters
        ----------
        scan : int
            PLC scan counter of the scan SP, PV and MV were read from (one Read).
        t_s : float
            Model time [s].
        sp, pv : array_like, shape (n_loops,)
            Setpoints and PVs exactly as the PLC's PID used them; ``e = sp - pv``.
        mv : array_like, shape (n_u,)
            Applied (clamped) pump outputs of that scan.
        u_mpc : array_like, shape (n_u,)
            MPC input for this scan, computed from the same measured state. A non-finite entry
            (MPC failure) skips that pump's update (counted by its RLS).
        x : array_like, shape (n_x,), optional
            Full measured state (every level) for the input-bound simulation; by default the
            unmeasured states are set to their operating values:
            ``x = x_op + pinv(C) (pv - C x_op)``.

        Returns
        -------
        SampleStatus
        """
        if isinstance(scan, bool) or not isinstance(scan, (int, np.integer)):
            raise TypeError(f"scan must be an int, got {type(scan).__name__}")
        scan = int(scan)
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError("t_s must be finite")
        model = self._model
        nl, m = model.n_loops, model.n_u
        sp_v = matrix(sp, "sp", (nl,))
        pv_v = matrix(pv, "pv", (nl,))
        mv_v = matrix(mv, "mv", (m,))
        um_v = matrix(u_mpc, "u_mpc", (m,))
        if self._t_start is None:
            self._t_start = t

        if self._last_scan is not None and scan == self._last_scan:
            self._counters.duplicates += 1
            return SampleStatus.DUPLICATE
        self._last_scan = scan

        if x is None:
            x_v = model.x_op + np.linalg.pinv(model.C) @ (pv_v - model.C @ model.x_op)
        else:
            x_v = matrix(x, "x", (model.n_x,))
        if not (np.isfinite(sp_v).all() and np.isfinite(pv_v).all() and np.isfinite(mv_v).all()):
            self._history.clear()
            self._after_gap = True
            self._noise.restart()
            self._counters.invalid += 1
            return SampleStatus.INVALID

        reading = _Reading(scan=scan, e=sp_v - pv_v, sp=sp_v, mv=mv_v, x=x_v)
        if self._history and scan != self._history[-1].scan + 1:
            self._history.clear()
            self._after_gap = True
            self._noise.restart()
        self._history.append(reading)
        if len(self._history) > 3:
            del self._history[0]
        if len(self._history) < 3:
            # The window [k-2, k] is incomplete: at the very start that is warm-up; after a gap in
            # the scan counter (or an invalid reading) the window spans it and the sample is dropped.
            if self._after_gap:
                self._counters.gap += 1
                return SampleStatus.GAP
            return SampleStatus.WARMUP
        self._after_gap = False

        r0, r1, r2 = self._history[-1], self._history[-2], self._history[-3]
        self._counters.formed += 1
        self._noise.track(r0.x, r1.x, r1.mv)
        band = self._cfg.saturation_band * (model.u_max - model.u_min)
        if np.isfinite(x_v).all():
            with np.errstate(invalid="ignore"):
                mpc_at_max = np.isfinite(um_v) & (um_v >= model.u_max - band)
                mpc_at_min = np.isfinite(um_v) & (um_v <= model.u_min + band)
            self._horizon = HorizonState(
                x=x_v, u=r0.mv, e=r0.e, e_prev=r1.e, r=r0.sp, mpc_at_max=mpc_at_max, mpc_at_min=mpc_at_min
            )
        ts = model.ts_s
        de = r0.e - r1.e
        d2e = r0.e - 2.0 * r1.e + r2.e
        for i, rls in enumerate(self._rls):
            loops = list(self._loops[i])
            psi = np.column_stack([de[loops], ts * r0.e[loops], d2e[loops] / ts]).ravel()
            y = float(um_v[i] - r1.mv[i])
            U = float(model.u_max[i] - model.u_min[i])
            x_hat = psi / (U * self._scale[i])
            at_max = math.isfinite(um_v[i]) and um_v[i] >= model.u_max[i] - band[i]
            at_min = math.isfinite(um_v[i]) and um_v[i] <= model.u_min[i] + band[i]
            mode = self._cfg.saturated
            if (at_max or at_min) and mode != "equality":
                if mode == "drop":
                    self._saturated[i] += 1
                    continue
                # One-sided (module doc): the MPC pinned at u_max wants at least u_MPC, so the
                # PID's move from the applied input must be at least y (at most y at u_min). A
                # consistent estimate learns nothing; a violating one is projected onto psi' theta
                # = y in the metric of P^-1, with P untouched (an inequality is not a measurement).
                if rls.constrain(x_hat, y / U, "ge" if at_max else "le"):
                    self._one_sided[i] += 1
                else:
                    self._saturated[i] += 1
                continue
            rls.update(x_hat, y / U)
        return SampleStatus.FORMED

    def noise_std(self) -> FloatArray:
        """Estimated transmitter noise per loop [error unit], shape (n_loops,); 0 before data."""
        return self._noise.std()

    def _update_noise_limit(self) -> None:
        """From the noise estimate: each pump's loop-gain limit (with hysteresis) and dead zone.

        Transmitter noise of standard deviation ``sigma`` moves a PI's output by about
        ``sqrt(2) Kp sigma`` rms per scan, so ``Kp <= kp_noise = budget U / (sqrt(2) sigma)`` keeps
        the noise-driven moves within ``noise_move_budget`` of the range ``U``; :meth:`propose`
        scales a pump's whole own-loop target (Kp, Ki, Kd) down to it (the loop gain, not the
        PID's shape). The limit engages below ``Kp_model / 1.2``, releases above ``Kp_model x 1.2``
        and moves only when it changes by more than 20 %, so that the scatter of the estimate (a
        few %) does not make the gains wander. The dead zone becomes at least ``17 sigma / E``.
        """
        budget = self._cfg.noise_move_budget
        if not self._noise.ready:
            return
        model = self._model
        sigma = self.noise_std()
        base = self._prior.stacked()
        for i, j in enumerate(self._own):
            U = float(model.u_max[i] - model.u_min[i])
            kp = float(base[0, i, j])
            if budget is None or sigma[j] <= 0.0 or kp <= 0.0:
                continue
            kp_noise = budget * U / (math.sqrt(2.0) * float(sigma[j]))
            self._kp_noise[i] = hold_gain_limit(self._kp_noise[i], kp_noise, kp)
        for i, rls in enumerate(self._rls):
            if isinstance(rls, PriorRls):
                # Dead zone sized to the noise (docs/adaptation.md 2.7: about 17 sigma / E, the
                # regressor's noise-driven change being about 5.3 sigma / E rms): noise alone does
                # not adapt (measured: 0.5 mm pulled Ki1 below its fixed value without this).
                sigma_i = float(sigma[list(self._loops[i])].max())
                rls.set_excitation_threshold(
                    max(self._cfg.excitation_threshold, NOISE_DEAD_ZONE * sigma_i / self._cfg.error_scale)
                )

    @property
    def noise_gain_limit(self) -> FloatArray:
        """Each pump's own-loop Kp limit from the noise [pump unit / error unit] (inf: none)."""
        return np.array([math.inf if v is None else v for v in self._kp_noise])

    # ------------------------------------------------------------------ guards
    def evaluate(self, candidate: PidGains, t_s: float = math.nan) -> Decision:
        """Judge ``candidate`` against every guard, without side effects.

        The guards and their order are :meth:`GainGuards.evaluate`'s
        (:mod:`supervisor.adaptation.guards`): finite, inside the box, signs, rate limit from the
        applied gains, spectral radius, and the input bounds simulated from the last formed
        sample (skipped, ``input_violation`` NaN, before the first).

        Parameters
        ----------
        candidate : PidGains
            Shape (n_u, n_loops).
        t_s : float, optional
            Model time recorded in the decision [s].
        """
        return self._guards.evaluate(candidate, self._applied, self._horizon, t_s)

    def submit(self, candidate: PidGains, t_s: float = math.nan) -> Decision:
        """Judge ``candidate`` (:meth:`evaluate`), count the outcome, and take it as applied if accepted.

        A rejected candidate leaves the applied gains untouched.
        """
        decision = self.evaluate(candidate, t_s)
        c = self._counters
        if decision.accepted:
            c.accepted += 1
            self._applied = decision.candidate
        else:
            c.rejected += 1
            for reason in decision.reasons:
                c.by_reason[reason.value] = c.by_reason.get(reason.value, 0) + 1
            c.last_reject = decision.reason
        self._last_decision = decision
        return decision

    def set_applied(self, gains: PidGains) -> None:
        """Record the gains the PLC really applies (after a refused push, or read back)."""
        if gains.shape != (self._model.n_u, self._model.n_loops):
            raise ValueError(f"gains must have shape {(self._model.n_u, self._model.n_loops)}")
        if not gains.is_finite():
            raise ValueError("gains must be finite")
        self._applied = gains

    def propose(self, t_s: float) -> Decision | None:
        """Propose, judge and count a candidate gain set when one is due.

        A candidate is due when ``t_s`` is at least ``min_time_s`` after the first reading, at least
        one pump's RLS has applied as many updates as it has parameters, and ``push_period_s`` has
        passed since the previous proposal. Each ready pump moves from its applied gains along the
        straight line toward its RLS estimate, ``g = g_applied + alpha (g_estimate - g_applied)``
        with the largest ``alpha <= 1`` that keeps every one of its gains inside the rate limit;
        other pumps keep their applied gains.

        Parameters
        ----------
        t_s : float
            Model time [s].

        Returns
        -------
        Decision or None
            None when no candidate is due; otherwise the decision (accepted: push
            ``decision.candidate``).
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError("t_s must be finite")
        if self._t_start is None or t - self._t_start < self._cfg.min_time_s - 1e-9:
            return None
        ready = [self._ready(i) for i in range(len(self._rls))]
        if not any(ready):
            return None
        period = self._cfg.push_period_s
        if self._t_last_proposal is not None and t - self._t_last_proposal < period - 1e-9 * max(1.0, period):
            return None
        self._update_noise_limit()
        a = self._applied.stacked()
        target = a.copy()
        for i, rls in enumerate(self._rls):
            if ready[i]:
                self._unpack_into(target, i, rls.theta / self._scale[i])
        # The noise limit scales a pump's whole own-loop PID (the loop gain, not its shape): the
        # MPC teaches its own reaction to the noise (measured: Kp1 2.2e-3 learned under 0.5 mm).
        for i, j in enumerate(self._own):
            held = self._kp_noise[i]
            if ready[i] and held is not None and target[0, i, j] > held:
                target[:, i, j] *= held / target[0, i, j]
        limit = self._guards.step_limit(a)
        # Move toward the estimate, as far as the rate limit lets every gain of the pump go, along
        # one path per pump (direction-preserving). Clipping each gain on its own bends the path,
        # and a bent path between two admissible sets can cross unstable ones (measured: the
        # Energies run froze at the stability margin that way, see docs/adaptation.md).
        candidate = a.copy()
        for i in range(self._model.n_u):
            candidate[:, i, :] = gain_path_step(a[:, i, :], target[:, i, :], limit[:, i, :], self._cfg.path)
        self._t_last_proposal = t
        return self.submit(PidGains.from_stacked(candidate), t)
