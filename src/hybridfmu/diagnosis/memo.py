"""Memos of the selection: design arrays per (effect, setting, maneuvers) within a memory budget, the latest fits.

The forward selection, its exchanges and the refits on each maneuver fit the same effects at the same
settings many times over; a stacked design (``hybridfmu.diagnosis.joint.StackedCache.design``) depends on
nothing else, so it is built once, and a fit the selection has just made is not solved again. Keys hold the
settings' exact values (:func:`setting_key`): two settings that differ in the last bit are two entries, so a
result never depends on which of them was asked for first.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any, Callable, Hashable

import numpy as np

#: Bytes of design arrays a :class:`DesignMemo` keeps (the least recently used go first beyond it).
DEFAULT_DESIGN_BUDGET_BYTES = 512 * 2 ** 20

#: Entries an :class:`LruMemo` keeps.
DEFAULT_LRU_ENTRIES = 256


def setting_key(setting: dict[str, float]) -> tuple:
    """A hashable form of a nonlinear setting: its items sorted by name with their exact float values (no
    rounding: a memo must never hand a design or fit made at one setting to a caller that asked for another)."""
    return tuple(sorted((k, float(v)) for k, v in setting.items()))


class DesignMemo:
    """Arrays by key, the least recently used dropped once they hold more than ``budget_bytes``.

    The arrays it returns are read-only (one array serves every caller)."""

    def __init__(self, budget_bytes: int = DEFAULT_DESIGN_BUDGET_BYTES) -> None:
        self.budget_bytes = int(budget_bytes)
        self._arrays: OrderedDict[Hashable, np.ndarray] = OrderedDict()
        self._bytes = 0

    def get(self, key: Hashable, compute: Callable[[], np.ndarray]) -> np.ndarray:
        """The array of ``key``, from ``compute()`` the first time (or again after it was dropped)."""
        array = self._arrays.get(key)
        if array is not None:
            self._arrays.move_to_end(key)
            return array
        array = np.asarray(compute())
        array.setflags(write=False)
        self._arrays[key] = array
        self._bytes += array.nbytes
        while self._bytes > self.budget_bytes and len(self._arrays) > 1:
            _, dropped = self._arrays.popitem(last=False)
            self._bytes -= dropped.nbytes
        return array


class LruMemo:
    """The latest ``entries`` values by key (the least recently used dropped first)."""

    def __init__(self, entries: int = DEFAULT_LRU_ENTRIES) -> None:
        self.entries = int(entries)
        self._values: OrderedDict[Hashable, Any] = OrderedDict()

    def get(self, key: Hashable) -> Any:
        """The value of ``key``, or None."""
        value = self._values.get(key)
        if value is not None:
            self._values.move_to_end(key)
        return value

    def put(self, key: Hashable, value: Any) -> None:
        """Keep ``value`` for ``key``."""
        self._values[key] = value
        self._values.move_to_end(key)
        while len(self._values) > self.entries:
            self._values.popitem(last=False)
