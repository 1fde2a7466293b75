"""DCS optimizer: Jacobians against finite differences, residuals and solutions against GTSAM.

GTSAM (PyPI gtsam==4.3.0, a test-only extra) is the independent oracle: BetweenFactor<Pose2>
with noiseModel.Robust(mEstimator.DCS(c = Phi)) on loop closures, the first pose held by
NonlinearEquality, Levenberg-Marquardt with relative / absolute error tolerances of 1e-15 and
lambda bound 1e12. Both solvers then agree on the poses to 1e-6 (metres and radians) and on
the cost to 1e-9, except where the cost is flat (see the Phi = 1 test on Intel).
"""
import gtsam
import numpy as np
import pytest

from map_consistency_ros.core.backend import (PoseGraph, SparseSystem, dcs_scales, edge_residuals,
                                              optimize, robust_cost)
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io.datasets import BuildSettings, build_dataset
from map_consistency_ros.io.g2o import read_g2o

POSE_TOLERANCE = 1e-6
FALSE_LOOPS = 50


def gtsam_problem(graph: PoseGraph, phi: float | None):
    """The same problem in GTSAM: factor graph and initial values."""
    factors = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for index, pose in enumerate(graph.poses):
        values.insert(index, gtsam.Pose2(*pose))
    factors.add(gtsam.NonlinearEqualityPose2(0, gtsam.Pose2(*graph.poses[0])))
    for k in range(graph.edge_count):
        noise = gtsam.noiseModel.Gaussian.Information(graph.information[k])
        if graph.is_loop_closure[k] and phi is not None:
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.DCS.Create(phi),
                                                   noise)
        factors.add(gtsam.BetweenFactorPose2(int(graph.edge_from[k]), int(graph.edge_to[k]),
                                             gtsam.Pose2(*graph.measurements[k]), noise))
    return factors, values


def gtsam_optimize(graph: PoseGraph, phi: float | None) -> tuple[np.ndarray, float]:
    factors, values = gtsam_problem(graph, phi)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-15)
    params.setAbsoluteErrorTol(1e-15)
    params.setMaxIterations(1000)
    params.setlambdaUpperBound(1e12)
    result = gtsam.LevenbergMarquardtOptimizer(factors, values, params).optimize()
    poses = np.array([[result.atPose2(i).x(), result.atPose2(i).y(), result.atPose2(i).theta()]
                      for i in range(graph.vertex_count)])
    return poses, factors.error(result)


def pose_difference(a: np.ndarray, b: np.ndarray) -> float:
    difference = a - b
    difference[:, 2] = se2.wrap_angle(difference[:, 2])
    return float(np.abs(difference).max())


@pytest.fixture(scope='module')
def intel_graph(shared_data) -> PoseGraph:
    """The Intel graph built from the corrected log, relations and raw bag, with false loops."""
    intel = shared_data / 'intel'
    return build_dataset(intel / 'intel.gfs.log', intel / 'intel.relations',
                         intel / 'intel.orig.bag',
                         BuildSettings(false_loop_closures=FALSE_LOOPS, seed=3)).graph


def _random_graph(seed: int, count: int = 6) -> PoseGraph:
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.normal(0, 3, (count, 2)), rng.uniform(-np.pi, np.pi, count)])
    edge_from = np.array([0, 1, 2, 3, 4, 0, 5, 1])
    edge_to = np.array([1, 2, 3, 4, 5, 3, 2, 4])
    measurements = np.column_stack([rng.normal(0, 2, (8, 2)), rng.uniform(-3, 3, 8)])
    root = rng.normal(0, 1, (8, 3, 3))
    information = root @ np.swapaxes(root, 1, 2) + np.eye(3)
    return PoseGraph(poses, edge_from, edge_to, measurements, information)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_residuals_match_gtsam_between_factors(seed):
    graph = _random_graph(seed)
    errors, chi2, _, _ = edge_residuals(graph)
    factors, values = gtsam_problem(graph, None)
    for k in range(graph.edge_count):
        factor = factors.at(k + 1)  # factor 0 is the gauge
        np.testing.assert_allclose(errors[k], factor.unwhitenedError(values), atol=1e-12)
        np.testing.assert_allclose(chi2[k], 2.0 * factor.error(values), rtol=1e-10)


@pytest.mark.parametrize('seed', [0, 1])
def test_jacobians_match_finite_differences_of_right_perturbations(seed):
    graph = _random_graph(seed)
    errors, _, jac_from, jac_to = edge_residuals(graph)
    step = 1e-7
    for vertex_of, jacobians in ((graph.edge_from, jac_from), (graph.edge_to, jac_to)):
        for axis in range(3):
            delta = np.zeros(3)
            delta[axis] = step
            for k in range(graph.edge_count):
                poses = graph.poses.copy()
                poses[vertex_of[k]] = se2.compose(poses[vertex_of[k]], delta)
                moved = edge_residuals(graph, poses)[0][k]
                numeric = (moved - errors[k]) / step
                numeric[2] = se2.wrap_angle(moved[2] - errors[k][2]) / step
                np.testing.assert_allclose(jacobians[k][:, axis], numeric, atol=2e-5)


def test_dcs_scales_and_cost_match_the_definitions_and_gtsam():
    chi2 = np.array([0.0, 0.5, 1.0, 3.0, 100.0])
    phi = 1.0
    expected = np.array([1.0, 1.0, 1.0, 2.0 / 4.0, 2.0 / 101.0])
    np.testing.assert_allclose(dcs_scales(chi2, phi), expected)
    np.testing.assert_allclose(dcs_scales(chi2, None), 1.0)
    estimator = gtsam.noiseModel.mEstimator.DCS.Create(phi)
    loss = sum(estimator.loss(np.sqrt(value)) for value in chi2)
    np.testing.assert_allclose(robust_cost(chi2, np.ones(5, bool), phi), 2.0 * loss)
    for value in chi2:
        assert estimator.weight(np.sqrt(value)) == pytest.approx(dcs_scales(value, phi) ** 2)


@pytest.mark.parametrize('name, phi', [('ring.g2o', 1.0), ('manhattanOlson3500.g2o', 1.0)])
def test_vertigo_graphs_agree_with_gtsam(shared_data, name, phi):
    graph = read_g2o(shared_data / 'posegraphs_vertigo' / name).graph
    ours = optimize(graph, phi, iterations=200)
    reference, reference_error = gtsam_optimize(graph, phi)
    assert ours.converged
    assert pose_difference(ours.poses, reference) < POSE_TOLERANCE
    assert ours.cost == pytest.approx(2.0 * reference_error, rel=1e-9)


def _without_false_loops(graph: PoseGraph) -> PoseGraph:
    keep = slice(0, graph.edge_count - FALSE_LOOPS)  # the builder appends them last
    return PoseGraph(graph.poses, graph.edge_from[keep], graph.edge_to[keep],
                     graph.measurements[keep], graph.information[keep], graph.fixed)


@pytest.mark.parametrize('false_loops, phi', [(True, 5.0), (False, 5.0), (False, None)])
def test_built_intel_graph_agrees_with_gtsam(intel_graph, false_loops, phi):
    graph = intel_graph if false_loops else _without_false_loops(intel_graph)
    ours = optimize(graph, phi, iterations=300)
    reference, reference_error = gtsam_optimize(graph, phi)
    assert ours.converged
    assert pose_difference(ours.poses, reference) < POSE_TOLERANCE
    assert ours.cost == pytest.approx(2.0 * reference_error, rel=1e-9)


def test_gtsams_stopping_rule_stops_as_close_to_the_optimum_as_gtsam(intel_graph):
    """With GTSAM's relative error decrease criterion (1e-10 on both sides) both solvers stop
    about 2e-6 short of the optimum (GTSAM at tolerances of 1e-15): ours no further than GTSAM,
    in fewer iterations than by the step criterion, on the same cost to 1e-9."""
    optimum, _ = gtsam_optimize(intel_graph, 5.0)
    factors, values = gtsam_problem(intel_graph, 5.0)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(300)
    solution = gtsam.LevenbergMarquardtOptimizer(factors, values, params).optimize()
    theirs = np.array([[solution.atPose2(i).x(), solution.atPose2(i).y(),
                        solution.atPose2(i).theta()] for i in range(intel_graph.vertex_count)])
    ours = optimize(intel_graph, 5.0, iterations=300, relative_tolerance=1e-10)
    by_step = optimize(intel_graph, 5.0, iterations=300)
    assert ours.converged and ours.iterations < by_step.iterations
    assert pose_difference(ours.poses, optimum) <= 1.5 * pose_difference(theirs, optimum)
    assert pose_difference(ours.poses, theirs) < 1e-5
    assert ours.cost == pytest.approx(2.0 * factors.error(solution), rel=1e-9)


@pytest.fixture(scope='module')
def fr079_graph(shared_data) -> PoseGraph:
    """The Freiburg 079 graph (every 5th scan) built from the corrected log, relations and bag."""
    fr079 = shared_data / 'fr079'
    return build_dataset(fr079 / 'freiburg-079-corrected.log.gz', fr079 / 'fr079.relations',
                         fr079 / 'fr079.orig.bag',
                         BuildSettings(stride=5, false_loop_closures=FALSE_LOOPS, seed=3)).graph


@pytest.mark.parametrize('false_loops, phi', [(True, 5.0), (False, None)])
def test_built_fr079_graph_reaches_gtsams_optimum(fr079_graph, false_loops, phi):
    """On this graph GTSAM's Levenberg-Marquardt stops early (its damping runs into the upper
    bound after a few iterations), 2e-5 to 5e-4 from our solution. GTSAM's own error function
    is lower at our solution than at its own, and our solver started from GTSAM's solution
    returns to ours: we reach the optimum GTSAM approaches."""
    graph = fr079_graph if false_loops else _without_false_loops(fr079_graph)
    ours = optimize(graph, phi, iterations=300)
    reference, reference_error = gtsam_optimize(graph, phi)
    factors, _ = gtsam_problem(graph, phi)
    at_ours = gtsam.Values()
    for index, pose in enumerate(ours.poses):
        at_ours.insert(index, gtsam.Pose2(*pose))
    assert ours.converged
    assert factors.error(at_ours) <= reference_error
    assert ours.cost == pytest.approx(2.0 * factors.error(at_ours), rel=1e-12)
    assert pose_difference(ours.poses, reference) < 1e-3
    restarted = optimize(graph.with_poses(reference), phi, iterations=300)
    assert pose_difference(restarted.poses, ours.poses) < POSE_TOLERANCE


def test_built_intel_graph_at_phi_1_agrees_with_gtsam_as_far_as_the_cost_resolves(intel_graph):
    """At Phi = 1 many loop closures weigh ~1e-6: the robust cost is flat to 1e-9 along
    directions where the two solvers' stopping points still differ by ~1e-5."""
    ours = optimize(intel_graph, 1.0, iterations=500)
    reference, reference_error = gtsam_optimize(intel_graph, 1.0)
    assert ours.converged
    assert pose_difference(ours.poses, reference) < 1e-4
    assert ours.cost == pytest.approx(2.0 * reference_error, rel=1e-9)


def test_dcs_rejects_false_loop_closures_that_least_squares_follows(intel_graph):
    false = np.arange(intel_graph.edge_count) >= intel_graph.edge_count - FALSE_LOOPS
    robust = optimize(intel_graph, 1.0, iterations=100)
    assert np.median(robust.scales[false]) < 0.05
    assert np.median(robust.scales[intel_graph.is_loop_closure & ~false]) > 0.5
    plain = optimize(intel_graph, None, iterations=20)
    np.testing.assert_allclose(plain.scales, 1.0)
    clean = _without_false_loops(intel_graph)
    true_chi2 = [edge_residuals(clean, result.poses)[1].sum() for result in (robust, plain)]
    assert true_chi2[0] < 0.5 * true_chi2[1]


def test_fixed_vertices_stay_and_a_shared_system_gives_the_same_solution():
    graph = _random_graph(4)
    graph = PoseGraph(graph.poses, graph.edge_from, graph.edge_to, graph.measurements,
                      graph.information, fixed=[False, False, True, False, False, True])
    system = SparseSystem(graph)
    first = optimize(graph, 0.5, iterations=100, system=system)
    second = optimize(graph, 0.5, iterations=100, system=system)
    np.testing.assert_array_equal(first.poses[[2, 5]], graph.poses[[2, 5]])
    np.testing.assert_array_equal(first.poses, second.poses)
    assert first.iterations >= 1


def test_a_non_positive_phi_and_an_unconstrained_graph_are_refused():
    with pytest.raises(ValueError, match='phi must be positive'):
        optimize(_random_graph(0), 0.0)
    no_edges = PoseGraph(poses=np.zeros((3, 3)), edge_from=[], edge_to=[],
                         measurements=np.zeros((0, 3)), information=np.zeros((0, 3, 3)))
    with pytest.raises(ValueError, match='no edge constrains the free vertices'):
        optimize(no_edges, 1.0)


def test_a_component_without_fixed_vertex_stays_at_its_guess_and_keeps_its_shape():
    measurements = np.array([[1.0, 0.0, 0.1], [2.0, 1.0, -0.2]])
    apart = PoseGraph(poses=np.zeros((4, 3)), edge_from=[0, 2], edge_to=[1, 3],
                      measurements=measurements, information=[np.eye(3)] * 2)
    result = optimize(apart, 1.0, iterations=100)
    np.testing.assert_allclose(se2.relative(result.poses[[0, 2]], result.poses[[1, 3]]),
                               measurements, atol=1e-6)
