"""Markdown of runs for docs/reproduction.md (regenerated from runs, never hand-copied):
reports, the transfer-function experiment, the MRAC gamma sweep, and the regeneration of the
generated blocks (``python -m tankctl.simulate docs/reproduction.md``)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from tankctl.limits import imc_tf_experiment
from tankctl.simulate.reports import fmt, orderings, published_rows
from tankctl.simulate.results import ScenarioResult
from tankctl.simulate.runner import run_scenario, run_variant
from tanklab.scenario import (
    load_scenario,
)

FloatArray = NDArray[np.float64]


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def markdown_report(result: ScenarioResult, figure: str | None = None) -> str:
    """Markdown of a run: ours beside the paper, every loop metric, the steps with their bounds."""
    parts = []
    rows = published_rows(result)
    if rows:
        parts.append("Ours beside the paper's printed numbers (ours in the units of the note):\n")
        table = []
        for r in rows:
            ratio = r["ours"] / r["paper"] if r["ours"] is not None and r["paper"] else None
            table.append(
                [
                    r["variant"],
                    r["loop"],
                    r["metric"],
                    fmt(r["ours"]),
                    fmt(r["paper"]),
                    fmt(ratio, ".3g"),
                    r["note"],
                ]
            )
        parts.append(_md_table(["variant", "loop", "metric", "ours", "paper", "ours / paper", "note"], table))
        order = orderings(rows)
        if order:
            parts.append("\nOrderings (smaller first):\n")
            parts.append("\n".join(f"- {line.strip()}" for line in order))
    parts.append("\nEvery loop (IAE m s, ISE m^2 s, ITAE m s^2, max du in the pump's unit per scan):\n")
    table = []
    for name, v in result.variants.items():
        for loop, m in v.loops.items():
            table.append(
                [
                    name,
                    loop,
                    fmt(m.iae),
                    fmt(m.ise),
                    fmt(m.itae),
                    fmt(m.overshoot_pct, ".2f"),
                    fmt(m.settling_time_s, ".1f"),
                    fmt(m.max_du, ".3g"),
                    str(m.constraint_violations),
                ]
            )
    parts.append(
        _md_table(
            ["variant", "loop", "IAE", "ISE", "ITAE", "overshoot %", "settling s", "max du", "violations"],
            table,
        )
    )
    parts.append("\nSteps, and the settling time as a multiple of the bang-bang minimum time:\n")
    table = []
    for name, v in result.variants.items():
        for st in v.steps:
            table.append(
                [
                    name,
                    st.loop,
                    f"{st.time_s:g}",
                    f"{st.from_m:.4f} -> {st.setpoint_m:.4f}",
                    f"{st.overshoot_pct:.2f}",
                    fmt(st.settling_time_s, ".1f"),
                    fmt(st.min_time_s, ".3g") + (f" ({st.min_time_method})" if st.min_time_method else ""),
                    fmt(st.settling_ratio, ".3g"),
                ]
            )
    parts.append(
        _md_table(
            [
                "variant",
                "loop",
                "t s",
                "from -> to m",
                "overshoot %",
                "settling s",
                "minimum time s",
                "ratio",
            ],
            table,
        )
    )
    dist = [(name, d) for name, v in result.variants.items() for d in v.disturbances]
    if dist:
        parts.append("\nPlant events: IAE and peak error from the event to the next event (or the end):\n")
        table = [
            [
                name,
                d.loop,
                f"{d.time_s:g}",
                d.event,
                f"{d.window_s:g}",
                fmt(d.iae),
                fmt(d.peak_error_m, ".3g"),
            ]
            for name, d in dist
        ]
        parts.append(
            _md_table(["variant", "loop", "t s", "event", "window s", "IAE m s", "peak abs(e) m"], table)
        )
    if figure:
        parts.append(f"\n![{result.scenario.name}]({figure})")
    return "\n".join(parts) + "\n"


def tf_markdown() -> str:
    """The IMC paper's transfer-function experiment as a markdown table."""
    rows = [
        [
            tf.name,
            f"{tf.Kc:.4f}",
            f"{tf.Ti:.3f}",
            f"{tf.Td:.3f}",
            f"{tf.overshoot_pct:.2f}",
            fmt(tf.settling_time_s, ".2f"),
            f"{tf.disturbance_peak:.4f}",
            f"{tf.iae:.3f}",
        ]
        for tf in imc_tf_experiment()
    ]
    header = [
        "controller",
        "Kc",
        "Ti s",
        "Td s",
        "overshoot %",
        "settling s (2 %)",
        "disturbance peak",
        "IAE",
    ]
    return _md_table(header, rows) + "\n"


MRAC_GAMMAS = (1e-4, 3e-4, 1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0)
"""The gamma grid of the MRAC sweep in docs/reproduction.md."""


def mrac_sweep_markdown(path: str | Path, gammas: Sequence[float] = MRAC_GAMMAS) -> str:
    """The gamma sweep behind mrac_two_tank.yaml's choice: model-following error per law and gamma.

    Every other setting is the scenario's (alpha, bounds, delta, wn); only gamma changes, in both
    loops. "steps settled" = both setpoint steps settled within their windows (a diverging
    adaptation does not).
    """
    scenario, site_path = load_scenario(path)
    rows = []
    for law in ("mit", "api"):
        base = next(v for v in scenario.variants if v.name == law)
        for g in gammas:
            overrides = dict(base.set)
            for key, value in base.set.items():
                if key.endswith(".mrac"):
                    overrides[key] = dict(value, gamma=g)
            run = run_variant(scenario, site_path, base.model_copy(update={"set": overrides}))
            err = np.nanmean(np.abs(run.levels_m - run.reference_m), axis=0)
            settled = all(st.settling_time_s is not None for st in run.steps)
            iaes = [m.iae for m in run.loops.values()]
            chosen = any(
                key.endswith(".mrac") and float(value["gamma"]) == g for key, value in base.set.items()
            )
            rows.append(
                [
                    law + (" (chosen)" if chosen else ""),
                    f"{g:g}",
                    " / ".join(f"{100 * x:.3f}" for x in err),
                    f"{100 * float(np.sum(err)):.3f}",
                    "yes" if settled else "NO",
                    " / ".join(f"{x:.3g}" for x in iaes),
                ]
            )
    header = [
        "law",
        "gamma",
        "mean abs(y - y_m) cm (T1 / T2)",
        "sum cm",
        "steps settled",
        "IAE m s (T1 / T2)",
    ]
    return _md_table(header, rows) + "\n"


_BLOCK = re.compile(
    r"(<!-- generated:(?P<kind>[a-z-]+) (?P<arg>[^ ]+) -->\n)(?P<body>.*?)(<!-- /generated -->)", re.S
)


def regenerate_docs(doc: str | Path, *, root: str | Path = ".") -> list[str]:
    """Rewrite every generated block of ``doc`` from fresh runs; return what was regenerated.

    Blocks: ``<!-- generated:scenario FILE -->`` (markdown_report of the scenario, and its figure
    written to ``docs/figures/<name>.png``), ``<!-- generated:tf imc -->`` (the transfer-function
    experiment), ``<!-- generated:mrac-sweep FILE -->`` (the gamma sweep),
    ``<!-- generated:kortela-notes FILE -->`` and ``<!-- generated:energies-notes FILE -->`` (the
    OPC UA MPC and MPC-based PID papers' findings as sentences) and
    ``<!-- generated:ratios all -->`` (the settling ratios of every scenario run above it), each
    closed by ``<!-- /generated -->``. Paths are relative to ``root``; a scenario runs once.
    """
    from tankctl.doc_notes import energies_notes, kortela_notes, ratio_notes

    base = Path(root)
    doc_path = base / doc
    text = doc_path.read_text(encoding="utf-8")
    done: list[str] = []
    runs: dict[str, ScenarioResult] = {}

    def run(arg: str) -> ScenarioResult:
        if arg not in runs:
            runs[arg] = run_scenario(base / arg)
        return runs[arg]

    def render(m: re.Match[str]) -> str:
        kind, arg = m["kind"], m["arg"]
        if kind == "scenario":
            result = run(arg)
            fig = doc_path.parent / "figures" / f"{result.scenario.name}.png"
            from tankctl.plots import plot_scenario

            plot_scenario(result, fig)
            body = markdown_report(result, f"figures/{fig.name}")
        elif kind == "tf":
            body = tf_markdown()
        elif kind == "mrac-sweep":
            body = mrac_sweep_markdown(base / arg)
        elif kind == "kortela-notes":
            body = kortela_notes(run(arg))
        elif kind == "energies-notes":
            body = energies_notes(run(arg))
        elif kind == "ratios":
            body = ratio_notes({r.scenario.name: r for r in runs.values()})
        else:
            raise ValueError(f"{doc}: unknown generated block {kind!r}")
        done.append(f"{kind} {arg}")
        return m.group(1) + body + m.group(5)

    doc_path.write_text(_BLOCK.sub(render, text), encoding="utf-8")
    return done
