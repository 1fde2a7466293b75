"""Changed places (explanation.py): the deep end points of change pairs grouped into places
(place_labels), and whether failures span places wider than any change."""
from __future__ import annotations

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult, pair_endpoints
from map_consistency_ros.core.geometry import ScanSet
from map_consistency_ros.core.verdict._assessment import ChangedPlace, ExplanationSettings
from map_consistency_ros.core.verdict._union_find import _components


def place_labels(points: np.ndarray, cell: float) -> np.ndarray:
    """Group points into places joined through neighbouring cells.

    Parameters
    ----------
    points: (M, 2) points, metres; M >= 1.
    cell: the side of a square cell, metres; points in one cell or in cells touching (the
        eight neighbours) share a place.

    Returns
    -------
    (M,) int64 labels, equal for the points of one place.
    """
    cells = np.floor(points / cell).astype(np.int64)
    cells -= cells.min(axis=0) - 1  # every neighbour of a cell has non-negative coordinates
    width = int(cells[:, 1].max()) + 2
    unique, cell_of_point = np.unique(cells[:, 0] * width + cells[:, 1], return_inverse=True)
    # half of the eight neighbours suffices: a link joins both ways
    neighbours = unique[:, None] + np.array([width - 1, width, width + 1, 1])[None]
    found = np.minimum(np.searchsorted(unique, neighbours), unique.size - 1)
    present = unique[found] == neighbours
    links = np.stack([np.nonzero(present)[0], found[present]], axis=1)
    return _components(unique.size, links)[cell_of_point.reshape(-1)]


def _changes(scans: ScanSet, result: ConsistencyResult, rows: np.ndarray,
             settings: ExplanationSettings) -> tuple[ChangedPlace, ...]:
    """The deep end points of the change pairs `rows` of `result`, grouped into places."""
    points, owners = pair_endpoints(scans, result, rows, settings.change_depth)
    if not len(points):
        return ()
    labels = place_labels(points, settings.change_cell)
    places = []
    for label in np.unique(labels):
        members = labels == label
        centre = points[members].mean(axis=0)
        places.append(ChangedPlace(scans=np.unique(owners[members]), x=float(centre[0]),
                                   y=float(centre[1]), points=int(members.sum())))
    return tuple(sorted(places, key=lambda place: -place.points))


_EXTENT_SAMPLE = 2000  # pairs whose end points show a region's extent: bounded cost


def _spans_beyond_changes(scans: ScanSet, result: ConsistencyResult, rows: np.ndarray,
                          settings: ExplanationSettings) -> bool:
    """Whether most deep inconsistent end points of the pairs `rows` lie in places wider than
    any change: a gross error crosses whole walls and rooms (places of 5-40 m on displaced
    copies), people, doors and furniture make places of a metre or two."""
    rows = rows[::max(1, -(-rows.size // _EXTENT_SAMPLE))]
    points, _ = pair_endpoints(scans, result, rows, settings.change_depth)
    if not len(points):
        return False
    labels = place_labels(points, settings.change_cell)
    low = np.full((labels.max() + 1, 2), np.inf)
    high = np.full((labels.max() + 1, 2), -np.inf)
    np.minimum.at(low, labels, points)
    np.maximum.at(high, labels, points)
    extent = np.hypot(*(high - low).T)
    return bool(np.count_nonzero(extent[labels] > settings.max_change_extent) * 2 > len(points))
