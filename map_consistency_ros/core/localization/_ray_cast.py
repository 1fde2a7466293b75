"""Ray casting scans into an occupancy grid: a map from a mapping run's scans at their poses.

Each valid beam (a real return within the usable range) is traced cell by cell (Amanatides &
Woo): the cells it crosses count a miss, the cell of its end point a hit; beams without a
return clear nothing (their length is unknown). A cell is occupied when hits / (hits +
misses) > OCCUPIED_RATIO (gmapping's occ_thresh), free when reached and not occupied, unknown
when no beam reached it. The reference of `map-consistency localize` when it is a mapping
run, and the generator's maps (evaluation/localization_data.py).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from map_consistency_ros.core.geometry import ScanSet
from map_consistency_ros.core.localization._grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

# gmapping's occ_thresh: a cell is occupied when more than this share of the beams that
# reached it ended there
OCCUPIED_RATIO = 0.25


@numba.njit(cache=True)
def _traverse(sx: float, sy: float, ex: float, ey: float, rows: np.ndarray,
              cols: np.ndarray) -> int:
    """The cells from (sx, sy) to (ex, ey) (grid units) in order, the end point's last
    (Amanatides & Woo); returns how many were written to rows / cols."""
    col, row = math.floor(sx), math.floor(sy)
    end_col, end_row = math.floor(ex), math.floor(ey)
    dx, dy = ex - sx, ey - sy
    step_col = 1 if dx > 0 else -1
    step_row = 1 if dy > 0 else -1
    delta_x = abs(1.0 / dx) if dx != 0 else np.inf
    delta_y = abs(1.0 / dy) if dy != 0 else np.inf
    next_x = ((col + 1 - sx) if dx > 0 else (sx - col)) * delta_x if dx != 0 else np.inf
    next_y = ((row + 1 - sy) if dy > 0 else (sy - row)) * delta_y if dy != 0 else np.inf
    steps = min(abs(end_col - col) + abs(end_row - row), rows.shape[0] - 1)
    for index in range(steps):
        rows[index], cols[index] = row, col
        if next_x < next_y:
            col += step_col
            next_x += delta_x
        else:
            row += step_row
            next_y += delta_y
    rows[steps], cols[steps] = end_row, end_col
    return steps + 1


@numba.njit(cache=True)
def _cast(starts: np.ndarray, ends: np.ndarray, valid: np.ndarray, hits: np.ndarray,
          misses: np.ndarray, buffer: int) -> None:
    height, width = hits.shape
    rows, cols = np.empty(buffer, np.int64), np.empty(buffer, np.int64)
    for scan in range(ends.shape[0]):
        for beam in range(ends.shape[1]):
            if not valid[scan, beam]:
                continue
            count = _traverse(starts[scan, 0], starts[scan, 1], ends[scan, beam, 0],
                              ends[scan, beam, 1], rows, cols)
            for index in range(count):
                row, col = rows[index], cols[index]
                if 0 <= row < height and 0 <= col < width:
                    if index == count - 1:
                        hits[row, col] += 1
                    else:
                        misses[row, col] += 1


@numba.njit(cache=True)
def _crossings(starts: np.ndarray, ends: np.ndarray, valid: np.ndarray, mask: np.ndarray,
               buffer: int) -> np.ndarray:
    """Per scan, the valid beams that cross a masked cell before their end point's cell."""
    height, width = mask.shape
    rows, cols = np.empty(buffer, np.int64), np.empty(buffer, np.int64)
    counts = np.zeros(ends.shape[0], np.int64)
    for scan in range(ends.shape[0]):
        for beam in range(ends.shape[1]):
            if not valid[scan, beam]:
                continue
            count = _traverse(starts[scan, 0], starts[scan, 1], ends[scan, beam, 0],
                              ends[scan, beam, 1], rows, cols)
            for index in range(count - 1):
                row, col = rows[index], cols[index]
                if 0 <= row < height and 0 <= col < width and mask[row, col]:
                    counts[scan] += 1
                    break
    return counts


def _grid_units(scans: ScanSet, origin: np.ndarray, resolution: float):
    starts = (scans.sensor_poses[:, :2] - origin[:2]) / resolution
    ends = (scans.endpoints - origin[:2]) / resolution
    lengths = np.where(scans.valid, scans.ranges, 0.0)
    buffer = int(2 * math.ceil(lengths.max(initial=0.0) / resolution)) + 4
    return np.ascontiguousarray(starts), np.ascontiguousarray(ends), buffer


def ray_cast_grid(scans: ScanSet, resolution: float = 0.05,
                  margin: float = 1.0) -> tuple[OccupancyGrid, np.ndarray, np.ndarray]:
    """The occupancy grid of scans at their poses, by hit and miss counts.

    Parameters
    ----------
    scans: the scans at their (true) poses; only valid beams are cast.
    resolution: metres per cell.
    margin: metres of grid beyond the scans' extents, all sides.

    Returns
    -------
    (grid, hits (H, W), misses (H, W)): the grid's origin is a multiple of the resolution with
    yaw 0; a cell is OCCUPIED when hits / (hits + misses) > OCCUPIED_RATIO, FREE when reached
    and not occupied, UNKNOWN when no beam reached it.
    """
    low = np.floor((scans.extents[:, :2].min(axis=0) - margin) / resolution) * resolution
    high = scans.extents[:, 2:].max(axis=0) + margin
    width, height = (np.ceil((high - low) / resolution)).astype(int)
    origin = np.array([low[0], low[1], 0.0])
    hits = np.zeros((height, width), np.int64)
    misses = np.zeros((height, width), np.int64)
    starts, ends, buffer = _grid_units(scans, origin, resolution)
    _cast(starts, ends, scans.valid, hits, misses, buffer)
    cells = np.full((height, width), UNKNOWN, np.int8)
    reached = hits + misses > 0
    cells[reached] = FREE
    with np.errstate(invalid='ignore', divide='ignore'):
        cells[reached & (hits / (hits + misses) > OCCUPIED_RATIO)] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=resolution, origin=origin), hits, misses


def beams_crossing(scans: ScanSet, grid: OccupancyGrid, mask: np.ndarray) -> np.ndarray:
    """Per scan, how many valid beams cross a masked cell before their end (labels of maps
    made out of date).

    Parameters
    ----------
    scans: the scans at their true poses.
    grid: the grid the mask belongs to (yaw 0, as ray_cast_grid makes them).
    mask: (H, W) bool, the cells of interest.

    Returns
    -------
    (N,) counts.
    """
    starts, ends, buffer = _grid_units(scans, grid.origin, grid.resolution)
    return _crossings(starts, ends, scans.valid, np.ascontiguousarray(mask, bool), buffer)
