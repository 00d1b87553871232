"""The shape of one contract node: :class:`Tag`, its roles, data types and arguments.

A :class:`Tag` is pure data (path, tier, type, unit, EURange, writers, description); the
contract itself, the list of every node of a site, is :mod:`tanklab.tags`, and the path
strings come from :mod:`tanklab.paths`. :class:`TagList` is the small builder the contract
is written with.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum, StrEnum
from typing import Literal

from tanklab.paths import Tier


class Role(StrEnum):
    """Who may do what. Reading is open to every role; writes and calls are listed per tag."""

    OBSERVER = "Observer"
    OPERATOR = "Operator"
    ENGINEER = "Engineer"
    SUPERVISOR = "Supervisor"
    PLC = "PLC"
    EXTERNAL = "External"
    """An external controller's certificate identity (``tankctl user add-external``): writes
    ``RemoteMV`` and ``Mode`` (AUTO <-> REMOTE) of the loops an engineer handed to it
    (``RemoteSource`` EXTERNAL) and ``PLC.External.Heartbeat``; never a password login."""


class DataType(StrEnum):
    """OPC UA built-in types used by the contract."""

    DOUBLE = "Double"
    INT32 = "Int32"
    UINT32 = "UInt32"
    BOOLEAN = "Boolean"
    STRING = "String"
    DOUBLE_ARRAY = "Double[]"


OPERATOR_UP = frozenset({Role.OPERATOR, Role.ENGINEER})
"""Operator-level writes: the operator and the engineer above them."""
ENGINEER_ONLY = frozenset({Role.ENGINEER})
NOBODY: frozenset[Role] = frozenset()


@dataclass(frozen=True)
class Argument:
    """One input or output argument of a method."""

    name: str
    data_type: DataType
    description: str
    unit: str | None = None


@dataclass(frozen=True)
class Tag:
    """One node of the contract.

    Attributes
    ----------
    path
        Dotted path, also the string NodeId (``Plant.T1.Level``).
    tier
        Which server hosts it.
    kind
        ``variable`` or ``method`` (objects are implied by the paths).
    data_type
        Value type of a variable (``None`` for a method).
    unit
        Engineering unit (``m``, ``m^3/s``, ``rpm``, ``s``, ``1``), or ``None``.
    eu_range
        (low, high) of the EURange; writes outside it are refused with BadOutOfRange.
    writers
        Roles that may write the variable or call the method; empty = read-only.
    restricted
        Pairs (role, values): that writer may only move the enumerated value between these
        values (old and new both among them), e.g. the supervisor switches a loop only between
        AUTO and REMOTE.
    description
        What the value means, with its array layout if it is an array.
    enum
        The enumeration of an Int32 enumerated node.
    inputs, outputs
        Method arguments.
    initial
        Value the node is created with.
    """

    path: str
    tier: Tier
    kind: Literal["variable", "method"]
    description: str
    data_type: DataType | None = None
    unit: str | None = None
    eu_range: tuple[float, float] | None = None
    writers: frozenset[Role] = NOBODY
    restricted: tuple[tuple[Role, frozenset[int]], ...] = ()
    enum: type[IntEnum] | None = None
    inputs: tuple[Argument, ...] = ()
    outputs: tuple[Argument, ...] = ()
    initial: float | int | bool | str | list[float] | None = None

    @property
    def name(self) -> str:
        """Browse name: the last path element."""
        return self.path.rsplit(".", 1)[-1]

    @property
    def parent(self) -> str:
        """Path of the object holding this node."""
        return self.path.rsplit(".", 1)[0]

    @property
    def writable(self) -> bool:
        """Whether any role may write (variables) or call (methods) it."""
        return bool(self.writers)

    @property
    def analog(self) -> bool:
        """AnalogItemType: a Double with an engineering unit and a range."""
        return self.data_type == DataType.DOUBLE and self.unit is not None and self.eu_range is not None

    def initial_value(self) -> float | int | bool | str | list[float]:
        """The value the node starts with (a type-appropriate zero unless given)."""
        if self.initial is not None:
            return self.initial
        zeros: dict[DataType, float | int | bool | str | list[float]] = {
            DataType.DOUBLE: 0.0,
            DataType.INT32: 0,
            DataType.UINT32: 0,
            DataType.BOOLEAN: False,
            DataType.STRING: "",
            DataType.DOUBLE_ARRAY: [],
        }
        return zeros[self.data_type or DataType.DOUBLE]


@dataclass
class TagList:
    """The tags of one tier, appended in contract order (:func:`var`, :func:`method`)."""

    tier: Tier
    tags: list[Tag] = field(default_factory=list)

    def var(
        self,
        path: str,
        data_type: DataType,
        description: str,
        *,
        unit: str | None = None,
        eu_range: tuple[float, float] | None = None,
        writers: frozenset[Role] = NOBODY,
        restricted: tuple[tuple[Role, frozenset[int]], ...] = (),
        enum: type[IntEnum] | None = None,
        initial: float | int | bool | str | list[float] | None = None,
    ) -> None:
        self.tags.append(
            Tag(
                path=path,
                tier=self.tier,
                kind="variable",
                description=description,
                data_type=data_type,
                unit=unit,
                eu_range=eu_range,
                writers=writers,
                restricted=restricted,
                enum=enum,
                initial=initial,
            )
        )

    def method(
        self,
        path: str,
        description: str,
        *,
        writers: frozenset[Role],
        inputs: tuple[Argument, ...] = (),
        outputs: tuple[Argument, ...] = (),
    ) -> None:
        self.tags.append(
            Tag(
                path=path,
                tier=self.tier,
                kind="method",
                description=description,
                writers=writers,
                inputs=inputs,
                outputs=outputs,
            )
        )


def enum_name(tag: Tag, value: int) -> str:
    return tag.enum(value).name if tag.enum is not None else str(value)


def enum_range(enum: type[IntEnum]) -> tuple[float, float]:
    values = [int(m) for m in enum]
    return (float(min(values)), float(max(values)))
