"""Markers of a monitored Intel excerpt: stable ids, verdict colours, misaligned points,
changed places and a legend."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from visualization_msgs.msg import Marker

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.live import ConsistencyMonitor
from map_consistency_ros.core.verdict import explain, misaligned_endpoints
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.ros.markers import (CHANGES_NAMESPACE, CONSISTENT, INCONSISTENT,
                                             KEYFRAME_NAMESPACE, LEGEND_NAMESPACE, MarkerUpdates,
                                             POINTS_NAMESPACE, UNTESTED)


@pytest.fixture(scope='module')
def snapshot(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    model = sensor_model(log)
    monitor = ConsistencyMonitor()
    stamps, ranges, poses = log.timestamps[:80], log.ranges[:80], log.laser_poses[:80]
    for stamp, scan in zip(stamps, ranges):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps, poses)
    # a wrong loop closure drags the second half of the excerpt aside
    displaced = poses.copy()
    displaced[40:] = se2.compose(se2.compose(poses[40], np.array([0.3, 0.0, 0.05])),
                                 se2.relative(poses[40], poses[40:]))
    monitor.update_trajectory(stamps, displaced)
    return monitor.evaluate()


@pytest.fixture(scope='module')
def assessment(snapshot):
    return explain(snapshot.scans(), snapshot.result)


def test_one_marker_per_keyframe_coloured_by_verdict(snapshot, assessment):
    result = snapshot.result
    assert not assessment.consistent
    assert assessment.flagged.any() and not assessment.flagged.all()
    points = misaligned_endpoints(snapshot.scans(), assessment)
    array = MarkerUpdates().changed(snapshot, assessment, snapshot, lambda: points, 'map',
                                    Time(sec=5))
    keyframes = [m for m in array.markers if m.ns == KEYFRAME_NAMESPACE]
    assert [m.id for m in keyframes] == snapshot.ids.tolist()
    for marker, pose, bad, tested in zip(keyframes, snapshot.poses, assessment.flagged,
                                         result.overlap_counts):
        assert marker.header.frame_id == 'map' and marker.header.stamp.sec == 5
        assert (marker.pose.position.x, marker.pose.position.y) == pytest.approx(pose[:2])
        yaw = 2 * np.arctan2(marker.pose.orientation.z, marker.pose.orientation.w)
        assert np.angle(np.exp(1j * (yaw - pose[2]))) == pytest.approx(0.0, abs=1e-9)
        expected = INCONSISTENT if bad else CONSISTENT if tested else UNTESTED
        assert marker.color == expected
    [cloud] = [m for m in array.markers if m.ns == POINTS_NAMESPACE]
    assert cloud.type == Marker.POINTS and cloud.action == Marker.ADD
    np.testing.assert_allclose([(p.x, p.y) for p in cloud.points], points)
    [places] = [m for m in array.markers if m.ns == CHANGES_NAMESPACE]
    assert places.type == Marker.SPHERE_LIST
    assert [(p.x, p.y) for p in places.points] == [(c.x, c.y) for c in assessment.changes]
    [legend] = [m for m in array.markers if m.ns == LEGEND_NAMESPACE]
    assert 'misaligned' in legend.text and 'changed places' in legend.text


def test_a_consistent_verdict_deletes_the_cloud(snapshot, assessment):
    consistent = dataclasses.replace(assessment, misalignments=(),
                                     misaligned_scans=np.zeros_like(assessment.misaligned_scans))
    array = MarkerUpdates().changed(snapshot, consistent, snapshot, lambda: np.ones((3, 2)),
                                    'map', Time())
    [cloud] = [m for m in array.markers if m.ns == POINTS_NAMESPACE]
    assert cloud.action == Marker.DELETE and not cloud.points
    arrows = [m for m in array.markers if m.ns == KEYFRAME_NAMESPACE]
    assert all(m.color != INCONSISTENT for m in arrows)


def test_updates_carry_only_what_changed(shared_data, snapshot, assessment):
    updates = MarkerUpdates()
    calls = []

    def points():
        calls.append(1)
        return misaligned_endpoints(snapshot.scans(), assessment)

    first = updates.changed(snapshot, assessment, snapshot, points, 'map', Time())
    assert len(first.markers) == snapshot.keyframe_count + 3 and len(calls) == 1
    assert updates.changed(snapshot, assessment, snapshot, points, 'map', Time()).markers == []
    assert len(calls) == 1  # the same verdict: no new points
    # one keyframe moves: its arrow only, until a new verdict comes
    moved_poses = snapshot.poses.copy()
    moved_poses[3, 0] += 0.5
    moved = dataclasses.replace(snapshot, poses=moved_poses)
    delta = updates.changed(moved, assessment, snapshot, points, 'map', Time())
    arrows = [m for m in delta.markers if m.ns == KEYFRAME_NAMESPACE]
    assert [m.id for m in arrows] == [int(snapshot.ids[3])] and len(calls) == 1
    renewed = explain(moved.scans(), snapshot.result)
    again = updates.changed(moved, renewed, moved, points, 'map', Time())
    assert {m.ns for m in again.markers} >= {POINTS_NAMESPACE, CHANGES_NAMESPACE}
    assert len(calls) == 2
    assert len(updates.all().markers) == snapshot.keyframe_count + 3
    # another frame redraws every keyframe
    elsewhere = updates.changed(moved, renewed, moved, points, 'odom', Time())
    assert len([m for m in elsewhere.markers if m.ns == KEYFRAME_NAMESPACE]) == \
        snapshot.keyframe_count
    [cleared] = updates.clear('map', Time()).markers
    assert cleared.action == Marker.DELETEALL and updates.all().markers == []
    # after a reset every keyframe is drawn again
    redrawn = updates.changed(moved, renewed, moved, points, 'odom', Time())
    assert len([m for m in redrawn.markers if m.ns == KEYFRAME_NAMESPACE]) == \
        snapshot.keyframe_count
