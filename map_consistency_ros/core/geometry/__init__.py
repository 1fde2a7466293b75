"""Geometry: where the scans are and what they see. SE(2) on pose arrays (`se2`), scans placed
in the world as visibility polygons (SensorModel, ScanSet), the grid index of their extents that
finds the pairs that can overlap, the pairwise inconsistency measure M_ij / n_ij of the paper
(numba kernels), and viewpoints (the scans that see the world from a new place). Knows nothing
of the test, the verdict or where the scans came from."""
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.geometry._arrays import read_only, spans, true_runs, with_rows
from map_consistency_ros.core.geometry._measure import (PairMeasures, measure_pairs,
                                                        pair_measures, pair_measures_naive,
                                                        pairs_point_distances, point_distances)
from map_consistency_ros.core.geometry._scan_geometry import SCAN_ARRAYS, ScanSet, SensorModel
from map_consistency_ros.core.geometry._spatial_index import (ScanExtentIndex, candidate_pairs,
                                                              extents_overlap)
from map_consistency_ros.core.geometry._viewpoints import (SAME_HEADING, SAME_POSITION,
                                                         disagreement, disagreements,
                                                         is_new_viewpoint, same_pose,
                                                         viewpoint_rows)

__all__ = [
    'se2',
    'SensorModel', 'ScanSet', 'SCAN_ARRAYS',
    'candidate_pairs', 'extents_overlap', 'ScanExtentIndex',
    'PairMeasures', 'pair_measures', 'measure_pairs', 'pair_measures_naive', 'point_distances',
    'pairs_point_distances',
    'viewpoint_rows', 'is_new_viewpoint', 'disagreement', 'disagreements', 'same_pose',
    'SAME_POSITION', 'SAME_HEADING',
    'with_rows', 'read_only', 'spans', 'true_runs',
]
