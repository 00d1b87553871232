"""One handler per writable tag: the table a server attaches its write and call handlers with.

Like caproto's ``pvproperty(put=...)``, each writable node of the contract gets its own
handler, registered against the node's path (:mod:`tanklab.paths`) when the server is built,
instead of one callback that splits the path and dispatches in an ``if``/``elif`` chain. A
:class:`HandlerTable` refuses a second handler for a path, and :func:`check_handlers` refuses a
tier's tables unless every writable variable has a write handler, every method a call handler,
and no handler names anything else, so a tag added to the contract without an implementation
(or an implementation left over from a removed tag) stops the server at start, not at the first
client's write.

This module is pure: it knows paths and tags, not the transport.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from typing import TypeVar

from tanklab.tags import Tag

H = TypeVar("H")


class HandlerTable(Mapping[str, H]):
    """Handlers keyed by node path, at most one per path."""

    def __init__(self) -> None:
        self._by_path: dict[str, H] = {}

    def on(self, path: str, handler: H) -> None:
        """Attach ``handler`` to the node ``path``.

        Raises
        ------
        ValueError
            ``path`` has a handler already.
        """
        if path in self._by_path:
            raise ValueError(f"a second handler for {path}")
        self._by_path[path] = handler

    def __getitem__(self, path: str) -> H:
        return self._by_path[path]

    def __iter__(self) -> Iterator[str]:
        return iter(self._by_path)

    def __len__(self) -> int:
        return len(self._by_path)


def writable_variables(tags: Iterable[Tag]) -> set[str]:
    """Paths of the variables some role may write."""
    return {t.path for t in tags if t.kind == "variable" and t.writable}


def methods_of(tags: Iterable[Tag]) -> set[str]:
    """Paths of the methods."""
    return {t.path for t in tags if t.kind == "method"}


def check_handlers(tags: Iterable[Tag], writes: Mapping[str, object], calls: Mapping[str, object]) -> None:
    """Check that ``writes`` covers exactly the writable variables of ``tags`` and ``calls``
    exactly its methods.

    Raises
    ------
    ValueError
        Naming the paths without a handler and the handlers without a writable node.
    """
    tags = list(tags)
    problems = []
    for what, expected, given in (
        ("write", writable_variables(tags), set(writes)),
        ("method", methods_of(tags), set(calls)),
    ):
        if missing := sorted(expected - given):
            problems.append(f"no {what} handler for {', '.join(missing)}")
        if extra := sorted(given - expected):
            problems.append(
                f"{what} handlers for nodes the contract does not make writable: {', '.join(extra)}"
            )
    if problems:
        raise ValueError("; ".join(problems))
