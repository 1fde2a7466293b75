"""The localization data generator: ray casting against shapely, the runs' errors against
their construction, and the whole generator on a short excerpt of the Intel log."""
import json
import math

import numpy as np
import pytest
from shapely.geometry import LineString, box

from map_consistency_ros.core.geometry import ScanSet, SensorModel, se2
from map_consistency_ros.core.localization import FREE, OCCUPIED, UNKNOWN
from map_consistency_ros.evaluation.localization_data import (GeneratorSettings,
                                                              beams_crossing, frozen, generate,
                                                              kidnapped, pose_labels,
                                                              ray_cast_grid)
from map_consistency_ros.io.carmen import read_carmen_log
from map_consistency_ros.io.occupancy_map import read_occupancy_map
from test.conftest import rectangle_room_ranges


def test_ray_casting_visits_the_cells_a_beam_crosses():
    rng = np.random.default_rng(1)
    model = SensorModel(angle_min=0.0, angle_increment=0.5, max_range=20.0)
    for _ in range(30):
        pose = np.array([[*rng.uniform(0, 3, 2), rng.uniform(-np.pi, np.pi)]])
        scans = ScanSet.from_ranges(np.array([[rng.uniform(0.5, 4.0), np.inf]]), pose, model)
        grid, hits, misses = ray_cast_grid(scans, resolution=0.25, margin=0.5)
        beam = LineString([scans.sensor_poses[0, :2], scans.endpoints[0, 0]])
        crossed = set()
        for row in range(grid.height):
            for col in range(grid.width):
                x0, y0 = grid.origin[0] + col * 0.25, grid.origin[1] + row * 0.25
                # crossing a cell's inside, not touching its corner
                if box(x0, y0, x0 + 0.25, y0 + 0.25).intersection(beam).length > 1e-9:
                    crossed.add((row, col))
        visited = set(map(tuple, np.argwhere(hits + misses > 0).tolist()))
        assert visited == crossed
        end = grid.cell_of(scans.endpoints[0, 0])
        assert hits.sum() == 1 and hits[end] == 1
        # the beam that did not return cleared nothing
        assert (grid.cells != UNKNOWN).sum() == len(crossed)


def test_occupied_free_and_unknown_by_the_hit_ratio():
    # a 180-degree scanner in a 4 x 3 m room, seen from a few poses
    poses = np.array([[2.0, 1.5, 0.0], [2.0, 1.5, np.pi], [1.0, 1.0, np.pi / 2]])
    ranges = rectangle_room_ranges(poses, width=4.0, height=3.0, noise=0.0)
    scans = ScanSet.from_ranges(ranges, poses,
                                SensorModel(-np.pi / 2, np.pi / 180, max_range=8.0))
    grid, hits, misses = ray_cast_grid(scans, resolution=0.05)
    occupied = grid.cells == OCCUPIED
    assert np.all(hits[occupied] / (hits + misses)[occupied] > 0.25)
    assert np.all(grid.cells[(hits + misses) == 0] == UNKNOWN)
    # the room's inside is free, its walls occupied
    assert grid.values_at(np.array([[2.0, 1.5], [1.0, 2.0]])).tolist() == [FREE, FREE]
    assert grid.values_at(np.array([[4.0 - 1e-3, 1.5], [2.0, 1e-3]])).tolist() == [
        OCCUPIED, OCCUPIED]


def test_kidnapped_poses_are_one_rigid_error_then_back():
    rng = np.random.default_rng(2)
    truth = np.column_stack([np.cumsum(rng.uniform(0, 0.3, (40, 2)), axis=0),
                             rng.uniform(-np.pi, np.pi, 40)])
    estimate = kidnapped(truth, 10, 15, 0.3, 5.0)
    assert np.array_equal(estimate[:10], truth[:10]) and np.array_equal(estimate[25:],
                                                                        truth[25:])
    # at the first off scan: 0.3 m to the robot's left, turned 5 degrees in place
    assert np.allclose(estimate[10, :2] - truth[10, :2],
                       0.3 * np.array([-math.sin(truth[10, 2]), math.cos(truth[10, 2])]))
    assert se2.wrap_angle(estimate[10, 2] - truth[10, 2]) == pytest.approx(math.radians(5))
    # rigid: the poses within the episode keep their relative placement
    assert np.allclose(se2.relative(estimate[10:24], estimate[11:25]),
                       se2.relative(truth[10:24], truth[11:25]))
    frozen_poses = frozen(truth, 30, 5)
    assert np.all(frozen_poses[30:35] == truth[30]) and np.array_equal(frozen_poses[35:],
                                                                       truth[35:])


def test_labels_off_scans_and_episodes():
    truth = np.zeros((20, 3))
    estimate = truth.copy()
    estimate[2:6, 0] = 0.2  # 4 scans off: too short for an episode
    estimate[8:14, 2] = math.radians(2)  # 6 scans off by 2 degrees: an episode
    estimate[15:20, 1] = 0.15  # exactly the threshold: not off
    labels = pose_labels(truth, estimate)
    assert labels['off'] == [False] * 2 + [True] * 4 + [False] * 2 + [True] * 6 + [False] * 6
    assert [(e['first'], e['last'], e['scans']) for e in labels['episodes']] == [(8, 13, 6)]
    assert labels['episodes'][0]['max_rotation_deg'] == pytest.approx(2.0)


@pytest.fixture(scope='module')
def excerpt(shared_data, tmp_path_factory):
    out = tmp_path_factory.mktemp('localization')
    settings = GeneratorSettings(scans=120, kidnap_start=40, kidnap_length=30,
                                 frozen_start=80, frozen_length=20, walls_removed=2,
                                 blocks_added=3)
    return out / 'intel', generate(shared_data, out, 'intel', settings), shared_data


def test_the_generator_on_an_excerpt(excerpt):
    folder, manifest, shared_data = excerpt
    truth_log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    assert manifest['scans'] == 120
    assert json.loads((folder / 'manifest.json').read_text()) == manifest
    # the map read back is the ray-cast one
    scans = ScanSet.from_ranges(truth_log.ranges[:120], truth_log.laser_poses[:120],
                                SensorModel(-np.pi / 2, np.pi / 180, 8.0))
    grid, _, _ = ray_cast_grid(scans, 0.05)
    read = read_occupancy_map(folder / 'map.yaml').grid
    assert np.array_equal(read.cells, grid.cells)
    for name, entry in manifest['runs'].items():
        log = read_carmen_log(folder / entry['log'])
        labels = json.loads((folder / entry['labels']).read_text())
        assert np.array_equal(log.ranges, truth_log.ranges[:120])
        errors = np.hypot(*(log.laser_poses[:, :2] - truth_log.laser_poses[:120, :2]).T)
        assert np.allclose(errors, labels['translation_error_m'], atol=2e-6)
        assert labels['episodes'] == entry['episodes']
    episodes = {name: entry['episodes'] for name, entry in manifest['runs'].items()}
    assert episodes['corrected'] == [] and episodes['kidnap_0.1m'] == []  # below 0.15 m
    for name in ('kidnap_0.3m', 'kidnap_2deg', 'kidnap_5deg', 'kidnap_1m_10deg'):
        assert [(e['first'], e['last']) for e in episodes[name]] == [(40, 69)], name
    # frozen from scan 80: off once the robot has moved away, back at scan 100
    (episode,) = episodes['frozen']
    assert 80 < episode['first'] and episode['last'] == 99


def test_the_outdated_map_differs_where_its_changes_are(excerpt):
    folder, manifest, _ = excerpt
    fresh = read_occupancy_map(folder / 'map.yaml').grid
    old = read_occupancy_map(folder / 'outdated.yaml').grid
    changes = manifest['outdated_map']['changes']
    assert [c['kind'] for c in changes].count('wall_removed') == 2
    assert [c['kind'] for c in changes].count('block_added') == 3
    inside = np.zeros(fresh.cells.shape, bool)
    for change in changes:
        rows, cols = slice(*change['rows']), slice(*change['cols'])
        inside[rows, cols] = True
        expected = FREE if change['kind'] == 'wall_removed' else OCCUPIED
        assert np.all(old.cells[rows, cols] == expected)
    assert np.array_equal(old.cells[~inside], fresh.cells[~inside])
    labels = json.loads((folder / 'labels' / 'outdated.json').read_text())
    assert labels['map'] == 'outdated.yaml' and labels['episodes'] == []
    seeing = (np.array(labels['endpoints_in_removed_walls'])
              + np.array(labels['beams_crossing_added_blocks'])) > 0
    assert seeing.sum() == manifest['runs']['outdated']['scans_seeing_changes'] > 0


def test_beams_crossing_counts_beams_through_a_mask():
    model = SensorModel(angle_min=-0.1, angle_increment=0.1, max_range=20.0)
    # three beams from the origin east, 5 m long; a wall of masked cells at x = 2 .. 2.5
    scans = ScanSet.from_ranges(np.array([[5.0, 5.0, 1.0]]), np.array([[0.05, 0.05, 0.0]]),
                                model)
    grid, _, _ = ray_cast_grid(scans, resolution=0.5, margin=1.0)
    mask = np.zeros(grid.cells.shape, bool)
    col = grid.cell_of(np.array([2.2, 0.0]))[1]
    mask[:, col] = True
    # the two 5 m beams cross it, the 1 m one ends before it
    assert beams_crossing(scans, grid, mask).tolist() == [2]
