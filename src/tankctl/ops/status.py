"""``tankctl status``: one Read per tier, shaped into the status document and its tables."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import typer
from rich.console import Group
from rich.table import Table
from rich.text import Text

from tankctl.ops.alarm_summary import summary_json, summary_line
from tankctl.ops.display import num, percent_of, plain, sci, secs, show, stdout_console
from tankctl.ops.errors import UnreachableError
from tankctl.ops.options import JsonOpt, StackOptions, stack_command
from tankctl.ops.run import run
from tankctl.ops.stack import TIERS, Stack
from tanklab import paths
from tanklab.tags import Tier


async def _read_tier(stack: Stack, tier: Tier) -> dict[str, Any] | UnreachableError:
    """Every contract variable of a tier in one Read (the one that checks its identity, unless
    the client was connected already to learn the site), or why the tier did not answer."""
    client = stack.io(tier)
    nodes = [t.path for t in client.tags.values() if t.kind == "variable"]
    try:
        async with client.will_read(nodes):  # with the identity, when not connected yet
            return await client.read(nodes)
    except UnreachableError as e:
        return e


def _plant_json(stack: Stack, v: dict[str, Any]) -> dict[str, Any]:
    site = stack.site
    tags = stack.tags("plant")
    tanks = {}
    for t in site.tank_names:
        tank, lt = paths.plant.tank(t), paths.plant.lt(t)
        tanks[t] = {
            "level_m": plain(v[tank.level]),
            "lt_pv_m": plain(v[lt.pv]),
            "lt_fault": show(tags[lt.fault], v[lt.fault]),
            "lt_fault_value": plain(v[lt.fault_value]),
            "leak": plain(v[tank.leak]),
            "disturbance_m3_s": plain(v[tank.disturbance]),
            "lsh": v[tank.lsh],
            "lsl": v[tank.lsl],
        }
    return {
        "model_time_s": plain(v[paths.plant.sim_time]),
        "speed": plain(v[paths.plant.sim_speed]),
        "watchdog": v[paths.plant.sim_watchdog],
        "tanks": tanks,
        "valves": {n: {"opening": plain(v[paths.plant.valve_opening(n)])} for n in site.valve_names},
        "pumps": {
            p.name: {
                "command": plain(v[paths.plant.pump(p.name).command]),
                "unit": p.unit,
                "flow_m3_s": plain(v[paths.plant.pump(p.name).flow]),
            }
            for p in site.plant.pumps
        },
        "balance_error_m3": plain(v[paths.plant.balance("Error")]),
    }


def _under(prefix: str, variables: list[str], v: dict[str, Any]) -> dict[str, Any]:
    """The values of the variables whose path starts with ``prefix``, keyed by the rest of the
    path (``PLC.Alarms.T1HH`` under ``PLC.Alarms.`` -> ``T1HH``), in the contract's order."""
    return {path.removeprefix(prefix): v[path] for path in variables if path.startswith(prefix)}


def _plc_json(stack: Stack, v: dict[str, Any]) -> dict[str, Any]:
    site = stack.site
    tags = stack.tags("plc")
    loops = {}
    for name in site.loop_names:
        p = paths.plc.loop(name)
        mv_tag = tags[p.mv]
        loops[name] = {
            "block": v[p.block],
            "mode": show(tags[p.mode], v[p.mode]),
            "sp_m": plain(v[p.sp]),
            "pv_m": plain(v[p.pv]),
            "mv": plain(v[p.mv]),
            "mv_unit": mv_tag.unit,
            "mv_percent": plain(percent_of(v[p.mv], mv_tag.eu_range)),
            "manual_mv": plain(v[p.manual_mv]),
            "kp": plain(v[p.kp]),
            "ki": plain(v[p.ki]),
            "kd": plain(v[p.kd]),
            "gain_source": show(tags[p.gain_source], v[p.gain_source]),
        }
    variables = [path for path, tag in tags.items() if tag.kind == "variable"]
    alarms = _under(paths.plc.alarms_prefix, variables, v)
    interlocks = _under(paths.plc.interlocks_prefix, variables, v)
    plc = paths.plc
    return {
        "scan": v[plc.scan],
        "model_time_s": plain(v[plc.model_time]),
        "io_healthy": v[plc.io_healthy],
        "overruns": v[plc.overruns],
        "last_scan_duration_s": plain(v[plc.last_scan_duration]),
        "supervisor_alive": v[plc.supervisor_alive],
        "loops": loops,
        "io": {
            paths.plant.lt(t).name: {"pv_m": plain(v[plc.io(t).pv]), "good": v[plc.io(t).good]}
            for t in site.tank_names
        },
        "alarms": alarms,
        "active_alarms": [k for k, on in alarms.items() if on],
        "interlocks": interlocks,
        "tripped": [k for k, on in interlocks.items() if on],
        "alarm_summary": summary_json("plc", v),
    }


def _supervisor_json(stack: Stack, v: dict[str, Any]) -> dict[str, Any]:
    tags = stack.tags("supervisor")
    sup = paths.supervisor
    return {
        "mode": show(tags[sup.mode], v[sup.mode]),
        "cycle": v[sup.cycle],
        "plc_connected": v[sup.plc_connected],
        "mpc": {
            "status": show(tags[sup.mpc_status], v[sup.mpc_status]),
            "solve_time_s": plain(v[sup.mpc_solve_time]),
            "iterations": v[sup.mpc_iterations],
            "failures": v[sup.mpc_failures],
            "horizon": v[sup.mpc_horizon],
        },
        "fdi": _fdi_json(tags, v),
        "alarm_summary": summary_json("supervisor", v),
    }


def _fdi_json(tags: dict[str, Any], v: dict[str, Any]) -> dict[str, Any]:
    """The fault diagnosis (docs/fdi.md): state, diagnosis and its size, the leading hypothesis."""
    sup = paths.supervisor
    return {
        "state": show(tags[sup.fdi_state], v[sup.fdi_state]),
        "diagnosis": v[sup.fdi_diagnosis],
        "size": plain(v[sup.fdi_size]),
        "size_std": plain(v[sup.fdi_size_std]),
        "confidence": plain(v[sup.fdi_confidence]),
        "best": v[sup.fdi_best],
        "message": v[sup.fdi_message],
    }


def fdi_line(fdi: dict[str, Any]) -> str:
    """One line of the diagnosis: its message when isolated, else the state (and the leader)."""
    if fdi["message"]:
        return f"diagnosis: {fdi['message']}"
    if fdi["best"]:
        return f"diagnosis: {fdi['state']} (leading: {fdi['best']}, not isolated)"
    return f"diagnosis: {fdi['state']}"


async def collect_status(stack: Stack) -> dict[str, Any]:
    """The status document (``status --json``): one Read per tier, the tiers concurrently."""
    tiers = [t for t in TIERS if stack.has(t)]
    results = await asyncio.gather(*(_read_tier(stack, t) for t in tiers))
    shape = {"plant": _plant_json, "plc": _plc_json, "supervisor": _supervisor_json}
    doc: dict[str, Any] = {
        "site": stack.site.name,
        "config_digest": stack.site_identity.digest,
        "plant": None,
        "plc": None,
        "supervisor": None,
    }
    for tier, res in zip(tiers, results, strict=True):
        if isinstance(res, UnreachableError):
            doc[tier] = {"reachable": False, "url": stack.urls[tier], "error": res.reason}
        else:
            doc[tier] = {"reachable": True, "url": stack.urls[tier], **shape[tier](stack, res)}
    return doc


def _tier_state(tier: str, d: dict[str, Any]) -> str:
    if not d["reachable"]:
        return f"UNREACHABLE: {d['error']}"
    if tier == "plant":
        text = f"model time {secs(d['model_time_s'])} s, speed {num(d['speed'])}"
        return text + (", pump watchdog TRIPPED" if d["watchdog"] else "")
    if tier == "plc":
        io = "IO healthy" if d["io_healthy"] else "IO FAULT"
        sup = "supervisor alive" if d["supervisor_alive"] else "no supervisor heartbeat"
        t = secs(d["model_time_s"])
        return f"scan {d['scan']}, model time {t} s, {io}, {sup}, overruns {d['overruns']}"
    mpc = d["mpc"]
    solve = f" {1e3 * mpc['solve_time_s']:.1f} ms" if isinstance(mpc["solve_time_s"], float) else ""
    plc = "PLC connected" if d["plc_connected"] else "PLC NOT connected"
    return f"mode {d['mode']}, cycle {d['cycle']}, MPC {mpc['status']}{solve}, {plc}"


def render_status(stack: Stack, doc: dict[str, Any]) -> Group:
    """The human form of the status document: tiers, tanks, loops, alarms."""
    site = stack.site
    shown = [t for t in TIERS if doc[t] is not None]
    url_width = max(len(doc[t]["url"]) for t in shown)
    title = Text(f"{site.name}", style="bold") + Text(
        f"  config {stack.site_identity.short} (from {stack.origin})"
    )
    title.no_wrap, title.overflow = True, "ignore"  # one line, however narrow the terminal
    lines = [title]
    for tier in shown:
        d = doc[tier]
        state = Text(_tier_state(tier, d), style="" if d["reachable"] else "bold red")
        line = Text(f"{tier:<11}{d['url']:<{url_width}}  ", no_wrap=True, overflow="ignore") + state
        line.no_wrap, line.overflow = True, "ignore"  # one line per tier, however wide
        lines.append(line)
    header = Group(*lines)

    plant = doc["plant"] if doc["plant"] and doc["plant"]["reachable"] else None
    plc = doc["plc"] if doc["plc"] and doc["plc"]["reachable"] else None
    loop_of = {"T" + lp.pv[2:]: lp.name for lp in (site.plc.loops if site.plc else [])}
    tanks = Table(title="tanks", title_justify="left")
    for col in ("tank", "level [m]", "PLC PV [m]", "SP [m]", "loop", "leak", "LT fault", "switches"):
        tanks.add_column(col, justify="left" if col in ("tank", "loop", "LT fault", "switches") else "right")
    for t in site.tank_names:
        pt = plant["tanks"][t] if plant else {}
        lt = f"LT{t[1:]}"
        io = plc["io"][lt] if plc else {}
        pv = num(io.get("pv_m"), "m") + ("" if io.get("good", True) else " BAD")
        loop = loop_of.get(t)
        sp = num(plc["loops"][loop]["sp_m"], "m") if plc and loop else ""
        switches = ", ".join(k.upper() for k in ("lsh", "lsl") if pt.get(k)) or ("-" if pt else "")
        fault = pt.get("lt_fault", "-")
        if fault not in ("NONE", "-"):
            fault = f"{fault} {pt.get('lt_fault_value', 0):g}"
        tanks.add_row(
            t, num(pt.get("level_m"), "m"), pv, sp, loop or "", num(pt.get("leak")), fault, switches
        )

    parts: list[Any] = [header]
    if plant is not None or plc is not None:
        parts += [Text(""), tanks]
    if plc is not None:
        loops = Table(title="loops", title_justify="left")
        for col in ("loop", "block", "mode", "SP [m]", "PV [m]", "MV", "MV %", "Kp", "Ki", "Kd", "gains"):
            loops.add_column(col, justify="left" if col in ("loop", "block", "mode", "gains") else "right")
        for name in site.loop_names:
            d = plc["loops"][name]
            mv = num(d["mv"]) + (f" {d['mv_unit']}" if d["mv_unit"] not in (None, "1") else "")
            pct = d["mv_percent"]
            loops.add_row(
                name,
                d["block"] or "-",
                d["mode"],
                num(d["sp_m"], "m"),
                num(d["pv_m"], "m"),
                mv,
                f"{pct:.1f}" if isinstance(pct, float) else "-",
                sci(d["kp"]),
                sci(d["ki"]),
                sci(d["kd"]),
                d["gain_source"],
            )
        parts += [Text(""), loops]
        alarms = ", ".join(plc["active_alarms"]) or "none"
        trips = ", ".join(plc["tripped"]) or "none"
        parts.append(Text(f"alarms: {alarms}; interlocks tripped: {trips}"))
    elif site.plc is not None:
        parts.append(Text("alarms: unknown (PLC unreachable)"))
    sup_doc = doc["supervisor"]
    if sup_doc is not None and sup_doc["reachable"]:
        fdi = sup_doc["fdi"]
        parts.append(Text(fdi_line(fdi), style="bold red" if fdi["message"] else ""))
    for tier in ("plc", "supervisor"):
        d = doc[tier]
        if d is not None and d["reachable"]:
            s = d["alarm_summary"]
            parts.append(Text(summary_line(tier, s), style="bold red" if s["flood"] else ""))
    return Group(*parts)


def _print_unresolved(stack: Stack, as_json: bool) -> None:
    """status when no tier answered and no site was given: each tier and why, no site."""
    if as_json:
        doc: dict[str, Any] = {"site": None, "config_digest": None}
        for tier in TIERS:
            e = stack.unreached[tier]
            doc[tier] = {"reachable": False, "url": e.url, "error": e.reason}
        typer.echo(json.dumps(doc, indent=2))
        return
    width = max(len(e.url) for e in stack.unreached.values())
    typer.echo("site unknown: no tier answered")
    for tier in TIERS:
        e = stack.unreached[tier]
        typer.echo(f"{tier:<11}{e.url:<{width}}  UNREACHABLE: {e.reason}")


@stack_command
def status(
    as_json: JsonOpt = False,
    *,
    options: StackOptions,
) -> None:
    """Levels, setpoints, MVs, modes, gains, alarms and health of every tier (one Read each).

    Exit 0 when the PLC answers (the plant, for a site without a PLC), even if another tier is
    down (shown as unreachable); exit 2, after printing what did answer, when it does not.
    """
    stack = options.stack()

    async def main() -> int:
        stack.use_relay()  # reads only: the relay's when ``up`` serves one
        try:
            await stack.resolve("plc", "plant")
        except UnreachableError as e:
            _print_unresolved(stack, as_json)
            raise e from None
        doc = await collect_status(stack)
        if as_json:
            typer.echo(json.dumps(doc, indent=2))
        else:
            stdout_console().print(render_status(stack, doc), crop=False)
        key: Tier = "plc" if stack.has("plc") else "plant"
        if not doc[key]["reachable"]:
            typer.echo(f"tankctl: cannot reach {key} at {doc[key]['url']}: {doc[key]['error']}", err=True)
            return 2
        return 0

    run(main)
