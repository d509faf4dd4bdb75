"""A keyed least-recently-used memo for what a process builds once and shares (no dependency).

:class:`KeyedLRU` serves ``build_plant``'s plants (``thsa_control.model.plant``) and the closed loops that the
simulators of one plant share (``thsa_control.sim.simulate``).  Each entry holds, beside its value, the
objects whose identity is part of its key (``keep``): they stay alive as long as the entry, so an ``id`` in a
key cannot be reused by another object while the entry exists.

Examples
--------
>>> memo = KeyedLRU(2)
>>> memo.get("a", lambda: 1), memo.get("b", lambda: 2), memo.get("a", lambda: 10)
(1, 2, 1)
>>> memo.get("c", lambda: 3)  # the least recently used entry ("b") is dropped
3
>>> sorted(memo.keys())
['a', 'c']
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

__all__ = ["KeyedLRU"]

V = TypeVar("V")


class KeyedLRU:
    """At most ``size`` values by key, the least recently used dropped first.

    Parameters
    ----------
    size : int
        How many entries are kept (>= 1).
    """

    def __init__(self, size: int):
        if not (isinstance(size, int) and size >= 1):
            raise ValueError(f"KeyedLRU size = {size!r} must be an integer >= 1")
        self.size = size
        self._entries: OrderedDict[Hashable, tuple[Any, Any]] = OrderedDict()

    def get(self, key: Hashable, build: Callable[[], V], keep: Any = ()) -> V:
        """The value under ``key``; if there is none, ``build()``'s, stored with ``keep`` (nothing is stored
        when ``build`` raises)."""
        hit = self._entries.get(key)
        if hit is not None:
            self._entries.move_to_end(key)
            return hit[1]
        value = build()
        self._entries[key] = (keep, value)
        if len(self._entries) > self.size:
            self._entries.popitem(last=False)
        return value

    def keys(self):
        """The keys, least recently used first."""
        return self._entries.keys()

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries
