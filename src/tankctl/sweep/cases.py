"""Cases of a sweep: the grid product times the draws, each case's seed and drawn values,
and each case's scenario and site (pure: no clock, no I/O beyond reading the scenario's files).

With grid parameters g_1 .. g_m of sizes n_1 .. n_m (file order) and D draws, the cases are

    case c = (i_1, ..., i_m, d),  c = ((i_1 n_2 + i_2) n_3 + ... + i_m) D + d,

the last grid parameter varying fastest, then the draw. Case c's random numbers come from
``numpy.random.SeedSequence(seed, spawn_key=(c,))``, which is the c-th child of
``SeedSequence(seed).spawn(...)``: the drawn parameters (file order) are drawn from
``default_rng`` on it, and its first 32-bit word is the case's ``seed``, written into the plant's
``noise_seed`` (unless a parameter sets that path). A case's values and seed therefore depend on
(spec seed, c) only: one worker or many, in any order, give the same rows.

Every case runs with each chosen variant of the scenario (one result row per case and variant);
variants share a case's seed and values, so they are compared on the same draws.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from tankctl.sweep.spec import LogNormal, Normal, Parameter, Scalar, SweepSpec, Uniform
from tanklab.config import ConfigError, SiteConfig, format_validation_error, site_from_mapping
from tanklab.scenario import Scenario, apply_overrides, check_against_site, load_scenario, variant_site

__all__ = [
    "MAX_REJECTIONS",
    "NOISE_SEED_PATH",
    "Case",
    "CaseTask",
    "Plan",
    "case_seed",
    "case_setup",
    "draw",
    "expand",
    "plan_sweep",
]

NOISE_SEED_PATH = "site.plant.noise_seed"
"""Where a case's seed goes (the plant's transmitter-noise generator)."""

MAX_REJECTIONS = 100_000
"""Most draws a truncated distribution takes for one value (at MIN_MASS = 1e-3 the chance of
needing more is exp(-100), so hitting it means a bug, and it raises)."""


@dataclass(frozen=True)
class Case:
    """One point of the sweep: its index, parameter values (by name), and seed."""

    index: int
    values: dict[str, Scalar]
    seed: int


@dataclass(frozen=True)
class CaseTask:
    """What a worker needs to run one case with one variant (small and picklable)."""

    spec: SweepSpec
    scenario_path: str
    case: Case
    variant: str
    loops: tuple[str, ...]


def case_seed(root_seed: int, index: int) -> np.random.SeedSequence:
    """The seed sequence of case ``index``: the ``index``-th spawned child of ``root_seed``."""
    return np.random.SeedSequence(root_seed, spawn_key=(index,))


def draw(dist: Uniform | Normal | LogNormal, rng: np.random.Generator) -> float:
    """One value of ``dist`` (truncated ones by rejection).

    Raises
    ------
    RuntimeError
        If :data:`MAX_REJECTIONS` draws all fell outside the bounds (impossible for a validated
        distribution short of a broken generator).
    """
    if isinstance(dist, Uniform):
        return float(rng.uniform(dist.low, dist.high))
    for _ in range(MAX_REJECTIONS):
        if isinstance(dist, Normal):
            x = float(rng.normal(dist.mean, dist.std))
        else:
            x = float(math.exp(rng.normal(dist.log_mean, dist.log_std)))
        if dist.low <= x <= dist.high:
            return x
    raise RuntimeError(f"no draw inside [{dist.low:g}, {dist.high:g}] in {MAX_REJECTIONS} tries")


def expand(spec: SweepSpec) -> list[Case]:
    """Every case of ``spec``, in case order (see the module docstring)."""
    grids = spec.grid_parameters
    drawn = spec.drawn_parameters
    cases: list[Case] = []
    index = 0
    for point in itertools.product(*(p.grid() for p in grids)):
        for _ in range(spec.draws):
            ss = case_seed(spec.seed, index)
            rng = np.random.default_rng(ss)
            values: dict[str, Scalar] = {p.name: v for p, v in zip(grids, point, strict=True)}
            for p in drawn:
                values[p.name] = draw(p.distribution, rng)
            seed = int(ss.generate_state(1, dtype=np.uint32)[0])
            ordered = {p.name: values[p.name] for p in spec.parameters}
            cases.append(Case(index, ordered, seed))
            index += 1
    return cases


def _walk(data: Any, dotted: str) -> None:
    """Raise KeyError naming the first missing step if ``dotted`` does not exist in ``data``."""
    node = data
    done: list[str] = []
    for part in dotted.split("."):
        done.append(part)
        if isinstance(node, list):
            try:
                node = node[int(part)]
            except (ValueError, IndexError):
                raise KeyError(f"no list item {part} at {'.'.join(done[:-1]) or '(top)'}") from None
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            raise KeyError(f"no field {part!r} at {'.'.join(done[:-1]) or '(top)'}")


def _overrides(parameters: Sequence[Parameter], values: Mapping[str, Scalar], root: str) -> dict[str, Any]:
    prefix = root + "."
    return {
        path[len(prefix) :]: values[p.name] for p in parameters for path in p.paths if path.startswith(prefix)
    }


def case_setup(
    spec: SweepSpec,
    scenario: Scenario,
    site_path: Path,
    variant_name: str,
    values: Mapping[str, Scalar],
    seed: int,
) -> tuple[Scenario, SiteConfig]:
    """The scenario and the site config one case runs with one variant.

    The scenario paths are set on the validated scenario (then validated again), the site paths
    on the variant's validated site (every default present, so any field can be swept), after
    the seed went into ``plant.noise_seed``.

    Raises
    ------
    ConfigError
        A path that does not exist, or a value its field refuses (one line naming the parameter).
    """
    where = f"{spec.name}: variant {variant_name}"
    scen_over = _overrides(spec.parameters, values, "scenario")
    if scen_over:
        data = scenario.model_dump(mode="python")
        for path in scen_over:
            try:
                _walk(data, path)
            except KeyError as e:
                raise ConfigError(f"{where}: parameter path scenario.{path}: {e.args[0]}") from None
        try:
            scenario = Scenario.model_validate(apply_overrides(data, scen_over))
        except ValidationError as e:
            raise ConfigError(format_validation_error(f"{where} (scenario overrides)", e)) from None
    variant = next((v for v in scenario.variants if v.name == variant_name), None)
    if variant is None:
        known = ", ".join(v.name for v in scenario.variants)
        raise ConfigError(
            f"{spec.name}: variants: scenario {scenario.name} has no variant {variant_name!r}; known: {known}"
        )
    site = variant_site(scenario, site_path, variant)
    data = site.model_dump(mode="python")
    data["plant"]["noise_seed"] = seed
    site_over = _overrides(spec.parameters, values, "site")
    for path in site_over:
        try:
            _walk(data, path)
        except KeyError as e:
            raise ConfigError(f"{where}: parameter path site.{path}: {e.args[0]}") from None
    site = site_from_mapping(apply_overrides(data, site_over), f"{where} (site overrides)")
    check_against_site(scenario, site)
    return scenario, site


@dataclass(frozen=True)
class Plan:
    """A checked sweep: the spec, its scenario, variants, loops, cases and result columns."""

    spec: SweepSpec
    scenario_path: Path
    variants: tuple[str, ...]
    loops: tuple[str, ...]
    cases: tuple[Case, ...]

    @property
    def metric_columns(self) -> list[str]:
        """``<loop>.<metric>`` for every kept loop and metric."""
        return [f"{loop}.{m}" for loop in self.loops for m in self.spec.metrics]

    def tasks(self) -> list[CaseTask]:
        """One task per case and variant, case-major."""
        return [
            CaseTask(self.spec, str(self.scenario_path), c, v, self.loops)
            for c in self.cases
            for v in self.variants
        ]


def _probe_values(spec: SweepSpec) -> list[dict[str, Scalar]]:
    """Value sets that together try every grid value once (the others at their first value)
    and every distribution at its bounds: what the pre-flight validates."""
    base: dict[str, Scalar] = {}
    for p in spec.parameters:
        base[p.name] = p.grid()[0] if p.is_grid else p.distribution.low
    probes = [dict(base)]
    for p in spec.parameters:
        others = p.grid()[1:] if p.is_grid else [p.distribution.high]
        for v in others:
            probes.append({**base, p.name: v})
    return probes


def plan_sweep(spec: SweepSpec, scenario_path: Path) -> Plan:
    """Check a sweep before any case runs and expand its cases.

    Every variant is set up with every grid value and every distribution bound (a path that
    does not exist or a value out of its field's range is found here, not in case 731), and the
    kept loops must exist in the site.

    Raises
    ------
    ConfigError
        One line: the sweep, the variant or parameter, and the rule.
    """
    scenario, site_path = load_scenario(scenario_path)
    variants = tuple(spec.variants) if spec.variants else tuple(v.name for v in scenario.variants)
    if len(set(variants)) != len(variants):
        raise ConfigError(f"{spec.name}: variants: names must be unique")
    loops: tuple[str, ...] = ()
    for name in variants:
        for values in _probe_values(spec):
            _, site = case_setup(spec, scenario, site_path, name, values, 0)
            if not loops:
                site_loops = tuple(site.loop_names)
                if spec.loops:
                    missing = [lp for lp in spec.loops if lp not in site_loops]
                    if missing:
                        raise ConfigError(
                            f"{spec.name}: loops: the site has no loop {missing[0]}; "
                            f"known: {', '.join(site_loops)}"
                        )
                    loops = tuple(spec.loops)
                else:
                    loops = site_loops
    return Plan(spec, scenario_path, variants, loops, tuple(expand(spec)))
