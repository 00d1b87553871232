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
instead of as a new list). ``step(y, h)`` is the integrator's step (``plant_sim.integrate.rk4_step``)
traced the same way: its calls of the right-hand side kept, its weighted sums unrolled.
``print(kernel_for(held, rk4_step).source)`` shows the code.
"""

from __future__ import annotations

import ast
import functools
import inspect
import linecache
import math
import re
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

from plant_sim import models
from plant_sim.models import LAWS, HeldRhs, Laws

RhsFn = Callable[[list[float]], list[float]]
"""``f(x) -> dx/dt`` on Python floats (the full state; only levels and lagged pump flows are read)."""
RhsAtFn = Callable[[list[float], list[float], float], list[float]]
"""``f(y, k, c) -> dx/dt`` at the stage point ``y[i] + c * k[i]``."""
StepFn = Callable[[list[float], float], tuple[list[float], float]]
"""``step(y, h) -> (y_new, stages' summed spill rate)``: one integrator step of ``h`` [s]."""
StepReference = Callable[[RhsFn, RhsAtFn, list[float], float], tuple[list[float], float]]
"""An integrator step written on floats (``plant_sim.integrate.rk4_step``), traced into the kernel."""

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


_SymOp = Callable[["_Sym", object], "_Sym"]


def _binary(op: str) -> tuple[_SymOp, _SymOp]:
    """``a op b`` recorded, as the operator and its reflected form (``2.0 * x`` keeps its order)."""

    def forward(self: _Sym, other: object) -> _Sym:
        return self.tape.emit(f"{_arg(self)} {op} {_arg(other)}")

    def reflected(self: _Sym, other: object) -> _Sym:
        return self.tape.emit(f"{_arg(other)} {op} {_arg(self)}")

    return forward, reflected


class _Sym:
    """A traced float: arithmetic on it records an assignment instead of computing."""

    __slots__ = ("name", "tape")

    def __init__(self, name: str, tape: _Tape) -> None:
        self.name = name
        self.tape = tape

    __add__, __radd__ = _binary("+")
    __sub__, __rsub__ = _binary("-")
    __mul__, __rmul__ = _binary("*")
    __truediv__, __rtruediv__ = _binary("/")

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

    constants = {k: v for k, v in vars(models).items() if type(v) is float}

    class _Substitute(ast.NodeTransformer):
        def visit_Name(self, node: ast.Name) -> ast.expr:
            if node.id in given:
                return ast.parse(given[node.id], mode="eval").body
            if node.id in constants:  # the module's constants (H_LAMINAR_M, ...) as literals
                return ast.parse(_lit(constants[node.id]), mode="eval").body
            return node

        def visit_Attribute(self, node: ast.Attribute) -> ast.expr:
            if isinstance(node.value, ast.Name) and node.value.id == "math":
                return ast.Name(id=f"math_{node.attr}", ctx=ast.Load())  # one lookup, not two
            return self.generic_visit(node)  # type: ignore[return-value]

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


_TEMP = re.compile(r"\bt\d+\b")


def _fold(lines: list[str]) -> list[str]:
    """Substitute every temporary used exactly once into its one use, parenthesised.

    The recorded operations are pure float arithmetic, so evaluating one where its value is used
    instead of one line earlier computes the same bits; it only saves a store and a load per
    operation (the RK4 sum becomes one expression per entry).
    """
    uses: dict[str, int] = {}
    for line in lines:
        rhs = line.split(" = ", 1)[1] if line.startswith("t") else line
        for name in _TEMP.findall(rhs):
            uses[name] = uses.get(name, 0) + 1
    pending: dict[str, str] = {}
    out = []
    for line in lines:
        target, expr = line.split(" = ", 1) if line.startswith("t") else ("", line)
        expr = _TEMP.sub(lambda m: f"({pending.pop(m.group())})" if m.group() in pending else m.group(), expr)
        if target and uses.get(target, 0) == 1:
            pending[target] = expr
        else:
            out.append(f"{target} = {expr}" if target else expr)
    assert not pending, "every temporary is used"
    return out


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


class Bound(NamedTuple):
    """A kernel with one input set's held values: the right-hand side and the traced step (a
    named tuple: built every step, at a tuple's cost)."""

    rhs: RhsFn
    rhs_at: RhsAtFn
    step: StepFn


@dataclass(frozen=True)
class Kernel:
    """A compiled kernel of one layout: ``make(*held_values(held)) -> (rhs, rhs_at, step)``."""

    source: str
    make: Callable[..., tuple[RhsFn, RhsAtFn, StepFn]]


def _trace(held: HeldRhs) -> tuple[list[str], list[str], list[str], list[int]]:
    """Run the reference on symbols: (argument names, body lines, read names, their x indices)."""
    tape = _Tape()
    sym: Any = HeldRhs.__new__(HeldRhs)  # the same layout and constants, the held values as arguments
    for name in HeldRhs.__slots__:
        setattr(sym, name, getattr(held, name))
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
    body = _fold([*tape.lines, f"return [{', '.join(_arg(v) for v in out)}]"])
    return args, body, reads, index


def _trace_step(step: StepReference, m: int) -> list[str]:
    """Run the integrator step on symbols: ``y`` and ``h`` traced, ``rhs`` and ``rhs_at`` recorded
    as calls returning traced lists (their entries read by index). Returns the body lines."""
    tape = _Tape()
    names: dict[int, str] = {}
    y = [_Sym(f"y[{i}]", tape) for i in range(m)]

    def result(expr: str) -> list[_Sym]:
        k = tape.emit(expr)
        out = [_Sym(f"{k.name}[{i}]", tape) for i in range(m)]
        names[id(out)] = k.name
        return out

    def rhs(v: list[_Sym]) -> list[_Sym]:
        assert v is y, "the step evaluates rhs at its own state"
        return result("rhs(y)")

    def rhs_at(v: list[_Sym], k: list[_Sym], c: object) -> list[_Sym]:
        assert v is y, "the step forms stage points from its own state"
        return result(f"rhs_at(y, {names[id(k)]}, {_arg(c)})")

    y_new, spill = step(rhs, rhs_at, y, _Sym("h", tape))  # type: ignore[arg-type]
    return _fold([*tape.lines, f"return [{', '.join(_arg(v) for v in y_new)}], {_arg(spill)}"])


def kernel_for(held: HeldRhs, step: StepReference) -> Kernel:
    """The compiled kernel of ``held``'s layout with ``step`` traced (once per layout, cached on
    the network)."""
    cache = held.net._kernels
    key = (layout(held), step)
    found = cache.get(key)
    if isinstance(found, Kernel):
        return found
    args, body, reads, index = _trace(held)
    step_body = _trace_step(step, held.n + held.p + 4)
    pad = " " * 8
    lines = [
        f'"""Traced from plant_sim.models.HeldRhs.derivative and {step.__module__}.{step.__qualname__}',
        "",
        f'Layout (outflows, leaks, drains, links, lagged pumps): {key[0]}."""',
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
        "    def step(y, h):",
        *(pad + b for b in step_body),
        "",
        "    return rhs, rhs_at, step",
        "",
    ]
    source = "\n".join(lines)
    filename = f"<plant_sim kernel {id(held.net):x} {len(cache)}>"
    namespace: dict[str, object] = dict(vars(models))  # the laws' own names
    namespace.update({f"math_{name}": getattr(math, name) for name in dir(math) if not name.startswith("_")})
    exec(compile(source, filename, "exec"), namespace)  # traced from the reference (module docstring)
    linecache.cache[filename] = (len(source), None, source.splitlines(keepends=True), filename)
    if len(cache) >= _KERNELS_KEPT:
        cache.clear()
    kernel = cache[key] = Kernel(source=source, make=namespace["make"])  # type: ignore[arg-type]
    return kernel


def bind(held: HeldRhs, step: StepReference) -> Bound:
    """``held``'s layout's kernel (with ``step`` traced) bound to its held values.

    The kernel is remembered on the openings' part of ``held`` (reused while the openings and
    disturbances are unchanged, i.e. most steps), so a step only binds the new pump flows.
    """
    if held.direct_pumps:
        raise ValueError("bind() needs the pumps' own flows (no pump_flows_m3_s override)")
    found = held.part.cache.get(step)
    if found is None:
        found = held.part.cache[step] = (kernel_for(held, step).make, _part_values(held))
    make, values = found
    if held.lagged:
        return Bound._make(
            make(*held.inflow, held.v_in0, *[target for _, _, target, _ in held.lagged], *values)
        )
    return Bound._make(make(*held.inflow, held.v_in0, *values))
