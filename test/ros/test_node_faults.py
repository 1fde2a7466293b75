"""The node's counts add up under faults: the node in its own process, driven over DDS.

Every status the probe receives must account for every scan received exactly once
(`scans received` == the sum of the other scan counts, core/live/_scan_counts.py), whatever
the timing; after each fault the counts must say what happened, and no scan of a new session
may be lost. Nothing here assumes how fast the machine is: the tests wait for conditions, with
generous timeouts. One node serves the light faults (each starts from its ~/reset and reads
the counts of its own session); the burst gets a node with small queues of its own.
"""
from __future__ import annotations

import os
import random
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path as FilePath
from typing import Iterator

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from map_consistency_ros.io import messages
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.ros.conversions import message_class
from map_consistency_ros.ros.diagnostics import SCAN_KEYS, STATUS_NAME

REPO = FilePath(__file__).resolve().parents[2]
TIMEOUT = 90.0  # seconds any one condition may take on a loaded machine
RECEIVED, *CATEGORIES = SCAN_KEYS.values()
LOST = ('scans lost in the queue', 'scans pushed out of the buffer', 'unplaced scans')
# the probe keeps every scan until the node took it: a count of scans sent is one of received
DEEP = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                  history=HistoryPolicy.KEEP_LAST)


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log, sensor_model(log)


def _wait(condition: Callable[[], object], what: str | Callable[[], str],
          timeout: float = TIMEOUT):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f'timed out after {timeout} s waiting for '
                         f'{what() if callable(what) else what}')


class Probe:
    """Publishes the node's inputs, keeps every status of the map, calls ~/reset."""

    def __init__(self, context: Context, log, model) -> None:
        self.log, self.model = log, model
        self.node = Node('fault_probe', context=context)
        self.scan = self.node.create_publisher(message_class(messages.SCAN_TYPE), 'scan', DEEP)
        self.trajectory = self.node.create_publisher(message_class(messages.PATH_TYPE),
                                                     'trajectory', 10)
        self.reset_client = self.node.create_client(Trigger, '/map_consistency/reset')
        self.statuses: list[dict[str, str]] = []
        self.messages: list[str] = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_status, 100)

    def _on_status(self, array: DiagnosticArray) -> None:
        for status in array.status:
            if status.name == STATUS_NAME:
                self.messages.append(status.message)
                self.statuses.append({kv.key: kv.value for kv in status.values})

    def counts(self) -> dict[str, int]:
        """The scan counts of the newest status."""
        return {key: int(self.statuses[-1][key]) for key in SCAN_KEYS.values()}

    def value(self, key: str) -> int:
        return int(self.statuses[-1][key])

    def send_scan(self, stamp: float, index: int, beams: int | None = None) -> None:
        ranges = self.log.ranges[index % len(self.log.ranges)]
        self.scan.publish(messages.scan_message(
            message_class, float(stamp), ranges if beams is None else ranges[:beams],
            self.model))

    def send_path(self, stamps, poses) -> None:
        self.trajectory.publish(messages.path_message(message_class, np.asarray(stamps),
                                                      np.asarray(poses), 'map'))

    def reset(self) -> dict[str, int]:
        """~/reset; the counts once the status shows it (the session starts empty)."""
        _wait(lambda: self.statuses, 'a status')
        resets = self.value('resets')
        assert self.reset_client.wait_for_service(timeout_sec=TIMEOUT)
        future = self.reset_client.call_async(Trigger.Request())
        _wait(future.done, 'the reset')
        assert future.result().success
        _wait(lambda: self.value('resets') > resets, 'the reset in the diagnostics')
        return self.counts()

    def settled(self, received: int, what: str, timeout: float = TIMEOUT) -> dict[str, int]:
        """The counts once `received` scans arrived and none waits any more."""
        _wait(lambda: self.statuses and self.value(RECEIVED) >= received
              and self.value('waiting scans') == 0, what, timeout)
        return self.counts()

    def assert_every_status_adds_up(self) -> None:
        for status in list(self.statuses):
            counts = [int(status[key]) for key in SCAN_KEYS.values()]
            assert min(counts) >= 0 and counts[0] == sum(counts[1:]), status


@contextmanager
def _node_and_probe(tmp_path: FilePath, intel, *parameters: str) -> Iterator[Probe]:
    """The node in its own process (its own DDS domain, localhost) and the probe; both
    stopped whatever happens."""
    env = {**os.environ, 'ROS_DOMAIN_ID': str(random.randint(1, 200)),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_LOG_DIR': str(tmp_path)}
    output = open(tmp_path / 'node_output.txt', 'w')
    process = subprocess.Popen(
        [sys.executable, '-m', 'map_consistency_ros.ros.node', '--ros-args',
         '-p', 'diagnostics_period:=0.2', '-p', 'scan_reliability:=reliable',
         '-p', 'scan_queue_depth:=5000', *parameters],
        cwd=REPO, env=env, stdout=output, stderr=subprocess.STDOUT)
    context = executor = spinner = probe = None
    try:
        context = Context()
        rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
        probe = Probe(context, *intel)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(probe.node)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        _wait(lambda: probe.scan.get_subscription_count()
              and probe.trajectory.get_subscription_count(), 'the node to subscribe')
        _wait(lambda: probe.statuses and probe.statuses[-1]['ready'] == 'yes',
              'the node to be ready')
        time.sleep(1.0)  # both ends of discovery matched (conftest.py, SETTLE_SECONDS)
        yield probe
    finally:
        try:
            if executor is not None:
                executor.shutdown()
                spinner.join(timeout=5)
            if probe is not None:
                probe.node.destroy_node()
            if context is not None:
                rclpy.shutdown(context=context)
        finally:
            process.terminate()
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            output.close()
            print((tmp_path / 'node_output.txt').read_text()[-3000:])


@pytest.fixture(scope='module')
def probe(tmp_path_factory, intel):
    with _node_and_probe(tmp_path_factory.mktemp('faults'), intel) as probe:
        yield probe


def _session(counts: dict[str, int]) -> int:
    """Scans received in the current session."""
    return counts[RECEIVED] - counts['scans of earlier sessions']


def test_a_frozen_estimate_fails_the_map_and_its_counts_add_up(probe):
    """Many scans, one pose (a stuck estimate): each scan is counted once, the scans that
    disagree at that pose are not folded away, and the map fails saying why."""
    before = probe.reset()
    stamps = probe.log.timestamps[:300]
    for index, stamp in enumerate(stamps):
        probe.send_scan(stamp, index)
        time.sleep(0.002)
    probe.send_path(stamps, np.repeat(probe.log.laser_poses[:1], len(stamps), axis=0))
    probe.settled(before[RECEIVED] + 300, '300 scans accounted for')
    _wait(lambda: probe.value('keyframes') + probe.value('folded scans') == 300,
          'every scan a keyframe or folded')
    counts = probe.counts()
    assert _session(counts) == 300 and counts['rejected scans'] == 0
    assert sum(counts[key] for key in LOST) == 0
    assert counts['keyframes'] > 3  # the building, not one viewpoint
    resent = [time.monotonic()]

    def reported() -> bool:
        # the same estimate again now and then: a node without input for stale_timeout says
        # STALE, not its verdict, while the second stage works through 300 scans at one pose
        if time.monotonic() - resent[0] > 1.0:
            probe.send_path(stamps, np.repeat(probe.log.laser_poses[:1], len(stamps), axis=0))
            resent[0] = time.monotonic()
        return any('the pose estimate stood still' in message
                   for message in probe.messages[-5:])

    _wait(reported, lambda: f'the frozen estimate reported (last status: '
                            f'{probe.messages[-1]!r})')
    probe.assert_every_status_adds_up()


def test_a_restart_behind_a_stray_old_scan_resets_once_and_keeps_every_scan(probe):
    """An old scan of the ending session arrives just before a restarted SLAM stack's scans
    (stamps back by about 100 s, still after the epoch: a negative stamp is bad input): one
    reset, the stray rejected, every new scan a keyframe."""
    before = probe.reset()
    log = probe.log
    stamps = log.timestamps[:40]
    for index, stamp in enumerate(stamps):
        probe.send_scan(stamp, index)
        time.sleep(0.002)
    probe.send_path(stamps, log.laser_poses[:40])
    probe.settled(before[RECEIVED] + 40, 'the first session')
    resets = probe.value('resets')
    probe.send_scan(stamps[5], 5)  # a late scan of the session, long before its newest
    restarted = log.timestamps[:30] - 30.0
    for index, stamp in enumerate(restarted):
        probe.send_scan(stamp, index)
        time.sleep(0.002)
    probe.send_path(restarted, log.laser_poses[:30])
    probe.settled(before[RECEIVED] + 71, 'the restarted session')
    _wait(lambda: probe.value('keyframes') + probe.value('folded scans') == 30,
          'every scan of the new session a keyframe or folded')
    counts = probe.counts()
    assert probe.value('resets') == resets + 1
    assert _session(counts) == 31 and counts['rejected scans'] == 1
    assert counts['scans of earlier sessions'] == before[RECEIVED] + 40
    assert sum(counts[key] for key in LOST) == 0 and probe.value('poses without scan') == 0
    probe.assert_every_status_adds_up()


def test_after_a_reset_the_poses_of_earlier_scans_are_not_scans_never_received(probe):
    """~/reset while the SLAM stack keeps sending its full Path: the poses of the previous
    session's scans wait unmatched, and nothing is called lost or never received."""
    log = probe.log
    probe.reset()
    stamps = log.timestamps[:120]
    for index in range(60):
        probe.send_scan(stamps[index], index)
        time.sleep(0.002)
    probe.send_path(stamps[:60], log.laser_poses[:60])
    _wait(lambda: probe.value('keyframes') + probe.value('folded scans') == 60, 'the map')
    before = probe.reset()
    for index in range(60, 120):
        probe.send_scan(stamps[index], index)
        time.sleep(0.002)
        if index % 10 == 9:
            probe.send_path(stamps[:index + 1], log.laser_poses[:index + 1])
    probe.settled(before[RECEIVED] + 60, 'the new session')
    _wait(lambda: probe.value('keyframes') + probe.value('folded scans') == 60, 'the new map')
    _wait(lambda: probe.value('unmatched poses') == 60, 'the old poses unmatched')
    counts = probe.counts()
    assert _session(counts) == 60 and probe.value('poses without scan') == 0
    assert 'never received' not in probe.messages[-1] and 'lost' not in probe.messages[-1]
    probe.assert_every_status_adds_up()


def test_bad_scans_are_rejected_and_their_poses_not_called_never_received(probe):
    """Scans of another beam geometry, unreadable scans and scans published twice among good
    ones, and a Path naming every stamp: each bad scan counted once, as rejected."""
    log = probe.log
    before = probe.reset()
    stamps = log.timestamps[:100]
    for index, stamp in enumerate(stamps):
        if index % 10 == 3:
            probe.send_scan(stamp, index, beams=100)  # another beam geometry
        elif index % 10 == 7:
            probe.send_scan(stamp, index, beams=1)  # unreadable: one range
        else:
            probe.send_scan(stamp, index)
            if index % 20 == 5:
                probe.send_scan(stamp, index)  # published twice
        time.sleep(0.002)
    probe.send_path(stamps, log.laser_poses[:100])
    probe.settled(before[RECEIVED] + 105, 'every scan accounted for')
    _wait(lambda: probe.value('keyframes') + probe.value('folded scans') == 80, 'the map')
    counts = probe.counts()
    assert _session(counts) == 105 and counts['rejected scans'] == 25
    assert sum(counts[key] for key in LOST) == 0 and probe.value('poses without scan') == 0
    assert 'never received' not in probe.messages[-1]
    probe.assert_every_status_adds_up()


def test_a_burst_faster_than_the_node_drains_is_counted_scan_by_scan(tmp_path, intel):
    """2,000 scans published back to back, a Path every 10, into a node whose queue and
    buffer hold 100: whatever the node could take in time, every scan received is a keyframe,
    folded, or lost (and said where), and the poses of lost scans are not counted again."""
    count = 2000
    with _node_and_probe(tmp_path, intel, '-p', 'max_buffered_scans:=100') as probe:
        log = probe.log
        stamps = log.timestamps[0] + 0.1 * np.arange(count)
        # 40 places, 50 scans each: the map stays small, the scans many
        places = np.arange(count) // 50
        for index in range(count):
            probe.send_scan(stamps[index], int(places[index]))
            if index % 10 == 9:
                probe.send_path(stamps[:index + 1], log.laser_poses[places[:index + 1]])
        counts = probe.settled(count, f'{count} scans accounted for')
        lost = sum(counts[key] for key in LOST)
        _wait(lambda: probe.value('keyframes') + probe.value('folded scans') + lost == count,
              'every scan a keyframe, folded or lost')
        counts = probe.counts()
        assert counts[RECEIVED] == count and counts['rejected scans'] == 0
        assert counts['passed-over scans'] == 0 and probe.value('poses without scan') == 0
        probe.assert_every_status_adds_up()
        if lost:
            assert 'scans lost' in probe.messages[-1]
