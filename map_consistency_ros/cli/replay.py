"""Replay a bag through the live node's consistency monitor and print its final verdict.

Reads ROS 2 bags (mcap, sqlite3: the bag folder) and ROS 1 bags (.bag) without a ROS install.
The scans (sensor_msgs/LaserScan) and poses are fed, in log order, to the same live pipeline
the node runs, so the verdict equals what the node would publish.

Pose sources (--pose-topic; default /trajectory, else the bag's only pose topic):
  nav_msgs/Path              the SLAM back-end's keyframe trajectory, as the node takes it:
                             each PoseStamped stamped like its LaserScan, the full current
                             estimate each time (a loop closure moves many poses at once);
  nav_msgs/Odometry, geometry_msgs/PoseStamped, geometry_msgs/PoseWithCovarianceStamped
                             one pose per message (raw odometry, a localizer): each scan takes
                             the pose interpolated at its stamp and becomes a keyframe when the
                             robot moved --keyframe-distance or turned --keyframe-angle; the
                             laser offset comes from /tf_static (pose child frame -> scan frame)
                             unless --laser-offset is given.
  slam_toolbox               its `pose` (PoseWithCovarianceStamped, one per accepted scan) and
                             its graph markers (MarkerArray on --graph-topic): when the bag has
                             both, the poses and markers go to the slam_toolbox bridge, as in the
                             node with pose_source slam_toolbox (docs/slam_bridges.md).
  slam_toolbox_graph         its node events (slam_toolbox/msg/NewNodeEvent on --new-node-topic,
                             chosen by default when the bag has them), pose graph (PoseGraph on
                             --pose-graph-topic) and loop-closure events (--loop-closure-topic):
                             keyframes with full headings, as in the node with pose_source
                             slam_toolbox_graph (docs/slam_bridges.md).
std_msgs/Float64MultiArray on /constraints (optional) is passed on as the pose-graph edges.

Every output names a keyframe by its laser record: the 0-based position of its scan message
on the scan topic (over all bags given, in log order), as `check` names a log's scans; the
report's keyframe_stamps give their stamps.

--publish plays the bag's scan, pose and constraints topics onto live ROS 2 topics instead
(raw CDR bytes, paced at --rate times real time) to drive a running node.

examples:
  map-consistency replay intel_demo/ --report out/replay.json --plot out/map.png
  map-consistency replay intel.orig.bag --pose-topic /odom --keyframe-distance 0.5
  map-consistency replay run_2024_05_01/ --publish --rate 2
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from map_consistency_ros.cli import check, exit_codes, options, plots, report
from map_consistency_ros.cli.progress import ProgressBar
from map_consistency_ros.core.configuration import Configuration, unknown_parameters
from map_consistency_ros.core.geometry import ScanSet
from map_consistency_ros.core.live import (ConsistencyMonitor, DroppedScans, FeedSettings,
                                           GraphSnapshot, KeyframeEstimate, LivePipeline,
                                           LiveVerdict, LoopClosure, MonitorSettings,
                                           MonitorSnapshot, NodeEvent, PoseGraphCounts,
                                           PoseGraphNodes, PoseSample, Scan)
from map_consistency_ros.core.verdict import Assessment
from map_consistency_ros.io.bags import BadMessage, BagReader, BagTopics
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.messages import (NEW_NODE_EVENT_TYPE, PATH_TYPE, POSE_SOURCE_TYPES,
                                             time_message)
from map_consistency_ros.io.parameter_file import read_parameter_file
from map_consistency_ros.io.staging import StagedOutputs

_SHOWN_WARNINGS = 5
_PUBLISH_DEPTH = 1000  # deep enough that a paced burst (a Path after its scan) is not dropped
_DRAIN_SECONDS = 0.5  # let the last messages leave before the publishers go
_SETTLE_SECONDS = 1.0  # after the first subscribers match, for the others to match too


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `replay`: the bags, the topics, the parameter file, the node's
    parameters, the outputs and publishing.

    Parameters
    ----------
    parser: the parser of the `replay` subcommand.
    """
    parser.add_argument('bags', type=Path, nargs='+', metavar='BAG',
                        help='ROS 1 .bag file, or rosbag2 folder (mcap / sqlite3); several files '
                             'of one recording may be given')
    add_topic_arguments(parser)
    parser.add_argument('--params-file', type=Path, metavar='YAML',
                        help="the node's ROS 2 parameter file (config/map_consistency.yaml); "
                             'options given here override its values')
    options.add_parameter_arguments(parser, FeedSettings, 'poses and sensor',
                                    skip=('pose_source',))
    options.add_parameter_arguments(parser, MonitorSettings, 'monitor')
    options.add_test_arguments(parser)
    options.add_verdict_arguments(parser)
    check.add_output_arguments(parser)
    parser.add_argument('--stats-plot', type=Path, metavar='PNG',
                        help='write the histogram of Psi over the tested pairs')
    parser.add_argument('--duration', type=float, default=None, metavar='SECONDS',
                        help='replay only the first SECONDS of the bag')
    play = parser.add_argument_group('publishing')
    play.add_argument('--publish', action='store_true',
                      help='play the bag onto live ROS 2 topics instead of checking it')
    play.add_argument('--rate', type=float, default=1.0,
                      help='playback speed, 1 = real time (default %(default)s)')
    play.add_argument('--subscribers', type=int, default=1, metavar='N',
                      help='wait (at most 10 s) until every topic has N subscribers, e.g. 2 for '
                           'a node and a recorder (default %(default)s)')


def add_topic_arguments(parser: argparse.ArgumentParser) -> None:
    """The bag topics replay reads.

    Parameters
    ----------
    parser: the parser to add them to, as the group 'topics'.
    """
    topics = parser.add_argument_group('topics')
    topics.add_argument('--scan-topic', default='/scan', help='LaserScan topic (%(default)s)')
    topics.add_argument('--pose-topic', default=None,
                        help='Path, Odometry, PoseStamped or PoseWithCovarianceStamped topic '
                             '(default /trajectory, else the only pose topic of the bag)')
    topics.add_argument('--constraints-topic', default='/constraints',
                        help='Float64MultiArray edge rows, optional (%(default)s)')
    topics.add_argument('--graph-topic', default=BagTopics.graph,
                        help="slam_toolbox's graph markers (MarkerArray), optional: with a "
                             'PoseWithCovarianceStamped pose topic the poses and markers go to '
                             'the slam_toolbox bridge (%(default)s)')
    topics.add_argument('--new-node-topic', default=BagTopics.new_node_event,
                        help="slam_toolbox's node events (NewNodeEvent): the pose topic by "
                             'default when the bag has it; with it, the pose graph and '
                             'loop-closure events go to the pose-graph bridge (%(default)s)')
    topics.add_argument('--pose-graph-topic', default=BagTopics.pose_graph,
                        help="slam_toolbox's pose graph (PoseGraph), optional (%(default)s)")
    topics.add_argument('--loop-closure-topic', default=BagTopics.loop_closure_event,
                        help="slam_toolbox's loop-closure events (LoopClosureEvent), optional "
                             '(%(default)s)')


# the ReplayStats counter of each kind of record (the rest are constraint sets)
_COUNTERS = {Scan: 'scans', KeyframeEstimate: 'trajectories', PoseSample: 'pose_messages',
             GraphSnapshot: 'graph_snapshots', NodeEvent: 'node_events',
             PoseGraphNodes: 'pose_graphs', LoopClosure: 'loop_closures'}


@dataclass
class ReplayStats:
    """Counts and timings of one replay."""

    scans: int = 0
    trajectories: int = 0
    pose_messages: int = 0
    constraint_sets: int = 0
    graph_snapshots: int = 0
    node_events: int = 0
    pose_graphs: int = 0
    loop_closures: int = 0
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0  # wall-clock time of the replay
    log_seconds: float = 0.0  # bag time replayed

    @property
    def scan_rate(self) -> float:
        """Scans replayed per wall-clock second."""
        return self.scans / self.seconds if self.seconds > 0 else math.inf

    @property
    def realtime_rate(self) -> float:
        """Scans per second of bag time, the rate a live node must keep up with."""
        return self.scans / self.log_seconds if self.log_seconds > 0 else math.inf

    def warn(self, text: str) -> None:
        """Keep a warning for the summary and the report.

        Parameters
        ----------
        text: the warning, one line.
        """
        self.warnings.append(text)


class Replay:
    """Feeds one bag's records through the node's live pipeline (core/live/pipeline.py), in
    log order.

    Parameters
    ----------
    bag: the open bag.
    pipeline: the live pipeline that takes its records (`make_pipeline`).
    """

    def __init__(self, bag: BagReader, pipeline: LivePipeline) -> None:
        self.bag = bag
        self.pipeline = pipeline
        self.stats = ReplayStats()
        # the stamp of every laser record (scan message) in log order, NaN for one that could
        # not be read: outputs name a keyframe by its record's position, as `check` does
        self._scan_stamps: list[float] = []

    def record_indices(self, stamps: np.ndarray) -> np.ndarray:
        """The 0-based positions of the laser records with these stamps among the scan
        messages replayed (of all bags, in log order): the names of keyframes in every output,
        as `check` names a log's scans by their laser records.

        Parameters
        ----------
        stamps: (N,) keyframe stamps, seconds (a keyframe keeps its scan's stamp).

        Returns
        -------
        (N,) int64; the first record of a stamp that several records carry (the monitor keeps
        the first), -1 for a stamp no record carries.
        """
        first: dict[float, int] = {}
        for index, stamp in enumerate(self._scan_stamps):
            first.setdefault(stamp, index)
        return np.array([first.get(float(stamp), -1) for stamp in stamps], dtype=np.int64)

    def run(self, progress=None, duration: float | None = None) -> MonitorSnapshot:
        """Feed the records (of the first `duration` seconds); return the first stage on the
        final map.

        Bad messages, and the pipeline's warnings and resets, become warnings of `stats`.

        Parameters
        ----------
        progress: progress(scans replayed, scans in the bag), called after each scan; None:
            no progress.
        duration: seconds of bag time to replay from its start; None: all of it.

        Returns
        -------
        The pipeline's snapshot of the final map.
        """
        total = self.bag.message_count(self.bag.topics.scan)
        started = time.perf_counter()
        stop = math.inf if duration is None else self.bag.start_time + duration
        for log_time, record in self.bag.records():
            if log_time > stop:
                break
            self.stats.log_seconds = log_time - self.bag.start_time
            if isinstance(record, BadMessage):
                if record.topic == self.bag.topics.scan:
                    self._scan_stamps.append(math.nan)
                self.stats.warn(f'message {record.index} on {record.topic} ignored: '
                                f'{record.reason}')
                if record.topic == self.bag.topics.scan:  # received: it counts (rejected)
                    self.pipeline.apply(DroppedScans(lost=np.zeros(0),
                                                     unreadable=np.array([math.nan])))
                continue
            self._count(record)
            if isinstance(record, Scan):
                self._scan_stamps.append(float(record.stamp))
            applied = self.pipeline.apply(record)
            self.stats.warnings.extend(applied.warnings)
            if applied.reset:
                self.stats.warn(f'monitor reset: {applied.reset}')
            if isinstance(record, Scan) and progress is not None:
                progress(self.stats.scans, total)
        self.stats.seconds = time.perf_counter() - started
        return self.pipeline.evaluate()

    def _count(self, record) -> None:
        counter = _COUNTERS.get(type(record), 'constraint_sets')
        setattr(self.stats, counter, getattr(self.stats, counter) + 1)


def _laser_offset(bag: BagReader, values: dict) -> tuple[np.ndarray, str]:
    """The laser pose in the pose frame and where it came from."""
    if 'laser_offset' in values:
        return np.asarray(values['laser_offset'], dtype=np.float64), 'parameter'
    if bag.pose_type == PATH_TYPE:
        return np.zeros(3), 'none (Path poses are laser poses)'
    if bag.pose_type == NEW_NODE_EVENT_TYPE:
        # node poses are of slam_toolbox's base_frame, which its events do not name: its
        # default, then the usual name
        scan_frame = next((record.frame_id for _, record in bag.records()
                           if isinstance(record, Scan)), None)
        for child in ('base_footprint', 'base_link'):
            offset = None if scan_frame is None else bag.static_transform(child, scan_frame)
            if offset is not None:
                return offset, f'/tf_static {child} -> {scan_frame}'
        return np.zeros(3), 'none found in /tf_static'
    frames = _first_frames(bag)
    if frames is not None:
        offset = bag.static_transform(*frames)
        if offset is not None:
            return offset, f'/tf_static {frames[0]} -> {frames[1]}'
    return np.zeros(3), 'none found in /tf_static'


def _first_frames(bag: BagReader) -> tuple[str, str] | None:
    """(pose child frame, scan frame) of the first pose and scan messages."""
    child = scan_frame = None
    for _, record in bag.records():
        if isinstance(record, PoseSample) and child is None:
            child = record.child_frame_id or 'base_link'
        elif isinstance(record, Scan) and scan_frame is None:
            scan_frame = record.frame_id
        if child is not None and scan_frame is not None:
            return child, scan_frame
    return None


def parameter_values(args: argparse.Namespace, base: dict | None = None) -> dict:
    """The parameter file's values overridden by the options given.

    Parameters
    ----------
    args: parsed `replay` options, --params-file among them.
    base: the values of a file read before; None: --params-file is read here (none given:
        no values), and its unknown names are warned about on stderr with the closest valid
        name.

    Returns
    -------
    name -> value, without the bags, the topics and the file's name; the other options that
    are no parameters stay (the configuration ignores them).
    """
    if base is None:
        base = {} if args.params_file is None else read_parameter_file(args.params_file)
        for warning in parameter_file_warnings(base):
            print(f'map-consistency replay: {args.params_file}: {warning}', file=sys.stderr)
    values = options.parameter_values(args, base)
    for name in ('bags', 'scan_topic', 'pose_topic', 'constraints_topic', 'graph_topic',
                 'new_node_topic', 'pose_graph_topic', 'loop_closure_topic', 'params_file'):
        values.pop(name, None)  # options, not parameters
    return values


def parameter_file_warnings(values: dict) -> list[str]:
    """A line for each name of a parameter file that is no node parameter.

    Parameters
    ----------
    values: the parameter file's values by name.

    Returns
    -------
    The warnings, sorted by name, each naming the closest valid name (use_sim_time, rclpy's,
    is valid).
    """
    return unknown_parameters(values, foreign=('use_sim_time',))


def configuration(values: dict, groups: tuple[str, ...] | None = None) -> Configuration:
    """The configuration of the parameter values, all checked as the node checks them, so a
    parameter file that would stop the node stops replay too.

    Parameters
    ----------
    values: parameter name -> value (`parameter_values`).
    groups: the configuration's groups made from `values` ('feed', ...); the others keep
        their defaults. None: every group.

    Returns
    -------
    The Configuration; InputError names a bad value.
    """
    try:
        return Configuration.from_values(values, groups)
    except ValueError as error:
        raise InputError('parameters', str(error)) from None


def open_bag(args: argparse.Namespace, values: dict | None = None,
             config: Configuration | None = None) -> BagReader:
    """The reader of the bags named by parsed replay options (enter it to open).

    Parameters
    ----------
    args: parsed `replay` options: the bags and topics.
    values: the parameters; None: from the options. Only read without `config`.
    config: their configuration, whose feed's max_range the reader converts scans with;
        None: the feed group's of `values`, all that opening needs.

    Returns
    -------
    The BagReader, not open yet; InputError for a bad parameter value.
    """
    if config is None:
        values = parameter_values(args) if values is None else values
        config = configuration(values, ('feed',))
    max_range = config.feed.max_range
    topics = BagTopics(scan=args.scan_topic, poses=args.pose_topic,
                       constraints=args.constraints_topic, graph=args.graph_topic,
                       pose_graph=args.pose_graph_topic, new_node_event=args.new_node_topic,
                       loop_closure_event=args.loop_closure_topic)
    return BagReader(args.bags, topics, max_range=max_range)


def make_pipeline(config: Configuration, pose_type: str, graph: bool = False) -> LivePipeline:
    """The node's live pipeline with the node's configuration.

    Parameters
    ----------
    config: the configuration; its feed's pose_source is replaced.
    pose_type: the message type of the bag's pose topic: its pose source
        (POSE_SOURCE_TYPES).
    graph: the bag has slam_toolbox's graph markers beside its poses: the pose source is
        slam_toolbox.

    Returns
    -------
    A new LivePipeline.
    """
    source = 'slam_toolbox' if graph else next(
        name for name, msgtype in POSE_SOURCE_TYPES.items() if msgtype == pose_type)
    return LivePipeline(config.consistency, config.monitor,
                        replace(config.feed, pose_source=source), config.explanation)


def replay_bag(args: argparse.Namespace, bag: BagReader, values: dict | None = None,
               config: Configuration | None = None) -> tuple[MonitorSnapshot, Replay, dict]:
    """Run the monitor over an open bag.

    Parameters
    ----------
    args: parsed `replay` options (quiet, duration).
    bag: the open bag.
    values: the parameters; None: from the options. Without laser_offset among them, the
        laser offset is the bag's (/tf_static).
    config: their configuration; None: made from them.

    Returns
    -------
    The snapshot of the final map (the first stage), the replay (its pipeline and counts)
    and the report's details. InputError for a bad parameter value.
    """
    values = parameter_values(args) if values is None else values
    config = configuration(values) if config is None else config
    offset, offset_source = _laser_offset(bag, values)
    try:
        config = replace(config, monitor=replace(config.monitor, laser_offset=tuple(offset)))
    except ValueError as error:
        raise InputError('parameters', str(error)) from None
    pipeline = make_pipeline(config, bag.pose_type, bag.has_graph)
    feed = pipeline.feed
    replay = Replay(bag, pipeline)
    with ProgressBar('replaying', enabled=not args.quiet) as progress:
        snapshot = replay.run(progress, args.duration)
    monitor = pipeline.monitor
    details = {
        'source': bag.source,
        'topics': {'scan': bag.topics.scan, 'poses': bag.pose_topic, 'pose_type': bag.pose_type,
                   'constraints': bag.topics.constraints if bag.has_constraints else None,
                   'graph': bag.topics.graph if bag.has_graph else None,
                   'pose_graph': (bag.topics.pose_graph if bag.has_pose_graph
                                  and bag.topics.pose_graph in bag.input_topics else None)},
        'laser_offset': offset, 'laser_offset_source': offset_source,
        'bag_duration_seconds': bag.duration,
        'replay': {'scan_messages': replay.stats.scans,
                   'trajectory_updates': replay.stats.trajectories,
                   'pose_messages': replay.stats.pose_messages,
                   'constraint_sets': replay.stats.constraint_sets,
                   'graph_snapshots': replay.stats.graph_snapshots,
                   'node_events': replay.stats.node_events,
                   'pose_graphs': replay.stats.pose_graphs,
                   'loop_closures': replay.stats.loop_closures,
                   'constraint_rows': int(monitor.constraints.shape[0]),
                   # what became of every scan message (core/live/_scan_counts.py)
                   'scan_counts': asdict(snapshot.scan_counts),
                   'unmatched_poses': snapshot.unmatched_poses,
                   'poses_without_scan': snapshot.poses_without_scan,
                   'scans_missing_from_stamps': feed.gap_scans,
                   'resets': feed.resets,
                   'seconds': replay.stats.seconds,
                   'bag_seconds_replayed': replay.stats.log_seconds,
                   'scans_per_second': replay.stats.scan_rate,
                   'realtime_scans_per_second': replay.stats.realtime_rate,
                   'warnings': replay.stats.warnings},
        'keyframe_stamps': snapshot.stamps,
        # the estimate the verdict judged, as the node's ~/report names it (core/live/_feed.py)
        'judged_stamp': snapshot.estimate_stamp,
        'judged_keyframes': snapshot.keyframe_count,
        'node_parameters': dict(config.values(), pose_source=feed.settings.pose_source.value),
    }
    if feed.bridge_counts is not None:
        details['slam_toolbox_bridge'] = asdict(feed.bridge_counts)
    if snapshot.model is not None:
        model = snapshot.model
        details['sensor_model'] = {'angle_min': model.angle_min,
                                   'angle_increment': model.angle_increment,
                                   'max_range': model.max_range, 'range_min': model.range_min,
                                   'beams': int(snapshot.ranges.shape[1])}
    if snapshot.result is not None:
        details['inconsistent_stamps'] = snapshot.stamps[snapshot.result.inconsistent]
    return snapshot, replay, details


def _summary(assessment: Assessment, replay: Replay, bag: BagReader,
             scan_ids: np.ndarray) -> str:
    stats = replay.stats
    lines = [report.format_summary(assessment, bag.source, scan_ids),
             f'  poses                 {bag.pose_topic} ({bag.pose_type}), '
             f'{stats.trajectories} trajectory updates',
             f'  replay                {stats.scans} scans in {stats.seconds:.2f} s: '
             f'{stats.scan_rate:.1f} scans/s, the bag\'s real time is '
             f'{stats.realtime_rate:.1f} scans/s']
    counts = replay.pipeline.feed.bridge_counts
    if isinstance(counts, PoseGraphCounts):
        lines.append(f'  slam_toolbox graph    {stats.node_events} node events, '
                     f'{stats.pose_graphs} pose graphs, {stats.loop_closures} loop closures: '
                     f'{counts.keyframes} keyframes, {counts.nodes_without_stamp} nodes '
                     'without an event' + (', waiting for the graph of a loop closure'
                                           if counts.waiting_for_graph else ''))
    elif counts is not None:
        lines.append(f'  slam_toolbox bridge   {stats.pose_messages} poses, '
                     f'{stats.graph_snapshots} graph snapshots: {counts.keyframes} keyframes, '
                     f'{counts.interpolated} headings interpolated, '
                     f'{counts.vertices_without_pose} vertices without a pose, '
                     f'{counts.pending_poses} poses without a vertex')
    elif stats.trajectories == 0 and stats.pose_messages:
        lines.append(f'  keyframes             {stats.pose_messages} poses, keyframes every '
                     f'{replay.pipeline.feed.settings.keyframe_distance:g} m / '
                     f'{replay.pipeline.feed.settings.keyframe_angle:g} rad')
    if stats.warnings:
        lines.append(f'  warnings              {len(stats.warnings)}')
        lines.extend(f'    {text}' for text in stats.warnings[:_SHOWN_WARNINGS])
    return '\n'.join(lines)


def publish_bag(bag: BagReader, rate: float, quiet: bool = False, subscribers: int = 1,
                discovery_timeout: float = 10.0) -> int:
    """Play the scan, pose and constraints topics onto ROS 2 as raw CDR, paced at `rate`.

    Publishers are reliable with deep queues, compatible with both reliable and sensor-data
    (best effort) subscribers. `/clock` carries the bag's log time before each message, so
    nodes with use_sim_time follow the bag (and see it pause when it ends).

    Parameters
    ----------
    bag: the open bag; its input topics are played.
    rate: playback speed, 1 = real time.
    quiet: no progress bar.
    subscribers: wait until every topic has this many subscribers, then a moment more for
        others found in the same discovery round, so that nodes started just before (a node
        under test, a recorder) get the first messages.
    discovery_timeout: seconds to wait for the `subscribers` at most.

    Returns
    -------
    The exit code 0. InputError for a bad `rate` or `subscribers`, without rclpy, or for a
    topic whose message package is not installed.
    """
    if not rate > 0:
        raise InputError('options', f'--rate must be positive, got {rate}')
    if subscribers < 0:
        raise InputError('options', f'--subscribers must not be negative, got {subscribers}')
    try:
        import rclpy
        from rclpy.context import Context
        from rosgraph_msgs.msg import Clock

        from map_consistency_ros.ros.conversions import message_class
    except ImportError as error:
        raise InputError('--publish', f'needs rclpy from ROS 2 Jazzy ({error})') from None
    topics = bag.input_topics
    messages = bag.raw_messages(topics)
    context = Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('map_consistency_replay', context=context)
        publishers = {}
        for topic in topics:
            msgtype = bag.topic_type(topic)
            try:
                kind = message_class(msgtype)
            except ImportError:
                raise InputError('--publish', f'{topic} carries {msgtype}, whose ROS 2 message '
                                              f'package {msgtype.split("/")[0]} is not '
                                              'installed') from None
            publishers[topic] = node.create_publisher(kind, topic, _PUBLISH_DEPTH)
        clock = node.create_publisher(Clock, '/clock', 10)
        deadline = time.monotonic() + discovery_timeout
        while (not all(publisher.get_subscription_count() >= subscribers
                       for publisher in publishers.values())
               and time.monotonic() < deadline):
            time.sleep(0.05)
        time.sleep(_SETTLE_SECONDS)
        total = sum(bag.message_count(topic) for topic in topics)
        start_wall, start_log, sent = time.monotonic(), None, 0
        with ProgressBar('publishing', enabled=not quiet) as progress:
            for topic, _, log_time, data in messages:
                start_log = log_time if start_log is None else start_log
                delay = start_wall + (log_time - start_log) / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                clock.publish(Clock(clock=time_message(message_class, log_time)))
                publishers[topic].publish(data)
                sent += 1
                progress(sent, total)
        time.sleep(_DRAIN_SECONDS)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    print(f'{bag.source}: published {sent} messages on {", ".join(topics)} '
          f'in {time.monotonic() - start_wall:.1f} s')
    return 0


def run(args: argparse.Namespace) -> int:
    """Replay the bags and report the final verdict; with --publish, play them onto ROS 2
    topics instead.

    Parameters
    ----------
    args: parsed `replay` options.

    Returns
    -------
    The exit code of the verdict (cli/exit_codes.py: 0 consistent, and after publishing;
    1 inconsistent; 4 nothing to judge). Bad input raises InputError, which `main`
    turns into exit code 2.
    """
    values = parameter_values(args)
    if args.publish:
        with open_bag(args, values) as bag:
            return publish_bag(bag, args.rate, quiet=args.quiet, subscribers=args.subscribers)
    return replay_and_report(args, values)[0]


@dataclass(frozen=True)
class BagJudgement:
    """Both stages' verdict on the final map of a replayed bag, with what the outputs are
    written from."""

    verdict: LiveVerdict  # the live pipeline's, with the map's placed scans
    details: dict  # the report's fields beside the verdict
    summary: str  # the lines replay prints
    monitor: ConsistencyMonitor  # in its final state
    seconds: float  # the replay and the explanation, without opening the bag
    # (N,) names of the judged keyframes in every output: their laser records' positions
    scan_ids: np.ndarray
    replay: Replay  # what was replayed: its record_indices name the keyframes of other maps

    @property
    def assessment(self) -> Assessment:
        """Both stages' verdict on the final map."""
        return self.verdict.assessment

    @property
    def scans(self) -> ScanSet:
        """The final map's scans placed at their poses (the verdict's, not placed again)."""
        return self.verdict.scans

    @property
    def snapshot(self) -> MonitorSnapshot:
        """The first stage on the final map, the snapshot the verdict judged."""
        return self.verdict.snapshot

    @property
    def consistent(self) -> bool:
        """Whether both stages find the final map consistent."""
        return self.verdict.consistent


def judge(args: argparse.Namespace, values: dict | None = None) -> BagJudgement:
    """Replay the bags named by parsed `replay` options and judge the final map (the one code
    path of `replay` and of `batch` for bags).

    Parameters
    ----------
    args: parsed `replay` options.
    values: the parameters; None: from the options (and --params-file).

    Returns
    -------
    The BagJudgement: both stages' verdict, the report's details, the summary lines, the
    monitor. InputError for a bad input, or when no pose matched a scan (no keyframe).
    """
    values = parameter_values(args) if values is None else values
    config = configuration(values)
    with open_bag(args, values, config) as bag:
        started = time.perf_counter()
        snapshot, replay, details = replay_bag(args, bag, values, config)
        if snapshot.result is None:
            raise InputError(bag.source, f'no keyframes: {replay.stats.scans} scans on '
                                         f'{bag.topics.scan} and no pose of {bag.pose_topic} '
                                         'matched one (check --stamp-tolerance)')
        verdict = replay.pipeline.explain(snapshot)
        scan_ids = replay.record_indices(snapshot.stamps)
        summary = _summary(verdict.assessment, replay, bag, scan_ids)
    return BagJudgement(verdict, details, summary, replay.pipeline.monitor,
                        time.perf_counter() - started, scan_ids, replay)


def replay_and_report(args: argparse.Namespace,
                      values: dict | None = None) -> tuple[int, BagJudgement]:
    """Replay the bag, print the verdict, write the outputs asked for.

    Parameters
    ----------
    args: parsed `replay` options.
    values: the parameters; None: from the options (and --params-file).

    Returns
    -------
    The exit code of the verdict (cli/exit_codes.py) and the judgement, its monitor in its
    final state.
    """
    judgement = judge(args, values)
    print(judgement.summary)
    with StagedOutputs() as outputs:  # every output, or none
        regions = check.write_outputs(args, judgement.scans, judgement.assessment,
                                      judgement.details, judgement.scan_ids, outputs=outputs)
        if args.stats_plot:
            # the verdict's result, with the pairs of flagged scans the partner budget left
            # out: the pairs the summary and the report count
            plots.save_statistics_figure(outputs.path(args.stats_plot),
                                         judgement.assessment.result)
    check.print_outputs([('report', args.report), ('figure', args.plot),
                         ('statistics figure', args.stats_plot), ('pairs', args.pairs_csv),
                         ('failed pairs figure', args.explain)], regions)
    code = exit_codes.of_outcome(judgement.assessment.outcome)
    return code, judgement
