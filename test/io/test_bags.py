"""Bag reading and writing: real ROS 1 bags, rosbag2 mcap / sqlite3 round trips, bad bags."""
import itertools
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from map_consistency_ros.core.geometry import SensorModel, se2
from map_consistency_ros.core.live import (Constraints, GraphSnapshot, KeyframeEstimate,
                                           MonitorFeed, PoseSample, Scan)
from map_consistency_ros.io import bags, messages
from map_consistency_ros.io.bags import BagReader, BagTopics, BagWriter
from map_consistency_ros.io.errors import InputError

MODEL = SensorModel(angle_min=-math.pi / 2, angle_increment=math.pi / 179, max_range=81.83)


@pytest.fixture(scope='module')
def recorded():
    """Ten scans, their growing trajectory and edge rows, as a writer would get them."""
    rng = np.random.default_rng(7)
    stamps = 100.0 + np.cumsum(rng.uniform(0.1, 0.3, 10))
    ranges = rng.uniform(0.5, 20.0, (10, 180)).astype(np.float32)
    ranges[:, :3] = [np.inf, np.nan, 81.83]
    poses = np.column_stack([rng.normal(size=(10, 2)), rng.uniform(-math.pi, math.pi, 10)])
    rows = np.column_stack([stamps[:-1], stamps[1:], rng.normal(size=(9, 3)),
                            np.tile([100.0, 0.0, 0.0, 100.0, 0.0, 400.0], (9, 1))])
    return stamps, ranges, poses, rows


def write_bag(path, recorded, storage='mcap', compress=False):
    stamps, ranges, poses, rows = recorded
    with BagWriter(path, storage=storage, compress=compress) as writer:
        for index, stamp in enumerate(stamps):
            writer.write_scan(stamp, stamp, ranges[index], MODEL)
            writer.write_trajectory(stamp + 1e-6, stamps[:index + 1], poses[:index + 1])
        writer.write_constraints(stamps[-1] + 1e-3, rows)
    return path


@pytest.mark.parametrize('storage, compress', [('mcap', False), ('mcap', True),
                                               ('sqlite3', False)])
def test_rosbag2_round_trip(tmp_path, recorded, storage, compress):
    stamps, ranges, poses, rows = recorded
    path = write_bag(tmp_path / 'bag', recorded, storage, compress)
    with BagReader([path]) as bag:
        assert bag.pose_topic == '/trajectory' and bag.pose_type == messages.PATH_TYPE
        assert bag.has_constraints and not bag.is_ros1
        assert bag.message_count('/scan') == 10
        records = [record for _, record in bag.records()]
    scans = [record for record in records if isinstance(record, Scan)]
    paths = [record for record in records if isinstance(record, KeyframeEstimate)]
    edges = [record for record in records if isinstance(record, Constraints)]
    assert len(scans) == len(paths) == 10 and len(edges) == 1
    for index, scan in enumerate(scans):
        np.testing.assert_array_equal(scan.ranges, ranges[index])
        assert scan.stamp == pytest.approx(stamps[index], abs=1e-9)
        assert scan.frame_id == 'laser'
        # float32 fields of LaserScan keep the geometry to single precision.
        assert scan.model.angle_min == pytest.approx(MODEL.angle_min, rel=1e-7)
        assert scan.model.angle_increment == pytest.approx(MODEL.angle_increment, rel=1e-7)
        assert scan.model.max_range == pytest.approx(81.83, rel=1e-7)
    for index, path_record in enumerate(paths):
        np.testing.assert_allclose(path_record.stamps, stamps[:index + 1], atol=1e-9, rtol=0)
        np.testing.assert_allclose(path_record.poses, poses[:index + 1], atol=1e-12)
    np.testing.assert_array_equal(edges[0].rows, rows)


def test_yaw_agrees_with_scipy():
    angles = np.random.default_rng(1).uniform(-3, 3, (50, 3))
    rotations = Rotation.from_euler('ZYX', angles * [1.0, 0.1, 0.1])
    x, y, z, w = rotations.as_quat().T
    # Any positive scale of a quaternion is the same rotation.
    yaw = se2.yaw_from_quaternion(3 * x, 3 * y, 3 * z, 3 * w)
    np.testing.assert_allclose(yaw, rotations.as_euler('ZYX')[:, 0], atol=1e-9)


def test_intel_ros1_bag(shared_data):
    with BagReader([shared_data / 'intel' / 'intel.orig.bag']) as bag:
        assert bag.is_ros1
        # No /trajectory: the only pose topic is picked.
        assert bag.pose_topic == '/odom' and bag.pose_type == messages.ODOMETRY_TYPE
        assert not bag.has_constraints
        assert bag.message_count('/scan') == 13631
        assert bag.duration == pytest.approx(2691.3, abs=0.1)
        np.testing.assert_array_equal(bag.static_transform('base_link', 'laser'), np.zeros(3))
        assert bag.static_transform('base_link', 'camera') is None
        first = list(itertools.islice(bag.records(), 4))
    odometry, scan = first[0][1], first[1][1]
    assert isinstance(odometry, PoseSample) and isinstance(scan, Scan)
    assert (odometry.frame_id, odometry.child_frame_id) == ('odom', 'base_link')
    # Data README: first LaserScan of the bag.
    assert first[1][0] == pytest.approx(976052857.337530017, abs=1e-6)
    assert scan.stamp == pytest.approx(976052857.337530017, abs=1e-6)
    assert scan.frame_id == 'laser' and scan.ranges.size == 180
    np.testing.assert_allclose(scan.ranges[:4], [1.07, 1.07, 1.08, 1.08], rtol=1e-6)
    assert scan.model.angle_min == pytest.approx(-math.pi / 2, rel=1e-7)
    assert scan.model.angle_increment == pytest.approx(math.pi / 179, rel=1e-6)
    assert (scan.model.range_min, scan.model.max_range) == pytest.approx((0.1, 80.0))


def test_missing_bag(tmp_path):
    with pytest.raises(InputError, match='no such bag'):
        with BagReader([tmp_path / 'nothing.bag']):
            pass
    with pytest.raises(InputError, match='no bag given'):
        BagReader([])


@pytest.mark.parametrize('name, content', [('garbage.bag', b'#ROSBAG V2.0\n' + b'\x00' * 64),
                                           ('noise.bag', bytes(range(256)) * 4),
                                           ('noise.mcap', b'\x89MCAP0\r\n' + b'\x01' * 100)])
def test_corrupt_files(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError, match='not a readable ROS bag'):
        with BagReader([path]):
            pass


@pytest.mark.parametrize('damage, message, line', [
    (lambda text: text.replace('message_count:', 'message_count: [', 1),
     r"malformed YAML in the bag's metadata \(while parsing a flow sequence; expected", None),
    (lambda text: 'rosbag2_bagfile_information: 5\n', 'not a readable ROS bag', None),
])
def test_malformed_metadata_is_one_line_naming_the_file(tmp_path, recorded, damage, message,
                                                        line):
    folder = write_bag(tmp_path / 'bag', recorded)
    metadata = folder / 'metadata.yaml'
    metadata.write_text(damage(metadata.read_text()))
    with pytest.raises(InputError, match=message) as caught:
        with BagReader([folder]):
            pass
    text = str(caught.value)
    assert '\n' not in text and str(folder) in text
    if 'YAML' in message:
        assert caught.value.source == str(metadata) and caught.value.line is not None


def test_truncated_mcap(tmp_path, recorded):
    folder = write_bag(tmp_path / 'bag', recorded)
    data = (folder / 'bag.mcap').read_bytes()
    damaged = tmp_path / 'damaged.mcap'
    damaged.write_bytes(data[:len(data) // 2])
    with pytest.raises(InputError, match=str(damaged)):
        with BagReader([damaged]) as bag:
            list(bag.records())


def test_malformed_ros1_index(shared_data):
    # Data README: this bag's index records are malformed; rosbags refuses it.
    path = shared_data / 'ros1_native' / 'ccny_laser_scan_matcher_demo.bag'
    with pytest.raises(InputError, match='not a readable ROS bag'):
        with BagReader([path]):
            pass


@pytest.mark.parametrize('topics, message', [
    (BagTopics(scan='/laser'), r'no topic /laser \(the bag has /constraints .*--scan-topic'),
    (BagTopics(scan='/trajectory'),
     'topic /trajectory carries nav_msgs/msg/Path, expected sensor_msgs/msg/LaserScan'),
    (BagTopics(poses='/scan'), 'topic /scan carries sensor_msgs/msg/LaserScan, expected '
                               'nav_msgs/msg/Path or nav_msgs/msg/Odometry'),
    (BagTopics(poses='/odom'), 'no topic /odom .*--pose-topic'),
    (BagTopics(constraints='/trajectory'),
     'topic /trajectory carries nav_msgs/msg/Path, expected std_msgs/msg/Float64MultiArray'),
])
def test_missing_and_mistyped_topics(tmp_path, recorded, topics, message):
    path = write_bag(tmp_path / 'bag', recorded)
    with pytest.raises(InputError, match=message):
        with BagReader([path], topics):
            pass


def test_no_pose_topic(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    path = tmp_path / 'scans_only'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.add_connection('/scan', messages.SCAN_TYPE,
                              typestore=get_typestore(Stores.ROS2_JAZZY))
    with pytest.raises(InputError, match='no /trajectory topic and 0 other pose topics'):
        with BagReader([path]):
            pass


def test_unusable_messages_are_reported_not_fatal(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    types = store.types
    header = types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='laser')
    scan = types[messages.SCAN_TYPE](  # angle_max says 3 beams, the scan has 10
        header=header, angle_min=-1.0, angle_max=1.0, angle_increment=1.0, time_increment=0.0,
        scan_time=0.0, range_min=0.0, range_max=10.0, ranges=np.ones(10, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32))
    pose = types['geometry_msgs/msg/Pose'](
        position=types['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.0),
        orientation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=0.0))
    path_message = types[messages.PATH_TYPE](
        header=header, poses=[types[messages.POSE_STAMPED_TYPE](header=header, pose=pose)])
    rows = types[messages.CONSTRAINTS_TYPE](
        layout=types['std_msgs/msg/MultiArrayLayout'](dim=[], data_offset=0),
        data=np.arange(12.0))
    path = tmp_path / 'bad_content'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for time, (topic, msgtype, message) in enumerate([
                ('/scan', messages.SCAN_TYPE, scan),
                ('/trajectory', messages.PATH_TYPE, path_message),
                ('/constraints', messages.CONSTRAINTS_TYPE, rows)]):
            connection = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connection, time + 1, store.serialize_cdr(message, msgtype))
    with BagReader([path]) as bag:
        records = [record for _, record in bag.records()]
    bad = [records[0], records[2]]
    assert all(isinstance(record, bags.BadMessage) for record in bad)
    assert [(record.topic, record.index) for record in bad] == [('/scan', 1), ('/constraints', 1)]
    assert 'imply 3.0 beams but it has 10 ranges' in records[0].reason
    # a zero quaternion has no heading: the pose is passed on without one, the feed skips it
    assert isinstance(records[1], KeyframeEstimate) and np.isnan(records[1].poses[0, 2])
    applied = MonitorFeed().apply(records[1])
    assert applied.summary is None and 'unusable quaternion' in applied.warnings[0]
    assert 'not a multiple of 11' in records[2].reason


class _Message:
    """Attribute bag standing in for a message object."""

    def __init__(self, **fields):
        self.__dict__.update(fields)


def test_scan_conversion_caps_usable_range():
    stamp = _Message(sec=12, nanosec=500_000_000)
    message = _Message(header=_Message(stamp=stamp), angle_min=-1.0, angle_max=1.0,
                       angle_increment=0.5, range_min=-1.0, range_max=30.0,
                       ranges=np.arange(1.0, 6.0, dtype=np.float32))
    seconds, ranges, model = messages.scan_to_numpy(message, max_range=8.0)
    assert seconds == 12.5
    np.testing.assert_array_equal(ranges, [1, 2, 3, 4, 5])
    assert (model.max_range, model.range_min) == (8.0, 0.0)
    assert messages.scan_to_numpy(message)[2].max_range == 30.0


def test_constraints_layout_and_offset():
    dims = [_Message(label='edges', size=2, stride=22), _Message(label='fields', size=11,
                                                                stride=11)]
    data = np.arange(25.0)
    rows = messages.constraints_to_numpy(_Message(layout=_Message(dim=dims, data_offset=3),
                                              data=data))
    np.testing.assert_array_equal(rows, data[3:25].reshape(2, 11))
    with pytest.raises(ValueError, match='layout says 3 x 11 values from offset 3'):
        dims[0].size = 3
        messages.constraints_to_numpy(_Message(layout=_Message(dim=dims, data_offset=3), data=data))


def test_writer_refuses_bad_settings(tmp_path):
    with pytest.raises(ValueError, match='storage'):
        BagWriter(tmp_path / 'x', storage='bag')
    with pytest.raises(ValueError, match='mcap storage only'):
        BagWriter(tmp_path / 'x', storage='sqlite3', compress=True)
    (tmp_path / 'exists').mkdir()
    with pytest.raises(InputError, match='already exists'):
        with BagWriter(tmp_path / 'exists'):
            pass


def test_raw_messages_are_cdr(tmp_path, recorded, shared_data):
    path = write_bag(tmp_path / 'bag', recorded)
    with BagReader([path]) as bag:
        raw = list(bag.raw_messages(['/scan']))
    assert len(raw) == 10
    from rosbags.typesys import Stores, get_typestore
    message = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(raw[0][3], messages.SCAN_TYPE)
    np.testing.assert_array_equal(message.ranges, recorded[1][0])
    with BagReader([shared_data / 'intel' / 'intel.orig.bag']) as bag:
        with pytest.raises(InputError, match='ROS 1 serialized'):
            bag.raw_messages(['/scan'])


def test_paths_read_from_their_bytes_as_rosbags_deserializes_them(tmp_path, recorded):
    from rosbags.typesys import Stores, get_typestore
    typestore = get_typestore(Stores.ROS2_JAZZY)
    path = write_bag(tmp_path / 'bag', recorded)
    with BagReader([path]) as bag:
        raw = [data for *_, data in bag.raw_messages(['/trajectory'])]
    assert len(raw) == 10
    for data in raw:
        message = typestore.deserialize_cdr(data, messages.PATH_TYPE)
        for frame in ('', 'a', 'map', 'base_link'):  # every alignment of the entries
            for entry in message.poses:
                entry.header.frame_id = frame
            data = typestore.serialize_cdr(message, messages.PATH_TYPE)
            fast = messages.path_from_cdr(data)
            slow = messages.to_record(messages.PATH_TYPE, message)
            np.testing.assert_array_equal(fast.stamps, slow.stamps)
            np.testing.assert_array_equal(fast.poses, slow.poses)


def test_graph_markers_read_from_their_bytes_as_rosbags_deserializes_them(tmp_path, recorded):
    from rosbags.typesys import Stores, get_typestore
    typestore = get_typestore(Stores.ROS2_JAZZY)
    stamps, _, poses, _ = recorded
    with BagWriter(tmp_path / 'bag', topics=BagTopics(poses='/pose')) as writer:
        writer.write_single_pose(stamps[0], messages.POSE_COVARIANCE_TYPE, stamps[0], poses[0])
        for count in (1, 4, 10):
            writer.write_graph(stamps[count - 1], np.arange(count), poses[:count, :2])
    with BagReader([tmp_path / 'bag']) as bag:
        raw = [data for *_, data in bag.raw_messages(['/slam_toolbox/graph_visualization'])]
        replayed = [record for _, record in bag.records() if isinstance(record, GraphSnapshot)]
    assert len(raw) == len(replayed) == 3
    for data, record in zip(raw, replayed):
        slow = messages.to_record(messages.MARKER_ARRAY_TYPE,
                                  typestore.deserialize_cdr(data, messages.MARKER_ARRAY_TYPE))
        for fast in (messages.graph_markers_from_cdr(data), record):
            np.testing.assert_array_equal(fast.ids, slow.ids)
            np.testing.assert_array_equal(fast.positions, slow.positions)


@pytest.mark.parametrize('msgtype', [messages.POSE_STAMPED_TYPE, messages.POSE_COVARIANCE_TYPE,
                                     messages.ODOMETRY_TYPE])
def test_single_pose_sources(tmp_path, msgtype):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    types = store.types
    header = types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=5, nanosec=250_000_000), frame_id='map')
    pose = types['geometry_msgs/msg/Pose'](
        position=types['geometry_msgs/msg/Point'](x=1.5, y=-2.0, z=0.3),
        orientation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=math.sin(0.35),
                                                          w=math.cos(0.35)))
    covariance = types['geometry_msgs/msg/PoseWithCovariance'](pose=pose,
                                                               covariance=np.zeros(36))
    twist = types['geometry_msgs/msg/TwistWithCovariance'](
        twist=types['geometry_msgs/msg/Twist'](
            linear=types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0),
            angular=types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)),
        covariance=np.zeros(36))
    message = {
        messages.POSE_STAMPED_TYPE: lambda: types[msgtype](header=header, pose=pose),
        messages.POSE_COVARIANCE_TYPE: lambda: types[msgtype](header=header, pose=covariance),
        messages.ODOMETRY_TYPE: lambda: types[msgtype](header=header, child_frame_id='base_link',
                                                   pose=covariance, twist=twist),
    }[msgtype]()
    path = tmp_path / 'poses'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.add_connection('/scan', messages.SCAN_TYPE, typestore=store)
        connection = writer.add_connection('/localizer', msgtype, typestore=store)
        writer.write(connection, 1, store.serialize_cdr(message, msgtype))
    with BagReader([path]) as bag:
        assert (bag.pose_topic, bag.pose_type) == ('/localizer', msgtype)
        [(_, sample)] = list(bag.records())
    assert isinstance(sample, PoseSample)
    assert sample.stamp == 5.25 and sample.frame_id == 'map'
    assert sample.child_frame_id == ('base_link' if msgtype == messages.ODOMETRY_TYPE else '')
    np.testing.assert_allclose(sample.pose, [1.5, -2.0, 0.7], atol=1e-12)
