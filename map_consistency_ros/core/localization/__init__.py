"""Localization mode: live scans judged against a fixed reference map (issue 49).

The reference as a trinary occupancy grid (OccupancyGrid, the nav2 map's cells), and the grid
side of the paper's measure: how deep live end points lie in the map's known free space and
how deep the map's obstacles lie in a live scan's visibility polygon, summed per scan into M
and n like the pairwise M_ij / n_ij so that the same statistics apply. Built on geometry (the
scans and the polygon kernel of the pairwise measure); knows nothing of ROS or files.
"""
from map_consistency_ros.core.localization._grid import (CELL_VALUES, FREE, OCCUPIED, UNKNOWN,
                                                         OccupancyGrid, trinary_cells)
from map_consistency_ros.core.localization._grid_measure import (GridMeasures,
                                                                 GridPointDistances,
                                                                 GridReference, grid_measures,
                                                                 grid_point_distances,
                                                                 prepare_reference)
from map_consistency_ros.core.localization._map_surface import map_surface
from map_consistency_ros.core.localization._ray_cast import (OCCUPIED_RATIO, beams_crossing,
                                                             ray_cast_grid)
from map_consistency_ros.core.localization._pipeline import (LOCALIZED, MISLOCALIZED,
                                                             NOTHING_TO_JUDGE, Episode,
                                                             LocalizationResult, MapChange,
                                                             MapSurface, Submaps, localize)
from map_consistency_ros.core.localization._scan_test import (ScanTests, WindowTests,
                                                              cascaded_test, judge_scans,
                                                              live_scales, measure_and_judge,
                                                              travel, window_starts)
from map_consistency_ros.core.localization._settings import LocalizationSettings

__all__ = [
    'OccupancyGrid', 'trinary_cells', 'UNKNOWN', 'FREE', 'OCCUPIED', 'CELL_VALUES',
    'GridReference', 'prepare_reference', 'GridMeasures', 'grid_measures',
    'GridPointDistances', 'grid_point_distances',
    'map_surface', 'LocalizationSettings', 'ray_cast_grid', 'beams_crossing', 'OCCUPIED_RATIO',
    'ScanTests', 'WindowTests', 'live_scales', 'judge_scans', 'measure_and_judge', 'travel',
    'window_starts', 'cascaded_test',
    'MapSurface', 'Episode', 'MapChange', 'Submaps', 'LocalizationResult', 'localize',
    'LOCALIZED', 'MISLOCALIZED', 'NOTHING_TO_JUDGE',
]
