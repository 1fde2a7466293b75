"""PoseGraph: validation, the odometry / loop-closure split and the odometry chain."""
import re

import numpy as np
import pytest

from map_consistency_ros.core.backend import PoseGraph
from map_consistency_ros.core.geometry import se2


def _graph(**overrides) -> PoseGraph:
    fields = dict(
        poses=np.zeros((4, 3)),
        edge_from=[0, 1, 3, 0], edge_to=[1, 2, 2, 3],
        measurements=[[1.0, 0.0, 0.5], [1.0, 0.2, -0.3], [0.5, -0.5, 1.0], [2.0, 1.0, 0.0]],
        information=np.repeat(np.eye(3)[None], 4, axis=0))
    fields.update(overrides)
    return PoseGraph(**fields)


def test_loop_closures_are_the_non_consecutive_edges():
    graph = _graph()
    assert graph.is_loop_closure.tolist() == [False, False, False, True]
    assert graph.vertex_count == 4 and graph.edge_count == 4
    assert not graph.fixed.any()


def test_odometry_chain_composes_forward_and_inverted_backward_edges():
    start = np.array([1.0, -2.0, 0.3])
    graph = _graph(poses=np.vstack([start, np.ones((3, 3))]))
    measurements = np.asarray(graph.measurements)
    chain = graph.odometry_chain()
    # Written out by hand: 0 -> 1 -> 2 along edges 0 and 1, then 2 -> 3 is edge 3 -> 2 inverted.
    expected_1 = se2.compose(start, measurements[0])
    expected_2 = se2.compose(expected_1, measurements[1])
    expected_3 = se2.compose(expected_2, se2.inverse(measurements[2]))
    np.testing.assert_allclose(chain, np.stack([start, expected_1, expected_2, expected_3]),
                               atol=1e-12)


def test_odometry_chain_keeps_the_estimate_where_odometry_is_missing():
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [2.0, 1.0, 1.0]])
    graph = PoseGraph(poses=poses, edge_from=[0], edge_to=[2], measurements=[[0.0, 0.0, 0.0]],
                      information=[np.eye(3)])
    np.testing.assert_allclose(graph.odometry_chain(), poses, atol=1e-12)


def test_arrays_are_read_only_and_with_poses_swaps_the_estimate():
    graph = _graph()
    with pytest.raises(ValueError):
        graph.poses[0, 0] = 1.0
    moved = graph.with_poses(np.ones((4, 3)))
    assert np.all(moved.poses == 1.0) and moved.edge_count == graph.edge_count


@pytest.mark.parametrize('overrides, message', [
    (dict(poses=np.zeros((4, 2))), 'poses has shape'),
    (dict(poses=np.full((4, 3), np.nan)), 'NaN'),
    (dict(edge_to=[1, 2, 2]), 'edge sources'),
    (dict(edge_to=[1, 2, 2, 7]), 'outside'),
    (dict(edge_to=[0, 2, 2, 3]), 'to itself'),
    (dict(information=np.repeat(np.triu(np.ones((3, 3)))[None], 4, axis=0)), 'not symmetric'),
    (dict(information=np.repeat(-np.eye(3)[None], 4, axis=0)), 'positive definite'),
    (dict(measurements=np.zeros((3, 3))), 'measurements has shape'),
    (dict(fixed=[True, False]), 'fixed has'),
])
def test_malformed_graphs_are_refused(overrides, message):
    with pytest.raises(ValueError, match=message):
        _graph(**overrides)


def test_odometry_chain_follows_the_first_of_parallel_sequential_edges():
    first, second = [1.0, 0.0, 0.0], [5.0, 5.0, 1.0]
    graph = PoseGraph(poses=np.zeros((2, 3)), edge_from=[0, 0, 1], edge_to=[1, 1, 0],
                      measurements=[first, second, second], information=[np.eye(3)] * 3)
    np.testing.assert_allclose(graph.odometry_chain()[1], first, atol=1e-12)


def test_graphs_that_cannot_be_tuned_honestly_are_named():
    from map_consistency_ros.core.backend import tuning_problem
    assert tuning_problem(_graph()) is None
    sparse = _graph(edge_from=[0, 2], edge_to=[1, 3], measurements=np.zeros((2, 3)),
                    information=np.repeat(np.eye(3)[None], 2, axis=0))
    assert '2 constraints for 4 poses' in tuning_problem(sparse)
    split = _graph(edge_from=[0, 1, 0], edge_to=[1, 0, 2], measurements=np.zeros((3, 3)),
                   information=np.repeat(np.eye(3)[None], 3, axis=0),
                   poses=np.zeros((4, 3)))
    assert 'disconnected parts' in tuning_problem(split)
    chain = _graph(edge_from=[0, 1, 2], edge_to=[1, 2, 3], measurements=np.zeros((3, 3)),
                   information=np.repeat(np.eye(3)[None], 3, axis=0))
    assert 'no loop closure' in tuning_problem(chain)
    huge = _graph(information=np.repeat(1e300 * np.eye(3)[None], 4, axis=0))
    assert 'edge 0 (pose 0 to 1) has information entries beyond' in tuning_problem(huge)
    far = _graph(poses=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1e300, 0.0, 0.0],
                                 [3.0, 0.0, 0.0]]))
    assert 'pose 2 of 4 (1e+300, 0, 0) lies beyond 100000' in tuning_problem(far)
    assert tuning_problem(far, extent=1e301) is None  # the node's own max_pose_extent
    measured = np.zeros((4, 3))
    measured[3] = [0.0, 1e300, 0.0]
    assert 'edge 3 (pose 0 to 3) has a measurement beyond' in tuning_problem(
        _graph(measurements=measured))


@pytest.mark.parametrize('edge, change, reason', [
    (1, ('measurement', (0, 2), np.inf), 'non-finite values'),
    (2, ('information', (0, 0), np.nan), 'non-finite values'),
    (1, ('measurement', (0, 0), 2e5), 'measurement beyond 100000'),
    (0, ('information', (1, 1), 2e12), r'information entries beyond 1e\+12'),
    (2, ('information', (2, 2), -1.0), 'information matrix that is not positive definite'),
    (1, ('information', (0, 1), 5.0), 'information matrix that is not symmetric'),
])
def test_edge_problem_names_the_first_edge_no_solve_can_take(edge, change, reason):
    from map_consistency_ros.core.backend import edge_problem
    measurements, information = np.zeros((3, 3)), np.repeat(np.eye(3)[None], 3, axis=0)
    assert edge_problem(measurements, information) is None
    name, index, value = change
    target = measurements[edge] if name == 'measurement' else information[edge]
    target[index[1] if name == 'measurement' else index] = value
    found = edge_problem(measurements, information)
    assert found[0] == edge
    assert re.search(reason, found[1])


def test_constraint_rows_round_trip_and_refusals():
    from map_consistency_ros.core.backend import (check_constraint_rows, constraint_rows,
                                                  split_constraint_rows)
    information = np.array([[[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 9.0]]] * 2)
    measurements = np.array([[1.0, 2.0, 0.3], [0.0, -1.0, 3.0]])
    rows = constraint_rows(np.array([1.0, 2.0]), np.array([2.0, 5.0]), measurements,
                           information)
    assert rows[0].tolist() == [1.0, 2.0, 1.0, 2.0, 0.3, 4.0, 1.0, 0.5, 3.0, 0.2, 9.0]
    stamp_from, stamp_to, back_measurements, back_information = split_constraint_rows(
        check_constraint_rows(rows))
    np.testing.assert_array_equal(back_information, information)
    np.testing.assert_array_equal(back_measurements, measurements)
    assert stamp_to.tolist() == [2.0, 5.0] and stamp_from.tolist() == [1.0, 2.0]
    for change, message in (((0, 1), 'to itself'), ((0, 5), 'not positive definite'),
                            ((1, 7), r'row 1 has information entries beyond 1e\+12'),
                            ((1, 3), 'row 1 has a measurement beyond 100000')):
        bad = rows.copy()
        bad[change] = {1: 1.0, 5: -4.0, 7: 1e300, 3: 1e300}[change[1]]
        with pytest.raises(ValueError, match=message):
            check_constraint_rows(bad)
    with pytest.raises(ValueError, match=r'shape \(E, 11\)'):
        check_constraint_rows(rows[:, :10])
