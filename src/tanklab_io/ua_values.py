"""Tag values as OPC UA Variants: the one conversion both sides of the contract use.

A tag's value is stored as the Variant of its data type (:data:`VARIANT_TYPES`); a Double array is a
Double Variant with ``is_array``. The client side (:mod:`tanklab_io.ua_client`) writes with it and
the servers (:mod:`tanklab_io.ua`) store with it. Kept apart from the server module so that a
client (an operator command) imports no server code.
"""

from __future__ import annotations

from typing import Any

from asyncua import ua

from tanklab.tags import DataType, Tag

__all__ = ["DATATYPE_IDS", "VARIANT_TYPES", "python_value", "stored_variant", "variant"]

VARIANT_TYPES = {
    DataType.DOUBLE: ua.VariantType.Double,
    DataType.INT32: ua.VariantType.Int32,
    DataType.UINT32: ua.VariantType.UInt32,
    DataType.BOOLEAN: ua.VariantType.Boolean,
    DataType.STRING: ua.VariantType.String,
    DataType.DOUBLE_ARRAY: ua.VariantType.Double,
}
DATATYPE_IDS = {
    DataType.DOUBLE: ua.ObjectIds.Double,
    DataType.INT32: ua.ObjectIds.Int32,
    DataType.UINT32: ua.ObjectIds.UInt32,
    DataType.BOOLEAN: ua.ObjectIds.Boolean,
    DataType.STRING: ua.ObjectIds.String,
    DataType.DOUBLE_ARRAY: ua.ObjectIds.Double,
}


def python_value(data_type: DataType, value: Any) -> Any:
    """``value`` as the Python type a tag of ``data_type`` stores (arrays as lists of float)."""
    if data_type == DataType.DOUBLE_ARRAY:
        return [float(v) for v in value]
    if data_type == DataType.DOUBLE:
        return float(value)
    if data_type in (DataType.INT32, DataType.UINT32):
        return int(value)
    if data_type == DataType.BOOLEAN:
        return bool(value)
    return str(value)


def variant(tag: Tag, value: Any) -> ua.Variant:
    """The Variant a tag's value is stored as (arrays as Double arrays)."""
    if tag.data_type is None:
        raise ValueError(f"{tag.path} is a method, not a variable")
    return stored_variant(tag.data_type, python_value(tag.data_type, value))


def stored_variant(data_type: DataType, value: Any) -> ua.Variant:
    """The Variant of a value already of its Python type (:func:`python_value`)."""
    return ua.Variant(value, VARIANT_TYPES[data_type], is_array=data_type == DataType.DOUBLE_ARRAY)
