"""Golden trajectories: one trimmed scenario per paper, rerun and compared with stored .npz files.

The co-simulation is deterministic (seeded noise, no clock), so on the machine that wrote the
files the runs agree to the last bit. Tolerances allow for other CPUs and BLAS builds (different
rounding in matrix products and in the MPC's QP solver) while still catching any change of
behaviour: levels rtol 1e-6 plus atol 1e-9 m; pump commands rtol 1e-6 plus atol 1e-6 of the
pump's command range (1.2e-10 m^3/s on the three-tank pumps). Time stamps must match exactly.

After an intended change of behaviour: .venv/bin/python tests/golden/regenerate.py
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent


def _regenerate() -> ModuleType:
    spec = importlib.util.spec_from_file_location("golden_regenerate", HERE / "regenerate.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


REGEN = _regenerate()
LEVEL_RTOL, LEVEL_ATOL_M = 1e-6, 1e-9
COMMAND_RTOL, COMMAND_ATOL_OF_RANGE = 1e-6, 1e-6


@pytest.mark.parametrize("case", REGEN.CASES, ids=lambda c: c.scenario)
def test_golden_trajectory(case: Any) -> None:
    from tanklab.scenario import load_scenario, variant_site

    stored = np.load(REGEN.path_of(case))
    meta = json.loads(str(stored["meta"]))
    assert meta["scenario"] == case.scenario and meta["variants"] == list(case.variants)
    fresh = REGEN.compute(case)
    assert set(fresh) == set(stored.files) - {"meta"}
    scenario, site_path = load_scenario(REGEN.ROOT / "configs" / "scenarios" / f"{case.scenario}.yaml")
    for variant in scenario.variants:
        if variant.name not in case.variants:
            continue
        site = variant_site(scenario, site_path, variant)
        span = np.array([p.command_max - p.command_min for p in site.plant.pumps])
        key = variant.name
        np.testing.assert_array_equal(fresh[f"{key}/t_s"], stored[f"{key}/t_s"])
        np.testing.assert_allclose(
            fresh[f"{key}/levels_m"],
            stored[f"{key}/levels_m"],
            rtol=LEVEL_RTOL,
            atol=LEVEL_ATOL_M,
            err_msg=f"{case.scenario}/{key}: levels",
        )
        np.testing.assert_allclose(
            fresh[f"{key}/commands"] / span,
            stored[f"{key}/commands"] / span,
            rtol=COMMAND_RTOL,
            atol=COMMAND_ATOL_OF_RANGE,
            err_msg=f"{case.scenario}/{key}: pump commands",
        )


def test_golden_files_stay_small() -> None:
    # A few hundred KB in total at most (the brief); currently about 130 KiB.
    total = sum(REGEN.path_of(c).stat().st_size for c in REGEN.CASES)
    assert total < 300 * 1024
