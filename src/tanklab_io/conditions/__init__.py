"""OPC UA Alarms & Conditions: the projection of the alarm core onto a tier's asyncua server.

:class:`UaConditions` (``projection``) installs the condition nodes, publishes the core's
events and hands client calls to the core; ``fields`` is the node layout and the pure
snapshot-to-values mapping, ``nodes`` builds nodes and notifier chains, ``calls`` checks roles
and arguments, ``oftype`` makes event filters' OfType match subtypes
(docs/decisions/0037-ua-conditions.md).
"""

from tanklab_io.conditions.calls import ALLOWED, INPUTS, check_call, status_code
from tanklab_io.conditions.fields import CHILDREN, ConditionNode, child_id, children_of, snapshot_values
from tanklab_io.conditions.oftype import SubtypeWhereClause, match_event_subtypes
from tanklab_io.conditions.projection import (
    DEFAULT_MAX_TIME_SHELVED_S,
    TYPE_METHODS,
    Handler,
    Retained,
    ToUtc,
    UaConditions,
    initial_snapshot,
)
from tanklab_io.conditions.utc import ModelUtc

__all__ = [
    "ALLOWED",
    "CHILDREN",
    "DEFAULT_MAX_TIME_SHELVED_S",
    "INPUTS",
    "TYPE_METHODS",
    "ConditionNode",
    "Handler",
    "ModelUtc",
    "Retained",
    "SubtypeWhereClause",
    "ToUtc",
    "UaConditions",
    "check_call",
    "child_id",
    "children_of",
    "initial_snapshot",
    "match_event_subtypes",
    "snapshot_values",
    "status_code",
]
