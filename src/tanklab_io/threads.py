"""One BLAS thread per tanklab process.

The numerical work of a tier (a Kalman filter, a QP's small dense products, an RK4 step) is far
too small to gain from a BLAS thread pool, and on a two-core machine that also runs the other
two tiers the pool's threads cost latency instead: OpenBLAS wakes its threads for a product of a
few dozen by a few hundred, and a wake-up that finds the cores busy stalls the calling thread for
milliseconds (measured on the MPC step: a 48 x 510 by 510 x 48 product took 3 to 15 ms instead of
0.1 ms; docs/decisions/0011-exact-active-set-solves.md). The tiers, the co-simulation commands
and the benchmarks therefore pin BLAS to one thread at start-up.
"""

from __future__ import annotations

import numpy  # noqa: F401 -- loads numpy's OpenBLAS, so that the limit reaches it
import scipy.linalg  # noqa: F401 -- loads scipy's OpenBLAS (scipy.linalg.lapack), likewise
from threadpoolctl import threadpool_limits

__all__ = ["limit_blas_threads"]


def limit_blas_threads() -> None:
    """Limit every BLAS library of this process (OpenBLAS, MKL, BLIS) to one thread.

    threadpoolctl can only limit a library that is loaded, and numpy and scipy ship one OpenBLAS
    each: scipy's (behind ``scipy.linalg.lapack``, which the MPC's Schur complement calls) is
    loaded by importing scipy.linalg. This module imports both, so the limit holds whatever the
    caller imported before (measured: a caller that limited before importing scipy.linalg
    left scipy's OpenBLAS at two threads, and ``dgetrs`` with ten right-hand sides took 15 ms
    instead of 6 us on a busy machine).
    """
    threadpool_limits(limits=1, user_api="blas")
