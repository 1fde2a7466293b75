"""OccupancyGrid: its checks and its transforms between the map frame and cells."""
import math

import numpy as np
import pytest

from map_consistency_ros.core.localization import (FREE, OCCUPIED, UNKNOWN, OccupancyGrid,
                                                   trinary_cells)


def test_cells_centres_and_back_with_a_turned_origin():
    grid = OccupancyGrid(cells=np.zeros((4, 6), np.int8), resolution=0.5,
                         origin=[10.0, -2.0, math.pi / 2])
    # cell (row 1, col 2) spans grid x in [1, 1.5], y in [0.5, 1]: its centre (1.25, 0.75)
    # turned by 90 degrees is (-0.75, 1.25) from the origin
    assert np.allclose(grid.cell_centres(1, 2), [10.0 - 0.75, -2.0 + 1.25])
    rows, cols = np.meshgrid(np.arange(-1, 5), np.arange(-1, 7), indexing='ij')
    back = grid.cell_of(grid.cell_centres(rows, cols))
    assert np.array_equal(back[0], rows) and np.array_equal(back[1], cols)
    assert grid.contains(rows, cols).sum() == 24


def test_values_at_is_unknown_off_the_grid():
    cells = np.array([[FREE, OCCUPIED], [UNKNOWN, FREE]], np.int8)
    grid = OccupancyGrid(cells=cells, resolution=1.0, origin=[0, 0, 0])
    points = np.array([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5], [-0.1, 0.5], [0.5, 2.0]])
    assert grid.values_at(points).tolist() == [FREE, OCCUPIED, UNKNOWN, FREE, UNKNOWN, UNKNOWN]
    assert grid.counts() == {'unknown': 1, 'free': 2, 'occupied': 1}
    assert np.allclose(grid.occupied_centres(), [[1.5, 0.5]])
    assert not grid.cells.flags.writeable


@pytest.mark.parametrize('kwargs, word', [
    ({'cells': np.zeros((0, 3), np.int8)}, 'non-empty'),
    ({'cells': np.zeros(3, np.int8)}, 'non-empty'),
    ({'cells': np.array([[0, 50]])}, r'cell \(0, 1\) is 50:'),
    ({'resolution': 0.0}, 'resolution'),
    ({'resolution': float('inf')}, 'resolution'),
    ({'origin': [0, 0]}, 'origin'),
    ({'origin': [0, float('nan'), 0]}, 'origin'),
])
def test_bad_grids(kwargs, word):
    fields = {'cells': np.zeros((2, 2), np.int8), 'resolution': 0.05, 'origin': [0, 0, 0]}
    fields.update(kwargs)
    with pytest.raises(ValueError, match=word):
        OccupancyGrid(**fields)


def test_trinary_cells_compare_strictly_and_nan_is_unknown():
    occupancy = np.array([0.0, 0.195, 0.196, 0.5, 0.65, 0.651, 1.0, np.nan])
    assert trinary_cells(occupancy, 0.65, 0.196).tolist() == [
        FREE, FREE, UNKNOWN, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED, UNKNOWN]
    with pytest.raises(ValueError):
        trinary_cells(occupancy, 0.2, 0.3)
