"""`map-consistency convert`: CARMEN logs and g2o graphs into rosbag2 that replay like a run."""
import math

import numpy as np
import pytest

from map_consistency_ros.cli.main import main
from map_consistency_ros.io import carmen
from map_consistency_ros.core.live import Constraints, KeyframeEstimate, Scan
from map_consistency_ros.io.bags import BagReader

SCANS = 40


@pytest.fixture(scope='module')
def intel_log(shared_data):
    return shared_data / 'intel' / 'intel.gfs.log'


def first_records(log, count):
    """The first `count` laser records of a log, as read_carmen_log gives them."""
    return carmen.CarmenLog(
        path=log.path, ranges=log.ranges[:count], laser_poses=log.laser_poses[:count],
        robot_poses=log.robot_poses[:count], timestamps=log.timestamps[:count],
        line_numbers=log.line_numbers[:count], stated_angles=log.stated_angles,
        parameters=log.parameters)


@pytest.fixture(scope='module')
def converted(intel_log, tmp_path_factory):
    output = tmp_path_factory.mktemp('bags') / 'intel40'
    assert main(['convert', str(intel_log), str(output), '--quiet', '--limit', str(SCANS),
                 '--constraints-every', '16']) == 0
    with BagReader([output]) as bag:
        records = [record for _, record in bag.records()]
    return first_records(carmen.read_carmen_log(intel_log), SCANS), records


def test_scans(converted):
    log, records = converted
    scans = [record for record in records if isinstance(record, Scan)]
    assert len(scans) == SCANS
    for index, scan in enumerate(scans):
        np.testing.assert_array_equal(scan.ranges, log.ranges[index].astype(np.float32))
        assert scan.stamp == pytest.approx(log.timestamps[index], abs=1e-9)
    model, checked = scans[0].model, carmen.sensor_model(log)
    # The beam angles `check` uses, at LaserScan's single precision; the log states no sensor
    # maximum, so range_max is its largest reading (81.83 m, a 'no return' of the whole log).
    assert model.angle_min == pytest.approx(checked.angle_min, rel=1e-7)
    assert model.angle_increment == pytest.approx(checked.angle_increment, rel=1e-7)
    assert model.max_range == pytest.approx(81.83, rel=1e-7)
    assert model.range_min == 0.0


def test_trajectory_grows_by_one_keyframe(converted):
    log, records = converted
    paths = [record for record in records if isinstance(record, KeyframeEstimate)]
    assert [path.stamps.size for path in paths] == list(range(1, SCANS + 1))
    np.testing.assert_allclose(paths[-1].stamps, log.timestamps)
    np.testing.assert_allclose(paths[-1].poses, log.laser_poses, atol=1e-12)
    # Each scan comes before the path that names it.
    kinds = [type(record).__name__ for record in records if not isinstance(record, Constraints)]
    assert kinds == ['Scan', 'KeyframeEstimate'] * SCANS


def test_constraints_are_the_odometry_steps(converted):
    log, records = converted
    edges = [record.rows for record in records if isinstance(record, Constraints)]
    assert [rows.shape[0] for rows in edges] == [16, 32, SCANS - 1]
    rows = edges[-1]
    np.testing.assert_allclose(rows[:, 0], log.timestamps[:-1])
    np.testing.assert_allclose(rows[:, 1], log.timestamps[1:])
    # Oracle: the step of pose b in the frame of pose a, by rotation matrices.
    for row, a, b in zip(rows, log.robot_poses[:-1], log.robot_poses[1:]):
        rotation = np.array([[math.cos(a[2]), -math.sin(a[2])], [math.sin(a[2]), math.cos(a[2])]])
        np.testing.assert_allclose(row[2:4], rotation.T @ (b[:2] - a[:2]), atol=1e-12)
        turn = math.remainder(b[2] - a[2], 2 * math.pi)
        assert row[4] == pytest.approx(turn, abs=1e-12)
    np.testing.assert_allclose(rows[:, 5:], np.tile([400.0, 0, 0, 400.0, 0, 2500.0],
                                                    (SCANS - 1, 1)))


def test_sqlite3_storage_and_limit(intel_log, tmp_path):
    output = tmp_path / 'small'
    assert main(['convert', str(intel_log), str(output), '--storage', 'sqlite3',
                 '--limit', '5', '--quiet']) == 0
    assert list(output.glob('*.db3'))
    with BagReader([output]) as bag:
        assert bag.message_count('/scan') == 5
        assert bag.message_count('/constraints') == 1


def test_backwards_timestamps(intel_log, tmp_path, capsys):
    # Intel's record 295 (line 5643) is logged 0.114 s before its predecessor.
    log = intel_log
    assert main(['convert', str(log), str(tmp_path / 'refused'), '--quiet',
                 '--limit', '297']) == 2
    error = capsys.readouterr().err
    assert f'{log}:5643: logger timestamp 940.54 does not increase' in error
    assert 'Traceback' not in error and error.count('\n') == 1
    assert main(['convert', str(log), str(tmp_path / 'fixed'), '--quiet', '--fix-stamps',
                 '--limit', '297']) == 0
    assert '1 records whose logger timestamp went backwards' in capsys.readouterr().out
    with BagReader([tmp_path / 'fixed']) as bag:
        stamps = [record.stamp for _, record in bag.records() if isinstance(record, Scan)]
    assert stamps[295] == pytest.approx(stamps[294] + 0.01)
    assert np.all(np.diff(stamps) > 0)


def test_rate_for_logs_without_timestamps(shared_data, tmp_path, capsys):
    log = shared_data / 'carmen_corrected_extra' / 'orebro-corrected.log.gz'
    assert main(['convert', str(log), str(tmp_path / 'refused'), '--quiet']) == 2
    assert '--rate' in capsys.readouterr().err
    assert main(['convert', str(log), str(tmp_path / 'orebro'), '--quiet', '--rate', '4',
                 '--limit', '9']) == 0
    with BagReader([tmp_path / 'orebro']) as bag:
        scans = [record for _, record in bag.records() if isinstance(record, Scan)]
    np.testing.assert_allclose([scan.stamp for scan in scans], np.arange(9) / 4)
    assert scans[0].ranges.size == 181


@pytest.mark.parametrize('arguments, message', [
    (['--rate', '0'], '--rate must be positive'),
    (['--limit', '0'], '--limit must be at least 1'),
    (['--constraints-every', '0'], '--constraints-every must be at least 1'),
    (['--odometry-sigmas', '0', '1', '1'], '--odometry-sigmas must be 3 positive'),
    (['--storage', 'sqlite3', '--compress'], 'mcap storage only'),
    (['--range-max', '-1'], '--range-max must be positive'),
    (['--range-max', '1e300'], '--range-max must be positive and at most 100000 m'),
    (['--rate', '1e-300'], '--rate 1e-300 stamps record 1 at 9.99'),
])
def test_bad_options(intel_log, tmp_path, capsys, arguments, message):
    assert main(['convert', str(intel_log), str(tmp_path / 'out'), '--quiet',
                 *arguments]) == 2
    assert message in capsys.readouterr().err


def test_bad_inputs(intel_log, tmp_path, capsys):
    assert main(['convert', str(tmp_path / 'missing.log'), str(tmp_path / 'a'), '--quiet']) == 2
    assert 'no such file' in capsys.readouterr().err
    (tmp_path / 'exists').mkdir()
    assert main(['convert', str(intel_log), str(tmp_path / 'exists'), '--quiet',
                 '--limit', '3']) == 2
    assert 'already exists' in capsys.readouterr().err
    empty = tmp_path / 'empty.log'
    empty.write_text('PARAM robot_front_laser_max 30 nohost 0\n')
    assert main(['convert', str(empty), str(tmp_path / 'b'), '--quiet']) == 2
    assert 'no FLASER or ROBOTLASER1' in capsys.readouterr().err


def test_a_conversion_failing_midway_leaves_no_bag(intel_log, tmp_path, monkeypatch, capsys):
    from map_consistency_ros.io.bags import BagWriter
    written = []

    def failing(self, *args, **kwargs):
        written.append(1)
        if len(written) == 20:
            raise OSError(28, 'No space left on device', 'disk')

    monkeypatch.setattr(BagWriter, 'write_trajectory', failing)
    output = tmp_path / 'new' / 'folders' / 'bag'
    assert main(['convert', str(intel_log), str(output), '--quiet', '--limit', '40']) == 2
    assert 'No space left on device' in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # neither the bag nor the folders made for it


def test_a_log_with_a_nan_timestamp_is_refused_before_any_bag(intel_log, tmp_path, capsys):
    lines = intel_log.read_text().splitlines(keepends=True)[:2000]
    flaser = [index for index, line in enumerate(lines) if line.startswith('FLASER')]
    tokens = lines[flaser[10]].split()
    tokens[-1] = 'nan'
    lines[flaser[10]] = ' '.join(tokens) + '\n'
    damaged = tmp_path / 'nan_stamp.log'
    damaged.write_text(''.join(lines))
    assert main(['convert', str(damaged), str(tmp_path / 'bag'), '--quiet']) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.endswith(f'{damaged}:{flaser[10] + 1}: logger timestamp nan is not finite')
    assert not (tmp_path / 'bag').exists()


GRAPH_SCANS = 30
LOOPS = ((5, 20), (0, 25))
LASER_OFFSET = np.array([0.1, -0.05, 0.02])


@pytest.fixture(scope='module')
def graph_bag(intel_log, tmp_path_factory):
    """A g2o graph of the first Intel scans (laser offset, two loop closures), converted."""
    from map_consistency_ros.core.backend import PoseGraph
    from map_consistency_ros.core.geometry import se2
    from map_consistency_ros.io import g2o
    log = first_records(carmen.read_carmen_log(intel_log), GRAPH_SCANS)
    offsets = np.broadcast_to(LASER_OFFSET, (GRAPH_SCANS, 3))
    robot = se2.compose(log.laser_poses, se2.inverse(offsets))
    first = [*range(GRAPH_SCANS - 1), *(a for a, _ in LOOPS)]
    second = [*range(1, GRAPH_SCANS), *(b for _, b in LOOPS)]
    information = np.tile(np.diag([100.0, 100.0, 400.0]), (len(first), 1, 1))
    graph = PoseGraph(poses=robot, edge_from=first, edge_to=second,
                      measurements=se2.relative(robot[first], robot[second]),
                      information=information)
    laser = carmen.CarmenLog(
        path='', ranges=log.ranges, laser_poses=log.laser_poses, robot_poses=robot,
        timestamps=log.timestamps, line_numbers=log.line_numbers,
        stated_angles=carmen.LaserAngles(start_angle=-math.pi / 2, fov=math.pi,
                                         resolution=math.pi / 179, max_range=50.0),
        parameters={})
    folder = tmp_path_factory.mktemp('graph')
    g2o.write_g2o(folder / 'intel30.g2o', g2o.G2oGraph(
        graph=graph, vertex_ids=np.arange(GRAPH_SCANS) * 10, laser=laser,
        laser_vertices=np.arange(GRAPH_SCANS)))
    assert main(['convert', str(folder / 'intel30.g2o'), str(folder / 'bag'), '--quiet']) == 0
    with BagReader([folder / 'bag']) as bag:
        records = [record for _, record in bag.records()]
    return folder, log, records


def test_graph_scans_and_trajectory(graph_bag):
    _, log, records = graph_bag
    scans = [record for record in records if isinstance(record, Scan)]
    paths = [record for record in records if isinstance(record, KeyframeEstimate)]
    np.testing.assert_array_equal(np.array([scan.ranges for scan in scans]),
                                  log.ranges.astype(np.float32))
    assert scans[0].model.angle_increment == pytest.approx(math.pi / 179, rel=1e-7)
    assert scans[0].model.max_range == 50.0  # the sensor maximum the records state
    # Vertex pose (+) laser offset gives back the laser poses the graph was built from.
    np.testing.assert_allclose(paths[-1].poses, log.laser_poses, atol=1e-9)
    np.testing.assert_allclose(paths[-1].stamps, log.timestamps, atol=1e-6)


def test_graph_constraints_after_each_loop_closure(graph_bag):
    _, log, records = graph_bag
    edges = [record.rows for record in records if isinstance(record, Constraints)]
    # Published when a loop closure arrives (keyframes 20 and 25) and after the last.
    assert [rows.shape[0] for rows in edges] == [21, 27, 31]
    loop = edges[0][-1]
    np.testing.assert_allclose(loop[:2], log.timestamps[[5, 20]], atol=1e-6)
    np.testing.assert_allclose(loop[5:], [100.0, 0, 0, 100.0, 0, 400.0])


def test_graph_replays_like_the_batch_test(strict_json, graph_bag):
    from map_consistency_ros.core.consistency import check_consistency
    from map_consistency_ros.core.geometry import ScanSet, SensorModel
    folder, log, _ = graph_bag
    assert main(['replay', str(folder / 'bag'), '--quiet', '--report',
                 str(folder / 'r.json')]) in (0, 1)
    report = strict_json((folder / 'r.json').read_text())
    model = SensorModel(angle_min=-math.pi / 2, angle_increment=math.pi / 179, max_range=8.0)
    batch = check_consistency(ScanSet.from_ranges(log.ranges, log.laser_poses, model))
    assert report['summary']['tested_pairs'] == batch.tested_pair_count
    assert report['inconsistent_scans'] == batch.inconsistent_scans.tolist()
    assert report['replay']['constraint_rows'] == 31


def test_graph_without_scans(shared_data, tmp_path, capsys):
    assert main(['convert', str(shared_data / 'posegraphs_vertigo' / 'ring.g2o'),
                 str(tmp_path / 'ring'), '--quiet']) == 2
    assert 'carries no laser data' in capsys.readouterr().err
