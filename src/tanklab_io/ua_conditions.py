"""The alarm conditions' OPC UA projection, under the name the seam's docstring gives it
(``tanklab_io.ua_conditions``); the code is the :mod:`tanklab_io.conditions` package."""

from tanklab_io.conditions import (
    DEFAULT_MAX_TIME_SHELVED_S,
    Handler,
    Retained,
    ToUtc,
    UaConditions,
    match_event_subtypes,
)

__all__ = [
    "DEFAULT_MAX_TIME_SHELVED_S",
    "Handler",
    "Retained",
    "ToUtc",
    "UaConditions",
    "match_event_subtypes",
]
