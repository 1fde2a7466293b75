"""`map-consistency replay`: bags through the live monitor, the CARMEN round trip, bad bags."""
import csv
import os
import random
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from map_consistency_ros.cli import replay
from map_consistency_ros.cli.main import build_parser, main
from map_consistency_ros.io.bags import BagReader, BagWriter

ROUND_TRIP_SCANS = 60
ROS1_SECONDS = 60.0


def carmen_excerpt(source, destination, records):
    """The lines of a CARMEN log up to its `records`-th laser record."""
    lines, seen = [], 0
    with open(source) as stream:
        for line in stream:
            if line.startswith('FLASER'):
                if seen == records:
                    break
                seen += 1
            lines.append(line)
    destination.write_text(''.join(lines))
    return destination


def ros1_excerpt(source, destination, seconds):
    """The first `seconds` of a ROS 1 bag, messages copied byte for byte."""
    from rosbags.rosbag1 import Reader, Writer
    with Reader(source) as reader, Writer(destination) as writer:
        connections = {
            connection.id: writer.add_connection(
                connection.topic, connection.msgtype, msgdef=connection.msgdef.data,
                md5sum=connection.digest, callerid=connection.ext.callerid,
                latching=connection.ext.latching)
            for connection in reader.connections}
        stop = reader.start_time + int(seconds * 1e9)
        for connection, timestamp, data in reader.messages(stop=stop):
            writer.write(connections[connection.id], timestamp, data)
    return destination


def read_pairs(path):
    with open(path) as stream:
        rows = list(csv.DictReader(stream))
    return {(int(row['i']), int(row['j'])): row for row in rows}


@pytest.fixture(scope='module')
def round_trip(shared_data, tmp_path_factory):
    """`check` on an Intel excerpt, and `replay` of the same excerpt after `convert`."""
    folder = tmp_path_factory.mktemp('round_trip')
    log = carmen_excerpt(shared_data / 'intel' / 'intel.gfs.log', folder / 'intel.log',
                         ROUND_TRIP_SCANS)
    checked = main(['check', str(log), '--quiet', '--report', str(folder / 'check.json'),
                    '--pairs-csv', str(folder / 'check.csv')])
    assert main(['convert', str(log), str(folder / 'bag'), '--quiet']) == 0
    replayed = main(['replay', str(folder / 'bag'), '--quiet',
                     '--report', str(folder / 'replay.json'),
                     '--pairs-csv', str(folder / 'replay.csv'),
                     '--plot', str(folder / 'map.png'), '--stats-plot', str(folder / 'psi.png'),
                     '--explain', str(folder / 'pairs.png')])
    return folder, checked, replayed


def test_round_trip_verdict(strict_json, round_trip):
    folder, checked, replayed = round_trip
    assert replayed == checked
    check_report = strict_json((folder / 'check.json').read_text())
    replay_report = strict_json((folder / 'replay.json').read_text())
    assert replay_report['verdict'] == check_report['verdict']
    assert replay_report['inconsistent_scans'] == check_report['inconsistent_scans']
    for key in ('tested_pairs', 'failed_pairs', 'critical_count'):
        assert replay_report['scans'][key] == check_report['scans'][key]
    # Ranges travel as float32 in a LaserScan: scales agree to about single precision.
    np.testing.assert_allclose(replay_report['scans']['scale'], check_report['scans']['scale'],
                               rtol=1e-4)
    # both test the same viewpoints; the other keyframes are folded into them
    counts = replay_report['replay']['scan_counts']
    assert counts['keyframes'] == check_report['summary']['scans']
    assert (counts['keyframes'] + counts['folded'] == counts['received'] == ROUND_TRIP_SCANS
            == check_report['laser_records'])
    assert replay_report['replay']['warnings'] == []
    assert (folder / 'map.png').read_bytes()[:4] == b'\x89PNG'
    assert (folder / 'psi.png').read_bytes()[:4] == b'\x89PNG'
    assert (folder / 'pairs.png').read_bytes()[:4] == b'\x89PNG'


def test_round_trip_pairs(strict_json, round_trip):
    folder = round_trip[0]
    # both name a scan by its laser record's position in the input
    assert (strict_json((folder / 'check.json').read_text())['scans']['id']
            == strict_json((folder / 'replay.json').read_text())['scans']['id'])
    checked = read_pairs(folder / 'check.csv')
    replayed = read_pairs(folder / 'replay.csv')
    assert checked.keys() == replayed.keys() and len(checked) > 400
    for key, row in checked.items():
        other = replayed[key]
        assert int(other['n_ij']) == int(row['n_ij'])
        assert float(other['M_ij']) == pytest.approx(float(row['M_ij']), rel=1e-4, abs=1e-6)
        assert other['failed'] == row['failed']
        if row['psi_ij']:
            assert float(other['psi_ij']) == pytest.approx(float(row['psi_ij']), rel=1e-3,
                                                           abs=1e-3)


@pytest.fixture(scope='module')
def intel_odometry(shared_data, tmp_path_factory):
    """Replay of the first minute of the raw Intel bag (ROS 1, LaserScan + Odometry)."""
    bag_path = ros1_excerpt(shared_data / 'intel' / 'intel.orig.bag',
                            tmp_path_factory.mktemp('ros1') / 'intel_start.bag', ROS1_SECONDS)
    args = build_parser().parse_args(['replay', str(bag_path), '--quiet'])
    with replay.open_bag(args) as bag:
        snapshot, _, details = replay.replay_bag(args, bag)
        odometry = [(record.stamp, record.pose) for _, record in bag.records()
                    if hasattr(record, 'child_frame_id')]
    return bag_path, snapshot, details, odometry


def test_odometry_bag_keyframes(intel_odometry):
    _, snapshot, details, odometry = intel_odometry
    assert details['topics']['poses'] == '/odom'
    assert details['laser_offset_source'] == '/tf_static base_link -> laser'
    assert details['replay']['scan_messages'] > 250
    assert 5 < snapshot.keyframe_count < details['replay']['scan_messages']
    stamps = np.array([stamp for stamp, _ in odometry])
    poses = np.array([pose for _, pose in odometry])
    # Oracle: odometry at 10 Hz, interpolated linearly per coordinate at the keyframe stamps.
    for coordinate in (0, 1):
        expected = np.interp(snapshot.stamps, stamps, poses[:, coordinate])
        np.testing.assert_allclose(snapshot.poses[:, coordinate], expected, atol=2e-3)
    steps = np.diff(snapshot.poses, axis=0)
    moved = np.hypot(steps[:, 0], steps[:, 1])
    turned = np.abs(np.angle(np.exp(1j * steps[:, 2])))
    assert np.all((moved >= 0.5 - 0.02) | (turned >= 0.25 - 0.01))
    assert snapshot.result.scan_count == snapshot.keyframe_count


def test_odometry_bag_cli(strict_json, intel_odometry, tmp_path, capsys):
    bag_path = intel_odometry[0]
    code = main(['replay', str(bag_path), '--pose-topic', '/odom', '--quiet',
                 '--report', str(tmp_path / 'r.json')])
    out = capsys.readouterr().out
    report = strict_json((tmp_path / 'r.json').read_text())
    assert code == (0 if report['verdict'] == 'consistent' else 1)
    assert report['replay']['scan_counts']['keyframes'] == intel_odometry[1].keyframe_count
    assert 'scans/s' in out and "the bag's real time" in out


def _one_line_error(capsys):
    captured = capsys.readouterr()
    assert 'Traceback' not in captured.err
    assert captured.err.count('\n') == 1
    return captured.err


def test_bad_bags_exit_2(shared_data, tmp_path, capsys, round_trip):
    corrupt = tmp_path / 'corrupt.bag'
    corrupt.write_bytes(b'#ROSBAG V2.0\n' + bytes(200))
    assert main(['replay', str(corrupt), '--quiet']) == 2
    assert 'not a readable ROS bag' in _one_line_error(capsys)
    bag = str(round_trip[0] / 'bag')
    assert main(['replay', bag, '--scan-topic', '/laser', '--quiet']) == 2
    assert 'no topic /laser' in _one_line_error(capsys)
    assert main(['replay', bag, '--pose-topic', '/scan', '--quiet']) == 2
    assert 'topic /scan carries sensor_msgs/msg/LaserScan' in _one_line_error(capsys)
    assert main(['replay', bag, '--max-range', '0', '--quiet']) == 2
    assert 'max_range: 0.0 is outside [0.1, 1000]' in _one_line_error(capsys)
    assert main(['replay', str(tmp_path / 'missing'), '--quiet']) == 2
    assert 'no such bag' in _one_line_error(capsys)
    malformed = shared_data / 'ros1_native' / 'ccny_laser_scan_matcher_demo.bag'
    assert main(['replay', str(malformed), '--quiet']) == 2
    assert 'not a readable ROS bag' in _one_line_error(capsys)


def test_no_matching_poses(tmp_path, capsys):
    from map_consistency_ros.core.geometry import SensorModel
    model = SensorModel(angle_min=-1.5, angle_increment=0.5, max_range=10.0)
    with BagWriter(tmp_path / 'offset') as writer:
        for stamp in (1.0, 2.0, 3.0):
            writer.write_scan(stamp, stamp, np.full(7, 2.0), model)
            # Stamped half a second off its scan: no pose names a scan.
            writer.write_trajectory(stamp, np.array([stamp + 0.5]), np.zeros((1, 3)))
    assert main(['replay', str(tmp_path / 'offset'), '--quiet']) == 2
    assert 'no keyframes: 3 scans on /scan and no pose of /trajectory matched' in (
        _one_line_error(capsys))


@pytest.fixture()
def ros_domain(tmp_path, monkeypatch):
    """An isolated DDS domain and ROS log folder, for this process and the ones it starts."""
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 200)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path / 'ros_log'))


class Listener:
    """An rclpy node spinning in a thread that keeps (arrival ns, message) per topic."""

    def __init__(self, subscriptions):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('replay_listener', context=self.context)
        self.received = {}
        for topic, msgtype, qos, raw in subscriptions:
            self.received[topic] = []
            self.node.create_subscription(msgtype, topic, self._keeper(self.received[topic]), qos,
                                          raw=raw)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    @staticmethod
    def _keeper(messages):
        return lambda message: messages.append((time.monotonic_ns(), message))

    def wait(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while not predicate() and time.monotonic() < deadline:
            time.sleep(0.05)
        return predicate()

    def close(self):
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
        self.thread.join(timeout=5)


def test_publish(round_trip, ros_domain):
    """--publish plays the bag onto ROS 2 topics; a subscriber gets every message intact."""
    from nav_msgs.msg import Path
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import LaserScan
    from std_msgs.msg import Float64MultiArray
    listener = Listener([('/scan', LaserScan, 1000, False), ('/trajectory', Path, 1000, False),
                         ('/constraints', Float64MultiArray, 10, False),
                         ('/clock', Clock, 1000, False)])
    try:
        assert main(['replay', str(round_trip[0] / 'bag'), '--publish', '--rate', '50',
                     '--quiet']) == 0
        listener.wait(lambda: len(listener.received['/trajectory']) == ROUND_TRIP_SCANS, 5)
    finally:
        listener.close()
    scans, paths = ([message for _, message in listener.received[topic]]
                    for topic in ('/scan', '/trajectory'))
    assert len(scans) == len(paths) == ROUND_TRIP_SCANS
    # convert publishes the odometry edges once, after the last record.
    [(_, constraints)] = listener.received['/constraints']
    assert len(constraints.data) == 11 * (ROUND_TRIP_SCANS - 1)
    assert [len(path.poses) for path in paths] == list(range(1, ROUND_TRIP_SCANS + 1))
    with BagReader([round_trip[0] / 'bag']) as bag:
        first = next(record for _, record in bag.records())
        start, end = bag.start_time, bag.start_time + bag.duration
    np.testing.assert_array_equal(np.asarray(scans[0].ranges, dtype=np.float64), first.ranges)
    # /clock follows the bag's log time, for nodes with use_sim_time
    clock = [message.clock.sec + message.clock.nanosec * 1e-9
             for _, message in listener.received['/clock']]
    assert clock == sorted(clock) and len(clock) >= ROUND_TRIP_SCANS
    assert start - 1e-6 <= clock[0] and clock[-1] <= end + 1e-6


def record_raw(path, received, types):
    """Write raw CDR messages received per topic into a rosbag2 (mcap), in arrival order."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, messages in received.items():
            connection = writer.add_connection(topic, types[topic], typestore=store)
            for arrival, data in messages:
                writer.write(connection, arrival, data)
    return path


@pytest.fixture(scope='module')
def wrong_loop_closure(round_trip):
    """The round-trip run, then a last trajectory that bends its final third by 0.15 rad."""
    from map_consistency_ros.core.geometry import se2
    from map_consistency_ros.core.live import KeyframeEstimate, Scan
    folder = round_trip[0]
    with BagReader([folder / 'bag']) as bag:
        records = [record for _, record in bag.records()]
    scans = [record for record in records if isinstance(record, Scan)]
    final = [record for record in records if isinstance(record, KeyframeEstimate)][-1]
    pivot = 2 * ROUND_TRIP_SCANS // 3
    bent = final.poses.copy()
    bend = np.array([0.0, 0.0, 0.15])
    bent[pivot:] = se2.compose(se2.compose(bent[pivot], bend),
                               se2.relative(bent[pivot], bent[pivot:]))
    path = folder / 'bent'
    with BagWriter(path) as writer:
        for index, scan in enumerate(scans):
            writer.write_scan(scan.stamp, scan.stamp, scan.ranges, scan.model)
            writer.write_trajectory(scan.stamp + 1e-3, final.stamps[:index + 1],
                                    final.poses[:index + 1])
        writer.write_trajectory(final.stamps[-1] + 1.0, final.stamps, bent)
    return path


def test_replay_of_recorded_node_inputs_matches_the_node(strict_json, wrong_loop_closure,
                                                         ros_domain, tmp_path,
                                                         process_stopper):
    """The node fed by --publish, and replay of a recording of its inputs, agree on the map
    both judged: the node's report whose judged_stamp and judged_keyframes are replay's (not
    the newest report after a quiet spell, which on a busy machine may judge an older
    estimate)."""
    from nav_msgs.msg import Path
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import LaserScan
    from std_msgs.msg import Bool, Float64MultiArray, String
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node = subprocess.Popen([sys.executable, '-m', 'map_consistency_ros.ros.node'],
                            env=dict(os.environ), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    listener = None
    try:
        listener = Listener([('/scan', LaserScan, 1000, True), ('/trajectory', Path, 1000, True),
                             ('/constraints', Float64MultiArray, 10, True),
                             ('/map_consistency/report', String, latched, False),
                             ('/map_consistency/consistent', Bool, latched, False)])
        stamped = {topic: listener.received[topic]
                   for topic in ('/scan', '/trajectory', '/constraints')}
        assert listener.wait(lambda: listener.node.count_publishers('/map_consistency/report')
                             > 0, 30), 'the node did not start'
        assert main(['replay', str(wrong_loop_closure), '--publish', '--rate', '50',
                     '--subscribers', '2', '--quiet']) == 0
        assert listener.wait(lambda: len(stamped['/trajectory']) == ROUND_TRIP_SCANS + 1
                             and len(stamped['/scan']) == ROUND_TRIP_SCANS, 60), \
            'the inputs did not all arrive'
        received = {topic: [(arrival, bytes(data)) for arrival, data in messages]
                    for topic, messages in stamped.items()}
        recorded = record_raw(tmp_path / 'recorded', received,
                              {'/scan': 'sensor_msgs/msg/LaserScan',
                               '/trajectory': 'nav_msgs/msg/Path',
                               '/constraints': 'std_msgs/msg/Float64MultiArray'})
        code = main(['replay', str(recorded), '--quiet', '--report', str(tmp_path / 'r.json')])
        report = strict_json((tmp_path / 'r.json').read_text())
        judged = (report['judged_stamp'], report['judged_keyframes'])
        # the last Path's header stamp: the bent estimate, all of its keyframes
        last = deserialize_message(received['/trajectory'][-1][1], Path).header.stamp
        # ... its keyframes judged as viewpoints or folded into them
        assert judged[0] == last.sec + last.nanosec * 1e-9
        assert judged[1] + report['replay']['scan_counts']['folded'] == ROUND_TRIP_SCANS
        reports = listener.received['/map_consistency/report']

        def node_report_on_that_map():
            contents = (strict_json(message.data) for _, message in reversed(list(reports)))
            return next((content for content in contents
                         if (content.get('judged_stamp'),
                             content.get('judged_keyframes')) == judged), None)

        assert listener.wait(lambda: node_report_on_that_map() is not None, 60), \
            'the node never judged the map replay judged'
        node_report = node_report_on_that_map()
        consistent = listener.received['/map_consistency/consistent']
        assert listener.wait(lambda: consistent and consistent[-1][1].data is False, 10)
    finally:
        if listener is not None:
            listener.close()
        process_stopper(node)
    assert code == 1 and report['verdict'] == 'inconsistent' and not node_report['consistent']
    assert report['summary']['inconsistent_scans'] > 0
    # the node said what replay says: the paper's figures and both stages' verdict
    for key, value in report['summary'].items():
        if key != 'consistent':
            assert node_report[key] == value, key
    assert node_report['paper_consistent'] == report['summary']['consistent']
    assert node_report['summary_line'] == report['summary_line']
    # replay names keyframes by their laser records, the node by their stamps
    stamp_of = dict(zip(report['scans']['id'], report['keyframe_stamps']))
    np.testing.assert_allclose(node_report['misaligned_scans'],
                               [stamp_of[record] for record in report['misaligned_scans']],
                               atol=1e-6)


def test_publish_refuses_ros1(intel_odometry, capsys):
    assert main(['replay', str(intel_odometry[0]), '--publish', '--quiet']) == 2
    assert 'ROS 1 serialized' in _one_line_error(capsys)


def test_duration_limits_the_replay(strict_json, intel_odometry, tmp_path):
    bag_path, _, details, _ = intel_odometry
    code = main(['replay', str(bag_path), '--duration', '20', '--quiet',
                 '--report', str(tmp_path / 'r.json')])
    assert code in (0, 1, 4)  # 20 s may hold too little travel to judge
    replayed = strict_json((tmp_path / 'r.json').read_text())['replay']
    assert 15 < replayed['bag_seconds_replayed'] <= 20
    assert replayed['scan_messages'] < details['replay']['scan_messages']


def test_bundled_demo_bag(shared_data):
    """The demo bag is `convert --limit 290 --compress` of the Intel corrected log."""
    from importlib import resources

    from map_consistency_ros.io import carmen
    from map_consistency_ros.core.live import KeyframeEstimate, Scan
    demo = resources.files('map_consistency_ros') / 'data' / 'intel_demo.mcap'
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    with BagReader([demo]) as bag:
        assert bag.message_count('/scan') == bag.message_count('/trajectory') == 290
        records = [record for _, record in bag.records()]
    scans = [record for record in records if isinstance(record, Scan)]
    last_path = [record for record in records if isinstance(record, KeyframeEstimate)][-1]
    np.testing.assert_array_equal(np.array([scan.ranges for scan in scans]),
                                  log.ranges[:290].astype(np.float32))
    np.testing.assert_allclose(last_path.poses[:, :2], log.laser_poses[:290, :2], atol=1e-12)
    # The log's headings run past pi; a quaternion gives them back wrapped.
    turn = np.angle(np.exp(1j * (last_path.poses[:, 2] - log.laser_poses[:290, 2])))
    np.testing.assert_allclose(turn, 0.0, atol=1e-12)
    np.testing.assert_allclose(last_path.stamps, log.timestamps[:290])


def _changed(spec):
    """A valid value of a parameter other than its default."""
    if spec.choices:
        return spec.choices[(spec.choices.index(spec.default) + 1) % len(spec.choices)]
    if spec.kind is bool:
        return not spec.default
    if spec.kind is str:
        return 'odom'
    if spec.kind is tuple:
        return [0.01, 0.0, 0.0]
    low, high = spec.bounds
    value = spec.default * 1.1 if spec.default else low + (high - low) * 1e-3
    if spec.kind is int:
        value = spec.default + 1
    assert low <= value <= high and value != spec.default, spec.name
    return value


def test_every_node_parameter_goes_through_params_file(strict_json, round_trip, tmp_path, capsys):
    """The node's parameter file drives replay: every parameter is checked and reported."""
    import yaml

    from map_consistency_ros.core.configuration import PARAMETERS
    values = {spec.name: _changed(spec) for spec in PARAMETERS}
    values['pose_source'] = 'path'  # the bag's pose topic is a Path
    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump({'/map_consistency': {'ros__parameters': values}}))
    code = main(['replay', str(round_trip[0] / 'bag'), '--quiet', '--params-file', str(params),
                 '--report', str(tmp_path / 'r.json')])
    assert code in (0, 1) and 'unknown parameter' not in capsys.readouterr().err
    report = strict_json((tmp_path / 'r.json').read_text())
    used = report['node_parameters']
    assert used.keys() == values.keys()
    for name, value in values.items():
        assert used[name] == pytest.approx(value), name
    test_parameters = report['parameters']
    for name in test_parameters:
        assert test_parameters[name] == pytest.approx(values[name]), name
    # an option given on the command line wins over the file
    main(['replay', str(round_trip[0] / 'bag'), '--quiet', '--params-file', str(params),
          '--alpha', '0.02', '--report', str(tmp_path / 'r2.json')])
    assert strict_json((tmp_path / 'r2.json').read_text())['parameters']['alpha'] == 0.02


def test_bad_parameter_files(round_trip, tmp_path, capsys):
    bag = str(round_trip[0] / 'bag')
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    alpha: "0.01"\n')
    assert main(['replay', bag, '--quiet', '--params-file', str(params)]) == 2
    assert "alpha: expected a float, got a string '0.01'" in _one_line_error(capsys)
    params.write_text('/**:\n  ros__parameters:\n    max_range: 8\n    trim: 5\n')
    assert main(['replay', bag, '--quiet', '--params-file', str(params)]) in (0, 1)
    error = capsys.readouterr().err
    assert "unknown parameter 'trim' ignored; did you mean trim_largest?" in error
    params.write_text('just text')
    assert main(['replay', bag, '--quiet', '--params-file', str(params)]) == 2
    assert 'not a ROS 2 parameter file' in _one_line_error(capsys)


@pytest.fixture(scope='module')
def demo_and_excerpt(shared_data, tmp_path_factory):
    """`replay` of the demo bag (the Intel log's first 290 laser records) and `check` of those
    records, their reports and printed summaries; the titles of replay's statistics figure."""
    from map_consistency_ros.cli import plots
    from map_consistency_ros.cli.demo import demo_bag_path
    folder = tmp_path_factory.mktemp('demo_and_excerpt')
    log = carmen_excerpt(shared_data / 'intel' / 'intel.gfs.log', folder / 'intel.log', 290)
    titles, save_figure = [], plots.save_figure

    def keep_titles(figure, path):
        titles.extend(ax.get_title() for ax in figure.axes)
        save_figure(figure, path)

    outputs = {}
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(plots, 'save_figure', keep_titles)
        for command, source in (('check', log), ('replay', demo_bag_path())):
            report = folder / f'{command}.json'
            out = printed_by_main(
                [command, str(source), '--quiet', '--report', str(report)]
                + (['--stats-plot', str(folder / 'psi.png')] if command == 'replay' else []))
            outputs[command] = (report, out)
    return outputs, titles


def printed_by_main(arguments):
    """main(arguments) in this process; what it printed."""
    import contextlib
    import io
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        main(arguments)
    return printed.getvalue()


def test_replay_and_check_name_scans_by_the_same_laser_records(strict_json, demo_and_excerpt):
    outputs, _ = demo_and_excerpt
    checked, replayed = (strict_json(outputs[command][0].read_text())
                         for command in ('check', 'replay'))
    ids = checked['scans']['id']
    assert replayed['scans']['id'] == ids
    for report in (checked, replayed):  # the explained classes and the rest: the failed pairs
        assert (sum(report['explained_pairs'].values()) + report['failed_pairs_not_explained']
                == report['summary']['failed_pairs'])
    # folded records leave gaps: ranks among the keyframes would differ from these names
    assert ids != list(range(len(ids))) and max(ids) == 289


def test_statistics_figure_counts_the_pairs_the_summary_counts(strict_json, demo_and_excerpt):
    outputs, titles = demo_and_excerpt
    report, out = outputs['replay']
    summary = strict_json(report.read_text())['summary']
    failed, tested = summary['failed_pairs'], summary['tested_pairs']
    assert f'failed pairs          {failed}\n' in out
    assert f'({tested} with enough points to test)' in out
    assert titles == [f'{failed} of {tested} tested pairs failed']
