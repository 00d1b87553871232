"""The loop shell around a non-PID block (decision 0029): the NL-PI through the block protocol."""

from __future__ import annotations

import math

import pytest

from plc_emulator.loop import LoopShell, ShellConfig
from plc_emulator.nlpi import NlPi, NlPiConfig
from plc_emulator.single_loop import SingleLoopBlock
from plc_emulator.tuning import nlpi_gains
from tanklab.enums import LoopMode
from tanklab.gains import LoopLimits

TS = 0.01
GAINS = nlpi_gains(b=1.0, a_prime=0.5, zeta=0.7071, wn=0.5)


def shell(du_max: float = math.inf, substitute: str = "hold", sp_step: float = math.inf) -> LoopShell:
    law = NlPi(NlPiConfig(ts_s=TS, gains=GAINS, u_min=0.0, u_max=1.0, initial_mv=0.1))
    return LoopShell(
        SingleLoopBlock(law),
        ShellConfig(
            limits=(LoopLimits(0.0, 1.0, du_max),),
            sp_min=(0.0,),
            sp_max=(1.0,),
            sp_step=(sp_step,),
            pv_bad_scans=2,
            substitute=(substitute,),  # type: ignore[arg-type]
            substitute_mv=(0.5,),
            initial_mv=(0.1,),
            initial_mode=(LoopMode.AUTO,),
        ),
    )


def law_of(s: LoopShell) -> NlPi:
    block = s.block
    assert isinstance(block, SingleLoopBlock) and isinstance(block.law, NlPi)
    return block.law


def test_rate_limit_is_the_shells_and_the_law_continues_from_the_applied_mv() -> None:
    s = shell(du_max=1e-4)
    for _ in range(5):
        before = s.mv_of(0)
        mv = s.scan([0.5], [0.1], [True])[0]  # a large error: the law asks for far more
        assert mv == pytest.approx(before + 1e-4) and s.rate_limited[0]
        assert law_of(s).mv == mv  # tracked: the NL-PI's u(k-1) is the applied value


def test_remote_applies_the_held_value_and_auto_resumes_bumplessly() -> None:
    s = shell()
    for _ in range(20):
        s.scan([0.2], [0.19], [True])
    s.set_mode(0, LoopMode.REMOTE)
    s.set_remote_mv(0, 0.3)
    assert s.scan([0.2], [0.19], [True])[0] == 0.3 and law_of(s).mv == 0.3
    s.set_mode(0, LoopMode.AUTO)
    mv = s.scan([0.2], [0.19], [True])[0]
    # Re-initialised from the applied 0.3: the first AUTO move is the integral's, Ki Ts e.
    assert mv - 0.3 == pytest.approx(GAINS.Ki * TS * 0.01)


def test_substitute_value_after_the_bad_scans_at_the_rate_limit() -> None:
    s = shell(du_max=0.1, substitute="value")
    s.scan([0.2], [0.19], [True])
    held = s.mv_of(0)
    assert s.scan([0.2], [math.nan], [True])[0] == held and not s.substituted[0]  # one bad scan: hold
    mv = s.scan([0.2], [0.19], [False])[0]  # the second: the substitute, 0.1 per scan toward 0.5
    assert s.substituted[0] and mv == pytest.approx(held + 0.1)


def test_setpoint_ramp_is_the_shells() -> None:
    s = shell(sp_step=0.01)
    s.scan([0.2], [0.2], [True])
    s.scan([0.5], [0.2], [True])
    assert s.working_sp[0] == pytest.approx(0.21)
