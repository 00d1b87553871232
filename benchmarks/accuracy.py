"""The MPC's accuracy guard, measured in the same run as its speed.

The guard (docs/mpc.md, architecture "Accuracy before speed"): closed-loop IAE within 1 % of a
high-accuracy reference solver on the same scenario. The reference is the test suite's own:
``tests/supervisor/test_mpc.py``'s ``ReferenceController`` (the same filter, the same QP written
in unscaled SI deviations and solved by cvxpy + CLARABEL at tolerances 1e-12) and its
``closed_loop`` (the nonlinear three-tank plant of the OPC UA MPC paper, RK4 with its automatic sub-steps).
So the benchmark and the test measure one thing. Scenarios: the docs/mpc.md accuracy table's
four (h1 step +5 cm with rate 1e-6; two setpoints with rate 1e-5; the paper-literal step; a T1
leak with rate 1e-5), each with the condensed and the sparse QP.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from benchmarks.common import ROOT


@dataclass(frozen=True)
class GuardResult:
    """One scenario and QP form: IAE of the controller and of the reference [m s]."""

    scenario: str
    formulation: str
    steps: int
    iae: tuple[float, float]
    iae_ref: tuple[float, float]
    statuses: dict[str, int]

    @property
    def total_error(self) -> float:
        """|IAE - IAE_ref| / IAE_ref summed over h1 and h2: the guard's figure (<= 0.01)."""
        ref = sum(self.iae_ref)
        return abs(sum(self.iae) - ref) / ref


def _test_module() -> ModuleType:
    """tests/supervisor/test_mpc.py as a module (it imports ``digest_models`` from tests/)."""
    for sub in ("tests", "tests/supervisor"):
        path = str(ROOT / sub)
        if path not in sys.path:
            sys.path.insert(0, path)
    spec = importlib.util.spec_from_file_location("_guard_test_mpc", ROOT / "tests/supervisor/test_mpc.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def run(log: Callable[[str], None]) -> list[GuardResult]:
    """Every scenario, both forms; the reference loop once per scenario."""
    from supervisor.mpc import MpcController
    from tanklab.enums import MpcStatus

    T = _test_module()
    h_op = T.H_OP
    step_r = T.STEP_R
    scenarios: dict[str, tuple[dict[str, Any], Callable[[int], Any], Callable[[int], Any] | None, int]] = {
        "h1 +5 cm, rate 1e-6": ({}, step_r, None, 200),
        "h1 +5 cm, h2 -3 cm, rate 1e-5": (
            {"du_min": -1e-5, "du_max": 1e-5},
            lambda k: h_op[:2] + (np.array([0.05, -0.03]) if k >= 4 else 0.0),
            None,
            200,
        ),
        "h1 +5 cm, paper-literal (first move free)": ({"first_move_rate_limited": False}, step_r, None, 200),
        "T1 leak, rate 1e-5": (
            {"du_min": -1e-5, "du_max": 1e-5},
            lambda k: h_op[:2],
            lambda k: np.array([1.0, 0.0, 0.0]) if k >= 10 else np.zeros(3),
            300,
        ),
    }
    out = []
    for name, (kw, r_of_k, leak_of_k, steps) in scenarios.items():
        ref_ctrl = T.ReferenceController(MpcController(T.MODEL, T.paper_config(**kw)))
        ref = T.closed_loop(ref_ctrl, steps, r_of_k, leak_of_k)
        iae_ref = np.sum(np.abs(ref["h"][:, :2] - ref["r"]), axis=0) * T.TS
        for form in ("condensed", "sparse"):
            ctrl = MpcController(T.MODEL, T.paper_config(formulation=form, **kw))
            got = T.closed_loop(ctrl, steps, r_of_k, leak_of_k)
            iae = np.sum(np.abs(got["h"][:, :2] - got["r"]), axis=0) * T.TS
            counts = np.bincount(got["status"].astype(int), minlength=len(MpcStatus))
            statuses = {MpcStatus(i).name: int(c) for i, c in enumerate(counts) if c}
            res = GuardResult(
                name,
                form,
                steps,
                (float(iae[0]), float(iae[1])),
                (float(iae_ref[0]), float(iae_ref[1])),
                statuses,
            )
            log(f"  {name} ({form}): IAE error {res.total_error:.1e}")
            out.append(res)
    return out
