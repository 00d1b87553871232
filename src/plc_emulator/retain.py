"""The PLC program's retentive memory: what a warm restart keeps, and how it continues.

`retained` gives the data to save (JSON-able), `restore_retained` checks and applies it as if
each value were written now, and `resume_from_plant` puts every loop at the plant's pump command
before the first scan, so the restart moves no pump (``PlcProgram`` calls these; decision 0026
and docs/plc.md describe the warm restart).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from tanklab.enums import GainSource, LoopMode, RemoteSource
from tanklab.gains import LoopGains

if TYPE_CHECKING:
    from plc_emulator.program import PlcProgram

__all__ = ["restore_retained", "resume_from_plant", "retained"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def retained(program: PlcProgram) -> dict[str, Any]:
    """`PlcProgram.retained` (its docstring says what and why)."""
    loops = {}
    for lp in program.loops:
        g = lp.applied
        loops[lp.spec.name] = {
            "sp_m": lp.sp_m,
            "sp_limits_m": list(program.sp_limits(lp.spec.name)),
            "mode": lp.mode.name,
            "remote_source": lp.remote_source.name,
            "gains": [g.kp, g.ki, g.kd] if g is not None else None,
            "source": lp.source.name,
            "manual_mv": lp.manual_mv,
            "mv": lp.mv,
        }
    return {
        "scan": program.scan_count,
        "t_s": program.t_s,
        "loops": loops,
        "tripped": [il.tank_name for il in program.interlocks if il.tripped],
        "alarms": program.alarms.manager.to_retain(),
    }


def restore_retained(program: PlcProgram, data: Mapping[str, Any]) -> list[str]:
    """`PlcProgram.restore_retained` (its docstring says what and why)."""
    skipped: list[str] = []
    if "scan" in data or "t_s" in data:  # absent in files of earlier versions
        try:
            scan, t_s = data["scan"], float(data["t_s"])
            if type(scan) is not int or scan < 0 or not (math.isfinite(t_s) and t_s >= 0.0):
                raise ValueError(f"scan {scan!r} and model time {t_s!r} must be >= 0")
        except (KeyError, ValueError, TypeError) as e:
            skipped.append(f"scan counter and model time: {e}")
        else:
            program.scan_count, program.t_s = scan, t_s
    for name, entry in dict(data.get("loops", {})).items():
        try:
            lp = program.loop(name)
            if "sp_limits_m" in entry:  # absent in files of earlier versions
                lo, hi = (float(x) for x in entry["sp_limits_m"])
                lp.sp_low_m, lp.sp_high_m = lp.spec.sp_min_m, lp.spec.sp_max_m
                if not lo <= lp.sp_m <= hi:
                    program.set_sp(name, min(max(lp.sp_m, lo), hi))
                program.set_sp_limits(name, lo, hi)
            program.set_sp(name, float(entry["sp_m"]))
            gains = entry.get("gains")
            if gains is not None and lp.spec.block == "pid":
                kp, ki, kd = (float(x) for x in gains)
                box = lp.gain_box
                finite = all(math.isfinite(v) for v in (kp, ki, kd))
                if not finite or (box is not None and not box.contains(LoopGains(kp, ki, kd))):
                    raise ValueError("retained gains outside the gain box")
                source = GainSource[str(entry["source"])]
                lp.applied = LoopGains(kp, ki, kd)
                if source is not GainSource.ENGINEER:  # last_accepted: the supervisor's gains
                    lp.last_accepted = lp.applied
                lp.source = source
            # The REMOTE owner before the mode (absent in files of earlier versions: SUPERVISOR).
            lp.remote_source = RemoteSource[str(entry.get("remote_source", "SUPERVISOR"))]
            # Mode before the manual value: entering MANUAL tracks the applied MV.
            program.set_mode(name, LoopMode[str(entry["mode"])])
            lp.mode_changed_scan = -1  # a restored mode is not a change in progress
            program.set_manual_mv(name, float(entry["manual_mv"]))
            if "mv" in entry:  # the start value until the plant's command is read
                mv = float(entry["mv"])
                program._check_mv(lp, mv)
                program._resume_mv(lp, mv, math.nan)
        except (KeyError, ValueError, TypeError) as e:
            skipped.append(f"{name}: {e}")
    program._set_pid_gains()
    tripped = set(data.get("tripped", []))
    for il in program.interlocks:
        il.tripped = il.tank_name in tripped
    if "alarms" in data:  # absent in files of earlier versions
        alarms = data["alarms"]
        if isinstance(alarms, Mapping):
            skipped += program.alarms.manager.from_retain(alarms)
        else:
            skipped.append("alarms: not a mapping")
    return skipped


def resume_from_plant(
    program: PlcProgram, commands: FloatArray, levels_m: FloatArray, good: BoolArray
) -> None:
    """`PlcProgram.resume_from_plant` (its docstring says what and why)."""
    cmd = np.asarray(commands, dtype=float)
    levels = np.asarray(levels_m, dtype=float)
    ok = np.asarray(good, dtype=bool)
    if cmd.shape != (program.n_pumps,) or levels.shape != program._shape or ok.shape != program._shape:
        raise ValueError(
            f"resume needs {program.n_pumps} commands and {program.n_tanks} levels and qualities, got "
            f"shapes {cmd.shape}, {levels.shape} and {ok.shape}"
        )
    for k, x in enumerate(levels.tolist()):
        lo, hi = program._tr_range[k]
        if ok[k] and math.isfinite(x) and lo <= x <= hi:
            program._last_good_m[k] = x
        else:
            levels[k] = math.nan
    for lp in program.loops:
        c = float(cmd[lp.pump])
        mv = min(max(c, lp.mv_min), lp.mv_max) if math.isfinite(c) else lp.mv
        pv = float(levels[lp.tank])
        if math.isfinite(pv):
            lp.pv_last_good_m = pv
        program._resume_mv(lp, mv, pv)
