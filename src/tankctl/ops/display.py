"""How the operator commands show values: enum names, units, table cells, JSON-safe data."""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

from tanklab.tags import Tag

if TYPE_CHECKING:
    from rich.console import Console


def show(tag: Tag, value: Any) -> str:
    """A value as the operator typed or reads it: enum names, %g numbers."""
    if value is None:
        return "-"
    if tag.enum is not None and not isinstance(value, bool):
        try:
            return tag.enum(int(value)).name
        except ValueError:
            return str(value)
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return "[" + ", ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in value) + "]"
    return str(value)


def with_unit(tag: Tag, value: Any) -> str:
    text = show(tag, value)
    return f"{text} {tag.unit}" if tag.unit and tag.unit != "1" and value is not None else text


def num(value: Any, unit: str | None = None) -> str:
    """A number for a table cell: 4 decimals for metres, 4 significant digits otherwise."""
    if value is None or isinstance(value, bool) or not isinstance(value, int | float):
        return "-" if value is None else str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if unit == "m":
        return f"{value:.4f}"
    if isinstance(value, float) and 1e3 <= abs(value) < 1e9:  # model times, scan counts: no exponent
        return f"{value:.1f}"
    return f"{value:.4g}"


def secs(value: Any) -> str:
    """A model time for display: seconds with one decimal."""
    return f"{value:.1f}" if isinstance(value, float) else num(value)


def sci(value: Any) -> str:
    """A gain for a table cell: scientific notation, 3 decimals."""
    if isinstance(value, float) and math.isfinite(value):
        return f"{value:.3e}"
    return num(value)


def enum_name(enum: Any, value: Any) -> Any:
    if value is None or isinstance(value, bool):
        return value
    try:
        return enum(int(value)).name
    except (ValueError, TypeError):
        return value


def plain(value: Any) -> Any:
    """A JSON-safe value: non-finite floats as null, OPC UA structures as plain data."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    from asyncua import ua  # only an asyncua value gets here (never on the relay path)

    if isinstance(value, ua.LocalizedText):
        return value.Text
    if isinstance(value, ua.Range):
        return [float(value.Low), float(value.High)]
    if isinstance(value, ua.EUInformation):
        return value.DisplayName.Text
    if isinstance(value, ua.NodeId):
        return value.to_string()
    if isinstance(value, bytes):
        return value.hex()
    return str(value)


def stdout_console() -> Console:
    """stdout console; 120 columns when not a terminal (pipes, tests) unless COLUMNS says.
    (rich is imported here: a write, which prints one plain line, does not load it.)"""
    from rich.console import Console

    console = Console(markup=False, highlight=False, emoji=False)
    if not console.is_terminal and not os.environ.get("COLUMNS"):
        console.width = 120
    return console


def percent_of(value: Any, rng: tuple[float, float] | None) -> float | None:
    if not isinstance(value, int | float) or rng is None or rng[1] <= rng[0]:
        return None
    return 100.0 * (float(value) - rng[0]) / (rng[1] - rng[0])
