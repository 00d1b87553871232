"""tanklab benchmarks: ``python -m benchmarks.run`` (``make bench``) writes ``docs/benchmarks.md``.

Modules: :mod:`benchmarks.mpc` (MPC step time against cvxpy and do-mpc),
:mod:`benchmarks.cosim` (co-simulation speed and hot spots), :mod:`benchmarks.stack` (OPC UA
round trip, setpoint-to-action latency, PLC scan lateness, lock-step speed through the real
processes), :mod:`benchmarks.cli` (operator command wall time), :mod:`benchmarks.restarts`
(the restart driver; its results, goals and section in :mod:`benchmarks.restarts_report`),
:mod:`benchmarks.report` (the Markdown document, a package: goals, sections, render). Nothing
here is imported by the project; the tests import it only to test the benchmarks themselves
(tests/test_bench_*.py).
"""
