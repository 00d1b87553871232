"""The benchmark document (benchmarks.report) rendered from hand-made results (tests/bench_samples.py).

No measurement runs here: the samples fill every section the way a full run does, and their
variants take the branches a full run does not (comparators not run, a failed lock-step run, no
speed reference, an empty report).
"""

from __future__ import annotations

import re

import pytest
from benchmarks.report import goals, render

from bench_samples import VARIANTS, sample_report

SECTIONS = (
    "# Benchmarks",
    "## Machine",
    "## Goals",
    "## Closing notes",
    "## 1. MPC step time (Kortela configuration)",
    "### 1c. Accuracy guard",
    "## 2. Co-simulation speed",
    "## 3. OPC UA round trip",
    "## 6. Lock-step speed",
    "## 9. Operator commands: wall time and import cost",
)


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_variant_renders_its_sections_in_order_and_one_row_per_goal(variant: str) -> None:
    text = render(sample_report(variant))
    headings = [h for h in SECTIONS if h in text.splitlines()]
    assert headings == sorted(headings, key=text.index)
    if variant != "empty":
        assert headings == list(SECTIONS)
    table = text.split("## Goals\n\n", 1)[1].split("\n\n", 1)[0].splitlines()
    assert len(table) == 2 + len(goals(sample_report(variant)))
    assert text.endswith("\n") and not text.endswith("\n\n")


def test_the_same_results_render_the_same_document() -> None:
    assert render(sample_report("full")) == render(sample_report("full"))


def test_a_failed_run_and_missing_comparators_are_reported_not_hidden() -> None:
    text = render(sample_report("failures"))
    assert "failed: timed out after 180 s" in text and "## Errors" in text
    assert "- section security failed: RuntimeError: boom" in text
    rows = {g.name: g for g in goals(sample_report("slow-comparators"))}
    dompc = rows["faster than do-mpc (IPOPT), Np = 40"]
    assert dompc.met is None and dompc.measured == "n/a" and "do_mpc" in dompc.note
    assert re.search(
        r"\| do-mpc \(IPOPT\) \| - \| .*not run: ModuleNotFoundError",
        render(sample_report("slow-comparators")),
    )
