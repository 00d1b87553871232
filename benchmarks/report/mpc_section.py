"""Section 1 of the document: the MPC's step time alone (1a), side by side with cvxpy and do-mpc
on the same QPs (1b, with the backend table and the profile), and the accuracy guard (1c)."""

from __future__ import annotations

from benchmarks.common import Summary, fmt
from benchmarks.mpc import CVXPY_DEFAULT, CVXPY_OSQP, CVXPY_OSQP_TIGHT, DOMPC, LABELS, OURS, OURS_ALT, Series
from benchmarks.report.base import (
    GOAL_NP,
    Report,
    cores_cell,
    find,
    hotspot_table,
    in_ms,
    ratio,
    status_cell,
    table,
)


def mpc_section(rep: Report) -> list[str]:
    lines = [
        "## 1. MPC step time (Kortela configuration)",
        "",
        "`build_mpc(load_site('configs/three_tank_kortela.yaml'))` with `supervisor.mpc.horizon = Np` "
        "(Qz = S = I in SI units, u in [0, 1.2e-4] m^3/s, |du| <= 1e-6 m^3/s per 2.5 s sample, "
        "soft z in [0, 0.63] m, `formulation=auto`: the condensed QP below Np = 200, on daqp). "
        "The closed loop is the nonlinear plant and the PLC "
        "through `CoSimulation(site, supervisor_mode='MPC')` on the benchmark scenario (LIC1's "
        "setpoint +0.05 m at 10 s); every supervisor cycle calls `MpcController.step` once. "
        "The solve (supervisor/mpc/backends.py, decision 0027): daqp's model is set up once, on the QP "
        "without its linear term (shifted by the unconstrained minimiser); each step updates its bounds "
        "and solves hot-started from the previous step's working set. The "
        "other backend, OSQP, runs its tolerance ladder 1e-4 / 1e-5 / 1e-6 with polish, warm-started "
        "from the previous solution shifted by one sample. Goals on step times are stated at the "
        "reference machine speed (`REFERENCE_SPEED_MS` in benchmarks/common.py): a run's times are "
        "scaled by that over the run's own speed reference.",
        "",
        "### 1a. The controller alone",
        "",
        "Closed loop with nothing else timed in the process. *step* = the whole `step(y, r, u_prev)` "
        "call (Kalman filter, input checks, the QP's vectors, the solver, projection, "
        "prediction; the objective is evaluated only when read); *solver* = "
        "`MpcResult.solve_time_s` (daqp's solve time, or OSQP's "
        "own update + solve + polish time over the rungs); iterations are the solver's.",
        "",
    ]
    rows = []
    for r in rep.mpc_alone:
        s = r.series[OURS]
        w, o = in_ms(s.wall), in_ms(s.solver)
        it = Summary.of([float(i) for i in s.iterations])
        rows.append(
            [
                str(r.horizon),
                r.formulation,
                f"{r.qp_size[0]} / {r.qp_size[1]}",
                str(w.n),
                fmt(w.median),
                fmt(w.p99),
                fmt(w.maximum),
                fmt(o.median),
                fmt(o.p99),
                f"{fmt(it.median)} / {fmt(it.p99)}",
                f"{s.path['daqp']} / {s.path['osqp']} / {s.path['held']}",
                status_cell(s),
                cores_cell(r.other_cores),
            ]
        )
    lines += table(
        [
            "Np",
            "form",
            "QP vars / rows",
            "n",
            "step median [ms]",
            "step p99 [ms]",
            "step max [ms]",
            "solver median [ms]",
            "solver p99 [ms]",
            "iterations median / p99",
            "solved by daqp / OSQP / held",
            "status",
            "other load [cores]",
        ],
        rows,
        "rlrrrrrrrlrlr",
    )
    lines += [
        "### 1b. Side by side on the same QPs",
        "",
        "A second closed loop, identical (the co-simulation is deterministic), in which every sample "
        "the same QP is also given, right after the controller's own step, to: the controller with "
        "the other QP form (same y, r, u_prev: its filter sees the same data); cvxpy (the QP built "
        "once with `cp.Parameter`s, DPP, re-solved with `problem.solve(warm_start=True)`); and do-mpc. "
        "The comparators get the state estimate and disturbance the controller's filter produced "
        "(`MpcResult.state`, `.disturbance`), r and u_prev, so all answer the same QP.",
        "",
        "Fairness: every formulation is in the controller's scaled variables (fractions of the "
        "ranges, same weights after scaling, same slack penalties, same hard input and rate bounds, "
        "soft output bounds on z(1..Np)), so a tolerance means the same thing to all. cvxpy + OSQP "
        "runs at eps_abs = eps_rel = 1e-4 with polish (the controller's first rung: where it stops "
        "whenever the polish succeeds; the fastest setting any rung uses, so the ratio is the "
        "conservative one) and again at 1e-6 with polish (the last rung), with max_iter 10000, "
        "check_termination 5 and adaptive_rho_interval 50 as the controller; cvxpy's warm start is "
        "its own (previous solution, not shifted). *cvxpy default* is `problem.solve()` with no "
        "solver named (cvxpy picks the solver and its defaults). do-mpc: a discrete linear model "
        "with the state augmented by the previous input (do-mpc has no rate bounds and its "
        "constraints see x_k, u_k only), slacks as extra inputs with the same penalties, IPOPT "
        "with do-mpc's defaults (tol 1e-8, MUMPS, its own warm start). Timed: the whole call "
        "(`step`, `problem.solve()`, `make_step`) with `time.perf_counter`; *solver* is the "
        "solver's part: OSQP's reported time for ours, `solver_stats.solve_time` for cvxpy, and for "
        "do-mpc the wall time of its `solve()` (the CasADi nlpsol call with IPOPT; CasADi 3.8 "
        "reports no total). |du0| = largest difference of the applied first move from the "
        "controller's, as a fraction of the input range (the QP is nearly flat along move-timing "
        "directions, docs/mpc.md, so first moves agree only to about the tolerance).",
        "",
        "Running the controller and five other solvers interleaved in one process costs the "
        "controller some cache warmth: "
        "its times here are somewhat above those of 1a; the ratios use these side-by-side times. "
        "Each call is timed on the wall clock and on the process's CPU clock (`time.process_time`): "
        "on a machine shared with other work a comparator's call of several milliseconds is "
        "preempted far more often than the controller's step of a fraction of one, so the wall "
        "ratio grows with the machine's load; the CPU ratio is what the calls cost (decision 0059).",
        "",
    ]
    for r in rep.mpc_side:
        ours_s = r.series[OURS]
        lines += [
            f"**Np = {r.horizon}** ({r.formulation}, {r.qp_size[0]} variables / {r.qp_size[1]} rows; "
            f"other form {r.alt_formulation}: {r.alt_qp_size[0]} / {r.alt_qp_size[1]}), {r.steps} samples, "
            f"other work on the machine: {cores_cell(r.other_cores)} cores",
            "",
        ]
        rows = []
        for key in (OURS, OURS_ALT, CVXPY_OSQP, CVXPY_OSQP_TIGHT, CVXPY_DEFAULT, DOMPC):
            sr = r.series.get(key)
            if sr is None:
                continue
            s = sr
            label = LABELS[key]
            if key == OURS:
                label += f" ({r.formulation})"
            elif key == OURS_ALT:
                label = f"tanklab MpcController ({r.alt_formulation})"
            if s.detail and key in (CVXPY_DEFAULT,):
                label += f" [{s.detail}]"
            if not s.wall_s:
                rows.append([label, "-", "-", "-", "-", "-", "-", "-", "-", "-", f"not run: {s.error}"])
                continue
            w, sv, cpu = in_ms(s.wall), in_ms(s.solver), in_ms(s.cpu)
            du = Summary.of(s.du0)
            rows.append(
                [
                    label,
                    fmt(w.median),
                    fmt(w.p99),
                    fmt(cpu.median) if s.cpu_s else "-",
                    fmt(cpu.p99) if s.cpu_s else "-",
                    fmt(sv.median),
                    fmt(sv.p99),
                    "1" if key == OURS else _ratios(s, ours_s, "median"),
                    "1" if key == OURS else _ratios(s, ours_s, "p99"),
                    "-" if key == OURS else f"{fmt(du.median, 2)} / {fmt(du.maximum, 2)}",
                    status_cell(s) + (f"; stopped: {s.error}" if s.error else ""),
                ]
            )
        lines += table(
            [
                "solver",
                "median [ms]",
                "p99 [ms]",
                "CPU median [ms]",
                "CPU p99 [ms]",
                "solver median [ms]",
                "solver p99 [ms]",
                "ratio of medians, CPU (wall)",
                "ratio of p99, CPU (wall)",
                "|du0| median / max",
                "status",
            ],
            rows,
            "lrrrrrrrrrl",
        )
    if rep.mpc_side:
        rows = []
        for r in rep.mpc_side:
            cells = [str(r.horizon)]
            for key in (CVXPY_OSQP, CVXPY_OSQP_TIGHT, CVXPY_DEFAULT, DOMPC):
                other = r.series.get(key)
                if other is None or not other.wall_s:
                    cells.append("n/a")
                    continue
                ours = r.series[OURS]
                cells.append(f"{_ratios(other, ours, 'median')} / {_ratios(other, ours, 'p99')}")
            rows.append(cells)
        lines += [
            "Ratios (comparator time / controller time, side by side; median / p99, each on "
            "CPU time with the wall-time ratio in brackets; the goals use CPU time, decision 0059):",
            "",
            *table(["Np", "cvxpy OSQP 1e-4", "cvxpy OSQP 1e-6", "cvxpy default", "do-mpc"], rows),
            *_side_reading(rep),
            *_form_table(rep),
        ]
    if rep.mpc_profile:
        lines += [
            f"Where a step's time goes (cProfile of every `step` call of the 1a closed loop at "
            f"Np = {rep.mpc_profile_np}, own time; the profiler inflates the Python parts):",
            "",
            *hotspot_table(rep.mpc_profile, 6),
        ]
    lines += _accuracy_section(rep)
    return lines


def _form_table(rep: Report) -> list[str]:
    """daqp against OSQP on the same QPs, from the side-by-side loops (decision 0027)."""
    rows = []
    for r in rep.mpc_side:
        alt = r.series.get(OURS_ALT)
        if alt is None or not alt.wall_s:
            continue
        ours, other = in_ms(r.series[OURS].wall), in_ms(alt.wall)
        du = Summary.of(alt.du0)
        rows.append(
            [
                str(r.horizon),
                r.formulation,
                f"{fmt(ours.median)} / {fmt(ours.p99)}",
                r.alt_formulation,
                f"{fmt(other.median)} / {fmt(other.p99)}",
                f"{fmt(ratio(other.median, ours.median))}x / {fmt(ratio(other.p99, ours.p99))}x",
                fmt(du.maximum, 2),
            ]
        )
    if not rows:
        return []
    return [
        "QP backend, side by side (whole `step` on the same QPs; each sample runs the controller's "
        "own backend first, right after the plant and PLC code, and the other backend second (the "
        "order may favour the second: its data is warm in the cache)):",
        "",
        *table(
            [
                "Np",
                "ours (form, backend)",
                "median / p99 [ms]",
                "other backend",
                "median / p99 [ms]",
                "other / ours, median / p99",
                "max |du0| / range",
            ],
            rows,
            "rlrlrrr",
        ),
    ]


def _side_reading(rep: Report) -> list[str]:
    """What the side-by-side numbers at the goal horizon say (numbers from this run)."""
    r = find(rep.mpc_side, GOAL_NP)
    if r is None:
        return []
    ours, cvx, dompc = r.series[OURS], r.series.get(CVXPY_OSQP), r.series.get(DOMPC)
    out = []
    if cvx is not None and cvx.wall_s:
        du = Summary.of(cvx.du0)
        cvx_over = 1e3 * (cvx.wall.median - cvx.solver.median)
        our_over = 1e3 * (ours.wall.median - ours.solver.median)
        out.append(
            f"Reading (Np = {GOAL_NP}): at the median sample (near the steady state) OSQP inside cvxpy "
            f"takes {fmt(1e3 * cvx.solver.median)} ms, warm-started, plus {fmt(cvx_over)} ms of "
            "cvxpy's per-solve work (parameter update, canonicalisation, result unpacking); our step "
            f"spends {fmt(1e3 * ours.solver.median)} ms in daqp (hot-started: near a steady state the "
            f"working set is the previous one) and {fmt(our_over)} ms in the rest of the step, filter "
            "included. At the p99 (the setpoint-step transient) daqp changes its working set a few "
            "times per sample, against cvxpy's warm-started OSQP at 1e-4. The first moves differ from the "
            f"controller's by up to {fmt(du.maximum, 2)} of the input range"
            + (
                f" (do-mpc's IPOPT at 1e-8: up to {fmt(Summary.of(dompc.du0).maximum, 2)}; this QP is "
                "nearly flat along move-timing directions, so the first move is determined only "
                "loosely, docs/mpc.md)."
                if dompc is not None and dompc.du0
                else "."
            )
        )
    if dompc is not None and dompc.wall_s:
        out.append(
            f"do-mpc spends {fmt(1e3 * dompc.solver.median)} ms of its {fmt(1e3 * dompc.wall.median)} ms "
            "median in IPOPT (an interior-point method: some ten iterations whatever the warm start, "
            "so its time hardly varies between steady state and transient, which is why its p99 ratio "
            "is small) and the rest in do-mpc's own bookkeeping."
        )
    return [" ".join(out), ""] if out else []


def _accuracy_section(rep: Report) -> list[str]:
    if not rep.accuracy:
        return []
    rows = [
        [
            g.scenario,
            g.formulation,
            str(g.steps),
            f"{g.iae[0]:.4f} / {g.iae[1]:.4f}",
            f"{g.iae_ref[0]:.4f} / {g.iae_ref[1]:.4f}",
            f"{g.total_error:.1e}",
            ", ".join(f"{k} {v}" for k, v in sorted(g.statuses.items())),
        ]
        for g in rep.accuracy
    ]
    return [
        "### 1c. Accuracy guard",
        "",
        "Closed-loop IAE (h1, h2) of the controller against the reference: the same filter and QP "
        "solved by cvxpy + CLARABEL in unscaled SI units at tolerances 1e-12 (the test suite's "
        "`ReferenceController` and `closed_loop`, tests/supervisor/test_mpc.py: nonlinear plant of "
        "the OPC UA MPC paper, Np = 40, Qz = S = I). The guard: |IAE - IAE_ref| / IAE_ref, summed "
        "over h1 and h2, within 1 %.",
        "",
        *table(
            ["scenario", "form", "samples", "IAE [m s]", "reference IAE [m s]", "error", "status"],
            rows,
            "llrrrrl",
        ),
    ]


def _ratios(other: Series, ours: Series, stat: str) -> str:
    """``other`` / ``ours`` at the median or p99 as 'CPU (wall)', on CPU time where both were
    timed on it, else '(wall)' alone."""
    wall = ratio(getattr(other.wall, stat), getattr(ours.wall, stat))
    if not (other.cpu_s and ours.cpu_s):
        return f"({fmt(wall)}x)"
    return f"{fmt(ratio(getattr(other.cpu, stat), getattr(ours.cpu, stat)))}x ({fmt(wall)}x)"
