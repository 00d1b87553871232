"""Small sweeps for the sweep tests: written into a test's directory, short runs of the
Energies scenario (the fixed PID: about 0.1 s per case), so that Dask's start dominates."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from helpers import ROOT

ENERGIES = ROOT / "configs/scenarios/energies_mpc_pid_vs_pid.yaml"
SITE = ROOT / "configs/three_tank_energies_sim.yaml"

VOLATILE = ("worker", "wall_s")
"""Columns that say where and how fast a case ran: not part of a case's result."""


def write_spec(directory: Path, name: str = "tiny", **fields: Any) -> Path:
    """A sweep file over the Energies scenario's fixed PID, 60 s runs; ``fields`` override."""
    spec: dict[str, Any] = {
        "name": name,
        "scenario": str(ENERGIES),
        "variants": ["pid"],
        "duration_s": 60.0,
        "seed": 7,
        "draws": 2,
        "parameters": [
            {"name": "kp", "paths": ["site.plc.loops.0.gains.kp"], "values": [3.0e-4, 6.0e-4]},
            {
                "name": "noise_std_m",
                "paths": ["site.plant.tanks.0.transmitter.noise_std_m"],
                "uniform": {"low": 0.0, "high": 1.0e-3},
            },
        ],
        "metrics": ["iae", "overshoot_pct", "max_du"],
        "loops": ["LIC1"],
    }
    spec.update(fields)
    path = directory / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False), encoding="utf-8")
    return path


def stable(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows without the columns that depend on the worker and the machine's speed."""
    return [{k: v for k, v in r.items() if k not in VOLATILE} for r in rows]
