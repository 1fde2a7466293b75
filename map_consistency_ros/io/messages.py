"""ROS messages <-> numpy and input records, without ROS: the one owner of the message formats.

Reading: functions read message objects by attribute only, so they serve rclpy's messages
(the node) and rosbags' deserialized ones (bag replay) alike; `to_record` turns one message of
a known type into its core record and raises ValueError, with a message fit for a log line,
when its content is unusable.

Writing: builders take `types`, a function from a type name ('nav_msgs/msg/Path') to its
message class (rclpy's classes, or a rosbags typestore's), and fill every field, as the
rosbags classes require.
"""
from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.backend import CONSTRAINT_FIELDS, CONSTRAINT_WIDTH
from map_consistency_ros.core.geometry import SensorModel, se2
from map_consistency_ros.core.live import (Constraints, GraphSnapshot, KeyframeEstimate,
                                           LoopClosure, NodeEvent, PoseGraphNodes, PoseSample,
                                           Record, Scan)
from map_consistency_ros.io.limits import DISTANCE, SCAN_ANGLE, STAMP, implausible

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
PATH_TYPE = 'nav_msgs/msg/Path'
ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
POSE_STAMPED_TYPE = 'geometry_msgs/msg/PoseStamped'
POSE_COVARIANCE_TYPE = 'geometry_msgs/msg/PoseWithCovarianceStamped'
CONSTRAINTS_TYPE = 'std_msgs/msg/Float64MultiArray'
MARKER_ARRAY_TYPE = 'visualization_msgs/msg/MarkerArray'
# slam_toolbox's pose-graph interface (pull request 818, docs/slam_bridges.md); the field lists
# ship in io/msg/slam_toolbox/ for bags (register_slam_toolbox_types).
POSE_GRAPH_TYPE = 'slam_toolbox/msg/PoseGraph'
NEW_NODE_EVENT_TYPE = 'slam_toolbox/msg/NewNodeEvent'
LOOP_CLOSURE_EVENT_TYPE = 'slam_toolbox/msg/LoopClosureEvent'
SLAM_TOOLBOX_GRAPH_TYPES = (NEW_NODE_EVENT_TYPE, POSE_GRAPH_TYPE, LOOP_CLOSURE_EVENT_TYPE)
SINGLE_POSE_TYPES = (ODOMETRY_TYPE, POSE_STAMPED_TYPE, POSE_COVARIANCE_TYPE)
POSE_TYPES = (PATH_TYPE,) + SINGLE_POSE_TYPES
# The node's pose_source parameter -> message type of its pose topic (slam_toolbox_graph: the
# node events, which name the scans; its graph and loop closures come beside them).
POSE_SOURCE_TYPES = {'path': PATH_TYPE, 'odometry': ODOMETRY_TYPE, 'pose': POSE_STAMPED_TYPE,
                     'pose_with_covariance': POSE_COVARIANCE_TYPE,
                     'slam_toolbox': POSE_COVARIANCE_TYPE,
                     'slam_toolbox_graph': NEW_NODE_EVENT_TYPE}
# slam_toolbox's graph_visualization (src/loop_closure_assistant.cpp, publishGraph): one SPHERE
# per vertex in this namespace, marker id = vertex id; edges in other namespaces.
SLAM_TOOLBOX_NAMESPACE = 'slam_toolbox'
# visualization_msgs/Marker constants (the same in every ROS 2 release)
MARKER_SPHERE, MARKER_LINE_LIST = 2, 5
MARKER_ADD, MARKER_DELETE, MARKER_DELETEALL = 0, 2, 3

MessageTypes = Callable[[str], type]


# -- messages -> numpy --------------------------------------------------------------------------

def stamp_to_seconds(stamp) -> float:
    """A builtin_interfaces/Time (or ROS 1 time) as float seconds.

    Parameters
    ----------
    stamp: any object with integer fields `sec` and `nanosec`.

    Returns
    -------
    sec + nanosec * 1e-9.
    """
    return stamp.sec + stamp.nanosec * 1e-9


def scan_to_numpy(msg, max_range: float = math.inf) -> tuple[float, np.ndarray, SensorModel]:
    """The stamp, ranges and beam geometry of a LaserScan.

    The usable range is the smaller of the scan's `range_max` and `max_range` (beams beyond it
    count as free space); a range_max of +inf states no maximum. NaN / inf ranges are kept:
    they are beams without a return.

    Parameters
    ----------
    msg: a sensor_msgs/LaserScan (rclpy's or rosbags').
    max_range: the usable range of the test in metres; inf leaves the scan's `range_max`.

    Returns
    -------
    (header stamp in seconds, ranges (K,) float64 metres, SensorModel); the model's range_min
    is the scan's when finite and positive, else 0. Raises ValueError, naming the stamp, for
    fewer than 2 ranges, a negative stamp, angle fields that are not finite or beyond two
    turns, a non-positive angle_increment, a range_max that is NaN, negative or beyond 1e5 m (io/limits.py)
    (io/limits.py), angle fields that disagree with the number of ranges by more than one
    beam (drivers differ on whether angle_max is inclusive), or a geometry SensorModel
    rejects.
    """
    stamp = stamp_to_seconds(msg.header.stamp)
    where = f'scan stamped {stamp!r} s'
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    beams = ranges.size
    if beams < 2:
        raise ValueError(f'{where} has {beams} ranges; at least 2 are needed')
    angle_min, angle_max, increment = msg.angle_min, msg.angle_max, msg.angle_increment
    range_max = msg.range_max
    check_fields(where, (('header stamp', stamp, STAMP), ('angle_min', angle_min, SCAN_ANGLE),
                         ('angle_increment', increment, SCAN_ANGLE),
                         ('angle_max', angle_max, SCAN_ANGLE),
                         # +inf: no maximum stated (the usable range caps it)
                         ('range_max', 0.0 if range_max == math.inf else range_max, DISTANCE)))
    if increment <= 0.0:
        raise ValueError(f'{where}: scan angle fields are unusable: angle_min={angle_min}, '
                         f'angle_max={angle_max}, angle_increment={increment}')
    implied = (angle_max - angle_min) / increment + 1.0
    if abs(implied - beams) > 1.0 + 1e-6:
        raise ValueError(f'{where}: scan angles imply {implied:.1f} beams but it has {beams} '
                         f'ranges (angle_min={angle_min}, angle_max={angle_max}, '
                         f'angle_increment={increment})')
    usable = min(range_max, max_range) if math.isfinite(range_max) else max_range
    range_min = msg.range_min if math.isfinite(msg.range_min) and msg.range_min > 0.0 else 0.0
    try:
        model = SensorModel(angle_min=angle_min, angle_increment=increment, max_range=usable,
                            range_min=range_min)
        model.check_beam_count(beams)
    except ValueError as error:
        raise ValueError(f'{where}: {error}') from None
    return stamp, ranges, model


def check_fields(where: str, fields) -> None:
    """Refuse message fields outside their plausible range (io/limits.py).

    Parameters
    ----------
    where: the message, e.g. 'scan stamped 12.5 s', the start of the error message.
    fields: (name, value, Limit) of each field.

    Returns
    -------
    None. Raises ValueError naming the message and the first implausible field.
    """
    for name, value, limit in fields:
        problem = implausible(value, limit)
        if problem is not None:
            raise ValueError(f'{where}: {name} {problem[1]}')


def pose_to_numpy(pose) -> np.ndarray:
    """The planar pose of a geometry_msgs/Pose (z and roll / pitch are dropped).

    Parameters
    ----------
    pose: a geometry_msgs/Pose.

    Returns
    -------
    (3,) x, y, yaw (radians); yaw NaN for an unusable quaternion.
    """
    orientation = pose.orientation
    return np.array([pose.position.x, pose.position.y,
                     se2.yaw_from_quaternion(orientation.x, orientation.y, orientation.z,
                                             orientation.w)])


def path_to_numpy(msg) -> tuple[np.ndarray, np.ndarray]:
    """The stamps and planar poses of a Path's PoseStamped entries.

    Non-finite values, and a NaN yaw for an unusable quaternion (zero, or with a non-finite
    component), are passed on: the monitor skips those poses and says so.

    Parameters
    ----------
    msg: a nav_msgs/Path.

    Returns
    -------
    (stamps (M,) seconds of the entries' headers, poses (M, 3) x, y, yaw).
    """
    count = len(msg.poses)
    stamps = np.empty(count)
    values = np.empty((count, 6))
    for index, entry in enumerate(msg.poses):
        position, orientation = entry.pose.position, entry.pose.orientation
        stamps[index] = stamp_to_seconds(entry.header.stamp)
        values[index] = (position.x, position.y, orientation.x, orientation.y, orientation.z,
                         orientation.w)
    yaw = se2.yaw_from_quaternion(*values[:, 2:].T)
    return stamps, np.column_stack([values[:, :2], yaw])


# CDR little endian (XCDR1), how ROS 2 Jazzy's middlewares and rosbag2 carry messages: a
# 4-byte encapsulation header, then fields aligned to their size from the end of that header.
_CDR_LE = b'\x00\x01'
_ENCAPSULATION = 4
_POSE_VALUES = 7  # position x, y, z, orientation x, y, z, w: float64 each


def _align(offset: int, size: int) -> int:
    return offset + (-offset) % size


def _pose_entries(values_offset: int) -> np.dtype:
    """A PoseStamped in CDR: stamp, frame id length, (its characters), the 7 pose values."""
    return np.dtype({'names': ['sec', 'nanosec', 'frame_length', 'values'],
                     'formats': ['<i4', '<u4', '<u4', ('<f8', _POSE_VALUES)],
                     'offsets': [0, 4, 8, values_offset],
                     'itemsize': values_offset + 8 * _POSE_VALUES})


@dataclass(frozen=True)
class _PathLayout:
    """Where a serialized Path's entries lie in its CDR body (after the encapsulation)."""

    frame_id: str
    stamp: float  # the header's
    count: int
    first: int  # offset of the first entry in the body
    head: np.dtype  # the first entry (4-aligned)
    rest: np.dtype  # every later entry (8-aligned, evenly spaced)
    frame_length: int  # of the entries' frame ids, which all share it

    def end(self, count: int) -> int:
        """The body offset just past the first `count` entries (count >= 1)."""
        return self.first + self.head.itemsize + (count - 1) * self.rest.itemsize


def _path_layout(body: memoryview) -> _PathLayout | None:
    """The layout of a Path's CDR body, None for one path_from_cdr does not read."""
    header_frame = int.from_bytes(body[8:12], 'little')
    count_at = _align(12 + header_frame, 4)
    if header_frame == 0 or count_at + 4 > len(body):
        return None
    frame_id = bytes(body[12:11 + header_frame]).decode('utf-8', errors='replace')
    count = int.from_bytes(body[count_at:count_at + 4], 'little')
    first = count_at + 4
    # the header's stamp: sec (int32), nanosec (uint32) before its frame id
    stamp = int.from_bytes(body[0:4], 'little', signed=True) + int.from_bytes(
        body[4:8], 'little') * 1e-9
    if count == 0:
        return _PathLayout(frame_id, stamp, 0, first, _pose_entries(8), _pose_entries(8), 0)
    if first + 12 > len(body):
        return None
    length = int.from_bytes(body[first + 8:first + 12], 'little')
    # The first entry starts 4-aligned, every later one right after 8-aligned values: with
    # one frame id length, the later ones are evenly spaced.
    layout = _PathLayout(frame_id, stamp, count, first,
                         _pose_entries(_align(first + 12 + length, 8) - first),
                         _pose_entries(_align(12 + length, 8)), length)
    return layout if layout.end(count) <= len(body) else None


def _path_entries(body: memoryview, layout: _PathLayout, start: int
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """(stamps, poses (., 3)) of entries start..count-1 of a Path body; None when one of
    their frame ids differs in length from the first's."""
    entries = [] if start else [np.frombuffer(body, dtype=layout.head, count=1,
                                              offset=layout.first)]
    later = max(start, 1)
    entries.append(np.frombuffer(body, dtype=layout.rest, count=layout.count - later,
                                 offset=layout.end(later)))
    if any(np.any(entry['frame_length'] != layout.frame_length) for entry in entries):
        return None
    stamps = np.concatenate([entry['sec'] + entry['nanosec'] * 1e-9 for entry in entries])
    values = np.concatenate([entry['values'] for entry in entries])
    yaw = se2.yaw_from_quaternion(*values[:, 3:].T)
    return stamps, np.column_stack([values[:, :2], yaw])


def path_from_cdr(data: bytes) -> KeyframeEstimate | None:
    """The record of a serialized nav_msgs/Path, read straight from its CDR bytes.

    Deserializing a Path builds a message object per pose, all of it holding the interpreter
    lock, and a SLAM back-end sends the whole estimate every time; numpy reads the bytes in one
    pass. The values are those of path_to_numpy.

    Parameters
    ----------
    data: the serialized message, 4-byte encapsulation header first (as rclpy's raw
        subscriptions and rosbag2 give it).

    Returns
    -------
    A KeyframeEstimate (entry stamps, poses (M, 3), frame id and header stamp), or None for a
    layout this does not read (big endian, XCDR2, entries whose frame ids differ in length,
    a message shorter than its lengths say): the caller deserializes those.
    """
    return PathReader()(data)


class PathReader:
    """path_from_cdr for one stream of Paths: the entries a Path repeats byte for byte from
    the previous one are not decoded again.

    A back-end sends its whole estimate every time, and between optimisations it only appends
    poses: decoding every entry would make each Path cost more than the last, with the length
    of the run. The repeated entries are found by comparing bytes (one pass of memory
    comparison, several times cheaper than decoding them), and only the entries after them
    are decoded. Any difference, in a pose, a stamp or the frame ids' length, decodes the
    whole Path. Not thread-safe: one reader per subscription.
    """

    def __init__(self) -> None:
        self._last: tuple[bytes, _PathLayout, np.ndarray, np.ndarray] | None = None
        self._mask: tuple[tuple[int, int], np.ndarray] | None = None

    def __call__(self, data: bytes) -> KeyframeEstimate | None:
        """The record of serialized Path `data`, as path_from_cdr."""
        if len(data) < _ENCAPSULATION + 16 or bytes(data[:2]) != _CDR_LE:
            return None
        body = memoryview(data)[_ENCAPSULATION:]
        layout = _path_layout(body)
        if layout is None:
            return None
        if layout.count == 0:
            return KeyframeEstimate(stamps=np.zeros(0), poses=np.zeros((0, 3)),
                                    frame_id=layout.frame_id, stamp=layout.stamp)
        repeated = self._repeated(body, layout)
        decoded = _path_entries(body, layout, repeated)
        if decoded is None:
            return None
        stamps, poses = decoded
        if repeated:
            _, _, old_stamps, old_poses = self._last
            stamps = np.concatenate([old_stamps[:repeated], stamps])
            poses = np.concatenate([old_poses[:repeated], poses])
        self._last = (data, layout, stamps, poses)
        return KeyframeEstimate(stamps=stamps, poses=poses, frame_id=layout.frame_id,
                                stamp=layout.stamp)

    def _repeated(self, body: memoryview, layout: _PathLayout) -> int:
        """How many leading entries `body` shares byte for byte with the last Path read (0
        when the layouts differ or it does not start with all of the last one's)."""
        if self._last is None:
            return 0
        data, last, _, _ = self._last
        count = last.count
        if (count == 0 or count > layout.count or last.first != layout.first
                or last.frame_length != layout.frame_length):
            return 0
        start, end = layout.first, layout.end(count)
        # Every byte but the alignment padding after each entry's frame id, which serializers
        # leave as they find it: compared as 4-byte words (entries start 4-aligned in the
        # body), each masked to its meaningful bytes.
        words = (end - start) // 4
        old = np.frombuffer(data, dtype='<u4', count=words, offset=_ENCAPSULATION + start)
        new = np.frombuffer(body, dtype='<u4', count=words, offset=start)
        head = layout.head.itemsize // 4
        if np.any((old[:head] ^ new[:head]) & _entry_mask(layout.head, layout.frame_length)):
            return 0
        differ = old[head:] ^ new[head:]
        differ &= self._rest_mask(layout, differ.size)
        return 0 if differ.any() else count

    def _rest_mask(self, layout: _PathLayout, words: int) -> np.ndarray:
        """The masks of `words` words of evenly spaced entries: one flat array, kept (masking
        a (count, words per entry) view entry by entry costs several times more)."""
        key = (layout.rest.itemsize, layout.frame_length)
        if self._mask is None or self._mask[0] != key or self._mask[1].size < words:
            entry = _entry_mask(layout.rest, layout.frame_length)
            self._mask = (key, np.tile(entry, 2 * -(-words // entry.size)))
        return self._mask[1][:words]


def _entry_mask(entry: np.dtype, frame_length: int) -> np.ndarray:
    """(itemsize / 4,) little-endian word masks of a Path entry: 0xff on every byte but the
    padding between its frame id's characters and its pose values."""
    mask = np.full(entry.itemsize, 0xFF, dtype=np.uint8)
    mask[12 + frame_length:entry.fields['values'][1]] = 0
    return mask.view('<u4')


def constraints_to_numpy(msg) -> np.ndarray:
    """The pose-graph edge rows of a Float64MultiArray.

    Parameters
    ----------
    msg: a std_msgs/Float64MultiArray. With a layout, it must be two dimensions (edges, 11)
        whose sizes match the data after data_offset; without one, the data length after
        data_offset must be a multiple of 11.

    Returns
    -------
    (E, 11) float64 rows in the order of CONSTRAINT_FIELDS. Raises ValueError when the layout
    or the data length does not fit.
    """
    data = np.asarray(msg.data, dtype=np.float64)
    width = CONSTRAINT_WIDTH
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


def graph_markers_to_numpy(msg) -> tuple[np.ndarray, np.ndarray, str]:
    """The vertices of a slam_toolbox graph_visualization array.

    See _graph_vertices for which markers are vertices.

    Parameters
    ----------
    msg: a visualization_msgs/MarkerArray.

    Returns
    -------
    (vertex ids (V,) int64, positions (V, 2) x, y, the first non-empty frame id of a vertex
    marker or '').
    Raises ValueError as _graph_vertices does (no DELETEALL, a non-SPHERE marker in the vertex
    namespace, a repeated id, a non-finite position).
    """
    return _graph_vertices(
        (marker.ns, marker.id, marker.type, marker.action, marker.pose.position.x,
         marker.pose.position.y, marker.header.frame_id) for marker in msg.markers)


def _graph_vertices(markers) -> tuple[np.ndarray, np.ndarray, str]:
    """The vertices of markers given as (namespace, id, type, action, x, y, frame id).

    Only SPHERE markers of namespace `slam_toolbox` are vertices (the edges' LINE_LISTs live in
    `slam_toolbox_edges`); the orientation is ignored, slam_toolbox leaves it the identity.
    Markers are taken in order: DELETEALL forgets every vertex before it, DELETE the vertex of
    its id. An array without a DELETEALL is not a full snapshot (slam_toolbox always starts
    with one), and one it cannot take whole would silently lose or misplace vertices: both
    raise ValueError, as do a non-SPHERE marker in the vertex namespace and a non-finite
    position.
    """
    vertices: dict[int, tuple[float, float]] = {}
    repeated: list[int] = []
    cleared = False
    frame_id = ''
    for index, (namespace, marker_id, marker_type, action, x, y, frame) in enumerate(markers):
        if action == MARKER_DELETEALL:
            vertices.clear()
            repeated.clear()
            cleared = True
            continue
        if namespace != SLAM_TOOLBOX_NAMESPACE:
            continue
        if action == MARKER_DELETE:
            vertices.pop(int(marker_id), None)
            continue
        if action != MARKER_ADD or marker_type != MARKER_SPHERE:
            raise ValueError(f'marker {index} (id {marker_id}) in namespace '
                             f'{SLAM_TOOLBOX_NAMESPACE!r} has type {marker_type}, action '
                             f'{action}; a vertex is an added SPHERE')
        position = (x, y)
        if not all(math.isfinite(value) for value in position):
            raise ValueError(f'vertex {marker_id} has a non-finite position {position}')
        if int(marker_id) in vertices:
            repeated.append(int(marker_id))
        vertices[int(marker_id)] = position
        frame_id = frame_id or frame
    if not cleared:
        raise ValueError('no DELETEALL marker: not a full slam_toolbox graph snapshot')
    if repeated:
        # slam_toolbox's ids are per-laser state ids: several lasers repeat them.
        raise ValueError(f'vertex ids {sorted(set(repeated))[:5]} appear more than once '
                         '(one laser is supported)')
    ids = np.fromiter(vertices, dtype=np.int64, count=len(vertices))
    positions = np.array(list(vertices.values()), dtype=np.float64).reshape(-1, 2)
    return ids, positions, frame_id


def pose_graph_to_numpy(msg) -> tuple[np.ndarray, np.ndarray]:
    """The nodes of a slam_toolbox PoseGraph; its edges are not read (the monitor takes
    constraints in its own row format).

    Parameters
    ----------
    msg: a slam_toolbox/msg/PoseGraph.

    Returns
    -------
    (node ids (V,) int64, poses (V, 3) x, y, yaw) in message order. Raises ValueError for
    repeated or negative ids and non-finite values (see _graph_nodes).
    """
    count = len(msg.nodes)
    ids = np.empty(count, dtype=np.int64)
    values = np.empty((count, 7))
    for index, node in enumerate(msg.nodes):
        position, orientation = node.pose.position, node.pose.orientation
        ids[index] = node.node_id
        values[index] = (position.x, position.y, position.z, orientation.x, orientation.y,
                         orientation.z, orientation.w)
    return _graph_nodes(ids, values)


def _graph_nodes(ids: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ids, poses (V, 3)) of node ids and their Pose values (V, 7: position, quaternion).

    A repeated id (slam_toolbox's ids are unique over all lasers), a negative one, a non-finite
    position or an unusable quaternion would misplace or lose a node silently: ValueError."""
    ids = np.asarray(ids, dtype=np.int64)
    unique, counts = np.unique(ids, return_counts=True)
    if np.any(counts > 1):
        raise ValueError(f'pose graph node ids {unique[counts > 1][:5].tolist()} appear more '
                         'than once')
    if np.any(ids < 0):
        raise ValueError('pose graph node ids must not be negative, got '
                         f'{ids[ids < 0][:5].tolist()}')
    yaw = se2.yaw_from_quaternion(*values[:, 3:].T)
    poses = np.column_stack([values[:, :2], yaw])
    bad = ~np.all(np.isfinite(poses), axis=1)
    if np.any(bad):
        raise ValueError(f'pose graph nodes {ids[bad][:5].tolist()} have non-finite positions or '
                         'unusable orientations')
    return ids, poses


def new_node_event_to_record(msg) -> NodeEvent:
    """The record of a slam_toolbox NewNodeEvent (its edge is not read).

    Parameters
    ----------
    msg: a slam_toolbox/msg/NewNodeEvent.

    Returns
    -------
    A NodeEvent: node id, stamp of its scan in seconds, pose (3,) x, y, yaw. Raises ValueError
    for a negative id or a non-finite pose.
    """
    pose = pose_to_numpy(msg.pose)
    if msg.new_node_id < 0 or not np.all(np.isfinite(pose)):
        raise ValueError(f'new node event {msg.new_node_id}: negative id or non-finite pose '
                         f'{pose.tolist()}')
    return NodeEvent(node_id=int(msg.new_node_id), stamp=stamp_to_seconds(msg.stamp), pose=pose)


class _CdrReader:
    """Reads CDR (little endian, XCDR1) fields in order; IndexError past the end."""

    _THREE_INT32 = struct.Struct('<3i')
    _FLOAT64_PAIR = struct.Struct('<2d')
    _STAMP = struct.Struct('<iI')

    def __init__(self, body: memoryview) -> None:
        self.body, self.offset = body, 0

    def _at(self, size: int, alignment: int) -> int:
        start = _align(self.offset, alignment)
        if start + size > len(self.body):
            raise IndexError('CDR message shorter than its fields')
        self.offset = start + size
        return start

    def stamp(self) -> tuple[int, int]:
        """builtin_interfaces/Time: (sec, nanosec)."""
        return self._STAMP.unpack_from(self.body, self._at(8, 4))

    def uint32(self) -> int:
        return int.from_bytes(self.body[self._at(4, 4):self.offset], 'little')

    def int32s(self) -> tuple[int, int, int]:
        return self._THREE_INT32.unpack_from(self.body, self._at(12, 4))

    def float64_pair(self) -> tuple[float, float]:
        return self._FLOAT64_PAIR.unpack_from(self.body, self._at(16, 8))

    def skip(self, size: int, alignment: int) -> None:
        if size:
            self._at(size, alignment)

    def string(self) -> str:
        length = self.uint32()
        start = self._at(length, 1)
        return bytes(self.body[start:start + max(length - 1, 0)]).decode('utf-8', 'replace')

    def sequence(self, element: int, alignment: int) -> None:
        """Skip a sequence of fixed-size elements."""
        self.skip(self.uint32() * element, alignment)


def graph_markers_from_cdr(data: bytes) -> GraphSnapshot | None:
    """The record of a serialized slam_toolbox graph_visualization MarkerArray, read from its
    CDR bytes (visualization_msgs/Marker of ROS 2 Jazzy) without building a message object per
    marker, which for a graph of thousands of vertices holds the interpreter for long.

    Parameters
    ----------
    data: the serialized message, 4-byte encapsulation header first.

    Returns
    -------
    A GraphSnapshot with the values of graph_markers_to_numpy, or None for a layout this does
    not read (big endian, XCDR2). Raises ValueError as graph_markers_to_numpy, and for a
    message shorter than its fields.
    """
    if len(data) < _ENCAPSULATION + 4 or bytes(data[:2]) != _CDR_LE:
        return None
    reader = _CdrReader(memoryview(data)[_ENCAPSULATION:])
    try:
        markers = [_marker_fields(reader) for _ in range(reader.uint32())]
    except IndexError as error:
        raise ValueError(f'graph markers: {error}') from None
    ids, positions, frame_id = _graph_vertices(markers)
    return GraphSnapshot(ids=ids, positions=positions, frame_id=frame_id)


def _marker_fields(reader: _CdrReader) -> tuple:
    """(namespace, id, type, action, x, y, frame id) of the next Marker; the rest skipped."""
    reader.skip(8, 4)  # header stamp
    frame_id = reader.string()
    namespace = reader.string()
    marker_id, marker_type, action = reader.int32s()
    x, y = reader.float64_pair()
    reader.skip(8 + 32 + 24, 8)  # position z, orientation, scale
    reader.skip(16 + 8 + 1, 4)  # color, lifetime, frame_locked
    reader.sequence(24, 8)  # points
    reader.sequence(16, 4)  # colors
    reader.string()  # texture_resource
    reader.skip(8, 4)  # texture: header stamp, frame id, format, data
    reader.string()
    reader.string()
    reader.sequence(1, 1)
    reader.sequence(8, 4)  # uv_coordinates
    reader.string()  # text
    reader.string()  # mesh_resource
    reader.string()  # mesh_file: filename, data
    reader.sequence(1, 1)
    reader.skip(1, 1)  # mesh_use_embedded_materials
    return namespace, marker_id, marker_type, action, x, y, frame_id


def pose_graph_from_cdr(data: bytes) -> PoseGraphNodes | None:
    """The record of a serialized slam_toolbox PoseGraph, its nodes read from the CDR bytes
    with numpy (the edges after them are not read): a message object per node and edge, all
    holding the interpreter, is slow for a graph of thousands.

    Parameters
    ----------
    data: the serialized message, 4-byte encapsulation header first.

    Returns
    -------
    A PoseGraphNodes with the values of pose_graph_to_numpy, the header stamp and frame id,
    or None for a layout this does not read (big endian, XCDR2). Raises ValueError as
    pose_graph_to_numpy, and for a message shorter than its node count says.
    """
    if len(data) < _ENCAPSULATION + 16 or bytes(data[:2]) != _CDR_LE:
        return None
    body = memoryview(data)[_ENCAPSULATION:]
    reader = _CdrReader(body)
    try:
        sec, nanosec = reader.stamp()
        frame_id = reader.string()
        count = reader.uint32()
    except IndexError as error:
        raise ValueError(f'pose graph: {error}') from None
    first = reader.offset  # 4-aligned: a node is int32 node_id, then Pose's 7 float64
    # the first node's values align to 8 from wherever it starts; every later node starts
    # 8-aligned right after the previous one's values, so the later ones are evenly spaced
    head = _align(first + 4, 8) - first
    node = np.dtype({'names': ['node_id', 'values'], 'formats': ['<i4', ('<f8', _POSE_VALUES)],
                     'offsets': [0, head], 'itemsize': head + 8 * _POSE_VALUES})
    rest = np.dtype({'names': ['node_id', 'values'], 'formats': ['<i4', ('<f8', _POSE_VALUES)],
                     'offsets': [0, 8], 'itemsize': 8 + 8 * _POSE_VALUES})
    if count and first + node.itemsize + (count - 1) * rest.itemsize > len(body):
        raise ValueError(f'pose graph: {count} nodes do not fit in {len(body)} bytes')
    entries = ([np.frombuffer(body, dtype=node, count=1, offset=first),
                np.frombuffer(body, dtype=rest, count=count - 1, offset=first + node.itemsize)]
               if count else [])
    ids = np.concatenate([entry['node_id'] for entry in entries]) if count else np.zeros(0)
    values = (np.concatenate([entry['values'] for entry in entries]) if count
              else np.zeros((0, _POSE_VALUES)))
    ids, poses = _graph_nodes(ids, values)
    return PoseGraphNodes(ids=ids, poses=poses, stamp=sec + nanosec * 1e-9, frame_id=frame_id)


# Message types whose records are read straight from their CDR bytes, by the node and by bag
# replay alike: type -> reader (None for a layout left to the deserializer).
CDR_RECORDS: dict[str, Callable[[bytes], Record | None]] = {
    PATH_TYPE: path_from_cdr, MARKER_ARRAY_TYPE: graph_markers_from_cdr,
    POSE_GRAPH_TYPE: pose_graph_from_cdr}


def record_from_cdr(msgtype: str, data: bytes, deserialize: Callable[[bytes, str], object],
                    max_range: float = math.inf,
                    reader: Callable[[bytes], Record | None] | None = None) -> Record:
    """The record of serialized message `data` of a type in CDR_RECORDS: read from its bytes,
    or, for a layout the reader leaves, `deserialize(data, msgtype)` and to_record.

    Parameters
    ----------
    msgtype: the message type, a key of CDR_RECORDS (KeyError otherwise).
    data: the serialized message, 4-byte encapsulation header first.
    deserialize: deserialize(data, msgtype) -> message object, for the layouts left over.
    max_range: passed to to_record (only scans use it).
    reader: the reader of the bytes instead of CDR_RECORDS[msgtype] (a stream's PathReader).

    Returns
    -------
    The core record. Raises ValueError for unusable content, as to_record.
    """
    record = (reader or CDR_RECORDS[msgtype])(data)
    return to_record(msgtype, deserialize(data, msgtype), max_range) if record is None else record


def to_record(msgtype: str, msg, max_range: float = math.inf) -> Record:
    """The core record of one message.

    Parameters
    ----------
    msgtype: the message type, one of SCAN_TYPE, POSE_TYPES, CONSTRAINTS_TYPE,
        MARKER_ARRAY_TYPE, SLAM_TOOLBOX_GRAPH_TYPES.
    msg: the message object (rclpy's or rosbags'), read by attribute.
    max_range: usable range of scans in metres, as scan_to_numpy.

    Returns
    -------
    A Scan, KeyframeEstimate (Path), Constraints, GraphSnapshot (markers), NodeEvent,
    PoseGraphNodes, LoopClosure or PoseSample (single poses). Raises ValueError for unusable
    content and for a type outside the list.
    """
    if msgtype == SCAN_TYPE:
        stamp, ranges, model = scan_to_numpy(msg, max_range)
        return Scan(stamp=stamp, ranges=ranges, model=model, frame_id=msg.header.frame_id)
    if msgtype == PATH_TYPE:
        stamps, poses = path_to_numpy(msg)
        return KeyframeEstimate(stamps=stamps, poses=poses, frame_id=msg.header.frame_id,
                                stamp=stamp_to_seconds(msg.header.stamp))
    if msgtype == CONSTRAINTS_TYPE:
        return Constraints(rows=constraints_to_numpy(msg))
    if msgtype == MARKER_ARRAY_TYPE:
        ids, positions, frame_id = graph_markers_to_numpy(msg)
        return GraphSnapshot(ids=ids, positions=positions, frame_id=frame_id)
    if msgtype == NEW_NODE_EVENT_TYPE:
        return new_node_event_to_record(msg)
    if msgtype == POSE_GRAPH_TYPE:
        ids, poses = pose_graph_to_numpy(msg)
        return PoseGraphNodes(ids=ids, poses=poses, stamp=stamp_to_seconds(msg.header.stamp),
                              frame_id=msg.header.frame_id)
    if msgtype == LOOP_CLOSURE_EVENT_TYPE:
        return LoopClosure(stamp=stamp_to_seconds(msg.stamp))
    if msgtype in SINGLE_POSE_TYPES:
        pose = msg.pose if msgtype == POSE_STAMPED_TYPE else msg.pose.pose
        stamp = stamp_to_seconds(msg.header.stamp)
        check_fields(f'pose stamped {stamp!r} s', (('header stamp', stamp, STAMP),))
        return PoseSample(stamp=stamp, pose=pose_to_numpy(pose),
                          frame_id=msg.header.frame_id,
                          child_frame_id=getattr(msg, 'child_frame_id', ''))
    raise ValueError(f'no input record for messages of type {msgtype}')


# -- numpy -> messages --------------------------------------------------------------------------

def time_message(types: MessageTypes, seconds: float):
    """Float seconds as a builtin_interfaces/Time (nanoseconds rounded).

    Parameters
    ----------
    types: type name -> message class (see the module docstring).
    seconds: the time in seconds.

    Returns
    -------
    The Time message; nanosec in [0, 1e9), sec floored (negative for times before 0).
    """
    total = round(seconds * 1e9)
    return types('builtin_interfaces/msg/Time')(sec=int(total // 1_000_000_000),
                                                nanosec=int(total % 1_000_000_000))


def header_message(types: MessageTypes, stamp: float, frame_id: str):
    """A std_msgs/Header.

    Parameters
    ----------
    types: type name -> message class.
    stamp: header stamp in seconds.
    frame_id: the header's frame.

    Returns
    -------
    The Header message.
    """
    return types('std_msgs/msg/Header')(stamp=time_message(types, stamp), frame_id=frame_id)


def scan_message(types: MessageTypes, stamp: float, ranges: np.ndarray, model: SensorModel,
                 frame_id: str = 'laser'):
    """A LaserScan whose beam k has bearing angle_min + k * angle_increment.

    Parameters
    ----------
    types: type name -> message class.
    stamp: header stamp in seconds.
    ranges: (K,) ranges in metres, written as float32.
    model: beam geometry; its range_min and max_range become the scan's range limits.
    frame_id: the laser frame.

    Returns
    -------
    The LaserScan; angle_max is the bearing of the last beam, timing fields are zero and
    intensities empty.
    """
    ranges = np.asarray(ranges, dtype=np.float32)
    return types(SCAN_TYPE)(
        header=header_message(types, stamp, frame_id), angle_min=float(model.angle_min),
        angle_max=float(model.angle_min + (ranges.size - 1) * model.angle_increment),
        angle_increment=float(model.angle_increment), time_increment=0.0, scan_time=0.0,
        range_min=float(model.range_min), range_max=float(model.max_range), ranges=ranges,
        intensities=np.zeros(0, dtype=np.float32))


def geometry_pose(types: MessageTypes, pose: np.ndarray):
    """A geometry_msgs/Pose of a planar pose.

    Parameters
    ----------
    types: type name -> message class.
    pose: (3,) x, y, yaw (radians).

    Returns
    -------
    The Pose, with z = 0 and a rotation about z only.
    """
    x, y, yaw = (float(v) for v in pose)
    z, w = se2.quaternion_from_yaw(yaw)
    return types('geometry_msgs/msg/Pose')(
        position=types('geometry_msgs/msg/Point')(x=x, y=y, z=0.0),
        orientation=types('geometry_msgs/msg/Quaternion')(x=0.0, y=0.0, z=z, w=w))


def path_message(types: MessageTypes, stamps: np.ndarray, poses: np.ndarray, frame_id: str,
                 stamp: float | None = None):
    """A Path whose PoseStamped entries are stamped with their scans' stamps.

    Parameters
    ----------
    types: type name -> message class.
    stamps: (M,) seconds, the stamp of the scan of each keyframe.
    poses: (M, 3) x, y, yaw.
    frame_id: frame of the header and of every entry.
    stamp: header stamp in seconds; None for the last entry's (0 for an empty Path).

    Returns
    -------
    The Path message.
    """
    if stamp is None:
        stamp = float(stamps[-1]) if len(stamps) else 0.0
    pose_stamped = types(POSE_STAMPED_TYPE)
    entries = [pose_stamped(header=header_message(types, seconds, frame_id),
                            pose=geometry_pose(types, pose))
               for seconds, pose in zip(np.asarray(stamps).tolist(), np.asarray(poses))]
    return types(PATH_TYPE)(header=header_message(types, stamp, frame_id), poses=entries)


def single_pose_message(types: MessageTypes, msgtype: str, stamp: float, pose: np.ndarray,
                        frame_id: str = 'odom', child_frame_id: str = 'base_link'):
    """An Odometry, PoseStamped or PoseWithCovarianceStamped of one pose (zero covariance,
    zero twist).

    Parameters
    ----------
    types: type name -> message class.
    msgtype: one of SINGLE_POSE_TYPES.
    stamp: header stamp in seconds.
    pose: (3,) x, y, yaw.
    frame_id: the header's frame (the frame the pose is in).
    child_frame_id: the moving frame; only Odometry carries it.

    Returns
    -------
    The message. Raises ValueError for a `msgtype` outside SINGLE_POSE_TYPES.
    """
    header = header_message(types, stamp, frame_id)
    geometry = geometry_pose(types, pose)
    if msgtype == POSE_STAMPED_TYPE:
        return types(msgtype)(header=header, pose=geometry)
    with_covariance = types('geometry_msgs/msg/PoseWithCovariance')(
        pose=geometry, covariance=np.zeros(36))
    if msgtype == POSE_COVARIANCE_TYPE:
        return types(msgtype)(header=header, pose=with_covariance)
    if msgtype != ODOMETRY_TYPE:
        raise ValueError(f'not a single-pose message type: {msgtype}')
    vector = types('geometry_msgs/msg/Vector3')
    twist = types('geometry_msgs/msg/TwistWithCovariance')(
        twist=types('geometry_msgs/msg/Twist')(linear=vector(x=0.0, y=0.0, z=0.0),
                                               angular=vector(x=0.0, y=0.0, z=0.0)),
        covariance=np.zeros(36))
    return types(msgtype)(header=header, child_frame_id=child_frame_id, pose=with_covariance,
                          twist=twist)


def constraints_message(types: MessageTypes, rows: np.ndarray):
    """Edge rows as a Float64MultiArray with the layout labelled ('edges', 'fields').

    Parameters
    ----------
    types: type name -> message class.
    rows: (E, 11) rows laid out as CONSTRAINT_FIELDS (any array of E * 11 values is reshaped).

    Returns
    -------
    The Float64MultiArray, data_offset 0, data row-major.
    """
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, len(CONSTRAINT_FIELDS))
    dimension = types('std_msgs/msg/MultiArrayDimension')
    layout = types('std_msgs/msg/MultiArrayLayout')(
        dim=[dimension(label='edges', size=rows.shape[0], stride=rows.size),
             dimension(label='fields', size=rows.shape[1], stride=rows.shape[1])],
        data_offset=0)
    return types(CONSTRAINTS_TYPE)(layout=layout, data=rows.ravel())


def _marker(types: MessageTypes, header, namespace: str, marker_id: int, marker_type: int,
            action: int, position: tuple[float, float] = (0.0, 0.0), points=()):
    """A Marker with every field filled (rosbags classes have no defaults)."""
    point = types('geometry_msgs/msg/Point')
    return types('visualization_msgs/msg/Marker')(
        header=header, ns=namespace, id=marker_id, type=marker_type, action=action,
        pose=types('geometry_msgs/msg/Pose')(
            position=point(x=float(position[0]), y=float(position[1]), z=0.0),
            orientation=types('geometry_msgs/msg/Quaternion')(x=0.0, y=0.0, z=0.0, w=1.0)),
        scale=types('geometry_msgs/msg/Vector3')(x=0.1, y=0.1, z=0.1),
        color=types('std_msgs/msg/ColorRGBA')(r=1.0, g=0.0, b=0.0, a=1.0),
        lifetime=types('builtin_interfaces/msg/Duration')(sec=0, nanosec=0),
        frame_locked=False, points=[point(x=float(x), y=float(y), z=0.0) for x, y in points],
        colors=[], texture_resource='',
        texture=types('sensor_msgs/msg/CompressedImage')(
            header=header, format='', data=np.zeros(0, dtype=np.uint8)),
        uv_coordinates=[], text='', mesh_resource='',
        mesh_file=types('visualization_msgs/msg/MeshFile')(
            filename='', data=np.zeros(0, dtype=np.uint8)),
        mesh_use_embedded_materials=False)


def graph_markers_message(types: MessageTypes, stamp: float, ids: np.ndarray,
                          positions: np.ndarray, frame_id: str = 'map'):
    """A MarkerArray as slam_toolbox's publishGraph builds it: DELETEALL, one SPHERE per vertex
    (namespace `slam_toolbox`, id = vertex id, identity orientation), then the edges as a
    LINE_LIST in `slam_toolbox_edges` (here between consecutive vertices).

    Parameters
    ----------
    types: type name -> message class.
    stamp: header stamp of every marker, seconds.
    ids: (V,) vertex ids.
    positions: (V, 2) x, y of the vertices.
    frame_id: the markers' frame.

    Returns
    -------
    The MarkerArray (V + 2 markers).
    """
    header = header_message(types, stamp, frame_id)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    markers = [_marker(types, header, '', 0, MARKER_SPHERE, MARKER_DELETEALL)]
    markers += [_marker(types, header, SLAM_TOOLBOX_NAMESPACE, int(vertex), MARKER_SPHERE,
                        MARKER_ADD, tuple(position))
                for vertex, position in zip(np.asarray(ids).tolist(), positions)]
    edges = [tuple(point) for pair in zip(positions[:-1], positions[1:]) for point in pair]
    markers.append(_marker(types, header, 'slam_toolbox_edges', 0, MARKER_LINE_LIST, MARKER_ADD,
                           points=edges))
    return types(MARKER_ARRAY_TYPE)(markers=markers)


def _graph_edge(types: MessageTypes, source: int, target: int, relative: np.ndarray,
                covariance: np.ndarray):
    return types('slam_toolbox/msg/GraphEdge')(
        source_id=int(source), target_id=int(target), relative_pose=geometry_pose(types, relative),
        covariance=np.asarray(covariance, dtype=np.float64).reshape(9))


def new_node_event_message(types: MessageTypes, node_id: int, stamp: float, pose: np.ndarray,
                           step: np.ndarray | None = None,
                           covariance: np.ndarray | None = None):
    """A NewNodeEvent as slam_toolbox's publishNewNodeEvent fills it: the node, the stamp of its
    scan, its pose, and the edge from node `node_id - 1`.

    Parameters
    ----------
    types: type name -> message class.
    node_id: the new node's id; for 0 (the first node, whose event has no edge) the edge
        runs from 0 to 0.
    stamp: stamp of the scan the node was built from, seconds.
    pose: (3,) x, y, yaw of the node.
    step: (3,) relative pose of the edge; None for zeros.
    covariance: (3, 3) or (9,) covariance of the edge; None for zeros.

    Returns
    -------
    The NewNodeEvent message.
    """
    step = np.zeros(3) if step is None else step
    covariance = np.zeros(9) if covariance is None else covariance
    source = node_id - 1 if node_id > 0 else 0
    return types(NEW_NODE_EVENT_TYPE)(
        new_node_id=int(node_id), stamp=time_message(types, stamp),
        pose=geometry_pose(types, pose),
        edge=_graph_edge(types, source, node_id if node_id > 0 else 0, step, covariance))


def pose_graph_message(types: MessageTypes, stamp: float, ids: np.ndarray, poses: np.ndarray,
                       frame_id: str = 'map', edges: np.ndarray | None = None):
    """A slam_toolbox PoseGraph.

    Parameters
    ----------
    types: type name -> message class.
    stamp: header stamp in seconds (slam_toolbox: its clock when it built the message).
    ids: (V,) node ids.
    poses: (V, 3) x, y, yaw of the nodes.
    frame_id: the header's frame.
    edges: (E, 2) (source, target) node id pairs, each from `ids` (KeyError otherwise); each
        gets the relative pose of its nodes and an identity covariance. None for no edges.

    Returns
    -------
    The PoseGraph message.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    node = types('slam_toolbox/msg/GraphNode')
    nodes = [node(node_id=int(node_id), pose=geometry_pose(types, pose))
             for node_id, pose in zip(np.asarray(ids).tolist(), poses)]
    index = {int(node_id): row for row, node_id in enumerate(np.asarray(ids).tolist())}
    pairs = np.zeros((0, 2), dtype=np.int64) if edges is None else np.asarray(edges)
    graph_edges = [_graph_edge(types, source, target,
                               se2.relative(poses[index[int(source)]], poses[index[int(target)]]),
                               np.eye(3)) for source, target in pairs.tolist()]
    return types(POSE_GRAPH_TYPE)(header=header_message(types, stamp, frame_id), nodes=nodes,
                                  edges=graph_edges)


def loop_closure_event_message(types: MessageTypes, stamp: float):
    """A LoopClosureEvent (only a stamp: slam_toolbox's clock at the end of the closure).

    Parameters
    ----------
    types: type name -> message class.
    stamp: the stamp in seconds.

    Returns
    -------
    The LoopClosureEvent message.
    """
    return types(LOOP_CLOSURE_EVENT_TYPE)(stamp=time_message(types, stamp))


def slam_toolbox_definitions() -> dict[str, str]:
    """slam_toolbox's pose-graph message definitions shipped with this package (io/msg/).

    Returns
    -------
    Type name ('slam_toolbox/msg/PoseGraph', ...) -> .msg text, for GraphNode, GraphEdge,
    PoseGraph, NewNodeEvent and LoopClosureEvent.
    """
    from importlib.resources import files
    folder = files('map_consistency_ros.io').joinpath('msg', 'slam_toolbox')
    return {f'slam_toolbox/msg/{name}': folder.joinpath(f'{name}.msg').read_text()
            for name in ('GraphNode', 'GraphEdge', 'PoseGraph', 'NewNodeEvent',
                         'LoopClosureEvent')}


def register_slam_toolbox_types(typestore) -> None:
    """Register slam_toolbox's pose-graph messages in a rosbags typestore (bags are read and
    written without slam_toolbox installed).

    Parameters
    ----------
    typestore: a rosbags Typestore, changed in place.
    """
    from rosbags.typesys import get_types_from_msg
    types = {}
    for name, text in slam_toolbox_definitions().items():
        types.update(get_types_from_msg(text, name))
    typestore.register(types)
