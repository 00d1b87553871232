"""MPC-based PID gain adaptation with admissibility guards (seeds digest 2.1, 2.3, 2.4).

The PLC runs, every scan ``k`` of period ``Ts`` [s], the velocity-form MIMO PID (digest 2.1) with
``e_j = r_j - y_j`` (setpoint minus measured level, [m])::

    u_i(k) = u_i(k-1) + sum_j [ Kp_ij De_j(k) + Ki_ij Ts e_j(k) + (Kd_ij / Ts) D2e_j(k) ]

The supervisor's MPC runs in the shadow and proposes ``u_MPC(k)``; for each pump a recursive
least-squares estimator fits that pump's gains so that the PID increment reproduces the MPC's
move from the applied input, ``y_i(k) = u_i,MPC(k) - u_i,applied(k-1) = psi_i(k)' theta_i``
[pump unit]. Candidate gain sets are pushed only when they pass every admissibility guard.

Layout (decision 0034), one responsibility per module, all pure (model time and scan counter are
arguments; no clock, no I/O, no logging):

- :mod:`~supervisor.adaptation.model`: :class:`LoopModel`, the ZOH linear loop model;
- :mod:`~supervisor.adaptation.closed_loop`: the closed loop with the PID (closed-loop matrix,
  spectral radius, SIMC tuning, simulated inputs and their bound violation);
- :mod:`~supervisor.adaptation.config`: :class:`AdaptationConfig`, the adapter's settings;
- :mod:`~supervisor.adaptation.decisions`: what the adapter reports (:class:`Decision`,
  :class:`RejectReason`, :class:`SampleStatus`, diagnostics);
- :mod:`~supervisor.adaptation.limits`: the admissible region derived from the fixed gains;
- :mod:`~supervisor.adaptation.guards`: the admissibility guards of a candidate;
- :mod:`~supervisor.adaptation.noise`: the transmitter-noise estimate and its gain limit;
- :mod:`~supervisor.adaptation.path`: the path of a proposal toward the estimate;
- :mod:`~supervisor.adaptation.adapter`: :class:`PidGainAdapter`, regression and proposals.

``PidGains`` and ``GainBox`` are the kernel's (:mod:`tanklab.gains`, decision 0030), re-exported.
"""

from __future__ import annotations

from supervisor.adaptation.adapter import PidGainAdapter
from supervisor.adaptation.closed_loop import (
    closed_loop_matrix,
    closed_loop_spectral_radius,
    input_bound_violation,
    model_based_gains,
    simulate_pid_inputs,
)
from supervisor.adaptation.config import AdaptationConfig, Estimator, GainPath, SaturatedSamples
from supervisor.adaptation.decisions import (
    AdapterDiagnostics,
    Decision,
    PumpDiagnostics,
    RejectReason,
    SampleStatus,
)
from supervisor.adaptation.model import LoopModel
from supervisor.adaptation.path import gain_path_step
from tanklab.gains import GainBox, PidGains

__all__ = [
    "AdaptationConfig",
    "AdapterDiagnostics",
    "Decision",
    "Estimator",
    "GainBox",
    "GainPath",
    "LoopModel",
    "PidGainAdapter",
    "PidGains",
    "PumpDiagnostics",
    "RejectReason",
    "SampleStatus",
    "SaturatedSamples",
    "closed_loop_matrix",
    "closed_loop_spectral_radius",
    "gain_path_step",
    "input_bound_violation",
    "model_based_gains",
    "simulate_pid_inputs",
]
