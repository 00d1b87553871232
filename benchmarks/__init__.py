"""tanklab benchmarks: ``python -m benchmarks.run`` (``make bench``) writes ``docs/benchmarks.md``.

Modules: :mod:`benchmarks.mpc` (MPC step time against cvxpy and do-mpc),
:mod:`benchmarks.cosim` (co-simulation speed and hot spots), :mod:`benchmarks.stack` (OPC UA
round trip, setpoint-to-action latency, PLC scan lateness, lock-step speed through the real
processes), :mod:`benchmarks.report` (the Markdown document). Nothing here is imported by the
project or its tests.
"""
