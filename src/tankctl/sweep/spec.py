"""The sweep file: a scenario, the parameters to vary, the draws, the metrics to keep.

A sweep spec (YAML, ``sweeps/*.yaml``, documented in ``docs/sweeps.md``) is validated like the
site configs and scenarios (``extra="forbid"``; one line naming the file, the field and the
rule). Each parameter sets one value at one or more dotted paths (list items by index, as a
scenario variant's ``set:`` does) rooted at ``site.`` (the variant's validated site config, every
default filled in) or ``scenario.`` (the scenario file: its events, duration, initial state).
A parameter takes its values from exactly one of:

- ``values: [v0, v1, ...]``: a grid of given values (numbers, booleans or strings);
- ``linspace: {start, stop, num}``: ``num`` evenly spaced values, both ends included;
- ``uniform: {low, high}``: a draw from U(low, high) per case;
- ``normal: {mean, std, low, high}``: N(mean, std^2) truncated to [low, high] (rejection);
- ``lognormal: {log_mean, log_std, low, high}``: exp(N(log_mean, log_std^2)) truncated to
  [low, high] (rejection).

Grid parameters span a product; the distributed ones are drawn once per case. A truncated
distribution must keep at least :data:`MIN_MASS` of its probability inside its bounds, so that
rejection sampling ends after a few tries.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

from pydantic import Field, model_validator

from tanklab.config import Finite, Model, PositiveFloat, load_model, sibling_file
from tanklab.scenario import LOOP_METRICS, LoopMetricName

__all__ = [
    "LOOP_METRICS",
    "MIN_MASS",
    "Linspace",
    "LogNormal",
    "Normal",
    "Parameter",
    "SweepSpec",
    "Uniform",
    "load_spec",
]


def _default_metrics() -> list[LoopMetricName]:
    return ["iae", "overshoot_pct", "settling_time_s"]


MIN_MASS = 1e-3
"""Least probability a truncated distribution keeps inside its bounds."""

Scalar = bool | int | float | str
PATH = r"^(site|scenario)\.[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*$"


def _phi(z: float) -> float:
    """Standard normal CDF."""
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))


class Linspace(Model):
    """``num`` evenly spaced values from ``start`` to ``stop``, both included."""

    start: Finite = Field(description="First value.")
    stop: Finite = Field(description="Last value.")
    num: Annotated[int, Field(ge=1, le=10_000)] = Field(description="Number of values (1: start only).")

    def grid(self) -> list[float]:
        """The values, computed as start + k (stop - start) / (num - 1)."""
        if self.num == 1:
            return [float(self.start)]
        step = (self.stop - self.start) / (self.num - 1)
        return [float(self.start + k * step) for k in range(self.num - 1)] + [float(self.stop)]


class Uniform(Model):
    """U(low, high)."""

    low: Finite = Field(description="Lower bound.")
    high: Finite = Field(description="Upper bound, above low.")

    @model_validator(mode="after")
    def _order(self) -> Uniform:
        _ordered(self.low, self.high)
        return self


def _ordered(low: float, high: float) -> None:
    if not low < high:
        raise ValueError(f"low ({low:g}) must be below high ({high:g})")


def _enough_mass(z_low: float, z_high: float) -> None:
    """A truncation to the standard-normal interval [z_low, z_high] keeps at least MIN_MASS."""
    mass = _phi(z_high) - _phi(z_low)
    if mass < MIN_MASS:
        raise ValueError(f"[low, high] holds {mass:.2g} of the distribution, less than {MIN_MASS:g}")


class Normal(Model):
    """N(mean, std^2) truncated to [low, high]."""

    mean: Finite = Field(description="Mean.")
    std: PositiveFloat = Field(description="Standard deviation, > 0.")
    low: Finite = Field(description="Lower bound (draws below are drawn again).")
    high: Finite = Field(description="Upper bound, above low.")

    @model_validator(mode="after")
    def _bounds(self) -> Normal:
        _ordered(self.low, self.high)
        _enough_mass((self.low - self.mean) / self.std, (self.high - self.mean) / self.std)
        return self


class LogNormal(Model):
    """exp(N(log_mean, log_std^2)) truncated to [low, high], 0 < low < high."""

    log_mean: Finite = Field(description="Mean of the logarithm.")
    log_std: PositiveFloat = Field(description="Standard deviation of the logarithm, > 0.")
    low: PositiveFloat = Field(description="Lower bound, > 0.")
    high: PositiveFloat = Field(description="Upper bound, above low.")

    @model_validator(mode="after")
    def _bounds(self) -> LogNormal:
        _ordered(self.low, self.high)
        z_lo = (math.log(self.low) - self.log_mean) / self.log_std
        _enough_mass(z_lo, (math.log(self.high) - self.log_mean) / self.log_std)
        return self


class Parameter(Model):
    """One swept quantity: a name, the paths it sets, where its values come from."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$", description="Column name in the results.")
    paths: list[Annotated[str, Field(pattern=PATH)]] = Field(
        min_length=1,
        description="Dotted paths the value is written to, each rooted at site. or scenario.",
    )
    values: list[Scalar] | None = Field(None, min_length=1, description="Grid: the values, in order.")
    linspace: Linspace | None = Field(None, description="Grid: evenly spaced values.")
    uniform: Uniform | None = Field(None, description="Drawn per case: uniform.")
    normal: Normal | None = Field(None, description="Drawn per case: truncated normal.")
    lognormal: LogNormal | None = Field(None, description="Drawn per case: truncated lognormal.")

    @model_validator(mode="after")
    def _one_source(self) -> Parameter:
        given = [k for k in ("values", "linspace", "uniform", "normal", "lognormal") if getattr(self, k)]
        if len(given) != 1:
            raise ValueError(
                "needs exactly one of values, linspace, uniform, normal, lognormal"
                + (f" (got {', '.join(given)})" if given else "")
            )
        return self

    @property
    def is_grid(self) -> bool:
        """Whether the parameter spans a grid (else it is drawn per case)."""
        return self.values is not None or self.linspace is not None

    def grid(self) -> list[Scalar]:
        """The grid values (a grid parameter only)."""
        if self.values is not None:
            return list(self.values)
        if self.linspace is not None:
            return list(self.linspace.grid())
        raise ValueError(f"{self.name} is drawn, not a grid")

    @property
    def distribution(self) -> Uniform | Normal | LogNormal:
        """The distribution (a drawn parameter only)."""
        dist = self.uniform or self.normal or self.lognormal
        if dist is None:
            raise ValueError(f"{self.name} is a grid, not drawn")
        return dist


class SweepSpec(Model):
    """A sweep file."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$", description="Sweep name.")
    description: str = Field("", description="What the sweep asks.")
    scenario: str = Field(description="Scenario file, relative to the sweep file.")
    variants: list[str] | None = Field(
        None, min_length=1, description="Scenario variants to run each case with (default: every variant)."
    )
    duration_s: PositiveFloat | None = Field(None, description="Run length [s] instead of the scenario's.")
    parameters: list[Parameter] = Field(default_factory=list, description="The swept parameters.")
    draws: Annotated[int, Field(ge=1, le=1_000_000)] = Field(
        1, description="Monte Carlo draws per grid point (each with its own seed)."
    )
    seed: Annotated[int, Field(ge=0)] = Field(0, description="Root seed of every case's seed.")
    metrics: list[LoopMetricName] = Field(
        default_factory=_default_metrics,
        min_length=1,
        description=f"Loop metrics to keep, among {', '.join(LOOP_METRICS)}.",
    )
    loops: list[str] | None = Field(
        None, min_length=1, description="Loops to keep metrics of (default: all)."
    )

    @model_validator(mode="after")
    def _unique(self) -> SweepSpec:
        names = [p.name for p in self.parameters]
        if len(set(names)) != len(names):
            raise ValueError("parameter names must be unique")
        paths = [path for p in self.parameters for path in p.paths]
        if len(set(paths)) != len(paths):
            raise ValueError("a path may be set by one parameter only")
        reserved = {"case", "variant", "seed", "status", "error", "worker", "wall_s"}
        clash = reserved & set(names)
        if clash:
            raise ValueError(f"parameter name {sorted(clash)[0]!r} is a results column")
        if len(set(self.metrics)) != len(self.metrics):
            raise ValueError("metrics must be unique")
        return self

    @property
    def grid_parameters(self) -> list[Parameter]:
        """The grid parameters, in file order."""
        return [p for p in self.parameters if p.is_grid]

    @property
    def drawn_parameters(self) -> list[Parameter]:
        """The drawn parameters, in file order."""
        return [p for p in self.parameters if not p.is_grid]


def load_spec(path: str | Path) -> tuple[SweepSpec, Path]:
    """Read and validate a sweep file; return it and the resolved scenario file path.

    Raises
    ------
    ConfigError
        One line naming the file, the field and the rule.
    """
    p = Path(path)
    spec = load_model(p, SweepSpec)
    return spec, sibling_file(p, "scenario", spec.scenario)
