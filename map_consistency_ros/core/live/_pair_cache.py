"""Cached pair measures of keyframe slot pairs, so that an update measures only the pairs its
new and moved keyframes touch.

Pairs are named by keys that pack the two slots (low, high) into one int64, so that pair sets
compare with np.isin / np.unique. Invariants of a PairCache:
- an entry is never written once stored: inserts go past the end, and dropping entries or
  growing builds new arrays; so views of the first `size` entries stay valid for as long as
  anyone holds them, and a snapshot shares them instead of copying a million pairs;
- `generation` changes exactly when entries are dropped: between two drops entries are only
  appended, in insertion order;
- every pair of slot s lies at or after entry `first_rows(...)[s]`.
"""
from __future__ import annotations

import numpy as np

# robust_sums: the cache trims each pair once, as evaluate_pairs would on every update
from map_consistency_ros.core.consistency import robust_sums
from map_consistency_ros.core.geometry import PairMeasures, read_only, with_rows

_SLOT_BITS = 31


def pair_keys(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The keys of pairs of slots.

    Parameters
    ----------
    first, second: (P,) the slots of each pair, in either order (each below 2^31).

    Returns
    -------
    (P,) int64 keys: low << 31 | high of each pair.
    """
    low, high = np.minimum(first, second), np.maximum(first, second)
    return (low.astype(np.int64) << _SLOT_BITS) | high.astype(np.int64)


def key_slots(keys: np.ndarray) -> np.ndarray:
    """The slots of pair keys (the inverse of `pair_keys`).

    Parameters
    ----------
    keys: (P,) int64 pair keys.

    Returns
    -------
    (P, 2) int64 the slots (low, high) of each pair.
    """
    return np.stack([keys >> _SLOT_BITS, keys & ((1 << _SLOT_BITS) - 1)], axis=1)


class PairCache:
    """Pair measures of slot pairs (low, high) in growable arrays, insertion order, with each
    pair's trimmed (M_ij, n_ij) of the test, computed once when the pair is inserted."""

    def __init__(self, keep_largest: int, trim: int) -> None:
        self.size = 0
        self.generation = 0  # counts drops: between two drops entries are only appended
        # per slot, the first entry that can hold one of its pairs: the size when the slot's
        # pairs were first inserted (its later partners come later), 0 after a drop
        self._first_rows = np.zeros(0, dtype=np.int64)
        self._trim = trim
        self._pairs = np.zeros((64, 2), dtype=np.int64)
        self._distance_sum = np.zeros(64)
        self._point_count = np.zeros(64, dtype=np.int64)
        self._largest = np.zeros((64, keep_largest))
        self._trimmed_sum = np.zeros(64)
        self._trimmed_count = np.zeros(64, dtype=np.int64)

    @property
    def pairs(self) -> np.ndarray:
        """(size, 2) the slots (low, high) of the cached pairs."""
        return self._pairs[:self.size]

    @property
    def keys(self) -> np.ndarray:
        """(size,) the keys of the cached pairs."""
        return pair_keys(self.pairs[:, 0], self.pairs[:, 1])

    def _arrays(self) -> tuple[np.ndarray, ...]:
        return (self._pairs, self._distance_sum, self._point_count, self._largest,
                self._trimmed_sum, self._trimmed_count)

    def _keep(self, keep: np.ndarray) -> None:
        kept = int(np.count_nonzero(keep))
        self.generation += 1
        self._first_rows[:] = 0  # entries moved down
        (self._pairs, self._distance_sum, self._point_count, self._largest,
         self._trimmed_sum, self._trimmed_count) = (
            with_rows(array[:self.size][keep], array.shape[0]) for array in self._arrays())
        self.size = kept

    def retain(self, keys: np.ndarray) -> None:
        """Drop every entry whose key is not in `keys` (a drop: `generation` changes).

        Parameters
        ----------
        keys: the keys of the pairs to keep (any order; keys not cached are ignored).
        """
        self._keep(np.isin(self.keys, keys))

    def drop_slots(self, slots: np.ndarray, slot_count: int) -> None:
        """Drop every pair that involves one of some slots.

        Parameters
        ----------
        slots: int slots whose pairs go (empty: nothing happens).
        slot_count: a bound above every slot of `slots` and of the cached pairs.
        """
        if slots.size == 0:
            return
        hit = np.zeros(slot_count, dtype=bool)
        hit[slots] = True
        involved = hit[self.pairs[:, 0]] | hit[self.pairs[:, 1]]
        if involved.any():
            self._keep(~involved)

    def first_rows(self, slot_count: int) -> np.ndarray:
        """Where the pairs of each slot can begin.

        Parameters
        ----------
        slot_count: N, the slots asked for.

        Returns
        -------
        (N,) int64: no pair of slot s lies before entry first_rows[s] (0 when unknown).
        """
        rows = np.zeros(slot_count, dtype=np.int64)
        known = min(slot_count, self._first_rows.size)
        rows[:known] = self._first_rows[:known]
        return rows

    def mark_new(self, slots: np.ndarray) -> None:
        """Note slots that have no pair yet: theirs are all inserted from now on.

        Parameters
        ----------
        slots: int slots of new keyframes.
        """
        if slots.size and slots.max() >= self._first_rows.size:
            self._first_rows = with_rows(self._first_rows,
                                         max(int(slots.max()) + 1, 2 * self._first_rows.size))
        self._first_rows[slots] = self.size

    def insert(self, keys: np.ndarray, measures: PairMeasures) -> None:
        """Append pairs with their measures; their trimmed sums are computed here.

        Parameters
        ----------
        keys: (P,) keys of pairs none of which is cached.
        measures: the P pairs' measures, in the order of `keys`.
        """
        end = self.size + keys.size
        if end > self._pairs.shape[0]:
            capacity = max(2 * self._pairs.shape[0], end)
            (self._pairs, self._distance_sum, self._point_count, self._largest,
             self._trimmed_sum, self._trimmed_count) = (
                with_rows(array[:self.size], capacity) for array in self._arrays())
        self._pairs[self.size:end] = key_slots(keys)
        self._distance_sum[self.size:end] = measures.distance_sum
        self._point_count[self.size:end] = measures.point_count
        self._largest[self.size:end] = measures.largest
        self._trimmed_sum[self.size:end], self._trimmed_count[self.size:end] = robust_sums(
            measures, self._trim)
        self.size = end

    def measures(self, rank_of_slot: np.ndarray | None) -> PairMeasures:
        """The cached pairs as PairMeasures over scan indices.

        Parameters
        ----------
        rank_of_slot: the scan index of each slot (rank_of_slot[slot]); None means the scan
            indices are the slots.

        Returns
        -------
        PairMeasures of the `size` entries in insertion order, each pair (i, j) with i < j;
        read-only views (see the module).
        """
        if rank_of_slot is None:
            pairs = self.pairs
        else:  # each row (i, j) with i < j; sorting rows of two is many times slower
            first, second = rank_of_slot[self.pairs[:, 0]], rank_of_slot[self.pairs[:, 1]]
            pairs = np.stack([np.minimum(first, second), np.maximum(first, second)], axis=1)
        return PairMeasures(pairs=read_only(pairs),
                            distance_sum=read_only(self._distance_sum[:self.size]),
                            point_count=read_only(self._point_count[:self.size]),
                            largest=read_only(self._largest[:self.size]))

    def robust(self) -> tuple[np.ndarray, np.ndarray]:
        """The trimmed sums of the cached pairs.

        Returns
        -------
        (trimmed M_ij (size,), trimmed n_ij (size,)), read-only, in the order of `measures`.
        """
        return (read_only(self._trimmed_sum[:self.size]),
                read_only(self._trimmed_count[:self.size]))
