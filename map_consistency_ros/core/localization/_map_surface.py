"""The map as a reference surface for registration: occupied cell centres with normals.

Registration (core/verdict/_registration.py) matches query end points to reference points
along the reference's surface normals. A map has no beams to take normals from; each
occupied cell takes the normal of the line fitted to the occupied cells around it (the
principal axes of their centres within `SURFACE_REACH` cells): a wall's cells lie along a
line, and its normal is the direction of least spread. Cells whose neighbourhood is no line
(a lone cell, a blob, a corner's tip) keep a zero normal and are never matched.
"""
from __future__ import annotations


import numpy as np

from map_consistency_ros.core.localization._grid import OCCUPIED, OccupancyGrid

SURFACE_REACH = 2  # cells on each side: a 5 x 5 neighbourhood, 0.25 m at 0.05 m cells
# the least spread must stay below this share of the largest for the cells to form a line
LINE_RATIO = 0.3
MIN_NEIGHBOURS = 3  # the cell and at least two more


def map_surface(grid: OccupancyGrid) -> tuple[np.ndarray, np.ndarray]:
    """The occupied cells' centres and the normals of the lines through their neighbours.

    Parameters
    ----------
    grid: the reference map.

    Returns
    -------
    (points (M, 2), normals (M, 2)): map-frame centres of the M occupied cells (row by row
    from the lowest, as OccupancyGrid.occupied_centres) and unit normals in the map frame,
    zero where the neighbourhood is no line.
    """
    from scipy.ndimage import correlate
    occupied = (grid.cells == OCCUPIED).astype(np.float64)
    offsets = np.arange(-SURFACE_REACH, SURFACE_REACH + 1, dtype=np.float64)
    dy, dx = np.meshgrid(offsets, offsets, indexing='ij')  # rows are y, columns x

    def total(kernel: np.ndarray) -> np.ndarray:
        return correlate(occupied, kernel, mode='constant', cval=0.0)

    count = total(np.ones_like(dx))
    sum_x, sum_y = total(dx), total(dy)
    sum_xx, sum_xy, sum_yy = total(dx * dx), total(dx * dy), total(dy * dy)
    rows, cols = np.nonzero(occupied)
    n = count[rows, cols]
    mean_x, mean_y = sum_x[rows, cols] / n, sum_y[rows, cols] / n
    cxx = sum_xx[rows, cols] / n - mean_x * mean_x
    cxy = sum_xy[rows, cols] / n - mean_x * mean_y
    cyy = sum_yy[rows, cols] / n - mean_y * mean_y
    half_trace, spread = 0.5 * (cxx + cyy), np.hypot(0.5 * (cxx - cyy), cxy)
    largest, least = half_trace + spread, half_trace - spread
    along = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy) + grid.origin[2]  # the line's direction
    line = (n >= MIN_NEIGHBOURS) & (largest > 0.0) & (least < LINE_RATIO * largest)
    normals = np.zeros((rows.size, 2))
    normals[line, 0] = -np.sin(along[line])
    normals[line, 1] = np.cos(along[line])
    return grid.cell_centres(rows, cols), normals

