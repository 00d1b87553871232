"""Order statistics of a sample: what every benchmark table and fuzz summary shows.

n, median and p99 (``numpy.percentile``, linear interpolation), plus min, max and mean;
non-finite samples (a wait that timed out is NaN) are left out.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Summary:
    """Order statistics of a sample (in the sample's unit)."""

    n: int
    median: float
    p99: float
    minimum: float
    maximum: float
    mean: float

    @classmethod
    def of(cls, samples: Iterable[float]) -> Summary:
        arr = np.asarray([s for s in samples if math.isfinite(s)], dtype=float)
        if arr.size == 0:
            nan = math.nan
            return cls(0, nan, nan, nan, nan, nan)
        p99 = np.percentile(arr, 99)
        return cls(
            n=int(arr.size),
            median=float(np.median(arr)),
            p99=float(p99),
            minimum=float(arr.min()),
            maximum=float(arr.max()),
            mean=float(arr.mean()),
        )

    def scaled(self, factor: float) -> Summary:
        """The same summary in another unit (e.g. 1e3 for s -> ms)."""
        return Summary(
            self.n,
            self.median * factor,
            self.p99 * factor,
            self.minimum * factor,
            self.maximum * factor,
            self.mean * factor,
        )
