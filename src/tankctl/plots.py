"""One PNG per scenario run: every variant side by side, readable at a glance.

Layout: one column per variant (its name and description as the column title), three rows sharing
the time axis:

1. levels [m]: each controlled level (solid) with its setpoint (dashed, same colour), the
   reference model of an MRAC loop (dotted), uncontrolled tanks in grey;
2. pump flows [m^3/s] with each pump's limits (dotted);
3. gains over time, each divided by its first value (or by its largest magnitude when it starts
   at 0, e.g. the MIT rule's theta2), so gains of different units share one axis (symlog: linear
   within +-1, logarithmic beyond, so a gain that grows 100-fold and one that moves 10 % are both
   visible); the divisor is in the legend. Scans in REMOTE (the MPC drives the pump, the PID gains
   are unused) are shaded and not drawn.

Events (setpoint steps, leaks, disturbances, mode switches) are thin vertical lines labelled at
the top of the level panels. Matplotlib's object API with the Agg canvas: no pyplot, no global
state, safe in tests and servers.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tanklab.enums import LoopMode

if TYPE_CHECKING:
    from tankctl.simulate import ScenarioResult, VariantResult

__all__ = ["plot_scenario"]

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def _controlled(v: VariantResult) -> list[int]:
    """Loops not in MANUAL for the whole run."""
    return [j for j in range(v.modes.shape[1]) if not np.all(v.modes[:, j] == int(LoopMode.MANUAL))]


def _events(ax: Any, events: list[tuple[float, str]], label: bool) -> None:
    for t, text in events:
        ax.axvline(t, color="0.6", lw=0.6, ls=":", zorder=0)
        if label:
            ax.text(
                t,
                1.0,
                f" {text}",
                transform=ax.get_xaxis_transform(),
                rotation=90,
                va="top",
                ha="right",
                fontsize=6,
                color="0.35",
            )


def _levels(ax: Any, v: VariantResult) -> None:
    site = v.site
    assert site.plc is not None
    loops = site.plc.loops
    controlled = _controlled(v)
    tank_colour: dict[int, str] = {}
    for c, j in enumerate(controlled):
        i = site.tank_names.index("T" + loops[j].pv[2:])
        tank_colour[i] = _COLOURS[c % len(_COLOURS)]
    for i, name in enumerate(site.tank_names):
        if i in tank_colour:
            ax.plot(v.t_s, v.levels_m[:, i], color=tank_colour[i], lw=1.3, label=f"h{name[1:]} ({name})")
        else:
            ax.plot(v.t_s, v.levels_m[:, i], color="0.6", lw=0.9, label=f"h{name[1:]} ({name}, uncontrolled)")
    for c, j in enumerate(controlled):
        colour = _COLOURS[c % len(_COLOURS)]
        ax.plot(v.t_s, v.setpoints_m[:, j], color=colour, lw=1.0, ls="--", label=f"{loops[j].name} SP")
        if np.isfinite(v.reference_m[:, j]).any():
            ax.plot(v.t_s, v.reference_m[:, j], color=colour, lw=0.9, ls=":", label=f"{loops[j].name} y_m")
    ax.set_ylabel("level [m]")


def _flows(ax: Any, v: VariantResult) -> None:
    site = v.site
    for p, pump in enumerate(site.plant.pumps):
        colour = _COLOURS[p % len(_COLOURS)]
        ax.plot(v.t_s, v.flows_m3_s[:, p], color=colour, lw=1.1, label=f"{pump.name} -> {pump.feeds}")
        lo, hi = pump.flow_of(pump.command_min), pump.flow_of(pump.command_max)
        ax.axhline(hi, color=colour, lw=0.8, ls=":", label=f"{pump.name} limits")
        ax.axhline(lo, color=colour, lw=0.8, ls=":")
    ax.set_ylabel("pump flow [m$^3$/s]")
    ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 3))


def _gains(ax: Any, v: VariantResult) -> None:
    site = v.site
    assert site.plc is not None
    loops = site.plc.loops
    plotted = False
    for c, j in enumerate(_controlled(v)):
        colour = _COLOURS[c % len(_COLOURS)]
        remote = v.modes[:, j] == int(LoopMode.REMOTE)
        if remote.any():
            ax.fill_between(
                v.t_s, 0, 1, where=remote, transform=ax.get_xaxis_transform(), color=colour, alpha=0.08, lw=0
            )
        if np.mean(remote) > 0.95:
            continue
        for g, (name, ls) in enumerate(zip(v.gain_names[j], ("-", "--", ":"), strict=True)):
            if not name:
                continue
            y = np.where(remote, np.nan, v.gains[:, j, g])
            finite = y[np.isfinite(y)]
            if finite.size == 0 or not np.any(finite != 0):
                continue
            ref = abs(float(finite[0])) if finite[0] != 0 else float(np.max(np.abs(finite)))
            ax.plot(v.t_s, y / ref, color=colour, ls=ls, lw=1.1, label=f"{loops[j].name} {name} / {ref:.3g}")
            plotted = True
    if not plotted:
        ax.text(
            0.5,
            0.5,
            "loops in REMOTE: the MPC drives the pumps\n(PID gains unused)",
            transform=ax.transAxes,
            ha="center",
            va="center",
            fontsize=8,
            color="0.3",
        )
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_ylabel("gain / its first value (symlog)")
    ax.set_xlabel("time [s]")


def plot_scenario(result: ScenarioResult, path: str | Path, *, dpi: int = 110) -> Path:
    """Draw every variant of a run into one PNG at ``path``; return the path."""
    variants = list(result.variants.values())
    n = len(variants)
    fig = Figure(figsize=(4.8 * n + 0.8, 9.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, n, sharex="col", sharey="row", squeeze=False)
    sc = result.scenario
    fig.suptitle(
        f"{sc.name}  ({result.site_path.name}, {result.duration_s:g} s)", fontsize=12, fontweight="bold"
    )
    for c, v in enumerate(variants):
        title = f"{v.name}: " + (v.description or f"supervisor {v.supervisor_mode}")
        axes[0, c].set_title(textwrap.fill(title, 58), fontsize=8.5, loc="left")
        _levels(axes[0, c], v)
        _flows(axes[1, c], v)
        _gains(axes[2, c], v)
        for r in range(3):
            axes[r, c].grid(True, lw=0.4, alpha=0.5)
            _events(axes[r, c], result.events, label=r == 0)
            axes[r, c].set_xlim(0.0, result.duration_s)
        # Levels and gains differ between variants (MRAC y_m, gain names): a legend in every
        # column; the pumps are the same everywhere: a legend in the first column only.
        for r in (0, 1, 2) if c == 0 else (0, 2):
            handles, _ = axes[r, c].get_legend_handles_labels()
            if handles:
                axes[r, c].legend(fontsize=6.5, loc="best", framealpha=0.85)
        if c > 0:
            for r in range(3):
                axes[r, c].set_ylabel("")
    lo = min(float(np.nanmin(v.levels_m)) for v in variants)
    hi = max(float(np.nanmax(np.maximum(v.levels_m, v.setpoints_m.max(initial=-math.inf)))) for v in variants)
    pad = 0.06 * (hi - lo if hi > lo else 1.0)
    axes[0, 0].set_ylim(lo - pad, hi + 3 * pad)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out
