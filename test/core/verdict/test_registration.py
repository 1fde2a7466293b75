"""Point-to-line registration of submaps of real Intel scans."""
import numpy as np
import pytest

from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.verdict import RegistrationSettings, register_submaps, surface_points
from map_consistency_ros.io import carmen


@pytest.fixture(scope='module')
def intel(shared_data):
    return carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')


def _scans(log, indices, poses=None, max_range=8.0):
    model = carmen.sensor_model(log, max_range=max_range)
    poses = log.laser_poses[indices] if poses is None else poses
    return ScanSet.from_ranges(log.ranges[indices], poses, model)


def _about(centre, shift, degrees):
    """The world transform turning by `degrees` about `centre`, then moving by `shift`."""
    theta = np.radians(degrees)
    rotation = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    return np.array([*(centre + np.asarray(shift) - rotation @ centre), theta])


@pytest.mark.parametrize('start', [240, 800])
@pytest.mark.parametrize('offset', [(0.2, -0.1, 2.0), (-0.35, 0.0, 0.0), (0.0, 0.05, -4.0)])
def test_a_known_offset_between_two_visits_is_recovered(intel, start, offset):
    # Eleven scans against eleven overlapping later ones, those turned about their centre and
    # moved; both stretches lie in rooms, whose walls fix every direction.
    reference, query = np.arange(start, start + 11), np.arange(start + 4, start + 15)
    centre = intel.laser_poses[query, :2].mean(axis=0)
    transform = _about(centre, offset[:2], offset[2])
    moved = se2.compose(np.broadcast_to(transform, (11, 3)), intel.laser_poses[query])
    poses = np.vstack([intel.laser_poses[reference], moved])
    scans = _scans(intel, np.r_[reference, query], poses)
    found = register_submaps(surface_points(scans.endpoints, scans.valid),
                             np.array([[0, 11, 11, 22]]))
    assert found.determined[0]
    undo = found.world_transforms()[0]
    # The correction undoes the displacement: applied after it, the query is back in place.
    back = se2.compose(undo, se2.compose(transform, intel.laser_poses[query]))
    assert np.abs(back[:, :2] - intel.laser_poses[query][:, :2]).max() < 0.02
    assert np.abs(se2.wrap_angle(back[:, 2] - intel.laser_poses[query][:, 2])).max() < 0.003


def test_outliers_are_trimmed(intel):
    # A third of the query's beams replaced by clutter in the free space: the fit holds.
    reference, query = np.arange(100, 111), np.arange(104, 115)
    ranges = intel.ranges[np.r_[reference, query]].copy()
    rng = np.random.default_rng(3)
    clutter = rng.random(ranges[11:].shape) < 0.33
    ranges[11:][clutter] *= rng.uniform(0.3, 0.9, clutter.sum())
    model = carmen.sensor_model(intel, max_range=8.0)
    scans = ScanSet.from_ranges(ranges, intel.laser_poses[np.r_[reference, query]], model)
    found = register_submaps(surface_points(scans.endpoints, scans.valid),
                             np.array([[0, 11, 11, 22]]))
    assert found.determined[0]
    assert np.hypot(*found.corrections[0, :2]) < 0.02
    assert abs(np.degrees(found.corrections[0, 2])) < 0.3


def test_a_corridor_leaves_the_slide_along_it_uncertain(intel):
    # Down and up the corridor at x = -5.9 m, seeing only its side walls (1.5 m range).
    reference, query = np.array([693, 694, 695, 696]), np.array([864, 865, 873, 874, 875])
    along, across = np.array([0.0, 1.0]), np.array([1.0, 0.0])
    ratios = {}
    for max_range in (1.5, 8.0):
        scans = _scans(intel, np.r_[reference, query], max_range=max_range)
        found = register_submaps(surface_points(scans.endpoints, scans.valid),
                                 np.array([[0, 4, 4, 9]]))
        covariance = found.covariances[0, :2, :2]
        ratios[max_range] = np.sqrt((along @ covariance @ along) / (across @ covariance @ across))
    assert ratios[1.5] > 4.0  # the walls fix the robot across the corridor, not along it
    assert ratios[8.0] < 0.5 * ratios[1.5]  # the corridor's doors and ends fix it along too


def test_undetermined_and_bad_tasks(intel):
    scans = _scans(intel, np.arange(100, 104))
    surfaces = surface_points(scans.endpoints, scans.valid)
    found = register_submaps(surfaces, np.zeros((0, 4), dtype=np.int64))
    assert found.corrections.shape == (0, 3)
    for task in ([0, 0, 1, 2], [0, 1, 2, 5], [-1, 1, 2, 3]):
        with pytest.raises(ValueError, match='registration tasks'):
            register_submaps(surfaces, np.array([task]))
    with pytest.raises(ValueError, match='gates must shrink'):
        RegistrationSettings(gates=(0.1, 0.5))


@pytest.mark.parametrize('gate', [0.5, 0.25, 0.12])
def test_the_grid_lookup_finds_the_nearest_point_within_the_gate(intel, gate):
    from scipy.spatial import cKDTree

    from map_consistency_ros.core.verdict import nearest_point, point_grid
    scans = _scans(intel, np.arange(100, 111))
    surfaces = surface_points(scans.endpoints, scans.valid)
    points = surfaces.points
    queries = points[::7] + np.random.default_rng(5).normal(scale=0.2, size=(len(points[::7]), 2))
    distance, oracle = cKDTree(points).query(queries, distance_upper_bound=gate)
    x0, y0, nx, ny, starts, items = point_grid(points, 0.25, 0.5)
    found = np.array([nearest_point(points, x0, y0, nx, ny, 0.25, starts, items, x, y, gate)
                      for x, y in queries])
    expected = np.where(np.isfinite(distance), oracle, -1)
    assert (found >= 0).sum() > 0.3 * len(found)
    np.testing.assert_array_equal(found, expected)


def test_surface_normals_are_perpendicular_to_the_beam_neighbours(intel):
    scans = _scans(intel, np.arange(300, 305))
    surfaces = surface_points(scans.endpoints, scans.valid)
    assert surfaces.offsets[-1] == scans.valid.sum() == len(surfaces.points)
    np.testing.assert_array_equal(surfaces.points, scans.endpoints[scans.valid])
    # An oracle on one scan: the chord between the two neighbours of every beam.
    ends, valid = scans.endpoints[2], scans.valid[2]
    rows = slice(surfaces.offsets[2], surfaces.offsets[3])
    normals = np.zeros_like(ends)
    for beam in range(1, len(ends) - 1):
        chord = ends[beam + 1] - ends[beam - 1]
        if (valid[beam - 1:beam + 2].all() and np.linalg.norm(chord) > 1e-9
                and max(np.linalg.norm(ends[beam + 1] - ends[beam]),
                        np.linalg.norm(ends[beam - 1] - ends[beam])) < 0.25):
            normals[beam] = np.array([-chord[1], chord[0]]) / np.linalg.norm(chord)
    assert np.count_nonzero(normals[valid].any(axis=1)) > 0.5 * valid.sum()
    np.testing.assert_allclose(surfaces.normals[rows], normals[valid], atol=1e-12)


def test_the_closed_form_inverse_matches_lapack():
    from map_consistency_ros.core.verdict import symmetric_inverse
    rng = np.random.default_rng(11)
    for scale in (1e-3, 1.0, 1e4):
        jacobians = rng.normal(scale=scale, size=(40, 3))
        hessian = jacobians.T @ jacobians
        inverse = np.empty((3, 3))
        determinant = symmetric_inverse(hessian, inverse)
        assert determinant == pytest.approx(np.linalg.det(hessian), rel=1e-9)
        np.testing.assert_allclose(inverse, np.linalg.inv(hessian), rtol=1e-9)
    # a corridor: no information along x, so no inverse
    corridor = np.diag([0.0, 2.0, 3.0])
    assert symmetric_inverse(corridor, inverse) == 0.0
