"""The node in its own process, driven over DDS with real Intel scans and trajectories.

One node process serves the module (start-up dominates the cost). No test relies on what an
earlier one left: each starts from the node's ~/reset and builds the map it needs (fixtures
`mapped` and `misaligned`); the test of a node that never had input gets a node of its own.
"""
from __future__ import annotations

import os
import random
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path as FilePath
from typing import Iterator

import numpy as np
import pytest
import rclpy
from rclpy.serialization import serialize_message
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Path
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Bool, Float64, Float64MultiArray, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from map_consistency_ros.core.consistency import check_consistency
from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.verdict import explain
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.io import messages
from map_consistency_ros.ros.conversions import message_class
from map_consistency_ros.ros.diagnostics import STATUS_NAME
from map_consistency_ros.ros.markers import KEYFRAME_NAMESPACE, POINTS_NAMESPACE
from map_consistency_ros.ros.settings import parameter_file

REPO = FilePath(__file__).resolve().parents[2]
SCANS = 80  # the first 80 Intel scans form a consistent map at the logged poses
# The node's outputs per keyframe: every keyframe is a viewpoint (the folding of keyframes
# into viewpoints is tested in core/live/test_monitor.py and by replay against check).
EVERY_KEYFRAME = ('-p', 'viewpoint_spacing:=0.0', '-p', 'viewpoint_turn:=0.0')
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
TIMEOUT = 20.0


def _wait(predicate, timeout: float = TIMEOUT, what: str = 'condition'):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f'timed out after {timeout} s waiting for {what}')


class Probe:
    """A test-side node: publishes inputs, records the node's outputs."""

    def __init__(self, context: Context) -> None:
        self.context = context
        self.node = Node('probe', context=context)
        self.scan = self.node.create_publisher(LaserScan, 'scan', 100)
        self.trajectory = self.node.create_publisher(Path, 'trajectory', 10)
        self.constraints = self.node.create_publisher(Float64MultiArray, 'constraints', 10)
        self.markers: list[MarkerArray] = []
        self.diagnostics: list[DiagnosticStatus] = []
        self.diagnostics_arrivals: list[float] = []
        self.call_window = (0.0, 0.0)
        self.consistent: list[bool] = []
        self.reports: list[str] = []
        self.phi: list[float] = []
        self.optimized: list[Path] = []
        node_ns = '/map_consistency/'
        self.node.create_subscription(MarkerArray, node_ns + 'markers', self.markers.append, 10)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50)
        self.node.create_subscription(Bool, node_ns + 'consistent',
                                      lambda m: self.consistent.append(m.data), LATCHED)
        self.node.create_subscription(String, node_ns + 'report',
                                      lambda m: self.reports.append(m.data), LATCHED)
        self.node.create_subscription(Float64, node_ns + 'tuned_phi',
                                      lambda m: self.phi.append(m.data), LATCHED)
        self.node.create_subscription(Path, node_ns + 'optimized_trajectory',
                                      self.optimized.append, LATCHED)
        self.check = self.node.create_client(Trigger, node_ns + 'check')
        self.retune = self.node.create_client(Trigger, node_ns + 'retune_dcs')
        self.reset = self.node.create_client(Trigger, node_ns + 'reset')

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.diagnostics.extend(s for s in msg.status if s.name == STATUS_NAME)
        self.diagnostics_arrivals.append(time.monotonic())

    def latest_status(self) -> DiagnosticStatus | None:
        return self.diagnostics[-1] if self.diagnostics else None

    def status_value(self, key: str) -> str | None:
        status = self.latest_status()
        values = {} if status is None else {kv.key: kv.value for kv in status.values}
        return values.get(key)

    def call(self, client, timeout: float = 60.0) -> Trigger.Response:
        assert client.wait_for_service(timeout_sec=TIMEOUT), 'service not offered'
        start = time.monotonic()
        future = client.call_async(Trigger.Request())
        _wait(future.done, timeout, 'service response')
        self.call_window = (start, time.monotonic())
        return future.result()


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log, sensor_model(log)


def _isolated_env(log_dir: FilePath) -> dict[str, str]:
    """The environment of a node and its probe alone on a DDS domain of their own."""
    return {**os.environ, 'ROS_DOMAIN_ID': str(random.randint(1, 200)),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_LOG_DIR': str(log_dir)}


@pytest.fixture(scope='module')
def ros_env(tmp_path_factory):
    """Isolated DDS domain and log folder for this module's node and probe."""
    return _isolated_env(tmp_path_factory.mktemp('ros_log'))


@contextmanager
def _node_process(env: dict[str, str]) -> Iterator[subprocess.Popen]:
    command = [sys.executable, '-m', 'map_consistency_ros.ros.node', '--ros-args',
               '--params-file', str(REPO / 'config' / 'map_consistency.yaml'),
               '-p', 'stale_timeout:=4.0', '-p', 'diagnostics_period:=0.2',
               '-p', 'grid_steps:=12', *EVERY_KEYFRAME]
    # a file, not a pipe: nobody reads the node's output until the end
    log_path = FilePath(env['ROS_LOG_DIR']) / 'node_output.txt'
    with open(log_path, 'w') as output:
        process = subprocess.Popen(command, cwd=REPO, env=env, stdout=output,
                                   stderr=subprocess.STDOUT, text=True)
        try:
            yield process
        finally:
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
            print(log_path.read_text()[-4000:])  # shown by pytest when a test failed


@contextmanager
def _ros_variables(env: dict[str, str]) -> Iterator[None]:
    """os.environ's ROS_ variables as in `env` for the duration (rclpy reads them there)."""
    keys = [key for key in env if key.startswith('ROS_')]
    saved = {key: os.environ.get(key) for key in keys}
    os.environ.update({key: env[key] for key in keys})
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@contextmanager
def _spinning(node: Node, context: Context) -> Iterator[None]:
    """`node` served by an executor of its own on a thread; destroyed on exit."""
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield
    finally:
        executor.shutdown()
        spinner.join(timeout=5)
        node.destroy_node()


@contextmanager
def _probe_of(env: dict[str, str]) -> Iterator[Probe]:
    with _ros_variables(env):
        context = Context()
        rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
        probe = Probe(context)
    try:
        with _spinning(probe.node, context):
            _wait(lambda: probe.trajectory.get_subscription_count() > 0
                  and probe.scan.get_subscription_count() > 0, what='the node to subscribe')
            yield probe
    finally:
        rclpy.shutdown(context=context)


@pytest.fixture(scope='module')
def node_process(ros_env):
    with _node_process(ros_env) as process:
        yield process


@pytest.fixture(scope='module')
def probe(node_process, ros_env):
    with _probe_of(ros_env) as probe:
        yield probe


@pytest.fixture
def idle_probe(tmp_path):
    """A probe beside a node of its own that has had no input at all."""
    env = _isolated_env(tmp_path)
    with _node_process(env), _probe_of(env) as probe:
        yield probe


def _reset(probe: Probe) -> None:
    """The node back to an empty map; later arrays and verdicts are the new session's."""
    resets = int(_wait(lambda: probe.status_value('resets'), what='a status with the resets'))
    assert probe.call(probe.reset).success
    _wait(lambda: probe.status_value('keyframes') == '0'
          and int(probe.status_value('resets')) > resets, what='the reset in the diagnostics')
    probe.markers.clear()
    probe.consistent.clear()
    probe.reports.clear()


@pytest.fixture
def mapped(probe, intel):
    """The node holding the consistent map of the first SCANS Intel scans, and nothing else."""
    _reset(probe)
    log, model = intel
    _publish_scans(probe, log, model, range(SCANS))
    _publish_path(probe, log.timestamps[:SCANS], log.laser_poses[:SCANS])
    _wait(lambda: probe.status_value('keyframes') == str(SCANS), what=f'{SCANS} keyframes')
    _wait(lambda: probe.consistent and probe.consistent[-1] is True, what='consistent = true')
    return probe


@pytest.fixture
def misaligned(mapped, intel):
    """The mapped node after a wrong loop closure moved the poses from scan 50 on."""
    log, _ = intel
    _publish_path(mapped, log.timestamps[:SCANS], _wrong_loop_closure(log.laser_poses[:SCANS], 50))
    _wait(lambda: mapped.consistent and mapped.consistent[-1] is False,
          what='consistent = false')
    return mapped


def _publish_scans(probe: Probe, log, model, indices) -> None:
    for index in indices:
        probe.scan.publish(messages.scan_message(message_class, log.timestamps[index],
                                                 log.ranges[index], model))
        time.sleep(0.004)  # a paced stream, as a laser driver publishes


def _publish_path(probe: Probe, stamps, poses) -> None:
    probe.trajectory.publish(messages.path_message(message_class, stamps, poses, 'map'))


def _marker_state(arrays: list[MarkerArray]) -> dict[tuple[str, int], Marker]:
    """What RViz shows after the arrays received so far (updates carry only changes)."""
    shown: dict[tuple[str, int], Marker] = {}
    for array in list(arrays):
        for marker in array.markers:
            if marker.action == Marker.DELETEALL:
                shown.clear()
            elif marker.action == Marker.DELETE:
                shown.pop((marker.ns, marker.id), None)
            else:
                shown[(marker.ns, marker.id)] = marker
    return shown


def _keyframe_markers(arrays: list[MarkerArray]) -> list[Marker]:
    return [m for (ns, _), m in _marker_state(arrays).items() if ns == KEYFRAME_NAMESPACE]


def _wrong_loop_closure(poses: np.ndarray, start: int, amount: float = 1.0) -> np.ndarray:
    """Poses from `start` on moved rigidly, as a false loop closure would drag them."""
    moved = poses.copy()
    pivot = poses[start]
    shifted = se2.compose(pivot, amount * np.array([0.3, 0.0, 0.05]))
    moved[start:] = se2.compose(shifted, se2.relative(pivot, poses[start:]))
    return moved


def test_config_file_is_generated_from_the_settings():
    # regenerate with: python -m map_consistency_ros.ros.settings > config/map_consistency.yaml
    assert (REPO / 'config' / 'map_consistency.yaml').read_text() == parameter_file()


def test_a_parameter_out_of_range_ends_the_node_with_one_line(ros_env):
    done = subprocess.run([sys.executable, '-m', 'map_consistency_ros.ros', '--ros-args', '-p',
                           'alpha:=0.7'], cwd=REPO, env=ros_env, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2
    assert 'bad parameter' in done.stderr and 'alpha' in done.stderr
    assert 'Traceback' not in done.stderr


def test_before_any_input_the_node_is_stale_and_has_nothing_to_check(idle_probe):
    probe = idle_probe
    first = _wait(probe.latest_status, what='a first status')
    assert first.level in (DiagnosticStatus.WARN, DiagnosticStatus.STALE)
    status = _wait(lambda: probe.status_value('ready') == 'yes' and probe.latest_status(),
                   what='the kernels loaded')
    starting = [s for s in probe.diagnostics if s.level == DiagnosticStatus.WARN]
    assert all(s.message == 'starting: compiling the kernels or loading them from the cache '
                            '(nothing received yet)' for s in starting)
    assert status.level == DiagnosticStatus.STALE
    assert status.message == 'no scan or trajectory received yet'
    response = probe.call(probe.check)
    assert not response.success
    assert response.message.startswith('no keyframes yet')


def test_consistent_map_from_late_and_early_scans(probe, intel):
    _reset(probe)
    log, model = intel
    oracle = check_consistency(ScanSet.from_ranges(log.ranges[:SCANS], log.laser_poses[:SCANS],
                                                   model))
    assert oracle.consistent, 'precondition: the Intel excerpt is consistent offline'
    stamps, poses = log.timestamps[:SCANS], log.laser_poses[:SCANS]
    # Poses 40..49 arrive before their scans, 50..79 after: both orders must register.
    _publish_scans(probe, log, model, range(40))
    _publish_path(probe, stamps[:50], poses[:50])
    _wait(lambda: probe.status_value('unmatched poses') == '10', what='10 poses awaiting scans')
    _publish_scans(probe, log, model, range(40, SCANS))
    _publish_path(probe, stamps, poses)
    _wait(lambda: probe.status_value('keyframes') == str(SCANS), what=f'{SCANS} keyframes')
    _wait(lambda: probe.consistent and probe.consistent[-1] is True, what='consistent = true')
    # the pair counts are those of the map the verdict judged: wait for the verdict on all
    status = _wait(lambda: (s := probe.latest_status()) and s.level == DiagnosticStatus.OK
                   and probe.status_value('judged keyframes') == str(SCANS) and s,
                   what='diagnostics OK on the whole map')
    values = {kv.key: kv.value for kv in status.values}
    assert values['judged keyframes'] == str(SCANS)
    assert values['inconsistent scans'] == '0'
    assert values['overlapping pairs'] == str(oracle.overlapping_pair_count)
    assert values['tested pairs'] == str(oracle.tested_pair_count)
    keyframes = _wait(lambda: len(k := _keyframe_markers(probe.markers)) == SCANS and k,
                      what='a marker per keyframe')
    assert sorted(m.id for m in keyframes) == list(range(SCANS))
    assert all(m.color.g > m.color.r for m in keyframes if m.id < SCANS)


def test_bad_input_warns_without_losing_state(mapped, intel):
    probe = mapped
    log, model = intel
    problems = int(probe.status_value('input problems'))
    late = log.timestamps[SCANS] + 10.0  # after the map: no stamp jump, no reset
    bad_angles = messages.scan_message(message_class, late + 1.0, log.ranges[0], model)
    bad_angles.angle_increment = float('nan')
    probe.scan.publish(bad_angles)
    short = messages.scan_message(message_class, late + 2.0, log.ranges[0], model)
    short.ranges = short.ranges[:90]  # angle fields say 180 beams
    probe.scan.publish(short)
    probe.scan.publish(messages.scan_message(message_class, late + 3.0, np.zeros(0), model))
    # 90 beams
    other_model = messages.scan_message(message_class, late + 4.0, log.ranges[0, :90], model)
    probe.scan.publish(other_model)
    nan_scan = messages.scan_message(message_class, late + 5.0,
                                     np.full(log.ranges.shape[1], np.nan), model)
    probe.scan.publish(nan_scan)  # valid: every beam is free space
    broken = messages.path_message(message_class, log.timestamps[:2], log.laser_poses[:2], 'map')
    broken.poses[1].pose.orientation.w = 0.0
    broken.poses[1].pose.orientation.z = 0.0
    probe.trajectory.publish(broken)
    malformed = Float64MultiArray(data=[1.0, 2.0, 3.0])
    probe.constraints.publish(malformed)
    # bytes no Path serializes to (the node reads Paths from their bytes)
    serialized = serialize_message(messages.path_message(message_class, log.timestamps[:3],
                                                         log.laser_poses[:3], 'map'))
    probe.trajectory.publish(serialized[:len(serialized) // 2])
    _wait(lambda: int(probe.status_value('input problems')) >= problems + 7,
          what='seven bad messages counted')
    status = _wait(lambda: (s := probe.latest_status()) and s.level == DiagnosticStatus.WARN
                   and s, what='diagnostics WARN')
    assert 'bad input' in status.message
    assert probe.status_value('keyframes') == str(SCANS)
    assert node_alive(probe)


def node_alive(probe: Probe) -> bool:
    return probe.check.wait_for_service(timeout_sec=TIMEOUT)


def test_absurd_poses_are_skipped_and_counted(mapped, intel):
    probe = mapped
    log, _ = intel
    problems = int(probe.status_value('input problems'))
    stamps, poses = log.timestamps[:SCANS], log.laser_poses[:SCANS]
    absurd = messages.path_message(message_class, stamps, poses, 'map')
    absurd.poses[3].pose.orientation.z = float('inf')  # (0, 0, inf, 1): no heading
    absurd.poses[4].pose.position.x = 1e300
    probe.trajectory.publish(absurd)
    _wait(lambda: int(probe.status_value('input problems')) >= problems + 2,
          what='two skipped poses counted')
    assert probe.status_value('keyframes') == str(SCANS)
    assert probe.status_value('inconsistent scans') == '0'  # the two kept their last pose


def test_a_path_the_byte_reader_cannot_read_is_deserialized(mapped, intel):
    probe = mapped
    log, _ = intel
    problems = int(probe.status_value('input problems'))
    stamps, poses = log.timestamps[:SCANS], log.laser_poses[:SCANS]
    uneven = messages.path_message(message_class, stamps, poses, 'map')
    uneven.poses[2].header.frame_id = 'base_link'  # entries of different sizes
    uneven.poses[4].pose.position.x = 1e300  # proof that it was read: one absurd pose
    probe.trajectory.publish(uneven)
    _wait(lambda: int(probe.status_value('input problems')) >= problems + 1,
          what='the absurd pose counted')
    assert probe.status_value('keyframes') == str(SCANS)


def test_wrong_loop_closure_turns_the_map_inconsistent(strict_json, mapped, intel):
    probe = mapped
    log, model = intel
    stamps = log.timestamps[:SCANS]
    poses = _wrong_loop_closure(log.laser_poses[:SCANS], 50)
    placed = ScanSet.from_ranges(log.ranges[:SCANS], poses, model)
    oracle = explain(placed, check_consistency(
        placed,
        reference_scans=ScanSet.from_ranges(log.ranges[:SCANS], log.laser_poses[:SCANS], model)))
    assert not oracle.consistent
    optimized = len(probe.optimized)
    # a burst, as an optimizer iterating: only the last estimate counts
    for amount in np.linspace(0.1, 0.9, 9):
        _publish_path(probe, stamps, _wrong_loop_closure(log.laser_poses[:SCANS], 50, amount))
    _publish_path(probe, stamps, poses)
    expected_red = np.flatnonzero(oracle.flagged).tolist()

    def red_keyframes():
        shown = _marker_state(probe.markers)
        if (POINTS_NAMESPACE, 0) not in shown:
            return None
        return sorted(m.id for m in _keyframe_markers(probe.markers) if m.color.r > m.color.g)

    _wait(lambda: red_keyframes() == expected_red, what='red markers of the final estimate')
    _wait(lambda: probe.status_value('misaligned scans') == str(len(expected_red)),
          what='the final count in the diagnostics')
    status = probe.latest_status()
    assert status.level == DiagnosticStatus.ERROR
    assert status.message.startswith('map INCONSISTENT: 1 misaligned region')
    assert probe.status_value('inconsistent scans') == str(int(oracle.result.inconsistent.sum()))
    # one publication, three topics: the probe may take them in any order
    _wait(lambda: probe.consistent and probe.consistent[-1] is False,
          what='~/consistent of the final estimate')
    _wait(lambda: probe.reports and strict_json(probe.reports[-1])['consistent'] is False,
          what='~/report of the final estimate')
    report = strict_json(probe.reports[-1])
    assert report['paper_consistent'] is False
    # every update that changed the map is counted, and its latency is a plausible wait
    assert report['updates'] >= 2 and 0.0 < report['update_latency_s'] < TIMEOUT
    assert report['scan_counts']['keyframes'] == SCANS
    assert report['summary_line'] == oracle.summary_line()
    assert report['misaligned_scans'] == pytest.approx(stamps[oracle.flagged].tolist())
    (region,) = report['misalignments']
    assert set(region) >= {'scans', 'reference_scans', 'dx_m', 'dy_m', 'dtheta_deg',
                           'displacement_m'}
    assert min(region['scans']) >= stamps[50] > max(region['reference_scans'])
    assert report['changes'] and set(report['changes'][0]) >= {'scans', 'x', 'y', 'points'}
    assert len(probe.optimized) == optimized  # only a retune publishes an optimized path


def test_check_service_recomputes_everything(misaligned):
    probe = misaligned
    response = probe.call(probe.check)
    assert response.success
    assert response.message.startswith('INCONSISTENT')
    assert probe.consistent[-1] is False


@contextmanager
def _late_subscriber(probe: Probe, message_type, topic: str, callback, qos) -> Iterator[None]:
    """A subscriber that joins now, on a node and executor of its own: destroying a
    subscription of the probe's node while its executor spins can kill that executor."""
    node = Node('late_subscriber', context=probe.context)
    node.create_subscription(message_type, topic, callback, qos)
    with _spinning(node, probe.context):
        yield


def test_a_late_subscriber_gets_the_latched_verdict(misaligned):
    late: list[bool] = []
    with _late_subscriber(misaligned, Bool, '/map_consistency/consistent',
                          lambda m: late.append(m.data), LATCHED):
        _wait(lambda: late, what='the transient-local verdict')
        assert late[-1] is False


def test_a_late_marker_subscriber_gets_every_marker(mapped):
    late: list[MarkerArray] = []
    with _late_subscriber(mapped, MarkerArray, '/map_consistency/markers', late.append, 10):
        _wait(lambda: len(_keyframe_markers(late)) == SCANS, what='the whole marker array')


def test_retune_without_a_graph_fails_clearly(mapped):
    probe = mapped
    response = probe.call(probe.retune)
    assert not response.success
    assert response.message.startswith('no pose graph to tune')


def test_retune_refuses_a_graph_it_cannot_tune_honestly(mapped, intel):
    probe = mapped
    log, _ = intel
    stamps, logged = log.timestamps[:SCANS], log.laser_poses[:SCANS]
    # two separate pieces of odometry: the graph's 4 poses in two parts
    two_edges = np.concatenate([_constraint_rows(stamps[k:k + 2], logged[k:], logged[k:],
                                                 (0, 1))[:1] for k in (0, 2)])
    tuned = len(probe.phi)
    probe.constraints.publish(messages.constraints_message(message_class, two_edges))
    response = _wait(lambda: (r := probe.call(probe.retune)).message.startswith('cannot') and r,
                     what='the refusal')
    assert not response.success
    assert 'cannot tune this graph honestly: 2 constraints for 4 poses' in response.message
    assert len(probe.phi) == tuned


def _constraint_rows(stamps, odometry_poses, loop_poses, loop):
    """Odometry between consecutive keyframes and one loop closure measured on `loop_poses`."""
    information = [100.0, 0.0, 0.0, 100.0, 0.0, 400.0]
    rows = [[stamps[k], stamps[k + 1], *se2.relative(odometry_poses[k], odometry_poses[k + 1]),
             *information] for k in range(len(stamps) - 1)]
    i, j = loop
    rows.append([stamps[i], stamps[j], *se2.relative(loop_poses[i], loop_poses[j]),
                 *information])
    return np.array(rows)


def test_retune_rejects_the_wrong_loop_closure(mapped, intel):
    probe = mapped
    log, _ = intel
    stamps, logged = log.timestamps[:SCANS], log.laser_poses[:SCANS]
    displaced = _wrong_loop_closure(logged, 50)
    probe.constraints.publish(messages.constraints_message(message_class, 
        _constraint_rows(stamps, logged, displaced, (10, 70))))
    response = _wait(lambda: (r := probe.call(probe.retune)).message.startswith('Phi*') and r,
                     timeout=60.0, what='a retune on the published graph')
    assert response.success
    assert 'optimized map CONSISTENT' in response.message
    start, end = probe.call_window
    during = sum(start < t < end for t in probe.diagnostics_arrivals)
    assert during >= int((end - start) / 0.2) // 2, 'the node kept publishing while tuning'
    phi = _wait(lambda: probe.phi and probe.phi[-1], what='the tuned Phi')
    assert 1e-6 <= phi <= 16.0
    optimized = _wait(lambda: probe.optimized and probe.optimized[-1], what='optimized path')
    optimized_stamps, optimized_poses = messages.path_to_numpy(optimized)
    np.testing.assert_allclose(optimized_stamps, stamps, atol=1e-6)
    error_to_logged = np.linalg.norm(optimized_poses[:, :2] - logged[:, :2], axis=1).max()
    error_to_displaced = np.linalg.norm(optimized_poses[:, :2] - displaced[:, :2], axis=1).max()
    assert error_to_logged < 0.05 < error_to_displaced
    _wait(lambda: probe.status_value('phi') == f'{phi:.6f}', what='Phi in the diagnostics')


def test_reset_service_and_automatic_reset_on_a_stamp_jump(mapped, intel):
    probe = mapped
    log, model = intel
    resets = int(probe.status_value('resets'))
    response = probe.call(probe.reset)
    assert response.success and response.message == f'reset: {SCANS} keyframes forgotten'
    _wait(lambda: probe.status_value('keyframes') == '0'
          and probe.status_value('resets') == str(resets + 1),
          what='no keyframes after the reset, counted')
    # the same session again is accepted (no duplicate stamps after a reset)
    stamps, poses = log.timestamps[:SCANS], log.laser_poses[:SCANS]
    _publish_scans(probe, log, model, range(SCANS))
    _publish_path(probe, stamps, poses)
    _wait(lambda: probe.status_value('keyframes') == str(SCANS), what='the map rebuilt')
    # a SLAM stack restarting with earlier stamps: the node resets by itself
    for index in range(6):
        # earlier by a minute or more, and still after the epoch: a negative stamp is bad input
        probe.scan.publish(messages.scan_message(message_class, stamps[index] - 30.0,
                                                 log.ranges[index], model))
        time.sleep(0.004)
    _wait(lambda: probe.status_value('resets') == str(resets + 2), what='an automatic reset')
    assert 'scan stamps jumped back' in probe.status_value('last reset')
    _wait(lambda: probe.status_value('keyframes') == '0'
          and probe.status_value('buffered scans') == '6',
          what='the new session buffered, no keyframes of the old one')


def test_diagnostics_turn_stale_when_inputs_stop(mapped, node_process):
    probe = mapped
    status = _wait(lambda: (s := probe.latest_status()) and s.level == DiagnosticStatus.STALE
                   and s, what='diagnostics STALE')
    assert status.message.startswith('no input for')
    assert node_process.poll() is None


def test_parameter_table_of_the_docs_is_generated_from_the_settings():
    from map_consistency_ros.ros.settings import parameter_table
    text = (REPO / 'docs' / 'node.md').read_text()
    begin = text.index('-->\n', text.index('<!-- parameters: generated')) + 4
    assert text[begin:text.index('<!-- end of parameters -->')] == parameter_table()
