"""Hähnel et al. (ISRR 2003) scan-matching log-likelihood: the baseline of Mazuran et al.

Each scan builds a local occupancy grid in its own sensor frame: the cells its beams cross
are free, the cell of each valid end point is occupied, the rest is unknown. The other scan
of an overlapping pair is superimposed on that grid and scored with the ray model of
Hähnel's scan matcher: every known cell a beam crosses before its end point contributes
log(1 - p), the cell it ends in contributes log(p), where p is the occupancy probability of
the cell (`occupied_probability` or `free_probability`). Two discretisation allowances keep
a well-aligned pair from being penalised for the grid alone: an end point counts as a hit
when any cell of its 3 x 3 neighbourhood is occupied, and crossed cells next to the end
point cell are not scored.

The pair's statistic is its mean log-likelihood per scored cell, both directions pooled
(the scan i on the grid of j and j on the grid of i). The map's statistic is the minimum
(or a low quantile) of that over pairs with enough scored cells; the map is inconsistent
when it falls below a threshold.
"""
from dataclasses import dataclass

import numba
import numpy as np

from map_consistency_ros.core.geometry import ScanSet

UNKNOWN, FREE, OCCUPIED = 0, 1, 2


@dataclass(frozen=True)
class BaselineParameters:
    """Grid resolution and sensor model of the baseline.

    `min_events`: pairs with fewer scored cells than this are treated as not overlapping.
    `quantile`: the map statistic is this quantile of the per-pair statistics (0 = minimum).
    """

    cell_size: float = 0.1
    occupied_probability: float = 0.9
    free_probability: float = 0.1
    min_events: int = 20
    quantile: float = 0.0

    def __post_init__(self) -> None:
        if not self.cell_size > 0.0:
            raise ValueError(f'cell_size must be positive, got {self.cell_size}')
        if not 0.0 < self.free_probability < self.occupied_probability < 1.0:
            raise ValueError('need 0 < free_probability < occupied_probability < 1, got '
                             f'{self.free_probability} and {self.occupied_probability}')
        if self.min_events < 1:
            raise ValueError(f'min_events must be at least 1, got {self.min_events}')
        if not 0.0 <= self.quantile <= 1.0:
            raise ValueError(f'quantile must lie in [0, 1], got {self.quantile}')


@dataclass(frozen=True)
class LocalGrids:
    """One occupancy grid per scan, in the scan's sensor frame, sensor at the centre cell.

    `cells (N, G, G) int8` holds UNKNOWN / FREE / OCCUPIED indexed [scan, x cell, y cell];
    cell (c, c) with c = G // 2 is centred on the sensor.
    """

    cells: np.ndarray
    cell_size: float


@dataclass(frozen=True)
class PairLikelihoods:
    """Per-pair log-likelihood sums and the number of scored cells, both directions pooled."""

    pairs: np.ndarray
    log_likelihood: np.ndarray
    event_count: np.ndarray

    def normalised(self) -> np.ndarray:
        """Mean log-likelihood per scored cell.

        Returns
        -------
        (P,) log_likelihood / event_count, -inf where nothing was scored.
        """
        return np.where(self.event_count > 0,
                        self.log_likelihood / np.maximum(self.event_count, 1), -np.inf)


@numba.njit(cache=True)
def _axis_start(cell: int, start: float, delta: float) -> tuple[int, float, float]:
    """Step direction, parameter t of the first cell border, t between borders along an axis."""
    if delta == 0.0:
        return 1, np.inf, np.inf
    if delta > 0.0:
        return 1, (cell + 1 - start) / delta, 1.0 / delta
    return -1, (start - cell) / -delta, -1.0 / delta


@numba.njit(cache=True)
def traverse_cells(x0: float, y0: float, x1: float, y1: float, out: np.ndarray) -> int:
    """Cells (in cell units) crossed by the segment, in order, ending at the end point's cell.

    Amanatides-Woo traversal: a 4-connected walk visits exactly |dx cells| + |dy cells| + 1
    cells, which bounds the loop even when rounding misses the end cell.

    Parameters
    ----------
    x0, y0: the start of the segment in cell units (cell (c, c) spans [c, c + 1)).
    x1, y1: its end, in cell units.
    out: (L, 2) int64 buffer with L at least the cell count; rows [0, count) receive the
        cells (x, y).

    Returns
    -------
    count, the number of cells written; the last is the end point's cell.
    """
    cx, cy = int(np.floor(x0)), int(np.floor(y0))
    ex, ey = int(np.floor(x1)), int(np.floor(y1))
    step_x, t_max_x, t_delta_x = _axis_start(cx, x0, x1 - x0)
    step_y, t_max_y, t_delta_y = _axis_start(cy, y0, y1 - y0)
    count = abs(ex - cx) + abs(ey - cy) + 1
    for n in range(count):
        out[n, 0] = cx
        out[n, 1] = cy
        # never step past the end cell's column or row, whatever rounding says
        if (t_max_x < t_max_y and cx != ex) or cy == ey:
            cx += step_x
            t_max_x += t_delta_x
        else:
            cy += step_y
            t_max_y += t_delta_y
    out[count - 1, 0] = ex
    out[count - 1, 1] = ey
    return count


@numba.njit(cache=True, parallel=True)
def _build_grids(ranges: np.ndarray, valid: np.ndarray, bearings: np.ndarray,
                 size: int, cell_size: float) -> np.ndarray:
    scan_count, beam_count = ranges.shape
    grids = np.zeros((scan_count, size, size), dtype=np.int8)
    centre = size // 2 + 0.5
    for s in numba.prange(scan_count):
        cells = np.empty((2 * size + 4, 2), dtype=np.int64)
        for k in range(beam_count):
            x1 = centre + ranges[s, k] * np.cos(bearings[k]) / cell_size
            y1 = centre + ranges[s, k] * np.sin(bearings[k]) / cell_size
            count = traverse_cells(centre, centre, x1, y1, cells)
            # the end point cell is not free space: the beam stopped in it
            last = count - 1 if valid[s, k] else count
            for n in range(last):
                cx, cy = cells[n, 0], cells[n, 1]
                if 0 <= cx < size and 0 <= cy < size and grids[s, cx, cy] == UNKNOWN:
                    grids[s, cx, cy] = FREE
        # occupied wins over free whatever the beam order
        for k in range(beam_count):
            if valid[s, k]:
                cx = int(np.floor(centre + ranges[s, k] * np.cos(bearings[k]) / cell_size))
                cy = int(np.floor(centre + ranges[s, k] * np.sin(bearings[k]) / cell_size))
                if 0 <= cx < size and 0 <= cy < size:
                    grids[s, cx, cy] = OCCUPIED
    return grids


@numba.njit(cache=True)
def _end_label(grid: np.ndarray, cx: int, cy: int) -> int:
    size = grid.shape[0]
    own = UNKNOWN
    if 0 <= cx < size and 0 <= cy < size:
        own = grid[cx, cy]
    for ix in range(max(cx - 1, 0), min(cx + 2, size)):
        for iy in range(max(cy - 1, 0), min(cy + 2, size)):
            if grid[ix, iy] == OCCUPIED:
                return OCCUPIED
    return own


@numba.njit(cache=True)
def _score_on_grid(grid: np.ndarray, cell_size: float, grid_pose: np.ndarray,
                   sensor_pose: np.ndarray, ranges: np.ndarray, valid: np.ndarray,
                   bearings: np.ndarray, log_p: np.ndarray, log_not_p: np.ndarray,
                   cells: np.ndarray) -> tuple[float, int]:
    """Log-likelihood of one scan's beams on another scan's grid, and the scored cells."""
    size = grid.shape[0]
    centre = size // 2 + 0.5
    # the scan's sensor pose in the grid's frame, in cell units
    cos_g, sin_g = np.cos(grid_pose[2]), np.sin(grid_pose[2])
    dx, dy = sensor_pose[0] - grid_pose[0], sensor_pose[1] - grid_pose[1]
    sx = (cos_g * dx + sin_g * dy) / cell_size + centre
    sy = (-sin_g * dx + cos_g * dy) / cell_size + centre
    heading = sensor_pose[2] - grid_pose[2]
    total = 0.0
    events = 0
    for k in range(ranges.shape[0]):
        reach = ranges[k] / cell_size
        count = traverse_cells(sx, sy, sx + reach * np.cos(heading + bearings[k]),
                               sy + reach * np.sin(heading + bearings[k]), cells)
        ex, ey = cells[count - 1, 0], cells[count - 1, 1]
        for n in range(count - 1):
            cx, cy = cells[n, 0], cells[n, 1]
            if max(abs(cx - ex), abs(cy - ey)) <= 1:
                continue
            if 0 <= cx < size and 0 <= cy < size and grid[cx, cy] != UNKNOWN:
                total += log_not_p[grid[cx, cy]]
                events += 1
        if valid[k]:
            label = _end_label(grid, ex, ey)
            if label != UNKNOWN:
                total += log_p[label]
                events += 1
    return total, events


@numba.njit(cache=True, parallel=True)
def _pair_kernel(grids: np.ndarray, cell_size: float, poses: np.ndarray, ranges: np.ndarray,
                 valid: np.ndarray, bearings: np.ndarray, pairs: np.ndarray,
                 log_p: np.ndarray, log_not_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pair_count = pairs.shape[0]
    sums = np.zeros(pair_count)
    counts = np.zeros(pair_count, dtype=np.int64)
    # beams may be longer than the grid is wide (the other scan's max range)
    buffer_size = 2 * int(np.ceil(np.max(ranges) / cell_size)) + 2 * grids.shape[1] + 8
    for p in numba.prange(pair_count):
        cells = np.empty((buffer_size, 2), dtype=np.int64)
        i, j = pairs[p, 0], pairs[p, 1]
        forward, n_forward = _score_on_grid(grids[j], cell_size, poses[j], poses[i], ranges[i],
                                            valid[i], bearings, log_p, log_not_p, cells)
        backward, n_backward = _score_on_grid(grids[i], cell_size, poses[i], poses[j],
                                              ranges[j], valid[j], bearings, log_p, log_not_p,
                                              cells)
        sums[p] = forward + backward
        counts[p] = n_forward + n_backward
    return sums, counts


def local_grids(scans: ScanSet, parameters: BaselineParameters) -> LocalGrids:
    """The occupancy grid of every scan, just wide enough for its longest beam.

    Parameters
    ----------
    scans: the N scans (only their ranges, valid beams and model are used).
    parameters: the baseline's parameters (cell_size).

    Returns
    -------
    The LocalGrids of the N scans, G = 2 ceil(longest range / cell_size) + 3 cells wide.
    """
    reach = float(np.max(scans.ranges)) if scans.ranges.size else 0.0
    size = 2 * int(np.ceil(reach / parameters.cell_size)) + 3
    cells = _build_grids(scans.ranges, scans.valid, scans.model.bearings(scans.ranges.shape[1]),
                         size, parameters.cell_size)
    return LocalGrids(cells=cells, cell_size=parameters.cell_size)


def pair_log_likelihoods(scans: ScanSet, pairs: np.ndarray, parameters: BaselineParameters,
                         grids: LocalGrids | None = None) -> PairLikelihoods:
    """Score every pair (i, j): scan i on the grid of j plus scan j on the grid of i.

    Parameters
    ----------
    scans: the N scans placed in the world.
    pairs: (P, 2) rows (i, j) of `scans` (ValueError when out of range).
    parameters: the baseline's parameters.
    grids: the scans' grids from `local_grids`, when the same scans are scored repeatedly;
        None builds them. ValueError when built for other scans or another cell size.

    Returns
    -------
    The PairLikelihoods of the P pairs, in the given order.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if pairs.size and (pairs.min() < 0 or pairs.max() >= len(scans.ranges)):
        raise ValueError(f'pair indices must lie in [0, {len(scans.ranges)})')
    if grids is None:
        grids = local_grids(scans, parameters)
    elif grids.cell_size != parameters.cell_size or len(grids.cells) != len(scans.ranges):
        raise ValueError('grids were built for other scans or another cell size')
    p = np.array([0.5, parameters.free_probability, parameters.occupied_probability])
    sums, counts = _pair_kernel(grids.cells, grids.cell_size, scans.sensor_poses, scans.ranges,
                                scans.valid, scans.model.bearings(scans.ranges.shape[1]), pairs,
                                np.log(p), np.log1p(-p))
    return PairLikelihoods(pairs=pairs, log_likelihood=sums, event_count=counts)


def map_statistic(likelihoods: PairLikelihoods, parameters: BaselineParameters) -> float:
    """The map's log-likelihood statistic: a low quantile of the per-pair means.

    Parameters
    ----------
    likelihoods: the pairs' scores.
    parameters: the baseline's parameters (min_events, quantile).

    Returns
    -------
    The `quantile` quantile of the mean log-likelihoods of the pairs with at least `min_events`
    scored cells; +inf when there is none (nothing contradicts the map).
    """
    overlapping = likelihoods.event_count >= parameters.min_events
    if not np.any(overlapping):
        return float(np.inf)
    return float(np.quantile(likelihoods.normalised()[overlapping], parameters.quantile))
