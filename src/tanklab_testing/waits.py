"""The bounded waits of tests and benchmarks: :mod:`tankctl.testing.waits`, shipped so that the
pytest plugin's ``tanklab_stack`` waits the same way from a wheel (decision 0056)."""

from tankctl.testing.waits import hang_bound, load_stretch, wait_until, wait_until_sync

__all__ = ["hang_bound", "load_stretch", "wait_until", "wait_until_sync"]
