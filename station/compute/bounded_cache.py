"""A small cache of computed arrays keyed by their inputs, oldest entry out when full, safe to
share between threads (a cycle's wheels are measured in threads; `station live` detects the
rims of one update in threads)."""

from __future__ import annotations

import threading
from typing import Callable, Hashable, TypeVar

V = TypeVar("V")


class BoundedCache:
    """``get(key, make)``: the value cached under ``key``, else ``make()``, stored (the oldest
    entry out beyond ``size`` entries). ``make`` runs outside the lock: two threads missing the
    same key both compute it, and the value kept is either (the caller's values are pure)."""

    def __init__(self, size: int):
        self.size = int(size)
        self._items: dict = {}
        self._lock = threading.Lock()

    def get(self, key: Hashable, make: Callable[[], V]) -> V:
        with self._lock:
            hit = self._items.get(key)
        if hit is not None:
            return hit
        value = make()
        with self._lock:
            while len(self._items) >= self.size:
                self._items.pop(next(iter(self._items)))
            self._items[key] = value
        return value

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
