"""A coarse search for a submap's correction on the map: where the registration starts.

Point-to-line ICP converges to the correction only from within its coarsest gate; a
localizer kidnapped by a metre and ten degrees puts a submap's far end points two metres
off, and ICP from zero then settles on a wrong wall. The search scores every correction on a
grid (rotations about the submap's centre, then shifts) by the mean distance of the submap's
end points to the map's nearest occupied cell (a likelihood field, capped: an end point
where the map has nothing costs the cap, not more), and the best one seeds the ICP.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from map_consistency_ros.core.localization._grid import OCCUPIED, OccupancyGrid

FIELD_CAP = 0.5  # metres: an end point further from any obstacle costs this


@dataclass(frozen=True)
class DistanceField:
    """Per cell, the distance (metres) from its centre to the nearest occupied cell's centre,
    capped at FIELD_CAP; the grid it belongs to."""

    grid: OccupancyGrid
    distance: np.ndarray

    @classmethod
    def of(cls, grid: OccupancyGrid) -> DistanceField:
        """The distance field of a map.

        Parameters
        ----------
        grid: the map.

        Returns
        -------
        The DistanceField.
        """
        from scipy.ndimage import distance_transform_edt
        occupied = grid.cells == OCCUPIED
        if occupied.any():
            distance = distance_transform_edt(~occupied) * grid.resolution
        else:
            distance = np.full(grid.cells.shape, FIELD_CAP)
        return cls(grid=grid, distance=np.minimum(distance, FIELD_CAP))

    def cost(self, points: np.ndarray) -> np.ndarray:
        """The capped distance of points to the map's obstacles.

        Parameters
        ----------
        points: (..., 2) map-frame points, metres.

        Returns
        -------
        (...) metres, FIELD_CAP off the grid.
        """
        cells = np.floor(self.grid.to_grid_frame(points)).astype(np.int64)
        cols, rows = cells[..., 0], cells[..., 1]
        height, width = self.distance.shape
        inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
        out = np.full(rows.shape, FIELD_CAP)
        out[inside] = self.distance[rows[inside], cols[inside]]
        return out


def coarse_correction(field: DistanceField, points: np.ndarray, centre: np.ndarray,
                      max_translation: float, max_rotation: float, translation_step: float,
                      rotation_step: float) -> tuple[np.ndarray, float, float]:
    """The best correction on a grid of rotations about `centre` and shifts.

    Parameters
    ----------
    field: the map's distance field.
    points: (M, 2) the submap's end points, metres (a few hundred: thin them first).
    centre: (2,) the centre of the rotations, metres.
    max_translation, max_rotation: the grid's half extents, metres and radians.
    translation_step, rotation_step: its spacing, metres and radians.

    Returns
    -------
    (transform (3,), cost, cost_at_zero): the world transform (x, y, theta), p -> R p + t,
    of the best correction, its mean capped distance and that of no correction.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    zero_cost = float(field.cost(points).mean()) if points.size else FIELD_CAP
    if points.shape[0] == 0:
        return np.zeros(3), zero_cost, zero_cost
    shifts = np.arange(-max_translation, max_translation + 1e-9, translation_step)
    angles = np.arange(-max_rotation, max_rotation + 1e-12, rotation_step)
    # the search in cell units of the grid frame: a shift of the map frame turns with its yaw
    local = field.grid.to_grid_frame(points)
    pivot = field.grid.to_grid_frame(np.asarray(centre, dtype=np.float64))
    yaw = field.grid.origin[2]
    grid_shifts = np.stack([np.cos(yaw) * shifts, np.sin(yaw) * shifts], axis=1) / (
        field.grid.resolution)
    grid_normals = np.stack([-np.sin(yaw) * shifts, np.cos(yaw) * shifts], axis=1) / (
        field.grid.resolution)
    angle, along, across, cost = _search(np.ascontiguousarray(local), pivot[0], pivot[1],
                                         angles, grid_shifts, grid_normals, field.distance,
                                         FIELD_CAP)
    if not cost < zero_cost:
        return np.zeros(3), zero_cost, zero_cost
    cos, sin = np.cos(angles[angle]), np.sin(angles[angle])
    tx, ty = shifts[along], shifts[across]
    # p -> R (p - c) + c + s  ==  R p + (c - R c + s), in the map frame
    x = centre[0] - (cos * centre[0] - sin * centre[1]) + tx
    y = centre[1] - (sin * centre[0] + cos * centre[1]) + ty
    return np.array([x, y, angles[angle]]), float(cost), zero_cost


@numba.njit(cache=True)
def _search(points: np.ndarray, cx: float, cy: float, angles: np.ndarray, along: np.ndarray,
            across: np.ndarray, distance: np.ndarray, cap: float) -> tuple:
    """The (angle, x shift, y shift) indices of the least mean capped distance, and it. Points
    and the pivot in cell units of the grid frame; a map-frame shift (x, y) is
    along[x] + across[y] there."""
    height, width = distance.shape
    best, best_cost = (0, 0, 0), np.inf
    count = points.shape[0]
    for a in range(angles.size):
        cos, sin = math.cos(angles[a]), math.sin(angles[a])
        # a map-frame rotation is the same rotation in the grid frame (the yaw only offsets)
        turned = np.empty((count, 2))
        for k in range(count):
            ox, oy = points[k, 0] - cx, points[k, 1] - cy
            turned[k, 0] = cos * ox - sin * oy + cx
            turned[k, 1] = sin * ox + cos * oy + cy
        for i in range(along.shape[0]):
            for j in range(across.shape[0]):
                dx = along[i, 0] + across[j, 0]
                dy = along[i, 1] + across[j, 1]
                total = 0.0
                for k in range(count):
                    col = int(math.floor(turned[k, 0] + dx))
                    row = int(math.floor(turned[k, 1] + dy))
                    if 0 <= row < height and 0 <= col < width:
                        total += distance[row, col]
                    else:
                        total += cap
                    if total >= best_cost * count:
                        break
                cost = total / count
                if cost < best_cost:
                    best, best_cost = (a, i, j), cost
    return best[0], best[1], best[2], best_cost
