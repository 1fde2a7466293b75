"""The grid side of the measure against independent oracles: shapely for the depth of points
in a map's free space (the union of free cells) and for map obstacles inside a scan's
visibility polygon; numpy for the sums and the unjudged beams; a real Intel scan against a
map ray-cast from the corrected log."""
import numpy as np
import pytest
from shapely.geometry import Point, Polygon
from shapely.ops import unary_union

from map_consistency_ros.core.geometry import ScanSet, SensorModel
from map_consistency_ros.core.localization import (FREE, OCCUPIED, UNKNOWN, OccupancyGrid,
                                                   grid_measures, grid_point_distances,
                                                   prepare_reference)

MODEL = SensorModel(angle_min=-np.pi / 2, angle_increment=np.pi / 180, max_range=8.0)


def random_grid(rng, height=40, width=50, resolution=0.1, blobs=14):
    cells = np.full((height, width), FREE, np.int8)
    for _ in range(blobs):
        row, col = rng.integers(0, height), rng.integers(0, width)
        cells[row:row + rng.integers(1, 6), col:col + rng.integers(1, 6)] = rng.choice(
            [OCCUPIED, UNKNOWN])
    return OccupancyGrid(cells=cells, resolution=resolution,
                         origin=[1.0, -2.0, rng.uniform(-np.pi, np.pi)])


def world_polygon(grid, rows, cols):
    """Union of the cells' squares in the map frame."""
    squares = []
    for row, col in zip(rows, cols):
        corners = np.array([[col, row], [col + 1, row], [col + 1, row + 1], [col, row + 1]])
        squares.append(Polygon(_to_world(grid, corners)))
    return unary_union(squares)


def _to_world(grid, grid_points):
    x, y, yaw = grid.origin
    cos, sin = np.cos(yaw), np.sin(yaw)
    points = grid_points * grid.resolution
    return np.stack([x + cos * points[:, 0] - sin * points[:, 1],
                     y + sin * points[:, 0] + cos * points[:, 1]], axis=1)


def scans_in(grid, rng, count=6, beams=180):
    """Scans with wavy ranges from poses over the grid (end points anywhere: free, occupied,
    unknown, off the grid)."""
    centre = grid.cell_centres(grid.height // 2, grid.width // 2)
    poses = np.column_stack([centre + rng.uniform(-1.5, 1.5, (count, 2)),
                             rng.uniform(-np.pi, np.pi, count)])
    phase = rng.uniform(0, 2 * np.pi, (count, 1))
    ranges = 1.5 + 0.8 * np.sin(np.linspace(0, 6 * np.pi, beams)[None, :] + phase)
    ranges += rng.uniform(0, 0.3, ranges.shape)
    ranges[:, ::23] = np.inf  # no return: free to max range, not a test point
    return ScanSet.from_ranges(ranges, poses, SensorModel(-np.pi / 2, np.pi / beams, 8.0))


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_endpoint_depth_is_the_distance_to_the_nearest_non_free_square(seed):
    rng = np.random.default_rng(seed)
    grid = random_grid(rng)
    reference = prepare_reference(grid)
    free = world_polygon(grid, *np.nonzero(grid.cells == FREE))
    scans = scans_in(grid, rng)
    checked = 0
    for scan in range(scans.scan_count):
        distances = grid_point_distances(scans, reference, scan)
        values = grid.values_at(scans.endpoints[scan])
        assert np.array_equal(distances.endpoint_cells, values)
        for beam in np.flatnonzero(scans.valid[scan]):
            point = Point(scans.endpoints[scan, beam])
            exact = free.boundary.distance(point) if free.contains(point) else 0.0
            # the depth is to a real non-free square (never below the exact one); the
            # nearest squares of the 3 x 3 cells around the point find the exact one here
            assert distances.endpoint_depth[beam] == pytest.approx(exact, abs=1e-9)
            checked += exact > 0
    assert checked > 100


def test_endpoint_depth_in_open_space_with_sparse_obstacles():
    rng = np.random.default_rng(5)
    cells = np.full((80, 80), FREE, np.int8)
    cells[rng.integers(0, 80, 15), rng.integers(0, 80, 15)] = OCCUPIED
    grid = OccupancyGrid(cells=cells, resolution=0.25, origin=[0, 0, 0])
    free = world_polygon(grid, *np.nonzero(cells == FREE))
    points = rng.uniform(0, 20, (400, 2))
    # one scan per point: a two-beam scan whose first beam ends at the point
    poses = np.column_stack([points - [0.5, 0.0], np.zeros(len(points))])
    model = SensorModel(angle_min=0.0, angle_increment=0.5, max_range=8.0)
    scans = ScanSet.from_ranges(np.tile([0.5, np.inf], (len(points), 1)), poses, model)
    reference = prepare_reference(grid)
    depths = np.array([grid_point_distances(scans, reference, i).endpoint_depth[0]
                       for i in range(len(points))])
    exact = np.array([free.boundary.distance(Point(p)) if free.contains(Point(p)) else 0.0
                      for p in points])
    assert np.allclose(depths, exact, atol=1e-9)


@pytest.mark.parametrize('seed', [0, 3])
def test_obstacles_inside_the_visibility_polygon_and_their_depth(seed):
    rng = np.random.default_rng(seed)
    grid = random_grid(rng, blobs=25)
    reference = prepare_reference(grid)
    scans = scans_in(grid, rng)
    centres = reference.obstacles
    seen = 0
    for scan in range(scans.scan_count):
        polygon = Polygon(np.vstack([scans.sensor_poses[scan, :2], scans.endpoints[scan]]))
        assert polygon.is_valid
        inside = np.array([polygon.contains(Point(c)) for c in centres])
        depth = np.array([polygon.exterior.distance(Point(c)) for c in centres])
        inside &= depth > 1e-9  # on the boundary is not inside
        distances = grid_point_distances(scans, reference, scan)
        assert set(distances.obstacle_rows.tolist()) == set(np.flatnonzero(inside).tolist())
        assert np.allclose(distances.obstacle_depth, depth[distances.obstacle_rows],
                           atol=1e-9)
        seen += inside.sum()
    assert seen > 20


def test_obstacles_in_many_batches_of_beams():
    """More candidate obstacles than beams: the kernel measures them K at a time."""
    cells = np.full((60, 60), OCCUPIED, np.int8)
    grid = OccupancyGrid(cells=cells, resolution=0.1, origin=[0, 0, 0])
    model = SensorModel(angle_min=-np.pi / 2, angle_increment=np.pi / 8, max_range=8.0)
    scans = ScanSet.from_ranges(np.full((1, 8), 2.0), np.array([[3.0, 3.0, 0.0]]), model)
    reference = prepare_reference(grid)
    distances = grid_point_distances(scans, reference, 0)
    polygon = Polygon(np.vstack([scans.sensor_poses[0, :2], scans.endpoints[0]]))
    expected = [row for row, c in enumerate(reference.obstacles)
                if polygon.contains(Point(c)) and polygon.exterior.distance(Point(c)) > 1e-9]
    assert len(expected) > 100
    assert sorted(distances.obstacle_rows.tolist()) == expected


@pytest.mark.parametrize('seed', [0, 4])
def test_sums_counts_and_unjudged_share(seed):
    rng = np.random.default_rng(seed)
    grid = random_grid(rng, blobs=20)
    reference = prepare_reference(grid)
    scans = scans_in(grid, rng, count=9)
    measures = grid_measures(scans, reference, keep_largest=5)
    for scan in range(scans.scan_count):
        distances = grid_point_distances(scans, reference, scan)
        valid = scans.valid[scan]
        depths = np.concatenate([distances.endpoint_depth[valid & (distances.endpoint_depth > 0)],
                                 distances.obstacle_depth])
        assert measures.distance_sum[scan] == pytest.approx(depths.sum())
        assert measures.point_count[scan] == depths.size
        assert measures.endpoint_count[scan] + measures.obstacle_count[scan] == depths.size
        assert np.allclose(measures.largest[scan],
                           np.pad(np.sort(depths)[::-1][:5], (0, max(0, 5 - depths.size))))
        unknown = grid.values_at(scans.endpoints[scan]) == UNKNOWN
        assert measures.unjudged_count[scan] == np.count_nonzero(unknown & valid)
        assert measures.valid_count[scan] == np.count_nonzero(valid)
    assert 0 < measures.unjudged_share.max() <= 1
    part = measures.take([2, 0])
    assert part.distance_sum.tolist() == measures.distance_sum[[2, 0]].tolist()


def test_a_scan_agreeing_with_the_map_scores_nothing_and_unknown_is_not_judged():
    # a 6 x 4 m room: walls occupied, inside free, a unknown patch where nobody looked
    cells = np.full((80, 120), FREE, np.int8)
    cells[:2], cells[-2:], cells[:, :2], cells[:, -2:] = OCCUPIED, OCCUPIED, OCCUPIED, OCCUPIED
    grid = OccupancyGrid(cells=cells, resolution=0.05, origin=[0, 0, 0])
    reference = prepare_reference(grid)
    pose = np.array([[3.0, 2.0, 0.0]])
    bearings = MODEL.bearings(180)
    # ranges to the inner wall faces (x = 5.9, y = 0.1 and 3.9), 1 mm into the wall cells
    with np.errstate(divide='ignore'):
        to_x = np.where(np.cos(bearings) > 0, 2.901 / np.cos(bearings), np.inf)
        to_y = np.abs(1.901 / np.sin(bearings))
    scans = ScanSet.from_ranges(np.minimum(to_x, to_y)[None], pose, MODEL)
    measures = grid_measures(scans, reference)
    assert measures.distance_sum[0] == 0 and measures.point_count[0] == 0
    assert measures.unjudged_count[0] == 0
    # the same scan 0.3 m back: the end points meant for the wall ahead float in free space
    moved = scans.with_poses(pose - [0.3, 0.0, 0.0])
    measures = grid_measures(moved, reference)
    assert measures.endpoint_count[0] > 50 and measures.obstacle_count[0] == 0
    assert measures.distance_sum[0] / measures.point_count[0] > 0.1
    # 0.3 m ahead: those end points pass the wall (off the map: not judged), and the wall
    # lies inside what the scan saw empty
    ahead = grid_measures(scans.with_poses(pose + [0.3, 0.0, 0.0]), reference)
    assert ahead.obstacle_count[0] > 50 and ahead.endpoint_count[0] == 0
    assert ahead.obstacle_sum[0] / ahead.obstacle_count[0] > 0.1
    assert ahead.unjudged_count[0] > 50
    # where the map knows nothing, nothing is judged
    unknown = OccupancyGrid(cells=np.full_like(cells, UNKNOWN), resolution=0.05,
                            origin=[0, 0, 0])
    measures = grid_measures(moved, prepare_reference(unknown))
    assert measures.point_count[0] == 0 and measures.unjudged_share[0] == 1.0


def test_bad_arguments():
    grid = OccupancyGrid(cells=np.zeros((3, 3), np.int8), resolution=0.1, origin=[0, 0, 0])
    scans = ScanSet.from_ranges(np.ones((1, 180)), np.zeros((1, 3)), MODEL)
    with pytest.raises(ValueError):
        grid_measures(scans, prepare_reference(grid), keep_largest=-1)
    with pytest.raises(IndexError):
        grid_point_distances(scans, prepare_reference(grid), 1)


@pytest.fixture(scope='module')
def intel_map(shared_data):
    """The first 150 scans of the corrected Intel log and the map ray-cast from them."""
    from map_consistency_ros.evaluation.localization_data import ray_cast_grid
    from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    scans = ScanSet.from_ranges(log.ranges[:150], log.laser_poses[:150], sensor_model(log))
    grid, _, _ = ray_cast_grid(scans, resolution=0.05)
    return scans, grid, prepare_reference(grid)


def test_a_real_intel_scan_against_the_map_of_its_log(intel_map):
    scans, grid, reference = intel_map
    scan = 100
    one = scans.take([scan])
    distances = grid_point_distances(one, reference, 0)
    # the shapely oracle on the real scan: the map's obstacles in its visibility polygon
    polygon = Polygon(np.vstack([one.sensor_poses[0, :2], one.endpoints[0]]))
    polygon = polygon if polygon.is_valid else polygon.buffer(0)
    near = reference.obstacles[(np.abs(reference.obstacles - one.sensor_poses[0, :2])
                                <= 8.5).all(axis=1)]
    depth = np.array([polygon.exterior.distance(Point(c)) if polygon.contains(Point(c))
                      else 0.0 for c in near])
    assert np.isclose(np.sort(distances.obstacle_depth).sum(), depth.sum(), atol=1e-6)
    # the scan helped make the map: its end points agree with it (a few centimetres deep at
    # most, as the other scans' walls spread over their cells)
    measures = grid_measures(one, reference)
    agreeing = measures.distance_sum[0] / measures.point_count[0]
    assert agreeing < 0.05 and measures.unjudged_share[0] == 0
    # off by 0.3 m to the side or 5 degrees: several times deeper
    x, y, theta = one.sensor_poses[0]
    for error in ([-0.3 * np.sin(theta), 0.3 * np.cos(theta), 0.0], [0.0, 0.0, np.radians(5)]):
        moved = grid_measures(one.with_poses(one.sensor_poses + error), reference)
        assert moved.distance_sum[0] / moved.point_count[0] > 3 * agreeing
        assert moved.distance_sum[0] > 3 * measures.distance_sum[0]


def test_every_real_scan_measured_at_once(intel_map):
    scans, _, reference = intel_map
    measures = grid_measures(scans, reference)
    one_by_one = [grid_point_distances(scans, reference, scan) for scan in (0, 75, 149)]
    for row, distances in zip((0, 75, 149), one_by_one):
        expected = (distances.endpoint_depth[scans.valid[row]].sum()
                    + distances.obstacle_depth.sum())
        assert measures.distance_sum[row] == pytest.approx(expected)
    assert np.median(measures.distance_sum / np.maximum(measures.point_count, 1)) < 0.05


def test_obstacle_depths_are_the_pairwise_measures_own(intel_map):
    """The obstacles' depths equal pairs_point_distances with the obstacles as a second scan's
    end points. This also guards numba's cache, which does not see changes to the kernel of
    core/geometry/_measure.py that the grid kernels call: after such a change this fails
    until the grid kernels are compiled again (touch _grid_measure.py)."""
    from map_consistency_ros.core.geometry import pairs_point_distances
    scans, _, reference = intel_map
    beams = scans.ranges.shape[1]
    for scan in (10, 120):
        one = scans.take([scan])
        distances = grid_point_distances(one, reference, 0)
        candidates = reference.obstacles[
            (np.abs(reference.obstacles - one.sensor_poses[0, :2]) < 8.0).all(axis=1)]
        expected = []
        for start in range(0, len(candidates), beams):
            batch = candidates[start:start + beams]
            ends = np.zeros((beams, 2))
            ends[:len(batch)] = batch
            valid = np.arange(beams) < len(batch)
            pair = ScanSet.from_parts(
                one.model, sensor_poses=np.repeat(one.sensor_poses, 2, axis=0),
                ranges=np.repeat(one.ranges, 2, axis=0),
                valid=np.stack([one.valid[0], valid]),
                endpoints=np.stack([one.endpoints[0], ends]),
                extents=np.repeat(one.extents, 2, axis=0))
            depth = pairs_point_distances(pair, np.array([[0, 1]]))[0, 0]
            expected += depth[valid & (depth > 0)].tolist()
        assert len(expected) > 10
        assert np.allclose(np.sort(distances.obstacle_depth), np.sort(expected), atol=1e-12)
