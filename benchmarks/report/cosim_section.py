"""Section 2 of the document: co-simulation speed, its hot spots and where a PID-run scan goes."""

from __future__ import annotations

from benchmarks.common import Summary, fmt
from benchmarks.cosim import plant_substeps
from benchmarks.report.base import Report, cores_cell, hotspot_table, table


def cosim_section(rep: Report) -> list[str]:
    if not rep.cosim:
        return []
    lines = [
        "## 2. Co-simulation speed",
        "",
        "`CoSimulation(load_site('configs/three_tank_energies_sim.yaml'), supervisor_mode=...)` "
        "(the default config: 1 s scans; the plant's RK4 with its automatic sub-step, "
        f"{fmt(plant_substeps()[1])} s here, docs/plant.md), the benchmark scenario: "
        "1000 s of model time, LIC1's setpoint +0.05 m at 10 s. Wall time of `run` (construction "
        "excluded), repeated; real-time factor = 1000 s / median wall time. ADVISORY (the default "
        "config's supervisor mode: shadow MPC at Np = 10 + RLS every scan) is shown because it is "
        "what the lock-step run below computes each scan.",
        "",
    ]
    rows = []
    for res in rep.cosim:
        w = Summary.of(res.wall_s)
        rows.append(
            [
                res.label,
                str(w.n),
                str(res.scans),
                fmt(w.median),
                fmt(w.p99),
                fmt(w.minimum),
                f"{res.model_s / w.median:,.0f}x",
                fmt(1e3 * w.median / res.scans),
                cores_cell(res.other_cores),
            ]
        )
    lines += table(
        [
            "run",
            "n",
            "scans",
            "wall median [s]",
            "wall p99 [s]",
            "wall min [s]",
            "real-time factor (median)",
            "wall per scan [ms]",
            "other load [cores]",
        ],
        rows,
    )
    lines += [
        "### Hot spots",
        "",
        "cProfile of one more run of each (own time, i.e. excluding callees; the profiler roughly "
        "doubles the Python-heavy parts, so read the shares).",
        "",
    ]
    for res in rep.cosim:
        lines += [
            f"**{res.label}** (profiled total {fmt(res.profiled_total_s)} s)",
            "",
            *hotspot_table(res.profile),
        ]
    lines += _cosim_reading(rep)
    return lines


def _cosim_reading(rep: Report) -> list[str]:
    pid = next((r for r in rep.cosim if r.mode is None), None)
    if pid is None or not pid.parts:
        return []
    per_scan = 1e3 * Summary.of(pid.wall_s).median / pid.scans
    rows = [[label, fmt(100 * share, 2)] for label, share in pid.parts.items() if share > 0]
    steps, h = plant_substeps()
    return [
        "Where a PID-run scan goes (cumulative share of the profiled time; the profiler inflates the "
        "Python-heavy parts):",
        "",
        *table(["part", "share [%]"], rows, "lr"),
        f"Reading: at {fmt(per_scan)} ms per scan the PID co-simulation runs {fmt(1000.0 / per_scan)}x "
        "real time; 20,000x needs 0.05 ms per scan for the plant, the PLC program and the trace "
        f"together. The plant integrates a scan in {steps} RK4 step{'s' if steps > 1 else ''} of "
        f"{fmt(h)} s ({4 * steps} right-hand sides), the sub-step its stiffness bound allows outside "
        "the 5 mm zone around the orifice law's non-smooth points (steps that come near one are "
        "redone finely), checked against solve_ivp to 1e-6 m (docs/plant.md).",
        "",
    ]
