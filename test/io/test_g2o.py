"""g2o files: reading against GTSAM's reader, round trips with laser data, malformed lines."""
import gtsam
import numpy as np
import pytest

from map_consistency_ros.core.backend import PoseGraph
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io.carmen import CarmenLog, LaserAngles
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.g2o import G2oGraph, read_g2o, write_g2o


def test_vertigo_ring_reads_as_gtsam_reads_it(shared_data):
    path = shared_data / 'posegraphs_vertigo' / 'ring.g2o'
    content = read_g2o(path)
    graph = content.graph
    factors, values = gtsam.readG2o(str(path), False)
    assert graph.vertex_count == values.size() == 434
    assert graph.edge_count == factors.size() == 459
    for index in (0, 17, 433):
        pose = values.atPose2(index)
        np.testing.assert_allclose(graph.poses[index, :2], [pose.x(), pose.y()], atol=1e-12)
        assert se2.wrap_angle(graph.poses[index, 2] - pose.theta()) == pytest.approx(0, abs=1e-12)
    for k in (0, 100, 458):
        factor = factors.at(k)
        assert list(factor.keys()) == [graph.edge_from[k], graph.edge_to[k]]
        measured = factor.measured()
        np.testing.assert_allclose(graph.measurements[k, :2], [measured.x(), measured.y()],
                                   atol=1e-12)
        assert se2.wrap_angle(graph.measurements[k, 2] - measured.theta()) == pytest.approx(
            0, abs=1e-12)
        covariance = factor.noiseModel().covariance()
        np.testing.assert_allclose(np.linalg.inv(graph.information[k]), covariance, rtol=1e-9)
    assert graph.is_loop_closure.sum() == 26
    assert content.laser is None


def test_bicocca_edges_pointing_backwards_keep_their_direction(shared_data):
    graph = read_g2o(shared_data / 'bicocca_rrr' / 'B25b_0.500.g2o').graph
    loop = graph.is_loop_closure
    assert loop.sum() == 122
    first = np.flatnonzero(loop)[0]
    assert (graph.edge_from[first], graph.edge_to[first]) == (2482, 1971)


def _content_with_laser(fixed_first: bool = True) -> G2oGraph:
    rng = np.random.default_rng(5)
    poses = np.column_stack([rng.normal(0, 2, (5, 2)), rng.uniform(-3, 3, 5)])
    graph = PoseGraph(poses=poses, edge_from=[0, 1, 2, 3, 0], edge_to=[1, 2, 3, 4, 4],
                      measurements=rng.normal(0, 1, (5, 3)),
                      information=np.repeat(np.diag([20.0, 30.0, 400.0])[None], 5, axis=0)
                      + np.array([[0, 1.5, 0.5], [1.5, 0, 0.25], [0.5, 0.25, 0]]),
                      fixed=[fixed_first, False, False, False, False])
    offset = np.array([0.1, -0.05, 0.2])
    laser = CarmenLog(path='memory', ranges=np.round(rng.uniform(0.5, 9.0, (5, 7)), 3),
                      laser_poses=se2.compose(poses, offset), robot_poses=poses,
                      timestamps=np.arange(5) * 0.5 + 100.0, line_numbers=np.arange(5),
                      stated_angles=LaserAngles(start_angle=-1.5, fov=3.0, resolution=0.5,
                                                max_range=80.0),
                      parameters={})
    return G2oGraph(graph=graph, vertex_ids=np.array([10, 11, 12, 13, 14]), laser=laser,
                    laser_vertices=np.arange(5))


def test_round_trip_keeps_graph_ids_fix_and_laser(tmp_path):
    content = _content_with_laser()
    path = tmp_path / 'graph.g2o'
    write_g2o(path, content)
    back = read_g2o(path)
    for name in ('poses', 'measurements', 'information'):
        np.testing.assert_allclose(getattr(back.graph, name), getattr(content.graph, name),
                                   atol=1e-12)
    np.testing.assert_array_equal(back.graph.edge_from, content.graph.edge_from)
    np.testing.assert_array_equal(back.graph.fixed, content.graph.fixed)
    np.testing.assert_array_equal(back.vertex_ids, content.vertex_ids)
    np.testing.assert_array_equal(back.scan_ranges(), content.laser.ranges)
    np.testing.assert_allclose(back.laser_offset, [0.1, -0.05, 0.2], atol=1e-12)
    assert back.laser.stated_angles == content.laser.stated_angles
    np.testing.assert_allclose(back.laser.timestamps, content.laser.timestamps)


def _write(tmp_path, text: str):
    path = tmp_path / 'bad.g2o'
    path.write_text(text)
    return path


GOOD = 'VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n'
EDGE = 'EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n'


def laser_line(beams: int = 4, laser_x: float = 0.0) -> str:
    """A ROBOTLASER1 record: beams 1..K, no remissions, laser pose (laser_x, 0, 0), robot at 0."""
    ranges = ' '.join(str(value) for value in range(1, beams + 1))
    return (f'ROBOTLASER1 0 -1.5 3 1 8 0.01 0 {beams} {ranges} 0 {laser_x} 0 0 0 0 0 '
            f'0 0 0 0 0 1.0 host 1.0\n')


LASER = laser_line()


@pytest.mark.parametrize('text, message, line', [
    (GOOD + 'VERTEX_XY 2 0 0\n', "unsupported record 'VERTEX_XY'", 3),
    (GOOD + 'EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n', 'EDGE_SE2 needs 11 fields, got 10', 3),
    ('VERTEX_SE2 0 0 zero 0\n', "non-numeric pose value 'zero'", 1),
    ('VERTEX_SE2 a 0 0 0\n', "vertex id must be an integer, got 'a'", 1),
    ('VERTEX_SE2 0 0 nan 0\n', 'vertex pose y nan is not finite', 1),
    (GOOD + 'VERTEX_SE2 2 0 0 1e200\n', r'vertex pose theta 1e\+200 is beyond 1000 rad', 3),
    (GOOD + 'VERTEX_SE2 2 -3e6 0 0\n', 'vertex pose x -3000000.0 is beyond', 3),
    ('VERTEX_SE2 0 0 0 0\n' + laser_line(laser_x='1e300'), r'laser pose x 1e\+300 is beyond', 2),
    (GOOD + 'EDGE_SE2 0 1 inf 0 0 1 0 0 1 0 1\n', 'edge value is not finite', 3),
    (GOOD + 'VERTEX_SE2 1 0 0 0\n', 'vertex 1 defined twice', 3),
    (GOOD + 'EDGE_SE2 0 5 1 0 0 1 0 0 1 0 1\n', 'unknown vertex 5', 3),
    (GOOD + 'FIX 7\n', 'unknown vertex 7', 3),
    (GOOD + 'FIX\n', 'FIX names no vertex', 3),
    (GOOD + 'EDGE_SE2 0 0 1 0 0 1 0 0 1 0 1\n', 'connects vertex 0 to itself', 3),
    (GOOD + 'EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n', 'not positive definite', 3),
    (GOOD + 'EDGE_SE2 0 1 1 0 0 1e300 0 0 1e300 0 1\n', r'information entries beyond 1e\+12', 3),
    (GOOD + 'EDGE_SE2 0 1 1e300 0 0 1 0 0 1 0 1\n', 'measurement beyond 100000', 3),
    (LASER + GOOD, 'ROBOTLASER1 before any VERTEX_SE2', 1),
    (GOOD + 'ROBOTLASER1 0 -1.5 3 1 8 0.01 0 4 1 2\n', 'truncated ROBOTLASER1', 3),
    ('# only a comment\n', 'no VERTEX_SE2 records', None),
])
def test_malformed_files_name_file_and_line(tmp_path, text, message, line):
    path = _write(tmp_path, text)
    with pytest.raises(InputError, match=message) as error:
        read_g2o(path)
    assert error.value.line == line
    assert str(path) in str(error.value)


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match='no such file'):
        read_g2o(tmp_path / 'absent.g2o')


def test_laser_records_must_cover_every_vertex_once_and_agree(tmp_path):
    partial = read_g2o(_write(tmp_path, 'VERTEX_SE2 0 0 0 0\n' + LASER + 'VERTEX_SE2 1 1 0 0\n'))
    with pytest.raises(InputError, match='vertex 1 has 0 laser scans'):
        partial.scan_ranges()
    no_laser = read_g2o(_write(tmp_path, GOOD + EDGE))
    with pytest.raises(InputError, match='no laser data'):
        no_laser.scan_ranges()
    short = laser_line(beams=3)
    with pytest.raises(InputError, match='3 beams, but the first laser record has 4'):
        read_g2o(_write(tmp_path, 'VERTEX_SE2 0 0 0 0\n' + LASER + 'VERTEX_SE2 1 1 0 0\n' + short))
    moved = laser_line(laser_x=0.5)
    varying = read_g2o(_write(tmp_path, 'VERTEX_SE2 0 0 0 0\n' + LASER
                              + 'VERTEX_SE2 1 1 0 0\n' + moved))
    with pytest.raises(InputError, match='laser offset from the robot varies'):
        varying.laser_offset
