"""The default site config (Energies, three tanks) as tests and benchmarks run it.

:func:`site_config` writes it for one run, optionally with a retentive-memory file and the
tanks at the operating point with the equilibrium pump flows, so that the loops regulate from
the first scan instead of filling empty tanks.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from plant_sim.linearize import operating_point
from plant_sim.models import TankNetwork, default_inputs
from tankctl.testing.stack import HOST, PORT_ORDER, TIERS, tier_url
from tanklab.config import SiteConfig, load_site
from tanklab.tags import plc_tags
from tanklab_testing.procs import ROOT

__all__ = ["ENERGIES", "HOST", "PLC_TAGS", "PORT_ORDER", "SITE", "TIERS", "site_config", "tier_url"]

ENERGIES = ROOT / "configs" / "three_tank_energies_sim.yaml"
SITE = load_site(ENERGIES)
PLC_TAGS = plc_tags(SITE)


def site_config(
    path: Path,
    *,
    retain: Path | None = None,
    at_operating_point: bool = False,
    pumps_hold_on_watchdog: bool = False,
) -> Path:
    """The default config written to ``path``, optionally with a retentive-memory file and the
    tanks starting at the operating point with the equilibrium pump flows (so the loops start
    settled instead of filling empty tanks).

    ``pumps_hold_on_watchdog`` sets ``plant.watchdog.safe_state: hold``: the plant's pumps keep
    their last command when no command arrives within the watchdog's timeout. A test that starts
    the plant before the PLC at a high speed needs it: at speed 20 the default 10 s (model time)
    timeout is 0.5 s of wall time, shorter than a PLC's start on a loaded machine, and pumps
    switched off meanwhile drain the tanks away from the operating point the test starts from."""
    data = yaml.safe_load(ENERGIES.read_text(encoding="utf-8"))
    if pumps_hold_on_watchdog:
        data["plant"]["watchdog"]["safe_state"] = "hold"
    if retain is not None:
        data["plc"]["retain_file"] = str(retain)
    if at_operating_point:
        net = TankNetwork.from_config(SITE.plant)
        op = operating_point(net, SITE.plant, default_inputs(net, SITE.plant))
        for tank, level in zip(data["plant"]["tanks"], op.equilibrium_levels_m, strict=True):
            tank["initial_level_m"] = float(level)
        for pump, command in zip(data["plant"]["pumps"], op.commands, strict=True):
            pump["initial_command"] = float(command)
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def noisy_site(noise_m: float = 1e-3, seed: int = 1) -> SiteConfig:
    """The default site at its operating point (equilibrium levels) with transmitter noise
    ``noise_m`` [m] (1 mm, a rig's) and noise seed ``seed``: the FDI tests' and benchmark's plant."""
    s = SITE.model_copy(deep=True)
    net = TankNetwork.from_config(s.plant)
    op = operating_point(net, s.plant, default_inputs(net, s.plant))
    for tank, lvl in zip(s.plant.tanks, op.equilibrium_levels_m, strict=True):
        tank.transmitter.noise_std_m = noise_m
        tank.initial_level_m = float(lvl)
    s.plant.noise_seed = seed
    return s
