"""The supervisory-controller plug-in interface: one PLC snapshot in, actions and diagnostics out.

A supervisory controller is a class with one verb (decision 0054, docs/your-controller.md):

    step(snapshot, t_s) -> ControllerOutput

called on every supervisor sample (every ``supervisor.sample_time_s``, a whole number of PLC
scans) with the PLC's :class:`supervisor.cycle.PlcSnapshot` of that scan (scan counter, model time,
per loop SP, PV, MV, mode, applied gains and their source, every level the PLC read and its
quality) and the snapshot's model time ``t_s`` [s]. It returns

- ``gains``: (Kp, Ki, Kd) per loop, pushed through ``SetGains`` (the PLC stages them for its next
  scan boundary and refuses a set outside the loop's gain box);
- ``remote_mv``: the output [pump unit, within the loop's MV range] of loops in REMOTE (or put in
  REMOTE by the same output); a value for another loop is not written;
- ``modes``: AUTO or REMOTE per loop (the supervisor's identity may switch a loop between the two;
  enter REMOTE bumplessly by writing ``remote_mv`` = the applied MV with it);
- ``diagnostics``: its own values, name -> float / bool / str, each declared in the class's
  ``diagnostics`` (a tuple of :class:`tanklab.tags.Diagnostic`) and published as
  ``Supervisor.Controller.Diagnostics.<name>``.

What it writes reaches the pumps from PLC scan k + 1 on (the snapshot is of scan k). Construction:
``Class(site, params)`` with the validated :class:`tanklab.config.SiteConfig` and the mapping
``supervisor.controller.params`` of the site file. An optional ``track(snapshot)`` method is called
on the scans between two samples. The supervisor contains a controller that misbehaves
(:mod:`supervisor.host`).

The shipped MPC and adaptive PID implement the interface: :class:`ShippedController` runs
:meth:`supervisor.cycle.SupervisorCore.cycle` (dotted path ``supervisor.controller:ShippedController``).

This module is pure apart from :func:`load_controller_class`, which imports the named module.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from supervisor.cycle import Actions, PlcSnapshot, SupervisorCore, SupervisorStatus
from tanklab.config import SiteConfig
from tanklab.config.supervisor import CONTROLLER_PATH
from tanklab.enums import LoopMode
from tanklab.errors import ControllerError
from tanklab.tags import Diagnostic

__all__ = [
    "SHIPPED",
    "ControllerOutput",
    "Diagnostic",
    "DiagnosticValue",
    "ShippedController",
    "SupervisoryController",
    "build_controller",
    "class_name",
    "load_controller_class",
]

DiagnosticValue = float | bool | str
"""A diagnostic's value: a finite float, a bool or a string."""

_EMPTY: Mapping[str, Any] = MappingProxyType({})

SHIPPED = "supervisor.controller:ShippedController"
"""The dotted path of the shipped MPC and adaptive PID."""


@dataclass(slots=True)
class ControllerOutput:
    """What a controller asks for after one snapshot (see the module docstring).

    Attributes
    ----------
    gains : loop -> (Kp, Ki, Kd) in the loop's error unit.  remote_mv : loop -> RemoteMV [pump unit].
    modes : loop -> LoopMode.AUTO or LoopMode.REMOTE.  diagnostics : name -> float / bool / str.
    """

    gains: Mapping[str, tuple[float, float, float]] = field(default_factory=lambda: _EMPTY)
    remote_mv: Mapping[str, float] = field(default_factory=lambda: _EMPTY)
    modes: Mapping[str, LoopMode] = field(default_factory=lambda: _EMPTY)
    diagnostics: Mapping[str, DiagnosticValue] = field(default_factory=lambda: _EMPTY)


@runtime_checkable
class SupervisoryController(Protocol):
    """A supervisory controller (the module docstring says what each part means).

    Built as ``Class(site: SiteConfig, params: Mapping[str, Any])``.
    """

    diagnostics: ClassVar[tuple[Diagnostic, ...]]
    """The diagnostics :meth:`step` may return, in publishing order."""

    def step(self, snapshot: PlcSnapshot, t_s: float) -> ControllerOutput:
        """The actions for the PLC scan after ``snapshot`` (model time ``t_s`` [s])."""
        ...


class ShippedController:
    """The shipped MPC and RLS adaptive PID as a :class:`SupervisoryController`: each step is one
    :meth:`SupervisorCore.cycle` (mode logic, shadow or direct MPC, gain adaptation), so the
    supervisor behaves exactly as before the interface. Its diagnostics are the MPC's and RLS's
    own nodes (``Supervisor.MPC.*``, ``Supervisor.RLS.*``): it declares none here.

    Parameters
    ----------
    site : the site.  params : must be empty (the shipped controllers take theirs from the
        ``supervisor`` section).  core : an existing core to wrap (default: a new one).
    """

    diagnostics: ClassVar[tuple[Diagnostic, ...]] = ()

    def __init__(
        self, site: SiteConfig, params: Mapping[str, Any] = _EMPTY, *, core: SupervisorCore | None = None
    ) -> None:
        if params:
            raise ValueError(
                f"takes no params (the supervisor section configures it), got {', '.join(sorted(params))}"
            )
        self.core = core if core is not None else SupervisorCore(site)
        self.last_status: SupervisorStatus | None = None
        self.last_actions: Actions | None = None
        """The core's actions of the last step (the host writes these, once checked)."""

    def step(
        self, snapshot: PlcSnapshot, t_s: float, preview: NDArray[np.float64] | None = None
    ) -> ControllerOutput:
        """One supervisor cycle; ``preview`` is the optional reference preview of
        :meth:`SupervisorCore.cycle`."""
        act: Actions = self.core.cycle(snapshot, preview)
        self.last_status = act.status
        self.last_actions = act
        return ControllerOutput(act.gains, act.remote_mv, act.modes, _EMPTY)

    def track(self, snapshot: PlcSnapshot) -> None:
        """A scan between two samples (:meth:`SupervisorCore.track`)."""
        self.core.track(snapshot)


def class_name(cls: type) -> str:
    """The dotted path of a class, ``package.module:Class``."""
    return f"{cls.__module__}:{cls.__qualname__}"


def load_controller_class(path: str) -> type:
    """Import the controller class named ``package.module:Class`` and check its interface.

    Raises
    ------
    ControllerError
        one line naming the path and the problem: malformed, module not importable (or raising
        on import), no such name, not a class, no ``step`` method, ``diagnostics`` not a tuple of
        :class:`Diagnostic`.
    """
    if not re.match(CONTROLLER_PATH, path):
        raise ControllerError(f"controller {path!r}: not a dotted path package.module:Class")
    module_name, attr = path.split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:
        raise ControllerError(f"controller {path}: module {module_name!r} is not importable ({e})") from e
    except Exception as e:  # a user's module may raise anything on import: name it, in one line
        raise ControllerError(
            f"controller {path}: importing {module_name!r} raised {type(e).__name__}: {e}"
        ) from e
    cls = getattr(module, attr, None)
    if cls is None:
        raise ControllerError(f"controller {path}: module {module_name!r} has no attribute {attr!r}")
    if not isinstance(cls, type):
        raise ControllerError(f"controller {path}: {attr!r} is a {type(cls).__name__}, not a class")
    if not callable(getattr(cls, "step", None)):
        raise ControllerError(
            f"controller {path}: does not implement SupervisoryController (no step(snapshot, t_s) method)"
        )
    diags = getattr(cls, "diagnostics", None)
    if not isinstance(diags, tuple) or not all(isinstance(d, Diagnostic) for d in diags):
        raise ControllerError(
            f"controller {path}: does not implement SupervisoryController "
            "(its diagnostics must be a tuple of tanklab.tags.Diagnostic)"
        )
    names = [d.name for d in diags]
    if len(set(names)) != len(names):
        raise ControllerError(f"controller {path}: a diagnostic name is declared twice ({', '.join(names)})")
    return cls


def build_controller(site: SiteConfig, path: str | None = None) -> SupervisoryController:
    """The site's supervisory controller: ``path`` (a CLI's ``--controller``) or else the site's
    ``supervisor.controller.class``, built with the site's ``supervisor.controller.params``;
    without either, the shipped one.

    Raises
    ------
    ControllerError
        the class cannot be loaded (:func:`load_controller_class`) or its construction raised; the
        message starts with where the path came from (``--controller`` or
        ``supervisor.controller.class``; a caller that knows the site file puts it first).
    """
    spec = site.supervisor.controller if site.supervisor is not None else None
    where = "--controller" if path else "supervisor.controller.class"
    path = path or (spec.class_ if spec is not None else SHIPPED)
    params: Mapping[str, Any] = spec.params if spec is not None else {}
    try:
        cls = load_controller_class(path)
        try:
            controller = cls(site, MappingProxyType(dict(params)))
        except Exception as e:  # the user's constructor validates its params: name what it said
            raise ControllerError(
                f"controller {path}: construction failed (supervisor.controller.params): "
                f"{type(e).__name__}: {e}"
            ) from e
        if not isinstance(controller, SupervisoryController):
            raise ControllerError(f"controller {path}: its instance does not implement SupervisoryController")
    except ControllerError as e:
        raise ControllerError(f"{where}: {e}") from e.__cause__
    return controller
