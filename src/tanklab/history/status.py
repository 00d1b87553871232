"""OPC UA StatusCodes the history reads return, and the aggregates' status rules (pure).

Codes (OPC UA Part 4, 7.39 and Part 11/13): a StatusCode is a uint32; the top two bits are the
severity (``00`` Good, ``01`` Uncertain, ``10`` Bad), bits 16-27 the sub-code, bits 10-11 the
InfoType (``01`` DataValue: the low bits are valid) and, with InfoType DataValue, bits 0-4 are the
**historian bits** (Part 11, 5.3.6 / Part 4 7.39, Table "DataValue InfoBits")::

    bits 0-1  00 Raw, 01 Calculated, 10 Interpolated     HISTORIAN_CALCULATED = 0x0401
    bit  2    Partial (interval shorter than asked)      HISTORIAN_PARTIAL    = 0x0404
    bit  3    ExtraData                                   HISTORIAN_EXTRA_DATA = 0x0408
    bit  4    MultiValue (several raw values qualify)     HISTORIAN_MULTI_VALUE= 0x0410

(the ``0x0400`` in each is the InfoType DataValue flag that makes the low bits meaningful).

**The status of an aggregate (Part 13, 5.4.3.2):** the interval's data is split into Good and Bad
(Uncertain counts as Bad when ``treat_uncertain_as_bad``, still reported Uncertain), by **count**
for the aggregates that count raw values (Average, Count, Minimum, Maximum) and by **duration**
for the time-weighted ones (TimeAverage, Total). With ``bad`` and ``good`` the shares in percent::

    no data                          -> Bad_NoData
    no Bad part                      -> Good
    bad  >= percent_data_bad         -> Bad
    good >= percent_data_good        -> Good
    otherwise                        -> Uncertain_DataSubNormal

With the defaults (100, 100) any Bad part makes the result Uncertain_DataSubNormal and an all-Bad
interval Bad.
"""

from __future__ import annotations

from dataclasses import dataclass

from tanklab.history.model import is_good, is_uncertain

__all__ = [
    "BAD",
    "BAD_AGGREGATE_INVALID_INPUTS",
    "BAD_AGGREGATE_NOT_SUPPORTED",
    "BAD_BOUND_NOT_FOUND",
    "BAD_CONTINUATION_POINT_INVALID",
    "BAD_HISTORY_OPERATION_UNSUPPORTED",
    "BAD_INVALID_ARGUMENT",
    "BAD_INVALID_TIMESTAMP_ARGUMENT",
    "BAD_NODE_ID_UNKNOWN",
    "BAD_NO_DATA",
    "GOOD",
    "GOOD_NO_DATA",
    "HISTORIAN_CALCULATED",
    "HISTORIAN_INTERPOLATED",
    "HISTORIAN_MULTI_VALUE",
    "HISTORIAN_PARTIAL",
    "UNCERTAIN_DATA_SUB_NORMAL",
    "AggregateConfig",
    "counts_as_good",
    "status_from_shares",
    "with_bits",
]

GOOD = 0x0000_0000
GOOD_NO_DATA = 0x00A5_0000
BAD = 0x8000_0000
BAD_NO_DATA = 0x809B_0000
BAD_BOUND_NOT_FOUND = 0x80D7_0000
BAD_INVALID_TIMESTAMP_ARGUMENT = 0x80BD_0000
BAD_NODE_ID_UNKNOWN = 0x8034_0000
BAD_AGGREGATE_NOT_SUPPORTED = 0x80D5_0000
BAD_AGGREGATE_INVALID_INPUTS = 0x80D6_0000
BAD_CONTINUATION_POINT_INVALID = 0x804A_0000
BAD_HISTORY_OPERATION_UNSUPPORTED = 0x8072_0000
BAD_INVALID_ARGUMENT = 0x80AB_0000
UNCERTAIN_DATA_SUB_NORMAL = 0x40A4_0000

_INFO_DATAVALUE = 0x0400
HISTORIAN_CALCULATED = _INFO_DATAVALUE | 0x01
HISTORIAN_INTERPOLATED = _INFO_DATAVALUE | 0x02
HISTORIAN_PARTIAL = _INFO_DATAVALUE | 0x04
HISTORIAN_MULTI_VALUE = _INFO_DATAVALUE | 0x10


@dataclass(frozen=True)
class AggregateConfig:
    """Part 13's AggregateConfiguration (4.2.1.2) with its defaults, and the variable's Stepped.

    ``percent_data_bad`` / ``percent_data_good`` are percentages 0..100; ``stepped`` is the
    HistoricalDataConfiguration's Stepped property (True: a value holds until the next one; False:
    values are joined by straight lines, "sloped").
    """

    treat_uncertain_as_bad: bool = True
    percent_data_bad: int = 100
    percent_data_good: int = 100
    use_sloped_extrapolation: bool = False
    stepped: bool = False

    def __post_init__(self) -> None:
        for name in ("percent_data_bad", "percent_data_good"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 100:
                raise ValueError(f"{name} must be an int in 0..100, got {v!r}")


def with_bits(code: int, bits: int) -> int:
    """``code`` with historian info bits ``bits`` (``HISTORIAN_*``, or-ed) set."""
    return code | bits


def counts_as_good(status: int, config: AggregateConfig) -> bool:
    """Whether a raw value enters a calculation: Good, or Uncertain when it is not treated as
    Bad."""
    if is_good(status):
        return True
    return is_uncertain(status) and not config.treat_uncertain_as_bad


def status_from_shares(good: float, bad: float, config: AggregateConfig) -> int:
    """The aggregate's severity code from the Good and Bad amounts (counts or durations [us]).

    >>> status_from_shares(3, 0, AggregateConfig())
    0
    >>> hex(status_from_shares(3, 1, AggregateConfig()))
    '0x40a40000'
    """
    total = good + bad
    if total <= 0:
        return BAD_NO_DATA
    if bad <= 0:
        return GOOD
    if 100.0 * bad / total >= config.percent_data_bad:
        return BAD
    if 100.0 * good / total >= config.percent_data_good:
        return GOOD
    return UNCERTAIN_DATA_SUB_NORMAL
