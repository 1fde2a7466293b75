"""The live map-consistency node: scans and the SLAM poses in; verdict, markers, diagnostics out.

Callbacks only convert messages into core records (io/messages.py) and queue them: scans in
their own callback group, the heavier poses and constraints in another, so decoding a long Path
never delays a scan. One worker thread owns the feed (core/feed.py, the one shared with bag
replay) and its monitor, applies the queued records (bursts of keyframe estimates coalesce into
the newest; single poses are all kept), and publishes. Every scan the node cannot process is
counted (DDS losses, a full queue, the monitor's full buffer). Services run in a third group,
so a DCS retune never blocks monitoring. The contract is in docs/node.md.
"""
from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import asdict
from concurrent.futures import TimeoutError as FutureTimeout

import numba
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Path
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Bool, Float64, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from map_consistency_ros.core.backend import tune_dcs, tuning_problem
from map_consistency_ros.core.configuration import (PARAMETERS, Configuration, NodeSettings,
                                                    unknown_parameters)
from map_consistency_ros.core.geometry import ScanSet
from map_consistency_ros.core.live import (Constraints, GraphSnapshot, KeyframeEstimate,
                                           MonitorFeed, MonitorSnapshot, PoseGraphNodes,
                                           PoseSample, Scan, sensor_poses, warm_up)
from map_consistency_ros.core.parameters import ParameterSpec
from map_consistency_ros.core.verdict import (Assessment, RegistrationCache,
                                              assessment_report, explain, misaligned_endpoints,
                                              plain, to_json)
from map_consistency_ros.io import messages
from map_consistency_ros.ros.conversions import message_class
from map_consistency_ros.ros.diagnostics import MonitorHealth, map_status, not_monitoring
from map_consistency_ros.ros.markers import MarkerUpdates
from map_consistency_ros.ros import slam_toolbox_graph

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST)
RELIABLE = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)
SINGLE_POSES = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE,
                          history=HistoryPolicy.KEEP_LAST)
# slam_toolbox publishes its graph markers reliable with depth 1; every snapshot counts (the
# bridge chains its headings from one to the next), so keep a few while the node is busy.
GRAPH = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   history=HistoryPolicy.KEEP_LAST)
# Parameters every rclpy node has, and per-topic QoS overrides: not ours, not unknown.
_FOREIGN_PARAMETERS = ('use_sim_time', 'start_type_description_service')
# The second stage's niceness (0 the default, 19 the lowest priority): an explanation may take
# as long as it likes, an update's latency is what the node promises.
EXPLAINER_NICENESS = 19
# The second stage's compiled kernels run on its own thread only. Niceness alone did not keep
# it off the updates: the first 2,500 scans of Freiburg 079 streamed at 100 scans/s had update
# latency median 169-190 ms and p99 1.1-1.6 s with both cores, 94-114 ms and 0.33-0.48 s with
# one (bench_node_load, interleaved runs on a slow machine; docs/node.md).
EXPLAINER_THREADS = 1
_SHUTDOWN_ANSWER_SECONDS = 0.2  # spinning after a stop request, for pending answers to go out
_SHUTTING_DOWN = 'the node is shutting down'


def _descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    # Dynamic typing and no rclpy ranges: wrong types and values reach the one check the
    # node and replay share (one line, exit 2), not an rclpy traceback; the description
    # states the range.
    return ParameterDescriptor(description=spec.help, read_only=True, dynamic_typing=True)


def _ros_default(spec: ParameterSpec):
    return list(spec.default) if spec.kind is tuple else spec.default


class NotMonitoring(Exception):
    """The worker could not start (its compiled kernels failed to load)."""


class ShuttingDown(Exception):
    """A service gave up waiting because the node is shutting down."""


class ExplanationFailed(Exception):
    """The second stage raised: logged and shown in diagnostics, tried again a period later."""


class MapConsistencyNode(Node):
    """The `map_consistency` node (see docs/node.md for its contract)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('map_consistency', **kwargs)
        values = self._declare_parameters()
        for warning in unknown_parameters(self._override_names()):
            self.get_logger().warning(warning)
        config = Configuration.from_values(values)
        self._settings: NodeSettings = config.node
        feed_settings = config.feed
        self._feed = MonitorFeed(config.consistency, config.monitor, feed_settings)
        self._tuning = config.tuning
        self._explanation = config.explanation
        self._registrations = RegistrationCache()  # replaced under _publishing, used under _explaining
        # the last verdict of both stages, the snapshot it judged and its scans (the markers
        # draw from them), and when (time.monotonic)
        self._verdict: tuple[Assessment, MonitorSnapshot, ScanSet] | None = None
        self._verdict_content: tuple[object, dict] = (None, {})  # (verdict, its report part)
        self._explained_at = -math.inf
        self._explaining = threading.Lock()  # one explanation at a time (the cache is shared)
        self._explanation_failure = ''  # why the last explanation failed, '' after a success
        # the worker and the explainer both publish (reentrant: a reset takes a snapshot)
        self._publishing = threading.RLock()
        self._explain_wake = threading.Event()
        settings = self._settings
        self._queue_limit = self._feed.monitor_settings.max_buffered_scans
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._ready = threading.Event()  # set once the worker has loaded the kernels
        self._start_failure = ''  # why loading the kernels failed: the worker never ran
        # queued records with their arrival (time.monotonic), for the update latency
        self._scans: deque[tuple[float, Scan]] = deque()
        # single poses and graph snapshots, in arrival order: the slam_toolbox bridge's
        # association and heading chain depend on it
        self._poses: deque[tuple[float, PoseSample | GraphSnapshot]] = deque()
        self._estimate: tuple[float, KeyframeEstimate] | None = None
        self._constraints: tuple[float, Constraints] | None = None
        self._jobs: deque[tuple[Callable[[], object], Future]] = deque()
        self._frame_id = settings.frame_id or 'map'
        self._last_input: float | None = None
        self._problems = 0
        self._last_problem = ('', -math.inf)
        self._warned: dict[str, float] = {}
        self._latency: float | None = None  # arrival of a change -> its verdict published
        self._updates = 0  # verdicts published for changes of the map (since the start)
        self._timing: dict[str, float] = {}  # seconds per stage of the last update
        self._phi: float | None = None
        self._dds_lost = 0  # scans the middleware reported lost
        self._queue_lost = 0  # scans dropped from the node's full queue
        self._retuning = threading.Lock()
        self._calls = 0  # service calls being answered, for the shutdown to wait for
        self._tuner: threading.Thread | None = None
        self._snapshot = self._feed.snapshot()  # replaced whole by the worker
        self._serial = 0  # counts snapshots: a verdict never replaces one of a newer snapshot
        self._verdict_serial = -1
        self._marker_updates = MarkerUpdates()  # used under _publishing
        self._marker_subscribers = 0

        self._markers = self.create_publisher(MarkerArray, '~/markers', RELIABLE)
        self._diagnostics = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._consistent = self.create_publisher(Bool, '~/consistent', LATCHED)
        self._report = self.create_publisher(String, '~/report', LATCHED)
        self._tuned_phi = self.create_publisher(Float64, '~/tuned_phi', LATCHED)
        self._optimized = self.create_publisher(Path, '~/optimized_trajectory', LATCHED)

        reliability = (ReliabilityPolicy.RELIABLE if settings.scan_reliability == 'reliable'
                       else ReliabilityPolicy.BEST_EFFORT)
        scan_qos = QoSProfile(depth=settings.scan_queue_depth, reliability=reliability,
                              durability=DurabilityPolicy.VOLATILE,
                              history=HistoryPolicy.KEEP_LAST)
        self.create_subscription(
            message_class(messages.SCAN_TYPE), 'scan', self._on_scan, scan_qos,
            callback_group=MutuallyExclusiveCallbackGroup(),
            event_callbacks=SubscriptionEventCallbacks(message_lost=self._on_scans_lost))
        poses = MutuallyExclusiveCallbackGroup()
        pose_type = messages.POSE_SOURCE_TYPES[feed_settings.pose_source]
        if feed_settings.slam_toolbox_graph:
            slam_toolbox_graph.subscribe(self, poses, self._convert, self._convert_bytes,
                                         self._queue_pose)
        elif feed_settings.pose_source != 'path':
            self.create_subscription(message_class(pose_type), 'pose',
                                     lambda msg: self._on_pose(pose_type, msg), SINGLE_POSES,
                                     callback_group=poses)
            # raw, the graph and the Path below: their bytes are read (messages.CDR_RECORDS)
            # where message objects of the whole estimate would hold the interpreter for
            # 50-150 us per pose
            if feed_settings.slam_toolbox:
                self.create_subscription(message_class(messages.MARKER_ARRAY_TYPE),
                                         'graph_visualization', self._on_graph, GRAPH,
                                         callback_group=poses, raw=True)
        else:
            self.create_subscription(Path, 'trajectory', self._on_trajectory, RELIABLE,
                                     callback_group=poses, raw=True)
        self.create_subscription(message_class(messages.CONSTRAINTS_TYPE), 'constraints',
                                 self._on_constraints, RELIABLE, callback_group=poses)
        self.service_host = self._host_services()
        # a steady timer: diagnostics go on (and turn STALE) when a simulated clock pauses
        self.create_timer(settings.diagnostics_period, self._publish_diagnostics,
                          callback_group=MutuallyExclusiveCallbackGroup(),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._worker = threading.Thread(target=self._work, name='map_consistency_worker',
                                        daemon=True)
        self._worker.start()
        self._explainer = threading.Thread(target=self._explain_loop,
                                           name='map_consistency_explainer', daemon=True)
        self._explainer.start()

    def _host_services(self) -> Node:
        """The node's services on a node of their own, spun by a multi-threaded executor.

        A service waits for the worker (a retune for minutes), so it needs a thread of its own,
        which the events executor that takes the messages cannot give. The host ignores the
        command line (a `__node:=` rename would give it this node's name too) and offers the
        services under this node's resolved names, e.g. /map_consistency/check.
        """
        host = Node(f'{self.get_name()}_services', namespace=self.get_namespace(),
                    context=self.context, use_global_arguments=False,
                    start_parameter_services=False)
        services = ReentrantCallbackGroup()
        for name, callback in (('~/check', self._on_check), ('~/retune_dcs', self._on_retune),
                               ('~/reset', self._on_reset)):
            host.create_service(Trigger, self.resolve_service_name(name), callback,
                                callback_group=services)
        return host

    # -- parameters --------------------------------------------------------------------------

    def _declare_parameters(self) -> dict:
        values = {}
        for spec in PARAMETERS:
            value = self.declare_parameter(spec.name, _ros_default(spec),
                                           _descriptor(spec)).value
            # arrays come back as array.array or list: our check takes lists
            sequence = not isinstance(value, (str, bool, int, float)) and value is not None
            values[spec.name] = list(value) if sequence else value
        return values

    def _override_names(self) -> list[str]:
        # rclpy keeps every --params-file / -p value for this node here, declared or not
        return [name for name in self._parameter_overrides
                if name not in _FOREIGN_PARAMETERS and not name.startswith('qos_overrides.')]

    # -- input callbacks (cheap: convert and queue) -----------------------------------------

    def _now(self) -> float:
        """Seconds on the node's clock (simulated time with use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _input_problem(self, topic: str, message: str) -> None:
        """Count a bad message, keep it for diagnostics, warn at most once per period."""
        now = time.monotonic()
        with self._lock:
            self._problems += 1
            self._last_problem = (f'{topic}: {message}', now)
        if now - self._warned.get(topic, -math.inf) >= self._settings.warning_period:
            self._warned[topic] = now
            self.get_logger().warning(f'ignored bad input on {topic}: {message}')

    def _record(self, topic: str, convert: Callable[[], object]):
        """The record `convert()` makes of a message that just arrived on `topic`; None, and
        the problem counted, when it was bad."""
        with self._lock:
            self._last_input = self._now()
        try:
            return convert()
        except ValueError as error:
            self._input_problem(topic, str(error))
            return None

    def _convert(self, topic: str, msgtype: str, msg):
        return self._record(topic, lambda: messages.to_record(msgtype, msg,
                                                              self._feed.settings.max_range))

    def _on_scan(self, msg) -> None:
        record = self._convert('scan', messages.SCAN_TYPE, msg)
        if record is None:
            return
        with self._lock:
            if len(self._scans) >= self._queue_limit:
                self._scans.popleft()
                self._queue_lost += 1
            self._scans.append((time.monotonic(), record))
        self._wake.set()

    def _on_scans_lost(self, info) -> None:
        with self._lock:
            self._dds_lost += info.total_count_change

    def _convert_bytes(self, topic: str, msgtype: str, data: bytes):
        """The record of a raw subscription's message (None when it was bad)."""
        return self._record(topic, lambda: messages.record_from_cdr(
            msgtype, data, _deserialized, self._feed.settings.max_range))

    def _on_trajectory(self, data: bytes) -> None:
        record = self._convert_bytes('trajectory', messages.PATH_TYPE, data)
        if record is not None:
            with self._lock:
                # the full estimate: a newer one replaces it, and the wait counts from the
                # first one it replaced (the latency is that of the oldest input answered)
                first = time.monotonic() if self._estimate is None else self._estimate[0]
                self._estimate = (first, record)
            self._wake.set()

    def _on_pose(self, msgtype: str, msg) -> None:
        self._queue_pose(self._convert('pose', msgtype, msg))

    def _on_graph(self, data: bytes) -> None:
        self._queue_pose(self._convert_bytes('graph_visualization', messages.MARKER_ARRAY_TYPE,
                                             data))

    def _queue_pose(self, record: PoseSample | GraphSnapshot | None) -> None:
        """Queue a single pose or graph snapshot (all kept, in order; None: it was bad)."""
        if record is not None:
            with self._lock:
                if len(self._poses) >= self._queue_limit:
                    self._poses.popleft()
                    self._problems += 1
                    self._last_problem = ('pose: queue full, the oldest pose or graph dropped',
                                          time.monotonic())
                self._poses.append((time.monotonic(), record))
            self._wake.set()

    def _on_constraints(self, msg) -> None:
        record = self._convert('constraints', messages.CONSTRAINTS_TYPE, msg)
        if record is not None:
            with self._lock:
                self._constraints = (time.monotonic(), record)
            self._wake.set()

    # -- worker ------------------------------------------------------------------------------

    def _work(self) -> None:
        _run_kernels_on(self._settings.update_threads)
        # records queue meanwhile: the first update then finds the kernels loaded
        try:
            warm_up()
        except Exception as error:  # noqa: BLE001 - the node stays up to say why it cannot work
            self._start_failure = f'{type(error).__name__}: {error}'
            self.get_logger().error(not_monitoring(self._start_failure))
            return
        self._ready.set()
        while not self._stop.is_set():
            self._wake.wait(timeout=0.5)
            self._wake.clear()
            try:
                self._work_once()
            except Exception as error:  # noqa: BLE001 - the worker must outlive any bug
                self.get_logger().error(f'monitor update failed: {error!r}')

    def _take(self) -> list:
        with self._lock:
            records = list(self._scans) + list(self._poses)
            self._scans.clear()
            self._poses.clear()
            for latest in (self._constraints, self._estimate):
                if latest is not None:
                    records.append(latest)
            self._estimate = self._constraints = None
        return records

    def _work_once(self) -> None:
        """Apply what arrived, answer queued jobs, publish the first stage's update."""
        changed_at = None  # arrival of the oldest record that changed the map
        records = self._take()
        taken = time.monotonic()
        for arrival, record in records:
            summary, reset = self._apply(record)
            if summary is not None or reset:
                changed_at = arrival if changed_at is None else min(changed_at, arrival)
        applied_seconds = time.monotonic() - taken  # every record, changing the map or not
        while self._jobs:
            job, future = self._jobs.popleft()
            _run_kernels_on(0)  # a service caller waits for the job: every core
            try:
                future.set_result(job())
            except Exception as error:  # noqa: BLE001 - handed to the waiting service
                future.set_exception(error)
            finally:
                _run_kernels_on(self._settings.update_threads)
        self._greet_marker_subscribers()
        start = time.perf_counter()
        self._take_snapshot()
        if changed_at is not None:
            self._timing = {'queued_s': max(taken - changed_at, 0.0),
                            'monitor_s': applied_seconds,
                            'snapshot_s': time.perf_counter() - start}
            try:
                self._publish_verdict(changed_at)
            except ExplanationFailed:
                pass  # no verdict yet: diagnostics say why, the explainer tries again
        if self._verdict_behind():
            self._explain_wake.set()

    def _apply(self, record):
        """Apply one record through the feed: (the update or None, whether it reset)."""
        if isinstance(record, (KeyframeEstimate, GraphSnapshot, PoseGraphNodes)):
            self._frame_id = self._settings.frame_id or record.frame_id or 'map'
        applied = self._feed.apply(record)
        topic = {Scan: 'scan', KeyframeEstimate: 'trajectory', PoseSample: 'pose',
                 Constraints: 'constraints',
                 GraphSnapshot: 'graph_visualization',
                 **slam_toolbox_graph.RECORD_TOPICS}[type(record)]
        for warning in applied.warnings:
            self._input_problem(topic, warning)
        if applied.reset:
            self._after_reset(applied.reset)
        return applied.summary, bool(applied.reset)

    def _after_reset(self, reason: str) -> None:
        self.get_logger().warning(f'monitor reset: {reason}')
        with self._publishing:
            self._take_snapshot()
            self._verdict, self._verdict_serial = None, self._serial
            self._markers.publish(self._marker_updates.clear(self._frame_id,
                                                             self.get_clock().now().to_msg()))
            self._registrations = RegistrationCache()
        with self._lock:
            self._dds_lost = self._queue_lost = 0
        self._latency = None

    def _submit(self, job: Callable[[], object]) -> Future:
        """Run `job` on the worker thread (the monitor's owner)."""
        future: Future = Future()
        self._jobs.append((job, future))
        self._wake.set()
        return future

    def _wait(self, future: Future, timeout: float):
        """The future's result; ShuttingDown when the node stops first, NotMonitoring when
        the worker could not start, TimeoutError."""
        deadline = time.monotonic() + timeout
        while not self._stop.is_set():
            if self._start_failure:
                raise NotMonitoring(self._start_failure)
            try:
                return future.result(timeout=min(0.05, max(deadline - time.monotonic(), 0.0)))
            except FutureTimeout:
                if time.monotonic() >= deadline:
                    raise TimeoutError from None
        raise ShuttingDown

    # -- outputs -----------------------------------------------------------------------------

    def _take_snapshot(self) -> None:
        """The monitor's current state becomes the one published (worker thread)."""
        snapshot = self._feed.snapshot()
        with self._publishing:
            self._snapshot, self._serial = snapshot, self._serial + 1

    def _verdict_behind(self) -> bool:
        """Whether the last verdict judged an older snapshot than the current one."""
        return (self._snapshot.result is not None
                and (self._verdict is None or self._verdict[1].result is not self._snapshot.result))

    def _explain(self, snapshot: MonitorSnapshot, cache: RegistrationCache
                 ) -> tuple[tuple[Assessment, MonitorSnapshot, ScanSet], float]:
        """Both stages' verdict on `snapshot` and its seconds (any thread; one explanation
        at a time: `cache` is shared)."""
        with self._explaining:
            start = time.perf_counter()
            try:
                scans = snapshot.scans()
                assessment = explain(scans, snapshot.result, self._explanation, cache=cache)
            except Exception as error:  # noqa: BLE001 - any bug: the node says so and goes on
                self._explanation_failure = (f'explanation failed: {type(error).__name__}: '
                                             f'{error}')
                self.get_logger().error(self._explanation_failure)
                raise ExplanationFailed(self._explanation_failure) from error
            finally:
                self._explained_at = time.monotonic()  # a failure too: no retry in a tight loop
            seconds = time.perf_counter() - start
        self._explanation_failure = ''
        return (assessment, snapshot, scans), seconds

    def _explain_loop(self) -> None:
        """The explainer thread: the second stage on the newest snapshot, at most every
        `explanation_period`, so a long explanation never delays a first-stage update."""
        _yield_to_updates()
        while not self._stop.is_set():
            wait = self._explained_at + self._settings.explanation_period - time.monotonic()
            if wait > 0.0:
                self._stop.wait(wait)
                continue
            if not self._verdict_behind():
                self._explain_wake.wait(timeout=0.5)
                self._explain_wake.clear()
                continue
            with self._publishing:
                snapshot, serial, cache = self._snapshot, self._serial, self._registrations
            try:
                verdict, seconds = self._explain(snapshot, cache)
                with self._publishing:
                    if serial > self._verdict_serial:  # not overtaken by ~/check or a reset
                        self._verdict, self._verdict_serial = verdict, serial
                        self._timing['explanation_s'] = seconds
                        self._publish_outputs(None)
            except ExplanationFailed:
                pass  # logged and shown in diagnostics; the next period tries again
            except Exception as error:  # noqa: BLE001 - the explainer must outlive any bug
                self.get_logger().error(f'explanation failed: {error!r}')

    def _publish_verdict(self, changed_at: float, explain_now: bool = False) -> None:
        """Markers, ~/consistent, ~/report and /diagnostics (worker thread) for a change whose
        input arrived at `changed_at` (time.monotonic): the first stage of the current snapshot
        with the newest second-stage verdict, which the explainer brings up to date.
        `explain_now`, or no verdict yet: the second stage first, on this thread."""
        snapshot = self._snapshot
        if snapshot.result is None:
            return
        if explain_now or self._verdict is None:
            serial = self._serial
            try:
                verdict, seconds = self._explain(snapshot, self._registrations)
            except ExplanationFailed:
                self._publish_diagnostics()  # no verdict to publish, or not the one asked for
                raise
            with self._publishing:
                self._verdict, self._verdict_serial = verdict, serial
                self._timing['explanation_s'] = seconds
        with self._publishing:
            self._publish_outputs(changed_at)

    def _publish_outputs(self, changed_at: float | None) -> None:
        """Publish the current snapshot with the newest verdict (under _publishing);
        `changed_at`: the arrival of the input this answers, None for a new second stage."""
        snapshot = self._snapshot
        assessment, judged, judged_scans = self._verdict
        start = time.perf_counter()
        limit = self._settings.max_marker_pairs
        stamp = self.get_clock().now().to_msg()
        markers = self._marker_updates.changed(
            snapshot, assessment, judged,
            lambda: misaligned_endpoints(judged_scans, assessment, limit),
            self._frame_id, stamp)
        built = time.perf_counter()
        if markers.markers:
            self._markers.publish(markers)
        self._consistent.publish(Bool(data=assessment.consistent))
        self._timing.update(markers_s=built - start, publish_s=time.perf_counter() - built)
        if changed_at is not None:
            self._latency = time.monotonic() - changed_at
            self._updates += 1
        self._report.publish(String(data=to_json(self._report_dict())))
        self._publish_diagnostics()

    def _greet_marker_subscribers(self) -> None:
        """The whole marker array once more when a subscriber joined (RViz started late):
        updates carry only what changed (worker thread only)."""
        count = self._markers.get_subscription_count()
        if count > self._marker_subscribers:
            with self._publishing:
                self._markers.publish(self._marker_updates.all())
        self._marker_subscribers = count

    def _report_dict(self) -> dict:
        """The machine-readable report of ~/report (the one place it is built): the verdict's
        report of the CLI, scans named by their stamps, and the node's own figures."""
        snapshot = self._snapshot
        content = dict(self._verdict_report())
        content.update(plain(dict(update_latency_s=self._latency, updates=self._updates,
                                  phi=self._phi,
                                  timing=self._timing, lost_scans=self._health().lost_scans,
                                  keyframes=snapshot.keyframe_count,
                                  folded_keyframes=snapshot.folded_scans)))
        if self._feed.bridge_counts is not None:
            content['slam_toolbox_bridge'] = plain(asdict(self._feed.bridge_counts))
        return content

    def _verdict_report(self) -> dict:
        """The part of the report that only a new verdict changes, built once per verdict
        (every update publishes a report; a verdict comes at most every explanation_period)."""
        if self._verdict_content[0] is not self._verdict:
            assessment, judged, _ = self._verdict
            content = assessment_report(assessment, judged.stamps)
            content.pop('scans')  # per-scan arrays: the CLI's JSON has room for them, a topic not
            content.update(dict(assessment.result.summary(), consistent=assessment.consistent,
                                paper_consistent=assessment.result.consistent,
                                judged_keyframes=judged.keyframe_count,
                                judged_stamp=judged.estimate_stamp,
                                inconsistent_stamps=judged.stamps[
                                    assessment.result.inconsistent]))
            self._verdict_content = (self._verdict, plain(content))
        return self._verdict_content[1]

    def _health(self) -> MonitorHealth:
        snapshot = self._snapshot
        result = snapshot.result
        assessment = None if self._verdict is None or result is None else self._verdict[0]
        feed, now = self._feed, self._now()
        with self._lock:
            last_input, problems, (problem, when) = (self._last_input, self._problems,
                                                     self._last_problem)
            lost = self._dds_lost + self._queue_lost
            queued = len(self._scans)
        stale_timeout = self._settings.stale_timeout
        return MonitorHealth(
            keyframes=snapshot.keyframe_count, buffered_scans=snapshot.buffered_scans,
            overlapping_pairs=0 if result is None else result.overlapping_pair_count,
            tested_pairs=0 if result is None else result.tested_pair_count,
            failed_pairs=0 if result is None else result.failed_pair_count,
            inconsistent_scans=0 if result is None else int(result.inconsistent.sum()),
            unmatched_poses=snapshot.unmatched_poses,
            consistent=None if assessment is None else assessment.consistent,
            verdict='' if assessment is None else assessment.summary_line(),
            misaligned_scans=0 if assessment is None else int(assessment.flagged.sum()),
            misaligned_regions=0 if assessment is None else len(assessment.misalignments),
            changed_places=0 if assessment is None else len(assessment.changes),
            update_latency=self._latency, phi=self._phi, input_problems=problems,
            recent_problem=problem if time.monotonic() - when <= stale_timeout else '',
            seconds_since_input=None if last_input is None else max(now - last_input, 0.0),
            stale_timeout=stale_timeout, queued_scans=queued,
            lost_scans=lost + snapshot.dropped_scans, gap_scans=feed.gap_scans,
            poses_without_scan=snapshot.poses_without_scan,
            folded_scans=snapshot.folded_scans, resets=feed.resets,
            last_reset=feed.last_reset, starting=not self._ready.is_set(),
            start_failure=self._start_failure, explanation_failure=self._explanation_failure)

    def _publish_diagnostics(self) -> None:
        status = map_status(self._health(), self.get_fully_qualified_name())
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    # -- services ----------------------------------------------------------------------------

    def _answer(self, response: Trigger.Response, work: Callable[[], tuple[bool, str]]
                ) -> Trigger.Response:
        with self._lock:
            self._calls += 1
        try:
            response.success, response.message = work()
        except TimeoutError:
            response.success, response.message = False, 'timed out waiting for the monitor'
        except ShuttingDown:
            response.success, response.message = False, _SHUTTING_DOWN
        except NotMonitoring as failure:
            response.success, response.message = False, not_monitoring(str(failure))
        finally:
            with self._lock:
                self._calls -= 1
        return response

    def _check(self) -> tuple[bool, str]:
        """Measure every pair again and publish (worker thread)."""
        summary = self._feed.monitor.recompute()
        self._take_snapshot()
        result = self._snapshot.result
        if result is None:
            return False, 'no keyframes yet: no trajectory pose matches a scan'
        self._timing = {'monitor_s': summary.elapsed}
        try:
            self._publish_verdict(time.monotonic() - summary.elapsed, explain_now=True)
        except ExplanationFailed as error:
            return False, f'no verdict: {error}'
        assessment = self._verdict[0]
        return True, (f'{assessment.summary_line()}; the paper\'s test: '
                      f'{int(result.inconsistent.sum())} of {result.scan_count} scans fail, '
                      f'{result.failed_pair_count} of {result.tested_pair_count} tested pairs '
                      f'fail; {summary.measured_pairs} pairs measured in {summary.elapsed:.2f} s')

    def _on_check(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/check: recompute everything now and answer with the verdict."""
        return self._answer(response, lambda: self._wait(self._submit(self._check),
                                                         self._settings.service_timeout))

    def _reset(self) -> tuple[bool, str]:
        keyframes = self._feed.monitor.keyframe_count
        self._feed.reset('~/reset service')
        self._after_reset('~/reset service')  # takes the new snapshot
        self._publish_diagnostics()
        return True, f'reset: {keyframes} keyframes forgotten'

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/reset: forget every scan, keyframe and constraint (a new SLAM session)."""
        return self._answer(response, lambda: self._wait(self._submit(self._reset),
                                                         self._settings.service_timeout))

    def _on_retune(self, request: Trigger.Request,
                   response: Trigger.Response) -> Trigger.Response:
        """~/retune_dcs: the Phi search on the current graph while monitoring goes on."""
        if not self._retuning.acquire(blocking=False):
            response.success, response.message = False, 'a retune is already running'
            return response
        try:
            return self._answer(response, self._retune)
        except ValueError as error:
            response.success, response.message = False, f'retune failed: {error}'
            return response
        finally:
            self._retuning.release()

    def _retune(self) -> tuple[bool, str]:
        graph, snapshot = self._wait(self._submit(
            lambda: (self._feed.monitor.pose_graph(), self._feed.monitor.snapshot())),
            self._settings.service_timeout)
        if graph is None:
            return False, ('no pose graph to tune: it needs two keyframes and constraint rows '
                           'on the constraints topic whose stamps match keyframes')
        problem = tuning_problem(graph)
        if problem:
            return False, f'cannot tune this graph honestly: {problem}'
        start = time.monotonic()
        future: Future = Future()

        def tune() -> None:
            try:
                future.set_result(tune_dcs(graph, snapshot.ranges, snapshot.model,
                                           snapshot.laser_offset, self._tuning))
            except Exception as error:  # noqa: BLE001 - handed to the waiting service
                future.set_exception(error)

        # a thread of its own: on shutdown the service answers at once and the search is
        # abandoned (it cannot be interrupted)
        self._tuner = threading.Thread(target=tune, name='map_consistency_retune', daemon=True)
        self._tuner.start()
        result = self._wait(future, math.inf)
        elapsed = time.monotonic() - start
        self._phi = result.phi
        self._tuned_phi.publish(Float64(data=result.phi))
        self._optimized.publish(messages.path_message(message_class, snapshot.stamps,
                                                      result.poses, self._frame_id))
        tuned = ScanSet.from_ranges(snapshot.ranges,
                                    sensor_poses(result.poses, snapshot.laser_offset),
                                    snapshot.model)
        verdict = explain(tuned, result.consistency, self._explanation)
        return True, (f'Phi* = {result.phi:.6g} (M = {result.average_inconsistency:.4g} m): '
                      f'optimized map {verdict.summary_line()}; {graph.edge_count} edges, '
                      f'{result.profile_phi.size} Phi values in {elapsed:.1f} s')

    # -- shutdown ----------------------------------------------------------------------------

    def begin_shutdown(self) -> None:
        """Stop the worker; waiting services answer with a failure."""
        self._stop.set()
        self._wake.set()

    @property
    def answering(self) -> bool:
        """Whether service calls are still being answered."""
        with self._lock:
            return self._calls > 0

    @property
    def executor_kind(self) -> str:
        """The executor the node's messages need (NodeSettings.executor)."""
        return self._settings.executor

    @property
    def busy(self) -> bool:
        """Whether a retune or an update is still running (neither can be interrupted)."""
        return ((self._tuner is not None and self._tuner.is_alive()) or self._worker.is_alive()
                or self._explainer.is_alive())

    def destroy_node(self) -> None:
        self.begin_shutdown()
        self._worker.join(timeout=_SHUTDOWN_ANSWER_SECONDS)
        self._explainer.join(timeout=_SHUTDOWN_ANSWER_SECONDS)
        self.service_host.destroy_node()
        super().destroy_node()


def _message_executor(node: MapConsistencyNode) -> Executor:
    """The executor that takes the node's messages (NodeSettings.executor)."""
    if node.executor_kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # an rclpy older than Jazzy's 7.1 releases that have it
            node.get_logger().warning('executor: events needs rclpy.experimental.'
                                      'EventsExecutor, which this rclpy lacks; using '
                                      'multi_threaded')
        else:
            return EventsExecutor()
    return MultiThreadedExecutor(num_threads=4)


def _deserialized(data: bytes, msgtype: str):
    """rclpy's message of `data`; ValueError for bytes it cannot decode (a raw publisher can
    send anything)."""
    try:
        return deserialize_message(data, message_class(msgtype))
    except RuntimeError as error:
        raise ValueError(f'undecodable {msgtype} message ({error})') from None


def _run_kernels_on(threads: int) -> None:
    """Run the calling thread's compiled kernels on `threads` threads (0: every core numba
    has; more than it has: all of them). Thread-local: other threads keep theirs."""
    available = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(available if threads == 0 else min(threads, available))


def _yield_to_updates() -> None:
    """Lower the calling thread's CPU priority (Linux: nice is per thread) and run its
    compiled kernels on it alone, so that on a loaded machine the second stage takes what the
    first-stage updates leave instead of slowing them down.

    Kernel threads first: the first call launches numba's threading layer, whose threads
    inherit the niceness of the thread that creates them (Linux), and must keep the node's.
    """
    _run_kernels_on(EXPLAINER_THREADS)
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), EXPLAINER_NICENESS)
    except (AttributeError, OSError):  # not Linux, or not allowed: same priority, still correct
        pass


def _spin_until(executor: Executor, stop: threading.Event) -> None:
    while not stop.is_set() and executor.context.ok():
        executor.spin_once(timeout_sec=0.05)


def main(args: list[str] | None = None) -> int:
    """Entry point of `map_consistency_node` and `python -m map_consistency_ros.ros.node`.

    SIGINT / SIGTERM stop the node within a second in every state: pending service calls are
    answered with a failure, a running retune is abandoned.
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    node = None
    abandoned = False
    try:
        try:
            node = MapConsistencyNode()
        except (ParameterException, ValueError) as error:
            print(f'map_consistency: bad parameter: {error}', file=sys.stderr)
            return 2
        except slam_toolbox_graph.MissingInterfaces as error:
            print(f'map_consistency: {error}', file=sys.stderr)
            return 2
        executor = _message_executor(node)
        executor.add_node(node)
        service_executor = MultiThreadedExecutor(num_threads=4)
        service_executor.add_node(node.service_host)
        services_done = threading.Event()
        service_thread = threading.Thread(target=_spin_until, name='map_consistency_services',
                                          args=(service_executor, services_done), daemon=True)
        service_thread.start()
        _spin_until(executor, stop)
        node.begin_shutdown()
        # waiting calls fail at once; spin while their answers go out
        deadline = time.monotonic() + _SHUTDOWN_ANSWER_SECONDS
        answered = False
        while time.monotonic() < deadline and (node.answering or not answered):
            answered = not node.answering
            executor.spin_once(timeout_sec=0.02)
        services_done.set()
        service_thread.join(timeout=0.2)
        service_executor.shutdown(timeout_sec=0.1)
        executor.shutdown(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.destroy_node()
            abandoned = node.busy
        rclpy.try_shutdown()
    if abandoned:
        # a retune's solver threads or a long update cannot be interrupted, and the
        # interpreter would wait for them
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
