"""The grid side of the paper's measure: live scans against a fixed occupancy grid.

Mazuran et al. (2014, eqs. 1-2) measure a pair of scans i, j by how deep each one's end points
lie inside the other's visibility polygon: M_ij = sum d_i(p_j) + sum d_j(p_i), n_ij the points
inside. Against a map, the map's known free space plays the part of one polygon and its
obstacles the part of that scan's end points:

- a live end point p inside the map's free space (the union of FREE cells; everything off the
  grid is not free) counts its depth d_F(p), its Euclidean distance to the nearest cell that is
  not free (occupied, unknown or off the grid): how far into space the map knows to be empty
  the scan saw something;
- the centre c of an occupied map cell strictly inside the live scan's visibility polygon V
  counts d_V(c), its distance to V's boundary (the pairwise measure's own kernel,
  core/geometry/_measure.py): how far inside what the scan saw empty the map has an obstacle.

M_i is the sum of both kinds of depth, n_i the count of both kinds of point, so a scan's
(M_i, n_i) takes the same statistics as a pair's. End points in unknown cells or off the grid
are not judged (nobody mapped that space); their share of a scan's valid beams is reported.

d_F comes from one Euclidean distance transform of the free space at map load (scipy):
every cell keeps the nearest non-free cell to its centre; a point's depth is its distance to
the nearest of the squares kept by its own cell and the 8 around it. That is the distance to a
real non-free square, so never below the exact depth; tests bound the excess against shapely.

numba's cache does not see changes to functions of other files: the grid kernels inline
`_fill_distances` of core/geometry/_measure.py, so after changing it, touch this file (or
clear its cache) to compile them again; test_grid_measure.py compares the two and fails on a
stale cache.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from map_consistency_ros.core.geometry import ScanSet, read_only
from map_consistency_ros.core.geometry._measure import _fill_distances, _keep_largest
from map_consistency_ros.core.localization._grid import FREE, UNKNOWN, OccupancyGrid


@dataclass(frozen=True)
class GridReference:
    """An OccupancyGrid prepared once for measuring live scans against it.

    `grid`; `nearest (2, H + 2, W + 2) int32` for the grid padded by one ring of non-free
    cells (the outside), the (row, col) in padded cells of the nearest non-free cell to each
    cell's centre; `obstacles (M, 2)` the occupied cells' centres sorted by y (so that a scan's
    extent selects a slice).
    """

    grid: OccupancyGrid
    nearest: np.ndarray
    obstacles: np.ndarray


def prepare_reference(grid: OccupancyGrid) -> GridReference:
    """The distance transform of a grid's free space and its obstacles, once per map.

    Parameters
    ----------
    grid: the reference map.

    Returns
    -------
    The GridReference.
    """
    from scipy.ndimage import distance_transform_edt
    free = np.zeros((grid.height + 2, grid.width + 2), dtype=bool)
    free[1:-1, 1:-1] = grid.cells == FREE
    if free.any():
        nearest = distance_transform_edt(free, return_distances=False, return_indices=True)
    else:  # every cell is its own nearest non-free cell
        nearest = np.indices(free.shape)
    obstacles = grid.occupied_centres()
    obstacles = obstacles[np.argsort(obstacles[:, 1], kind='stable')]
    return GridReference(grid=grid, nearest=read_only(np.ascontiguousarray(nearest, np.int32)),
                         obstacles=read_only(np.ascontiguousarray(obstacles)))


@dataclass(frozen=True)
class GridMeasures:
    """Measures of N live scans against a grid, row i for scan i.

    `distance_sum (N,)` = M_i and `point_count (N,)` = n_i (both kinds of point);
    `largest (N, T)` the T largest depths of the scan, descending, zero padded (as
    PairMeasures.largest); `endpoint_sum`, `endpoint_count`: the live end points inside the
    map's free space; `obstacle_sum`, `obstacle_count`: the occupied cells inside the scan's
    polygon; `valid_count (N,)` the scan's valid beams; `unjudged_count (N,)` those ending in
    unknown cells or off the grid; `unjudged_share (N,)` their share of the valid beams (1
    for a scan without valid beams: nothing of it can be judged).
    """

    distance_sum: np.ndarray
    point_count: np.ndarray
    largest: np.ndarray
    endpoint_sum: np.ndarray
    endpoint_count: np.ndarray
    obstacle_sum: np.ndarray
    obstacle_count: np.ndarray
    valid_count: np.ndarray
    unjudged_count: np.ndarray

    @property
    def unjudged_share(self) -> np.ndarray:
        """(N,) share of each scan's valid beams that end where the map knows nothing."""
        with np.errstate(invalid='ignore', divide='ignore'):
            share = self.unjudged_count / self.valid_count
        return np.where(self.valid_count > 0, share, 1.0)

    def take(self, rows: np.ndarray) -> GridMeasures:
        """The measures of some of the scans.

        Parameters
        ----------
        rows: indices of scans or a boolean mask.

        Returns
        -------
        GridMeasures of those scans, in that order.
        """
        return GridMeasures(**{name: getattr(self, name)[rows]
                               for name in self.__dataclass_fields__})


@dataclass(frozen=True)
class GridPointDistances:
    """The points of one live scan's measure against a grid.

    `endpoint_depth (K,)` d_F of each end point (0 where invalid, not in free space, or
    unjudged); `endpoint_cells (K,) int8` the cell value under each end point (UNKNOWN off the
    grid; meaningful for valid beams only); `obstacle_rows (M',)` rows of
    GridReference.obstacles strictly inside the scan's polygon, `obstacle_depth (M',)` their
    d_V.
    """

    endpoint_depth: np.ndarray
    endpoint_cells: np.ndarray
    obstacle_rows: np.ndarray
    obstacle_depth: np.ndarray


@numba.njit(cache=True)
def _square_distance2(gx: float, gy: float, row: int, col: int) -> float:
    """Squared distance, in cells, from grid point (gx, gy) to the square of padded cell
    (row, col), which spans [col - 1, col] x [row - 1, row] unpadded."""
    dx = max(col - 1.0 - gx, 0.0, gx - col)
    dy = max(row - 1.0 - gy, 0.0, gy - row)
    return dx * dx + dy * dy


@numba.njit(cache=True)
def _endpoint_depths(ends: np.ndarray, valid: np.ndarray, cells: np.ndarray,
                     nearest: np.ndarray, frame: np.ndarray, depth: np.ndarray,
                     cell_values: np.ndarray) -> None:
    """depth[k] = d_F(end point k), cell_values[k] = the cell under it (UNKNOWN off the grid).

    `frame` = (origin x, origin y, cos yaw, sin yaw, resolution)."""
    height, width = cells.shape
    ox, oy, cos, sin, resolution = frame[0], frame[1], frame[2], frame[3], frame[4]
    for beam in range(ends.shape[0]):
        depth[beam] = 0.0
        dx, dy = ends[beam, 0] - ox, ends[beam, 1] - oy
        gx = (cos * dx + sin * dy) / resolution
        gy = (-sin * dx + cos * dy) / resolution
        col, row = math.floor(gx), math.floor(gy)
        if not (0 <= row < height and 0 <= col < width):
            cell_values[beam] = UNKNOWN
            continue
        value = cells[row, col]
        cell_values[beam] = value
        if not valid[beam] or value != FREE:
            continue
        best2 = np.inf
        # a free cell is never on the padded ring: its 8 neighbours exist in padded cells
        for prow in range(row, row + 3):
            for pcol in range(col, col + 3):
                best2 = min(best2, _square_distance2(gx, gy, nearest[0, prow, pcol],
                                                     nearest[1, prow, pcol]))
        depth[beam] = math.sqrt(best2) * resolution


@numba.njit(cache=True)
def _obstacle_depths(endpoints: np.ndarray, poses: np.ndarray, extents: np.ndarray, scan: int,
                     angle_min: float, increment: float, full_circle: bool,
                     obstacles: np.ndarray, first: int, last: int, rows: np.ndarray,
                     depths: np.ndarray) -> int:
    """Obstacles[first:last] strictly inside scan's polygon: their rows and d_V in rows[:n],
    depths[:n]; returns n. Batches of K candidates go through the pairwise measure's kernel as
    the end points of a second scan (invalid beyond the batch), so that the inside test and
    the boundary distance are the measure's own."""
    beams = endpoints.shape[1]
    pair_ends = np.zeros((2, beams, 2))
    pair_ends[0] = endpoints[scan]
    pair_poses = np.empty((2, 3))
    pair_poses[0] = poses[scan]
    pair_poses[1] = poses[scan]
    pair_valid = np.zeros((2, beams), dtype=np.bool_)
    pair_extents = np.empty((2, 4))
    pair_extents[0] = extents[scan]
    pair_extents[1] = extents[scan]
    out, found, bearings = np.empty(beams), np.empty(beams, dtype=np.int64), np.empty(beams)
    batch_rows = np.empty(beams, dtype=np.int64)
    xmin, xmax = extents[scan, 0], extents[scan, 2]
    inside, batch = 0, 0
    for row in range(first, last + 1):
        if row < last:
            x = obstacles[row, 0]
            if x <= xmin or x >= xmax:
                continue
            pair_ends[1, batch, 0] = x
            pair_ends[1, batch, 1] = obstacles[row, 1]
            pair_valid[1, batch] = True
            batch_rows[batch] = row
            batch += 1
        if batch == beams or (row == last and batch > 0):
            pair_valid[1, batch:] = False
            _fill_distances(pair_ends, pair_poses, pair_valid, pair_extents, angle_min,
                            increment, full_circle, False, 0, 1, out, found, bearings)
            for slot in range(batch):
                if out[slot] > 0.0:
                    rows[inside] = batch_rows[slot]
                    depths[inside] = out[slot]
                    inside += 1
            batch = 0
    return inside


@numba.njit(cache=True, parallel=True, nogil=True)
def _grid_kernel(endpoints: np.ndarray, poses: np.ndarray, valid: np.ndarray,
                 extents: np.ndarray, angle_min: float, increment: float, full_circle: bool,
                 cells: np.ndarray, nearest: np.ndarray, frame: np.ndarray,
                 obstacles: np.ndarray, keep: int):
    count, beams = valid.shape
    sums = np.zeros((count, 2))
    points = np.zeros((count, 2), dtype=np.int64)
    judged = np.zeros((count, 2), dtype=np.int64)  # valid beams, unjudged beams
    largest = np.zeros((count, keep))
    obstacle_y = obstacles[:, 1].copy()
    for scan in numba.prange(count):
        depth = np.empty(beams)
        cell_values = np.empty(beams, dtype=np.int8)
        _endpoint_depths(endpoints[scan], valid[scan], cells, nearest, frame, depth,
                         cell_values)
        row = largest[scan]
        for beam in range(beams):
            if not valid[scan, beam]:
                continue
            judged[scan, 0] += 1
            if cell_values[beam] == UNKNOWN:
                judged[scan, 1] += 1
            elif depth[beam] > 0.0:
                sums[scan, 0] += depth[beam]
                points[scan, 0] += 1
                _keep_largest(row, depth[beam])
        first = np.searchsorted(obstacle_y, extents[scan, 1], side='right')
        last = np.searchsorted(obstacle_y, extents[scan, 3], side='left')
        if last > first:
            rows = np.empty(last - first, dtype=np.int64)
            depths = np.empty(last - first)
            inside = _obstacle_depths(endpoints, poses, extents, scan, angle_min, increment,
                                      full_circle, obstacles, first, last, rows, depths)
            for index in range(inside):
                sums[scan, 1] += depths[index]
                _keep_largest(row, depths[index])
            points[scan, 1] = inside
    return sums, points, judged, largest


def _frame(grid: OccupancyGrid) -> np.ndarray:
    x, y, yaw = grid.origin
    return np.array([x, y, math.cos(yaw), math.sin(yaw), grid.resolution])


def grid_measures(scans: ScanSet, reference: GridReference,
                  keep_largest: int = 10) -> GridMeasures:
    """M_i, n_i and the unjudged share of every live scan against the map.

    Parameters
    ----------
    scans: the N live scans at the poses the localizer gives them (map frame).
    reference: the prepared map (prepare_reference).
    keep_largest: T, how many of each scan's largest depths to keep (non-negative).

    Returns
    -------
    The GridMeasures, row i for scan i. Raises ValueError for a bad keep_largest.
    """
    if int(keep_largest) != keep_largest or keep_largest < 0:
        raise ValueError(f'keep_largest must be a non-negative integer, got {keep_largest}')
    model = scans.model
    sums, points, judged, largest = _grid_kernel(
        scans.endpoints, scans.sensor_poses, scans.valid, scans.extents, model.angle_min,
        model.angle_increment, scans.full_circle, reference.grid.cells, reference.nearest,
        _frame(reference.grid), reference.obstacles, int(keep_largest))
    return GridMeasures(distance_sum=sums.sum(axis=1), point_count=points.sum(axis=1),
                        largest=largest, endpoint_sum=sums[:, 0], endpoint_count=points[:, 0],
                        obstacle_sum=sums[:, 1], obstacle_count=points[:, 1],
                        valid_count=judged[:, 0], unjudged_count=judged[:, 1])


def grid_point_distances(scans: ScanSet, reference: GridReference,
                         scan: int) -> GridPointDistances:
    """The depths behind one live scan's measure, for plots and tests.

    Parameters
    ----------
    scans: the live scans placed in the map frame.
    reference: the prepared map.
    scan: the row of the scan in `scans`.

    Returns
    -------
    The GridPointDistances of that scan. Raises IndexError for a row out of range.
    """
    if not 0 <= scan < scans.scan_count:
        raise IndexError(f'scan {scan} out of range [0, {scans.scan_count})')
    beams = scans.ranges.shape[1]
    depth, cell_values = np.zeros(beams), np.empty(beams, dtype=np.int8)
    _endpoint_depths(scans.endpoints[scan], scans.valid[scan], reference.grid.cells,
                     reference.nearest, _frame(reference.grid), depth, cell_values)
    obstacle_y = reference.obstacles[:, 1]
    first = int(np.searchsorted(obstacle_y, scans.extents[scan, 1], side='right'))
    last = int(np.searchsorted(obstacle_y, scans.extents[scan, 3], side='left'))
    rows = np.empty(max(last - first, 0), dtype=np.int64)
    depths = np.empty(max(last - first, 0))
    inside = 0
    if last > first:
        model = scans.model
        inside = _obstacle_depths(scans.endpoints, scans.sensor_poses, scans.extents, scan,
                                  model.angle_min, model.angle_increment, scans.full_circle,
                                  reference.obstacles, first, last, rows, depths)
    return GridPointDistances(endpoint_depth=depth, endpoint_cells=cell_values,
                              obstacle_rows=rows[:inside], obstacle_depth=depths[:inside])
