"""Rebuild the golden trajectories in tests/golden/ (one scenario per paper, trimmed).

Run from anywhere:  .venv/bin/python tests/golden/regenerate.py

Each case runs a shipped scenario through ``tankctl.simulate.run_scenario`` for a trimmed
duration and stores, per variant, every ``every``-th scan of the time, the true levels [m] and
the pump commands [pump unit] in ``<scenario>.npz`` (keys ``<variant>/t_s``, ``<variant>/levels_m``,
``<variant>/commands``, and ``meta``, a JSON string with the case and the versions used).
tests/golden/test_golden.py reruns the same cases and compares with tolerances.

Regenerate after an INTENDED change of behaviour (a plant, PLC block or supervisor change) and
say why in the commit.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
if str(ROOT / "src") not in sys.path:
    sys.path.insert(0, str(ROOT / "src"))


@dataclass(frozen=True)
class Case:
    """A trimmed scenario run: which variants, for how long, every how many scans."""

    scenario: str
    duration_s: float
    variants: tuple[str, ...]
    every: int


CASES = (
    # NL-PI: the fill, the first disturbance and the second step; 0.01 s scans kept every 0.1 s.
    Case("nlpi_short_sim", 60.0, ("nlpi", "pi", "nlpi_1s"), 10),
    # IMC-PI on the calibrated plant: the step and the start of the input disturbance.
    Case("imc_pi_coupled", 400.0, ("imc_pi", "imc_pid", "zn_pi"), 2),
    # MRAC: rest and the h1 step (the adaptive laws' parameters move from 950 s on).
    Case("mrac_two_tank", 1300.0, ("cpi", "mit", "api"), 4),
    # Kortela: both steps, every variant (MPC rate bounds, the PLC at 0.5 s under the MPC's 2.5 s,
    # and the paper-literal form).
    Case("kortela_mpc_vs_pi", 500.0, ("pi", "mpc", "mpc_fast", "mpc_fast_plc_0_5", "mpc_literal"), 1),
    # Energies: the fill from empty and the leak opened and closed, the adapted PID included.
    Case("energies_mpc_pid_vs_pid", 750.0, ("pid", "mpc_pid", "mpc"), 2),
)


def path_of(case: Case) -> Path:
    """The stored file of a case."""
    return HERE / f"{case.scenario}.npz"


def compute(case: Case) -> dict[str, np.ndarray]:
    """Run a case; return the arrays as stored (without ``meta``)."""
    from tankctl.simulate import run_scenario

    result = run_scenario(
        ROOT / "configs" / "scenarios" / f"{case.scenario}.yaml",
        variants=list(case.variants),
        duration_s=case.duration_s,
    )
    out: dict[str, np.ndarray] = {}
    for name, v in result.variants.items():
        out[f"{name}/t_s"] = v.t_s[:: case.every]
        out[f"{name}/levels_m"] = v.levels_m[:: case.every]
        out[f"{name}/commands"] = v.commands[:: case.every]
    return out


def main() -> None:
    import scipy

    for case in CASES:
        arrays = compute(case)
        meta = {
            "scenario": case.scenario,
            "duration_s": case.duration_s,
            "variants": list(case.variants),
            "every": case.every,
            "numpy": np.__version__,
            "scipy": scipy.__version__,
        }
        np.savez_compressed(path_of(case), meta=np.array(json.dumps(meta)), **arrays)  # type: ignore[arg-type]
        print(f"wrote {path_of(case).relative_to(ROOT)} ({path_of(case).stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
