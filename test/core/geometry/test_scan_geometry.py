"""SensorModel validation and ScanSet construction, checked against se2 and shapely."""
import math

import numpy as np
import pytest
import shapely

from map_consistency_ros.core.geometry import ScanSet, SensorModel, se2
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

HALF_CIRCLE = SensorModel(angle_min=-math.pi / 2, angle_increment=math.pi / 4, max_range=8.0,
                          range_min=0.1)


@pytest.mark.parametrize('fields, message', [
    (dict(angle_min=0.0, angle_increment=0.0, max_range=8.0), 'angle_increment'),
    (dict(angle_min=0.0, angle_increment=-0.01, max_range=8.0), 'angle_increment'),
    (dict(angle_min=0.0, angle_increment=math.pi, max_range=8.0), 'angle_increment'),
    (dict(angle_min=0.0, angle_increment=float('nan'), max_range=8.0), 'finite'),
    (dict(angle_min=float('inf'), angle_increment=0.1, max_range=8.0), 'finite'),
    (dict(angle_min=0.0, angle_increment=0.1, max_range=float('inf')), 'finite'),
    (dict(angle_min=0.0, angle_increment=0.1, max_range=1.0, range_min=1.0), 'max_range'),
    (dict(angle_min=0.0, angle_increment=0.1, max_range=0.0), 'max_range'),
    (dict(angle_min=0.0, angle_increment=0.1, max_range=8.0, range_min=-0.5), 'range_min'),
])
def test_sensor_model_rejects_bad_fields(fields, message):
    with pytest.raises(ValueError, match=message):
        SensorModel(**fields)


def test_sensor_model_beam_count_and_full_circle():
    ring = SensorModel(angle_min=-math.pi, angle_increment=2 * math.pi / 360, max_range=30.0)
    assert ring.is_full_circle(360)
    assert not ring.is_full_circle(359)
    assert not HALF_CIRCLE.is_full_circle(5)
    ring.check_beam_count(360)
    # An endpoint-inclusive full circle repeats its first beam.
    inclusive = SensorModel(angle_min=-math.pi, angle_increment=2 * math.pi / 359, max_range=30.0)
    with pytest.raises(ValueError, match='overlap past 2 pi'):
        inclusive.check_beam_count(360)
    with pytest.raises(ValueError, match='at least 2 beams'):
        HALF_CIRCLE.check_beam_count(1)
    np.testing.assert_allclose(HALF_CIRCLE.bearings(5), np.linspace(-math.pi / 2, math.pi / 2, 5))


def test_from_ranges_marks_and_closes_invalid_beams():
    ranges = np.array([[1.0, np.nan, np.inf, -np.inf, -1.0],
                       [0.1, 0.1000001, 8.0, 7.9999, 0.0]])
    scans = ScanSet.from_ranges(ranges, np.zeros((2, 3)), HALF_CIRCLE)
    expected_valid = np.array([[True, False, False, False, False],
                               [False, True, False, True, False]])
    np.testing.assert_array_equal(scans.valid, expected_valid)
    np.testing.assert_array_equal(scans.ranges, np.where(expected_valid, ranges, 8.0))
    assert scans.scan_count == 2 and not scans.full_circle


@pytest.mark.parametrize('ranges, poses, message', [
    (np.ones(5), np.zeros((1, 3)), r'\(N, K\)'),
    (np.ones((2, 5)), np.zeros((3, 3)), 'sensor poses'),
    (np.ones((2, 5)), np.zeros((2, 2)), 'sensor poses'),
    (np.ones((2, 5)), np.array([[0, 0, 0], [0, np.nan, 0]]), 'scan 1 is not finite'),
    (np.ones((2, 1)), np.zeros((2, 3)), 'at least 2 beams'),
    (np.ones((1, 9)), np.zeros((1, 3)), 'overlap past 2 pi'),
])
def test_from_ranges_rejects_bad_shapes(ranges, poses, message):
    with pytest.raises(ValueError, match=message):
        ScanSet.from_ranges(ranges, poses, HALF_CIRCLE)


def test_direct_construction_checks_valid_shape():
    with pytest.raises(ValueError, match='valid must have the shape'):
        ScanSet(sensor_poses=np.zeros((1, 3)), ranges=np.ones((1, 5)),
                valid=np.ones((1, 4), bool), model=HALF_CIRCLE)


def _polygon(scans: ScanSet, index: int) -> shapely.Polygon:
    ring = scans.endpoints[index]
    if not scans.full_circle:
        ring = np.vstack([scans.sensor_poses[index, :2], ring])
    return shapely.Polygon(ring)


@pytest.mark.parametrize('beams, increment', [(5, math.pi / 4), (12, 2 * math.pi / 12)])
def test_endpoints_and_extents_match_independent_oracles(beams, increment):
    model = SensorModel(angle_min=-1.0, angle_increment=increment, max_range=8.0)
    rng = np.random.default_rng(beams)
    poses = np.column_stack([rng.uniform(-20, 20, (6, 2)), rng.uniform(-math.pi, math.pi, 6)])
    ranges = rng.uniform(0.5, 9.0, (6, beams))
    scans = ScanSet.from_ranges(ranges, poses, model)
    assert scans.full_circle == (beams == 12)
    bearings = -1.0 + increment * np.arange(beams)
    closed = np.minimum(ranges, 8.0)
    for index in range(6):
        local = np.column_stack([closed[index] * np.cos(bearings),
                                 closed[index] * np.sin(bearings), np.zeros(beams)])
        world = se2.compose(poses[index], local)[:, :2]
        np.testing.assert_allclose(scans.endpoints[index], world, atol=1e-12)
        polygon = _polygon(scans, index)
        assert polygon.is_valid
        np.testing.assert_allclose(scans.extents[index], polygon.bounds, atol=1e-12)


def test_with_poses_moves_the_same_scans_rigidly():
    rng = np.random.default_rng(3)
    scans = ScanSet.from_ranges(rng.uniform(0.5, 7.0, (4, 5)), np.zeros((4, 3)), HALF_CIRCLE)
    poses = np.column_stack([rng.uniform(-5, 5, (4, 2)), rng.uniform(-3, 3, 4)])
    moved = scans.with_poses(poses)
    np.testing.assert_array_equal(moved.ranges, scans.ranges)
    np.testing.assert_array_equal(moved.valid, scans.valid)
    np.testing.assert_allclose(moved.sensor_poses, poses)
    local = np.linalg.norm(scans.endpoints[:, :, None] - scans.endpoints[:, None, :], axis=-1)
    world = np.linalg.norm(moved.endpoints[:, :, None] - moved.endpoints[:, None, :], axis=-1)
    np.testing.assert_allclose(world, local, atol=1e-12)


def test_scan_set_arrays_are_read_only():
    scans = ScanSet.from_ranges(np.ones((1, 5)), np.zeros((1, 3)), HALF_CIRCLE)
    for array in (scans.sensor_poses, scans.ranges, scans.valid, scans.endpoints, scans.extents):
        with pytest.raises(ValueError):
            array[...] = 0


def test_intel_scans_are_valid_polygons(intel_log):
    ranges, poses, model = intel_log
    scans = ScanSet.from_ranges(ranges[:50], poses[:50], model)
    assert scans.valid.mean() > 0.8
    for index in range(50):
        polygon = _polygon(scans, index)
        assert polygon.is_valid
        np.testing.assert_allclose(scans.extents[index], polygon.bounds, atol=1e-12)


@pytest.fixture(scope='module')
def intel_log(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log.ranges, log.laser_poses, sensor_model(log)


def test_take_keeps_the_geometry_of_the_rows_it_picks(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    model = sensor_model(log)
    scans = ScanSet.from_ranges(log.ranges[:40], log.laser_poses[:40], model)
    rows = np.array([31, 2, 2, 17])
    taken = scans.take(rows)
    built = ScanSet.from_ranges(log.ranges[rows], log.laser_poses[rows], model)
    for name in ('sensor_poses', 'ranges', 'valid', 'endpoints', 'extents'):
        np.testing.assert_array_equal(getattr(taken, name), getattr(built, name))
        assert not getattr(taken, name).flags.writeable
    assert taken.model == model and taken.scan_count == 4


def test_from_parts_needs_every_array():
    scans = ScanSet.from_ranges(np.full((1, 5), 2.0), np.zeros((1, 3)), HALF_CIRCLE)
    with pytest.raises(ValueError, match='need exactly the arrays'):
        ScanSet.from_parts(HALF_CIRCLE, sensor_poses=scans.sensor_poses, ranges=scans.ranges)


def test_moved_equals_the_scans_built_at_the_moved_poses(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    model = sensor_model(log)
    scans = ScanSet.from_ranges(log.ranges[:30], log.laser_poses[:30], model)
    rows = np.array([4, 11, 29])
    transforms = np.array([[0.3, -0.2, 0.05], [-1.0, 2.0, -1.2], [0.0, 0.0, math.pi]])
    moved = scans.moved(rows, transforms)
    # p -> R p + t in the world is the pose composed on the left with the transform
    poses = se2.compose(transforms, log.laser_poses[rows])
    built = ScanSet.from_ranges(log.ranges[rows], poses, model)
    np.testing.assert_allclose(se2.wrap_angle(moved.sensor_poses[:, 2] - poses[:, 2]), 0.0,
                               atol=1e-12)
    np.testing.assert_allclose(moved.sensor_poses[:, :2], poses[:, :2], atol=1e-12)
    for name in ('endpoints', 'extents'):
        np.testing.assert_allclose(getattr(moved, name), getattr(built, name), atol=1e-9)
    np.testing.assert_array_equal(moved.valid, built.valid)
