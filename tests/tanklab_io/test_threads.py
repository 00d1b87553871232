"""tanklab_io.threads: one BLAS thread for every BLAS library, whatever was imported before."""

from __future__ import annotations

import json
import subprocess
import sys


def test_limit_reaches_numpy_and_scipy_blas_in_a_fresh_process() -> None:
    """The limit is applied before scipy.linalg is imported by anyone else: scipy's own OpenBLAS
    (behind scipy.linalg.lapack) must still end up at one thread, as numpy's does."""
    code = (
        "import json\n"
        "from tanklab_io.threads import limit_blas_threads\n"
        "limit_blas_threads()\n"
        "from scipy.linalg import lapack\n"
        "from threadpoolctl import threadpool_info\n"
        "print(json.dumps([(p['filepath'], p['num_threads']) for p in threadpool_info()"
        " if p['user_api'] == 'blas']))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    pools = json.loads(out.stdout)
    assert any("scipy" in path for path, _ in pools)  # scipy's BLAS is among them
    assert len(pools) >= 2 and all(threads == 1 for _, threads in pools), pools
