"""The paper's test (Mazuran et al., ICRA 2014): the half-normal statistics, Psi and the
binomial critical counts (`statistics`), local scales from the incremental solution, the
pairwise one-sided tests and the cascaded binomial test per scan (check_consistency,
evaluate_pairs for callers that cache the measures), and the Haehnel et al. 2003
scan-matching baseline the paper compares against. Built on geometry only."""
from map_consistency_ros.core.consistency import statistics
from map_consistency_ros.core.consistency._baseline import (FREE, OCCUPIED, UNKNOWN,
                                                            BaselineParameters, LocalGrids,
                                                            PairLikelihoods, local_grids,
                                                            map_statistic, pair_log_likelihoods,
                                                            traverse_cells)
from map_consistency_ros.core.consistency._check import (ConsistencyParameters,
                                                         ConsistencyResult, NO_BOUND,
                                                         Progress, add_local_bounds,
                                                         average_inconsistency,
                                                         check_consistency, evaluate_pairs,
                                                         inconsistent_endpoints, local_pairs,
                                                         local_scales, pair_endpoints,
                                                         robust_statistic, robust_sums,
                                                         scales_from_bounds, select_viewpoints)

__all__ = [
    'statistics',
    'ConsistencyParameters', 'ConsistencyResult', 'Progress', 'check_consistency',
    'evaluate_pairs', 'select_viewpoints', 'local_pairs', 'local_scales', 'robust_sums',
    'NO_BOUND', 'add_local_bounds', 'scales_from_bounds',
    'robust_statistic', 'average_inconsistency', 'inconsistent_endpoints', 'pair_endpoints',
    'BaselineParameters', 'LocalGrids', 'PairLikelihoods', 'local_grids', 'pair_log_likelihoods',
    'map_statistic', 'traverse_cells', 'UNKNOWN', 'FREE', 'OCCUPIED',
]
