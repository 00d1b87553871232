"""MANUAL/AUTO output handling shared by the single-loop blocks (NL-PI, MRAC).

A block keeps the applied output ``u(k-1)`` (clamped), a held manual value and its mode. The
switches are bumpless: entering MANUAL without a value holds the applied MV (tracking);
entering AUTO asks the block to re-initialise its law from the applied MV (``_needs_init``),
so the first AUTO output continues from where the actuator is. REMOTE belongs to the PID
blocks; the PLC program drives a single-loop block's REMOTE through its MANUAL path.
"""

from __future__ import annotations

from tanklab.checks import finite
from tanklab.enums import LoopMode


def check_limits(u_min: float, u_max: float, initial_mv: float) -> None:
    """Output limits u_min < u_max, both finite, and u(-1) = initial_mv inside them."""
    lo, hi = finite("u_min", u_min), finite("u_max", u_max)
    if lo >= hi:
        raise ValueError(f"u_min must be < u_max, got [{lo}, {hi}]")
    u0 = finite("initial_mv", initial_mv)
    if not lo <= u0 <= hi:
        raise ValueError(f"initial_mv must lie within [u_min, u_max] = [{lo}, {hi}], got {u0}")


def check_two_modes(mode: LoopMode, what: str = "mode") -> LoopMode:
    """MANUAL or AUTO; ``TypeError`` for a non-LoopMode, ``ValueError`` for REMOTE."""
    if not isinstance(mode, LoopMode):
        raise TypeError(f"{what} must be a tanklab.enums.LoopMode, got {type(mode).__name__}")
    if mode is LoopMode.REMOTE:
        raise ValueError(f"{what} must be MANUAL or AUTO for this block (REMOTE applies to PID loops)")
    return mode


class ManualAutoOutput:
    """Mode, manual value and applied-output memory of a single-loop block.

    Subclasses set ``_mode``, ``_manual``, ``_u`` and ``_needs_init`` in their constructor and
    define ``_clamp`` (their output limits).
    """

    _mode: LoopMode
    _manual: float
    _u: float
    _needs_init: bool

    def _clamp(self, value: float) -> float:
        raise NotImplementedError

    @property
    def mv(self) -> float:
        """Applied MV u(k-1) [MV unit]."""
        return self._u

    @property
    def mode(self) -> LoopMode:
        """Current mode."""
        return self._mode

    @property
    def manual_mv(self) -> float:
        """Held manual value [MV unit]."""
        return self._manual

    def set_mode(self, mode: LoopMode, mv: float | None = None) -> None:
        """Switch between MANUAL and AUTO bumplessly.

        Parameters
        ----------
        mode : LoopMode
            MANUAL or AUTO (REMOTE raises ValueError).
        mv : float, optional
            MANUAL only: the manual value (clamped). Omitted: the manual value tracks the applied MV.
        """
        mode = check_two_modes(mode)
        if mode is LoopMode.MANUAL:
            if mv is not None:
                self._manual = self._clamp(finite("mv", mv))
            elif self._mode is not LoopMode.MANUAL:
                self._manual = self._u
        else:
            if mv is not None:
                raise ValueError("mv applies only to MANUAL; AUTO continues from the applied MV")
            if self._mode is not LoopMode.AUTO:
                self._needs_init = True
        self._mode = mode

    def set_manual_mv(self, mv: float) -> None:
        """Set the manual value [MV unit] (clamped to the limits)."""
        self._manual = self._clamp(finite("mv", mv))

    def track(self, mv: float) -> None:
        """Set the applied-MV memory to an external value (clamped); AUTO re-initialises from it."""
        self._u = self._clamp(finite("mv", mv))
        self._needs_init = True
