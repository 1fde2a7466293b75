"""Candidate pairs and the incremental grid index, against brute force."""
import numpy as np
import pytest

from map_consistency_ros.core.geometry import ScanExtentIndex, ScanSet, candidate_pairs
from map_consistency_ros.core.geometry import _spatial_index
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model


def _brute_force(extents: np.ndarray, ids: np.ndarray | None = None) -> np.ndarray:
    """Every overlapping pair (closed boxes), i < j, optionally only those touching ids."""
    a, b = extents[:, None, :], extents[None, :, :]
    overlap = ((a[..., 0] <= b[..., 2]) & (b[..., 0] <= a[..., 2])
               & (a[..., 1] <= b[..., 3]) & (b[..., 1] <= a[..., 3]))
    pairs = np.argwhere(np.triu(overlap, 1))
    if ids is not None:
        pairs = pairs[np.isin(pairs, ids).any(axis=1)]
    return pairs


def _random_boxes(rng: np.random.Generator, count: int, span: float = 50.0) -> np.ndarray:
    corner = rng.uniform(-span, span, (count, 2))
    size = rng.uniform(0.0, 12.0, (count, 2)) * (rng.random((count, 1)) > 0.05)
    boxes = np.concatenate([corner, corner + size], axis=1)
    # Rounded corners make touching and identical boxes common.
    return np.round(boxes)


@pytest.mark.parametrize('seed', range(5))
def test_candidate_pairs_equal_brute_force(seed):
    boxes = _random_boxes(np.random.default_rng(seed), 300)
    pairs = candidate_pairs(boxes)
    assert pairs.dtype == np.int64
    np.testing.assert_array_equal(pairs, _brute_force(boxes))


def test_candidate_pairs_of_intel_scans(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    scans = ScanSet.from_ranges(log.ranges, log.laser_poses, sensor_model(log))
    pairs = candidate_pairs(scans.extents)
    np.testing.assert_array_equal(pairs, _brute_force(scans.extents))
    assert 80_000 < len(pairs) < 110_000
    index = ScanExtentIndex()
    index.update(np.arange(scans.scan_count), scans.extents)
    np.testing.assert_array_equal(index.pairs_touching(np.arange(scans.scan_count)), pairs)
    some = np.arange(0, scans.scan_count, 7)
    np.testing.assert_array_equal(index.pairs_touching(some),
                                  pairs[np.isin(pairs, some).any(axis=1)])


def test_candidate_pairs_small_inputs():
    assert candidate_pairs(np.zeros((0, 4))).shape == (0, 2)
    assert candidate_pairs(np.array([[0.0, 0, 1, 1]])).shape == (0, 2)
    touching = np.array([[0.0, 0, 1, 1], [1.0, 1, 2, 2], [2.5, 0, 3, 1]])
    np.testing.assert_array_equal(candidate_pairs(touching), [[0, 1]])


@pytest.mark.parametrize('extents, message', [
    (np.zeros((3, 3)), r'\(N, 4\)'),
    (np.array([[0.0, 0, np.nan, 1]]), 'finite'),
    (np.array([[2.0, 0, 1, 1]]), 'xmin <= xmax'),
])
def test_candidate_pairs_rejects_bad_extents(extents, message):
    with pytest.raises(ValueError, match=message):
        candidate_pairs(extents)


@pytest.mark.parametrize('seed, box_tests', [(0, None), (1, None), (2, 0), (3, 0)])
def test_index_follows_updates_moves_and_removals(seed, box_tests, monkeypatch):
    if box_tests is not None:  # every query sweeps every box (a large loop closure)
        monkeypatch.setattr(_spatial_index, '_BOX_TESTS', box_tests)
    rng = np.random.default_rng(seed)
    boxes = _random_boxes(rng, 200)
    index = ScanExtentIndex()
    present = np.zeros(len(boxes), bool)
    for step in range(30):
        if step % 3 == 2 and present.any():
            gone = rng.choice(np.flatnonzero(present), min(10, present.sum()), replace=False)
            index.remove(gone)
            present[gone] = False
        else:
            moved = rng.choice(len(boxes), 25, replace=False)
            boxes[moved] = _random_boxes(rng, 25)
            index.update(moved, boxes[moved])
            present[moved] = True
        stored = np.flatnonzero(present)
        assert len(index) == len(stored) and all(scan in index for scan in stored)
        query = rng.choice(stored, min(15, len(stored)), replace=False)
        expected = stored[_brute_force(boxes[stored], np.searchsorted(stored, query))]
        np.testing.assert_array_equal(index.pairs_touching(query), expected)


def test_index_refreshes_only_pairs_of_moved_scans():
    """Pairs untouched by a move plus pairs_touching(moved) rebuild the full candidate set."""
    rng = np.random.default_rng(9)
    boxes = _random_boxes(rng, 300)
    index = ScanExtentIndex()
    index.update(np.arange(300), boxes)
    before = candidate_pairs(boxes)
    moved = rng.choice(300, 40, replace=False)
    boxes[moved] += rng.uniform(-5, 5, (40, 1)) * np.array([1, 0, 1, 0])
    index.update(moved, boxes[moved])
    kept = before[~np.isin(before, moved).any(axis=1)]
    combined = np.unique(np.concatenate([kept, index.pairs_touching(moved)]), axis=0)
    np.testing.assert_array_equal(combined, candidate_pairs(boxes))


def test_index_rejects_bad_input():
    index = ScanExtentIndex()
    index.update([3], [[0.0, 0, 1, 1]])
    assert index.pairs_touching([]).shape == (0, 2)
    with pytest.raises(ValueError, match='2 ids but 1 extents'):
        index.update([1, 2], [[0.0, 0, 1, 1]])
    with pytest.raises(ValueError, match='must not repeat'):
        index.update([1, 1], [[0.0, 0, 1, 1], [0.0, 0, 1, 1]])
    with pytest.raises(ValueError, match='xmin <= xmax'):
        index.update([1], [[1.0, 0, 0, 1]])
    with pytest.raises(KeyError, match='scan 7'):
        index.remove([3, 7])
    with pytest.raises(KeyError, match='scan 7'):
        index.pairs_touching([7])
    assert len(index) == 1 and 3 in index


def test_index_pairs_boxes_that_only_touch_and_none_of_a_scan_alone():
    index = ScanExtentIndex()
    # 1 touches 0 at an edge, 2 touches 1 at a corner only, 3 is far away
    boxes = np.array([[0.0, 0.0, 1.0, 1.0], [1.0, 0.5, 2.0, 1.5], [2.0, 1.5, 3.0, 2.5],
                      [10.0, 10.0, 11.0, 11.0]])
    index.update(np.array([7, 8, 9, 4]), boxes)
    assert index.pairs_touching(np.array([8])).tolist() == [[7, 8], [8, 9]]
    assert index.pairs_touching(np.array([7, 8])).tolist() == [[7, 8], [8, 9]]
    assert index.pairs_touching(np.array([4])).shape == (0, 2)
    assert index.pairs_touching(np.zeros(0, dtype=np.int64)).shape == (0, 2)
