"""The historian's value types: status severities and the OPC UA epoch offset."""

from datetime import UTC, datetime

from tanklab.history.model import EPOCH_OFFSET_TICKS, Sample, is_bad, is_good, is_uncertain


def test_epoch_offset_is_1601_to_1970_in_100ns_ticks() -> None:
    seconds = (datetime(1970, 1, 1, tzinfo=UTC) - datetime(1601, 1, 1, tzinfo=UTC)).total_seconds()
    assert int(seconds) * 10_000_000 == EPOCH_OFFSET_TICKS


def test_severity_is_the_top_two_bits() -> None:
    good, uncertain, bad = (
        0x0000_0000,
        0x408F_0000,
        0x8034_0000,
    )  # Good, Uncertain, BadNodeIdUnknown
    assert (is_good(good), is_uncertain(good), is_bad(good)) == (True, False, False)
    assert (is_good(uncertain), is_uncertain(uncertain), is_bad(uncertain)) == (False, True, False)
    assert (is_good(bad), is_uncertain(bad), is_bad(bad)) == (False, False, True)


def test_a_sample_is_good_by_default() -> None:
    assert Sample(1, 0.5).status == 0
