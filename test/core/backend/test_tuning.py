"""The Phi search on a small real graph: M(Phi) against the naive measure, search invariants."""
import math

import numpy as np
import pytest

from map_consistency_ros.core.backend import (InconsistencyProfile, TuningSettings, measure_moved,
                                              optimize, profile_shape, tune_dcs)
from map_consistency_ros.core.consistency import ConsistencyParameters, check_consistency
from map_consistency_ros.core.geometry import candidate_pairs, pair_measures_naive, se2
from map_consistency_ros.io import carmen
from map_consistency_ros.io.datasets import BuildSettings, build_dataset

# flat_tolerance=0: the golden section refines to the tolerance wherever it lands.
SEARCH = TuningSettings(grid_steps=5, tolerance=0.05, workers=1, flat_tolerance=0.0)
# not the defaults: the search must judge with the parameters it is given
TEST = ConsistencyParameters(alpha=0.2)


@pytest.fixture(scope='module')
def intel_excerpt(shared_data):
    """Every 8th Intel scan (114) with 10 false loop closures: graph, ranges, model, offset."""
    intel = shared_data / 'intel'
    content = build_dataset(intel / 'intel.gfs.log', intel / 'intel.relations',
                            intel / 'intel.orig.bag',
                            BuildSettings(stride=8, false_loop_closures=10, seed=2))
    return (content.graph, content.scan_ranges(), carmen.sensor_model(content.laser),
            content.laser_offset)


@pytest.fixture(scope='module')
def tuned(intel_excerpt):
    calls = []
    profile = InconsistencyProfile(*intel_excerpt, settings=SEARCH)
    result = tune_dcs(*intel_excerpt, settings=SEARCH, parameters=TEST,
                      progress=lambda done, total: calls.append((done, total)), profile=profile)
    return result, profile, calls


def test_average_inconsistency_matches_the_naive_measure_at_an_independent_solve(intel_excerpt):
    graph, ranges, model, offset = intel_excerpt
    profile = InconsistencyProfile(graph, ranges, model, offset, SEARCH)
    evaluation = profile.evaluate(1.0)
    solution = optimize(graph, 1.0, iterations=SEARCH.iterations,
                        relative_tolerance=SEARCH.relative_tolerance,
                        initial_damping=SEARCH.initial_damping)
    np.testing.assert_array_equal(evaluation.optimization.poses, solution.poses)
    scans = profile.scans_at(solution.poses)
    naive = pair_measures_naive(scans, candidate_pairs(scans.extents), keep_largest=1)
    overlapping = naive.point_count > 0
    expected = naive.distance_sum[overlapping].sum() / overlapping.sum()
    assert evaluation.value == pytest.approx(expected, rel=1e-9)
    assert profile.evaluate(1.0) is evaluation


def test_the_search_returns_the_smallest_evaluated_m_and_refines_around_it(tuned):
    result, _, _ = tuned
    best = int(np.argmin(result.profile_value))
    assert result.phi == result.profile_phi[best]
    assert result.average_inconsistency == result.profile_value[best]
    assert np.all(np.diff(result.profile_phi) > 0)
    for phi in SEARCH.grid():
        assert np.any(np.isclose(result.profile_phi, phi, rtol=0, atol=1e-15))
    grid = SEARCH.grid()
    closest = int(np.argmin(np.abs(grid - result.phi)))
    low, high = grid[max(closest - 1, 0)], grid[min(closest + 1, len(grid) - 1)]
    inside = result.profile_phi[(result.profile_phi > low) & (result.profile_phi < high)]
    refined = np.setdiff1d(inside, grid)
    assert len(refined) >= 2
    assert np.min(np.diff(np.sort(refined))) < SEARCH.tolerance


def test_the_verdict_is_the_test_on_the_map_at_phi_star(tuned):
    result, profile, _ = tuned
    np.testing.assert_array_equal(result.poses, profile.evaluate(result.phi).optimization.poses)
    expected = check_consistency(profile.scans_at(result.poses), TEST,
                                 reference_scans=profile.scans_at(
                                     profile.graph.odometry_chain()))
    np.testing.assert_array_equal(result.consistency.inconsistent, expected.inconsistent)
    assert result.consistent == expected.consistent
    assert result.consistency.parameters == TEST
    assert result.average_inconsistency <= profile.evaluate(1.0).value


def test_progress_counts_up_to_its_total(tuned):
    _, _, calls = tuned
    done = [call[0] for call in calls]
    assert done == sorted(done)
    assert calls[-1][0] == calls[-1][1]


def test_parallel_grid_gives_the_serial_values(intel_excerpt, tuned):
    result, _, _ = tuned
    parallel = InconsistencyProfile(*intel_excerpt,
                                    settings=TuningSettings(grid_steps=5, workers=3))
    values = [item.value for item in parallel.evaluate_many(SEARCH.grid())]
    serial = [result.profile_value[np.isclose(result.profile_phi, phi, rtol=0, atol=1e-15)][0]
              for phi in SEARCH.grid()]
    np.testing.assert_array_equal(values, serial)


def test_grids_are_even_in_sqrt_phi_or_in_phi():
    sqrt_grid = TuningSettings(phi_min=0.01, phi_max=16.0, grid_steps=5).grid()
    np.testing.assert_allclose(np.diff(np.sqrt(sqrt_grid)), (4.0 - 0.1) / 4)
    linear = TuningSettings(phi_min=1.0, phi_max=9.0, grid_steps=5, sqrt_grid=False).grid()
    np.testing.assert_allclose(linear, [1.0, 3.0, 5.0, 7.0, 9.0])
    assert math.isclose(sqrt_grid[-1], 16.0)


@pytest.mark.parametrize('settings', [dict(phi_min=0.0), dict(phi_min=2.0, phi_max=1.0),
                                      dict(grid_steps=2), dict(tolerance=0.0),
                                      dict(iterations=0), dict(workers=-1),
                                      dict(flat_tolerance=-0.1), dict(reuse_tolerance=-1.0),
                                      dict(relative_tolerance=-1e-9), dict(initial_damping=0.0)])
def test_invalid_settings_are_refused(settings):
    with pytest.raises(ValueError):
        TuningSettings(**settings)


def test_a_flat_profile_stops_the_golden_section_after_its_first_two_points(intel_excerpt):
    flat = TuningSettings(grid_steps=5, tolerance=1e-6, workers=1, flat_tolerance=1.0)
    result = tune_dcs(*intel_excerpt, settings=flat)
    assert len(result.profile_phi) == len(flat.grid()) + 2
    assert result.average_inconsistency == result.profile_value.min()


def test_only_pairs_that_moved_are_measured_again(intel_excerpt):
    """A rigid motion of the whole map keeps every relative pose, so every pair is reused; pairs
    of one scan moved by 5 cm are measured again. Both against the naive kernel."""
    graph, ranges, model, offset = intel_excerpt
    profile = InconsistencyProfile(graph, ranges, model, offset, SEARCH)
    first = profile.scans_at(graph.poses)
    pairs = candidate_pairs(first.extents)
    measured = measure_moved(first, pairs, None, 1e-4)
    moved_poses = se2.compose(np.array([2.0, -1.0, 0.3]), graph.poses)
    moved_poses[7] = se2.compose(moved_poses[7], [0.05, 0.0, 0.0])
    second = profile.scans_at(moved_poses)
    second_pairs = candidate_pairs(second.extents)
    again = measure_moved(second, second_pairs, measured, 1e-4)
    naive = pair_measures_naive(second, second_pairs, keep_largest=0)
    np.testing.assert_array_equal(again.measures.point_count, naive.point_count)
    np.testing.assert_allclose(again.measures.distance_sum, naive.distance_sum, rtol=1e-9,
                               atol=1e-12)
    involved = (second_pairs == 7).any(axis=1)
    assert involved.any() and (~involved).any()
    known = pairs[:, 0] * len(ranges) + pairs[:, 1]
    keys = second_pairs[:, 0] * len(ranges) + second_pairs[:, 1]
    rows = np.minimum(np.searchsorted(known, keys), len(known) - 1)
    # Reused pairs carry the relative pose they were measured at; measured ones the new one.
    reused = ~involved & (known[rows] == keys)
    assert reused.sum() > 0.8 * len(second_pairs)
    np.testing.assert_array_equal(again.relative[reused], measured.relative[rows[reused]])
    poses = second.sensor_poses
    np.testing.assert_allclose(again.relative[involved], se2.relative(
        poses[second_pairs[involved, 0]], poses[second_pairs[involved, 1]]))


def test_profile_shape_finds_a_minimum_at_an_end_of_the_range_and_a_flat_profile():
    settings = TuningSettings(phi_min=1.0, phi_max=9.0, grid_steps=5, sqrt_grid=False,
                              flat_tolerance=1e-3)
    grid = settings.grid()
    assert profile_shape(grid, np.array([3.0, 2.0, 1.0, 2.0, 3.0]), settings) == (None, False)
    assert profile_shape(grid, np.array([1.0, 2.0, 3.0, 4.0, 5.0]), settings) == ('phi_min',
                                                                                False)
    # a refinement point beside the end does not move the minimum off the grid's end
    phis = np.append(grid, 8.5)
    values = np.array([5.0, 4.0, 3.0, 2.0, 1.0, 0.9])
    assert profile_shape(phis, values, settings) == ('phi_max', False)
    # 5.504 m against 5.506 m: a spread of 4e-4 of the smallest, within the flat tolerance
    flat = np.array([5.506, 5.504, 5.505, 5.506, 5.505])
    assert profile_shape(grid, flat, settings) == (None, True)
    failed = np.array([np.inf, 5.504, 5.505, 5.506, np.inf])
    assert profile_shape(grid, failed, settings) == (None, True)
    assert profile_shape(grid, np.full(5, np.inf), settings) == (None, False)


def test_scans_of_some_vertices_are_measured_at_their_vertices_of_the_whole_solve(
        intel_excerpt):
    """A SLAM graph whose scans the test folded: every vertex is solved, M is measured on the
    scans given, each placed at its own vertex."""
    graph, ranges, model, offset = intel_excerpt
    vertices = np.arange(0, graph.vertex_count, 3)
    profile = InconsistencyProfile(graph, ranges[vertices], model, offset, SEARCH,
                                   scan_vertices=vertices)
    whole = InconsistencyProfile(graph, ranges, model, offset, SEARCH)
    evaluation = profile.evaluate(1.0)
    np.testing.assert_array_equal(evaluation.optimization.poses,
                                  whole.evaluate(1.0).optimization.poses)
    scans = profile.scans_at(evaluation.optimization.poses)
    np.testing.assert_array_equal(
        scans.sensor_poses, whole.scans_at(evaluation.optimization.poses).sensor_poses[vertices])
    naive = pair_measures_naive(scans, candidate_pairs(scans.extents), keep_largest=1)
    overlapping = naive.point_count > 0
    assert evaluation.value == pytest.approx(
        naive.distance_sum[overlapping].sum() / overlapping.sum(), rel=1e-9)
    result = tune_dcs(graph, ranges[vertices], model, offset, SEARCH, TEST,
                      scan_vertices=vertices)
    assert result.poses.shape == (graph.vertex_count, 3)
    assert result.consistency.scan_count == vertices.size


@pytest.mark.parametrize('vertices, message', [
    ([0, 1], '3 scans but 2 scan vertices'), ([0, 2, 1], 'increasing'), ([0, 1, 999], 'in 0..'),
])
def test_scan_vertices_must_name_one_vertex_per_scan_in_order(intel_excerpt, vertices, message):
    graph, ranges, model, offset = intel_excerpt
    with pytest.raises(ValueError, match=message):
        InconsistencyProfile(graph, ranges[:3], model, offset, SEARCH, scan_vertices=vertices)
    with pytest.raises(ValueError, match='3 scans for'):
        InconsistencyProfile(graph, ranges[:3], model, offset, SEARCH)


def test_search_findings_name_the_settings_as_the_caller_does():
    import dataclasses
    from map_consistency_ros.core.backend import search_findings
    from map_consistency_ros.core.backend._tuning import TuningResult
    settings = TuningSettings(phi_min=1e-6, phi_max=2.0)
    values = np.array([5.504, 5.505, 5.506])
    fields = {field.name: None for field in dataclasses.fields(TuningResult)}
    result = TuningResult(**{**fields, 'phi': 2.0, 'profile_value': values,
                             'profile_phi': np.array([0.5, 1.0, 2.0]), 'at_bound': 'phi_max',
                             'flat': True})
    node = search_findings(result, settings)
    cli = search_findings(result, settings, lambda name: '--' + name.replace('_', '-'))
    assert len(node) == len(cli) == 2
    assert 'M(Phi) is flat: 5.504 m to 5.506 m' in node[0] and '(within flat_tolerance' in node[0]
    assert 'upper end of the search (phi_max 2)' in node[1]
    assert 'upper end of the search (--phi-max 2)' in cli[1]
    assert search_findings(dataclasses.replace(result, at_bound=None, flat=False), settings) == []
