"""Which scan pairs can overlap: pairs whose polygon extents (axis-aligned boxes) intersect.

Pairs with disjoint extents have disjoint polygons and so a measure of exactly zero; leaving
them out loses nothing. Boxes that merely touch count as overlapping (closed intervals).
"""
from __future__ import annotations

import numba
import numpy as np

from map_consistency_ros.core.geometry._arrays import with_rows


def _checked_extents(extents: np.ndarray) -> np.ndarray:
    extents = np.asarray(extents, dtype=np.float64)
    if extents.ndim != 2 or extents.shape[1] != 4:
        raise ValueError(f'extents must be an (N, 4) array of (xmin, ymin, xmax, ymax), '
                         f'got shape {extents.shape}')
    if not np.all(np.isfinite(extents)):
        raise ValueError('extents must be finite')
    if np.any(extents[:, 2] < extents[:, 0]) or np.any(extents[:, 3] < extents[:, 1]):
        raise ValueError('extents must have xmin <= xmax and ymin <= ymax')
    return extents


def extents_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether boxes overlap, elementwise with broadcasting (closed boxes: touching counts).

    Parameters
    ----------
    a, b: (..., 4) boxes (xmin, ymin, xmax, ymax), broadcastable against each other.

    Returns
    -------
    (...) boolean array, True where the boxes overlap.
    """
    return ((a[..., 0] <= b[..., 2]) & (b[..., 0] <= a[..., 2])
            & (a[..., 1] <= b[..., 3]) & (b[..., 1] <= a[..., 3]))


def _as_pairs(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Unique (i, j) rows with i < j, sorted."""
    low = np.minimum(first, second).astype(np.int64)
    high = np.maximum(first, second).astype(np.int64)
    span = int(high.max(initial=0)) + 1
    keys = np.unique(low * span + high)
    return np.stack([keys // span, keys % span], axis=1)


@numba.njit(cache=True)
def _sweep(extents: np.ndarray, order: np.ndarray, place: bool, slots: np.ndarray,
           pairs: np.ndarray) -> None:
    """Visit each overlapping pair (low, high) once, sweeping the boxes in `order` (by xmin).

    Without `place`, count the pairs of each low index into slots[low + 1]; with it, store the
    pair in row slots[low] of `pairs` and advance that slot.
    """
    for rank in range(order.shape[0]):
        a = order[rank]
        for b in order[rank + 1:]:
            if extents[b, 0] > extents[a, 2]:
                break
            if (extents[a, 1] <= extents[b, 3] and extents[b, 1] <= extents[a, 3]
                    and extents[a, 0] <= extents[b, 2]):
                low, high = min(a, b), max(a, b)
                if place:
                    pairs[slots[low], 0], pairs[slots[low], 1] = low, high
                    slots[low] += 1
                else:
                    slots[low + 1] += 1


# nogil: on a large map the sweep takes milliseconds, and the live second stage runs it on a
# thread of its own while the first stage's updates need the interpreter
@numba.njit(cache=True, nogil=True)
def _sweep_pairs(extents: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Overlapping pairs (i < j), rows sorted: counted, then placed by i, then sorted by j
    within each i (cheaper than a global sort of all pairs)."""
    count = order.shape[0]
    starts = np.zeros(count + 1, dtype=np.int64)
    _sweep(extents, order, False, starts, np.empty((0, 2), dtype=np.int64))
    starts = np.cumsum(starts)
    pairs = np.empty((starts[count], 2), dtype=np.int64)
    _sweep(extents, order, True, starts[:count].copy(), pairs)
    for low in range(count):
        pairs[starts[low]:starts[low + 1], 1].sort()
    return pairs


def candidate_pairs(extents: np.ndarray) -> np.ndarray:
    """All pairs of boxes that overlap.

    Sort and sweep along x: each box meets the boxes that start within its x interval.

    Parameters
    ----------
    extents: (N, 4) finite boxes (xmin, ymin, xmax, ymax) with xmin <= xmax, ymin <= ymax.

    Returns
    -------
    (P, 2) int64 rows (i, j), i < j, sorted. Raises ValueError for malformed extents.
    """
    extents = _checked_extents(extents)
    return _sweep_pairs(extents, np.argsort(extents[:, 0], kind='stable'))


# Above this many box tests (queried scans x scans held: a loop closure moving a large part of
# a large map), a query sweeps every box once instead (sort by xmin, O(N log N + pairs)); below
# it, testing the queried boxes against every box held costs about a millisecond at most.
_BOX_TESTS = 2_000_000


class ScanExtentIndex:
    """Scan extents by id, for the overlapping pairs of a few moved scans (the live monitor).

    Boxes are kept by row (one per id, for good). A query tests the queried scans' boxes
    against every box held, compiled: the tests of a few scans against a map of thousands
    take microseconds, however often their place was visited; a query of many scans in a
    large map sweeps every box once (_BOX_TESTS).
    """

    def __init__(self) -> None:
        self._row: dict[int, int] = {}
        self._ids = np.zeros(16, dtype=np.int64)  # id of each row
        self._boxes = np.zeros((16, 4))  # box of each row
        self._held = np.zeros(16, dtype=bool)  # whether each row's id is in the index
        self._count = 0  # ids in the index

    def __len__(self) -> int:
        return self._count

    def __contains__(self, scan_id: int) -> bool:
        row = self._row.get(int(scan_id))
        return row is not None and bool(self._held[row])

    def _rows_of_known(self, ids: list[int]) -> np.ndarray:
        rows = np.array([self._row.get(scan_id, -1) for scan_id in ids], dtype=np.int64)
        unknown = (rows < 0) | ~self._held[rows]
        if unknown.any():
            raise KeyError(f'scan {ids[int(np.argmax(unknown))]} is not in the index')
        return rows

    def _row_of(self, scan_id: int) -> int:
        row = self._row.setdefault(scan_id, len(self._row))
        if row == len(self._ids):
            rows = 2 * row
            self._ids, self._boxes = with_rows(self._ids, rows), with_rows(self._boxes, rows)
            self._held = with_rows(self._held, rows, fill=False)
        self._ids[row] = scan_id
        return row

    def update(self, ids: np.ndarray, extents: np.ndarray) -> None:
        """Insert scans or move them to new extents.

        Parameters
        ----------
        ids: (M,) scan ids, none repeated; known ids are moved, the others inserted.
        extents: (M, 4) their boxes (xmin, ymin, xmax, ymax) in metres.

        Raises ValueError for repeated ids, a count mismatch or malformed extents.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        extents = _checked_extents(extents)
        if len(ids) != len(extents):
            raise ValueError(f'{len(ids)} ids but {len(extents)} extents')
        if len(np.unique(ids)) != len(ids):
            raise ValueError('ids must not repeat')
        rows = np.array([self._row_of(scan_id) for scan_id in ids.tolist()], dtype=np.int64)
        self._count += int(np.count_nonzero(~self._held[rows]))
        self._boxes[rows] = extents
        self._held[rows] = True

    def remove(self, ids: np.ndarray) -> None:
        """Forget scans.

        Parameters
        ----------
        ids: the scan ids to forget; raises KeyError (and forgets none) if one is not in the
            index.
        """
        rows = self._rows_of_known(np.asarray(ids, dtype=np.int64).reshape(-1).tolist())
        self._count -= int(np.count_nonzero(self._held[np.unique(rows)]))
        self._held[rows] = False

    def pairs_touching(self, ids: np.ndarray) -> np.ndarray:
        """Every overlapping pair that involves one of `ids`.

        Parameters
        ----------
        ids: scan ids in the index; raises KeyError if one is not.

        Returns
        -------
        (P, 2) int64 rows (i, j) of scan ids, i < j, unique and sorted.
        """
        rows = self._rows_of_known(np.asarray(ids, dtype=np.int64).reshape(-1).tolist())
        if rows.size == 0:
            return np.zeros((0, 2), dtype=np.int64)
        held = np.flatnonzero(self._held)
        if rows.size * held.size <= _BOX_TESTS:
            first, second = _overlapping(self._boxes, rows, held)
        else:
            pairs = held[candidate_pairs(self._boxes[held])]
            queried = np.zeros(self._held.size, dtype=bool)
            queried[rows] = True
            first, second = pairs[queried[pairs].any(axis=1)].T
        return _as_pairs(self._ids[first], self._ids[second])


@numba.njit(cache=True)
def _overlap(boxes: np.ndarray, row: int, other: int) -> bool:
    """Whether two rows' boxes overlap (closed: touching counts, as extents_overlap)."""
    return (boxes[row, 0] <= boxes[other, 2] and boxes[other, 0] <= boxes[row, 2]
            and boxes[row, 1] <= boxes[other, 3] and boxes[other, 1] <= boxes[row, 3])


@numba.njit(cache=True)
def _overlapping(boxes: np.ndarray, rows: np.ndarray, near: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(row, other) for each of `rows` and each other row of `near` whose boxes overlap:
    counted, then filled (no rows x near matrix)."""
    count = 0
    for row in rows:
        for other in near:
            count += other != row and _overlap(boxes, row, other)
    first, second = np.empty(count, dtype=np.int64), np.empty(count, dtype=np.int64)
    count = 0
    for row in rows:
        for other in near:
            if other != row and _overlap(boxes, row, other):
                first[count], second[count] = row, other
                count += 1
    return first, second
