"""The monitor's keyframe store: per-keyframe stamps, poses and scans, the stamps of the scans
folded into an earlier viewpoint, and the matching of stamps to keyframes.

Invariants:
- a keyframe is identified by its slot, its registration index: slots are 0..count-1, never
  reused or renumbered;
- a slot's stamp and ranges never change once appended (views of them stay valid); its pose
  changes when the trajectory moves it, its incremental pose never;
- `order()` holds the slots in stamp order (stable for equal stamps) at every moment;
- the folded stamps are sorted and are no keyframe's;
- `version` counts the stamps ever added (keyframes and folded scans): `added_since(v)` holds
  every stamp a result computed at version v has not seen.
"""
from __future__ import annotations

import numba
import numpy as np

from map_consistency_ros.core.geometry import read_only, spans, with_rows

# A trajectory pose's slot: its keyframe's, or one of these.
NO_SCAN = -1  # no scan registered for it (yet)
FOLDED = -2  # its scan was folded into the previous viewpoint (core/geometry/_viewpoints.py)

# Stamps are seconds since an epoch (1.7e9 on ROS time, where a float's step is 2.4e-7 s):
# the slack covers the rounding of the differences that the reach of refresh_slots adds up.
_STAMP_SLACK = 1e-5


def match_stamps(queries: np.ndarray, stamps: np.ndarray, tolerance: float,
                 order: np.ndarray | None = None) -> np.ndarray:
    """The stamp nearest to each query within a tolerance.

    Parameters
    ----------
    queries: (Q,) seconds.
    stamps: (S,) seconds, in any order.
    tolerance: the largest |query - stamp| of a match, seconds.
    order: the stamps' stable argsort when the caller keeps it (else computed).

    Returns
    -------
    (Q,) int64: the index into `stamps` of each query's match, -1 where none.
    """
    if stamps.size == 0 or queries.size == 0:
        return np.full(queries.size, -1, dtype=np.int64)
    order = np.argsort(stamps, kind='stable') if order is None else order
    return _unsorted(match_sorted(queries, stamps[order], tolerance), order)


def match_sorted(queries: np.ndarray, ordered: np.ndarray, tolerance: float) -> np.ndarray:
    """match_stamps on stamps already sorted: no pass over them, a binary search per query.

    Parameters
    ----------
    queries: (Q,) seconds.
    ordered: (S,) seconds, sorted.
    tolerance: the largest |query - stamp| of a match, seconds.

    Returns
    -------
    (Q,) int64: the index into `ordered` of each query's nearest stamp (the first of equally
    near ones) when it is within `tolerance`, -1 where none.
    """
    # compiled: every scan asks (Keyframes.holds), and a dozen numpy calls on one stamp cost
    # more than the search
    return _match_sorted(np.ascontiguousarray(queries, dtype=np.float64),
                         np.ascontiguousarray(ordered, dtype=np.float64), float(tolerance))


@numba.njit(cache=True)
def _match_sorted(queries: np.ndarray, ordered: np.ndarray, tolerance: float) -> np.ndarray:
    """match_sorted's search: per query, the nearer of the stamps on either side of where it
    would be inserted (the right one on a tie), if within `tolerance`."""
    found = np.full(queries.size, -1, dtype=np.int64)
    last = ordered.size - 1
    if last < 0:
        return found
    for row in range(queries.size):
        query = queries[row]
        if not np.isfinite(query):
            continue  # nowhere near any stamp
        right = min(np.searchsorted(ordered, query), last)
        left = max(right - 1, 0)
        nearer = left if abs(ordered[left] - query) < abs(ordered[right] - query) else right
        if abs(ordered[nearer] - query) <= tolerance:
            found[row] = nearer
    return found


def _unsorted(found: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Indices into sorted stamps (-1: none, kept) as indices into the stamps that `order`
    sorts (in place)."""
    matched = found >= 0
    found[matched] = order[found[matched]]
    return found


def rank_of_slot(order: np.ndarray) -> np.ndarray:
    """The stamp-order rank of every slot.

    Parameters
    ----------
    order: (N,) the slots in stamp order (Keyframes.order).

    Returns
    -------
    (N,) int64: rank[slot] is the slot's position in `order`.
    """
    ranks = np.empty(order.size, dtype=np.int64)
    ranks[order] = np.arange(order.size)
    return ranks


def _claimed_twice(slots: np.ndarray, stamps: np.ndarray, slot_stamps: np.ndarray
                   ) -> np.ndarray:
    """Poses that lose their keyframe slot to a pose nearer its stamp.

    Two poses within the stamp tolerance of one keyframe (scans stamped microseconds apart)
    would both move it, to two places, on every update; the nearest keeps it (the first of
    equals), the others are poses without a keyframe (their own scan is matched or folded).
    """
    matched = np.flatnonzero(slots >= 0)
    losing = np.zeros(slots.size, dtype=bool)
    if matched.size < 2:
        return losing
    offset = np.abs(stamps[matched] - slot_stamps[slots[matched]])
    order = np.lexsort((matched, offset, slots[matched]))  # by slot, nearest first
    repeated = np.zeros(order.size, dtype=bool)
    repeated[1:] = slots[matched[order[1:]]] == slots[matched[order[:-1]]]
    losing[matched[order[repeated]]] = True
    return losing


def _within(stamps: np.ndarray, centres: np.ndarray, reach: float) -> np.ndarray:
    """Indices (sorted, unique) of the sorted `stamps` within `reach` of any of `centres`."""
    low = np.searchsorted(stamps, centres - reach, side='left')
    high = np.searchsorted(stamps, centres + reach, side='right')
    return np.unique(spans(low, high)[0])


class Keyframes:
    """Growable per-keyframe arrays indexed by slot, and the folded scans' stamps.

    The arrays `stamps`, `poses`, `incremental` and `ranges` have at least `count` rows; rows
    from `count` on are spare capacity. A pose matches a keyframe or a folded stamp within
    `tolerance` seconds.
    """

    def __init__(self, beams: int, tolerance: float) -> None:
        self.count = 0
        self.tolerance = tolerance
        self.stamps = np.zeros(16)
        self.poses = np.zeros((16, 3))
        self.incremental = np.zeros((16, 3))
        self.ranges = np.zeros((16, beams))
        # slots in stamp order and their stamps, kept: every scan and every trajectory is
        # matched against them
        self._order = np.zeros(0, dtype=np.int64)
        self._ordered_stamps = np.zeros(0)
        self.folded = np.zeros(0)  # stamps of the scans folded into their previous viewpoint
        self._added: list[float] = []  # every stamp added, keyframe or folded, in that order

    @property
    def beams(self) -> int:
        """K, the beams of every keyframe's scan."""
        return int(self.ranges.shape[1])

    def append(self, stamp: float, pose: np.ndarray, incremental: np.ndarray,
               ranges: np.ndarray) -> int:
        """Register a keyframe.

        Parameters
        ----------
        stamp: the stamp of its scan, seconds.
        pose: (3,) its current pose (x, y, yaw).
        incremental: (3,) its pose on the incremental solution (never changes).
        ranges: (K,) its scan's ranges, metres.

        Returns
        -------
        Its slot (the next one, `count` before the call).
        """
        if self.count == self.stamps.size:
            rows = 2 * self.count
            self.stamps, self.poses, self.incremental, self.ranges = (
                with_rows(array, rows)
                for array in (self.stamps, self.poses, self.incremental, self.ranges))
        slot = self.count
        self.stamps[slot], self.poses[slot], self.incremental[slot] = stamp, pose, incremental
        self.ranges[slot] = ranges
        self.count += 1
        self._added.append(float(stamp))
        if self._order.size == slot and (slot == 0 or stamp >= self.stamps[self._order[-1]]):
            self._order = np.append(self._order, slot)  # the usual case: in stamp order
        else:
            self._order = np.argsort(self.stamps[:self.count], kind='stable')
        self._ordered_stamps = self.stamps[self._order]
        return slot

    def fold(self, stamps: list[float]) -> None:
        """Record the stamps of scans folded into their previous viewpoint.

        Parameters
        ----------
        stamps: the folded scans' stamps, seconds, in any order (empty: nothing to do).
        """
        if stamps:
            # merged into the sorted stamps, not sorted again: a run folds thousands of scans
            # and an update adds a few, so a sort would grow with the run
            added = np.sort(np.asarray(stamps, dtype=np.float64))
            self.folded = np.insert(self.folded, np.searchsorted(self.folded, added), added)
            self._added.extend(float(stamp) for stamp in stamps)

    @property
    def version(self) -> int:
        """How many stamps (keyframes and folded scans) the store has taken so far."""
        return len(self._added)

    def added_since(self, version: int) -> np.ndarray:
        """The stamps taken after `version`.

        Parameters
        ----------
        version: an earlier value of `version`.

        Returns
        -------
        (A,) seconds, keyframes' and folded scans' alike, in the order they were taken.
        """
        return np.array(self._added[version:], dtype=np.float64)

    def order(self) -> np.ndarray:
        """The slots in stamp order.

        Returns
        -------
        (count,) int64 read-only view, stable for equal stamps.
        """
        return read_only(self._order)

    def in_stamp_order(self) -> bool:
        """Whether every keyframe arrived in stamp order.

        Returns
        -------
        True when `order()` is 0..count-1 (then rank == slot).
        """
        return bool(np.array_equal(self._order, np.arange(self.count)))

    def match(self, queries: np.ndarray) -> np.ndarray:
        """The keyframes of some stamps.

        Parameters
        ----------
        queries: (Q,) stamps, seconds.

        Returns
        -------
        (Q,) int64: the slot whose stamp is nearest to each query within the tolerance, -1
        where none.
        """
        return _unsorted(match_sorted(queries, self._ordered_stamps, self.tolerance),
                         self._order)

    def holds(self, stamp: float) -> bool:
        """Whether a stamp is already known.

        Parameters
        ----------
        stamp: a scan's stamp, seconds.

        Returns
        -------
        True when it is a keyframe's or a folded scan's (within the tolerance).
        """
        query = np.array([stamp])
        return bool(self.match(query)[0] >= 0 or self._folded_match(query)[0])

    def trajectory_slots(self, stamps: np.ndarray) -> np.ndarray:
        """The keyframe of every pose of a trajectory.

        Of several poses within the tolerance of one keyframe only the nearest holds its slot
        (_claimed_twice); a pose without a keyframe whose stamp is a folded scan's is FOLDED.

        Parameters
        ----------
        stamps: (M,) the trajectory's pose stamps (sorted), seconds.

        Returns
        -------
        (M,) int64: each pose's keyframe slot, FOLDED or NO_SCAN.
        """
        slots = (np.full(stamps.size, NO_SCAN, dtype=np.int64) if self.count == 0
                 else self.match(stamps))
        if self.count:
            slots[_claimed_twice(slots, stamps, self.stamps)] = NO_SCAN
        if self.folded.size:
            slots[self._folded_match(stamps) & (slots == NO_SCAN)] = FOLDED
        return slots

    def refresh_slots(self, stamps: np.ndarray, slots: np.ndarray,
                      changed: np.ndarray) -> np.ndarray:
        """`trajectory_slots(stamps)` from an earlier result, recomputed only where it can differ.

        A pose's slot depends only on the keyframe and folded stamps within the tolerance of
        its own and on the poses competing for its keyframe (within the tolerance of it): a
        new stamp can change the poses within 3 tolerances of it (one that loses its old
        keyframe to the new one frees that keyframe for a neighbour), and their competitors lie
        within 2 more. Those are recomputed among themselves; every other slot stands.

        Parameters
        ----------
        stamps: (M,) the trajectory's pose stamps, sorted, seconds.
        slots: (M,) int64 `trajectory_slots(stamps)` as it was before the stamps `changed`
            were known (changed poses of the trajectory may hold anything): brought up to date
            in place.
        changed: (C,) seconds: keyframe and folded stamps added since `slots` was computed
            (`added_since`), and the stamps of poses new to the trajectory.

        Returns
        -------
        (M,) int64: `slots`, now equal to `trajectory_slots(stamps)` (a trajectory holds
        every pose of the run: no copy of it).
        """
        if changed.size == 0 or stamps.size == 0:
            return slots
        reach = 3.0 * self.tolerance + _STAMP_SLACK
        affected = _within(stamps, changed, reach)
        if affected.size == 0:
            return slots
        window = _within(stamps, changed, reach + 2.0 * self.tolerance + _STAMP_SLACK)
        local = self.trajectory_slots(stamps[window])
        slots[affected] = local[np.searchsorted(window, affected)]
        return slots

    def _folded_match(self, stamps: np.ndarray) -> np.ndarray:
        return match_sorted(stamps, self.folded, self.tolerance) >= 0
