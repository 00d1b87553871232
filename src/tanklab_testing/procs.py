"""Tier processes of the repository's tests and benchmarks: the shipped wrapper run from the root.

The free ports, the /proc scans and :class:`TankctlProcess` are :mod:`tankctl.testing.procs`'s
(shipped, so that the pytest plugin's ``tanklab_stack`` runs the same code from a wheel;
decision 0056); here a process starts from the repository root (:data:`ROOT`) unless told
otherwise, and :class:`UpProcess` wraps ``tankctl up``. Only processes this module started, or
their children, are ever signalled.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from tankctl.testing import procs as _shipped
from tankctl.testing.procs import (
    READY_TIMEOUT_S,
    STOP_TIMEOUT_S,
    alive,
    descendants,
    free_base_port,
    free_port,
    tankctl_pids,
    tankctl_pids_on,
)

__all__ = [
    "READY_TIMEOUT_S",
    "ROOT",
    "STOP_TIMEOUT_S",
    "TankctlProcess",
    "UpProcess",
    "alive",
    "descendants",
    "free_base_port",
    "free_port",
    "site_name",
    "tankctl_pids",
    "tankctl_pids_on",
]

ROOT = Path(__file__).resolve().parents[2]
"""The repository root: processes run from there (configs/ and docs/ live there)."""


class TankctlProcess(_shipped.TankctlProcess):
    """:class:`tankctl.testing.procs.TankctlProcess` started from the repository root by default."""

    def __init__(self, *args: str, cwd: Path | None = ROOT, **kwargs: Any) -> None:
        super().__init__(*args, cwd=cwd, **kwargs)


def site_name(config: Path) -> str:
    """A site config's run-directory name (its ``name``, as ``tankctl up`` names it)."""
    return str(yaml.safe_load(config.read_text(encoding="utf-8"))["name"])


class UpProcess(TankctlProcess):
    """``tankctl up`` as a :class:`TankctlProcess`: its arguments, its ``started:`` line, every
    line it prints (stderr too), its run directory, and on :meth:`cleanup` the tiers bound to its
    ports. Nothing here handles the process: only what ``up`` is called with and where it writes."""

    def __init__(
        self,
        base: int,
        log_dir: Path,
        *extra: str,
        config: Path | None = None,
        env: Mapping[str, str] | None = None,
    ) -> None:
        config = config or ROOT / "configs/three_tank_energies_sim.yaml"
        # No HMI unless asked for (``--hmi-port``): its default port, 8080, is one per machine.
        hmi = [] if "--hmi-port" in extra else ["--no-hmi"]
        args = [
            "up",
            "--config",
            str(config),
            "--base-port",
            str(base),
            "--log-dir",
            str(log_dir),
            *hmi,
            *extra,
        ]
        super().__init__(
            *args,
            ready="started: ",
            merge_stderr=True,
            env=env,
            ports=[base + k for k in range(3)],
            ready_timeout_s=120.0,
            stop_timeout_s=60.0,
        )
        self.base = base
        self.log_dir = log_dir
        self.run_dir = log_dir / site_name(config)

    async def started(self) -> UpProcess:
        """Launch and wait for the ``started:`` line (every endpoint serves)."""
        await self.start()
        return self

    def pid(self, tier: str) -> int:
        """The pid in a tier's pid file."""
        return int((self.run_dir / f"{tier}.pid").read_text())

    def pid_files(self) -> list[Path]:
        return sorted(self.run_dir.glob("*.pid"))
