"""Level transmitters and level switches.

A transmitter reads the true level ``h`` [m] and reports

    y = clip(q(h + v + f(t)), range_min, range_max),     v ~ N(0, sigma^2) (seeded)

where ``q`` rounds to the resolution (quantization) and ``f`` is the injected fault:
NONE: 0; BIAS: the fault value [m]; DRIFT: fault value [m/s] times the time since the fault was
set; STUCK: the reading freezes at the value it had when the fault was set.

Switches: ``LSH`` is true at or above its level, ``LSL`` at or below its level (true level).
The noise generator is ``numpy.random.default_rng(seed)``, so a run is reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from plant_sim.models import FloatArray
from tanklab.config import PlantConfig
from tanklab.enums import SensorFault


@dataclass
class TransmitterBank:
    """All level transmitters of a plant, with their faults.

    Attributes
    ----------
    noise_std_m, quantization_m, range_min_m, range_max_m : (n,) per transmitter.
    fault : (n,) SensorFault codes; fault_value : (n,) bias [m] or drift rate [m/s].
    """

    noise_std_m: FloatArray
    quantization_m: FloatArray
    range_min_m: FloatArray
    range_max_m: FloatArray
    rng: np.random.Generator
    fault: list[SensorFault] = field(default_factory=list)
    fault_value: FloatArray = field(default_factory=lambda: np.zeros(0))
    fault_since_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    last: FloatArray = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def from_config(cls, plant: PlantConfig) -> TransmitterBank:
        n = len(plant.tanks)
        ranges = [t.transmitter_range() for t in plant.tanks]
        return cls(
            noise_std_m=np.array([t.transmitter.noise_std_m for t in plant.tanks]),
            quantization_m=np.array([t.transmitter.quantization_m for t in plant.tanks]),
            range_min_m=np.array([r[0] for r in ranges]),
            range_max_m=np.array([r[1] for r in ranges]),
            rng=np.random.default_rng(plant.noise_seed),
            fault=[SensorFault.NONE] * n,
            fault_value=np.zeros(n),
            fault_since_s=np.zeros(n),
            last=np.array([t.initial_level_m for t in plant.tanks]),
        )

    def set_fault(self, i: int, fault: SensorFault, value: float, t_s: float) -> None:
        """Inject ``fault`` with size ``value`` on transmitter ``i`` at model time ``t_s``."""
        self.fault[i] = SensorFault(fault)
        self.fault_value[i] = float(value)
        self.fault_since_s[i] = t_s

    def read(self, levels_m: FloatArray, t_s: float) -> FloatArray:
        """Sample every transmitter at model time ``t_s`` (draws fresh noise).

        Evaluated on Python floats (a handful of transmitters: numpy's per-call overhead would
        dominate), with the same operations in the same order as the array form, so readings
        are bit-identical to it: ``numpy.round`` and ``round`` both round half to even, and the
        clip is ``min(max(y, lo), hi)`` as ``numpy.clip``. ``test_sensors.py`` checks both forms
        against each other (Hypothesis). The noise stays one draw of ``n`` normals per read (a
        block draw gives the same numbers but leaves the generator ahead, and would save little).
        """
        z = self.rng.standard_normal(levels_m.shape).tolist()
        out = []
        for i, (h, std, zi, q, lo, hi, f) in enumerate(
            zip(
                levels_m.tolist(),
                self.noise_std_m.tolist(),
                z,
                self.quantization_m.tolist(),
                self.range_min_m.tolist(),
                self.range_max_m.tolist(),
                self.fault,
                strict=True,
            )
        ):
            # ``if f``: NONE is 0, so a healthy transmitter (the usual scan) skips the fault checks
            if f and f == SensorFault.STUCK:
                out.append(float(self.last[i]))
                continue
            y = h + std * zi
            if f:
                if f == SensorFault.BIAS:
                    y += float(self.fault_value[i])
                elif f == SensorFault.DRIFT:
                    y += float(self.fault_value[i]) * (t_s - float(self.fault_since_s[i]))
            if q > 0.0 and math.isfinite(y):  # round(inf) raises; numpy keeps inf and NaN
                y = round(y / q) * q
            out.append(lo if y < lo else hi if y > hi else y)
        self.last = np.array(out)
        return self.last.copy()


def switch_states(
    levels_m: FloatArray, high_m: FloatArray, low_m: FloatArray
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """(LSH, LSL) booleans per tank: level >= high, level <= low."""
    return levels_m >= high_m, levels_m <= low_m
