"""``tankctl tune``: tuning rules of ``plc_emulator.tuning`` on the command line.

Commands (mounted by ``tankctl.cli`` as ``tankctl tune``)::

    tankctl tune imc  --num 28.82 --den 29.6 14.7 1 --lam 1 [--pid/--pi] [--json]
    tankctl tune imc  --gain K --tau1 T1 --tau2 T2 --lam 1 [--pid/--pi] [--json]
    tankctl tune nlpi --b 2.0 --a-prime 0.5 (--zeta 0.7071 --wn 0.5 | --overshoot 4.32 --settling 13) [--json]
    tankctl tune zn   --gain K --dead-time THETA --tau TAU [--type p|pi|pid] [--json]

``--den`` takes its coefficients (highest power first) either space-separated after the option
(``--den 29.6 14.7 1``; click options take a fixed number of values, so the extra values are
collected from the command's remaining arguments) or as one quoted string (``--den "29.6 14.7 1"``).
Bad input prints one line on stderr and exits with code 2; nothing prints a traceback.
Each command imports ``plc_emulator.tuning`` (and through ``tanklab.checks``, numpy) when it
runs, so that mounting ``tune`` costs the other ``tankctl`` commands nothing
(docs/decisions/0023-lazy-cli-imports.md).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Annotated, Literal

import typer
from rich.console import Console
from rich.table import Table

from tankctl.usage import OneLineUsage

__all__ = ["app"]


class _TuneUsage(OneLineUsage):
    group = "tune"


app = typer.Typer(
    help="Tuning rules: IMC PI/PID, nonlinear PI gains, Ziegler-Nichols reaction curve.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

JsonOpt = Annotated[bool, typer.Option("--json", help="Print a JSON object instead of a table.")]
Row = tuple[str, float | None, str]


def _fail(command: str, message: str) -> typer.Exit:
    typer.echo(f"tankctl tune {command}: {message}", err=True)
    return typer.Exit(2)


def _emit(title: str, rows: Sequence[Row], as_json: bool) -> None:
    """Print rows (key, value, unit) as JSON (None for an infinite value) or as a table."""
    if as_json:
        typer.echo(json.dumps({k: v for k, v, _ in rows}))
        return
    table = Table(title=title)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_column("unit")
    for key, value, unit in rows:
        table.add_row(key, "inf" if value is None else f"{value:.6g}", unit)
    Console().print(table)


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _parse_den(den: str | None, extra: list[str]) -> tuple[float, ...]:
    if den is None:
        if extra:
            raise ValueError(f"unexpected arguments {' '.join(extra)!r} (did you mean --den?)")
        raise ValueError("--den is required with --num")
    tokens = den.replace(",", " ").split() + list(extra)
    try:
        return tuple(float(t) for t in tokens)
    except ValueError:
        raise ValueError(f"--den takes numbers, got {' '.join(tokens)!r}") from None


@app.command(cls=_TuneUsage, context_settings={"allow_extra_args": True})
def imc(
    ctx: typer.Context,
    lam: Annotated[float, typer.Option("--lam", help="IMC filter time constant lambda in s.")],
    num: Annotated[float | None, typer.Option(help="Numerator of num / (a2 s^2 + a1 s + a0).")] = None,
    den: Annotated[
        str | None,
        typer.Option(help="Denominator a2 a1 a0 (or a1 a0), highest power first, space-separated."),
    ] = None,
    gain: Annotated[
        float | None, typer.Option("--gain", help="Process gain K (instead of --num/--den).")
    ] = None,
    tau1: Annotated[float | None, typer.Option(help="Time constant tau1 in s (with --gain).")] = None,
    tau2: Annotated[float | None, typer.Option(help="Time constant tau2 in s (with --gain).")] = None,
    pid: Annotated[bool, typer.Option("--pid/--pi", help="PID (default) or PI (Td = 0).")] = True,
    as_json: JsonOpt = False,
) -> None:
    """IMC PI/PID for K / ((tau1 s + 1)(tau2 s + 1)).

    Kc = (tau1 + tau2) / (K lam), Ti = tau1 + tau2, Td = tau1 tau2 / Ti (PI: Td = 0).
    """
    from plc_emulator.tuning import imc_from_denominator, imc_from_taus

    try:
        by_tf = num is not None or den is not None
        by_taus = gain is not None or tau1 is not None or tau2 is not None
        if by_tf and by_taus:
            raise ValueError("give either --num/--den or --gain/--tau1/--tau2, not both")
        if by_tf:
            if num is None:
                raise ValueError("--num is required with --den")
            result = imc_from_denominator(num, _parse_den(den, ctx.args), lam, pid=pid)
        elif by_taus:
            if ctx.args:
                raise ValueError(f"unexpected arguments {' '.join(ctx.args)!r}")
            if gain is None or tau1 is None or tau2 is None:
                raise ValueError("--gain, --tau1 and --tau2 are required together")
            result = imc_from_taus(gain, tau1, tau2, lam, pid=pid)
        else:
            raise ValueError("give the model as --num N --den A2 A1 A0, or as --gain K --tau1 T1 --tau2 T2")
        vel = result.params.to_velocity()
    except (ValueError, TypeError) as e:
        raise _fail("imc", str(e)) from None
    rows: list[Row] = [
        ("Kc", result.Kc, "MV unit per PV unit"),
        ("Ti", result.Ti, "s"),
        ("Td", result.Td, "s"),
        ("tau1", result.tau1, "s"),
        ("tau2", result.tau2, "s"),
        ("K", result.K, "PV unit per MV unit"),
        ("lam", result.lam, "s"),
        ("Kp", vel.Kp, "MV unit per PV unit (velocity form)"),
        ("Ki", vel.Ki, "MV unit per PV unit s"),
        ("Kd", vel.Kd, "MV unit s per PV unit"),
    ]
    _emit(f"IMC {'PID' if pid else 'PI'} (lambda = {result.lam:g} s)", rows, as_json)


@app.command(cls=_TuneUsage)
def nlpi(
    b: Annotated[
        float, typer.Option("--b", help="Input gain b in m/s per MV unit of dh/dt = b u - a' sqrt(h).")
    ],
    a_prime: Annotated[float, typer.Option("--a-prime", help="Outflow coefficient a' in sqrt(m)/s.")],
    zeta: Annotated[float | None, typer.Option(help="Damping ratio.")] = None,
    wn: Annotated[float | None, typer.Option(help="Natural frequency in rad/s.")] = None,
    overshoot: Annotated[float | None, typer.Option(help="Overshoot in % (instead of --zeta).")] = None,
    settling: Annotated[float | None, typer.Option(help="Settling time in s (instead of --wn).")] = None,
    as_json: JsonOpt = False,
) -> None:
    """Feedback-linearized PI gains: Kp = 2 zeta wn / b, Ki = wn^2 / b, Kl = a' / b."""
    from plc_emulator.tuning import nlpi_gains, spec_to_zeta_wn

    try:
        by_zw = zeta is not None or wn is not None
        by_spec = overshoot is not None or settling is not None
        if by_zw == by_spec:
            raise ValueError("give either --zeta and --wn, or --overshoot and --settling")
        if by_zw:
            if zeta is None or wn is None:
                raise ValueError("--zeta and --wn are required together")
            z, w = zeta, wn
        else:
            if overshoot is None or settling is None:
                raise ValueError("--overshoot and --settling are required together")
            spec = spec_to_zeta_wn(overshoot, settling)
            z, w = spec.zeta, spec.wn
        g = nlpi_gains(b, a_prime, z, w)
    except (ValueError, TypeError) as e:
        raise _fail("nlpi", str(e)) from None
    rows: list[Row] = [
        ("Kp", g.Kp, "MV unit per m"),
        ("Ki", g.Ki, "MV unit per m s"),
        ("Kl", g.Kl, "MV unit per sqrt(m)"),
        ("zeta", z, "-"),
        ("wn", w, "rad/s"),
    ]
    _emit("Nonlinear PI", rows, as_json)


@app.command(cls=_TuneUsage)
def zn(
    gain: Annotated[float, typer.Option("--gain", help="Process gain K of K e^{-theta s} / (tau s + 1).")],
    dead_time: Annotated[float, typer.Option("--dead-time", help="Dead time theta in s.")],
    tau: Annotated[float, typer.Option("--tau", help="Time constant tau in s.")],
    kind: Annotated[
        Literal["p", "pi", "pid"], typer.Option("--type", help="Controller type.", case_sensitive=False)
    ] = "pi",
    as_json: JsonOpt = False,
) -> None:
    """Ziegler-Nichols open-loop (reaction curve) tuning from a FOPDT model."""
    from plc_emulator.tuning import velocity_gains, ziegler_nichols_open_loop

    try:
        p = ziegler_nichols_open_loop(gain, dead_time, tau, kind)
        vel = velocity_gains(p.Kc, p.Ti, p.Td)
    except (ValueError, TypeError) as e:
        raise _fail("zn", str(e)) from None
    rows: list[Row] = [
        ("Kc", p.Kc, "MV unit per PV unit"),
        ("Ti", _finite_or_none(p.Ti), "s"),
        ("Td", p.Td, "s"),
        ("Kp", vel.Kp, "MV unit per PV unit (velocity form)"),
        ("Ki", vel.Ki, "MV unit per PV unit s"),
        ("Kd", vel.Kd, "MV unit s per PV unit"),
    ]
    _emit(f"Ziegler-Nichols {kind.upper()}", rows, as_json)
