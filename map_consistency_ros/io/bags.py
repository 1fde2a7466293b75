"""ROS bags as numpy, through rosbags (no ROS install): ROS 1 `.bag`, rosbag2 sqlite3 and mcap.

Reading: `BagReader` checks that the bag has the node's topics with the node's message types
and yields typed records in log-time order:

- `Scan` from sensor_msgs/LaserScan (header stamp, ranges, beam geometry);
- `Trajectory` from nav_msgs/Path: the back-end's full current keyframe estimate, each
  PoseStamped stamped like the LaserScan it was built from;
- `PoseSample` from nav_msgs/Odometry, geometry_msgs/PoseStamped or
  geometry_msgs/PoseWithCovarianceStamped: one pose per message (raw odometry, a localizer);
  `OdometryKeyframes` turns such a stream plus the scans into a growing trajectory;
- `Constraints` from std_msgs/Float64MultiArray: one row per pose-graph edge,
  `CONSTRAINT_FIELDS` (stamps in seconds, upper triangle of the information matrix).

Writing: `BagWriter` writes rosbag2 (mcap or sqlite3) with the ROS 2 Jazzy message
definitions. Stamps are float seconds at the API. Every bad bag becomes an InputError that
names the bag.
"""
from __future__ import annotations

import lzma
import math
import struct
import zlib
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.core import se2
from map_consistency_ros.core.scan_geometry import SensorModel
from map_consistency_ros.io.errors import InputError

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
PATH_TYPE = 'nav_msgs/msg/Path'
ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
POSE_STAMPED_TYPE = 'geometry_msgs/msg/PoseStamped'
POSE_COVARIANCE_TYPE = 'geometry_msgs/msg/PoseWithCovarianceStamped'
CONSTRAINTS_TYPE = 'std_msgs/msg/Float64MultiArray'
TF_TYPE = 'tf2_msgs/msg/TFMessage'
POSE_TYPES = (PATH_TYPE, ODOMETRY_TYPE, POSE_STAMPED_TYPE, POSE_COVARIANCE_TYPE)
CONSTRAINT_FIELDS = ('stamp_from', 'stamp_to', 'dx', 'dy', 'dtheta',
                     'I11', 'I12', 'I13', 'I22', 'I23', 'I33')
STORAGES = ('mcap', 'sqlite3')


@dataclass(frozen=True)
class Scan:
    """One LaserScan; `model.max_range` is its range_max capped at the reader's max_range."""

    stamp: float
    ranges: np.ndarray  # (K,) metres
    model: SensorModel
    frame_id: str


@dataclass(frozen=True)
class Trajectory:
    """One Path: stamps (M,) seconds and poses (M, 3) in `frame_id`."""

    stamps: np.ndarray
    poses: np.ndarray
    frame_id: str


@dataclass(frozen=True)
class PoseSample:
    """One pose of a single-pose message: the pose of `child_frame_id` in `frame_id`."""

    stamp: float
    pose: np.ndarray  # (3,)
    frame_id: str
    child_frame_id: str


@dataclass(frozen=True)
class Constraints:
    """The full edge set: rows (E, 11) laid out as CONSTRAINT_FIELDS."""

    rows: np.ndarray


@dataclass(frozen=True)
class BadMessage:
    """A message whose content cannot be used (the node would drop it with a warning)."""

    topic: str
    index: int  # 1-based position on its topic
    reason: str


Record = Scan | Trajectory | PoseSample | Constraints | BadMessage


@dataclass(frozen=True)
class BagTopics:
    """Topic names. `poses=None` picks '/trajectory', else the bag's only pose topic."""

    scan: str = '/scan'
    poses: str | None = None
    constraints: str = '/constraints'


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


def stamp_to_seconds(stamp) -> float:
    """A builtin_interfaces/Time (or ROS 1 time) as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def yaw_from_quaternion(x, y, z, w):
    """Rotation about z of (possibly unnormalised) quaternions, scalars or arrays."""
    # w^2 + x^2 - y^2 - z^2 rather than 1 - 2 (y^2 + z^2): the same for unit quaternions,
    # and independent of the norm for the others.
    return np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


# The functions below read message objects by attribute only, so they serve rosbags'
# deserialized messages and rclpy's alike (the node and replay convert the same way).

def scan_to_numpy(msg, max_range: float = math.inf) -> tuple[float, np.ndarray, SensorModel]:
    """(stamp, ranges (K,), SensorModel) of a LaserScan.

    The usable range is the smaller of the scan's `range_max` and `max_range` (beams beyond it
    count as free space). NaN / inf ranges are kept. Raises ValueError for an empty scan,
    non-finite or non-positive angle fields, or angle fields that disagree with the number of
    ranges by more than one beam (drivers differ on whether angle_max is inclusive).
    """
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    beams = ranges.size
    if beams < 2:
        raise ValueError(f'scan has {beams} ranges; at least 2 are needed')
    angle_min, angle_max, increment = msg.angle_min, msg.angle_max, msg.angle_increment
    if not all(math.isfinite(v) for v in (angle_min, angle_max, increment)) or increment <= 0.0:
        raise ValueError(f'scan angle fields are unusable: angle_min={angle_min}, '
                         f'angle_max={angle_max}, angle_increment={increment}')
    implied = (angle_max - angle_min) / increment + 1.0
    if abs(implied - beams) > 1.0 + 1e-6:
        raise ValueError(f'scan angles imply {implied:.1f} beams but it has {beams} ranges '
                         f'(angle_min={angle_min}, angle_max={angle_max}, '
                         f'angle_increment={increment})')
    usable = min(msg.range_max, max_range) if math.isfinite(msg.range_max) else max_range
    range_min = msg.range_min if math.isfinite(msg.range_min) and msg.range_min > 0.0 else 0.0
    model = SensorModel(angle_min=angle_min, angle_increment=increment, max_range=usable,
                        range_min=range_min)
    model.check_beam_count(beams)
    return stamp_to_seconds(msg.header.stamp), ranges, model


def path_to_numpy(msg) -> tuple[np.ndarray, np.ndarray]:
    """(stamps (M,), poses (M, 3) x, y, yaw) of a Path's PoseStamped entries.

    Non-finite values are passed on (the monitor skips those poses); a zero quaternion
    has no heading and raises ValueError.
    """
    count = len(msg.poses)
    stamps = np.empty(count)
    values = np.empty((count, 6))
    for index, entry in enumerate(msg.poses):
        position, orientation = entry.pose.position, entry.pose.orientation
        stamps[index] = stamp_to_seconds(entry.header.stamp)
        values[index] = (position.x, position.y, orientation.x, orientation.y, orientation.z,
                         orientation.w)
    degenerate = np.flatnonzero(np.linalg.norm(values[:, 2:], axis=1) == 0.0)
    if degenerate.size:
        raise ValueError(f'path pose {int(degenerate[0])} has a zero quaternion')
    yaw = yaw_from_quaternion(*values[:, 2:].T)
    return stamps, np.column_stack([values[:, :2], yaw])


def constraints_to_numpy(msg) -> np.ndarray:
    """Edge rows (E, 11) of a Float64MultiArray, in the order of CONSTRAINT_FIELDS.

    With a layout, it must be two dimensions (edges, 11) whose sizes match the data after
    data_offset; without one, the data length must be a multiple of 11. Raises ValueError
    otherwise.
    """
    data = np.asarray(msg.data, dtype=np.float64)
    width = len(CONSTRAINT_FIELDS)
    dims = msg.layout.dim
    offset = msg.layout.data_offset
    if dims:
        if len(dims) != 2 or dims[1].size != width:
            shape = [d.size for d in dims]
            raise ValueError(f'constraints layout must be (edges, {width}), got {shape}')
        rows = dims[0].size
        if offset + rows * width > data.size:
            raise ValueError(f'constraints layout says {rows} x {width} values from offset '
                             f'{offset}, but data has {data.size}')
        return data[offset:offset + rows * width].reshape(rows, width)
    data = data[offset:]
    if data.size % width:
        raise ValueError(f'constraints data has {data.size} values, not a multiple of {width}')
    return data.reshape(-1, width)


def _pose_of(pose) -> np.ndarray:
    orientation = pose.orientation
    return np.array([pose.position.x, pose.position.y,
                     yaw_from_quaternion(orientation.x, orientation.y, orientation.z,
                                         orientation.w)])


class BagReader:
    """Typed, checked reading of one bag (or the split files of one bag).

    Scans are converted as the node does (`scan_to_numpy` with `max_range`, the usable range).
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
            reader = AnyReader(self.paths, default_typestore=get_typestore(Stores.ROS2_JAZZY))
            reader.open()
        except _bag_errors() as error:
            raise InputError(self.source, f'not a readable ROS bag ({_describe(error)})') from None
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
        self.pose_type = self._require(self.pose_topic, POSE_TYPES, '--pose-topic')
        if self.topics.constraints in self._connections:
            self._require(self.topics.constraints, (CONSTRAINTS_TYPE,), '--constraints-topic')

    def _default_pose_topic(self) -> str:
        types = self._topic_types()
        if '/trajectory' in types:
            return '/trajectory'
        candidates = sorted(topic for topic, msgtype in types.items() if msgtype in POSE_TYPES)
        if len(candidates) != 1:
            found = ', '.join(candidates) if candidates else 'none'
            raise InputError(self.source, f'no /trajectory topic and {len(candidates)} other pose '
                                          f'topics ({found}); choose one with --pose-topic')
        return candidates[0]

    def topic_type(self, topic: str) -> str:
        """Message type of a topic of the bag."""
        return self._topic_types()[topic]

    @property
    def has_constraints(self) -> bool:
        return self.topics.constraints in self._connections

    @property
    def is_ros1(self) -> bool:
        return not self._reader.is2

    def message_count(self, topic: str) -> int:
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

    def records(self) -> Iterator[tuple[float, Record]]:
        """(log time in seconds, record) of the scan, pose and constraints topics, in log order.

        Messages whose content is unusable come as BadMessage; a damaged file raises
        InputError.
        """
        topics = [self.topics.scan, self.pose_topic]
        if self.has_constraints:
            topics.append(self.topics.constraints)
        counts: dict[str, int] = {}
        for connection, timestamp, message in self._messages(self._selected(topics)):
            index = counts[connection.topic] = counts.get(connection.topic, 0) + 1
            try:
                record = _record(connection.msgtype, message, self.max_range)
            except ValueError as error:
                record = BadMessage(topic=connection.topic, index=index, reason=str(error))
            yield timestamp * 1e-9, record

    def raw_messages(self, topics: Sequence[str]) -> Iterator[tuple[str, str, float, bytes]]:
        """(topic, message type, log time in seconds, CDR bytes) of ROS 2 bags, in log order.

        Raises InputError at once for a ROS 1 bag, whose messages are not CDR.
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

    def _messages(self, connections: list) -> Iterator[tuple]:
        errors = _bag_errors()
        try:
            for connection, timestamp, data in self._reader.messages(connections):
                yield connection, timestamp, self._reader.deserialize(data, connection.msgtype)
        except errors as error:
            raise InputError(self.source, f'damaged bag ({_describe(error)})') from None

    def static_transform(self, parent: str, child: str) -> np.ndarray | None:
        """The planar pose of `child` in `parent` from /tf_static, None when the bag lacks it."""
        connections = [connection for connection in self._reader.connections
                       if connection.topic == '/tf_static' and connection.msgtype == TF_TYPE]
        wanted = (parent.lstrip('/'), child.lstrip('/'))
        for _, _, message in self._messages(connections):
            for transform in message.transforms:
                frames = (transform.header.frame_id.lstrip('/'),
                          transform.child_frame_id.lstrip('/'))
                if frames == wanted:
                    moved = transform.transform
                    rotation = moved.rotation
                    return np.array([moved.translation.x, moved.translation.y,
                                     yaw_from_quaternion(rotation.x, rotation.y, rotation.z,
                                                         rotation.w)])
        return None


def _describe(error: BaseException) -> str:
    text = str(error).strip()
    return f'{type(error).__name__}: {text}' if text else type(error).__name__


def _record(msgtype: str, message, max_range: float) -> Record:
    """The typed record of one deserialized message (ValueError for unusable content)."""
    if msgtype == SCAN_TYPE:
        stamp, ranges, model = scan_to_numpy(message, max_range)
        return Scan(stamp=stamp, ranges=ranges, model=model, frame_id=message.header.frame_id)
    if msgtype == PATH_TYPE:
        stamps, poses = path_to_numpy(message)
        return Trajectory(stamps=stamps, poses=poses, frame_id=message.header.frame_id)
    if msgtype == CONSTRAINTS_TYPE:
        return Constraints(rows=constraints_to_numpy(message))
    child = getattr(message, 'child_frame_id', '')
    pose = message.pose if msgtype == POSE_STAMPED_TYPE else message.pose.pose
    return PoseSample(stamp=stamp_to_seconds(message.header.stamp), pose=_pose_of(pose),
                      frame_id=message.header.frame_id, child_frame_id=child)


class OdometryKeyframes:
    """Keyframes from single-pose messages (odometry, a localizer) and the scans between them.

    Each scan takes the pose interpolated at its stamp between the two pose messages around
    it (scans outside the pose stream are dropped). A scan becomes a keyframe when the robot
    has moved `min_distance` metres or turned `min_angle` radians since the last keyframe, as
    a SLAM front end would select them. `add_pose` returns the scans that became keyframes.
    """

    def __init__(self, min_distance: float, min_angle: float, history: int = 256) -> None:
        if not (min_distance >= 0.0 and min_angle >= 0.0):
            raise ValueError('keyframe distance and angle must not be negative')
        self.min_distance = min_distance
        self.min_angle = min_angle
        self._pending: deque[Scan] = deque()
        self._poses: deque[tuple[float, np.ndarray]] = deque(maxlen=history)
        self._last: np.ndarray | None = None
        self.stamps: list[float] = []
        self.poses: list[np.ndarray] = []
        self.dropped = 0

    def add_scan(self, scan: Scan) -> None:
        self._pending.append(scan)

    def add_pose(self, sample: PoseSample) -> list[Scan]:
        """Place the scans the new pose brackets; return those that became keyframes."""
        self._poses.append((sample.stamp, sample.pose))
        keyframes = []
        while self._pending and self._pending[0].stamp <= sample.stamp:
            scan = self._pending.popleft()
            pose = self._interpolate(scan.stamp)
            if pose is None:
                self.dropped += 1
            elif self._is_keyframe(pose):
                self._last = pose
                self.stamps.append(scan.stamp)
                self.poses.append(pose)
                keyframes.append(scan)
        return keyframes

    def _interpolate(self, stamp: float) -> np.ndarray | None:
        stamps = np.fromiter((entry[0] for entry in self._poses), dtype=np.float64)
        after = int(np.searchsorted(stamps, stamp))
        if after == len(stamps) or (after == 0 and stamps[0] != stamp):
            return None
        if stamps[after] == stamp:
            return self._poses[after][1]
        (start, first), (end, second) = self._poses[after - 1], self._poses[after]
        fraction = (stamp - start) / (end - start)
        step = se2.relative(first, second)
        return se2.compose(first, fraction * step)

    def _is_keyframe(self, pose: np.ndarray) -> bool:
        if self._last is None:
            return True
        distance = math.hypot(pose[0] - self._last[0], pose[1] - self._last[1])
        turn = abs(float(se2.wrap_angle(pose[2] - self._last[2])))
        return distance >= self.min_distance or turn >= self.min_angle


# -- writing ---------------------------------------------------------------------------------

def _time(typestore, seconds: float):
    whole = math.floor(seconds)
    nanosec = int(round((seconds - whole) * 1e9))
    if nanosec >= 1_000_000_000:
        whole, nanosec = whole + 1, nanosec - 1_000_000_000
    return typestore.types['builtin_interfaces/msg/Time'](sec=int(whole), nanosec=nanosec)


class BagWriter:
    """Writes a rosbag2 (mcap or sqlite3) with /scan, /trajectory and /constraints.

    Use as a context manager; `path` must not exist. Each write takes its log time in seconds
    (the time the message would have been published). `compress` turns on zstd chunk
    compression (mcap only).
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
        self._connections: dict[str, object] = {}

    def __enter__(self) -> BagWriter:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
        from rosbags.typesys import Stores, get_typestore
        if self.path.exists():
            raise InputError(str(self.path), 'output already exists; remove it or choose another')
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        plugin = StoragePlugin.MCAP if self.storage == 'mcap' else StoragePlugin.SQLITE3
        writer = Writer(self.path, version=9, storage_plugin=plugin)
        if self.compress:
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.open()
        self._writer = writer
        for topic, msgtype in ((self.topics.scan, SCAN_TYPE), (self.topics.poses, PATH_TYPE),
                               (self.topics.constraints, CONSTRAINTS_TYPE)):
            self._connections[msgtype] = writer.add_connection(topic, msgtype,
                                                               typestore=self.typestore)
        return self

    def __exit__(self, *exc_info) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def _write(self, msgtype: str, time: float, message) -> None:
        data = self.typestore.serialize_cdr(message, msgtype)
        self._writer.write(self._connections[msgtype], int(round(time * 1e9)), data)

    def _header(self, stamp: float, frame_id: str):
        return self.typestore.types['std_msgs/msg/Header'](stamp=_time(self.typestore, stamp),
                                                           frame_id=frame_id)

    def write_scan(self, time: float, stamp: float, ranges: np.ndarray, model: SensorModel,
                   frame_id: str = 'laser') -> None:
        """A LaserScan whose beam k has bearing angle_min + k * angle_increment."""
        ranges = np.asarray(ranges, dtype=np.float32)
        types = self.typestore.types
        message = types[SCAN_TYPE](
            header=self._header(stamp, frame_id), angle_min=model.angle_min,
            angle_max=model.angle_min + (ranges.size - 1) * model.angle_increment,
            angle_increment=model.angle_increment, time_increment=0.0, scan_time=0.0,
            range_min=model.range_min, range_max=model.max_range, ranges=ranges,
            intensities=np.zeros(0, dtype=np.float32))
        self._write(SCAN_TYPE, time, message)

    def write_trajectory(self, time: float, stamps: np.ndarray, poses: np.ndarray,
                         frame_id: str = 'map') -> None:
        """A Path of poses (M, 3), each PoseStamped stamped with its scan's stamp."""
        types = self.typestore.types
        pose_type, point_type = types['geometry_msgs/msg/Pose'], types['geometry_msgs/msg/Point']
        quaternion = types['geometry_msgs/msg/Quaternion']
        entries = [
            types[POSE_STAMPED_TYPE](
                header=self._header(float(stamp), frame_id),
                pose=pose_type(position=point_type(x=float(x), y=float(y), z=0.0),
                               orientation=quaternion(x=0.0, y=0.0, z=math.sin(0.5 * theta),
                                                      w=math.cos(0.5 * theta))))
            for stamp, (x, y, theta) in zip(stamps, poses)]
        message = types[PATH_TYPE](header=self._header(time, frame_id), poses=entries)
        self._write(PATH_TYPE, time, message)

    def write_constraints(self, time: float, rows: np.ndarray) -> None:
        """All pose-graph edges as a Float64MultiArray of rows laid out as CONSTRAINT_FIELDS."""
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, len(CONSTRAINT_FIELDS))
        types = self.typestore.types
        dimension = types['std_msgs/msg/MultiArrayDimension']
        layout = types['std_msgs/msg/MultiArrayLayout'](
            dim=[dimension(label='edges', size=rows.shape[0], stride=rows.size),
                 dimension(label='fields', size=rows.shape[1], stride=rows.shape[1])],
            data_offset=0)
        message = types[CONSTRAINTS_TYPE](layout=layout, data=rows.ravel())
        self._write(CONSTRAINTS_TYPE, time, message)
