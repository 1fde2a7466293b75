"""The live map-consistency node: scans and the SLAM trajectory in; verdict, markers, diagnostics
out.

Subscription callbacks only convert messages and queue them; one worker thread owns the
ConsistencyMonitor, drains the queues (bursts of trajectories coalesce into the newest) and
publishes. Services run in their own callback group, so a DCS retune never blocks monitoring.
The contract (topics, QoS, parameters, diagnostics) is in docs/node.md.
"""
from __future__ import annotations

import json
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Path
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Bool, Float64, Float64MultiArray, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from map_consistency_ros.core.consistency import ConsistencyParameters, inconsistent_endpoints
from map_consistency_ros.core.tuning import TuningSettings, tune_dcs
from map_consistency_ros.core.monitor import ConsistencyMonitor, MonitorSettings, UpdateSummary
from map_consistency_ros.ros import conversions
from map_consistency_ros.ros.diagnostics import MonitorHealth, map_status
from map_consistency_ros.ros.markers import consistency_markers

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST)
RELIABLE = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)

_TEST = ConsistencyParameters()
_MONITOR = MonitorSettings()
_TUNING = TuningSettings()

# name -> (default, description, (low, high) or None); the type is the default's. Defaults of
# the science come from its dataclasses. Everything is read-only (the monitor's caches depend
# on it); rclpy enforces the ranges at start-up.
PARAMETERS = {
    # the original implementation's usable range
    'max_range': (8.0, 'usable laser range (m); longer or invalid beams count as free space',
                  (0.1, 1000.0)),
    'laser_offset': (list(_MONITOR.laser_offset),
                     'pose [x, y, yaw] of the laser in the keyframe frame', None),
    'stamp_tolerance': (_MONITOR.stamp_tolerance,
                        'largest |pose stamp - scan stamp| of a keyframe (s)', (0.0, 1.0)),
    'max_buffered_scans': (_MONITOR.max_buffered_scans,
                           'scans waiting for a pose; the oldest are dropped beyond',
                           (1, 1_000_000)),
    'scan_queue_depth': (50, 'depth of the scan subscription (sensor-data QoS)', (1, 10_000)),
    'move_tolerance': (_MONITOR.move_tolerance, 'a keyframe moving further is measured again (m)',
                       (0.0, 10.0)),
    'move_angle_tolerance': (_MONITOR.move_angle_tolerance,
                             'a keyframe turning further is measured again (rad)', (0.0, 3.14)),
    'cell_size': (_MONITOR.cell_size, 'cell of the spatial index of scan extents (m)',
                  (0.1, 1000.0)),
    'alpha': (_TEST.alpha, 'pairwise test level', (1e-9, 0.5)),
    'local_alpha': (_TEST.local_alpha, 'level of the local scale fit on the incremental solution',
                    (1e-9, 0.5)),
    'failure_probability': (_TEST.failure_probability,
                            'probability that one pairwise test fails', (1e-9, 0.5)),
    'binomial_alpha': (_TEST.binomial_alpha, 'level of the cascaded (binomial) test per scan',
                       (1e-9, 0.5)),
    'local_window': (_TEST.local_window, 'temporally adjacent scans that fit a local scale',
                     (0, 1000)),
    'min_points': (_TEST.min_points, 'pairs with fewer inconsistent points are not tested',
                   (1, 100_000)),
    'trim_largest': (_TEST.trim_largest, 'largest distances dropped per pair before its statistic',
                     (0, 1000)),
    'default_scale': (_TEST.default_scale, 'scale of a scan without local estimate (m)',
                      (1e-6, 10.0)),
    'min_scale': (_TEST.min_scale, 'floor on every local scale (m)', (0.0, 10.0)),
    'flag_window': (_TEST.flag_window,
                    'keep a flag only with another flagged scan this close (0: off)', (0, 1000)),
    'phi_min': (_TUNING.phi_min, 'smallest DCS Phi of the retune search', (1e-12, 1e6)),
    'phi_max': (_TUNING.phi_max, 'largest DCS Phi of the retune search', (1e-9, 1e9)),
    'grid_steps': (_TUNING.grid_steps, 'grid points of the Phi search (even in sqrt(Phi))',
                   (3, 10_000)),
    'tuning_tolerance': (_TUNING.tolerance, 'the Phi search stops when its bracket is narrower',
                         (1e-12, 1e3)),
    'dcs_iterations': (_TUNING.iterations, 'solver iterations per DCS solve', (1, 10_000)),
    'tuning_workers': (_TUNING.workers,
                       'DCS solves at once during a retune (0: one per CPU, at most 4)', (0, 64)),
    'frame_id': ('', 'frame of the markers; empty: the trajectory\'s frame, else "map"', None),
    'stale_timeout': (5.0, 'diagnostics turn STALE after this long without input (s)',
                      (0.1, 3600.0)),
    'diagnostics_period': (1.0, 'period of /diagnostics (s)', (0.05, 60.0)),
    'warning_period': (5.0, 'a bad-input warning per topic at most this often (s)',
                       (0.0, 3600.0)),
    'max_marker_pairs': (200, 'failed pairs whose points are drawn', (0, 100_000)),
    'service_timeout': (60.0, 'longest wait of a service for the worker (s)', (0.1, 3600.0)),
}


def _descriptor(description: str, bounds: tuple | None) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(description=description, read_only=True)
    if bounds is not None and isinstance(bounds[0], int):
        descriptor.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1])]
    elif bounds is not None:
        descriptor.floating_point_range = [FloatingPointRange(from_value=float(bounds[0]),
                                                              to_value=float(bounds[1]))]
    return descriptor


class MapConsistencyNode(Node):
    """The `map_consistency` node (see docs/node.md for its contract)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('map_consistency', **kwargs)
        self._declare_parameters()
        value = self._value
        if len(value('laser_offset')) != 3:
            raise ValueError('laser_offset must have 3 values [x, y, yaw]')
        self._monitor = ConsistencyMonitor(
            ConsistencyParameters(
                alpha=value('alpha'), local_alpha=value('local_alpha'),
                failure_probability=value('failure_probability'),
                binomial_alpha=value('binomial_alpha'), local_window=value('local_window'),
                min_points=value('min_points'), trim_largest=value('trim_largest'),
                default_scale=value('default_scale'), min_scale=value('min_scale'),
                flag_window=value('flag_window')),
            MonitorSettings(
                laser_offset=tuple(float(v) for v in value('laser_offset')),
                stamp_tolerance=value('stamp_tolerance'),
                max_buffered_scans=value('max_buffered_scans'),
                move_tolerance=value('move_tolerance'),
                move_angle_tolerance=value('move_angle_tolerance'),
                cell_size=value('cell_size')))
        self._tuning = TuningSettings(
            phi_min=value('phi_min'), phi_max=value('phi_max'), grid_steps=value('grid_steps'),
            tolerance=value('tuning_tolerance'), iterations=value('dcs_iterations'),
            workers=value('tuning_workers'), parameters=self._monitor.parameters)
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._scans: deque = deque(maxlen=value('max_buffered_scans'))
        self._path: tuple[np.ndarray, np.ndarray, str] | None = None
        self._constraints: np.ndarray | None = None
        self._jobs: deque[tuple[Callable[[], object], Future]] = deque()
        self._frame_id = value('frame_id') or 'map'
        self._last_input: float | None = None
        self._problems = 0
        self._last_problem = ('', -math.inf)
        self._warned: dict[str, float] = {}
        self._latency: float | None = None
        self._phi: float | None = None
        self._retuning = threading.Lock()
        self._snapshot = self._monitor.snapshot()  # replaced whole by the worker, read anywhere

        self._markers = self.create_publisher(MarkerArray, '~/markers', RELIABLE)
        self._diagnostics = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._consistent = self.create_publisher(Bool, '~/consistent', LATCHED)
        self._report = self.create_publisher(String, '~/report', LATCHED)
        self._tuned_phi = self.create_publisher(Float64, '~/tuned_phi', LATCHED)
        self._optimized = self.create_publisher(Path, '~/optimized_trajectory', LATCHED)

        inputs = MutuallyExclusiveCallbackGroup()
        scan_qos = QoSProfile(depth=value('scan_queue_depth'),
                              reliability=qos_profile_sensor_data.reliability,
                              durability=qos_profile_sensor_data.durability,
                              history=HistoryPolicy.KEEP_LAST)
        self.create_subscription(LaserScan, 'scan', self._on_scan, scan_qos,
                                 callback_group=inputs)
        self.create_subscription(Path, 'trajectory', self._on_trajectory, RELIABLE,
                                 callback_group=inputs)
        self.create_subscription(Float64MultiArray, 'constraints', self._on_constraints,
                                 RELIABLE, callback_group=inputs)
        services = ReentrantCallbackGroup()
        self.create_service(Trigger, '~/check', self._on_check, callback_group=services)
        self.create_service(Trigger, '~/retune_dcs', self._on_retune, callback_group=services)
        self.create_timer(value('diagnostics_period'), self._publish_diagnostics,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self._worker = threading.Thread(target=self._work, name='map_consistency_worker',
                                        daemon=True)
        self._worker.start()

    # -- parameters --------------------------------------------------------------------------

    def _declare_parameters(self) -> None:
        for name, (default, description, bounds) in PARAMETERS.items():
            if bounds is not None and isinstance(bounds[0], float):
                default = float(default)  # a double parameter even where the default is whole
            self.declare_parameter(name, default, _descriptor(description, bounds))

    def _value(self, name: str):
        return self.get_parameter(name).value

    # -- input callbacks (cheap: convert and queue) -----------------------------------------

    def _input_problem(self, topic: str, message: str) -> None:
        """Count a bad message, keep it for diagnostics, warn at most once per period."""
        now = time.monotonic()
        with self._lock:
            self._problems += 1
            self._last_problem = (f'{topic}: {message}', now)
        if now - self._warned.get(topic, -math.inf) >= self._value('warning_period'):
            self._warned[topic] = now
            self.get_logger().warning(f'ignored bad input on {topic}: {message}')

    def _touch(self) -> None:
        with self._lock:
            self._last_input = time.monotonic()

    def _on_scan(self, msg: LaserScan) -> None:
        self._touch()
        try:
            scan = conversions.scan_to_numpy(msg, self._value('max_range'))
        except ValueError as error:
            self._input_problem('scan', str(error))
            return
        self._scans.append(scan)
        self._wake.set()

    def _on_trajectory(self, msg: Path) -> None:
        self._touch()
        try:
            stamps, poses = conversions.path_to_numpy(msg)
        except ValueError as error:
            self._input_problem('trajectory', str(error))
            return
        with self._lock:
            self._path = (stamps, poses, msg.header.frame_id)
        self._wake.set()

    def _on_constraints(self, msg: Float64MultiArray) -> None:
        try:
            rows = conversions.constraints_to_numpy(msg)
        except ValueError as error:
            self._input_problem('constraints', str(error))
            return
        with self._lock:
            self._constraints = rows
        self._wake.set()

    # -- worker ------------------------------------------------------------------------------

    def _work(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(timeout=0.5)
            self._wake.clear()
            try:
                self._work_once()
            except Exception as error:  # noqa: BLE001 - the worker must outlive any bug
                self.get_logger().error(f'monitor update failed: {error!r}')

    def _work_once(self) -> None:
        monitor = self._monitor
        while self._scans:
            stamp, ranges, model = self._scans.popleft()
            try:
                monitor.add_scan(stamp, ranges, model)
            except ValueError as error:
                self._input_problem('scan', str(error))
        with self._lock:
            path, self._path = self._path, None
            constraints, self._constraints = self._constraints, None
        if constraints is not None:
            try:
                monitor.set_constraints(constraints)
            except ValueError as error:
                self._input_problem('constraints', str(error))
        summary = None
        if path is not None:
            stamps, poses, frame_id = path
            self._frame_id = self._value('frame_id') or frame_id or 'map'
            summary = self._update(lambda: monitor.update_trajectory(stamps, poses))
        elif monitor.pending:
            summary = self._update(monitor.refresh)
        while self._jobs:
            job, future = self._jobs.popleft()
            try:
                future.set_result(job())
            except Exception as error:  # noqa: BLE001 - handed to the waiting service
                future.set_exception(error)
        self._snapshot = monitor.snapshot()
        if summary is not None and summary.changed:
            self._publish_verdict()

    def _update(self, step: Callable[[], UpdateSummary]) -> UpdateSummary | None:
        try:
            summary = step()
        except ValueError as error:
            self._input_problem('trajectory', str(error))
            return None
        for warning in summary.warnings:
            self._input_problem('trajectory', warning)
        if summary.changed:
            self._latency = summary.elapsed
        return summary

    def _submit(self, job: Callable[[], object]) -> Future:
        """Run `job` on the worker thread (the monitor's owner)."""
        future: Future = Future()
        self._jobs.append((job, future))
        self._wake.set()
        return future

    # -- outputs -----------------------------------------------------------------------------

    def _publish_verdict(self) -> None:
        """Markers, ~/consistent, ~/report and /diagnostics (worker thread only)."""
        snapshot = self._snapshot
        result = snapshot.result
        if result is None:
            return
        limit = self._value('max_marker_pairs')
        points = (np.zeros((0, 2)) if result.consistent else
                  inconsistent_endpoints(snapshot.scans(), result, limit))
        stamp = self.get_clock().now().to_msg()
        self._markers.publish(consistency_markers(snapshot, points, self._frame_id, stamp))
        self._consistent.publish(Bool(data=result.consistent))
        report = dict(result.summary(), update_latency_s=self._latency, phi=self._phi,
                      inconsistent_stamps=snapshot.stamps[result.inconsistent].tolist())
        self._report.publish(String(data=json.dumps(report)))
        self._publish_diagnostics()

    def _health(self) -> MonitorHealth:
        snapshot = self._snapshot
        result = snapshot.result
        now = time.monotonic()
        with self._lock:
            last_input, problems, (problem, when) = (self._last_input, self._problems,
                                                     self._last_problem)
        stale_timeout = self._value('stale_timeout')
        return MonitorHealth(
            keyframes=snapshot.keyframe_count, buffered_scans=snapshot.buffered_scans,
            overlapping_pairs=0 if result is None else result.overlapping_pair_count,
            tested_pairs=0 if result is None else result.tested_pair_count,
            failed_pairs=0 if result is None else result.failed_pair_count,
            inconsistent_scans=0 if result is None else int(result.inconsistent.sum()),
            unmatched_poses=snapshot.unmatched_poses,
            consistent=None if result is None else result.consistent,
            update_latency=self._latency, phi=self._phi, input_problems=problems,
            recent_problem=problem if now - when <= stale_timeout else '',
            seconds_since_input=None if last_input is None else now - last_input,
            stale_timeout=stale_timeout)

    def _publish_diagnostics(self) -> None:
        status = map_status(self._health(), self.get_fully_qualified_name())
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    # -- services ----------------------------------------------------------------------------

    def _check(self) -> tuple[bool, str]:
        """Measure every pair again and publish (worker thread)."""
        summary = self._monitor.recompute()
        self._snapshot = self._monitor.snapshot()
        result = self._snapshot.result
        if result is None:
            return False, 'no keyframes yet: no trajectory pose matches a scan'
        self._latency = summary.elapsed
        self._publish_verdict()
        return True, (f"{'consistent' if result.consistent else 'INCONSISTENT'}: "
                      f'{int(result.inconsistent.sum())} of {result.scan_count} scans fail, '
                      f'{result.failed_pair_count} of {result.tested_pair_count} tested pairs '
                      f'fail; {summary.measured_pairs} pairs measured in {summary.elapsed:.2f} s')

    def _on_check(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/check: recompute everything now and answer with the verdict."""
        try:
            response.success, response.message = self._submit(self._check).result(
                timeout=self._value('service_timeout'))
        except TimeoutError:
            response.success, response.message = False, 'timed out waiting for the monitor'
        return response

    def _on_retune(self, request: Trigger.Request,
                   response: Trigger.Response) -> Trigger.Response:
        """~/retune_dcs: the Phi search on the current graph while monitoring goes on."""
        if not self._retuning.acquire(blocking=False):
            response.success, response.message = False, 'a retune is already running'
            return response
        try:
            response.success, response.message = self._retune()
        except TimeoutError:
            response.success, response.message = False, 'timed out waiting for the monitor'
        except ValueError as error:
            response.success, response.message = False, f'retune failed: {error}'
        finally:
            self._retuning.release()
        return response

    def _retune(self) -> tuple[bool, str]:
        graph, snapshot = self._submit(
            lambda: (self._monitor.pose_graph(), self._monitor.snapshot())).result(
                timeout=self._value('service_timeout'))
        if graph is None:
            return False, ('no pose graph to tune: it needs two keyframes and constraint rows '
                           'on the constraints topic whose stamps match keyframes')
        start = time.monotonic()
        result = tune_dcs(graph, snapshot.ranges, snapshot.model, snapshot.laser_offset,
                          self._tuning)
        elapsed = time.monotonic() - start
        self._phi = result.phi
        self._tuned_phi.publish(Float64(data=result.phi))
        self._optimized.publish(conversions.numpy_to_path(snapshot.stamps, result.poses,
                                                          self._frame_id))
        verdict = result.consistency
        return True, (f'Phi* = {result.phi:.6g} (M = {result.average_inconsistency:.4g} m): '
                      f"optimized map {'consistent' if result.consistent else 'INCONSISTENT'}, "
                      f'{int(verdict.inconsistent.sum())} of {verdict.scan_count} scans fail; '
                      f'{graph.edge_count} edges, {result.profile_phi.size} Phi values in '
                      f'{elapsed:.1f} s')

    def destroy_node(self) -> None:
        self._stop.set()
        self._wake.set()
        self._worker.join(timeout=5.0)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Entry point of `map_consistency_node` and `python -m map_consistency_ros.ros.node`."""
    rclpy.init(args=args)
    node = None
    try:
        try:
            node = MapConsistencyNode()
        except (InvalidParameterValueException, ValueError) as error:
            print(f'map_consistency: bad parameter: {error}', file=sys.stderr)
            return 2
        executor = MultiThreadedExecutor(num_threads=4)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
