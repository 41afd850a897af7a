"""Hand Python objects to Mitsuba plugins through a scene dictionary.

``mi.load_dict`` only passes plain properties to a plugin's constructor, so a plugin that needs
a Python object (a sensor configuration, a per-frame layer state) gets an integer key instead:
the renderer :meth:`~Handoff.put`s the object and writes the key into the dictionary, and the
plugin :meth:`~Handoff.take`s it. Each table also remembers the Mitsuba variants its plugin is
registered for.
"""

from __future__ import annotations

import itertools
from typing import Generic, TypeVar

T = TypeVar("T")


class Handoff(Generic[T]):
    """A process-wide table of objects waiting for the plugin that will own them."""

    def __init__(self) -> None:
        self._items: dict[int, T] = {}
        self._ids = itertools.count(1)
        self.registered: set[str] = set()  # Mitsuba variants the plugin is registered for

    def put(self, item: T) -> int:
        """Store ``item``; returns the key to write into the scene dictionary."""
        key = next(self._ids)
        self._items[key] = item
        return key

    def take(self, key: int) -> T:
        """The item stored under ``key``, removed from the table (the plugin owns it now)."""
        return self._items.pop(int(key))
