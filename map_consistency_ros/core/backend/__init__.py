"""The back-end: the SE(2) pose graph (vertices, edges with information matrices, the
constraint row format the node and bags carry; no files), sparse Levenberg-Marquardt with
Dynamic Covariance Scaling, and the paper's Phi search (M(Phi) over a grid of sqrt(Phi), then
golden-section refinement) that tunes DCS so the map becomes consistent. Built on geometry and
the paper's test."""
from map_consistency_ros.core.backend._dcs import (OptimizationResult, SparseSystem, dcs_scales,
                                                   edge_residuals, optimize, robust_cost)
from map_consistency_ros.core.backend._posegraph import (CONSTRAINT_FIELDS, CONSTRAINT_WIDTH,
                                                         MAX_INFORMATION, MAX_POSE_EXTENT,
                                                         PoseGraph, check_constraint_rows,
                                                         constraint_rows, edge_problem,
                                                         information_from_upper,
                                                         information_problem,
                                                         information_upper,
                                                         split_constraint_rows, tuning_problem)
from map_consistency_ros.core.backend._tuning import (Evaluation, InconsistencyProfile,
                                                      MeasuredPairs, TuningResult,
                                                      TuningSettings, measure_moved, profile_shape,
                                                      search_findings, tune_dcs)

__all__ = [
    'PoseGraph', 'information_upper', 'information_from_upper', 'information_problem',
    'tuning_problem', 'edge_problem', 'MAX_INFORMATION', 'MAX_POSE_EXTENT',
    'CONSTRAINT_FIELDS', 'CONSTRAINT_WIDTH', 'constraint_rows', 'split_constraint_rows',
    'check_constraint_rows',
    'OptimizationResult', 'SparseSystem', 'optimize', 'dcs_scales', 'robust_cost',
    'edge_residuals',
    'TuningSettings', 'Evaluation', 'TuningResult', 'InconsistencyProfile', 'tune_dcs',
    'search_findings',
    'profile_shape',
    'MeasuredPairs', 'measure_moved',
]
