"""Containment of a supervisory controller: what runs around every :meth:`step` call.

The supervisor calls its controller (:mod:`supervisor.controller`, the shipped one included)
only through a :class:`ControllerHost`, in the co-simulation and in the supervisor process alike
(:class:`supervisor.port.SupervisorDriver`). Per sample:

1. the CPU time of the call is measured with an injected clock (``cpu_clock``, CPU seconds of
   the calling thread; ``time.thread_time`` in the processes, a fake clock in tests). A CPU
   clock is a system call (microseconds on a loaded VM: more than 5 % of a 70 us MPC cycle), so
   with the default clock it is read around the call only while *armed* (the last step took
   more than a quarter of the budget in wall time); unarmed, the cheap ``time.perf_counter``
   bounds the CPU time from above (a thread's CPU time never exceeds the wall time), and a step
   whose wall time exceeds the budget is judged on that bound. A fake clock is always read;
2. the output is checked whole: a :class:`ControllerOutput`; loops that exist; gains finite and
   inside the loop's gain box when one is configured (as the PLC's SetGains checks them);
   RemoteMV finite and inside the loop's MV range [max(mv_min, command_min), min(mv_max,
   command_max)] of its pump; modes AUTO or REMOTE; diagnostics declared, of their declared kind,
   floats finite;
3. a step that raised (kind ``raised``), returned a non-finite value (``non_finite``), an
   out-of-range value (``out_of_range``), a malformed output (``bad_output``) or took more than the
   budget ``budget_s`` of CPU time (``overrun``; default budget: the supervisor's sample time) is
   *contained*: nothing of it is written, so the PLC holds the last safe action (the RemoteMV and
   gains it applies stay), it is counted (``errors``; ``overruns``), ``last_error`` says what, and it
   is logged once per kind, then at most once per ``log_every_s`` of model time with the count;
4. after ``max_failures`` failed steps in a row the host is ``failing``: the driver sends no
   heartbeat, so the PLC's watchdog (``plc_emulator.watchdog``) times out and sheds the loops (REMOTE
   to AUTO, supervisor gains to FALLBACK) exactly as for a lost supervisor. The controller is still
   called each sample; its first good step clears ``failing`` and the heartbeat resumes (the PLC
   trusts the supervisor again after its good-heartbeat scans).

RemoteMV for a loop that is neither in REMOTE in the snapshot nor put in REMOTE by the same output
is not written (the PLC would not apply it). With a plug-in (not the shipped controller) the
supervisor's requested mode is its mode: OFF calls nothing (the heartbeat goes on), any other
runs the plug-in.

Pure: no I/O; time comes from the snapshot and the injected CPU clock.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from supervisor.controller import (
    ControllerOutput,
    DiagnosticValue,
    ShippedController,
    SupervisoryController,
    build_controller,
    class_name,
)
from supervisor.cycle import Actions, PlcSnapshot, SupervisorCore, SupervisorStatus
from tanklab.config import SiteConfig
from tanklab.enums import LoopMode, SupervisorMode

log = logging.getLogger(__name__)

__all__ = ["FAILURE_KINDS", "ControllerHost", "ControllerReport"]

FAILURE_KINDS = ("raised", "non_finite", "out_of_range", "bad_output", "overrun")
"""What a contained step can have done wrong (``last_error`` starts with one of them)."""

LOG_EVERY_S = 60.0
"""Model seconds between two log lines of the same failure kind after its first [s]."""

_SWITCHABLE = (LoopMode.AUTO, LoopMode.REMOTE)


class _FailureError(Exception):
    """A step's output broke a rule (kind, message)."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class ControllerReport:
    """The controller's state to publish under ``Supervisor.Controller``.

    Attributes
    ----------
    class_name : package.module:Class.  cycles : steps called.  errors : steps discarded for a
    raise or a bad output.  last_error : "kind: message" of the last failure ("" until one).
    overruns : steps over the budget.  failing : the heartbeat is withheld.
    diagnostics : the last good step's diagnostics (declared ones; zero values before).
    """

    class_name: str
    cycles: int
    errors: int
    last_error: str
    overruns: int
    failing: bool
    diagnostics: Mapping[str, DiagnosticValue]


class ControllerHost:
    """Runs a :class:`SupervisoryController` with containment (the module docstring).

    Parameters
    ----------
    site : the site.  controller : the controller (a :class:`ShippedController` wraps ``core``).
    core : the supervisor core (mode, status; the shipped controller's own).
    cpu_clock : CPU seconds of the calling thread (default ``time.thread_time``).
    wall_clock : a cheaper clock that bounds the CPU time from above (default
        ``time.perf_counter``); used only with the default ``cpu_clock`` (a fake CPU clock is read
        before and after every call).
    budget_s, max_failures : override ``supervisor.controller``'s (default: its values, else the
        sample time and 3).
    """

    def __init__(
        self,
        site: SiteConfig,
        controller: SupervisoryController,
        core: SupervisorCore,
        *,
        cpu_clock: Callable[[], float] = time.thread_time,
        wall_clock: Callable[[], float] | None = time.perf_counter,
        budget_s: float | None = None,
        max_failures: int | None = None,
        log_every_s: float = LOG_EVERY_S,
    ) -> None:
        assert site.supervisor is not None and site.plc is not None
        spec = site.supervisor.controller
        self.controller = controller
        self.core = core
        self.shipped = controller if isinstance(controller, ShippedController) else None
        self.class_name = class_name(type(controller))
        self.cpu_clock = cpu_clock
        self.wall_clock = wall_clock if cpu_clock is time.thread_time else None
        self._armed = self.wall_clock is None
        self.budget_s = (
            budget_s or (spec.budget_s if spec is not None else None) or site.supervisor_sample_time_s
        )
        self.max_failures = max_failures or (spec.max_failures if spec is not None else 3)
        self.log_every_s = log_every_s
        self._track: Callable[[PlcSnapshot], object] | None = getattr(controller, "track", None)
        self.declared = {d.name: d.kind for d in controller.diagnostics}
        zero: dict[type, DiagnosticValue] = {float: 0.0, bool: False, str: ""}
        self._diagnostics: dict[str, DiagnosticValue] = {d.name: zero[d.kind] for d in controller.diagnostics}
        self.loops = {lp.name: j for j, lp in enumerate(site.plc.loops)}
        self.mv_range: dict[str, tuple[float, float]] = {}
        for lp in site.plc.loops:
            pump = site.plant.pump(lp.actuator)
            lo = max(lp.mv_min, pump.command_min) if lp.mv_min is not None else pump.command_min
            hi = min(lp.mv_max, pump.command_max) if lp.mv_max is not None else pump.command_max
            self.mv_range[lp.name] = (lo, hi)
        self.gain_box = {lp.name: lp.gain_box for lp in site.plc.loops}
        self.cycles = 0
        self.errors = 0
        self.overruns = 0
        self.last_error = ""
        self.consecutive = 0
        self.failing = False
        self._logged: dict[str, tuple[float, int]] = {}  # kind -> (model time logged, suppressed since)

    # ---- per scan -------------------------------------------------------------------------

    def track(self, snap: PlcSnapshot) -> None:
        """A scan between two samples: the controller's optional ``track`` (a raise is contained
        and counted as the step's are)."""
        if self._track is None:
            return
        try:
            self._track(snap)
        except Exception as e:  # a user's code: contain whatever it raises
            self._failed("raised", f"track: {type(e).__name__}: {e}", snap.t_s)

    def cycle(self, snap: PlcSnapshot, preview: NDArray[np.float64] | None = None) -> Actions:
        """One sample: call the controller, check and contain; the actions to write (none when
        the step failed) with the status (the controller's report: :meth:`report`)."""
        core = self.core
        if self.shipped is None:
            core.mode = core.requested  # a plug-in runs in any mode but OFF
            if core.mode is SupervisorMode.OFF:
                return Actions(status=self._status())
        self.cycles += 1
        # The CPU clock (a system call) is read around the call only when armed (a fake clock;
        # or the last step took more than a quarter of the budget in wall time); the cheap wall
        # clock bounds the CPU time from above otherwise (a thread's CPU time never exceeds it).
        gate = self.wall_clock
        t0 = self.cpu_clock() if self._armed else None
        w0 = gate() if gate is not None else 0.0
        out: Any = None
        raised: Exception | None = None
        try:
            if preview is not None and self.shipped is not None:
                out = self.shipped.step(snap, snap.t_s, preview)
            else:
                out = self.controller.step(snap, snap.t_s)
        except Exception as e:  # a user's code: contain whatever it raises
            raised = e
        wall_s = gate() - w0 if gate is not None else math.inf
        if t0 is not None and wall_s > self.budget_s:
            used_s = self.cpu_clock() - t0
        elif t0 is None and wall_s > self.budget_s:
            used_s = wall_s  # unarmed: the first slow step is judged on its wall time (>= CPU time)
        else:
            used_s = 0.0  # under the budget: CPU time <= wall time <= budget
        self._armed = gate is None or wall_s > self.budget_s / 4
        try:
            if raised is not None:
                raise _FailureError("raised", f"{type(raised).__name__}: {raised}")
            if used_s > self.budget_s:
                raise _FailureError(
                    "overrun", f"step took {used_s:.6g} s of CPU time, budget {self.budget_s:.6g} s"
                )
            act = self._actions(out, snap)
        except _FailureError as f:
            self._failed(f.kind, str(f), snap.t_s)
            return Actions(status=self._status())
        if self.consecutive:
            if self.failing:
                log.warning("controller %s: a good step again; heartbeat resumed", self.class_name)
            self.consecutive = 0
            self.failing = False
        act.status = self._status()
        return act

    # ---- checks ---------------------------------------------------------------------------

    def _actions(self, out: Any, snap: PlcSnapshot) -> Actions:
        """Check ``out`` whole; the actions it asks for (RemoteMV of loops neither in REMOTE nor
        put there by ``out`` left out)."""
        if not isinstance(out, ControllerOutput):
            raise _FailureError("bad_output", f"step returned {type(out).__name__}, not ControllerOutput")
        try:
            modes, gains, remote = out.modes, out.gains, out.remote_mv
            loops, auto, remote_mode = self.loops, LoopMode.AUTO, LoopMode.REMOTE
            for lp, m in modes.items():
                if (m is not auto and m is not remote_mode) or lp not in loops:
                    self._mode(lp, m)  # raises, naming the rule
            for lp, g in gains.items():
                self._gains(lp, g)
            drop: list[str] = []
            snap_modes, mv_range = snap.modes, self.mv_range
            for lp, v in remote.items():
                # the usual case inline (a float in range), every other one through _mv's checks
                r = mv_range.get(lp)
                if r is None or type(v) is not float or not r[0] <= v <= r[1]:
                    self._mv(lp, v)
                if snap_modes[loops[lp]] is not remote_mode and modes.get(lp) is not remote_mode:
                    drop.append(lp)
            diagnostics = (
                [(name, self._diagnostic(name, v)) for name, v in out.diagnostics.items()]
                if out.diagnostics
                else ()
            )
        except (TypeError, AttributeError) as e:
            raise _FailureError("bad_output", f"malformed output: {type(e).__name__}: {e}") from e
        if diagnostics:
            self._diagnostics.update(diagnostics)
        if self.shipped is not None and self.shipped.last_actions is not None:
            act = self.shipped.last_actions  # the core's own actions, already checked
            if drop:
                act.remote_mv = {lp: mv for lp, mv in act.remote_mv.items() if lp not in drop}
            return act
        return Actions(
            remote_mv={lp: float(v) for lp, v in remote.items() if lp not in drop},
            modes=dict(modes),
            gains={lp: self._gains(lp, g) for lp, g in gains.items()},
        )

    def _loop(self, lp: object, what: str) -> str:
        if lp not in self.loops or not isinstance(lp, str):
            msg = f"{what} for unknown loop {lp!r} (loops: {', '.join(self.loops)})"
            raise _FailureError("bad_output", msg)
        return lp

    def _mode(self, lp: str, m: object) -> LoopMode:
        self._loop(lp, "mode")
        if m is not LoopMode.AUTO and m is not LoopMode.REMOTE:
            raise _FailureError("bad_output", f"{lp} mode {m!r}: only LoopMode.AUTO or LoopMode.REMOTE")
        return m

    def _gains(self, lp: str, g: object) -> tuple[float, float, float]:
        self._loop(lp, "gains")
        if not isinstance(g, tuple | list) or len(g) != 3:
            raise _FailureError("bad_output", f"{lp} gains {g!r}: not a (Kp, Ki, Kd) triple")
        kp, ki, kd = (_number(x, f"{lp} gains") for x in g)
        if not (math.isfinite(kp) and math.isfinite(ki) and math.isfinite(kd)):
            raise _FailureError("non_finite", f"{lp} gains ({kp}, {ki}, {kd}) not finite")
        box = self.gain_box[lp]
        if box is not None and not box.contains(kp, ki, kd):
            msg = f"{lp} gains ({kp:.6g}, {ki:.6g}, {kd:.6g}) outside its gain box"
            raise _FailureError("out_of_range", msg)
        return (kp, ki, kd)

    def _mv(self, lp: str, v: object) -> float:
        self._loop(lp, "RemoteMV")
        mv = v if type(v) is float else _number(v, f"{lp} RemoteMV")
        lo, hi = self.mv_range[lp]
        if lo <= mv <= hi:  # False for NaN too
            return mv
        if not math.isfinite(mv):
            raise _FailureError("non_finite", f"{lp} RemoteMV {mv} not finite")
        raise _FailureError("out_of_range", f"{lp} RemoteMV {mv:.6g} outside [{lo:.6g}, {hi:.6g}]")

    def _diagnostic(self, name: object, v: object) -> DiagnosticValue:
        kind = self.declared.get(name) if isinstance(name, str) else None
        if kind is None:
            msg = f"diagnostic {name!r} not declared in the class's diagnostics"
            raise _FailureError("bad_output", msg)
        assert isinstance(name, str)
        if kind is bool:
            if not isinstance(v, bool | np.bool_):
                raise _FailureError("bad_output", f"diagnostic {name} = {v!r}: declared bool")
            return bool(v)
        if kind is str:
            if not isinstance(v, str):
                raise _FailureError("bad_output", f"diagnostic {name} = {v!r}: declared str")
            return v
        x = _number(v, f"diagnostic {name}")
        if not math.isfinite(x):
            raise _FailureError("non_finite", f"diagnostic {name} = {x} not finite")
        return x

    # ---- failures and reports -------------------------------------------------------------

    def _failed(self, kind: str, message: str, t_s: float) -> None:
        if kind == "overrun":
            self.overruns += 1
        else:
            self.errors += 1
        self.last_error = f"{kind}: {message}"
        self.consecutive += 1
        self._log(kind, message, t_s)
        if not self.failing and self.consecutive >= self.max_failures:
            self.failing = True
            log.error(
                "controller %s failed %d steps in a row: heartbeat withheld "
                "(the PLC's watchdog sheds the loops)",
                self.class_name,
                self.consecutive,
            )

    def _log(self, kind: str, message: str, t_s: float) -> None:
        """Once per kind, then at most once per ``log_every_s`` of model time with the count."""
        last = self._logged.get(kind)
        if last is None:
            log.warning(
                "controller %s contained (%s): %s; last safe action held", self.class_name, kind, message
            )
            self._logged[kind] = (t_s, 0)
            return
        at, suppressed = last
        if t_s - at < self.log_every_s:
            self._logged[kind] = (at, suppressed + 1)
            return
        log.warning(
            "controller %s contained (%s) %d more times since t = %.1f s; last: %s",
            self.class_name,
            kind,
            suppressed + 1,
            at,
            message,
        )
        self._logged[kind] = (t_s, 0)

    def _status(self) -> SupervisorStatus:
        if self.shipped is not None:
            status = self.shipped.last_status
            return status if status is not None else self.core.status()
        return SupervisorStatus(
            mode=self.core.mode, cycles=self.cycles, mpc=None, adaptation=None, rejected=0
        )

    def report(self) -> ControllerReport:
        """The controller's state now (:class:`ControllerReport`)."""
        return ControllerReport(
            class_name=self.class_name,
            cycles=self.cycles,
            errors=self.errors,
            last_error=self.last_error,
            overruns=self.overruns,
            failing=self.failing,
            diagnostics=MappingProxyType(dict(self._diagnostics)),
        )


def _number(x: object, what: str) -> float:
    """A real number as a float (bool and non-numbers are malformed)."""
    if type(x) is float:
        return x
    if isinstance(x, bool) or not isinstance(x, int | float | np.integer | np.floating):
        raise _FailureError("bad_output", f"{what}: {x!r} is not a number")
    return float(x)


def build_host(
    site: SiteConfig,
    path: str | None = None,
    *,
    controller: SupervisoryController | None = None,
    cpu_clock: Callable[[], float] = time.thread_time,
) -> tuple[SupervisorCore, ControllerHost]:
    """The supervisor core and the controller host of a site, the one way the co-simulation and
    the supervisor process build them: ``controller`` (an instance), else the class at ``path`` (a
    CLI's ``--controller``), else the site's ``supervisor.controller``, else the shipped one.

    Raises
    ------
    tanklab.errors.ControllerError
        the controller cannot be loaded or built (:func:`supervisor.controller.build_controller`).
    """
    if controller is None:
        controller = build_controller(site, path)
    core = controller.core if isinstance(controller, ShippedController) else SupervisorCore(site)
    return core, ControllerHost(site, controller, core, cpu_clock=cpu_clock)
