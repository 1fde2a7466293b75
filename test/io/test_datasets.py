"""Dataset builder on the real Intel and Freiburg 079 data: scan pairing, edges, bad input."""
import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io.carmen import read_carmen_log
from map_consistency_ros.io.datasets import (BuildSettings, build_dataset, build_graph,
                                             match_scans, read_raw_bag, read_relations)
from map_consistency_ros.io.errors import InputError

# Data README: raw bag stamp - corrected-log timestamp on Intel.
INTEL_CLOCK_OFFSET = 976052857.337
FALSE_LOOPS = 30


def intel_paths(shared_data):
    intel = shared_data / 'intel'
    return intel / 'intel.gfs.log', intel / 'intel.relations', intel / 'intel.orig.bag'


@pytest.fixture(scope='module')
def intel_inputs(shared_data):
    """The corrected log, relations and raw bag, read once."""
    log_path, relations_path, bag_path = intel_paths(shared_data)
    return read_carmen_log(log_path), read_relations(relations_path), read_raw_bag(bag_path)


@pytest.fixture(scope='module')
def intel(intel_inputs):
    return build_graph(*intel_inputs, BuildSettings(false_loop_closures=FALSE_LOOPS, seed=7))


def test_every_corrected_scan_pairs_with_an_identical_raw_scan_at_the_known_offset(
        intel_inputs):
    log, _, bag = intel_inputs
    matched = match_scans(log, bag)
    assert len(matched) == log.scan_count == 910
    assert len(np.unique(matched)) == 910
    np.testing.assert_array_equal(bag.scan_ranges[matched], log.ranges.astype(np.float32))
    # The log's own timestamps step back in a few places; the pairing follows the ranges.
    np.testing.assert_allclose(bag.scan_stamps[matched] - log.timestamps, INTEL_CLOCK_OFFSET,
                               atol=0.01)


def test_intel_graph_structure(intel):
    graph = intel.graph
    loop = graph.is_loop_closure
    assert graph.vertex_count == 910
    np.testing.assert_array_equal(graph.edge_to[:909], graph.edge_from[:909] + 1)
    assert (~loop).sum() > 909  # relations between neighbouring scans add sequential edges
    assert loop.sum() > 300 + FALSE_LOOPS
    assert graph.fixed.tolist() == [True] + [False] * 909
    pairs = np.sort(np.stack([graph.edge_from, graph.edge_to], axis=1)[loop], axis=1)
    assert len(np.unique(pairs, axis=0)) >= loop.sum() - FALSE_LOOPS
    np.testing.assert_array_equal(intel.scan_ranges(), read_carmen_log(intel.laser.path).ranges)
    np.testing.assert_allclose(intel.laser_offset, 0.0, atol=1e-12)


def test_true_edges_agree_with_the_independent_corrected_trajectory(intel):
    """GMapping's corrected poses were estimated without the relations or this graph."""
    graph = intel.graph
    true_edges = slice(0, graph.edge_count - FALSE_LOOPS)
    corrected = se2.relative(graph.poses[graph.edge_from[true_edges]],
                             graph.poses[graph.edge_to[true_edges]])
    difference = se2.relative(graph.measurements[true_edges], corrected)
    loop = graph.is_loop_closure[true_edges]
    for edges in (loop, ~loop):
        assert np.median(np.hypot(difference[edges, 0], difference[edges, 1])) < 0.08
        assert np.median(np.abs(difference[edges, 2])) < 0.05


def test_false_loop_closures_are_random_non_neighbours_reproducible_by_seed(intel_inputs, intel):
    graph = intel.graph
    false = slice(graph.edge_count - FALSE_LOOPS, None)
    assert np.all(np.abs(graph.edge_from[false] - graph.edge_to[false]) > 1)
    corrected = se2.relative(graph.poses[graph.edge_from[false]], graph.poses[graph.edge_to[false]])
    wrong = np.hypot(*(corrected[:, :2] - graph.measurements[false, :2]).T)
    assert np.median(wrong) > 1.0
    settings = BuildSettings(stride=10, false_loop_closures=5, seed=7, corrupt_guess=True)
    again = build_graph(*intel_inputs, settings)
    same = build_graph(*intel_inputs, settings)
    np.testing.assert_array_equal(again.graph.poses, same.graph.poses)
    np.testing.assert_array_equal(again.graph.edge_to, same.graph.edge_to)
    assert again.graph.vertex_count == 91


def test_corrupted_guess_moves_the_poses_but_not_the_edges(intel_inputs):
    settings = dict(stride=10, seed=1)
    clean = build_graph(*intel_inputs, BuildSettings(**settings)).graph
    noisy = build_graph(*intel_inputs, BuildSettings(corrupt_guess=True, **settings)).graph
    np.testing.assert_array_equal(noisy.measurements, clean.measurements)
    np.testing.assert_array_equal(noisy.poses[0], clean.poses[0])
    drift = np.hypot(*(noisy.poses[:, :2] - clean.poses[:, :2]).T)
    assert drift[-1] > 0.1 and drift.max() < 50.0


def test_freiburg_079_pairs_by_ranges_and_carries_the_laser_mounting(shared_data):
    fr079 = shared_data / 'fr079'
    content = build_dataset(fr079 / 'freiburg-079-corrected.log.gz', fr079 / 'fr079.relations',
                            fr079 / 'fr079.orig.bag', BuildSettings(stride=20))
    assert content.graph.vertex_count == 240
    assert content.graph.is_loop_closure.sum() > 100
    np.testing.assert_allclose(content.laser_offset, [0.04, 0.0, 0.0], atol=1e-9)
    assert content.laser.ranges.shape == (240, 360)


def _write(tmp_path, text: str, name: str = 'bad.relations'):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize('text, message, line', [
    ('1 2 0 0 0 0 0\n', 'a relation has 8 fields', 1),
    ('1 2 0 0 0 0 0 0\n1 2 x 0 0 0 0 0\n', 'non-numeric relation field', 2),
    ('1 2 0 nan 0 0 0 0\n', 'relation y nan is not finite', 1),
    ('1 2 0 0 0 0 0 1e200\n', r'relation yaw 1e\+200 is beyond 1000 rad', 1),
    ('1 2 0 0 0 0 0 0\n-1 2 0 0 0 0 0 0\n', 'relation t1 -1.0 is negative', 2),
    ('# nothing\n', 'no relations found', None),
])
def test_malformed_relations_name_file_and_line(tmp_path, text, message, line):
    with pytest.raises(InputError, match=message) as error:
        read_relations(_write(tmp_path, text))
    assert error.value.line == line


def test_relations_are_read_as_t1_t2_x_y_yaw(shared_data):
    rows = read_relations(shared_data / 'intel' / 'intel.relations')
    assert rows.shape == (2984, 5)
    np.testing.assert_allclose(rows[0], [976052905.167303, 976052911.885496, -0.056990,
                                         -0.128430, -1.682210])


def test_missing_and_unreadable_inputs(tmp_path, shared_data):
    with pytest.raises(InputError, match='no such file'):
        read_relations(tmp_path / 'absent.relations')
    with pytest.raises(InputError, match='no such file'):
        read_raw_bag(tmp_path / 'absent.bag')
    with pytest.raises(InputError, match='cannot read the bag'):
        read_raw_bag(_write(tmp_path, 'not a bag', 'fake.bag'))
    with pytest.raises(InputError, match='cannot read the bag'):
        read_raw_bag(shared_data / 'ros1_native' / 'ccny_laser_scan_matcher_demo.bag')
    with pytest.raises(InputError, match='needs /scan and /odom'):
        read_raw_bag(_bag_without_odometry(tmp_path / 'chatter'))


def _bag_without_odometry(path):
    """A rosbag2 holding one std_msgs/String on /chatter."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    message = typestore.types['std_msgs/msg/String'](data='hello')
    with Writer(path, version=9) as writer:
        connection = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=typestore)
        writer.write(connection, 1, typestore.serialize_cdr(message, 'std_msgs/msg/String'))
    return path


def test_a_scan_without_raw_twin_or_other_beam_count_is_refused(intel_inputs, tmp_path):
    log, _, bag = intel_inputs
    lines = open(log.path).read().splitlines(keepends=True)
    changed_line = int(log.line_numbers[3])
    tokens = lines[changed_line - 1].split()
    tokens[5] = '12.345'
    lines[changed_line - 1] = ' '.join(tokens) + '\n'
    altered = read_carmen_log(_write(tmp_path, ''.join(lines), 'altered.log'))
    with pytest.raises(InputError, match='no raw scan in the bag has these ranges') as error:
        match_scans(altered, bag)
    assert error.value.line == changed_line
    fewer = read_carmen_log(_write(tmp_path, 'FLASER 3 1 1 1 0 0 0 0 0 0 1.0 host 1.0\n',
                                   'short.log'))
    with pytest.raises(InputError, match='3 beams per scan'):
        match_scans(fewer, bag)


@pytest.mark.parametrize('settings', [dict(stride=0), dict(false_loop_closures=-1)])
def test_invalid_settings_are_refused(settings):
    with pytest.raises(ValueError):
        BuildSettings(**settings)
