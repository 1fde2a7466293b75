"""The placed world geometry of keyframes, kept until they move.

An update places only the scans it added or moved instead of every scan it touches. Invariant:
a slot is fresh exactly when its stored rows were placed at the slot's present pose; a caller
invalidates a slot whenever it changes the slot's pose (the ranges of a slot never change).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from map_consistency_ros.core.geometry import SCAN_ARRAYS, ScanSet, SensorModel, with_rows


class Placement:
    """The arrays of a ScanSet (SCAN_ARRAYS) of keyframe slots at one kind of pose."""

    def __init__(self) -> None:
        self._rows: dict[str, np.ndarray] = {}
        self._fresh = np.zeros(0, dtype=bool)
        self._model: SensorModel | None = None

    def invalidate(self, slots: np.ndarray) -> None:
        """Note slots whose pose changed: they are placed again when next asked for.

        Parameters
        ----------
        slots: keyframe slots (slots never placed are ignored).
        """
        slots = np.asarray(slots, dtype=np.int64)
        self._fresh[slots[slots < self._fresh.size]] = False

    def scans(self, slots: np.ndarray, build: Callable[[np.ndarray], ScanSet]) -> ScanSet:
        """The scans of `slots`, in that order.

        Parameters
        ----------
        slots: (S,) keyframe slots.
        build: build(missing) places the scans of the sorted unique slots `missing` that are
            not kept (or no longer fresh); they are kept from then on.

        Returns
        -------
        A ScanSet of the S scans.
        """
        slots = np.asarray(slots, dtype=np.int64)
        known = slots < self._fresh.size
        known[known] = self._fresh[slots[known]]
        missing = np.unique(slots[~known])
        if missing.size:
            self._store(missing, build(missing))
        return ScanSet.from_parts(self._model, **{name: rows[slots]
                                                  for name, rows in self._rows.items()})

    def _store(self, slots: np.ndarray, placed: ScanSet) -> None:
        self._model = placed.model
        needed = int(slots.max()) + 1
        if needed > self._fresh.size:
            capacity = max(needed, 2 * self._fresh.size, 16)
            for name in SCAN_ARRAYS:
                part = getattr(placed, name)
                self._rows[name] = with_rows(self._rows.get(name, part[:0]), capacity)
            self._fresh = with_rows(self._fresh, capacity)
        for name in SCAN_ARRAYS:
            self._rows[name][slots] = getattr(placed, name)
        self._fresh[slots] = True
