"""The PLC program's writable items, applied by path: one dispatch for every transport.

The OPC UA server (:class:`plc_emulator.server.PlcServer`) and the co-simulation's in-process
PLC port (:class:`tankctl.cosim.ProgramPort`) both apply a client's write of a contract path
through :func:`apply_write`, so a value reaches the program the same way, with the same checks,
whichever way it travelled. The contract's own checks (type, finiteness, EURange, enumeration)
run before, in :class:`tanklab.ua.WriteGuard` for OPC UA; the program's checks run here.
"""

from __future__ import annotations

from typing import Any

from plc_emulator.program import PlcProgram
from tanklab.enums import LoopMode
from tanklab.tags import HEARTBEAT_PATH


def apply_write(program: PlcProgram, path: str, value: Any) -> bool:
    """Apply a write of ``value`` to the contract path ``path``.

    Returns
    -------
    bool
        True when applied; False when ``path`` is not a writable item of the program.

    Raises
    ------
    ValueError, KeyError
        The program refused the value (out of range, unknown loop): nothing changed.
    """
    if path == HEARTBEAT_PATH:
        program.heartbeat(int(value))
        return True
    parts = path.split(".")
    if len(parts) != 3 or parts[0] != "PLC":
        return False
    loop, item = parts[1], parts[2]
    if item == "SP":
        program.set_sp(loop, float(value))
    elif item == "SPLow":
        program.set_sp_limits(loop, low_m=float(value))
    elif item == "SPHigh":
        program.set_sp_limits(loop, high_m=float(value))
    elif item == "Mode":
        program.set_mode(loop, LoopMode(int(value)))
    elif item == "ManualMV":
        program.set_manual_mv(loop, float(value))
    elif item == "RemoteMV":
        program.set_remote_mv(loop, float(value))
    else:
        return False
    return True
