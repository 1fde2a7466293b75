"""Hähnel baseline: a hand-computed case, an exact geometric oracle, real Intel scans."""
import math

import numpy as np
import pytest

from map_consistency_ros.core.consistency import (FREE, OCCUPIED, UNKNOWN, BaselineParameters,
                                                  PairLikelihoods, local_grids, map_statistic,
                                                  pair_log_likelihoods, traverse_cells)
from map_consistency_ros.core.geometry import ScanSet, SensorModel
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model


def _crossed_cells(start: np.ndarray, end: np.ndarray) -> set[tuple[int, int]]:
    """Cells (cell units) whose open square the segment passes through, by slab clipping."""
    lo = np.floor(np.minimum(start, end)).astype(int)
    hi = np.floor(np.maximum(start, end)).astype(int)
    cx, cy = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1),
                         indexing='ij')
    cx, cy = cx.ravel(), cy.ravel()
    enter, leave = np.zeros(cx.size), np.ones(cx.size)
    for axis, corner in ((0, cx), (1, cy)):
        delta = end[axis] - start[axis]
        if delta == 0.0:
            inside = (corner < start[axis]) & (start[axis] < corner + 1)
            leave = np.where(inside, leave, -1.0)
            continue
        t0, t1 = (corner - start[axis]) / delta, (corner + 1 - start[axis]) / delta
        enter = np.maximum(enter, np.minimum(t0, t1))
        leave = np.minimum(leave, np.maximum(t0, t1))
    crossed = leave > enter
    return set(zip(cx[crossed].tolist(), cy[crossed].tolist()))


def _beam_segments(pose: np.ndarray, ranges: np.ndarray, bearings: np.ndarray,
                   frame: np.ndarray, cell_size: float, centre: float) -> list:
    """Each beam's start and end in the cell units of a grid centred on `frame`."""
    cos_f, sin_f = math.cos(frame[2]), math.sin(frame[2])

    def to_cells(x: float, y: float) -> np.ndarray:
        dx, dy = x - frame[0], y - frame[1]
        return np.array([cos_f * dx + sin_f * dy, -sin_f * dx + cos_f * dy]) / cell_size + centre

    start = to_cells(pose[0], pose[1])
    return [(start, to_cells(pose[0] + r * math.cos(pose[2] + b),
                             pose[1] + r * math.sin(pose[2] + b)))
            for r, b in zip(ranges, bearings)]


def _oracle_grid(scans: ScanSet, index: int, size: int, cell_size: float) -> dict:
    centre = size // 2 + 0.5
    bearings = scans.model.bearings(scans.ranges.shape[1])
    pose = scans.sensor_poses[index]
    segments = _beam_segments(pose, scans.ranges[index], bearings, pose, cell_size, centre)
    grid = {}
    for (start, end), valid in zip(segments, scans.valid[index]):
        end_cell = tuple(np.floor(end).astype(int).tolist())
        for cell in _crossed_cells(start, end) - ({end_cell} if valid else set()):
            grid.setdefault(cell, FREE)
    for (_, end), valid in zip(segments, scans.valid[index]):
        if valid:
            grid[tuple(np.floor(end).astype(int).tolist())] = OCCUPIED
    return {cell: label for cell, label in grid.items()
            if 0 <= cell[0] < size and 0 <= cell[1] < size}


def _oracle_score(scans: ScanSet, scored: int, on: int, size: int,
                  parameters: BaselineParameters) -> tuple[float, int]:
    grid = _oracle_grid(scans, on, size, parameters.cell_size)
    log_p = {FREE: math.log(parameters.free_probability),
             OCCUPIED: math.log(parameters.occupied_probability)}
    log_not_p = {FREE: math.log(1 - parameters.free_probability),
                 OCCUPIED: math.log(1 - parameters.occupied_probability)}
    segments = _beam_segments(scans.sensor_poses[scored], scans.ranges[scored],
                              scans.model.bearings(scans.ranges.shape[1]),
                              scans.sensor_poses[on], parameters.cell_size, size // 2 + 0.5)
    total, events = 0.0, 0
    for (start, end), valid in zip(segments, scans.valid[scored]):
        ex, ey = np.floor(end).astype(int).tolist()
        for cell in _crossed_cells(start, end) - {(ex, ey)}:
            if max(abs(cell[0] - ex), abs(cell[1] - ey)) > 1 and cell in grid:
                total += log_not_p[grid[cell]]
                events += 1
        if valid:
            around = [grid.get((ex + a, ey + b)) for a in (-1, 0, 1) for b in (-1, 0, 1)]
            label = OCCUPIED if OCCUPIED in around else grid.get((ex, ey))
            if label is not None:
                total += log_p[label]
                events += 1
    return total, events


@pytest.fixture(scope='module')
def intel(shared_data):
    """Ten consecutive Intel scans at their corrected poses (real data excerpt)."""
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return ScanSet.from_ranges(log.ranges[300:310], log.laser_poses[300:310], sensor_model(log))


def test_hand_computed_pair():
    # beam 0 along x (4.2 m and 2.2 m), beam 1 ends in the sensor cell, cells of 1 m:
    # grid of scan 0 along x: occupied, free, free, free, occupied; of scan 1: occ., free, occ.
    model = SensorModel(angle_min=0.0, angle_increment=math.pi / 2, max_range=10.0)
    scans = ScanSet.from_ranges(np.array([[4.2, 0.3], [2.2, 0.3]]), np.zeros((2, 3)), model)
    parameters = BaselineParameters(cell_size=1.0, occupied_probability=0.9,
                                    free_probability=0.1)
    grids = local_grids(scans, parameters)
    centre = grids.cells.shape[1] // 2
    assert grids.cells[0, centre:centre + 6, centre].tolist() == [2, 1, 1, 1, 2, 0]
    assert grids.cells[1, centre:centre + 4, centre].tolist() == [2, 1, 2, 0]
    result = pair_log_likelihoods(scans, np.array([[0, 1]]), parameters)
    # scan 1 on grid 0: crosses the occupied sensor cell (0.1), ends in free (0.1), beam 1 hits
    # (0.9); scan 0 on grid 1: crosses occupied, free, occupied, ends unknown, beam 1 hits
    expected = 4 * math.log(0.1) + 3 * math.log(0.9)
    assert result.event_count.tolist() == [7]
    assert result.log_likelihood[0] == pytest.approx(expected, rel=1e-12)
    assert result.normalised()[0] == pytest.approx(expected / 7, rel=1e-12)


def test_grids_match_exact_segment_cell_oracle(intel):
    parameters = BaselineParameters(cell_size=0.25)
    grids = local_grids(intel, parameters)
    size = grids.cells.shape[1]
    for index in (0, 5):
        oracle = _oracle_grid(intel, index, size, parameters.cell_size)
        cells = grids.cells[index]
        known = {(int(x), int(y)): int(cells[x, y]) for x, y in zip(*np.nonzero(cells))}
        assert known == oracle
        assert np.count_nonzero(cells == UNKNOWN) == size * size - len(oracle)


def test_pair_scores_match_exact_oracle(intel):
    parameters = BaselineParameters(cell_size=0.25)
    pairs = np.array([[0, 1], [2, 7], [0, 9]])
    result = pair_log_likelihoods(intel, pairs, parameters)
    size = local_grids(intel, parameters).cells.shape[1]
    for (i, j), total, events in zip(pairs, result.log_likelihood, result.event_count):
        forward = _oracle_score(intel, i, j, size, parameters)
        backward = _oracle_score(intel, j, i, size, parameters)
        assert events == forward[1] + backward[1]
        assert total == pytest.approx(forward[0] + backward[0], rel=1e-9)


def test_misaligned_scan_scores_lower_than_aligned(intel):
    parameters = BaselineParameters()
    pairs = np.array([[i, i + 1] for i in range(9)])
    aligned = pair_log_likelihoods(intel, pairs, parameters).normalised()
    poses = intel.sensor_poses.copy()
    poses[5:, :2] += [0.4, 0.0]
    moved = pair_log_likelihoods(intel.with_poses(poses), pairs, parameters).normalised()
    assert moved[4] < aligned[4] - 0.02
    untouched = [0, 1, 2, 3, 5, 6, 7, 8]
    np.testing.assert_allclose(moved[untouched], aligned[untouched], rtol=1e-12)


def test_scores_are_symmetric_and_reuse_grids(intel):
    parameters = BaselineParameters()
    grids = local_grids(intel, parameters)
    forward = pair_log_likelihoods(intel, np.array([[1, 4], [3, 8]]), parameters, grids)
    backward = pair_log_likelihoods(intel, np.array([[4, 1], [8, 3]]), parameters)
    np.testing.assert_allclose(forward.log_likelihood, backward.log_likelihood, rtol=1e-12)
    np.testing.assert_array_equal(forward.event_count, backward.event_count)


def test_map_statistic_is_quantile_of_overlapping_pairs():
    likelihoods = PairLikelihoods(pairs=np.array([[0, 1], [0, 2], [1, 2], [2, 3]]),
                                  log_likelihood=np.array([-10.0, -50.0, -2.0, -90.0]),
                                  event_count=np.array([100, 100, 10, 30]))
    # per-pair means -0.1, -0.5, -0.2 (too few events), -3.0
    assert map_statistic(likelihoods, BaselineParameters(min_events=20)) == -3.0
    assert map_statistic(likelihoods, BaselineParameters(min_events=50)) == -0.5
    assert map_statistic(likelihoods, BaselineParameters(min_events=20, quantile=1.0)) == -0.1
    assert map_statistic(likelihoods, BaselineParameters(min_events=200)) == math.inf
    assert likelihoods.normalised()[2] == pytest.approx(-0.2)


def test_pair_without_scored_cells_has_minus_infinite_mean():
    empty = PairLikelihoods(pairs=np.array([[0, 1]]), log_likelihood=np.zeros(1),
                            event_count=np.zeros(1, dtype=np.int64))
    assert empty.normalised()[0] == -math.inf


@pytest.mark.parametrize('field, value', [('cell_size', 0.0), ('free_probability', 0.95),
                                          ('occupied_probability', 1.0), ('min_events', 0),
                                          ('quantile', 1.5)])
def test_bad_parameters_are_rejected(field, value):
    with pytest.raises(ValueError, match=field.split('_')[0]):
        BaselineParameters(**{field: value})


def test_bad_pairs_and_foreign_grids_are_rejected(intel):
    parameters = BaselineParameters()
    with pytest.raises(ValueError, match='pair indices'):
        pair_log_likelihoods(intel, np.array([[0, 10]]), parameters)
    grids = local_grids(intel, BaselineParameters(cell_size=0.2))
    with pytest.raises(ValueError, match='grids'):
        pair_log_likelihoods(intel, np.array([[0, 1]]), parameters, grids)


def test_traversal_visits_each_crossed_cell_once():
    cells = np.empty((64, 2), dtype=np.int64)
    rng = np.random.default_rng(3)
    for _ in range(50):
        start, end = rng.uniform(-6, 6, 2), rng.uniform(-6, 6, 2)
        count = traverse_cells(start[0], start[1], end[0], end[1], cells)
        walked = [tuple(cell) for cell in cells[:count].tolist()]
        assert len(set(walked)) == count
        assert set(walked) == _crossed_cells(start, end)
        assert walked[-1] == tuple(np.floor(end).astype(int).tolist())
