"""The density suite: subsample selections, displaced copies and their truth, native rebuild."""
import numpy as np
import pytest

from map_consistency_ros.core.geometry import ScanSet, SensorModel, se2
from map_consistency_ros.evaluation import density
from map_consistency_ros.io.carmen import CarmenLog, LaserAngles, read_carmen_log
from map_consistency_ros.io.datasets import RawBag
from test.conftest import rectangle_room_ranges


def _log(ranges, poses, stamps):
    count = len(poses)
    return CarmenLog(path='synthetic', ranges=np.asarray(ranges, dtype=np.float64),
                     laser_poses=np.asarray(poses, dtype=np.float64),
                     robot_poses=np.asarray(poses, dtype=np.float64),
                     timestamps=np.asarray(stamps, dtype=np.float64),
                     line_numbers=np.arange(1, count + 1), stated_angles=None, parameters={})


def _walk(count):
    """A robot crossing an 8 x 5 m room and turning, 5 cm per scan."""
    t = np.arange(count)
    return np.stack([1.0 + 0.05 * t, 2.5 + 0.3 * np.sin(t / 15.0), 0.02 * t], axis=1)


def test_selection_every_nth_and_keyframes_by_ranges():
    poses = _walk(30)
    ranges = np.round(rectangle_room_ranges(poses), 2)
    log = _log(ranges, poses, 100.0 + 0.2 * np.arange(30))
    assert list(density.selection(log, '5')) == [0, 5, 10, 15, 20, 25]
    keyframe_rows = np.array([0, 7, 13, 29])
    # the keyframe log has its own clock (as intel.gfs.log): found by identical ranges
    keyframes = _log(ranges[keyframe_rows], poses[keyframe_rows], 0.2 * keyframe_rows)
    assert list(density.selection(log, 'keyframes', keyframes)) == list(keyframe_rows)
    with pytest.raises(ValueError):
        density.selection(log, '0')


def test_displaced_copies_move_the_same_stretch_at_every_density():
    poses = _walk(200)
    stamps = 10.0 + 0.1 * np.arange(200)
    start, centre = density.pivot(poses, stamps, 0.5)
    assert 80 <= np.searchsorted(stamps, start) <= 120
    full, moved_full = density.displaced(poses, stamps, start, centre, 5.0, 0.0)
    rows = np.arange(0, 200, 7)
    sparse, moved_sparse = density.displaced(poses[rows], stamps[rows], start, centre, 5.0, 0.0)
    # the same scans are moved, to the same poses, whatever the sampling
    assert set(rows[moved_sparse]) == set(moved_full) & set(rows)
    np.testing.assert_allclose(sparse, full[rows], atol=1e-12)
    np.testing.assert_array_equal(full[: moved_full[0]], poses[: moved_full[0]])
    np.testing.assert_allclose(se2.wrap_angle(full[moved_full, 2] - poses[moved_full, 2]),
                               np.radians(5.0), atol=1e-12)


def test_truth_of_a_shift_and_of_a_rotation():
    poses = _walk(40)
    stamps = np.arange(40.0)
    model = SensorModel(angle_min=-np.pi / 2, angle_increment=np.pi / 180, max_range=8.0)
    ranges = rectangle_room_ranges(poses)
    start, centre = density.pivot(poses, stamps, 0.5)
    shifted, rows = density.displaced(poses, stamps, start, centre, 0.0, 0.3)
    scans = ScanSet.from_ranges(ranges, shifted, model)
    assert density.endpoint_rms(scans, rows, poses) == pytest.approx(0.3, abs=1e-9)
    turned, rows = density.displaced(poses, stamps, start, centre, 2.0, 0.0)
    scans = ScanSet.from_ranges(ranges, turned, model)
    truth = ScanSet.from_ranges(ranges, poses, model)
    # a rotation by a about c moves a point p by 2 |p - c| sin(a / 2)
    points = truth.endpoints[rows][truth.valid[rows]]
    expected = 2 * np.hypot(*(points - centre).T) * np.sin(np.radians(1.0))
    assert density.endpoint_rms(scans, rows, poses) == pytest.approx(
        np.sqrt(np.mean(expected ** 2)), rel=1e-9)
    assert density.endpoint_rms(scans, np.zeros(0, dtype=int), poses) == 0.0


def test_native_log_places_scans_between_keyframes_and_writes_a_readable_log(tmp_path):
    count = 41
    truth = _walk(count)
    ranges = rectangle_room_ranges(truth, noise=0.005).astype(np.float32)
    stamps = 1000.0 + 0.1 * np.arange(count)
    # odometry: the true path with a drift of 1 mm and 0.1 deg per scan in its own frame
    steps = se2.relative(truth[:-1], truth[1:]) + np.array([0.001, 0.0, np.radians(0.1)])
    odometry = se2.chain(np.array([5.0, -3.0, 1.0]), steps)
    odometry[:, 2] = np.unwrap(odometry[:, 2])
    bag = RawBag(scan_stamps=stamps, scan_ranges=ranges,
                 angles=LaserAngles(-np.pi / 2, np.pi, np.pi / 180, 80.0),
                 odom_stamps=stamps, odom_poses=odometry, laser_offset=np.zeros(3))
    keyframe_rows = np.arange(0, count, 10)
    keyframes = _log(ranges[keyframe_rows], truth[keyframe_rows], stamps[keyframe_rows] - 999.0)
    native = density.native_log(keyframes, bag)
    np.testing.assert_array_equal(native.keyframe_rows, keyframe_rows)
    np.testing.assert_array_equal(native.poses[keyframe_rows], truth[keyframe_rows])
    before = np.hypot(*(native.odometry_poses - truth)[:, :2].T)
    after = np.hypot(*(native.poses - truth)[:, :2].T)
    assert before.max() > 0.004  # the drift is visible before registration
    assert after.max() < 0.02 and np.median(after) < np.median(before[before > 0])
    path = tmp_path / 'native.log.gz'
    density.write_carmen_log(path, native)
    log = read_carmen_log(path)
    np.testing.assert_array_equal(log.ranges.astype(np.float32), ranges)
    np.testing.assert_allclose(log.laser_poses, native.poses, atol=1e-6)
    np.testing.assert_allclose(log.timestamps, stamps, atol=1e-6)
    assert list(density.selection(log, 'keyframes', keyframes)) == list(keyframe_rows)
