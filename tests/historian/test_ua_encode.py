"""The fast HistoryData encoder: asyncua's own decoder reads its bytes back as exactly the
DataValues the object path builds (every value type, Good and non-Good statuses)."""

from __future__ import annotations

from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import extensionobject_from_binary, extensionobject_to_binary
from hypothesis import given
from hypothesis import strategies as st

from historian.history_read import _history_data
from historian.ua_encode import datavalue_bytes, history_data_extension_object, pack_history_data
from tanklab.history.model import Sample

_values = st.one_of(
    st.floats(allow_nan=False),
    st.booleans(),
    st.integers(-(2**63), 2**63 - 1),
    st.text(st.characters(codec="utf-8"), max_size=20),
    st.none(),
)
_status = st.sampled_from([0, 0x8000_0000, 0x809B_0000, 0x40A4_0401, 0x0000_0402])


def _decode(samples: list[Sample]) -> object:
    data = extensionobject_to_binary(history_data_extension_object(samples))
    return extensionobject_from_binary(Buffer(data))


def test_one_of_each() -> None:
    xs = [Sample(0, 1.5), Sample(1, 2.5, 0x8000_0000), Sample(2, True), Sample(3, 7, 0x40A4_0401)]
    xs += [Sample(4, 2**40), Sample(5, "héllo"), Sample(6, None, 0x809B_0000)]
    got = _decode(xs)
    assert isinstance(got, ua.HistoryData)
    assert got == _history_data(xs)
    assert got.DataValues[4].Value.VariantType == ua.VariantType.Int64


@given(st.lists(st.tuples(st.integers(0, 2**50), _values, _status), max_size=30))
def test_the_bytes_decode_to_the_object_path(rows: list[tuple[int, object, int]]) -> None:
    xs = [Sample(t, v, s) for t, v, s in rows]  # type: ignore[arg-type]
    assert _decode(xs) == _history_data(xs)


@given(st.tuples(st.integers(0, 2**50), _values, _status))
def test_datavalue_bytes_is_the_encoded_size(row: tuple[int, object, int]) -> None:
    # the HistoryData body is an Int32 count and the DataValues, so one sample's share is the rest
    sample = Sample(*row)  # type: ignore[arg-type]
    assert datavalue_bytes(sample) == len(pack_history_data([sample])) - 4


def test_datavalue_bytes_by_hand() -> None:
    # mask 1 + Variant (type 1 + Double 8) + source ticks 8; + StatusCode 4 when not Good
    assert datavalue_bytes(Sample(0, 1.5)) == 18
    assert datavalue_bytes(Sample(0, 1.5, 0x8000_0000)) == 22
    # a String "héllo": type 1 + Int32 length 4 + 6 UTF-8 bytes
    assert datavalue_bytes(Sample(0, "héllo")) == 1 + 11 + 8
