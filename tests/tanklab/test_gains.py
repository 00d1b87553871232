"""The kernel's gain value types (decision 0030)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tanklab.config import GainBox as GainBoxSpec
from tanklab.config import PidGainsSpec
from tanklab.gains import GainBox, LoopGains, LoopLimits, PidGains


def test_loop_gains_are_finite_floats_with_the_tag_spelling() -> None:
    g = LoopGains(1, 2.5e-5, -1e-3)
    assert g.as_tuple() == (1.0, 2.5e-5, -1e-3) and type(g.kp) is float
    assert (g.Kp, g.Ki, g.Kd) == (g.kp, g.ki, g.kd)
    assert LoopGains(1.0, 0.0) == LoopGains(1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="ki must be finite"):
        LoopGains(1.0, math.nan)
    with pytest.raises(TypeError, match="kd"):
        LoopGains(1.0, 0.0, True)


def test_pid_gains_are_read_only_matrices_of_one_shape() -> None:
    g = PidGains.diagonal([1.0, 2.0], [0.1, 0.2], [0.0, -1.0])
    assert g.shape == (2, 2) and not g.kp.flags.writeable
    assert g.loop(1) == LoopGains(2.0, 0.2, -1.0) and g.loop(0, 1) == LoopGains(0.0, 0.0, 0.0)
    assert PidGains.from_stacked(g.stacked()).allclose(g)
    assert PidGains.of_loops([LoopGains(1.0, 0.1, 0.0), LoopGains(2.0, 0.2, -1.0)]).allclose(g)
    wide = PidGains(np.ones((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)))  # n_u x n_loops
    assert wide.shape == (2, 3) and wide.is_finite()
    assert not PidGains(np.full((1, 1), math.nan), np.zeros((1, 1)), np.zeros((1, 1))).is_finite()
    with pytest.raises(ValueError, match="2-D"):
        PidGains(np.ones(2), np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match="same shape"):
        PidGains(np.eye(2), np.eye(3), np.eye(2))


def test_gain_box_contains_matrices_and_one_loop() -> None:
    box = GainBox.of_loop((0.0, 1e-2), (0.0, 1e-3), (-1e-2, 1e-2))
    assert box.contains(LoopGains(1e-3, 1e-5, -1e-3))
    assert box.contains(LoopGains(1e-2, 1e-3, 1e-2))  # bounds included
    assert not box.contains(LoopGains(2e-2, 1e-5, 0.0))
    assert box.contains(PidGains.diagonal([1e-3], [1e-5], [0.0]))
    two = GainBox(PidGains.diagonal([0, 0], [0, 0], [0, 0]), PidGains.diagonal([1, 1], [1, 1], [1, 1]))
    with pytest.raises(ValueError, match="1 x 1"):
        two.contains(LoopGains(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="lower must be <= upper"):
        GainBox.of_loop((1.0, 0.0), (0.0, 1.0), (0.0, 1.0))


def test_config_models_convert_in_one_place() -> None:
    spec = PidGainsSpec(kp=4.29e-4, ki=5.32e-6, kd=-1.42e-4)
    assert LoopGains.of_spec(spec) == LoopGains(4.29e-4, 5.32e-6, -1.42e-4)
    box = GainBox.of_spec(GainBoxSpec(kp=(0.0, 1e-2), ki=(0.0, 1e-3), kd=(-1e-2, 1e-2)))
    assert box.contains(LoopGains(1e-3, 1e-5, 0.0)) and not box.contains(LoopGains(1e-3, 2e-3, 0.0))


def test_loop_limits() -> None:
    lim = LoopLimits(0.0, 1e-4)
    assert lim.du_max == math.inf and lim.clamp(2e-4) == 1e-4 and lim.clamp(-1.0) == 0.0
    with pytest.raises(ValueError, match="mv_min must be < mv_max"):
        LoopLimits(1.0, 1.0)
    with pytest.raises(ValueError, match="du_max"):
        LoopLimits(0.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        LoopLimits(0.0, math.inf)
