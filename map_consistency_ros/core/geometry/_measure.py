"""Pairwise inconsistency of two scans (Mazuran et al. 2014, eqs. 1-2).

d_i(p): the Euclidean distance from a point p to the boundary of scan i's visibility polygon
V_i when p lies strictly inside V_i, else 0 (eq. 1). M_ij = sum_k d_i(p_j^k) + sum_k d_j(p_i^k)
over the valid end points p of each scan (eq. 2); n_ij counts the end points of either scan
strictly inside the other's polygon.

The fast kernel uses that V_i is star-shaped around its sensor with uniformly spaced beams: a
point's bearing gives its beam wedge in O(1), one cross product with that wedge's end-point edge
decides inside / outside, and only edges whose wedge comes closer to p than the best distance
so far (an angular window that shrinks as the distance does) can hold the nearest boundary
point. The naive reference tests every edge (ray crossing + minimum over all edges, O(K) per
point), as the original implementation does.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numba
import numpy as np

from map_consistency_ros.core.geometry._scan_geometry import ScanSet

TWO_PI = 2.0 * math.pi
# _rough_bearing is within 1.2e-5 rad of atan2; the slack covers that with a margin.
BEARING_SLACK = 1e-4
# Below this many pairs a batch runs on the calling thread alone: waking the OpenMP threads for
# a handful of pairs costs more than it saves.
PARALLEL_MIN_PAIRS = 100


@dataclass(frozen=True)
class PairMeasures:
    """Measures of P scan pairs.

    `pairs (P, 2)` int64 with i < j, `distance_sum (P,)` = M_ij, `point_count (P,)` = n_ij,
    `largest (P, T)` the T largest of the pair's pooled distances, descending, zero padded
    (for trimming the pair's most extreme points before its statistic).
    """

    pairs: np.ndarray
    distance_sum: np.ndarray
    point_count: np.ndarray
    largest: np.ndarray

    def take(self, rows: np.ndarray) -> PairMeasures:
        """The measures of some of the pairs.

        Parameters
        ----------
        rows: indices of pairs (P',) or a boolean mask (P,).

        Returns
        -------
        PairMeasures of the pairs `rows`, in that order.
        """
        return PairMeasures(pairs=self.pairs[rows], distance_sum=self.distance_sum[rows],
                            point_count=self.point_count[rows], largest=self.largest[rows])


@numba.njit(cache=True)
def _segment_distance2(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Squared distance from p to the segment ab (squares spare a sqrt per edge)."""
    dx, dy = bx - ax, by - ay
    wx, wy = px - ax, py - ay
    length2 = dx * dx + dy * dy
    along = wx * dx + wy * dy
    if length2 == 0.0 or along <= 0.0:
        return wx * wx + wy * wy
    if along >= length2:
        ux, uy = px - bx, py - by
        return ux * ux + uy * uy
    # The perpendicular through the cross product keeps full precision near the edge.
    cross = dx * wy - dy * wx
    return cross * cross / length2


@numba.njit(cache=True)
def _edge_distance2(ends: np.ndarray, sx: float, sy: float, full_circle: bool, edge: int,
                   px: float, py: float) -> float:
    """Squared distance from p to the boundary in wedge `edge` (beam edge to the next, cyclic).

    The last wedge of a scan short of the full circle is the blind sector: its boundary is
    the two edges from the sensor to the first and last end points.
    """
    beams = ends.shape[0]
    if edge < beams - 1:
        return _segment_distance2(px, py, ends[edge, 0], ends[edge, 1],
                                  ends[edge + 1, 0], ends[edge + 1, 1])
    if full_circle:
        return _segment_distance2(px, py, ends[edge, 0], ends[edge, 1], ends[0, 0], ends[0, 1])
    return min(_segment_distance2(px, py, sx, sy, ends[0, 0], ends[0, 1]),
               _segment_distance2(px, py, ends[edge, 0], ends[edge, 1], sx, sy))


@numba.njit(cache=True)
def _rough_bearing(dx: float, dy: float) -> float:
    """atan2(dy, dx) within 1.2e-5 rad, several times cheaper than the exact one."""
    ax, ay = abs(dx), abs(dy)
    ratio = min(ax, ay) / max(max(ax, ay), 1e-300)
    square = ratio * ratio
    # Abramowitz & Stegun 4.4.49 on [0, 1], error <= 1e-5.
    angle = ratio * (0.9998660 + square * (-0.3302995 + square * (
        0.1801410 + square * (-0.0851330 + square * 0.0208351))))
    angle = 0.5 * math.pi - angle if ay > ax else angle
    angle = math.pi - angle if dx < 0.0 else angle
    return -angle if dy < 0.0 else angle


@numba.njit(cache=True)
def _beyond(angle: float, best2: float, rho2: float) -> bool:
    """Whether every edge `angle` or more away from p's bearing is further than the best
    distance: angle beyond asin(best / rho), bounded by its tangent (conservative) plus the
    bearing slack, compared squared to keep a root and a division off each point's chain."""
    if best2 >= rho2:
        return angle > math.pi
    reach = angle - BEARING_SLACK
    return reach > 0.0 and reach * reach * (rho2 - best2) > best2


@numba.njit(cache=True)
def _boundary_distance(ends: np.ndarray, sx: float, sy: float, wedge: int, bearing: float,
                       increment: float, full_circle: bool, px: float, py: float) -> float:
    """d_i(p) for a point p strictly inside the star-shaped polygon, in `wedge`, at `bearing`
    (p's bearing from the sensor counted from the first beam, in [0, 2 pi], possibly rough).

    An edge in a wedge an angle g away from p's bearing is at least rho * sin(g) from p, so the
    outward scan stops once g exceeds asin(best / rho); while best is not below rho (p near
    the sensor) the window is the whole circle, and shrinks as soon as a closer edge turns up.
    """
    beams = ends.shape[0]
    last = beams - 1
    last_width = TWO_PI - last * increment
    low_angle = wedge * increment
    high_angle = low_angle + (increment if wedge < last else last_width)
    # Keep the bearing within the settled wedge (it can be a rough error beyond, or wrapped).
    if bearing < low_angle - math.pi:
        bearing += TWO_PI
    elif bearing > high_angle + math.pi:
        bearing -= TWO_PI
    bearing = min(max(bearing, low_angle), high_angle)
    dx, dy = px - sx, py - sy
    best2 = _edge_distance2(ends, sx, sy, full_circle, wedge, px, py)
    rho2 = dx * dx + dy * dy
    left, right = wedge, wedge
    left_angle, right_angle = low_angle, high_angle
    go_left, go_right = True, True
    visited = 1
    while (go_left or go_right) and visited < beams:
        if go_left:
            if _beyond(bearing - left_angle, best2, rho2):
                go_left = False
            else:
                left = left - 1 if left > 0 else last
                left_angle -= increment if left < last else last_width
                visited += 1
                best2 = min(best2, _edge_distance2(ends, sx, sy, full_circle, left, px, py))
        if go_right and visited < beams:
            if _beyond(right_angle - bearing, best2, rho2):
                go_right = False
            else:
                right = right + 1 if right < last else 0
                right_angle += increment if right < last else last_width
                visited += 1
                best2 = min(best2, _edge_distance2(ends, sx, sy, full_circle, right, px, py))
    return math.sqrt(best2)


@numba.njit(cache=True)
def _naive_distance(ends: np.ndarray, sx: float, sy: float, full_circle: bool,
                    px: float, py: float) -> float:
    """d_i(p) by ray crossing over the polygon ring and the minimum over all its edges."""
    beams = ends.shape[0]
    corners = beams if full_circle else beams + 1
    inside = False
    best2 = np.inf
    for corner in range(corners):
        previous = corner - 1 if corner > 0 else corners - 1
        if full_circle:
            ax, ay = ends[previous, 0], ends[previous, 1]
            bx, by = ends[corner, 0], ends[corner, 1]
        else:
            ax, ay = (sx, sy) if previous == 0 else (ends[previous - 1, 0], ends[previous - 1, 1])
            bx, by = (sx, sy) if corner == 0 else (ends[corner - 1, 0], ends[corner - 1, 1])
        if (by > py) != (ay > py) and px < (ax - bx) * (py - by) / (ay - by) + bx:
            inside = not inside
        best2 = min(best2, _segment_distance2(px, py, ax, ay, bx, by))
    return math.sqrt(best2) if inside else 0.0


@numba.njit(cache=True)
def _fill_distances(endpoints: np.ndarray, poses: np.ndarray, valid: np.ndarray,
                    extents: np.ndarray, angle_min: float, increment: float, full_circle: bool,
                    naive: bool, polygon: int, other: int, out: np.ndarray,
                    found: np.ndarray, bearings: np.ndarray) -> None:
    """out[k] = d_polygon(end point k of other), 0 where that end point is invalid.

    A point's bearing gives its beam wedge (wedge m spans the bearings [m, m + 1) * increment
    from the first beam; the last one closes the circle), one cross product with that wedge's
    end-point edge whether it is inside. Two passes: which end points lie inside, with no
    branch on inside or not (a coin toss near the walls both scans see, and mispredicted
    branches cost more than the arithmetic they would skip), then the distances of those, a
    minority. `found` (int64) and `bearings`, both (K,), are scratch.
    """
    ends = endpoints[polygon]
    points = endpoints[other]
    usable = valid[other]
    sx, sy = poses[polygon, 0], poses[polygon, 1]
    first_beam = (poses[polygon, 2] + angle_min + math.pi) % TWO_PI - math.pi
    xmin, ymin, xmax, ymax = extents[polygon, 0], extents[polygon, 1], extents[polygon, 2], \
        extents[polygon, 3]
    beams = points.shape[0]
    last = beams - 1
    last_width = TWO_PI - last * increment
    inverse = 1.0 / increment
    # Every wedge is at least half a beam wide; the rough bearing needs room to be one off.
    rough = increment >= 8.0 * BEARING_SLACK
    inside = 0  # found[:inside] = beam * beams + wedge of the inside points, with bearings
    for beam in range(beams):
        out[beam] = 0.0
        px, py = points[beam, 0], points[beam, 1]
        # A point on or outside the polygon's bounding box is not strictly inside it.
        if not usable[beam] or px <= xmin or py <= ymin or px >= xmax or py >= ymax:
            continue
        if naive:
            out[beam] = _naive_distance(ends, sx, sy, full_circle, px, py)
            continue
        dx, dy = px - sx, py - sy
        # Both angles lie in [-pi, pi], so at most one turn brings the bearing into [0, 2 pi].
        angle = (_rough_bearing(dx, dy) if rough else math.atan2(dy, dx)) - first_beam
        bearing = angle + TWO_PI if angle < 0.0 else angle
        wedge = min(int(bearing * inverse), last)
        low_angle = wedge * increment
        high_angle = low_angle + (increment if wedge < last else last_width)
        # Near a side of its wedge (about one point in a hundred: a branch that predicts well),
        # the cross product with that side's beam decides.
        if rough and (bearing - low_angle < BEARING_SLACK or high_angle - bearing < BEARING_SLACK):
            previous = wedge - 1 if wedge > 0 else last
            following = wedge + 1 if wedge < last else 0
            # positive when (dx, dy) lies counter-clockwise of the beam (within pi)
            low_side = (ends[wedge, 0] - sx) * dy - (ends[wedge, 1] - sy) * dx
            high_side = (ends[following, 0] - sx) * dy - (ends[following, 1] - sy) * dx
            below = (bearing - low_angle < BEARING_SLACK) & (low_side < 0.0)
            above = (high_angle - bearing < BEARING_SLACK) & (high_side >= 0.0)
            wedge = previous if below else (following if above else wedge)
        following = wedge + 1 if wedge < last else 0
        ax, ay = ends[wedge, 0], ends[wedge, 1]
        # Beams turn counter-clockwise, so the interior lies left of every end-point edge.
        left = (ends[following, 0] - ax) * (py - ay) - (ends[following, 1] - ay) * (px - ax)
        bearings[inside] = bearing
        found[inside] = wedge + beams * beam
        inside += (left > 0.0) & (full_circle | (wedge != last))
    for index in range(inside):
        beam = found[index] // beams
        out[beam] = _boundary_distance(ends, sx, sy, found[index] - beams * beam,
                                       bearings[index], increment, full_circle,
                                       points[beam, 0], points[beam, 1])


@numba.njit(cache=True)
def _keep_largest(row: np.ndarray, distance: float) -> None:
    slot = row.shape[0]
    while slot > 0 and row[slot - 1] < distance:
        if slot < row.shape[0]:
            row[slot] = row[slot - 1]
        slot -= 1
    if slot < row.shape[0]:
        row[slot] = distance


@numba.njit(cache=True, parallel=True, nogil=True)
def _pair_kernel(endpoints: np.ndarray, poses: np.ndarray, valid: np.ndarray,
                 extents: np.ndarray, angle_min: float, increment: float, full_circle: bool,
                 naive: bool, pairs: np.ndarray, keep: int):
    count = pairs.shape[0]
    sums = np.zeros(count)
    points = np.zeros(count, dtype=np.int64)
    largest = np.zeros((count, keep))
    beams = endpoints.shape[1]
    for index in numba.prange(count):
        distances, bearings = np.empty(2 * beams), np.empty(beams)
        found = np.empty(beams, dtype=np.int64)
        first, second = pairs[index, 0], pairs[index, 1]
        _fill_distances(endpoints, poses, valid, extents, angle_min, increment, full_circle,
                        naive, first, second, distances[:beams], found, bearings)
        _fill_distances(endpoints, poses, valid, extents, angle_min, increment, full_circle,
                        naive, second, first, distances[beams:], found, bearings)
        row = largest[index]
        total, inside = 0.0, 0
        for distance in distances:
            if distance > 0.0:
                total += distance
                inside += 1
                _keep_largest(row, distance)
        sums[index], points[index] = total, inside
    return sums, points, largest


def _checked_pairs(pairs: np.ndarray, scan_count: int) -> np.ndarray:
    pairs = np.asarray(pairs)
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
        raise ValueError(f'pairs must be a (P, 2) integer array, got {pairs.dtype} {pairs.shape}')
    if pairs.min() < 0 or pairs.max() >= scan_count:
        raise ValueError(f'pair indices must lie in [0, {scan_count})')
    if np.any(pairs[:, 0] == pairs[:, 1]):
        raise ValueError('a pair must join two different scans')
    return np.ascontiguousarray(np.sort(pairs, axis=1), dtype=np.int64)


def _measure(scans: ScanSet, pairs: np.ndarray, keep_largest: int, naive: bool) -> PairMeasures:
    if int(keep_largest) != keep_largest or keep_largest < 0:
        raise ValueError(f'keep_largest must be a non-negative integer, got {keep_largest}')
    pairs = _checked_pairs(pairs, scans.scan_count)
    model = scans.model
    sums, points, largest = _pair_kernel(
        scans.endpoints, scans.sensor_poses, scans.valid, scans.extents, model.angle_min,
        model.angle_increment, scans.full_circle, naive, pairs, int(keep_largest))
    return PairMeasures(pairs=pairs, distance_sum=sums, point_count=points, largest=largest)


def pair_measures(scans: ScanSet, pairs: np.ndarray, keep_largest: int = 10) -> PairMeasures:
    """M_ij, n_ij and the largest distances of every pair.

    Parameters
    ----------
    scans: the N scans placed in the world.
    pairs: (P, 2) integer rows of `scans` (i, j), in either order; an empty array means none.
    keep_largest: T, how many of each pair's largest distances to keep (non-negative).

    Returns
    -------
    The PairMeasures of the P pairs, in the given order, each pair as (i, j) with i < j.
    Raises ValueError for indices out of range, a scan paired with itself or a bad
    keep_largest.
    """
    return _measure(scans, pairs, keep_largest, naive=False)


def measure_pairs(scans: ScanSet, pairs: np.ndarray, keep_largest: int = 10, chunk: int = 8192,
                  progress: Callable[[int, int], None] | None = None) -> PairMeasures:
    """pair_measures in batches, so that a long run can report progress and a caller's thread
    gets control back between batches; a batch of fewer than PARALLEL_MIN_PAIRS pairs runs on
    the calling thread alone. Batching changes no measure (each pair is measured alone).

    Parameters
    ----------
    scans, pairs, keep_largest: as pair_measures.
    chunk: the most pairs in one batch (positive).
    progress: called as progress(pairs measured, all pairs) after every batch.

    Returns
    -------
    The PairMeasures of pair_measures(scans, pairs, keep_largest).
    """
    count = len(pairs)
    parts = []
    for start in range(0, max(count, 1), chunk):  # one (empty) batch for no pairs
        batch = pairs[start:start + chunk]
        with _threads_for(len(batch)):
            parts.append(pair_measures(scans, batch, keep_largest=keep_largest))
        if progress is not None:
            progress(min(start + chunk, count), count)
    if len(parts) == 1:
        return parts[0]
    return PairMeasures(*(np.concatenate([getattr(part, name) for part in parts])
                          for name in ('pairs', 'distance_sum', 'point_count', 'largest')))


@contextmanager
def _threads_for(pair_count: int) -> Iterator[None]:
    """Run numba's parallel kernels on this thread alone for small batches."""
    if pair_count >= PARALLEL_MIN_PAIRS:
        yield
        return
    previous = numba.get_num_threads()
    numba.set_num_threads(1)  # thread-local: other threads keep their setting
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def pair_measures_naive(scans: ScanSet, pairs: np.ndarray, keep_largest: int = 10) -> PairMeasures:
    """pair_measures by the O(K^2)-per-pair reference (ray crossing, every edge).

    Parameters
    ----------
    scans, pairs, keep_largest: as pair_measures.

    Returns
    -------
    The PairMeasures, as pair_measures gives them (up to rounding).
    """
    return _measure(scans, pairs, keep_largest, naive=True)


def point_distances(scans: ScanSet, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
    """The distances d_i(p) and d_j(p) of one pair's end points.

    Parameters
    ----------
    scans: the N scans placed in the world.
    i, j: rows of two scans in `scans`.

    Returns
    -------
    (d_i of the end points of j, d_j of the end points of i), each (K,) in metres: zero where
    the end point is invalid or outside the other polygon.
    """
    distances = pairs_point_distances(scans, np.array([[i, j]]))[0]
    return distances[0], distances[1]


def pairs_point_distances(scans: ScanSet, pairs: np.ndarray) -> np.ndarray:
    """The distances d_i(p) and d_j(p) of the end points of several pairs.

    Parameters
    ----------
    scans: the N scans placed in the world.
    pairs: (P, 2) rows (i, j) of `scans` (any shape of 2P values is reshaped).

    Returns
    -------
    (P, 2, K) distances in metres: [p, 0] d_i of the end points of j, [p, 1] d_j of the end
    points of i, zero where the end point is invalid or outside the other polygon. Raises
    ValueError for an index out of range.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if pairs.size and not (pairs.min() >= 0 and pairs.max() < scans.scan_count):
        bad = pairs[(pairs < 0) | (pairs >= scans.scan_count)][0]
        raise ValueError(f'scan index {bad} out of range [0, {scans.scan_count})')
    model = scans.model
    distances = np.zeros((len(pairs), 2, scans.ranges.shape[1]))
    _pairs_distances(scans.endpoints, scans.sensor_poses, scans.valid, scans.extents,
                     model.angle_min, model.angle_increment, scans.full_circle, pairs, distances)
    return distances


@numba.njit(cache=True, parallel=True, nogil=True)
def _pairs_distances(endpoints: np.ndarray, poses: np.ndarray, valid: np.ndarray,
                     extents: np.ndarray, angle_min: float, increment: float,
                     full_circle: bool, pairs: np.ndarray, out: np.ndarray) -> None:
    beams = endpoints.shape[1]
    for pair in numba.prange(pairs.shape[0]):
        i, j = pairs[pair, 0], pairs[pair, 1]
        found, bearings = np.empty(beams, dtype=np.int64), np.empty(beams)
        _fill_distances(endpoints, poses, valid, extents, angle_min, increment, full_circle,
                        False, i, j, out[pair, 0], found, bearings)
        _fill_distances(endpoints, poses, valid, extents, angle_min, increment, full_circle,
                        False, j, i, out[pair, 1], found, bearings)
