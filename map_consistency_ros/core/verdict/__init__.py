"""The verdict's second stage and its report: robust point-to-line registration of submaps
(corrections with covariances), the explanation of every failed pair of the paper's test as
misalignment or change (regions, changed places, the safety net; Assessment, explain,
check_map), and the report dict and strict JSON that the CLI and the node share. Built on
geometry and the paper's test; `explanation` and `reporting` stay public modules, whose names
tests patch."""
from map_consistency_ros.core.verdict._registration import (RegistrationSettings, Registrations,
                                                            SurfacePoints, nearest_point,
                                                            point_grid, register_onto_points,
                                                            register_submaps,
                                                            surface_points, symmetric_inverse)
from map_consistency_ros.core.verdict._evidence import Evidence, evidence, flaggable_pair_count
from map_consistency_ros.core.verdict.explanation import (CHANGE, CONSISTENT, INCONSISTENT,
                                                          MINOR, MISALIGNED, NOTHING_TO_JUDGE,
                                                          PAIR_CLASSES, UNREGISTERED,
                                                          Assessment, PairClass, ChangedPlace,
                                                          ExplanationSettings, Misalignment,
                                                          PointMoments, RegistrationCache,
                                                          agreeing_registrations, check_map,
                                                          corrections_confirmed, explain,
                                                          longest_run, longest_travel,
                                                          misaligned_endpoints,
                                                          place_labels, regions_alike)
from map_consistency_ros.core.verdict.reporting import (assessment_report, joined_json, plain,
                                                        result_report, scan_names, to_json)

__all__ = [
    'RegistrationSettings', 'SurfacePoints', 'Registrations', 'surface_points',
    'register_submaps', 'register_onto_points',
    'ExplanationSettings', 'Misalignment', 'ChangedPlace', 'Assessment', 'RegistrationCache',
    'explain', 'check_map', 'misaligned_endpoints', 'regions_alike',
    'CONSISTENT', 'INCONSISTENT', 'NOTHING_TO_JUDGE', 'Evidence', 'evidence',
    'flaggable_pair_count',
    'PairClass', 'MISALIGNED', 'MINOR', 'CHANGE', 'UNREGISTERED', 'PAIR_CLASSES',
    'scan_names', 'result_report', 'assessment_report', 'plain', 'to_json', 'joined_json',
    # units the verdict is built from, tested on their own
    'point_grid', 'nearest_point', 'symmetric_inverse', 'PointMoments',
    'agreeing_registrations', 'corrections_confirmed', 'longest_run', 'longest_travel',
    'place_labels',
]
