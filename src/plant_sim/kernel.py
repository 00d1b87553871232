"""The RK4 fast path's right-hand side: the reference, traced into straight-line code.

Why it exists: the RK4 integrator evaluates the right-hand side four times per sub-step on a
handful of floats, where the loops, tuple unpacking and list allocations of the reference
(:meth:`plant_sim.models.HeldRhs.derivative`) cost more than its arithmetic; the measured gain is
in docs/decisions/0028-one-plant-model.md.

How it holds no second copy of the model: :func:`kernel_for` runs the reference once per *layout*
(which valves, leaks, lagged pumps and outflow disturbances are active) on symbolic values
(:class:`_Sym`): every arithmetic operation the reference performs on a level, a pump flow or a
held input is recorded as one assignment, in the reference's own order and operand order, and
every call of one of the model's laws (:data:`plant_sim.models.LAWS`) is recorded as a call of
that same function. Python runs the reference's loops and list indexing while tracing, so what
is left is the model's arithmetic, unrolled. The recorded code is compiled; the held inputs
(constant inflows, targets of lagged pumps, outflow disturbances, ``s * c`` of the open orifices)
are its arguments, so one compiled kernel serves every input set of a layout. Because the kernel
performs exactly the reference's floating-point operations, its results are the reference's bit
for bit (tests/plant_sim/test_kernel.py checks that on every shipped config).

``rhs(x)`` is dx/dt at ``x``; ``rhs_at(y, k, c)`` is dx/dt at the RK4 stage point ``y + c k``
(entries formed as ``y[i] + c * k[i]``, the integrator's own expression, inside the kernel
instead of as a new list). ``print(kernel_for(held).source)`` shows the code.
"""

from __future__ import annotations

import ast
import functools
import inspect
import linecache
import math
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from plant_sim import models
from plant_sim.models import LAWS, HeldRhs, Laws

RhsFn = Callable[[list[float]], list[float]]
"""``f(x) -> dx/dt`` on Python floats (the full state; only levels and lagged pump flows are read)."""
RhsAtFn = Callable[[list[float], list[float], float], list[float]]
"""``f(y, k, c) -> dx/dt`` at the stage point ``y[i] + c * k[i]``."""

_KERNELS_KEPT = 64
"""Layouts kept compiled per network (openings toggled through many layouts: start over)."""


def _lit(v: float) -> str:
    """A float as a source literal that parses back to the same bits."""
    if math.isfinite(v):
        return repr(v) if math.copysign(1.0, v) > 0 else f"({v!r})"
    return f"float('{v!r}')"


class _Tape:
    """The assignments recorded while tracing, in order."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def emit(self, expr: str) -> _Sym:
        name = f"t{len(self.lines)}"
        self.lines.append(f"{name} = {expr}")
        return _Sym(name, self)


def _arg(v: object) -> str:
    if isinstance(v, _Sym):
        return v.name
    if type(v) is float:
        return _lit(v)
    raise TypeError(f"the reference used a {type(v).__name__} where a float or a traced value was expected")


class _Sym:
    """A traced float: arithmetic on it records an assignment instead of computing."""

    __slots__ = ("name", "tape")

    def __init__(self, name: str, tape: _Tape) -> None:
        self.name = name
        self.tape = tape

    def _op(self, a: object, op: str, b: object) -> _Sym:
        return self.tape.emit(f"{_arg(a)} {op} {_arg(b)}")

    def __add__(self, o: object) -> _Sym:
        return self._op(self, "+", o)

    def __radd__(self, o: object) -> _Sym:
        return self._op(o, "+", self)

    def __sub__(self, o: object) -> _Sym:
        return self._op(self, "-", o)

    def __rsub__(self, o: object) -> _Sym:
        return self._op(o, "-", self)

    def __mul__(self, o: object) -> _Sym:
        return self._op(self, "*", o)

    def __rmul__(self, o: object) -> _Sym:
        return self._op(o, "*", self)

    def __truediv__(self, o: object) -> _Sym:
        return self._op(self, "/", o)

    def __rtruediv__(self, o: object) -> _Sym:
        return self._op(o, "/", self)

    def __neg__(self) -> _Sym:
        return self.tape.emit(f"-{self.name}")

    def __bool__(self) -> bool:
        raise TypeError("the reference branched on a traced value: branches belong in the laws")


@functools.cache
def _law_expression(fn: Callable[..., Any]) -> tuple[tuple[str, ...], ast.expr]:
    """A law's parameters and the expression of its one ``return`` statement."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    fdef = tree.body[0]
    assert isinstance(fdef, ast.FunctionDef)
    body = [s for s in fdef.body if not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))]
    if len(body) != 1 or not isinstance(body[0], ast.Return) or body[0].value is None:
        raise TypeError(f"law {fn.__name__} must be one return expression to be inlined")
    return tuple(a.arg for a in fdef.args.args), body[0].value


def _inline(fn: Callable[..., Any], args: list[str]) -> str:
    """The law's return expression with its parameters replaced by ``args`` (names or literals)."""
    params, expr = _law_expression(fn)
    given = dict(zip(params, args, strict=True))

    class _Substitute(ast.NodeTransformer):
        def visit_Name(self, node: ast.Name) -> ast.expr:
            return ast.parse(given[node.id], mode="eval").body if node.id in given else node

    return ast.unparse(_Substitute().visit(ast.parse(ast.unparse(expr), mode="eval")).body)


def _tracing_laws(tape: _Tape) -> Laws:
    """Laws that record the model's own law, inlined: its return expression on the traced values."""

    def inlined(fn: Callable[..., Any]) -> Callable[..., _Sym]:
        return lambda *args: tape.emit(_inline(fn, [_arg(a) for a in args]))

    return Laws(
        level=inlined(LAWS.level),
        orifice=inlined(LAWS.orifice),
        outlet=inlined(LAWS.outlet),
        fade=inlined(LAWS.fade),
        spill=inlined(LAWS.spill),
    )


def layout(held: HeldRhs) -> tuple[object, ...]:
    """What a kernel is unrolled for: the indices of the active terms (not their values)."""
    return (
        tuple(i for i, _ in held.outflows),
        tuple(i for i, _ in held.leaks),
        tuple((k, up) for k, up, _ in held.drains),
        tuple((k, up, down) for k, up, down, _ in held.links),
        tuple((j, tank, rate) for j, tank, _, rate in held.lagged),
    )


def held_values(held: HeldRhs) -> list[float]:
    """The kernel's arguments for one input set, in :func:`_trace`'s order."""
    return [*held.inflow, held.v_in0, *(target for _, _, target, _ in held.lagged), *_part_values(held)]


def _part_values(held: HeldRhs) -> list[float]:
    """The arguments fixed by the openings and disturbances (outflows, leaks, drains, links)."""
    return [
        *(d for _, d in held.outflows),
        *(cs for _, cs in held.leaks),
        *(cs for _, _, cs in held.drains),
        *(cs for _, _, _, cs in held.links),
    ]


@dataclass(frozen=True)
class Kernel:
    """A compiled kernel of one layout: ``make(*held_values(held)) -> (rhs, rhs_at)``."""

    source: str
    make: Callable[..., tuple[RhsFn, RhsAtFn]]


def _trace(held: HeldRhs) -> tuple[list[str], list[str], list[str], list[int]]:
    """Run the reference on symbols: (argument names, body lines, read names, their x indices)."""
    tape = _Tape()
    sym: Any = HeldRhs.__new__(HeldRhs)  # the same layout and constants, the held values as arguments
    sym.__dict__.update(held.__dict__)
    args: list[str] = []

    def arg(name: str) -> _Sym:
        args.append(name)
        return _Sym(name, tape)

    n = held.n
    sym.inflow = [arg(f"inflow{i}") for i in range(n)]
    sym.v_in0 = arg("v_in0")
    sym.lagged = [(j, tank, arg(f"target{j}"), rate) for j, tank, _, rate in held.lagged]
    sym.outflows = [(i, arg(f"d{m}")) for m, (i, _) in enumerate(held.outflows)]
    sym.leaks = [(i, arg(f"leak{m}")) for m, (i, _) in enumerate(held.leaks)]
    sym.drains = [(k, up, arg(f"drain{m}")) for m, (k, up, _) in enumerate(held.drains)]
    sym.links = [(k, up, down, arg(f"link{m}")) for m, (k, up, down, _) in enumerate(held.links)]
    index = list(range(n)) + [n + j for j, _, _, _ in held.lagged]
    reads = [f"h{i}" for i in range(n)] + [f"q{j}" for j, _, _, _ in held.lagged]
    x: list[Any] = [None] * (n + held.p + 4)  # a read of anything else fails the trace
    for name, i in zip(reads, index, strict=True):
        x[i] = _Sym(name, tape)
    out = sym.derivative(x, _tracing_laws(tape))
    body = [*tape.lines, f"return [{', '.join(_arg(v) for v in out)}]"]
    return args, body, reads, index


def kernel_for(held: HeldRhs) -> Kernel:
    """The compiled kernel of ``held``'s layout (traced once per layout, cached on the network)."""
    cache = held.net._kernels
    key = layout(held)
    found = cache.get(key)
    if isinstance(found, Kernel):
        return found
    args, body, reads, index = _trace(held)
    pad = " " * 8
    lines = [
        f'"""Right-hand side traced from plant_sim.models.HeldRhs.derivative (layout {key})."""',
        "",
        f"def make({', '.join(args)}):",
        "    def rhs(x):",
        *(f"{pad}{v} = x[{i}]" for v, i in zip(reads, index, strict=True)),
        *(pad + b for b in body),
        "",
        "    def rhs_at(y, k, c):",
        *(f"{pad}{v} = y[{i}] + c * k[{i}]" for v, i in zip(reads, index, strict=True)),
        *(pad + b for b in body),
        "",
        "    return rhs, rhs_at",
        "",
    ]
    source = "\n".join(lines)
    filename = f"<plant_sim kernel {id(held.net):x} {len(cache)}>"
    namespace: dict[str, object] = dict(vars(models))  # the laws' own names: math, H_LAMINAR_M, ...
    exec(compile(source, filename, "exec"), namespace)  # traced from the reference (module docstring)
    linecache.cache[filename] = (len(source), None, source.splitlines(keepends=True), filename)
    if len(cache) >= _KERNELS_KEPT:
        cache.clear()
    kernel = cache[key] = Kernel(source=source, make=namespace["make"])  # type: ignore[arg-type]
    return kernel


def bind(held: HeldRhs) -> tuple[RhsFn, RhsAtFn]:
    """``(rhs, rhs_at)`` of ``held``: its layout's kernel with its held values bound.

    The kernel is remembered on the openings' part of ``held`` (reused while the openings and
    disturbances are unchanged, i.e. most steps), so a step only binds the new pump flows.
    """
    if held.direct_pumps:
        raise ValueError("bind() needs the pumps' own flows (no pump_flows_m3_s override)")
    part_cache = held.part.cache
    kernel = part_cache.get("kernel")
    if not isinstance(kernel, Kernel):
        kernel = part_cache["kernel"] = kernel_for(held)
        part_cache["values"] = _part_values(held)
    values: list[float] = part_cache["values"]  # type: ignore[assignment]
    if held.lagged:
        return kernel.make(*held.inflow, held.v_in0, *[target for _, _, target, _ in held.lagged], *values)
    return kernel.make(*held.inflow, held.v_in0, *values)
