"""The node in its own process with a probe node beside it, and the node-equals-replay check
(test_pose_sources.py, test_slam_toolbox_source.py)."""
from __future__ import annotations

import os
import random
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
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
from map_consistency_ros.ros.conversions import message_class

REPO = FilePath(__file__).resolve().parents[2]
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
SETTLE_SECONDS = 1.0


@dataclass
class NodeUnderTest:
    """The node's process and a probe node that publishes its inputs and keeps its reports."""

    process: subprocess.Popen
    probe: Node
    parse: Callable[[str], dict]  # reports are parsed as strictly as their readers do
    reports: list[dict] = field(default_factory=list)
    publishers: list = field(default_factory=list)

    def publisher(self, msgtype: str, topic: str, qos):
        publisher = self.probe.create_publisher(message_class(msgtype), topic, qos)
        self.publishers.append(publisher)
        return publisher

    def wait_for_subscriptions(self, timeout: float = 30.0) -> None:
        """Until the node subscribes to every publisher (or `timeout` seconds), then a moment.

        The probe sees the node's subscription before the node's side has matched the probe's
        publisher; volatile messages sent in between are lost, and a lost slam_toolbox `pose`
        shifts every later vertex (what replay --publish's settle time is for, too)."""
        deadline = time.monotonic() + timeout
        while not all(p.get_subscription_count() for p in self.publishers) and (
                time.monotonic() < deadline):
            time.sleep(0.05)
        time.sleep(SETTLE_SECONDS)

    def replay_and_final_report(self, bag: FilePath, out: FilePath,
                                timeout: float = 60.0) -> tuple[int, dict, dict]:
        """(replay's exit code, replay's report of `bag`, the node's report of the same state).

        The node's report is the newest whose verdict judged the map replay judged: the same
        estimate (judged_stamp) with the same keyframes. Neither arrival order nor how far
        the node's second stage lags on a busy machine changes which report that is. The test
        fails, naming the maps the node judged, when it never judged that one within `timeout`
        seconds."""
        code = main(['replay', str(bag), '--quiet', '--report', str(out)])
        report = self.parse(out.read_text())
        judged = (report['judged_stamp'], report['judged_keyframes'])
        assert judged[0] is not None, 'replay judged no estimate'

        def same_map() -> dict | None:
            return next((node_report for node_report in reversed(list(self.reports))
                         if (node_report.get('judged_stamp'),
                             node_report.get('judged_keyframes')) == judged), None)

        deadline = time.monotonic() + timeout
        while same_map() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        found = same_map()
        if found is None:
            seen = [(content.get('judged_stamp'), content.get('judged_keyframes'),
                     content.get('scan_counts', {}).get('keyframes'))
                    for content in list(self.reports)[-5:]]
            pytest.fail(f'the node never judged the map replay judged {judged}; its last '
                        f'reports judged (stamp, keyframes) with keyframes: {seen}')
        return code, report, found


@pytest.fixture
def node_under_test(tmp_path, monkeypatch, strict_json, process_stopper):
    """`start(*ros_args)`: the node in its own process (random ROS_DOMAIN_ID, localhost only)
    with `--ros-args ros_args`, and the probe; both stopped after the test."""
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 200)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path / 'ros_log'))
    started: list[tuple[NodeUnderTest, Context, SingleThreadedExecutor, threading.Thread]] = []
    processes: list[subprocess.Popen] = []

    def start(*ros_args: str) -> NodeUnderTest:
        process = subprocess.Popen(
            [sys.executable, '-m', 'map_consistency_ros.ros.node', '--ros-args', *ros_args],
            cwd=REPO, env=dict(os.environ), stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        processes.append(process)  # stopped below even if the probe never starts
        context = Context()
        rclpy.init(context=context)
        node = NodeUnderTest(process, Node('probe', context=context), strict_json)
        node.probe.create_subscription(String, '/map_consistency/report',
                                       lambda m: node.reports.append(node.parse(m.data)),
                                       LATCHED)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node.probe)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        started.append((node, context, executor, spinner))
        return node

    yield start
    try:
        for node, context, executor, spinner in started:
            executor.shutdown()
            node.probe.destroy_node()
            rclpy.shutdown(context=context)
            spinner.join(timeout=5)
    finally:
        for process in processes:
            process_stopper(process)


def assert_node_agrees(node_report: dict, report: dict, code: int) -> None:
    """The node says what replay says: the paper's figures and the two-stage verdict."""
    expected = report['summary']
    assert code == (0 if report['verdict'] == 'consistent' else 1)
    for key, value in expected.items():
        if key != 'consistent':
            assert node_report.get(key) == value, key
    assert node_report['paper_consistent'] == expected['consistent']
    assert node_report['consistent'] == (report['verdict'] == 'consistent')
    assert node_report['summary_line'] == report['summary_line']
    # replay names keyframes by their laser records, the node by their stamps
    stamp_of_record = dict(zip(report['scans']['id'], report['keyframe_stamps']))
    np.testing.assert_allclose(node_report['misaligned_scans'],
                               [stamp_of_record[record] for record in report['misaligned_scans']],
                               atol=1e-6)


@pytest.fixture
def node_agrees():
    """assert_node_agrees(node_report, replay_report, replay_exit_code)."""
    return assert_node_agrees
