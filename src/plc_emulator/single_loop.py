"""The single-loop blocks (NL-PI, adaptive NL-PI, MRAC) as `plc_emulator.loop.Block`s.

Those laws keep MANUAL / AUTO and their applied output themselves (``ManualAutoOutput``), so
they can run on their own; inside the PLC a `plc_emulator.loop.LoopShell` owns the modes, the
held values, the substitute and the limits, and this adapter maps the block protocol onto them:
REMOTE runs the law's MANUAL path (the law waits; the shell applies the held remote value), a
bad PV is passed as ``pv_good=False`` (the law holds and re-initialises from the applied MV when
the PV returns), and ``track`` and ``resume`` become the law's ``track``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from tanklab.enums import LoopMode

__all__ = ["ManualAutoLaw", "SingleLoopBlock"]


class _HasMv(Protocol):
    @property
    def mv(self) -> float: ...


class ManualAutoLaw(Protocol):
    """What `SingleLoopBlock` needs of a law: ``NlPi``, ``AdaptiveNlPi`` and ``Mrac`` have it."""

    def step(self, sp: float, h: float, pv_good: bool = True) -> _HasMv: ...

    def set_mode(self, mode: LoopMode, mv: float | None = None) -> None: ...

    def track(self, mv: float) -> None: ...


class SingleLoopBlock:
    """A one-loop MANUAL/AUTO law as a `plc_emulator.loop.Block` (see the module docstring)."""

    def __init__(self, law: ManualAutoLaw) -> None:
        self.law = law

    @property
    def n_loops(self) -> int:
        """One loop."""
        return 1

    def step(
        self, w: Sequence[float], pv: Sequence[float], good: Sequence[bool], u_prev: Sequence[float]
    ) -> list[float]:
        """One scan of the law at the working setpoint (a bad PV is passed as the setpoint, flagged)."""
        ok = good[0]
        return [float(self.law.step(w[0], pv[0] if ok else w[0], pv_good=ok).mv)]

    def set_mode(self, loop: int, mode: LoopMode) -> None:
        """AUTO runs the law; MANUAL and REMOTE its MANUAL path."""
        self.law.set_mode(LoopMode.AUTO if mode is LoopMode.AUTO else LoopMode.MANUAL)

    def track(self, loop: int, mv: float) -> None:
        """The law continues from the applied ``mv`` (re-initialised on its next AUTO scan)."""
        self.law.track(mv)

    def resume(self, loop: int, mv: float, w: float, pv: float) -> None:
        """A warm restart: the law tracks the actuator's command."""
        self.law.track(mv)
