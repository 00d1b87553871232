"""The reports of a run: the CSV files, the text summary, and the comparison with the papers'
printed numbers (``tankctl compare``)."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tankctl.limits import imc_tf_experiment
from tankctl.simulate.results import ScenarioResult
from tanklab.enums import LoopMode

FloatArray = NDArray[np.float64]


def csv_paths(out: str | Path, names: Sequence[str]) -> dict[str, Path]:
    """Where ``--csv OUT`` writes each variant (see the module docstring).

    OUT is a directory when it exists as one or is written with a trailing ``/`` (pass a str:
    ``Path`` drops the slash); otherwise a file stem.
    """
    path = Path(out)
    if path.is_dir() or str(out).endswith(("/", "\\")):
        return {name: path / f"{name}.csv" for name in names}
    stem = path.with_suffix("") if path.suffix.lower() == ".csv" else path
    return {name: stem.parent / f"{stem.name}_{name}.csv" for name in names}


def write_csv(result: ScenarioResult, out: str | Path) -> list[Path]:
    """Write one CSV per variant; return the files written.

    Columns: ``t_s``, ``level_<tank>_m``, ``sp_<loop>_m``, ``mode_<loop>``,
    ``command_<pump>`` (pump unit), ``flow_<pump>_m3_s``, ``<loop>_<gain>`` (block units), and
    ``ym_<loop>_m`` (reference-model output) for MRAC loops.
    """
    paths = csv_paths(out, list(result.variants))
    written = []
    for name, v in result.variants.items():
        site = v.site
        header = ["t_s"]
        header += [f"level_{t}_m" for t in site.tank_names]
        header += [f"sp_{lp}_m" for lp in site.loop_names]
        header += [f"mode_{lp}" for lp in site.loop_names]
        header += [f"command_{p}" for p in site.pump_names]
        header += [f"flow_{p}_m3_s" for p in site.pump_names]
        gain_cols = [
            (j, g, f"{lp}_{label}")
            for j, lp in enumerate(site.loop_names)
            for g, label in enumerate(v.gain_names[j])
            if label
        ]
        header += [c for _, _, c in gain_cols]
        ym_cols = [j for j in range(len(site.loop_names)) if np.isfinite(v.reference_m[:, j]).any()]
        header += [f"ym_{site.loop_names[j]}_m" for j in ym_cols]
        path = paths[name]
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for k in range(v.t_s.size):
                row: list[Any] = [f"{v.t_s[k]:.6g}"]
                row += [repr(float(x)) for x in v.levels_m[k]]
                row += [repr(float(x)) for x in v.setpoints_m[k]]
                row += [LoopMode(int(m)).name for m in v.modes[k]]
                row += [repr(float(x)) for x in v.commands[k]]
                row += [repr(float(x)) for x in v.flows_m3_s[k]]
                row += [repr(float(v.gains[k, j, g])) for j, g, _ in gain_cols]
                row += [repr(float(v.reference_m[k, j])) for j in ym_cols]
                w.writerow(row)
        written.append(path)
    return written


def fmt(x: float | int | None, spec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "-"
    return format(x, spec)


def summary_text(result: ScenarioResult) -> str:
    """The readable table ``tankctl simulate`` prints without ``--json``."""
    sc = result.scenario
    lines = [f"scenario {sc.name}: {result.duration_s:g} s, site {result.site_path.name}"]
    lines.append(
        f"settling band {sc.settling_band * 100:g} % of each step; IAE in m s, ISE m^2 s, ITAE m s^2"
    )
    for name, v in result.variants.items():
        lines.append("")
        desc = f" - {v.description}" if v.description else ""
        lines.append(f"[{name}] supervisor {v.supervisor_mode}, scan {v.ts_s:g} s{desc}")
        lines.append(
            f"  {'loop':<6}{'IAE':>11}{'ISE':>11}{'ITAE':>11}{'OS %':>8}{'ts s':>9}{'max du':>11}{'viol':>6}"
        )
        for loop, m in v.loops.items():
            lines.append(
                f"  {loop:<6}{fmt(m.iae):>11}{fmt(m.ise):>11}{fmt(m.itae):>11}"
                f"{fmt(m.overshoot_pct, '.2f'):>8}{fmt(m.settling_time_s, '.1f'):>9}"
                f"{fmt(m.max_du, '.3g'):>11}{m.constraint_violations:>6}"
            )
        if v.steps:
            lines.append(
                f"  {'step':<6}{'t s':>8}{'from m':>9}{'to m':>9}{'OS %':>8}{'ts s':>9}"
                f"{'t_min s':>10}{'ratio':>8}"
            )
            for s in v.steps:
                lines.append(
                    f"  {s.loop:<6}{s.time_s:>8.6g}{s.from_m:>9.4f}{s.setpoint_m:>9.4f}"
                    f"{s.overshoot_pct:>8.2f}{fmt(s.settling_time_s, '.1f'):>9}"
                    f"{fmt(s.min_time_s, '.3g'):>10}{fmt(s.settling_ratio, '.3g'):>8}"
                )
    return "\n".join(lines)


def _our_value(result: ScenarioResult, variant: str, loop: str, metric: str) -> float | None:
    v = result.variants.get(variant)
    if v is None or loop not in v.loops:
        return None
    value = v.loops[loop].as_dict().get(metric)
    return None if value is None else float(value)


def published_rows(result: ScenarioResult) -> list[dict[str, Any]]:
    """One row per published number: variant, loop, metric, ours, paper, note."""
    rows = []
    for pm in result.scenario.published:
        rows.append(
            {
                "variant": pm.variant,
                "loop": pm.loop,
                "metric": pm.metric,
                "ours": _our_value(result, pm.variant, pm.loop, pm.metric),
                "paper": pm.value,
                "note": pm.note,
            }
        )
    return rows


def orderings(rows: list[dict[str, Any]]) -> list[str]:
    """For each (loop, metric) with two or more published variants: the paper's order and ours."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["loop"], r["metric"]), []).append(r)
    out = []
    for (loop, metric), rs in groups.items():
        if len(rs) < 2 or any(r["ours"] is None for r in rs):
            continue
        paper = " < ".join(r["variant"] for r in sorted(rs, key=lambda r: r["paper"]))
        ours = " < ".join(r["variant"] for r in sorted(rs, key=lambda r: r["ours"]))
        verdict = "same order" if paper == ours else "DIFFERENT order"
        out.append(f"  {loop} {metric}: paper {paper}; ours {ours} ({verdict})")
    return out


TF_REFERENCES = {"imc_pi_coupled"}
"""Scenarios whose paper ran on a transfer function: `compare` also prints that experiment."""


def compare_text(result: ScenarioResult) -> str:
    """The table ``tankctl compare`` prints: our metrics beside the paper's published ones."""
    sc = result.scenario
    lines = [f"scenario {sc.name}: our metrics beside the paper's (units: ours; see notes)"]
    rows = published_rows(result)
    if rows:
        lines.append(
            f"  {'variant':<12}{'loop':<6}{'metric':<17}{'ours':>11}{'paper':>11}{'ours/paper':>11}  note"
        )
        for r in rows:
            ratio = r["ours"] / r["paper"] if r["ours"] is not None and r["paper"] else None
            lines.append(
                f"  {r['variant']:<12}{r['loop']:<6}{r['metric']:<17}{fmt(r['ours']):>11}"
                f"{fmt(r['paper']):>11}{fmt(ratio, '.3g'):>11}  {r['note']}"
            )
        order = orderings(rows)
        if order:
            lines.append("orderings (smaller first):")
            lines.extend(order)
    else:
        lines.append("  (the paper printed no metric for this scenario)")
    lines.append("settling time / minimum-time (bang-bang) bound, per step:")
    lines.append(f"  {'variant':<12}{'loop':<6}{'t s':>8}{'to m':>9}{'ts s':>9}{'t_min s':>10}{'ratio':>9}")
    for name, v in result.variants.items():
        for s in v.steps:
            lines.append(
                f"  {name:<12}{s.loop:<6}{s.time_s:>8.6g}{s.setpoint_m:>9.4f}"
                f"{fmt(s.settling_time_s, '.1f'):>9}{fmt(s.min_time_s, '.3g'):>10}"
                f"{fmt(s.settling_ratio, '.3g'):>9}"
            )
    if sc.name in TF_REFERENCES:
        lines.append("")
        lines.append(
            "the paper's own experiment, on its transfer function 28.82 / (29.6 s^2 + 14.7 s + 1) "
            "(scipy.signal; unit SP step at 0 s, 10 % input disturbance at 50 s; 2 % band):"
        )
        lines.append(f"  {'controller':<42}{'Kc':>8}{'Ti s':>8}{'Td s':>8}{'OS %':>8}{'ts s':>8}{'IAE':>8}")
        for tf in imc_tf_experiment():
            lines.append(
                f"  {tf.name:<42}{tf.Kc:>8.4f}{tf.Ti:>8.3f}{tf.Td:>8.3f}{tf.overshoot_pct:>8.2f}"
                f"{fmt(tf.settling_time_s, '.2f'):>8}{tf.iae:>8.3f}"
            )
        lines.append(
            "  digest 2.7: IMC PID first order (tau 1 s), PI without Td 35.7 % and 19 s; "
            "paper's Kc 0.5091, Ti 14.714 s"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Markdown (docs/reproduction.md is regenerated from runs, never hand-copied)
# --------------------------------------------------------------------------------------------
