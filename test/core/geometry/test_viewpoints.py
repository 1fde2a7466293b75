"""Viewpoints: which scans of a trajectory the test keeps, and that standing still adds nothing."""
import math

import numpy as np
import pytest

from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.geometry import is_new_viewpoint, viewpoint_rows
from map_consistency_ros.core.live import ConsistencyMonitor
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model


def test_a_viewpoint_is_far_enough_from_the_previous_viewpoint_not_the_previous_scan():
    # 0.1 m steps: every fourth scan is 0.4 m from the last viewpoint
    poses = np.stack([np.arange(10) * 0.1, np.zeros(10), np.zeros(10)], axis=1)
    np.testing.assert_array_equal(viewpoint_rows(poses, 0.4, 0.4), [0, 4, 8])
    # turning in place: a viewpoint per 0.4 rad, whatever the number of scans
    turning = np.stack([np.zeros(9), np.zeros(9), np.linspace(0.0, 2.0, 9)], axis=1)
    np.testing.assert_array_equal(viewpoint_rows(turning, 0.4, 0.4), [0, 2, 4, 6, 8])
    # headings wrap: -3.1 and 3.1 rad are 0.08 rad apart
    wrapped = np.array([[0.0, 0.0, 3.1], [0.0, 0.0, -3.1]])
    np.testing.assert_array_equal(viewpoint_rows(wrapped, 0.4, 0.4), [0])
    np.testing.assert_array_equal(viewpoint_rows(poses, 0.0, 0.4), np.arange(10))
    np.testing.assert_array_equal(viewpoint_rows(turning, 0.4, 0.0), np.arange(9))
    assert viewpoint_rows(np.zeros((0, 3)), 0.4, 0.4).size == 0


def test_the_live_rule_is_the_batch_rule():
    rng = np.random.default_rng(3)
    steps = np.column_stack([rng.uniform(0.0, 0.6, 300), rng.normal(0.0, 0.05, 300),
                             rng.normal(0.0, 0.3, 300)])
    poses = np.zeros((301, 3))
    for row, step in enumerate(steps):  # a trajectory of random relative steps
        c, s = math.cos(poses[row, 2]), math.sin(poses[row, 2])
        poses[row + 1] = [poses[row, 0] + c * step[0] - s * step[1],
                          poses[row, 1] + s * step[0] + c * step[1], poses[row, 2] + step[2]]
    live, last = [0], poses[0]
    for row in range(1, len(poses)):
        c, s = math.cos(last[2]), math.sin(last[2])
        dx, dy = poses[row, :2] - last[:2]
        relative = np.array([c * dx + s * dy, -s * dx + c * dy, poses[row, 2] - last[2]])
        if is_new_viewpoint(relative, 0.4, 0.4):
            live.append(row)
            last = poses[row]
    np.testing.assert_array_equal(viewpoint_rows(poses, 0.4, 0.4), live)
    assert 50 < len(live) < 300


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log.timestamps[:120], log.ranges[:120], log.laser_poses[:120], sensor_model(log)


def test_standing_still_adds_no_pairs_no_flags_and_no_cost(intel):
    stamps, ranges, poses, model = intel
    order = np.argsort(stamps, kind='stable')
    stamps, ranges, poses = stamps[order], ranges[order], poses[order]
    monitor = ConsistencyMonitor()
    for stamp, scan in zip(stamps, ranges):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps, poses)
    before = monitor.evaluate()
    # the robot stands still for 200 scans (noise on the ranges, jitter on the pose)
    rng = np.random.default_rng(0)
    still_stamps = stamps[-1] + 0.05 * np.arange(1, 201)
    still_poses = poses[-1] + rng.normal(0.0, [0.005, 0.005, 0.002], (200, 3))
    for stamp in still_stamps:
        monitor.add_scan(stamp, ranges[-1] + rng.normal(0.0, 0.01, ranges.shape[1]), model)
    summary = monitor.update_trajectory(np.concatenate([stamps, still_stamps]),
                                        np.concatenate([poses, still_poses]))
    after = monitor.evaluate()
    assert summary.new_keyframes == 0 and summary.measured_pairs == 0
    assert after.folded_scans == before.folded_scans + 200
    assert after.keyframe_count == before.keyframe_count
    assert after.unmatched_poses == 0 and after.poses_without_scan == 0
    np.testing.assert_array_equal(after.result.pairs, before.result.pairs)
    np.testing.assert_array_equal(after.result.inconsistent, before.result.inconsistent)
    # a folded scan sent again is a duplicate, not a new scan waiting for its pose
    with pytest.raises(ValueError, match='duplicates'):
        monitor.add_scan(still_stamps[3], ranges[-1], model)


def test_every_keyframe_is_tested_when_viewpoints_are_off(intel):
    stamps, ranges, poses, model = intel
    monitor = ConsistencyMonitor(ConsistencyParameters(viewpoint_spacing=0.0,
                                                       viewpoint_turn=0.0))
    for stamp, scan in zip(stamps, ranges):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps, poses)
    assert monitor.keyframe_count == len(stamps) and monitor.evaluate().folded_scans == 0
