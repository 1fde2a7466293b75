"""Which scan pairs can overlap: pairs whose polygon extents (axis-aligned boxes) intersect.

Pairs with disjoint extents have disjoint polygons and so a measure of exactly zero; leaving
them out loses nothing. Boxes that merely touch count as overlapping (closed intervals).
"""
from __future__ import annotations

import math
from collections import defaultdict

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


class ScanExtentIndex:
    """Uniform-grid hash of scan extents for incremental candidate pairs (the live node).

    Each scan is stored in every grid cell its box touches; `pairs_touching` finds the
    overlapping pairs of a few moved scans without visiting the others. `cell_size` (metres)
    should be about the size of a scan's extent. Scans are kept by row (one per id, for good)
    so that the boxes of all neighbours are tested at once.
    """

    def __init__(self, cell_size: float) -> None:
        cell_size = float(cell_size)
        if not math.isfinite(cell_size) or cell_size <= 0.0:
            raise ValueError(f'cell_size must be a positive finite number, got {cell_size}')
        self.cell_size = cell_size
        self._row: dict[int, int] = {}
        self._ids = np.zeros(16, dtype=np.int64)  # id of each row
        self._boxes = np.zeros((16, 4))  # box of each row
        self._cells: dict[int, list[tuple[int, int]]] = {}  # of the ids in the index
        self._grid: defaultdict[tuple[int, int], set[int]] = defaultdict(set)  # rows

    def __len__(self) -> int:
        return len(self._cells)

    def __contains__(self, scan_id: int) -> bool:
        return int(scan_id) in self._cells

    def _check_known(self, ids: list[int]) -> None:
        unknown = [scan_id for scan_id in ids if scan_id not in self._cells]
        if unknown:
            raise KeyError(f'scan {unknown[0]} is not in the index')

    def _cells_of(self, box: np.ndarray) -> list[tuple[int, int]]:
        low = np.floor(box[:2] / self.cell_size).astype(np.int64)
        high = np.floor(box[2:] / self.cell_size).astype(np.int64)
        return [(cx, cy) for cx in range(low[0], high[0] + 1)
                for cy in range(low[1], high[1] + 1)]

    def _row_of(self, scan_id: int) -> int:
        row = self._row.setdefault(scan_id, len(self._row))
        if row == len(self._ids):
            self._ids, self._boxes = with_rows(self._ids, 2 * row), with_rows(self._boxes, 2 * row)
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
        # a lookup per id, not an array of every id in the index: this runs on every update
        known = np.fromiter((scan_id in self._cells for scan_id in ids.tolist()), dtype=bool,
                            count=ids.size)
        self.remove(ids[known])
        for scan_id, box in zip(ids.tolist(), extents):
            row = self._row_of(scan_id)
            cells = self._cells_of(box)
            for cell in cells:
                self._grid[cell].add(row)
            self._boxes[row] = box
            self._cells[scan_id] = cells

    def remove(self, ids: np.ndarray) -> None:
        """Forget scans.

        Parameters
        ----------
        ids: the scan ids to forget; raises KeyError (and forgets none) if one is not in the
            index.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1).tolist()
        self._check_known(ids)
        for scan_id in ids:
            row = self._row[scan_id]
            for cell in self._cells.pop(scan_id):
                members = self._grid[cell]
                members.discard(row)
                if not members:
                    del self._grid[cell]

    def pairs_touching(self, ids: np.ndarray) -> np.ndarray:
        """Every overlapping pair that involves one of `ids`.

        Parameters
        ----------
        ids: scan ids in the index; raises KeyError if one is not.

        Returns
        -------
        (P, 2) int64 rows (i, j) of scan ids, i < j, unique and sorted.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1).tolist()
        self._check_known(ids)
        # One union over the cells of all `ids` (a burst of keyframes, a loop closure's moved
        # scans mostly share cells), then every box of it against each of theirs, compiled:
        # boxes that overlap share a cell, so no pair is lost, and the cost follows the scans
        # near `ids`, not a Python set operation per id and neighbour.
        cells = set().union(*(self._cells[scan_id] for scan_id in ids))
        near = set().union(*(self._grid[cell] for cell in cells))
        if not ids or not near:
            return np.zeros((0, 2), dtype=np.int64)
        rows = np.array([self._row[scan_id] for scan_id in ids], dtype=np.int64)
        first, second = _overlapping(self._boxes, rows,
                                     np.fromiter(near, dtype=np.int64, count=len(near)))
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
    counted, then filled (a loop closure moves thousands of rows; no rows x near matrix)."""
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
