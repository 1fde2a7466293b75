"""Each single-pose source of the live node gives the verdict `replay` gives on a bag of the
same messages (node in its own process, real Intel scans, a wrong loop closure)."""
from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path as FilePath

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from map_consistency_ros.cli.main import main
from map_consistency_ros.core import se2
from map_consistency_ros.io import messages
from map_consistency_ros.io.bags import BagTopics, BagWriter
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.ros.conversions import message_class

REPO = FilePath(__file__).resolve().parents[2]
SCANS = 120
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
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
def test_single_pose_source_matches_replay(source, stream, tmp_path, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 200)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path / 'ros_log'))
    stamps, ranges, poses, model = stream
    msgtype = SOURCES[source]
    node = subprocess.Popen([sys.executable, '-m', 'map_consistency_ros.ros.node', '--ros-args',
                             '-p', f'pose_source:={source}',
                             '-p', 'scan_reliability:=reliable'], cwd=REPO, env=dict(os.environ),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    context = Context()
    rclpy.init(context=context)
    probe = Node('probe', context=context)
    reports: list[dict] = []
    probe.create_subscription(String, '/map_consistency/report',
                              lambda m: reports.append(json.loads(m.data)), LATCHED)
    # reliable scans (a parameter of the node): nothing may be lost on a loaded machine
    scan_pub = probe.create_publisher(message_class(messages.SCAN_TYPE), 'scan', SCANS)
    pose_pub = probe.create_publisher(message_class(msgtype), 'pose', SCANS)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    bag = tmp_path / 'sent'
    try:
        deadline = time.monotonic() + 30
        while (scan_pub.get_subscription_count() == 0 or pose_pub.get_subscription_count() == 0
               ) and time.monotonic() < deadline:
            time.sleep(0.05)
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
        code = main(['replay', str(bag), '--quiet', '--report', str(tmp_path / 'r.json')])
        report = json.loads((tmp_path / 'r.json').read_text())
        expected = report['summary']
        deadline = time.monotonic() + 30
        while not (reports and reports[-1]['scans'] == expected['scans']
                   and reports[-1]['judged_keyframes'] == expected['scans']) and (
                time.monotonic() < deadline):
            time.sleep(0.1)
        node_report = reports[-1] if reports else {}
    finally:
        executor.shutdown()
        probe.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=5)
        node.terminate()
        node.wait(timeout=10)
    assert report['topics']['pose_type'] == msgtype
    assert report['node_parameters']['pose_source'] == source
    assert 20 < expected['scans'] < SCANS  # keyframes by travelled distance / turned angle
    assert expected['inconsistent_scans'] > 0  # the paper's test sees the jump
    assert code == (0 if report['verdict'] == 'consistent' else 1)
    # the node says what replay says: the paper's figures and the two-stage verdict
    for key, value in expected.items():
        if key != 'consistent':
            assert node_report.get(key) == value, key
    assert node_report['paper_consistent'] == expected['consistent']
    assert node_report['consistent'] == (report['verdict'] == 'consistent')
    assert node_report['summary_line'] == report['summary_line']
    keyframe_stamps = np.array(report['keyframe_stamps'])
    np.testing.assert_allclose(node_report['misaligned_scans'],
                               keyframe_stamps[report['misaligned_scans']], atol=1e-6)
