"""A fixed reference map as a trinary occupancy grid (what nav2's map_server publishes).

Cell (row, col) is the square [col, col + 1] x [row, row + 1] * resolution of the grid frame,
whose origin is the map's `origin` pose (the lower-left corner of cell (0, 0), as in
nav_msgs/OccupancyGrid's info.origin): row 0 is the lowest y, columns run along x. Cells are
UNKNOWN (-1), FREE (0) or OCCUPIED (100), the message's own values, so that a grid and a
message convert without a table.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.geometry import read_only

UNKNOWN = -1
FREE = 0
OCCUPIED = 100
CELL_VALUES = (UNKNOWN, FREE, OCCUPIED)


@dataclass(frozen=True)
class OccupancyGrid:
    """A trinary occupancy grid placed in the map frame.

    Fields: `cells (H, W) int8` of UNKNOWN / FREE / OCCUPIED, row 0 the lowest y;
    `resolution` metres per cell; `origin (3,)` the pose (x, y, yaw) of the lower-left corner
    of cell (0, 0) in the map frame. Raises ValueError for cells that are not a non-empty 2-D
    array of those three values, a resolution that is not a positive finite number, or an
    origin that is not three finite numbers. Arrays are read-only.
    """

    cells: np.ndarray
    resolution: float
    origin: np.ndarray

    def __post_init__(self) -> None:
        cells = np.asarray(self.cells)
        if cells.ndim != 2 or cells.size == 0:
            raise ValueError(f'cells must be a non-empty (H, W) array, got shape {cells.shape}')
        known = np.isin(cells, CELL_VALUES)
        if not known.all():
            row, col = np.argwhere(~known)[0]
            raise ValueError(f'cell ({row}, {col}) is {cells[row, col].item()!r}: cells must be '
                             f'{UNKNOWN} (unknown), {FREE} (free) or {OCCUPIED} (occupied)')
        resolution = float(self.resolution)
        if not (math.isfinite(resolution) and resolution > 0.0):
            raise ValueError(f'resolution must be a positive finite number, got {resolution}')
        origin = np.asarray(self.origin, dtype=np.float64).reshape(-1)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f'origin must be three finite numbers (x, y, yaw), '
                             f'got {self.origin!r}')
        object.__setattr__(self, 'cells', read_only(np.ascontiguousarray(cells, np.int8)))
        object.__setattr__(self, 'resolution', resolution)
        object.__setattr__(self, 'origin', read_only(origin.copy()))

    @property
    def height(self) -> int:
        """H, the rows (along the grid's y)."""
        return int(self.cells.shape[0])

    @property
    def width(self) -> int:
        """W, the columns (along the grid's x)."""
        return int(self.cells.shape[1])

    def to_grid_frame(self, points: np.ndarray) -> np.ndarray:
        """Map-frame points in the grid frame, in cells (x / resolution, y / resolution).

        Parameters
        ----------
        points: (..., 2) map-frame points in metres.

        Returns
        -------
        (..., 2) coordinates in cell units: the floor of one is the (col, row) of the cell
        holding the point.
        """
        points = np.asarray(points, dtype=np.float64)
        x, y, yaw = self.origin
        dx, dy = points[..., 0] - x, points[..., 1] - y
        cos, sin = math.cos(yaw), math.sin(yaw)
        return np.stack([cos * dx + sin * dy, -sin * dx + cos * dy], axis=-1) / self.resolution

    def cell_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cell holding each point (on the grid or not).

        Parameters
        ----------
        points: (..., 2) map-frame points in metres.

        Returns
        -------
        (rows, cols), int64 arrays of shape (...); they may lie outside [0, H) x [0, W).
        """
        grid = np.floor(self.to_grid_frame(points))
        return grid[..., 1].astype(np.int64), grid[..., 0].astype(np.int64)

    def contains(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Whether cells lie on the grid.

        Parameters
        ----------
        rows, cols: integer arrays of one shape.

        Returns
        -------
        Boolean array of that shape.
        """
        rows, cols = np.asarray(rows), np.asarray(cols)
        return (rows >= 0) & (rows < self.height) & (cols >= 0) & (cols < self.width)

    def values_at(self, points: np.ndarray) -> np.ndarray:
        """The cell value under each point; UNKNOWN off the grid (nothing is known there).

        Parameters
        ----------
        points: (..., 2) map-frame points in metres.

        Returns
        -------
        int8 array of shape (...).
        """
        rows, cols = self.cell_of(points)
        on = self.contains(rows, cols)
        values = np.full(rows.shape, UNKNOWN, dtype=np.int8)
        values[on] = self.cells[rows[on], cols[on]]
        return values

    def cell_centres(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Map-frame centres of cells.

        Parameters
        ----------
        rows, cols: integer arrays of one shape (cells on the grid or beyond it).

        Returns
        -------
        (..., 2) centres in metres.
        """
        gx = (np.asarray(cols, dtype=np.float64) + 0.5) * self.resolution
        gy = (np.asarray(rows, dtype=np.float64) + 0.5) * self.resolution
        x, y, yaw = self.origin
        cos, sin = math.cos(yaw), math.sin(yaw)
        return np.stack([x + cos * gx - sin * gy, y + sin * gx + cos * gy], axis=-1)

    def occupied_centres(self) -> np.ndarray:
        """Centres of the occupied cells, row by row from the lowest.

        Returns
        -------
        (M, 2) map-frame centres in metres.
        """
        rows, cols = np.nonzero(self.cells == OCCUPIED)
        return self.cell_centres(rows, cols)

    def counts(self) -> dict[str, int]:
        """How many cells are unknown, free and occupied.

        Returns
        -------
        {'unknown': ..., 'free': ..., 'occupied': ...}.
        """
        return {name: int(np.count_nonzero(self.cells == value))
                for name, value in (('unknown', UNKNOWN), ('free', FREE),
                                    ('occupied', OCCUPIED))}


def trinary_cells(occupancy: np.ndarray, occupied_thresh: float,
                  free_thresh: float) -> np.ndarray:
    """Occupancy probabilities to trinary cells, by map_server's comparison.

    A cell is OCCUPIED when p > occupied_thresh, FREE when p < free_thresh, UNKNOWN otherwise
    (between the thresholds, on either, or NaN: nothing is known there).

    Parameters
    ----------
    occupancy: array of probabilities in [0, 1]; NaN for cells without one.
    occupied_thresh, free_thresh: the thresholds, 0 <= free_thresh <= occupied_thresh <= 1.

    Returns
    -------
    int8 array of UNKNOWN / FREE / OCCUPIED of the same shape. Raises ValueError for
    thresholds out of that order or range.
    """
    if not 0.0 <= free_thresh <= occupied_thresh <= 1.0:
        raise ValueError(f'need 0 <= free_thresh ({free_thresh}) <= occupied_thresh '
                         f'({occupied_thresh}) <= 1')
    occupancy = np.asarray(occupancy, dtype=np.float64)
    cells = np.full(occupancy.shape, UNKNOWN, dtype=np.int8)
    with np.errstate(invalid='ignore'):  # NaN compares False both ways: unknown
        cells[occupancy > occupied_thresh] = OCCUPIED
        cells[occupancy < free_thresh] = FREE
    return cells
