"""The Markdown document ``docs/benchmarks.md``: machine, goals, every table, closing notes.

Every number in the document comes from the run that wrote it; the text around the tables
states what was timed and how. A goal that is not met is reported as not met, with the measured
number and the reason where the measurements show it.

The package, by responsibility: :mod:`.base` (the :class:`Report` of one run and the table
helpers every section uses), :mod:`.goals` (the goals and their table), :mod:`.mpc_section`
(section 1: MPC step time, side by side, accuracy guard), :mod:`.cosim_section` (section 2),
:mod:`.stack_section` (sections 3-6: the processes), :mod:`.render` (header, closing notes and
the whole document). The sections of other modules (robustness, security, cli, restarts) come
in as :attr:`Report.extra`, their goals as :attr:`Report.extra_goals`.
"""

from benchmarks.common import REFERENCE_SPEED_MS
from benchmarks.report.base import GOAL_NP, GOAL_NP_LONG, Report
from benchmarks.report.goals import goals
from benchmarks.report.render import render

__all__ = ["GOAL_NP", "GOAL_NP_LONG", "REFERENCE_SPEED_MS", "Report", "goals", "render"]
