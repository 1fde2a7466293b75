"""Each single-pose source of the live node gives the verdict `replay` gives on a bag of the
same messages (node in its own process, real Intel scans, a wrong loop closure)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io import messages
from map_consistency_ros.io.bags import BagTopics, BagWriter
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.ros.conversions import message_class

SCANS = 120
SOURCES = {'odometry': messages.ODOMETRY_TYPE, 'pose': messages.POSE_STAMPED_TYPE,
           'pose_with_covariance': messages.POSE_COVARIANCE_TYPE}


@pytest.fixture(scope='module')
def stream(shared_data):
    """Scans and, per scan, the pose of a localizer that jumps at a wrong loop closure."""
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    order = np.argsort(log.timestamps[:SCANS], kind='stable')
    stamps, ranges = log.timestamps[:SCANS][order], log.ranges[:SCANS][order]
    poses = log.laser_poses[:SCANS][order].copy()
    pivot = 2 * SCANS // 3
    poses[pivot:] = se2.compose(se2.compose(poses[pivot], np.array([0.0, 0.0, 0.1])),
                                se2.relative(poses[pivot], poses[pivot:]))
    return stamps, ranges, poses, sensor_model(log)


@pytest.mark.parametrize('source', sorted(SOURCES))
def test_single_pose_source_matches_replay(source, stream, tmp_path, node_under_test,
                                           node_agrees):
    stamps, ranges, poses, model = stream
    msgtype = SOURCES[source]
    # reliable scans (a parameter of the node): nothing may be lost on a loaded machine
    node = node_under_test('-p', f'pose_source:={source}', '-p', 'scan_reliability:=reliable')
    scan_pub = node.publisher(messages.SCAN_TYPE, 'scan', SCANS)
    pose_pub = node.publisher(msgtype, 'pose', SCANS)
    node.wait_for_subscriptions()
    bag = tmp_path / 'sent'
    with BagWriter(bag, topics=BagTopics(poses='/pose')) as writer:
        for index in range(SCANS):
            scan = messages.scan_message(message_class, stamps[index], ranges[index], model)
            pose = messages.single_pose_message(message_class, msgtype, stamps[index],
                                                poses[index])
            scan_pub.publish(scan)
            pose_pub.publish(pose)
            writer.write_scan(stamps[index], stamps[index], ranges[index], model)
            writer.write_single_pose(stamps[index] + 1e-4, msgtype, stamps[index],
                                     poses[index])
            time.sleep(0.005)
    code, report, node_report = node.replay_and_final_report(bag, tmp_path / 'r.json')
    expected = report['summary']
    assert report['topics']['pose_type'] == msgtype
    assert report['node_parameters']['pose_source'] == source
    assert 20 < expected['scans'] < SCANS  # keyframes by travelled distance / turned angle
    assert expected['inconsistent_scans'] > 0  # the paper's test sees the jump
    node_agrees(node_report, report, code)
