"""The localization pipeline on a handmade room: scans simulated against the map, at the true
poses (localized), kidnapped (an episode with its error), against a map missing a box (a
change, never a mislocalization), a frozen estimate, a map that knows nothing."""
from __future__ import annotations

import math

import numpy as np
import pytest

from map_consistency_ros.core.geometry import ScanSet, SensorModel, se2
from map_consistency_ros.core.localization import (FREE, OCCUPIED, UNKNOWN, LocalizationSettings,
                                                   MapSurface, OccupancyGrid, cascaded_test,
                                                   judge_scans, localize, map_surface,
                                                   prepare_reference, travel, window_starts)
from map_consistency_ros.core.localization import grid_measures
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.verdict import register_onto_points, surface_points

RESOLUTION = 0.05
MODEL = SensorModel(-math.pi, 2.0 * math.pi / 360, 8.0)
BOXES = [(5.0, 2.0, 5.6, 2.6), (9.0, 7.0, 9.8, 7.5), (13.0, 3.0, 13.4, 3.8),
         (16.0, 6.5, 16.8, 7.1)]


def room(boxes=BOXES) -> OccupancyGrid:
    """A 20 m x 10 m room, walls 0.1 m thick, a few boxes, all known."""
    height, width = int(10 / RESOLUTION), int(20 / RESOLUTION)
    cells = np.full((height, width), FREE, np.int8)
    cells[:2, :] = cells[-2:, :] = cells[:, :2] = cells[:, -2:] = OCCUPIED
    for x0, y0, x1, y1 in boxes:
        cells[int(y0 / RESOLUTION):int(y1 / RESOLUTION),
              int(x0 / RESOLUTION):int(x1 / RESOLUTION)] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=RESOLUTION, origin=np.zeros(3))


def simulate(grid: OccupancyGrid, poses: np.ndarray, step: float = 0.01) -> np.ndarray:
    """Ranges of MODEL's beams at `poses`, marched through the grid to the first occupied
    cell (no return beyond max range: max range + 1)."""
    beams = MODEL.angle_min + MODEL.angle_increment * np.arange(360)
    distances = np.arange(step, MODEL.max_range, step)
    ranges = np.empty((len(poses), beams.size))
    for row, (x, y, theta) in enumerate(poses):
        angles = theta + beams
        px = x + np.cos(angles)[:, None] * distances[None]
        py = y + np.sin(angles)[:, None] * distances[None]
        cols = np.floor(px / grid.resolution).astype(int)
        rows = np.floor(py / grid.resolution).astype(int)
        inside = (rows >= 0) & (rows < grid.height) & (cols >= 0) & (cols < grid.width)
        hit = np.zeros_like(inside)
        hit[inside] = grid.cells[rows[inside], cols[inside]] == OCCUPIED
        first = np.where(hit.any(axis=1), hit.argmax(axis=1), -1)
        ranges[row] = np.where(first >= 0, distances[np.maximum(first, 0)], MODEL.max_range + 1)
    rng = np.random.default_rng(7)
    return ranges + np.where(ranges < MODEL.max_range, rng.normal(0, 0.01, ranges.shape), 0.0)


def path(count: int = 80) -> np.ndarray:
    x = np.linspace(2.0, 18.0, count)
    return np.stack([x, 5.0 + 0.5 * np.sin(x / 3.0), np.full(count, 0.1)], axis=1)


@pytest.fixture(scope='module')
def truth():
    poses = path()
    return poses, simulate(room(), poses), np.arange(len(poses), dtype=float)


@pytest.fixture(scope='module')
def surface():
    return MapSurface.of(prepare_reference(room()))


def test_map_surface_normals_are_across_the_walls():
    points, normals = map_surface(room(boxes=[]))
    bottom = (points[:, 1] < 0.1) & (points[:, 0] > 1.0) & (points[:, 0] < 19.0)
    assert np.allclose(np.abs(normals[bottom, 1]), 1.0)
    left = (points[:, 0] < 0.1) & (points[:, 1] > 1.0) & (points[:, 1] < 9.0)
    assert np.allclose(np.abs(normals[left, 0]), 1.0)


def test_windows_reach_back_by_travel_or_time():
    distance = np.arange(10.0)  # a metre per scan
    stamps = np.arange(10.0) * 10.0  # ten seconds per scan
    assert window_starts(distance, stamps, 3.0, 1000.0).tolist() == [0, 0, 0, 0, 1, 2, 3, 4, 5, 6]
    assert window_starts(distance, stamps, 100.0, 20.0).tolist() == [0, 0, 0, 1, 2, 3, 4, 5, 6, 7]
    assert travel(np.array([[0, 0, 0], [3, 4, 0], [3, 4, 1]])).tolist() == [0.0, 5.0, 5.0]


def test_cascaded_test_flags_the_failed_scans_of_a_failing_window(truth, surface):
    poses, ranges, _ = truth
    scans = ScanSet.from_ranges(ranges, poses, MODEL)
    measures = grid_measures(scans, surface.reference)
    parameters, settings = ConsistencyParameters(), LocalizationSettings()
    tests = judge_scans(measures, np.full(scans.scan_count, 0.03), parameters, settings)
    assert tests.judged.all() and not tests.failed.any()
    failed = tests.failed.copy()
    failed[40:45] = True
    tests = type(tests)(**{**tests.__dict__, 'failed': failed})
    windows = cascaded_test(tests, window_starts(travel(poses), np.arange(80.0), 5.0, 30.0),
                            parameters)
    assert np.flatnonzero(windows.flagged).tolist() == [40, 41, 42, 43, 44]
    assert windows.flaggable.all() or windows.flaggable[windows.flaggable_count:].all()


def test_registration_onto_the_map_recovers_a_shift(truth, surface):
    poses, ranges, _ = truth
    error = np.array([0.3, -0.4, math.radians(4.0)])
    wrong = se2.compose(error, poses[20:30])
    scans = ScanSet.from_ranges(ranges[20:30], wrong, MODEL)
    found = register_onto_points(surface.points, surface.normals,
                                 surface_points(scans.endpoints, scans.valid), [[0, 10]])
    assert found.determined[0]
    moved = se2.compose(found.world_transforms()[0], wrong)
    assert np.abs(moved[:, :2] - poses[20:30, :2]).max() < 0.05


def test_true_poses_are_localized(truth, surface):
    poses, ranges, stamps = truth
    result = localize(ScanSet.from_ranges(ranges, poses, MODEL), stamps, surface)
    assert result.outcome == 'localized'
    assert not result.episodes and not result.frozen and not result.mislocalized.any()


def test_a_kidnapping_is_an_episode_with_its_error(truth, surface):
    poses, ranges, stamps = truth
    estimate = poses.copy()
    error = np.array([0.0, 0.4, math.radians(3.0)])
    estimate[30:60] = se2.compose(error, poses[30:60])
    result = localize(ScanSet.from_ranges(ranges, estimate, MODEL), stamps, surface)
    assert result.outcome == 'mislocalized'
    assert len(result.episodes) == 1
    episode = result.episodes[0]
    assert abs(episode.first - 30) <= 3 and abs(episode.last - 59) <= 3
    truth_error = np.median(np.hypot(*(estimate[30:60, :2] - poses[30:60, :2]).T))
    assert episode.position_error == pytest.approx(truth_error, rel=0.25)
    assert math.degrees(episode.heading_error) == pytest.approx(-3.0, abs=1.0)


def test_an_outdated_map_is_a_change_not_a_mislocalization(truth):
    poses, ranges, stamps = truth
    # the map was made before a box was put in the room
    outdated = MapSurface.of(prepare_reference(room(boxes=BOXES[1:])))
    result = localize(ScanSet.from_ranges(ranges, poses, MODEL), stamps, outdated)
    assert not result.episodes
    assert result.changes
    near = [math.hypot(c.x - 5.3, c.y - 2.3) for c in result.changes]
    assert min(near) < 0.6


def test_a_frozen_estimate_is_reported(truth, surface):
    poses, ranges, stamps = truth
    estimate = poses.copy()
    estimate[40:60] = poses[40]
    result = localize(ScanSet.from_ranges(ranges, estimate, MODEL), stamps, surface)
    assert result.frozen and result.outcome == 'mislocalized'
    assert result.frozen[0].scans[0] == 40


def test_a_map_that_knows_nothing_has_nothing_to_judge(truth):
    poses, ranges, stamps = truth
    grid = room()
    blank = OccupancyGrid(cells=np.full(grid.cells.shape, UNKNOWN, np.int8),
                          resolution=RESOLUTION, origin=np.zeros(3))
    result = localize(ScanSet.from_ranges(ranges, poses, MODEL), stamps,
                      MapSurface.of(prepare_reference(blank)))
    assert result.outcome == 'nothing to judge' and not result.tests.judged.any()


def test_stamps_must_match_the_scans(truth, surface):
    poses, ranges, stamps = truth
    with pytest.raises(ValueError):
        localize(ScanSet.from_ranges(ranges, poses, MODEL), stamps[:-1], surface)


def test_coarse_search_finds_a_kidnapping_beyond_the_gates(truth):
    from map_consistency_ros.core.localization._search import DistanceField, coarse_correction
    poses, ranges, _ = truth
    error = np.array([0.0, 0.0, math.radians(10.0)])
    pivot = poses[20]
    # 10 degrees about the robot and 1 m to its left
    wrong = se2.compose(se2.compose(pivot, se2.compose(np.array([0.0, 1.0, 0.0]), error)),
                        se2.relative(pivot, poses[20:30]))
    scans = ScanSet.from_ranges(ranges[20:30], wrong, MODEL)
    points = scans.endpoints[scans.valid][::10]
    seed, cost, zero = coarse_correction(DistanceField.of(room()), points,
                                         np.median(wrong[:, :2], axis=0), 1.5,
                                         math.radians(15.0), 0.15, math.radians(2.5))
    assert cost < zero
    moved = se2.compose(seed, wrong)
    assert np.median(np.hypot(*(moved[:, :2] - poses[20:30, :2]).T)) < 0.3
    assert abs(math.degrees(se2.wrap_angle(moved[0, 2] - poses[20, 2]))) <= 2.5


def test_a_jump_of_the_estimate_does_not_inflate_the_scales_beside_it(truth, surface):
    from map_consistency_ros.core.localization import live_scales
    poses, ranges, _ = truth
    estimate = poses.copy()
    estimate[40:] = se2.compose(np.array([0.0, 0.5, 0.0]), poses[40:])
    parameters, settings = ConsistencyParameters(), LocalizationSettings()
    scales = live_scales(ScanSet.from_ranges(ranges, estimate, MODEL), parameters,
                         RESOLUTION, settings)
    calm = live_scales(ScanSet.from_ranges(ranges, poses, MODEL), parameters, RESOLUTION,
                       settings)
    assert np.allclose(scales, calm, atol=0.01)
    assert scales.min() >= settings.resolution_scale * RESOLUTION


@pytest.fixture(scope='module')
def intel_excerpt(shared_data):
    """The first 150 scans of the corrected Intel log and the map ray-cast from them."""
    from map_consistency_ros.core.localization import ray_cast_grid
    from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    scans = ScanSet.from_ranges(log.ranges[:150], log.laser_poses[:150], sensor_model(log))
    grid, _, _ = ray_cast_grid(scans, resolution=0.05)
    return scans, log.timestamps[:150], MapSurface.of(prepare_reference(grid))


def test_a_real_excerpt_at_its_own_poses_is_localized(intel_excerpt):
    scans, stamps, surface = intel_excerpt
    result = localize(scans, stamps, surface)
    assert result.outcome == 'localized' and not result.mislocalized.any()


def test_a_real_excerpt_kidnapped_by_0_3_m_is_found(intel_excerpt):
    scans, stamps, surface = intel_excerpt
    poses = scans.sensor_poses.copy()
    x, y, theta = poses[60]
    shift = np.array([-0.3 * math.sin(theta), 0.3 * math.cos(theta), 0.0])
    poses[60:120, :2] += shift[:2]
    result = localize(scans.with_poses(poses), stamps, surface)
    assert result.outcome == 'mislocalized'
    overlapping = [e for e in result.episodes if e.first <= 119 and e.last >= 60]
    assert overlapping and abs(overlapping[0].first - 60) <= 10
    assert overlapping[0].position_error == pytest.approx(0.3, rel=0.5)
    assert not any(e.last < 60 or e.first > 119 for e in result.episodes)


def test_register_onto_points_refuses_bad_rows(truth, surface):
    poses, ranges, _ = truth
    scans = ScanSet.from_ranges(ranges[:5], poses[:5], MODEL)
    surfaces = surface_points(scans.endpoints, scans.valid)
    with pytest.raises(ValueError):
        register_onto_points(surface.points, surface.normals, surfaces, [[0, 6]])
    with pytest.raises(ValueError):
        register_onto_points(surface.points, surface.normals, surfaces, [[3, 3]])
    with pytest.raises(ValueError):
        register_onto_points(surface.points, surface.normals[:-1], surfaces, [[0, 5]])
    # a query far from every map point is undetermined, not an error
    far = ScanSet.from_ranges(ranges[:5], poses[:5] + [100.0, 100.0, 0.0], MODEL)
    found = register_onto_points(surface.points, surface.normals,
                                 surface_points(far.endpoints, far.valid), [[0, 5]])
    assert not found.determined[0] and np.isinf(found.covariances[0]).all()
