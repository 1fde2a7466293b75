"""Pairwise inconsistency (eqs. 1-2) against shapely, the naive kernel and worked examples."""
import math

import numpy as np
import pytest
import shapely

from map_consistency_ros.core.geometry import (PairMeasures, ScanSet, SensorModel, candidate_pairs,
                                               measure_pairs, pair_measures, pair_measures_naive,
                                               pairs_point_distances, point_distances, se2)
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

RTOL = 1e-9


def _polygon(scans: ScanSet, index: int) -> shapely.Polygon:
    ring = scans.endpoints[index]
    if not scans.full_circle:
        ring = np.vstack([scans.sensor_poses[index, :2], ring])
    return shapely.Polygon(ring)


def _shapely_distances(scans: ScanSet, polygon_scan: int, point_scan: int) -> np.ndarray:
    """Eq. 1 by shapely: boundary distance of the valid points strictly inside the polygon."""
    polygon = _polygon(scans, polygon_scan)
    shapely.prepare(polygon)
    points = scans.endpoints[point_scan]
    inside = shapely.contains_xy(polygon, points[:, 0], points[:, 1]) & scans.valid[point_scan]
    distance = shapely.distance(polygon.boundary, shapely.points(points))
    return np.where(inside, distance, 0.0)


def _assert_matches_shapely(scans: ScanSet, pairs: np.ndarray) -> None:
    measures = pair_measures(scans, pairs)
    batch = pairs_point_distances(scans, measures.pairs)
    for row, (i, j) in enumerate(measures.pairs):
        of_j, of_i = batch[row]
        expected_j, expected_i = _shapely_distances(scans, i, j), _shapely_distances(scans, j, i)
        np.testing.assert_array_equal(of_j > 0, expected_j > 0)
        np.testing.assert_array_equal(of_i > 0, expected_i > 0)
        np.testing.assert_allclose(of_j, expected_j, rtol=RTOL, atol=1e-13)
        np.testing.assert_allclose(of_i, expected_i, rtol=RTOL, atol=1e-13)
        pooled = np.concatenate([expected_j, expected_i])
        assert measures.point_count[row] == np.count_nonzero(pooled)
        np.testing.assert_allclose(measures.distance_sum[row], pooled.sum(), rtol=RTOL, atol=1e-13)


def _assert_same_measures(fast: PairMeasures, naive: PairMeasures) -> None:
    np.testing.assert_array_equal(fast.pairs, naive.pairs)
    np.testing.assert_array_equal(fast.point_count, naive.point_count)
    np.testing.assert_allclose(fast.distance_sum, naive.distance_sum, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(fast.largest, naive.largest, rtol=1e-12, atol=1e-13)


def _random_scans(seed: int, beams: int, full_circle: bool, count: int = 8) -> ScanSet:
    """Random star polygons close together, with NaN, inf, negative and too long beams."""
    rng = np.random.default_rng(seed)
    if full_circle:
        increment = 2 * math.pi / beams
    else:
        # Short of the full circle: beams * increment < 2 pi, and each increment below pi.
        fov = rng.uniform(0.2, (beams - 1) * min((2 * math.pi - 0.2) / beams, math.pi - 0.05))
        increment = fov / (beams - 1)
    model = SensorModel(angle_min=rng.uniform(-math.pi, math.pi), angle_increment=increment,
                        max_range=5.0, range_min=0.05)
    ranges = rng.uniform(0.2, 6.0, (count, beams))
    ranges[rng.random(ranges.shape) < 0.3] *= 0.3
    for bad in (np.nan, np.inf, -1.0, 0.01):
        ranges[rng.random(ranges.shape) < 0.04] = bad
    poses = np.column_stack([rng.uniform(-2, 2, (count, 2)), rng.uniform(-math.pi, math.pi, count)])
    # A scan right beside another's sensor puts points near that polygon's apex.
    poses[1] = se2.compose(poses[0], [0.05, -0.02, 1.0])
    ranges[1] = np.abs(ranges[1]) * 0.1
    return ScanSet.from_ranges(ranges, poses, model)


def _all_pairs(count: int) -> np.ndarray:
    return np.argwhere(np.triu(np.ones((count, count), bool), 1))


RANDOM_CASES = [(seed, beams, full) for seed, (beams, full) in enumerate(
    [(3, False), (4, True), (7, False), (16, True), (40, False), (90, True), (181, False),
     (200, True), (360, False), (2, False)])]


@pytest.mark.parametrize('seed, beams, full_circle', RANDOM_CASES)
def test_random_star_polygons_match_shapely(seed, beams, full_circle):
    scans = _random_scans(seed, beams, full_circle)
    assert scans.full_circle == full_circle
    _assert_matches_shapely(scans, _all_pairs(scans.scan_count))


@pytest.mark.parametrize('seed, beams, full_circle', RANDOM_CASES)
def test_random_star_polygons_fast_equals_naive(seed, beams, full_circle):
    scans = _random_scans(100 + seed, beams, full_circle, count=16)
    pairs = _all_pairs(scans.scan_count)
    fast = pair_measures(scans, pairs, keep_largest=5)
    assert fast.point_count.sum() > 0
    _assert_same_measures(fast, pair_measures_naive(scans, pairs, keep_largest=5))


def test_worked_example_triangle():
    """A right triangle (sensor, (1, 0), (0, 1)); the other scan puts one point at (0.1, 0.2)."""
    model = SensorModel(angle_min=0.0, angle_increment=math.pi / 2, max_range=8.0)
    scans = ScanSet.from_ranges(np.array([[1.0, 1.0], [1.2, 0.5]]),
                                np.array([[0.0, 0.0, 0.0], [0.1, -1.0, math.pi / 2]]), model)
    np.testing.assert_allclose(scans.endpoints[1, 0], [0.1, 0.2], atol=1e-15)
    measures = pair_measures(scans, np.array([[0, 1]]))
    np.testing.assert_allclose(measures.distance_sum, [0.1], rtol=1e-12)
    np.testing.assert_array_equal(measures.point_count, [1])


def test_worked_example_full_circle_squares():
    """Two 2 m squares seen from their centres; each has one corner 0.5 m inside the other."""
    model = SensorModel(angle_min=math.pi / 4, angle_increment=math.pi / 2, max_range=8.0)
    scans = ScanSet.from_ranges(np.full((2, 4), math.sqrt(2)),
                                np.array([[0.0, 0.0, 0.0], [1.5, 1.2, 0.0]]), model)
    assert scans.full_circle
    of_j, of_i = point_distances(scans, 0, 1)
    np.testing.assert_allclose(of_j, [0, 0, 0.5, 0], atol=1e-12)
    np.testing.assert_allclose(of_i, [0.5, 0, 0, 0], atol=1e-12)
    measures = pair_measures(scans, np.array([[1, 0]]), keep_largest=3)
    np.testing.assert_array_equal(measures.pairs, [[0, 1]])
    np.testing.assert_allclose(measures.distance_sum, [1.0], rtol=1e-12)
    np.testing.assert_allclose(measures.largest, [[0.5, 0.5, 0.0]], rtol=1e-12)


def test_largest_and_sums_agree_with_point_distances():
    scans = _random_scans(7, 50, False, count=10)
    pairs = _all_pairs(scans.scan_count)[::-1, ::-1]
    measures = pair_measures(scans, pairs, keep_largest=4)
    assert np.all(measures.pairs[:, 0] < measures.pairs[:, 1])
    for row, (i, j) in enumerate(measures.pairs):
        pooled = np.sort(np.concatenate(point_distances(scans, i, j)))[::-1]
        np.testing.assert_allclose(measures.largest[row], pooled[:4], rtol=1e-15)
        np.testing.assert_allclose(measures.distance_sum[row], pooled.sum(), rtol=1e-12)
        assert measures.point_count[row] == np.count_nonzero(pooled)


def test_measure_is_invariant_under_moving_the_whole_map():
    scans = _random_scans(11, 60, True, count=10)
    pairs = _all_pairs(scans.scan_count)
    moved = scans.with_poses(se2.compose(np.array([30.0, -12.0, 2.0]), scans.sensor_poses))
    before, after = pair_measures(scans, pairs), pair_measures(moved, pairs)
    np.testing.assert_array_equal(before.point_count, after.point_count)
    np.testing.assert_allclose(before.distance_sum, after.distance_sum, rtol=1e-9)


@pytest.mark.parametrize('chunk', [1, 7, 45, 1000])
def test_measuring_in_batches_gives_the_measures_of_one_call(chunk):
    scans = _random_scans(5, 90, False, count=10)
    pairs = _all_pairs(scans.scan_count)[::-1]  # any order, kept
    whole = pair_measures(scans, pairs, keep_largest=4)
    reported = []
    batched = measure_pairs(scans, pairs, keep_largest=4, chunk=chunk,
                            progress=lambda done, total: reported.append((done, total)))
    for name in ('pairs', 'distance_sum', 'point_count', 'largest'):
        np.testing.assert_array_equal(getattr(batched, name), getattr(whole, name))
    count = len(pairs)
    assert reported == [(min(end, count), count) for end in range(chunk, count + chunk, chunk)]
    none = measure_pairs(scans, np.zeros((0, 2), dtype=np.int64), keep_largest=4,
                         progress=lambda done, total: reported.append((done, total)))
    assert none.pairs.shape == (0, 2) and none.largest.shape == (0, 4)
    assert reported[-1] == (0, 0)


def test_take_picks_pairs_by_index_or_mask():
    scans = _random_scans(3, 30, True, count=5)
    measures = pair_measures(scans, _all_pairs(scans.scan_count), keep_largest=3)
    mask = measures.distance_sum > np.median(measures.distance_sum)
    assert 0 < mask.sum() < mask.size
    for rows in (mask, np.flatnonzero(mask)[::-1]):
        taken = measures.take(rows)
        for name in ('pairs', 'distance_sum', 'point_count', 'largest'):
            np.testing.assert_array_equal(getattr(taken, name), getattr(measures, name)[rows])


def test_no_pairs_and_no_kept_distances():
    scans = _random_scans(1, 10, False, count=3)
    empty = pair_measures(scans, np.zeros((0, 2), dtype=np.int64))
    assert empty.pairs.shape == (0, 2) and empty.distance_sum.shape == (0,)
    assert empty.largest.shape == (0, 10)
    assert pair_measures(scans, np.array([[0, 2]]), keep_largest=0).largest.shape == (1, 0)


@pytest.mark.parametrize('pairs, keep, message', [
    (np.array([[0, 3]]), 10, r'in \[0, 3\)'),
    (np.array([[-1, 2]]), 10, r'in \[0, 3\)'),
    (np.array([[1, 1]]), 10, 'two different scans'),
    (np.array([[0, 1, 2]]), 10, r'\(P, 2\) integer'),
    (np.array([[0.0, 1.0]]), 10, r'\(P, 2\) integer'),
    (np.array([[0, 1]]), -1, 'non-negative integer'),
    (np.array([[0, 1]]), 2.5, 'non-negative integer'),
])
def test_bad_pairs_are_rejected(pairs, keep, message):
    scans = _random_scans(2, 10, False, count=3)
    for measure in (pair_measures, pair_measures_naive):
        with pytest.raises(ValueError, match=message):
            measure(scans, pairs, keep_largest=keep)


def test_point_distances_rejects_bad_index():
    scans = _random_scans(2, 10, False, count=3)
    with pytest.raises(ValueError, match='out of range'):
        point_distances(scans, 0, 3)
    with pytest.raises(ValueError, match='scan index -1 out of range'):
        pairs_point_distances(scans, np.array([[0, 1], [-1, 2]]))


def _log_scans(path) -> ScanSet:
    log = read_carmen_log(path)
    return ScanSet.from_ranges(log.ranges, log.laser_poses, sensor_model(log))


@pytest.fixture(scope='module')
def intel_scans(shared_data) -> ScanSet:
    return _log_scans(shared_data / 'intel' / 'intel.gfs.log')


@pytest.fixture(scope='module')
def fr079_scans(shared_data) -> ScanSet:
    scans = _log_scans(shared_data / 'fr079' / 'freiburg-079-corrected.log.gz')
    keep = np.arange(0, scans.scan_count, 6)
    return ScanSet.from_ranges(scans.ranges[keep], scans.sensor_poses[keep], scans.model)


def _sample_pairs(scans: ScanSet, count: int, seed: int) -> np.ndarray:
    pairs = candidate_pairs(scans.extents)
    return pairs[np.random.default_rng(seed).choice(len(pairs), count, replace=False)]


@pytest.mark.parametrize('name', ['intel_scans', 'fr079_scans'])
def test_real_scans_match_shapely(name, request):
    scans = request.getfixturevalue(name)
    pairs = _sample_pairs(scans, 100, seed=5)
    assert pair_measures(scans, pairs).point_count.sum() > 500
    _assert_matches_shapely(scans, pairs)


@pytest.mark.parametrize('name', ['intel_scans', 'fr079_scans'])
def test_real_scans_fast_equals_naive(name, request):
    scans = request.getfixturevalue(name)
    pairs = _sample_pairs(scans, 1500, seed=6)
    _assert_same_measures(pair_measures(scans, pairs), pair_measures_naive(scans, pairs))
