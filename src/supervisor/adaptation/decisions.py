"""What the gain adapter reports: guard verdicts, sample outcomes and diagnostics (value types).

These are the outputs of :class:`~supervisor.adaptation.adapter.PidGainAdapter` that the
supervisor maps to its ``Supervisor.RLS.*`` and gain-push nodes; gains are in the PID's units
([pump unit / e], [pump unit / (e s)], [pump unit s / e]), times in model seconds [s].
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from supervisor.adaptation._validate import FloatArray
from tanklab.gains import PidGains

__all__ = ["AdapterDiagnostics", "Decision", "PumpDiagnostics", "RejectReason", "SampleStatus"]


class RejectReason(StrEnum):
    """Why a candidate gain set was rejected, in the order the guards are reported."""

    NON_FINITE = "non_finite"
    OUTSIDE_BOX = "outside_box"
    SIGN = "sign"
    RATE_LIMIT = "rate_limit"
    UNSTABLE = "unstable"
    INPUT_BOUNDS = "input_bounds"


class SampleStatus(StrEnum):
    """What :meth:`PidGainAdapter.observe` did with one scan's readings."""

    FORMED = "formed"  # a regression sample was formed and offered to every pump's RLS
    WARMUP = "warmup"  # first readings after start: history not yet three scans long
    GAP = "gap"  # the window spans a gap in the scan counter: dropped, counted
    INVALID = "invalid"  # non-finite SP, PV or MV: dropped, counted, history restarts
    DUPLICATE = "duplicate"  # same scan number as the previous reading: ignored


@dataclass(frozen=True, eq=False)
class Decision:
    """Outcome of the admissibility guards for one candidate gain set.

    Attributes
    ----------
    t_s : float
        Model time of the proposal [s].
    candidate : PidGains
        The gain set judged.
    accepted : bool
        True when every guard passed (then it is the set to push).
    reasons : tuple of RejectReason
        Every failing guard, in :class:`RejectReason` order; empty when accepted.
    detail : str
        Human-readable detail of the first failure ("" when accepted).
    spectral_radius : float
        Closed-loop spectral radius with the candidate (NaN when not computed).
    input_violation : float
        Peak excursion of the simulated input beyond its bounds, as a fraction of the input
        range (0 inside; NaN when not computed).
    changed : bool
        True when the candidate differs from the gains applied at the time.
    """

    t_s: float
    candidate: PidGains
    accepted: bool
    reasons: tuple[RejectReason, ...]
    detail: str
    spectral_radius: float
    input_violation: float
    changed: bool

    @property
    def reason(self) -> RejectReason | None:
        """First failing guard, or None when accepted."""
        return self.reasons[0] if self.reasons else None


@dataclass(frozen=True)
class PumpDiagnostics:
    """Per-pump adaptation state.

    Attributes
    ----------
    theta : ndarray, shape (3 * loops used,)
        Current RLS estimate in physical units ``[Kp_ij, Ki_ij, Kd_ij, ...]``.
    covariance_trace : float
        Trace of the RLS covariance of the dimensionless parameters.
    samples_used : int
        Applied RLS updates.
    skipped_unexcited : int
        Samples skipped by the RLS dead zone.
    skipped_nonfinite : int
        Samples skipped for a non-finite target or result.
    dropped_saturated : int
        Samples with ``u_MPC`` at a bound that taught nothing: dropped (``saturated="drop"``) or
        already consistent with the estimate (``"one_sided"``).
    one_sided_updates : int
        Samples with ``u_MPC`` at a bound whose inequality the estimate violated and that moved it
        onto the boundary (``saturated="one_sided"``; not counted in ``samples_used``).
    ready : bool
        Enough informative samples (applied updates plus one-sided corrections, at least the
        number of parameters) to propose gains.
    excitation : float
        Smallest eigenvalue of the remembered data's information matrix ``R`` (dimensionless,
        >= 0): how well the weakest parameter direction is measured. For ``estimator="rls"``:
        ``1 / lambda_max(P)`` minus nothing (the RLS has no separate prior), i.e. the smallest
        eigenvalue of ``P^-1``.
    condition_number : float
        Condition number of the information matrix (``L0 + R``; ``P`` for "rls"), >= 1.
    box_distance : ndarray, shape (3 * loops used,)
        Per estimated gain ``[Kp, Ki, Kd, ...]``: distance of the estimate to the nearest limit of
        the gain box, as a fraction of the box width (0 on a limit, 0.5 in the middle; NaN for a
        pinned gain of zero width).
    on_box_limit : bool
        The estimate or the applied gains of this pump sit on a box limit
        (:meth:`PidGainAdapter.on_box_limit`): the box, not the data, decides such a gain.
    prior : ndarray, shape (3 * loops used,)
        The model-based tuning the estimate is regularised toward (physical units).
    """

    theta: FloatArray
    covariance_trace: float
    samples_used: int
    skipped_unexcited: int
    skipped_nonfinite: int
    dropped_saturated: int
    one_sided_updates: int
    ready: bool
    excitation: float = math.nan
    condition_number: float = math.nan
    box_distance: FloatArray = field(default_factory=lambda: np.zeros(0))
    on_box_limit: bool = False
    prior: FloatArray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class AdapterDiagnostics:
    """Adapter-wide counters and per-pump state.

    Attributes
    ----------
    pumps : tuple of PumpDiagnostics
        One per pump.
    samples_formed : int
        Regression samples formed (three contiguous scans).
    dropped_gap : int
        Readings whose window spans a gap in the scan counter.
    dropped_invalid : int
        Readings with a non-finite SP, PV or MV.
    duplicates : int
        Readings repeating the previous scan number (ignored).
    accepted_pushes : int
        Candidates that passed every guard.
    rejected_pushes : int
        Candidates rejected.
    rejected_by_reason : mapping of str to int
        Rejections per :class:`RejectReason` value (every failing guard counted).
    last_reject_reason : RejectReason or None
        First failing guard of the last rejected candidate.
    applied : PidGains
        Gains the adapter believes the PLC applies.
    """

    pumps: tuple[PumpDiagnostics, ...]
    samples_formed: int
    dropped_gap: int
    dropped_invalid: int
    duplicates: int
    accepted_pushes: int
    rejected_pushes: int
    rejected_by_reason: Mapping[str, int]
    last_reject_reason: RejectReason | None
    applied: PidGains
