"""Which keyframe pairs the monitor measures: the partner budget of the map pairs, and the
pairs of the local window (temporal neighbours) that the local scales are fitted on.

Invariants of a PartnerBudget: a keyframe is budgeted, or not, once and for all when it
arrives (until the budget is rebuilt); the pairs it keeps with earlier keyframes are chosen
then, so that moves measure the same pairs again; a keyframe that is not budgeted keeps every
pair with earlier keyframes.
"""
from __future__ import annotations

from collections.abc import Callable

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
        # pair keys kept by the budget of keyframes that exceeded it (sorted)
        self._kept = np.zeros(0, dtype=np.int64)

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
            self._budgeted = with_rows(self._budgeted, max(slot_count, 2 * self._budgeted.size),
                                       fill=False)
        budget = self.max_partners
        if budget and new.size and pairs.size:
            later = pairs[:, 1]
            counts = np.bincount(later, minlength=slot_count)
            crowded = new[counts[new] > budget]
            if crowded.size:
                kept = [_nearest_of_each_visit(pairs[later == slot, 0], slot, budget,
                                               laser_poses)
                        for slot in crowded]
                self._budgeted[crowded] = True
                self._kept = _sorted_insert(self._kept, np.concatenate(kept))
        budgeted = self._budgeted[pairs[:, 1]]
        if not budgeted.any():
            return pairs
        keep = ~budgeted
        keep[budgeted] = _sorted_contains(self._kept,
                                          pair_keys(pairs[budgeted, 0], pairs[budgeted, 1]))
        return pairs[keep]


def _nearest_of_each_visit(partners: np.ndarray, slot: int, budget: int,
                           laser_poses: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Pair keys of `slot` with the nearest of its earlier `partners` in each visit: runs of
    partners at most _VISIT_GAP slots apart (one pass through the place) share the budget
    evenly, at least one pair each."""
    partners = np.unique(partners)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(partners) > _VISIT_GAP) + 1])
    visit = np.zeros(partners.size, dtype=np.int64)
    visit[starts[1:]] = 1
    visit = np.cumsum(visit)
    quota = max(budget // starts.size, 1)
    laser = laser_poses(np.append(partners, slot))
    distance = np.hypot(*(laser[:-1, :2] - laser[-1, :2]).T)
    order = np.lexsort((distance, visit))  # by visit, nearest first
    rank = np.empty(partners.size, dtype=np.int64)
    rank[order] = np.arange(partners.size) - starts[visit[order]]
    chosen = partners[rank < quota]
    return pair_keys(chosen, np.full(chosen.size, slot))


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


def _sorted_insert(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """`sorted_keys` with the `keys` it lacks, sorted: a merge, so that a keyframe's
    arrival costs its own keys and a copy, not a sort of every key of the map."""
    keys = np.unique(keys)
    keys = keys[~_sorted_contains(sorted_keys, keys)]
    return np.insert(sorted_keys, np.searchsorted(sorted_keys, keys), keys)


def _sorted_contains(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Whether each of `keys` is in `sorted_keys` (binary search: no pass over the map)."""
    where = np.searchsorted(sorted_keys, keys)
    inside = where < sorted_keys.size
    found = np.zeros(keys.shape, dtype=bool)
    found[inside] = sorted_keys[where[inside]] == keys[inside]
    return found
