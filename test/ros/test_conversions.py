"""io/messages.py on rclpy's messages: round trips on real Intel data and every refusal."""
from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import Point
from nav_msgs.msg import Path
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import LaserScan
from std_msgs.msg import ColorRGBA, Float64MultiArray, Header, MultiArrayDimension
from visualization_msgs.msg import MarkerArray, UVCoordinate

from map_consistency_ros.core.geometry import SensorModel
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io import messages
from map_consistency_ros.ros.conversions import message_class


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log, sensor_model(log)


def test_stamps_round_trip_to_the_nanosecond():
    for seconds in (0.0, 976052857.337530017, 1.999999999, 32.9068):
        stamp = messages.time_message(message_class, seconds)
        assert 0 <= stamp.nanosec < 1_000_000_000
        assert messages.stamp_to_seconds(stamp) == pytest.approx(seconds, abs=1e-6)
    assert messages.time_message(message_class, 1.9999999999).sec == 2


def test_scan_round_trip_keeps_ranges_and_geometry(intel):
    log, model = intel
    ranges = log.ranges[3].copy()
    ranges[[0, 5]] = np.nan, np.inf  # invalid beams pass through untouched
    msg = messages.scan_message(message_class, log.timestamps[3], ranges, model)
    assert msg.angle_max == pytest.approx(model.angle_min + 179 * model.angle_increment)
    stamp, back, back_model = messages.scan_to_numpy(msg, max_range=6.0)
    assert stamp == pytest.approx(log.timestamps[3], abs=1e-6)
    np.testing.assert_allclose(back, ranges.astype(np.float32))
    assert back_model.angle_min == pytest.approx(model.angle_min)
    assert back_model.angle_increment == pytest.approx(model.angle_increment)
    assert back_model.max_range == pytest.approx(6.0)  # the smaller of the cap and range_max


def _scan(beams=180, angle_min=-math.pi / 2, increment=math.pi / 179, angle_max=None,
          range_max=30.0, sec=0):
    msg = LaserScan()
    msg.header.stamp.sec = sec
    msg.angle_min, msg.angle_increment = angle_min, increment
    msg.angle_max = angle_min + (beams - 1) * increment if angle_max is None else angle_max
    msg.range_min, msg.range_max = 0.1, range_max
    msg.ranges = [1.0] * beams
    return msg


def test_scan_angle_conventions_of_drivers_are_accepted():
    exclusive = _scan(beams=360, angle_min=-math.pi, increment=2 * math.pi / 360,
                      angle_max=math.pi - 2 * math.pi / 360)
    assert messages.scan_to_numpy(exclusive, 8.0)[2].is_full_circle(360)
    one_short = _scan(beams=181, angle_max=math.pi / 2)  # angle_max one beam short
    assert messages.scan_to_numpy(one_short, 8.0)[1].size == 181
    nan_limits = _scan()
    nan_limits.range_min, nan_limits.range_max = float('nan'), float('inf')
    model = messages.scan_to_numpy(nan_limits, 8.0)[2]
    assert (model.range_min, model.max_range) == (0.0, 8.0)


@pytest.mark.parametrize('msg, message', [
    (_scan(beams=0), 'at least 2'),
    (_scan(beams=1), 'at least 2'),
    (_scan(increment=float('nan')), 'angle_increment nan is not finite'),
    (_scan(increment=-0.01), 'unusable'),
    (_scan(increment=0.0), 'unusable'),
    (_scan(angle_max=float('inf')), 'angle_max inf is not finite'),
    (_scan(angle_min=-1e3), r'angle_min -1000.0 is beyond 12.56\d* rad'),
    (_scan(range_max=float('nan')), 'range_max nan is not finite'),
    (_scan(range_max=1e300), r'range_max 1e\+300 is beyond 100000 m'),
    (_scan(range_max=-float('inf')), 'range_max -inf is not finite'),
    (_scan(sec=-5), r'scan stamped -5.0 s: header stamp -5.0 is negative'),
    (_scan(beams=90, angle_max=math.pi / 2), 'imply 180.0 beams but it has 90'),
    (_scan(beams=400, increment=0.02), 'overlap past 2 pi'),
])
def test_bad_scans_are_refused(msg, message):
    with pytest.raises(ValueError, match=message):
        messages.scan_to_numpy(msg, 8.0)


def test_path_round_trip_on_real_poses(intel):
    log, _ = intel
    stamps, poses = log.timestamps[:50], log.laser_poses[:50]
    msg = messages.path_message(message_class, stamps, poses, 'map')
    assert msg.header.frame_id == 'map' and len(msg.poses) == 50
    assert messages.stamp_to_seconds(msg.header.stamp) == pytest.approx(stamps[-1], abs=1e-6)
    back_stamps, back_poses = messages.path_to_numpy(msg)
    np.testing.assert_allclose(back_stamps, stamps, atol=1e-6)
    np.testing.assert_allclose(back_poses[:, :2], poses[:, :2])
    heading_error = np.angle(np.exp(1j * (back_poses[:, 2] - poses[:, 2])))
    np.testing.assert_allclose(heading_error, 0.0, atol=1e-12)
    empty = messages.path_to_numpy(Path())
    assert empty[0].shape == (0,) and empty[1].shape == (0, 3)


@pytest.mark.parametrize('count', [0, 1, 2, 50])
@pytest.mark.parametrize('frame, entry_frame', [('map', 'map'), ('', 'a'), ('odom', ''),
                                                ('abcdefgh', 'base_link'), ('m', 'abcd')])
def test_path_read_from_its_bytes_as_rclpy_deserializes_it(intel, count, frame, entry_frame):
    # every alignment of the frame ids: the readers must agree bit for bit
    log, _ = intel
    msg = messages.path_message(message_class, log.timestamps[:count], log.laser_poses[:count],
                                frame, stamp=log.timestamps[0])
    for entry in msg.poses:
        entry.header.frame_id = entry_frame
    if count > 1:
        msg.poses[1].pose.orientation.z = float('inf')  # no heading: NaN yaw in both
        msg.poses[-1].pose.position.x = float('nan')
    data = serialize_message(msg)
    fast = messages.path_from_cdr(data)
    slow = messages.to_record(messages.PATH_TYPE, deserialize_message(data, Path))
    assert fast.frame_id == slow.frame_id == frame
    # the header's stamp names the estimate (core/live/_feed.py): both readers, to the nanosecond
    assert fast.stamp == slow.stamp == pytest.approx(log.timestamps[0], abs=1e-9)
    np.testing.assert_array_equal(fast.stamps, slow.stamps)
    np.testing.assert_array_equal(fast.poses, slow.poses)  # NaN where NaN


def test_path_layouts_the_byte_reader_leaves_to_the_deserializer(intel):
    log, _ = intel
    msg = messages.path_message(message_class, log.timestamps[:5], log.laser_poses[:5], 'map')
    data = serialize_message(msg)
    assert messages.path_from_cdr(data) is not None
    assert messages.path_from_cdr(data[:-8]) is None  # shorter than its count says
    assert messages.path_from_cdr(b'\x01\x00' + data[2:]) is None  # big endian
    msg.poses[3].header.frame_id = 'odom'  # entries no longer evenly spaced
    assert messages.path_from_cdr(serialize_message(msg)) is None


def test_a_path_reader_decodes_only_what_a_path_adds_and_reads_as_path_from_cdr(intel,
                                                                             monkeypatch):
    log, _ = intel
    stamps, poses = log.timestamps[:60], log.laser_poses[:60]

    def path(count, frame='map', entry_frame='base_link', moved=None):
        msg = messages.path_message(message_class, stamps[:count], poses[:count], frame,
                                    stamp=stamps[count - 1])
        for entry in msg.poses:
            entry.header.frame_id = entry_frame
        if moved is not None:
            msg.poses[moved].pose.position.x += 0.25  # an optimisation moved one pose
        return serialize_message(msg)

    decoded = []
    entries = messages._path_entries
    monkeypatch.setattr(messages, '_path_entries', lambda body, layout, start: (
        decoded.append(layout.count - start) or entries(body, layout, start)))
    reader = messages.PathReader()
    stream = [path(10), path(25), path(25, frame='odo'), path(25, frame='odom'),
              path(40, moved=3), path(41, moved=3), path(41, entry_frame='laser'),
              path(50, entry_frame='laser'), path(5, entry_frame='laser')]
    for data in stream:
        fast, whole = reader(data), messages.PathReader()(data)
        assert fast.frame_id == whole.frame_id and fast.stamp == whole.stamp
        np.testing.assert_array_equal(fast.stamps, whole.stamps)
        np.testing.assert_array_equal(fast.poses, whole.poses)
    # each reader call decodes, then the stateless one decodes everything
    by_reader = decoded[::2]
    # 15 appended; a new header frame id of the same length keeps the entries; one of another
    # length moves them, and a moved pose, a new entry frame id and a shorter Path change
    # them: those decode everything
    assert by_reader == [10, 15, 0, 25, 40, 1, 41, 9, 5]


def test_a_path_reader_leaves_a_broken_path_to_the_deserializer_and_loses_nothing(intel):
    log, _ = intel
    stamps, poses = log.timestamps[:30], log.laser_poses[:30]

    def path(count, odd_entry=None):
        msg = messages.path_message(message_class, stamps[:count], poses[:count], 'map')
        if odd_entry is not None:  # entries no longer evenly spaced
            msg.poses[odd_entry].header.frame_id = 'odom'
        return serialize_message(msg)

    reader = messages.PathReader()
    assert len(reader(path(10)).stamps) == 10
    assert reader(path(20)[:-8]) is None  # shorter than its count says
    assert reader(path(20, odd_entry=15)) is None  # an added entry of another layout
    assert reader(b'\x01\x00' + path(20)[2:]) is None  # big endian
    for count in (20, 25):  # the Paths after them read whole and right
        data = path(count)
        fast, whole = reader(data), messages.path_from_cdr(data)
        np.testing.assert_array_equal(fast.stamps, whole.stamps)
        np.testing.assert_array_equal(fast.poses, whole.poses)
        slow = messages.to_record(messages.PATH_TYPE, deserialize_message(data, Path))
        np.testing.assert_array_equal(fast.poses, slow.poses)


@pytest.mark.parametrize('vertices', [0, 1, 40])
def test_graph_markers_read_from_their_bytes_as_rclpy_deserializes_them(intel, vertices):
    log, _ = intel
    msg = messages.graph_markers_message(message_class, 1.0, np.arange(vertices) * 3 + 1,
                                         log.laser_poses[:vertices, :2], frame_id='map')
    # every variable-size field of a Marker in use on some markers: each shifts the rest
    for size, marker in enumerate(msg.markers[:4]):
        marker.text, marker.texture_resource, marker.mesh_resource = 'x' * size, 'ab'[:size], 'm'
        marker.colors = [ColorRGBA(r=1.0)] * size
        marker.points = marker.points or [Point(x=2.0)] * size
        marker.texture.format, marker.texture.data = 'png'[:size], bytes(range(size))
        marker.mesh_file.filename, marker.mesh_file.data = 'f' * (size + 1), bytes(3 * size)
        marker.uv_coordinates = [UVCoordinate(u=0.5)] * size
        marker.texture.header = Header(frame_id='camera'[:size])  # the builder shares one
    data = serialize_message(msg)
    fast = messages.graph_markers_from_cdr(data)
    slow = messages.to_record(messages.MARKER_ARRAY_TYPE, deserialize_message(data, MarkerArray))
    np.testing.assert_array_equal(fast.ids, slow.ids)
    np.testing.assert_array_equal(fast.positions, slow.positions)
    assert fast.frame_id == slow.frame_id == ('map' if vertices else '')
    with pytest.raises(ValueError, match='shorter than its fields'):
        messages.graph_markers_from_cdr(data[:-20])
    assert messages.graph_markers_from_cdr(b'\x01\x00' + data[2:]) is None  # big endian


def test_yaw_of_an_unnormalised_tilted_quaternion():
    # 2 x (rotation of 0.7 rad about z): the scale must not matter
    assert se2.yaw_from_quaternion(0.0, 0.0, 2 * math.sin(0.35),
                                           2 * math.cos(0.35)) == pytest.approx(0.7)


@pytest.mark.parametrize('z, w', [(0.0, 0.0), (math.inf, 1.0), (math.nan, 1.0)])
def test_unusable_quaternions_give_no_heading(intel, z, w):
    log, _ = intel
    msg = messages.path_message(message_class, log.timestamps[:3], log.laser_poses[:3], 'map')
    msg.poses[2].pose.orientation.z, msg.poses[2].pose.orientation.w = z, w
    _, poses = messages.path_to_numpy(msg)
    assert np.isnan(poses[2, 2]) and np.isfinite(poses[:2]).all()  # the monitor skips it


def test_constraints_round_trip_and_layouts():
    rows = np.arange(33, dtype=np.float64).reshape(3, 11)
    msg = messages.constraints_message(message_class, rows)
    assert [d.label for d in msg.layout.dim] == ['edges', 'fields']
    np.testing.assert_array_equal(messages.constraints_to_numpy(msg), rows)
    bare = Float64MultiArray(data=rows.ravel().tolist())
    np.testing.assert_array_equal(messages.constraints_to_numpy(bare), rows)
    offset = messages.constraints_message(message_class, rows[:2])
    offset.layout.data_offset = 11
    offset.data = rows.ravel().tolist()
    np.testing.assert_array_equal(messages.constraints_to_numpy(offset), rows[1:])


def _dims(*sizes):
    return [MultiArrayDimension(label=str(i), size=s) for i, s in enumerate(sizes)]


@pytest.mark.parametrize('dims, length, message', [
    ((), 12, 'not a multiple of 11'),
    ((2, 10), 20, r'layout must be \(edges, 11\), got \[2, 10\]'),
    ((2, 11, 1), 22, 'layout must be'),
    ((3, 11), 22, 'says 3 x 11 values'),
])
def test_malformed_constraints_are_refused(dims, length, message):
    msg = Float64MultiArray(data=[0.0] * length)
    msg.layout.dim = _dims(*dims)
    with pytest.raises(ValueError, match=message):
        messages.constraints_to_numpy(msg)


def test_sensor_model_fields_survive_a_scan_message():
    model = SensorModel(angle_min=-2.0, angle_increment=0.01, max_range=5.6, range_min=0.02)
    msg = messages.scan_message(message_class, 1.0, np.ones(400), model)
    back = messages.scan_to_numpy(msg, 100.0)[2]
    assert back.range_min == pytest.approx(0.02)
    assert back.max_range == pytest.approx(5.6)


def _graph(ids, positions):
    return messages.graph_markers_message(message_class, 12.5, np.asarray(ids),
                                          np.asarray(positions, dtype=np.float64))


def test_graph_markers_round_trip_on_real_positions(slam_toolbox_stream):
    _, ids, positions = slam_toolbox_stream.snapshots[-1]
    msg = _graph(ids, positions)
    # as slam_toolbox's publishGraph: DELETEALL, the vertices, then the edges elsewhere
    assert msg.markers[0].action == messages.MARKER_DELETEALL
    assert {m.ns for m in msg.markers[1:]} == {'slam_toolbox', 'slam_toolbox_edges'}
    record = messages.to_record(messages.MARKER_ARRAY_TYPE, msg)
    np.testing.assert_array_equal(record.ids, ids)
    np.testing.assert_allclose(record.positions, positions, atol=1e-12)
    assert record.frame_id == 'map'


def test_graph_markers_honour_deleteall_and_delete():
    msg = _graph([0, 1, 2], [[0.0, 0.0], [1.0, 0.0], [2.0, 1.0]])
    stale = _graph([7, 8], [[5.0, 5.0], [6.0, 5.0]])
    # vertices before a DELETEALL are gone; a DELETE removes its vertex
    msg.markers = stale.markers[1:3] + msg.markers
    deleted = _graph([1], [[0.0, 0.0]]).markers[1]
    deleted.action = messages.MARKER_DELETE
    msg.markers.append(deleted)
    ids, positions, _ = messages.graph_markers_to_numpy(msg)
    np.testing.assert_array_equal(ids, [0, 2])
    np.testing.assert_allclose(positions, [[0.0, 0.0], [2.0, 1.0]])
    empty = _graph([], np.zeros((0, 2)))
    ids, positions, _ = messages.graph_markers_to_numpy(empty)
    assert ids.shape == (0,) and positions.shape == (0, 2)


def _broken(change):
    msg = _graph([0, 1, 2], [[0.0, 0.0], [1.0, 0.0], [2.0, 1.0]])
    change(msg)
    return msg


@pytest.mark.parametrize('change, message', [
    (lambda m: m.markers.pop(0), 'no DELETEALL'),
    (lambda m: setattr(m.markers[2].pose.position, 'x', math.nan), 'vertex 1 has a non-finite'),
    (lambda m: setattr(m.markers[3], 'id', 0), r'vertex ids \[0\] appear more than once'),
    (lambda m: setattr(m.markers[1], 'type', messages.MARKER_LINE_LIST), 'a vertex is an added '
                                                                         'SPHERE'),
])
def test_bad_graph_markers_are_refused(change, message):
    with pytest.raises(ValueError, match=message):
        messages.to_record(messages.MARKER_ARRAY_TYPE, _broken(change))


def test_a_pose_stamped_before_the_epoch_is_refused():
    msg = messages.single_pose_message(message_class, messages.POSE_STAMPED_TYPE, 1.0,
                                       np.zeros(3))
    msg.header.stamp.sec = -3
    with pytest.raises(ValueError, match='pose stamped -3.0 s: header stamp -3.0 is negative'):
        messages.to_record(messages.POSE_STAMPED_TYPE, msg)
