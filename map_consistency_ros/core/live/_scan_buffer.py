"""The scans waiting for a trajectory to name their pose, bounded.

Invariants: at most `capacity` scans are held, by stamp; beyond it the oldest stamp is pushed
out and counted, in `passed_over` when the estimate had gone past its stamp without naming it
(the pose source made no keyframe of it), else in `pushed_out` (lost: no pose had reached it
yet); every scan added is held, popped or counted in one of those; `newest` is the newest stamp
ever added (it does not fall when scans leave).
"""
from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from map_consistency_ros.core.live._keyframes import match_stamps


class ScanBuffer:
    """Ranges by stamp until a pose claims them (`pop`), matched within `tolerance` seconds."""

    def __init__(self, capacity: int, tolerance: float) -> None:
        self.capacity = capacity
        self.tolerance = tolerance
        self.pushed_out = 0  # pushed out of the full buffer before any pose reached them
        self.passed_over = 0  # pushed out after the estimate went past them (module docstring)
        self.newest = -math.inf
        self._scans: OrderedDict[float, np.ndarray] = OrderedDict()

    def __len__(self) -> int:
        return len(self._scans)

    def __contains__(self, stamp: float) -> bool:
        return stamp in self._scans

    def add(self, stamp: float, ranges: np.ndarray, reached: float = -math.inf) -> list[float]:
        """Hold one scan; the oldest go when more than `capacity` are held.

        Parameters
        ----------
        stamp: the scan's stamp, seconds, not held yet (ValueError otherwise: the caller
            refuses the scan, so that it is counted once).
        ranges: (K,) its ranges, metres.
        reached: the newest pose stamp of the estimate: a scan pushed out that is older
            (beyond `tolerance`) was passed over, not lost.

        Returns
        -------
        The stamps of the scans pushed out as lost (`pushed_out`), usually none.
        """
        if stamp in self._scans:
            raise ValueError(f'scan at {stamp:.6f} duplicates a buffered scan\'s stamp; ignored')
        self._scans[stamp] = ranges
        self.newest = max(self.newest, stamp)
        lost = []
        while len(self._scans) > self.capacity:
            oldest = min(self._scans)
            self._scans.pop(oldest)
            if oldest < reached - self.tolerance:
                self.passed_over += 1
            else:
                self.pushed_out += 1
                lost.append(oldest)
        return lost

    def peek(self, stamp: float) -> np.ndarray:
        """A held scan, left in the buffer.

        Parameters
        ----------
        stamp: exactly the stamp of a held scan (KeyError otherwise).

        Returns
        -------
        (K,) the scan's ranges.
        """
        return self._scans[stamp]

    def pop(self, stamp: float) -> np.ndarray:
        """Take a scan out of the buffer.

        Parameters
        ----------
        stamp: exactly the stamp of a held scan (KeyError otherwise).

        Returns
        -------
        (K,) the scan's ranges; the scan leaves the buffer.
        """
        return self._scans.pop(stamp)

    def matches(self, stamps: np.ndarray) -> np.ndarray:
        """The held scans that match some stamps (nearest within `tolerance`).

        Parameters
        ----------
        stamps: (Q,) pose stamps, seconds.

        Returns
        -------
        (Q,) for each of `stamps`, the stamp of the held scan matching it, NaN where none.
        """
        held = np.fromiter(self._scans, dtype=np.float64, count=len(self._scans))
        found = match_stamps(stamps, held, self.tolerance)
        return np.where(found >= 0, held[np.maximum(found, 0)] if held.size else np.nan,
                        np.nan)
