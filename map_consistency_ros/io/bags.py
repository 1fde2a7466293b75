"""ROS bags as numpy, through rosbags (no ROS install): ROS 1 `.bag`, rosbag2 sqlite3 and mcap.

Reading: `BagReader` checks that the bag has the node's topics with the node's message types
and yields the core input records (core/live/_records.py, converted by io/messages.py exactly as
the node converts its messages) in log-time order, or `BadMessage` for unusable content.

Writing: `BagWriter` writes rosbag2 (mcap or sqlite3) with the ROS 2 Jazzy message
definitions. Stamps are float seconds at the API. Every bad bag becomes an InputError that
names the bag.
"""
from __future__ import annotations

import lzma
import math
import re
import struct
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import SensorModel, se2
from map_consistency_ros.core.live import Record
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.staging import StagedOutputs
from map_consistency_ros.io.messages import (CDR_RECORDS, CONSTRAINTS_TYPE,
                                             LOOP_CLOSURE_EVENT_TYPE, MARKER_ARRAY_TYPE,
                                             NEW_NODE_EVENT_TYPE, PATH_TYPE, PathReader,
                                             POSE_COVARIANCE_TYPE, POSE_GRAPH_TYPE, POSE_TYPES,
                                             SCAN_TYPE, constraints_message,
                                             graph_markers_message, loop_closure_event_message,
                                             new_node_event_message, path_message,
                                             pose_graph_message, record_from_cdr,
                                             register_slam_toolbox_types, scan_message,
                                             single_pose_message, to_record)

TF_TYPE = 'tf2_msgs/msg/TFMessage'
STORAGES = ('mcap', 'sqlite3')
# A pose topic replay reads: keyframe Paths, single poses, or slam_toolbox's node events.
POSE_TOPIC_TYPES = POSE_TYPES + (NEW_NODE_EVENT_TYPE,)


@dataclass(frozen=True)
class BadMessage:
    """A message whose content cannot be used (the node would drop it with a warning)."""

    topic: str
    index: int  # 1-based position on its topic
    reason: str


BagRecord = Record | BadMessage


@dataclass(frozen=True)
class BagTopics:
    """Topic names. `poses=None` picks '/trajectory', else slam_toolbox's node events
    (`new_node_event`) when the bag has them, else the bag's only pose topic. `graph` is
    slam_toolbox's graph markers (its node publishes `slam_toolbox/graph_visualization`);
    `pose_graph` and `loop_closure_event` its pose-graph interface, read beside node events."""

    scan: str = '/scan'
    poses: str | None = None
    constraints: str = '/constraints'
    graph: str = '/slam_toolbox/graph_visualization'
    pose_graph: str = '/slam_toolbox/pose_graph'
    new_node_event: str = '/slam_toolbox/new_node_event'
    loop_closure_event: str = '/slam_toolbox/loop_closure_event'


# Errors rosbags and the decompressors raise on damaged files (MemoryError: a garbage length
# field); all mean "this bag is bad".
def _bag_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1ReaderError
    from rosbags.rosbag2 import ReaderError as Ros2ReaderError
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError
    return (AnyReaderError, Ros1ReaderError, Ros2ReaderError, SerdeError, TypesysError,
            AssertionError, EOFError, KeyError, IndexError, ValueError, struct.error,
            UnicodeDecodeError, OSError, zlib.error, lzma.LZMAError, MemoryError, OverflowError)


class BagReader:
    """Typed, checked reading of one bag (or the split files of one bag).

    Messages are converted as the node does (`messages.to_record` with `max_range`, the usable
    range).
    Use as a context manager. On entering, checks that the scan topic is a LaserScan, that
    the pose topic is one of POSE_TYPES and that the constraints topic, if present, is a
    Float64MultiArray; raises InputError naming the bag and listing its topics otherwise.
    """

    def __init__(self, paths: Sequence[str | Path], topics: BagTopics = BagTopics(),
                 max_range: float = math.inf) -> None:
        if not paths:
            raise InputError('bag', 'no bag given')
        self.paths = [Path(path) for path in paths]
        self.source = ', '.join(str(path) for path in self.paths)
        self.topics = topics
        self.max_range = max_range
        self._reader = None
        self._connections: dict[str, list] = {}
        self.pose_topic = ''
        self.pose_type = ''

    def __enter__(self) -> BagReader:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
        for path in self.paths:
            if not path.exists():
                raise InputError(str(path), 'no such bag')
        try:
            typestore = get_typestore(Stores.ROS2_JAZZY)
            register_slam_toolbox_types(typestore)  # for bags without their definitions
            reader = AnyReader(self.paths, default_typestore=typestore)
            reader.open()
        except _bag_errors() as error:
            raise _unreadable(self.source, error) from None
        self._reader = reader
        try:
            self._check_topics()
        except InputError:
            reader.close()
            raise
        return self

    def __exit__(self, *exc_info) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    # -- topics ------------------------------------------------------------------------------

    def _topic_types(self) -> dict[str, str]:
        return {connection.topic: connection.msgtype for connection in self._reader.connections}

    def _listing(self) -> str:
        return ', '.join(f'{topic} ({msgtype})'
                         for topic, msgtype in sorted(self._topic_types().items())) or 'no topics'

    def _require(self, topic: str, allowed: Sequence[str], option: str) -> str:
        types = self._topic_types()
        if topic not in types:
            raise InputError(self.source, f'no topic {topic} (the bag has {self._listing()}); '
                                          f'choose another with {option}')
        if types[topic] not in allowed:
            raise InputError(self.source, f'topic {topic} carries {types[topic]}, expected '
                                          f'{" or ".join(allowed)}')
        return types[topic]

    def _check_topics(self) -> None:
        for connection in self._reader.connections:
            self._connections.setdefault(connection.topic, []).append(connection)
        self._require(self.topics.scan, (SCAN_TYPE,), '--scan-topic')
        self.pose_topic = self.topics.poses or self._default_pose_topic()
        self.pose_type = self._require(self.pose_topic, POSE_TOPIC_TYPES, '--pose-topic')
        if self.topics.constraints in self._connections:
            self._require(self.topics.constraints, (CONSTRAINTS_TYPE,), '--constraints-topic')
        if self.topics.graph in self._connections:
            self._require(self.topics.graph, (MARKER_ARRAY_TYPE,), '--graph-topic')
        if self.has_pose_graph:
            for topic, msgtype, option in (
                    (self.topics.pose_graph, POSE_GRAPH_TYPE, '--pose-graph-topic'),
                    (self.topics.loop_closure_event, LOOP_CLOSURE_EVENT_TYPE,
                     '--loop-closure-topic')):
                if topic in self._connections:
                    self._require(topic, (msgtype,), option)

    def _default_pose_topic(self) -> str:
        types = self._topic_types()
        if '/trajectory' in types:
            return '/trajectory'
        if types.get(self.topics.new_node_event) == NEW_NODE_EVENT_TYPE:
            return self.topics.new_node_event
        candidates = sorted(topic for topic, msgtype in types.items() if msgtype in POSE_TYPES)
        if len(candidates) != 1:
            found = ', '.join(candidates) if candidates else 'none'
            raise InputError(self.source, f'no /trajectory topic and {len(candidates)} other pose '
                                          f'topics ({found}); choose one with --pose-topic')
        return candidates[0]

    def topic_type(self, topic: str) -> str:
        """Message type of a topic of the bag.

        Parameters
        ----------
        topic: a topic name of the bag (KeyError otherwise).

        Returns
        -------
        The type name, e.g. 'sensor_msgs/msg/LaserScan'.
        """
        return self._topic_types()[topic]

    @property
    def has_constraints(self) -> bool:
        return self.topics.constraints in self._connections

    @property
    def has_graph(self) -> bool:
        """Whether the bag holds slam_toolbox's graph markers beside its `pose` messages
        (PoseWithCovarianceStamped): then the poses go to the slam_toolbox bridge."""
        return (self.topics.graph in self._connections
                and self.pose_type == POSE_COVARIANCE_TYPE)

    @property
    def has_pose_graph(self) -> bool:
        """Whether the poses are slam_toolbox's node events: then its pose graph and
        loop-closure events, when the bag has them, go to the pose-graph bridge too."""
        return self.pose_type == NEW_NODE_EVENT_TYPE

    @property
    def input_topics(self) -> list[str]:
        """The topics replay reads: scan, poses, and constraints and graph (markers, or pose
        graph and loop-closure events) when present."""
        topics = [self.topics.scan, self.pose_topic]
        if self.has_constraints:
            topics.append(self.topics.constraints)
        if self.has_graph:
            topics.append(self.topics.graph)
        if self.has_pose_graph:
            topics += [topic for topic in (self.topics.pose_graph,
                                           self.topics.loop_closure_event)
                       if topic in self._connections]
        return topics

    @property
    def is_ros1(self) -> bool:
        return not self._reader.is2

    def message_count(self, topic: str) -> int:
        """Number of messages on a topic.

        Parameters
        ----------
        topic: the topic name.

        Returns
        -------
        The count over all files of the bag; 0 for a topic the bag lacks.
        """
        return sum(connection.msgcount for connection in self._connections.get(topic, []))

    @property
    def start_time(self) -> float:
        """Log time of the first message, seconds."""
        return self._reader.start_time * 1e-9

    @property
    def duration(self) -> float:
        """Log-time span of the bag, seconds."""
        return self._reader.duration * 1e-9

    # -- messages ----------------------------------------------------------------------------

    def _selected(self, topics: Sequence[str]) -> list:
        return [connection for topic in topics for connection in self._connections.get(topic, [])]

    def records(self) -> Iterator[tuple[float, BagRecord]]:
        """The input topics' (`input_topics`) messages as core records, in log order.

        Yields
        ------
        (log time in seconds, record), the record converted as the node does, or BadMessage
        for a message whose content is unusable. A damaged file raises InputError.
        """
        topics = self.input_topics
        counts: dict[str, int] = {}
        # the node's readers of the bytes (Paths, graph markers), where ROS 2 bags hold CDR
        raw_types = () if self.is_ros1 else tuple(CDR_RECORDS)
        path_readers: dict[str, PathReader] = {}  # per topic, as the node's subscription
        for connection, timestamp, message in self._messages(self._selected(topics), raw_types):
            index = counts[connection.topic] = counts.get(connection.topic, 0) + 1
            reader = (path_readers.setdefault(connection.topic, PathReader())
                      if connection.msgtype == PATH_TYPE else None)
            try:
                record = (record_from_cdr(connection.msgtype, message, self._deserialize,
                                          self.max_range, reader) if isinstance(message, bytes)
                          else to_record(connection.msgtype, message, self.max_range))
            except ValueError as error:
                record = BadMessage(topic=connection.topic, index=index, reason=str(error))
            yield timestamp * 1e-9, record

    def raw_messages(self, topics: Sequence[str]) -> Iterator[tuple[str, str, float, bytes]]:
        """The serialized messages of some topics of a ROS 2 bag, in log order.

        Parameters
        ----------
        topics: topic names; those the bag lacks are skipped.

        Returns
        -------
        An iterator of (topic, message type, log time in seconds, CDR bytes); it raises
        InputError for a damaged file. Raises InputError at once for a ROS 1 bag, whose
        messages are not CDR.
        """
        if self.is_ros1:
            raise InputError(self.source, 'a ROS 1 bag holds ROS 1 serialized messages, not CDR; '
                                          'convert it first (rosbags-convert --src BAG --dst OUT '
                                          '--dst-typestore ros2_jazzy)')
        return self._raw(self._selected(topics))

    def _raw(self, connections: list) -> Iterator[tuple[str, str, float, bytes]]:
        try:
            for connection, timestamp, data in self._reader.messages(connections):
                yield connection.topic, connection.msgtype, timestamp * 1e-9, bytes(data)
        except _bag_errors() as error:
            raise InputError(self.source, f'damaged bag ({_describe(error)})') from None

    def _messages(self, connections: list, raw_types: tuple[str, ...] = ()) -> Iterator[tuple]:
        """(connection, log time, message), the CDR bytes for the types of `raw_types`."""
        errors = _bag_errors()
        try:
            for connection, timestamp, data in self._reader.messages(connections):
                yield connection, timestamp, (bytes(data) if connection.msgtype in raw_types
                                              else self._reader.deserialize(data,
                                                                            connection.msgtype))
        except errors as error:
            raise InputError(self.source, f'damaged bag ({_describe(error)})') from None

    def _deserialize(self, data: bytes, msgtype: str):
        try:
            return self._reader.deserialize(data, msgtype)
        except _bag_errors() as error:
            raise InputError(self.source, f'damaged bag ({_describe(error)})') from None

    def static_transform(self, parent: str, child: str) -> np.ndarray | None:
        """The planar pose of `child` in `parent` from /tf_static.

        Parameters
        ----------
        parent: the parent frame id (a leading '/' is ignored).
        child: the child frame id (a leading '/' is ignored).

        Returns
        -------
        (3,) x, y, yaw of the first matching transform (its z, roll and pitch dropped); None
        when the bag has no such static transform. A damaged file raises InputError.
        """
        connections = [connection for connection in self._reader.connections
                       if connection.topic == '/tf_static' and connection.msgtype == TF_TYPE]
        if not connections:
            return None  # rosbags reads every topic when given no connections
        wanted = (parent.lstrip('/'), child.lstrip('/'))
        for _, _, message in self._messages(connections):
            for transform in message.transforms:
                frames = (transform.header.frame_id.lstrip('/'),
                          transform.child_frame_id.lstrip('/'))
                if frames == wanted:
                    moved = transform.transform
                    rotation = moved.rotation
                    return np.array([moved.translation.x, moved.translation.y,
                                     se2.yaw_from_quaternion(rotation.x, rotation.y,
                                                             rotation.z, rotation.w)])
        return None


def _describe(error: BaseException) -> str:
    """The error in one line: a multi-line message (a YAML parser's, with the offending
    source quoted) keeps its unindented lines."""
    lines = [line.strip() for line in str(error).splitlines()
             if line.strip() and not line[0].isspace()]
    text = '; '.join(lines)
    return f'{type(error).__name__}: {text}' if text else type(error).__name__


# rosbags' words for a metadata.yaml its YAML parser refused, and the parser's position marks
_BAD_YAML = re.compile(r'Could not load YAML from (?P<path>.+?): (?P<problem>.*)', re.DOTALL)
_YAML_MARK = re.compile(r'line (\d+), column')


def _unreadable(source: str, error: BaseException) -> InputError:
    """The InputError of a bag rosbags cannot open: a malformed metadata.yaml is named with
    the line of the problem, anything else as an unreadable bag."""
    match = _BAD_YAML.match(str(error).strip())
    if match is None:
        return InputError(source, f'not a readable ROS bag ({_describe(error)})')
    marks = _YAML_MARK.findall(match['problem'])
    problem = '; '.join(line.strip() for line in match['problem'].splitlines()
                        if line.strip() and not line[0].isspace())
    return InputError(match['path'], f'malformed YAML in the bag\'s metadata ({problem})',
                      int(marks[-1]) if marks else None)


# -- writing ---------------------------------------------------------------------------------

class BagWriter:
    """Writes a rosbag2 (mcap or sqlite3) with /scan, the pose topic (/trajectory Paths, or
    single poses), /constraints and, when written, slam_toolbox's graph markers.

    Use as a context manager; `path` must not exist. Each write takes its log time in seconds
    (the time the message would have been published). `compress` turns on zstd chunk
    compression (mcap only). The bag is written beside `path` and appears there whole when the
    `with` block ends normally; when it raises, nothing is left (io/staging.py).
    """

    def __init__(self, path: str | Path, storage: str = 'mcap', compress: bool = False,
                 topics: BagTopics = BagTopics(poses='/trajectory')) -> None:
        if storage not in STORAGES:
            raise ValueError(f'storage must be one of {", ".join(STORAGES)}, got {storage!r}')
        if compress and storage != 'mcap':
            raise ValueError('compression is supported for mcap storage only')
        self.path = Path(path)
        self.storage = storage
        self.compress = compress
        self.topics = topics
        self._writer = None
        self._outputs: StagedOutputs | None = None
        self._connections: dict[str, object] = {}

    def __enter__(self) -> BagWriter:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
        from rosbags.typesys import Stores, get_typestore
        if self.path.exists():
            raise InputError(str(self.path), 'output already exists; remove it or choose another')
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        register_slam_toolbox_types(self.typestore)
        plugin = StoragePlugin.MCAP if self.storage == 'mcap' else StoragePlugin.SQLITE3
        self._outputs = StagedOutputs()
        try:
            writer = Writer(self._outputs.path(self.path), version=9, storage_plugin=plugin)
            if self.compress:
                writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            writer.open()
        except BaseException:
            self._outputs.discard()
            raise
        self._writer = writer
        for topic, msgtype in ((self.topics.scan, SCAN_TYPE),
                               (self.topics.constraints, CONSTRAINTS_TYPE)):
            self._connections[msgtype] = writer.add_connection(topic, msgtype,
                                                               typestore=self.typestore)
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if self._writer is None:
            return
        try:
            self._writer.close()
        except BaseException:
            self._outputs.discard()
            raise
        finally:
            self._writer = None
        if exc_type is None:
            self._outputs.commit()
        else:
            self._outputs.discard()

    def _write(self, msgtype: str, time: float, message) -> None:
        if msgtype not in self._connections:
            # the pose topic carries the first pose type; the graph topic appears only in bags
            # written with graph markers, since replay takes its presence as slam_toolbox input
            topic = {MARKER_ARRAY_TYPE: self.topics.graph,
                     NEW_NODE_EVENT_TYPE: self.topics.new_node_event,
                     POSE_GRAPH_TYPE: self.topics.pose_graph,
                     LOOP_CLOSURE_EVENT_TYPE: self.topics.loop_closure_event}.get(
                         msgtype, self.topics.poses)
            self._connections[msgtype] = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore)
        data = self.typestore.serialize_cdr(message, msgtype)
        self._writer.write(self._connections[msgtype], int(round(time * 1e9)), data)

    def _types(self, name: str) -> type:
        return self.typestore.types[name]

    def write_scan(self, time: float, stamp: float, ranges: np.ndarray, model: SensorModel,
                   frame_id: str = 'laser') -> None:
        """A LaserScan whose beam k has bearing angle_min + k * angle_increment.

        Parameters
        ----------
        time: log time in seconds.
        stamp: header stamp in seconds.
        ranges: (K,) ranges in metres (written as float32).
        model: beam geometry and range limits.
        frame_id: the laser frame.
        """
        self._write(SCAN_TYPE, time, scan_message(self._types, stamp, ranges, model, frame_id))

    def write_trajectory(self, time: float, stamps: np.ndarray, poses: np.ndarray,
                         frame_id: str = 'map') -> None:
        """A Path of keyframe poses, each PoseStamped stamped with its scan's stamp.

        Parameters
        ----------
        time: log time in seconds, also the Path's header stamp.
        stamps: (M,) seconds, the stamp of each keyframe's scan.
        poses: (M, 3) x, y, yaw.
        frame_id: frame of the header and of every entry.
        """
        self._write(PATH_TYPE, time, path_message(self._types, stamps, poses, frame_id,
                                                  stamp=time))

    def write_single_pose(self, time: float, msgtype: str, stamp: float, pose: np.ndarray,
                          frame_id: str = 'odom', child_frame_id: str = 'base_link') -> None:
        """One Odometry, PoseStamped or PoseWithCovarianceStamped on the pose topic (a bag
        holds one pose type: single poses or Paths).

        Parameters
        ----------
        time: log time in seconds.
        msgtype: one of messages.SINGLE_POSE_TYPES (ValueError otherwise).
        stamp: header stamp in seconds.
        pose: (3,) x, y, yaw.
        frame_id: the frame the pose is in.
        child_frame_id: the moving frame (Odometry only).
        """
        self._write(msgtype, time, single_pose_message(self._types, msgtype, stamp, pose,
                                                       frame_id, child_frame_id))

    def write_constraints(self, time: float, rows: np.ndarray) -> None:
        """All pose-graph edges as a Float64MultiArray of rows laid out as CONSTRAINT_FIELDS.

        Parameters
        ----------
        time: log time in seconds.
        rows: (E, 11) edge rows.
        """
        self._write(CONSTRAINTS_TYPE, time, constraints_message(self._types, rows))

    def write_graph(self, time: float, ids: np.ndarray, positions: np.ndarray,
                    frame_id: str = 'map') -> None:
        """slam_toolbox's graph markers: DELETEALL, a SPHERE per vertex, the edges, on the
        graph topic.

        Parameters
        ----------
        time: log time in seconds, also the markers' header stamp.
        ids: (V,) vertex ids.
        positions: (V, 2) x, y of the vertices.
        frame_id: the markers' frame.
        """
        self._write(MARKER_ARRAY_TYPE, time, graph_markers_message(self._types, time, ids,
                                                                   positions, frame_id))

    def write_new_node_event(self, time: float, node_id: int, stamp: float, pose: np.ndarray,
                             step: np.ndarray | None = None) -> None:
        """slam_toolbox's NewNodeEvent of node `node_id` built from the scan stamped `stamp`.

        Parameters
        ----------
        time: log time in seconds.
        node_id: the new node's id.
        stamp: stamp of the node's scan, seconds.
        pose: (3,) x, y, yaw of the node.
        step: (3,) relative pose from node `node_id - 1`; None for zeros.
        """
        self._write(NEW_NODE_EVENT_TYPE, time, new_node_event_message(self._types, node_id,
                                                                      stamp, pose, step))

    def write_pose_graph(self, time: float, stamp: float, ids: np.ndarray, poses: np.ndarray,
                         frame_id: str = 'map', edges: np.ndarray | None = None) -> None:
        """slam_toolbox's PoseGraph.

        Parameters
        ----------
        time: log time in seconds.
        stamp: header stamp in seconds.
        ids: (V,) node ids.
        poses: (V, 3) x, y, yaw of the nodes.
        frame_id: the header's frame.
        edges: (E, 2) node id pairs, given the relative pose of their nodes; None for none.
        """
        self._write(POSE_GRAPH_TYPE, time, pose_graph_message(self._types, stamp, ids, poses,
                                                              frame_id, edges))

    def write_loop_closure_event(self, time: float, stamp: float) -> None:
        """slam_toolbox's LoopClosureEvent.

        Parameters
        ----------
        time: log time in seconds.
        stamp: the event's stamp in seconds.
        """
        self._write(LOOP_CLOSURE_EVENT_TYPE, time, loop_closure_event_message(self._types,
                                                                              stamp))
