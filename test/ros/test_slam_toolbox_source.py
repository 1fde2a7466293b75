"""pose_source slam_toolbox: the live node gives the verdict `replay` gives on a bag of the same
messages (node in its own process, what slam_toolbox publishes for real Intel scans: a `pose`
per scan, graph markers every 10 scans, a wrong loop closure that moves many vertices)."""
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
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from map_consistency_ros.cli.main import main
from map_consistency_ros.io import messages
from map_consistency_ros.io.bags import BagTopics, BagWriter
from map_consistency_ros.ros.conversions import message_class

REPO = FilePath(__file__).resolve().parents[2]
GRAPH_TOPIC = '/slam_toolbox/graph_visualization'  # what slam_toolbox's node publishes
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def test_slam_toolbox_source_matches_replay(slam_toolbox_stream, tmp_path, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 200)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path / 'ros_log'))
    stream = slam_toolbox_stream
    stamps, count = stream.stamps, len(stream.stamps)
    snapshots = {index: (ids, positions) for index, ids, positions in stream.snapshots}
    # the remapping of the launch file: the node's graph_visualization is slam_toolbox's topic
    node = subprocess.Popen([sys.executable, '-m', 'map_consistency_ros.ros.node', '--ros-args',
                             '-p', 'pose_source:=slam_toolbox',
                             '-p', 'scan_reliability:=reliable',
                             '-r', f'graph_visualization:={GRAPH_TOPIC}'], cwd=REPO,
                            env=dict(os.environ), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    context = Context()
    rclpy.init(context=context)
    probe = Node('probe', context=context)
    reports: list[dict] = []
    probe.create_subscription(String, '/map_consistency/report',
                              lambda m: reports.append(json.loads(m.data)), LATCHED)
    # reliable scans (a parameter of the node): nothing may be lost on a loaded machine
    scan_pub = probe.create_publisher(message_class(messages.SCAN_TYPE), 'scan', count)
    pose_pub = probe.create_publisher(message_class(messages.POSE_COVARIANCE_TYPE), 'pose', count)
    graph_pub = probe.create_publisher(message_class(messages.MARKER_ARRAY_TYPE), GRAPH_TOPIC,
                                       RELIABLE)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    bag = tmp_path / 'sent'
    try:
        deadline = time.monotonic() + 30
        while not all(publisher.get_subscription_count() for publisher in
                      (scan_pub, pose_pub, graph_pub)) and time.monotonic() < deadline:
            time.sleep(0.05)
        with BagWriter(bag, topics=BagTopics(poses='/pose')) as writer:
            for index in range(count):
                stamp = float(stamps[index])
                scan = messages.scan_message(message_class, stamp, stream.ranges[index],
                                             stream.model)
                pose = messages.single_pose_message(message_class, messages.POSE_COVARIANCE_TYPE,
                                                    stamp, stream.poses[index], frame_id='map')
                scan_pub.publish(scan)
                pose_pub.publish(pose)
                writer.write_scan(stamp, stamp, stream.ranges[index], stream.model)
                writer.write_single_pose(stamp + 1e-4, messages.POSE_COVARIANCE_TYPE, stamp,
                                         stream.poses[index], frame_id='map')
                if index in snapshots:
                    # slam_toolbox publishes its graph after the poses of every vertex in it;
                    # the pause keeps that order across the two topics
                    time.sleep(0.05)
                    ids, positions = snapshots[index]
                    graph_pub.publish(messages.graph_markers_message(message_class, stamp, ids,
                                                                     positions))
                    writer.write_graph(stamp + 2e-4, ids, positions)
                time.sleep(0.005)
        code = main(['replay', str(bag), '--quiet', '--report', str(tmp_path / 'r.json')])
        report = json.loads((tmp_path / 'r.json').read_text())
        expected = report['summary']
        deadline = time.monotonic() + 60
        # the final snapshot, judged by both stages (the second may lag while input streams)
        while not (reports and reports[-1]['scans'] == expected['scans']
                   and reports[-1]['judged_keyframes'] == reports[-1]['keyframes']) and (
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
    assert report['topics']['pose_type'] == messages.POSE_COVARIANCE_TYPE
    assert report['topics']['graph'] == GRAPH_TOPIC
    assert report['node_parameters']['pose_source'] == 'slam_toolbox'
    replayed = report['replay']
    assert (replayed['pose_messages'], replayed['graph_snapshots'], replayed['warnings']) == (
        count, len(snapshots), [])
    assert report['slam_toolbox_bridge']['keyframes'] == count
    assert expected['scans'] == count  # every vertex is a keyframe
    assert expected['inconsistent_scans'] > 0  # the paper's test sees the wrong loop closure
    assert code == (0 if report['verdict'] == 'consistent' else 1)
    # the node says what replay says: the paper's figures and the two-stage verdict
    assert node_report.get('slam_toolbox_bridge') == report['slam_toolbox_bridge']
    for key, value in expected.items():
        if key != 'consistent':
            assert node_report.get(key) == value, key
    assert node_report['paper_consistent'] == expected['consistent']
    assert node_report['consistent'] == (report['verdict'] == 'consistent')
    assert node_report['summary_line'] == report['summary_line']
    keyframe_stamps = np.array(report['keyframe_stamps'])
    np.testing.assert_allclose(node_report['misaligned_scans'],
                               keyframe_stamps[report['misaligned_scans']], atol=1e-6)
