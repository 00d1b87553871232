"""The repository's :class:`Stack`: :class:`tankctl.testing.stack.Stack` run from the repository root.

One code path with the pytest plugin's ``tanklab_stack`` (decision 0056): the shipped Stack
starts, kills and stops the tiers; here only the processes' working directory defaults to the
repository root, where the tests' relative config paths point.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tankctl.testing import stack as _shipped
from tankctl.testing.stack import UP_TIMEOUT_S
from tanklab_testing.procs import ROOT

__all__ = ["UP_TIMEOUT_S", "Stack"]


@dataclass
class Stack(_shipped.Stack):
    """Tier processes of one test or measurement on ``base`` .. ``base + 2``, started from the
    repository root (see :class:`tankctl.testing.stack.Stack` for the fields)."""

    cwd: Path | None = ROOT
