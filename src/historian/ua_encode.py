"""A fast OPC UA binary encoder for the one structure a large history read returns: HistoryData.

asyncua encodes a ``ua.HistoryData`` of 86,400 DataValues field by field through its generic
dataclass codec (and the service would first build 86,400 ``DataValue``/``Variant``/
``StatusCode`` objects); this module packs the samples straight into the body of the
ExtensionObject (``i=658``, HistoryData_Encoding_DefaultBinary) that asyncua then sends as is.
Layout (OPC UA Part 6, 5.2.2.17 DataValue, 5.2.2.16 Variant)::

    HistoryData  = Int32 n, DataValue * n
    DataValue    = Byte mask (0x01 Value, 0x02 StatusCode if not Good, 0x04 SourceTimestamp),
                   Variant, [UInt32 status], Int64 source ticks (100 ns since 1601)
    Variant      = Byte type (0 null, 1 Boolean, 6 Int32, 8 Int64, 11 Double, 12 String), value

Values map as :func:`historian.history_read._variant` does (float Double, bool Boolean, int Int32
when it fits else Int64, str String, None null); tests check the bytes decode, with asyncua's own
decoder, to exactly the DataValues the object path gives.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

from asyncua import ua

from tanklab.history.model import EPOCH_OFFSET_TICKS, Sample

__all__ = ["HISTORY_DATA_BINARY", "datavalue_bytes", "history_data_extension_object", "pack_history_data"]

HISTORY_DATA_BINARY = ua.NodeId(ua.ObjectIds.HistoryData_Encoding_DefaultBinary)

_DOUBLE_GOOD = struct.Struct("<BBdq")  # mask, variant type, value, ticks
_DOUBLE_STATUS = struct.Struct("<BBdIq")
_MASK = 0x01 | 0x04
_MASK_STATUS = 0x01 | 0x02 | 0x04
_TICKS = struct.Struct("<q")
_STATUS = struct.Struct("<I")
_INT32 = struct.Struct("<i")


def _variant(value: object) -> bytes:
    if value is None:
        return b"\x00"
    if isinstance(value, bool):
        return b"\x01\x01" if value else b"\x01\x00"
    if isinstance(value, float):
        return b"\x0b" + struct.pack("<d", value)
    if isinstance(value, int):
        if -(2**31) <= value < 2**31:
            return b"\x06" + _INT32.pack(value)
        return b"\x08" + struct.pack("<q", value)
    data = str(value).encode("utf-8")
    return b"\x0c" + _INT32.pack(len(data)) + data


def datavalue_bytes(sample: Sample) -> int:
    """The encoded size of ``sample``'s DataValue in :func:`pack_history_data` [bytes]."""
    _, value, status = sample
    variant = 9 if type(value) is float else len(_variant(value))
    return 1 + variant + (4 if status else 0) + 8


def pack_history_data(samples: Sequence[Sample]) -> bytes:
    """The binary body of a HistoryData holding ``samples`` (source timestamps only)."""
    out = [_INT32.pack(len(samples))]
    append = out.append
    good, bad = _DOUBLE_GOOD.pack, _DOUBLE_STATUS.pack
    for t_us, value, status in samples:
        ticks = t_us * 10 + EPOCH_OFFSET_TICKS
        if type(value) is float:
            if status == 0:
                append(good(_MASK, 11, value, ticks))
            else:
                append(bad(_MASK_STATUS, 11, value, status, ticks))
        elif status == 0:
            append(bytes((_MASK,)) + _variant(value) + _TICKS.pack(ticks))
        else:
            append(bytes((_MASK_STATUS,)) + _variant(value) + _STATUS.pack(status) + _TICKS.pack(ticks))
    return b"".join(out)


def history_data_extension_object(samples: Sequence[Sample]) -> ua.ExtensionObject:
    """A HistoryData as an ExtensionObject asyncua encodes by copying its body."""
    return ua.ExtensionObject(TypeId=HISTORY_DATA_BINARY, Body=pack_history_data(samples))
