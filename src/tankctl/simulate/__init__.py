"""``tankctl simulate`` and ``tankctl compare``: scenarios in the in-process co-simulation.

A scenario (:mod:`tanklab.scenario`, ``configs/scenarios/*.yaml``, documented in
``docs/scenarios.md``) runs once per controller variant. Each run wires the same pure cores the
processes use (:class:`tankctl.cosim.CoSimulation`: plant, PLC scan, supervisor cycle) on a
virtual clock:

    for each scan k (t_k = k Ts):  apply the events due (at_s <= t_k)  ->  PLC scan  ->  supervisor
                                   cycle  ->  plant advances Ts

An event at ``at_s`` acts before the first scan at or after it (scan ``ceil(at_s / Ts)``); events
after the end are not applied. The scenario's ``initial`` section is written into the variant's
site before the run (levels, valve and leak openings, setpoints, modes, pump commands), so the
PLC starts from it as from a configured state.

Per variant the run gives trajectories (levels, setpoints, pump commands and flows, gains, modes
per scan), loop metrics and step metrics (:mod:`tankctl.metrics`), and for every step the
bang-bang minimum-time settling time of the nonlinear plant (:mod:`tankctl.limits`) and the
ratio of the controller's settling time to it. Levels in the metrics are the true levels [m]
(the shipped plants have noise-free transmitters, so they equal the readings).

JSON (``--json``)::

    {"scenario": NAME, "site": FILE, "duration_s": T,
     "variants": {VARIANT: {"description": ..., "supervisor_mode": ..., "scan_period_s": Ts,
                            "loops": {LOOP: {"iae", "ise", "itae", "overshoot_pct",
                                             "settling_time_s", "max_du", "constraint_violations"}},
                            "steps": [{"loop", "time", "setpoint", "from", "overshoot_pct",
                                       "settling_time_s", "min_time_s", "settling_ratio",
                                       "min_time_method"}],
                            "disturbances": [{"loop", "time", "event", "window_s", "iae",
                                              "peak_error_m"}]}}}

Units: iae m s, ise m^2 s, itae m s^2, time and settling s (from the step), setpoint and from m,
max_du in the pump's command unit per scan. ``disturbances`` lists, for every plant event (leak,
valve, fault, disturbance flow) and controlled loop, the IAE [m s] and peak |e| [m] from the
event to the next event of any kind. A settling time that did not happen within the
step's window is null.

``--csv OUT`` writes one CSV per variant: ``OUT/<variant>.csv`` when OUT is a directory (or ends
with ``/``), else ``<OUT stem>_<variant>.csv`` (a ``.csv`` suffix on OUT is dropped first).
``--plot OUT.png`` draws every variant side by side (:mod:`tankctl.plots`).

The package, one responsibility per module: :mod:`~tankctl.simulate.runner` (the runs),
:mod:`~tankctl.simulate.results` (what a run gives, and its JSON), :mod:`~tankctl.simulate.reports`
(CSV, the text summary, the comparison with the papers' numbers) and
:mod:`~tankctl.simulate.markdown` (docs/reproduction.md's generated blocks); this module
re-exports their public names (decision 0031).
"""

from __future__ import annotations

from tankctl.simulate.markdown import (
    MRAC_GAMMAS,
    markdown_report,
    mrac_sweep_markdown,
    regenerate_docs,
    tf_markdown,
)
from tankctl.simulate.reports import (
    TF_REFERENCES,
    compare_text,
    csv_paths,
    published_rows,
    summary_text,
    write_csv,
)
from tankctl.simulate.results import DisturbanceResult, ScenarioResult, StepResult, VariantResult, result_json
from tankctl.simulate.runner import apply_event, apply_initial, run_scenario, run_variant

# The commands live in tankctl.simulate_cli (light: no co-simulation import); re-exported.
from tankctl.simulate_cli import compare_command, register, simulate_command

__all__ = [
    "MRAC_GAMMAS",
    "TF_REFERENCES",
    "DisturbanceResult",
    "ScenarioResult",
    "StepResult",
    "VariantResult",
    "apply_event",
    "apply_initial",
    "compare_command",
    "compare_text",
    "csv_paths",
    "markdown_report",
    "mrac_sweep_markdown",
    "published_rows",
    "regenerate_docs",
    "register",
    "result_json",
    "run_scenario",
    "run_variant",
    "simulate_command",
    "summary_text",
    "tf_markdown",
    "write_csv",
]
