"""``tankctl sweep``: scenario sweeps (grids and Monte Carlo draws) run on Dask.

The package, one responsibility per module: :mod:`~tankctl.sweep.spec` (the sweep file),
:mod:`~tankctl.sweep.cases` (cases, seeds, each case's scenario and site; the pre-flight),
:mod:`~tankctl.sweep.worker` (one case in the co-simulation, as a Dask task),
:mod:`~tankctl.sweep.store` (``cases.parquet``, written per batch, resumable),
:mod:`~tankctl.sweep.summary` (median and p95 per variant), :mod:`~tankctl.sweep.plots`,
:mod:`~tankctl.sweep.progress` and :mod:`~tankctl.sweep.run` (the cluster and the loop). The
command itself is :mod:`tankctl.sweep_cli` (light: it imports this package when it runs).
Documented in ``docs/sweeps.md``; decision 0051.
"""
