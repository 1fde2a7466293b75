"""Which keyframe pairs the monitor measures: the partner budget of the map pairs, and the
pairs of the local window (temporal neighbours) that the local scales are fitted on.

Invariants of a PartnerBudget: a keyframe is budgeted, or not, once and for all when it
arrives (until the budget is rebuilt); the pairs it keeps with earlier keyframes are chosen
then, so that moves measure the same pairs again; a keyframe that is not budgeted keeps every
pair with earlier keyframes.
"""
from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np

from map_consistency_ros.core.geometry import with_rows
from map_consistency_ros.core.live._pair_cache import pair_keys

# Partners of a new keyframe further apart than this many slots belong to different visits of
# its place (a pass through a place gives consecutive overlapping keyframes; a few may miss it).
_VISIT_GAP = 5


class PartnerBudget:
    """At most about `max_partners` earlier partners per new keyframe (0: all), shared among
    the earlier visits of its place, the nearest of each visit."""

    def __init__(self, max_partners: int) -> None:
        self.max_partners = max_partners
        # per slot: whether its pairs with earlier slots were thinned to the budget on arrival
        self._budgeted = np.zeros(16, dtype=bool)
        # the partners a budgeted slot j keeps: _partners[_start[j]:_end[j]], sorted, appended
        # when j arrives (a keyframe's arrival costs its own partners, not a copy of the map's)
        self._start = np.zeros(16, dtype=np.int64)
        self._end = np.zeros(16, dtype=np.int64)
        self._partners = np.zeros(64, dtype=np.int64)
        self._size = 0  # of _partners in use

    def select(self, pairs: np.ndarray, new: np.ndarray, slot_count: int,
               laser_poses: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """The pairs the budget keeps.

        Pair (i, j), i < j, is kept when j is not budgeted, or when it is one j kept on
        arrival. A new slot j is budgeted when more than `max_partners` of `pairs` end at it;
        it then keeps the nearest keyframes of each earlier visit of its place
        (_nearest_of_each_visit). Every visit keeps pairs, so the failures of a revisit show
        whatever the budget; the local scales have pairs of their own (local_pair_keys).

        Parameters
        ----------
        pairs: (P, 2) slot pairs (i, j), i < j, touching the changed slots.
        new: the slots that arrived in this update.
        slot_count: the number of keyframes (every slot in `pairs` is below).
        laser_poses: laser_poses(slots) -> (S, 3), the laser poses of keyframe slots.

        Returns
        -------
        (P', 2) the kept rows of `pairs`, in their order.
        """
        if slot_count > self._budgeted.size:
            rows = max(slot_count, 2 * self._budgeted.size)
            self._budgeted = with_rows(self._budgeted, rows, fill=False)
            self._start, self._end = with_rows(self._start, rows), with_rows(self._end, rows)
        budget = self.max_partners
        if budget and new.size and pairs.size:
            later = pairs[:, 1]
            counts = np.bincount(later, minlength=slot_count)
            # once and for all: a slot budgeted before keeps the partners it chose then
            crowded = new[(counts[new] > budget) & ~self._budgeted[new]]
            if crowded.size:
                self._budgeted[crowded] = True
                self._keep(*_nearest_of_each_visit(pairs, crowded, budget, laser_poses))
        budgeted = self._budgeted[pairs[:, 1]]
        if not budgeted.any():
            return pairs
        keep = ~budgeted
        keep[budgeted] = _kept_by_slot(self._partners, self._start, self._end,
                                       np.ascontiguousarray(pairs[budgeted, 0], dtype=np.int64),
                                       np.ascontiguousarray(pairs[budgeted, 1], dtype=np.int64))
        return pairs[keep]

    def _keep(self, partner: np.ndarray, slot: np.ndarray) -> None:
        """Append the partners that slots budgeted now keep (rows ordered by slot, then
        partner; no slot had partners kept before)."""
        slots, counts = np.unique(slot, return_counts=True)
        size = self._size + partner.size
        if size > self._partners.size:
            self._partners = with_rows(self._partners, max(size, 2 * self._partners.size))
        self._partners[self._size:size] = partner
        ends = self._size + np.cumsum(counts)
        self._start[slots], self._end[slots] = ends - counts, ends
        self._size = size


def _nearest_of_each_visit(pairs: np.ndarray, slots: np.ndarray, budget: int,
                           laser_poses: Callable[[np.ndarray], np.ndarray]
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(partner, slot) of each of `slots` with the nearest of its earlier partners in `pairs`
    in each visit, ordered by slot, then partner: runs of partners at most _VISIT_GAP slots
    apart (one pass through the place) share the budget evenly, at least one pair each (ties
    in distance: the earlier partner).

    All the slots at once, compiled: a burst of keyframes in a place visited often is when the
    budget bites, and a pass of numpy calls per slot cost as much as measuring the kept pairs.
    """
    slots = np.unique(slots)
    partner, slot = _partners_by_slot(np.ascontiguousarray(pairs, dtype=np.int64), slots)
    here = laser_poses(partner)
    there = laser_poses(slots)[np.searchsorted(slots, slot)]
    distance = np.hypot(*(here[:, :2] - there[:, :2]).T)
    chosen = _nearest_in_visits(partner, slot, distance, budget, _VISIT_GAP)
    return partner[chosen], slot[chosen]


@numba.njit(cache=True)
def _kept_by_slot(partners: np.ndarray, start: np.ndarray, end: np.ndarray, first: np.ndarray,
                  second: np.ndarray) -> np.ndarray:
    """Whether each pair (first, second) is one that slot `second` kept: `first` among
    partners[start[second]:end[second]] (sorted; a binary search)."""
    found = np.zeros(first.size, dtype=np.bool_)
    for row in range(first.size):
        low, high = start[second[row]], end[second[row]]
        where = low + np.searchsorted(partners[low:high], first[row])
        found[row] = where < high and partners[where] == first[row]
    return found


@numba.njit(cache=True)
def _partners_by_slot(pairs: np.ndarray, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(partner, slot) of the pairs (partner, slot) of `pairs` that end at one of `slots`
    (sorted), once each, ordered by slot, then partner."""
    keys = np.empty(pairs.shape[0], dtype=np.int64)
    count = 0
    for row in range(pairs.shape[0]):
        later = pairs[row, 1]
        where = np.searchsorted(slots, later)
        if where < slots.size and slots[where] == later:
            keys[count] = (later << 31) | pairs[row, 0]
            count += 1
    keys = np.unique(keys[:count])
    return keys & ((1 << 31) - 1), keys >> 31


@numba.njit(cache=True)
def _nearest_in_visits(partner: np.ndarray, slot: np.ndarray, distance: np.ndarray,
                       budget: int, gap: int) -> np.ndarray:
    """Which rows (ordered by slot, then partner) are among the max(budget // visits, 1)
    nearest of their visit: a run of a slot's partners at most `gap` apart."""
    rows = slot.size
    chosen = np.zeros(rows, dtype=np.bool_)
    start = 0
    while start < rows:
        end = start + 1
        visits = 1
        while end < rows and slot[end] == slot[start]:
            visits += partner[end] - partner[end - 1] > gap
            end += 1
        quota = max(budget // visits, 1)
        first = start
        for row in range(start + 1, end + 1):
            if row == end or partner[row] - partner[row - 1] > gap:
                nearest = np.argsort(distance[first:row], kind='mergesort')  # stable
                for rank in range(min(quota, row - first)):
                    chosen[first + nearest[rank]] = True
                first = row
        start = end
    return chosen


def local_pair_keys(order: np.ndarray, new_ranks: np.ndarray, reach: int
                    ) -> tuple[np.ndarray, bool]:
    """The pairs of the local window: each keyframe with its `reach` predecessors in stamp
    order.

    Parameters
    ----------
    order: (N,) slots in stamp order.
    new_ranks: the stamp-order ranks of the keyframes that arrived in this update.
    reach: the predecessors of a keyframe it is paired with.

    Returns
    -------
    The sorted unique keys of the window pairs that may be missing, and whether the new
    keyframes were all appended at the end: then only their pairs are returned (the window
    only gained pairs); else every window pair (an insertion reshapes windows).
    """
    count = order.size
    appended = new_ranks.size == 0 or new_ranks.min() >= count - new_ranks.size
    ranks = np.arange(count - new_ranks.size if appended else 0, count)
    second = np.repeat(ranks, reach)
    first = second - np.tile(np.arange(1, reach + 1), ranks.size)
    inside = first >= 0
    return np.unique(pair_keys(order[first[inside]], order[second[inside]])), bool(appended)
