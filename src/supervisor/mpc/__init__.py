"""Constrained offset-free linear MPC (pure core of the supervisor's MPC mode).

The package, one job per module:

- :mod:`~supervisor.mpc.model`: the linear model, the tuning and the result of one step, validated;
- :mod:`~supervisor.mpc.formulation`: the optimal control problem, its scaling and the scaled QP
  (condensed or sparse), built once per model, with the vectors that change every step;
- :mod:`~supervisor.mpc.cost`: the SI cost of a plan and its output-bound violation (one snapshot
  per model; a result evaluates it when first read);
- :mod:`~supervisor.mpc.backends`: the QP solvers behind one interface (``QpBackend``): daqp, a
  dual active-set solver hot-started from the previous working set (default on the condensed
  QP), and OSQP with its warm start and tolerance ladder (default on the sparse QP);
- :mod:`~supervisor.mpc.controller`: :class:`MpcController`: estimate, solve, hold or project,
  and the result.

The choice of daqp, and the numbers behind it, are in docs/decisions/0027-qp-library.md.
"""

from supervisor.mpc.backends import DaqpBackend, OsqpBackend, QpBackend, QpSolution, SoftRows
from supervisor.mpc.controller import MpcController
from supervisor.mpc.formulation import SPARSE_FROM_HORIZON
from supervisor.mpc.model import MpcConfig, MpcModel, MpcResult, SolvedBy

__all__ = [
    "SPARSE_FROM_HORIZON",
    "DaqpBackend",
    "MpcConfig",
    "MpcController",
    "MpcModel",
    "MpcResult",
    "OsqpBackend",
    "QpBackend",
    "QpSolution",
    "SoftRows",
    "SolvedBy",
]
