"""Reading a site: YAML, environment overrides, endpoint URLs, one-line errors, the JSON schema."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from tanklab.config.site import Endpoint, SiteConfig
from tanklab.errors import ConfigError

ENV_ENDPOINT_VARS = {
    "plant": "TANKLAB_PLANT_URL",
    "plc": "TANKLAB_PLC_URL",
    "supervisor": "TANKLAB_SUPERVISOR_URL",
}

_URL = re.compile(r"^opc\.tcp://(?P<host>[^:/]+):(?P<port>\d+)(/.*)?$")


def parse_endpoint_url(url: str) -> Endpoint:
    """Parse ``opc.tcp://host:port[/path]`` into an :class:`Endpoint`.

    Raises
    ------
    ValueError
        If the URL is not of that form or the port is out of range.
    """
    m = _URL.match(url.strip())
    if not m:
        raise ValueError(f"not an opc.tcp://HOST:PORT URL: {url!r}")
    return Endpoint(host=m["host"], port=int(m["port"]))


def format_validation_error(path: str | Path, err: ValidationError) -> str:
    """One line: ``FILE: FIELD: RULE`` for the first error (and a count of the others)."""
    first = err.errors()[0]
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in first["loc"]).replace(".[", "[")
    more = len(err.errors()) - 1
    suffix = f" (and {more} more error{'s' if more > 1 else ''})" if more else ""
    msg = first["msg"].replace("Value error, ", "")
    return f"{path}: {loc or '(top level)'}: {msg}{suffix}"


_FAST_LOADER: Any = getattr(yaml, "CSafeLoader", None)
"""PyYAML's libyaml-based safe loader, when PyYAML was built with libyaml (else None)."""


def _safe_load(text: str) -> Any:
    """``yaml.safe_load(text)``, parsed by libyaml when available (a site file in about a tenth
    of the time; the objects are made by the same safe constructor). A document libyaml
    refuses is parsed again by the pure-Python loader, so an error names the same line and
    problem as before."""
    if _FAST_LOADER is not None:
        try:
            return yaml.load(text, Loader=_FAST_LOADER)  # the C twin of SafeLoader
        except yaml.YAMLError:
            pass
    return yaml.safe_load(text)


def read_yaml(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{path}: cannot read: {e.strerror or e}") from e
    try:
        return _safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(parse)"
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ConfigError(f"{path}: {where}: invalid YAML: {problem}") from e


ModelT = TypeVar("ModelT", bound=BaseModel)


def load_model(path: Path, model: type[ModelT]) -> ModelT:
    """Read a YAML file whose top level is a mapping and validate it as ``model`` (a scenario, a
    sweep spec).

    Raises
    ------
    ConfigError
        One line naming the file, the field and the rule.
    """
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: (top level): expected a mapping, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(path, e)) from e


def sibling_file(path: Path, field: str, name: str) -> Path:
    """The file ``name`` that field ``field`` of the file ``path`` names, relative to ``path``'s
    directory, resolved; ConfigError naming the field when there is no such file."""
    resolved = (path.parent / name).resolve()
    if not resolved.exists():
        raise ConfigError(f"{path}: {field}: no such file {name}")
    return resolved


def site_from_mapping(data: Any, source: str | Path = "<memory>") -> SiteConfig:
    """Validate a mapping (already parsed YAML) as a :class:`SiteConfig`.

    Raises
    ------
    ConfigError
        One line naming ``source``, the field and the rule.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: (top level): expected a mapping of sections, got {type(data).__name__}")
    try:
        return SiteConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(source, e)) from e


def load_site(path: str | Path, *, env: Mapping[str, str] | None = None) -> SiteConfig:
    """Read and validate a site YAML file, then apply endpoint overrides from ``env``.

    Parameters
    ----------
    path
        The YAML file.
    env
        Environment to read ``TANKLAB_PLANT_URL``, ``TANKLAB_PLC_URL`` and
        ``TANKLAB_SUPERVISOR_URL`` from; ``None`` means no overrides (pure). The CLI passes
        ``os.environ``.
    """
    p = Path(path)
    site = site_from_mapping(read_yaml(p), p)
    if env:
        apply_env_overrides(site, env, source=str(p))
    return site


def apply_env_overrides(site: SiteConfig, env: Mapping[str, str], source: str = "<env>") -> None:
    """Replace endpoints by the ``TANKLAB_*_URL`` variables present in ``env`` (in place)."""
    for tier, var in ENV_ENDPOINT_VARS.items():
        url = env.get(var)
        if url:
            try:
                setattr(site.endpoints, tier, parse_endpoint_url(url))
            except ValueError as e:
                raise ConfigError(f"{source}: {var}: {e}") from e


def default_config_path() -> Path:
    """The default site config (``TANKLAB_CONFIG`` or configs/three_tank_energies_sim.yaml)."""
    env = os.environ.get("TANKLAB_CONFIG")
    if env:
        return Path(env)
    return Path("configs/three_tank_energies_sim.yaml")


def site_schema() -> dict[str, Any]:
    """JSON schema of the site file (what `tankctl config schema` prints)."""
    return SiteConfig.model_json_schema()
