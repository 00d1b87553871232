"""``tankctl gains``: a loop's applied gains and the supervisor's RLS state; SetGains,
ReleaseGains and ResetGains as an engineer."""

from __future__ import annotations

import json
import math
from typing import Annotated, Any

import typer

from tankctl.ops.client import TierClient
from tankctl.ops.display import enum_name, num, plain, sci, show
from tankctl.ops.errors import UnreachableError
from tankctl.ops.options import JsonOpt, StackOptions, stack_command
from tankctl.ops.run import fail, run
from tankctl.ops.stack import Stack
from tanklab import paths
from tanklab.enums import SupervisorMode


async def _try_connect(client: TierClient) -> TierClient | UnreachableError:
    try:
        return await client.connect()
    except UnreachableError as e:
        return e


_GAIN_HINTS = {
    "BadUserAccessDenied": "your role may not do this",
    "BadOutOfRange": "a gain is not finite or lies outside the loop's gain box",
}
_RESET_HINTS = {
    **_GAIN_HINTS,
    "BadInvalidState": "a mode change of the loop is pending (retry after the next scan), or its "
    "block has no PID gains",
}
_SET_HINTS = {**_GAIN_HINTS, "BadInvalidState": "the loop's block has no PID gains"}


def _change_gains(
    stack: Stack,
    loop: str,
    new: tuple[float | None, float | None, float | None],
    reset: bool,
    release: bool,
) -> None:
    """``tankctl gains LOOP --kp/--ki/--kd | --reset | --release``: one call, one line."""
    if sum((reset, release, any(g is not None for g in new))) > 1:
        raise fail("give one of --kp/--ki/--kd, --reset and --release", 2)
    for label, g in zip(("--kp", "--ki", "--kd"), new, strict=True):
        if g is not None and not math.isfinite(g):
            raise fail(f"{label} must be a finite number, got {g}", 2)

    async def main() -> int:
        await stack.resolve("plc")
        name = stack.loop(loop)
        tags = stack.tags("plc")
        p = paths.plc.loop(name)
        async with stack.client("plc") as plc:
            before = await plc.read([*p.gains, p.gain_source])
            source = show(tags[p.gain_source], before[p.gain_source])
            applied = " ".join(
                f"{g} = {sci(before[path])}" for g, path in zip(("Kp", "Ki", "Kd"), p.gains, strict=True)
            )
            if reset:
                await plc.call(p.reset_gains, hints=_RESET_HINTS)
                typer.echo(
                    f"{name}: ResetGains: the configured gains from the next scan on, GainSource FIXED "
                    f"(was {source}: {applied})"
                )
            elif release:
                await plc.call(p.release_gains, hints=_SET_HINTS)
                if source == "ENGINEER":
                    typer.echo(
                        f"{name}: ReleaseGains: back under adaptation, gains kept ({applied}), "
                        "GainSource FIXED until the supervisor pushes"
                    )
                else:
                    typer.echo(
                        f"{name}: ReleaseGains: not held by an engineer (GainSource {source}), no change"
                    )
            else:
                # An omitted gain keeps its applied value: SetGains always sends all three.
                current = (before[p.kp], before[p.ki], before[p.kd])
                kp, ki, kd = (float(c) if g is None else g for g, c in zip(new, current, strict=True))
                await plc.call(p.set_gains, kp, ki, kd, hints=_SET_HINTS)
                typer.echo(
                    f"{name}: SetGains(Kp = {sci(kp)}, Ki = {sci(ki)}, Kd = {sci(kd)}) from the next scan "
                    f"on, GainSource ENGINEER (was {source}); the supervisor is kept off until "
                    f"`tankctl gains {name} --release` or `--reset`"
                )
        return 0

    run(main)


@stack_command
def gains(
    loop: Annotated[str, typer.Argument(help="Loop, e.g. LIC1.")],
    kp: Annotated[
        float | None, typer.Option("--kp", help="Set Kp (SetGains as an engineer: GainSource ENGINEER).")
    ] = None,
    ki: Annotated[
        float | None, typer.Option("--ki", help="Set Ki [per s] (omitted: the applied Ki).")
    ] = None,
    kd: Annotated[float | None, typer.Option("--kd", help="Set Kd [s] (omitted: the applied Kd).")] = None,
    reset: Annotated[
        bool, typer.Option("--reset", help="ResetGains: the configured (FIXED) gains at the next scan.")
    ] = False,
    release: Annotated[
        bool, typer.Option("--release", help="ReleaseGains: hand an ENGINEER loop back to adaptation.")
    ] = False,
    as_json: JsonOpt = False,
    *,
    options: StackOptions,
) -> None:
    """A loop's applied Kp, Ki, Kd and GainSource, and the supervisor's RLS state for it; with
    --kp/--ki/--kd, --reset or --release, change them (one call, one line)."""
    stack = options.stack()
    if reset or release or kp is not None or ki is not None or kd is not None:
        _change_gains(stack, loop, (kp, ki, kd), reset, release)
        return

    async def main() -> int:
        await stack.resolve("plc")
        name = stack.loop(loop)
        p = paths.plc.loop(name)
        plc_paths = [*p.gains, p.gain_source, p.block, p.mode]
        s = paths.supervisor.rls(name)
        sup_paths = [
            paths.supervisor.mode,
            s.theta,
            s.covariance_trace,
            s.accepted,
            s.rejected,
            s.last_reason,
        ]
        async with stack.client("plc") as plc:
            pv = await plc.read(plc_paths)
        sup_json: dict[str, Any] | None = None
        if stack.has("supervisor"):
            sup = await _try_connect(stack.client("supervisor"))
            if isinstance(sup, UnreachableError):
                sup_json = {"reachable": False, "url": sup.url, "error": sup.reason}
            else:
                try:
                    sv = await sup.read(sup_paths)
                finally:
                    await sup.close()
                sup_json = {
                    "reachable": True,
                    "url": sup.url,
                    "mode": enum_name(SupervisorMode, sv[paths.supervisor.mode]),
                    "theta": plain(sv[s.theta]),
                    "covariance_trace": plain(sv[s.covariance_trace]),
                    "accepted": sv[s.accepted],
                    "rejected": sv[s.rejected],
                    "last_reason": sv[s.last_reason],
                }
        tags = stack.tags("plc")
        out = {
            "loop": name,
            "url": stack.urls["plc"],
            "block": pv[p.block],
            "mode": show(tags[p.mode], pv[p.mode]),
            "kp": plain(pv[p.kp]),
            "ki": plain(pv[p.ki]),
            "kd": plain(pv[p.kd]),
            "gain_source": show(tags[p.gain_source], pv[p.gain_source]),
            "supervisor": sup_json,
        }
        if as_json:
            typer.echo(json.dumps(out, indent=2))
            return 0
        typer.echo(
            f"{name} ({out['block']}, {out['mode']}): Kp = {sci(out['kp'])}  Ki = {sci(out['ki'])}"
            f"  Kd = {sci(out['kd'])}  from {out['gain_source']}"
        )
        if sup_json is None:
            typer.echo("supervisor: not in this site")
        elif not sup_json["reachable"]:
            typer.echo(f"supervisor: unreachable at {sup_json['url']}: {sup_json['error']}")
        else:
            theta = sup_json["theta"] or []
            shown = "[" + ", ".join(sci(v) for v in theta) + "]" if theta else "[] (not estimated yet)"
            reason = sup_json["last_reason"] or "-"
            typer.echo(
                f"supervisor ({sup_json['mode']}): RLS theta {shown}, covariance trace "
                f"{num(sup_json['covariance_trace'])}, accepted {sup_json['accepted']}, "
                f"rejected {sup_json['rejected']}, last reason: {reason}"
            )
        return 0

    run(main)
