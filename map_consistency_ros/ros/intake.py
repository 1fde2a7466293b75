"""The node's intake: subscriptions whose callbacks only convert messages into core records
(io/messages.py, the converter bag replay uses too) and queue them for the engine.

Scans take a callback group of their own, the heavier poses and constraints another, so
decoding a long Path never delays a scan. Queued records carry their arrival (time.monotonic
on entering the callback: decoding counts in the update latency). Scans and single poses are
all kept, in arrival order (the slam_toolbox bridge's association and heading chain depend on
it), up to the monitor's `max_buffered_scans`; of keyframe estimates and constraints, each the
full set, only the newest. Every scan received is counted, and handed on or counted where it
went: scans dropped from the full queue (their stamps) and unreadable ones are handed to the
pipeline's account as a DroppedScans record (core/live/_scan_counts.py), so that
`InputFigures` and a snapshot of the pipeline read before them account for every scan received
(ScanCounts.with_intake). Scans the middleware reports lost never arrived: counted apart. Every
bad message is counted, kept for diagnostics and warned about at most once per
`warning_period` per topic.
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from nav_msgs.msg import Path
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.serialization import deserialize_message

import numpy as np

from map_consistency_ros.core.live import (Constraints, DroppedScans, FeedSettings,
                                           GraphSnapshot, KeyframeEstimate, PoseSample,
                                           PoseSource, Record, Scan)
from map_consistency_ros.io import messages
from map_consistency_ros.ros import slam_toolbox_graph
from map_consistency_ros.ros.conversions import message_class
from map_consistency_ros.ros.qos import GRAPH, RELIABLE, SINGLE_POSES, scan_qos
from map_consistency_ros.core.configuration import NodeSettings, Reliability

# the topic each record comes from, for the input-problem reports
RECORD_TOPICS = {Scan: 'scan', DroppedScans: 'scan', KeyframeEstimate: 'trajectory',
                 PoseSample: 'pose',
                 Constraints: 'constraints', GraphSnapshot: 'graph_visualization',
                 **slam_toolbox_graph.RECORD_TOPICS}


@dataclass(frozen=True)
class InputFigures:
    """What the intake knows at one instant, for /diagnostics."""

    last_input: float | None  # the node's clock at the last message, None before any
    problems: int  # bad messages since the start
    last_problem: tuple[str, float]  # (what, when by time.monotonic)
    middleware_lost: int  # scans the middleware reported lost since the last reset: never received
    # every scan received (since the start) is queued, handed to the engine, or dropped from
    # the full queue or unreadable and not handed over yet
    received_scans: int
    queued_scans: int  # received, not yet taken by the engine
    handed_scans: int  # handed to the engine: scan records and DroppedScans' counts
    lost_scans: int  # dropped from the full queue, not handed over yet
    unreadable_scans: int  # not handed over yet


def _deserialized(data: bytes, msgtype: str):
    """rclpy's message of `data`; ValueError for bytes it cannot decode (a raw publisher can
    send anything)."""
    try:
        return deserialize_message(data, message_class(msgtype))
    except RuntimeError as error:
        raise ValueError(f'undecodable {msgtype} message ({error})') from None


def _header_stamp(msg) -> float:
    """The header stamp of a scan message that could not be read, in seconds; NaN when that
    is unreadable too (a pose naming the scan is then taken for one whose scan never came)."""
    try:
        return messages.stamp_to_seconds(msg.header.stamp)
    except (AttributeError, TypeError, ValueError):
        return math.nan


class Intake:
    """The node's subscriptions and queues (see the module docstring).

    Parameters
    ----------
    node: the node that subscribes (its clock times the inputs, its logger warns).
    settings: the node's settings.
    feed_settings: the pose source and the usable range of the scans.
    queue_limit: scans (and single poses) queued at most; the oldest go beyond.
    wake: set whenever a record is queued.
    """

    def __init__(self, node: Node, settings: NodeSettings, feed_settings: FeedSettings,
                 queue_limit: int, wake: threading.Event) -> None:
        self._node = node
        self._settings = settings
        self._feed_settings = feed_settings
        self._queue_limit = queue_limit
        self._wake = wake
        self._lock = threading.Lock()
        self._scans: deque[tuple[float, Scan]] = deque()
        self._poses: deque[tuple[float, PoseSample | GraphSnapshot]] = deque()
        self._estimate: tuple[float, KeyframeEstimate] | None = None
        # the trajectory's Paths repeat the last one's entries: those are not decoded again
        self._path_reader = messages.PathReader()
        self._constraints: tuple[float, Constraints] | None = None
        self._last_input: float | None = None
        self._problems = 0
        self._last_problem = ('', -math.inf)
        self._warned: dict[str, float] = {}
        self._dds_lost = 0  # scans the middleware reported lost
        self._received = 0  # scan messages received
        self._handed = 0  # of those, handed to the engine (InputFigures.handed_scans)
        self._lost: list[float] = []  # stamps of scans dropped from the full queue, not handed
        self._unreadable: list[float] = []  # header stamps of unreadable scans, not handed

    def subscribe(self) -> None:
        """Create the subscriptions of the pose source (docs/node.md, Inputs)."""
        node, settings, feed_settings = self._node, self._settings, self._feed_settings
        node.create_subscription(
            message_class(messages.SCAN_TYPE), 'scan', self._on_scan,
            scan_qos(settings.scan_queue_depth, settings.scan_reliability == Reliability.RELIABLE),
            callback_group=MutuallyExclusiveCallbackGroup(),
            event_callbacks=SubscriptionEventCallbacks(message_lost=self._on_scans_lost))
        poses = MutuallyExclusiveCallbackGroup()
        pose_type = messages.POSE_SOURCE_TYPES[feed_settings.pose_source]
        if feed_settings.slam_toolbox_graph:
            slam_toolbox_graph.subscribe(node, poses, self._convert, self._convert_bytes,
                                         self._queue_pose)
        elif feed_settings.pose_source != PoseSource.PATH:
            node.create_subscription(message_class(pose_type), 'pose',
                                     lambda msg: self._on_pose(pose_type, msg), SINGLE_POSES,
                                     callback_group=poses)
            # raw, the graph and the Path below: their bytes are read (messages.CDR_RECORDS)
            # where message objects of the whole estimate would hold the interpreter for
            # 50-150 us per pose
            if feed_settings.slam_toolbox:
                node.create_subscription(message_class(messages.MARKER_ARRAY_TYPE),
                                         'graph_visualization', self._on_graph, GRAPH,
                                         callback_group=poses, raw=True)
        else:
            node.create_subscription(Path, 'trajectory', self._on_trajectory, RELIABLE,
                                     callback_group=poses, raw=True)
        node.create_subscription(message_class(messages.CONSTRAINTS_TYPE), 'constraints',
                                 self._on_constraints, RELIABLE, callback_group=poses)

    def now(self) -> float:
        """The time on the node's clock.

        Returns
        -------
        Seconds on the node's clock (simulated time with use_sim_time).
        """
        return self._node.get_clock().now().nanoseconds * 1e-9

    # -- what the engine takes and reports -------------------------------------------------

    def take(self) -> list[tuple[float, Record]]:
        """Take every queued record; the queues are empty after.

        Returns
        -------
        (arrival by time.monotonic, record) of every queued record: the scans dropped since
        the last take (one DroppedScans, when there were), scans, then single poses, each in
        arrival order, then the newest constraints and keyframe estimate.
        """
        with self._lock:
            records = list(self._scans) + list(self._poses)
            self._handed += len(self._scans)
            if self._lost or self._unreadable:
                dropped = DroppedScans(lost=np.array(self._lost),
                                       unreadable=np.array(self._unreadable))
                records.insert(0, (time.monotonic(), dropped))
                self._handed += len(self._lost) + len(self._unreadable)
                self._lost, self._unreadable = [], []
            self._scans.clear()
            self._poses.clear()
            for latest in (self._constraints, self._estimate):
                if latest is not None:
                    records.append(latest)
            self._estimate = self._constraints = None
        return records

    def problem(self, topic: str, message: str) -> None:
        """Count a bad message, keep it for diagnostics, warn at most once per period.

        Parameters
        ----------
        topic: the input it came on ('scan', 'trajectory', ...); warnings are rate-limited
            per topic (NodeSettings.warning_period).
        message: what was wrong with it.
        """
        now = time.monotonic()
        with self._lock:
            self._problems += 1
            self._last_problem = (f'{topic}: {message}', now)
        if now - self._warned.get(topic, -math.inf) >= self._settings.warning_period:
            self._warned[topic] = now
            self._node.get_logger().warning(f'ignored bad input on {topic}: {message}')

    def record_problems(self, record: Record, warnings: tuple[str, ...]) -> None:
        """The warnings of applying `record`, as problems of the topic it came from.

        Parameters
        ----------
        record: the record the pipeline applied.
        warnings: the pipeline's warnings about it, each one problem.
        """
        topic = RECORD_TOPICS[type(record)]
        for warning in warnings:
            self.problem(topic, warning)

    def forget_losses(self) -> None:
        """Start counting the scans the middleware lost afresh (a reset: a new session; the
        pipeline's account keeps the node's own losses by session)."""
        with self._lock:
            self._dds_lost = 0

    def figures(self) -> InputFigures:
        """The intake's figures now.

        Returns
        -------
        The InputFigures: last input, bad messages, scans received, queued, handed over,
        dropped or unreadable, and lost by the middleware. One instant: received ==
        queued + handed + lost + unreadable.
        """
        with self._lock:
            return InputFigures(last_input=self._last_input, problems=self._problems,
                                last_problem=self._last_problem,
                                middleware_lost=self._dds_lost, received_scans=self._received,
                                queued_scans=len(self._scans), handed_scans=self._handed,
                                lost_scans=len(self._lost),
                                unreadable_scans=len(self._unreadable))

    # -- callbacks (cheap: convert and queue) ------------------------------------------------

    def _record(self, topic: str, convert: Callable[[], object]):
        """The record `convert()` makes of a message that just arrived on `topic`; None, and
        the problem counted, when it was bad."""
        with self._lock:
            self._last_input = self.now()
        try:
            return convert()
        except ValueError as error:
            self.problem(topic, str(error))
            return None

    def _convert(self, topic: str, msgtype: str, msg):
        return self._record(topic, lambda: messages.to_record(msgtype, msg,
                                                              self._feed_settings.max_range))

    def _convert_bytes(self, topic: str, msgtype: str, data: bytes,
                       reader: messages.PathReader | None = None):
        """The record of a raw subscription's message (None when it was bad); `reader`: the
        stream's reader of the bytes (messages.record_from_cdr)."""
        return self._record(topic, lambda: messages.record_from_cdr(
            msgtype, data, _deserialized, self._feed_settings.max_range, reader))

    def _on_scan(self, msg) -> None:
        """Queue a scan; with the queue full, the oldest goes and counts as lost.

        Parameters
        ----------
        msg: a sensor_msgs/LaserScan; a bad one is counted as a problem and dropped.
        """
        arrival = time.monotonic()
        record = self._convert('scan', messages.SCAN_TYPE, msg)
        with self._lock:
            self._received += 1
            if record is None:
                self._unreadable.append(_header_stamp(msg))
            else:
                if len(self._scans) >= self._queue_limit:
                    self._lost.append(self._scans.popleft()[1].stamp)
                self._scans.append((arrival, record))
        self._wake.set()

    def _on_scans_lost(self, info) -> None:
        """Count the scans the middleware reports lost.

        Parameters
        ----------
        info: rclpy's QoSMessageLostInfo; its total_count_change is added.
        """
        with self._lock:
            self._dds_lost += info.total_count_change

    def _on_trajectory(self, data: bytes) -> None:
        """Keep the newest keyframe estimate.

        Parameters
        ----------
        data: a serialized nav_msgs/Path (raw subscription); a bad one is counted as a problem
            and dropped, the estimate queued before it stays.
        """
        arrival = time.monotonic()
        record = self._convert_bytes('trajectory', messages.PATH_TYPE, data, self._path_reader)
        if record is not None:
            with self._lock:
                # the full estimate: a newer one replaces it, and the wait counts from the
                # first one it replaced (the latency is that of the oldest input answered)
                first = arrival if self._estimate is None else self._estimate[0]
                self._estimate = (first, record)
            self._wake.set()

    def _on_pose(self, msgtype: str, msg) -> None:
        """Queue a single pose.

        Parameters
        ----------
        msgtype: the pose source's message type (Odometry, PoseStamped or
            PoseWithCovarianceStamped).
        msg: the message; a bad one is counted as a problem and dropped.
        """
        arrival = time.monotonic()
        self._queue_pose(arrival, self._convert('pose', msgtype, msg))

    def _on_graph(self, data: bytes) -> None:
        """Queue a snapshot of slam_toolbox's graph markers.

        Parameters
        ----------
        data: a serialized visualization_msgs/MarkerArray (raw subscription); a bad one is
            counted as a problem and dropped.
        """
        arrival = time.monotonic()
        self._queue_pose(arrival, self._convert_bytes('graph_visualization',
                                                      messages.MARKER_ARRAY_TYPE, data))

    def _queue_pose(self, arrival: float, record: PoseSample | GraphSnapshot | None) -> None:
        """Queue a single pose or graph snapshot that arrived at `arrival` (time.monotonic;
        all kept, in order; None: it was bad)."""
        if record is not None:
            with self._lock:
                if len(self._poses) >= self._queue_limit:
                    self._poses.popleft()
                    self._problems += 1
                    self._last_problem = ('pose: queue full, the oldest pose or graph dropped',
                                          time.monotonic())
                self._poses.append((arrival, record))
            self._wake.set()

    def _on_constraints(self, msg) -> None:
        """Keep the newest constraint set.

        Parameters
        ----------
        msg: a std_msgs/Float64MultiArray of edge rows; a bad one is counted as a problem and
            dropped, the set queued before it stays.
        """
        arrival = time.monotonic()
        record = self._convert('constraints', messages.CONSTRAINTS_TYPE, msg)
        if record is not None:
            with self._lock:
                self._constraints = (arrival, record)
            self._wake.set()
