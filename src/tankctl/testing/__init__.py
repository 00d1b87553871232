"""The machinery of the pytest plugin's ``tanklab_stack``, shipped with tanklab (decision 0056).

* :mod:`tankctl.testing.waits`: the bounded waits (``wait_until``, ``wait_until_sync``).
* :mod:`tankctl.testing.procs`: free loopback ports, the /proc scans, and :class:`TankctlProcess`,
  the one wrapper of a ``python -m tankctl ...`` process.
* :mod:`tankctl.testing.stack`: :class:`Stack`, plant, PLC, supervisor (and historian) processes
  on consecutive ports.
* :mod:`tankctl.testing.logins`: logins of a security home, a throw-away one, sessions.
* :mod:`tankctl.testing.fixture`: :func:`running_stack` and the clients by tag path.

The repository's test support, :mod:`tanklab_testing`, builds on these (one code path); nothing
here imports it, and nothing of the tiers or the CLI imports this package.
"""
