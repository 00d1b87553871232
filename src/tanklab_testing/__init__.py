"""Test support for tanklab: what ``tests/`` and ``benchmarks/`` share (decision 0032).

Never imported by the tiers or the CLI (an import-linter contract says so) and not in the wheel:
it drives real tier processes from a checkout of the repository. The processes, the Stack, the
waits and the logins are the shipped :mod:`tankctl.testing` (the pytest plugin's machinery,
decision 0056), re-exported here and run from the repository root: one code path.

* :mod:`tanklab_testing.waits`: the bounded waits (``wait_until``, ``wait_until_sync``).
* :mod:`tanklab_testing.procs`: free loopback ports, the /proc scans, and :class:`TankctlProcess`,
  the one wrapper of a ``python -m tankctl ...`` process.
* :mod:`tanklab_testing.stack`: :class:`Stack`, plant, PLC and supervisor processes on
  consecutive ports.
* :mod:`tanklab_testing.sites`: the default site config, written for a test or a run.
* :mod:`tanklab_testing.logins`: logins of a security home, sessions and a reconnecting probe.
* :mod:`tanklab_testing.security`: the protocol-fuzz and write-flood generators and oracles.
"""
