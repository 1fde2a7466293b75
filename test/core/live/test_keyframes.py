"""The monitor's keyframe store and scan buffer: stamp matching, twin poses, folded scans."""
import math

import numpy as np
import pytest

from map_consistency_ros.core.live._keyframes import (FOLDED, NO_SCAN, Keyframes, match_sorted,
                                                      match_stamps, rank_of_slot)
from map_consistency_ros.core.live._scan_buffer import ScanBuffer


def _store(stamps, tolerance: float = 0.5) -> Keyframes:
    keyframes = Keyframes(beams=3, tolerance=tolerance)
    for stamp in stamps:
        keyframes.append(stamp, np.zeros(3), np.zeros(3), np.ones(3))
    return keyframes


def test_stamps_match_the_nearest_within_the_tolerance():
    stamps = np.array([3.0, 1.0, 2.0])
    found = match_stamps(np.array([0.4, 1.2, 1.6, 2.5, 9.0]), stamps, 0.5)
    assert found.tolist() == [-1, 1, 2, 0, -1]  # 2.5: equally near 2 and 3, the later one


def _nearest_by_brute_force(queries, stamps, tolerance):
    """Index of the nearest stamp within the tolerance (the later of equally near stamps in
    stamp order, the first of equal stamps), -1 where none: every query against every stamp."""
    order = np.argsort(stamps, kind='stable')
    found = []
    for query in queries:
        distance = np.abs(stamps[order] - query)
        nearest = np.flatnonzero(distance == distance.min())
        # of equally near stamps, the one right of the query (searchsorted's side)
        right = [rank for rank in nearest if stamps[order[rank]] >= query]
        rank = right[0] if right else nearest[-1]
        found.append(int(order[rank]) if distance[rank] <= tolerance else -1)
    return found


def test_sorted_matching_and_the_kept_stamp_order_match_every_stamp_from_scratch():
    generator = np.random.default_rng(11)
    for trial in range(100):
        # stamps on a grid of 0.25 s: ties in distance and equal stamps are frequent
        stamps = generator.integers(0, 40, size=generator.integers(1, 30)) * 0.25
        queries = generator.integers(-4, 44, size=25) * 0.125
        tolerance = float(generator.choice([0.0, 0.125, 0.3]))
        expected = _nearest_by_brute_force(queries, stamps, tolerance)
        assert match_stamps(queries, stamps, tolerance).tolist() == expected
        ordered = np.sort(stamps, kind='stable')
        assert (match_sorted(queries, ordered, tolerance).tolist()
                == _nearest_by_brute_force(queries, ordered, tolerance))
        # the store keeps its stamps in order as keyframes arrive in any order
        distinct = np.unique(stamps)
        keyframes = _store(generator.permutation(distinct), tolerance)
        slot_stamps = keyframes.stamps[:keyframes.count]
        assert keyframes.match(queries).tolist() == _nearest_by_brute_force(
            queries, slot_stamps, tolerance)
        assert [keyframes.holds(query) for query in queries] == [
            found >= 0 for found in _nearest_by_brute_force(queries, slot_stamps, tolerance)]
    assert match_sorted(np.array([1.0]), np.zeros(0), 1.0).tolist() == [-1]
    assert match_sorted(np.zeros(0), np.array([1.0]), 1.0).tolist() == []
    assert match_sorted(np.array([np.nan, np.inf, 1.2]), np.array([1.0, 2.0]),
                        np.inf).tolist() == [-1, -1, 0]


def test_out_of_order_keyframes_keep_the_stamp_order():
    keyframes = _store([1.0, 3.0, 2.0, 4.0])
    assert keyframes.order().tolist() == [0, 2, 1, 3] and not keyframes.in_stamp_order()
    assert rank_of_slot(keyframes.order()).tolist() == [0, 2, 1, 3]
    assert _store([1.0, 2.0]).in_stamp_order()


def test_of_two_poses_on_one_keyframe_the_nearest_holds_it_the_first_of_equals():
    keyframes = _store([1.0, 2.0, 3.0])
    slots = keyframes.trajectory_slots(np.array([1.0, 1.875, 2.125, 2.75, 3.25, 6.0]))
    # 1.875 is nearer keyframe 2.0 than 2.125; 2.75 and 3.25 are equally near 3.0
    assert slots.tolist() == [0, 1, NO_SCAN, 2, NO_SCAN, NO_SCAN]


def test_folded_stamps_name_poses_without_a_keyframe():
    keyframes = _store([1.0, 2.0])
    keyframes.fold([5.0, 4.0])
    assert keyframes.folded.tolist() == [4.0, 5.0]
    keyframes.fold([4.5, 6.0, 0.5])  # merged into the sorted stamps, whatever their order
    keyframes.fold([])
    assert keyframes.folded.tolist() == [0.5, 4.0, 4.5, 5.0, 6.0]
    keyframes = _store([1.0, 2.0])
    keyframes.fold([5.0, 4.0])
    slots = keyframes.trajectory_slots(np.array([2.0, 2.25, 4.125, 7.0]))
    assert slots.tolist() == [1, NO_SCAN, FOLDED, NO_SCAN]
    assert keyframes.holds(2.25) and keyframes.holds(5.25) and not keyframes.holds(6.0)


def test_the_scan_buffer_drops_the_oldest_stamp_and_matches_the_rest():
    buffer = ScanBuffer(capacity=2, tolerance=0.01)
    for stamp in (2.0, 1.0, 3.0):
        buffer.add(stamp, np.full(3, stamp))
    assert len(buffer) == 2 and buffer.pushed_out == 1 and 1.0 not in buffer
    assert buffer.newest == 3.0
    matched = buffer.matches(np.array([2.005, 1.0, 2.5]))
    assert matched[0] == 2.0 and math.isnan(matched[1]) and math.isnan(matched[2])
    np.testing.assert_array_equal(buffer.pop(3.0), np.full(3, 3.0))
    assert buffer.newest == 3.0 and len(buffer) == 1  # the newest ever added stays
    with pytest.raises(ValueError, match='duplicates a buffered'):
        buffer.add(2.0, np.zeros(3))
    # the estimate went past 2.0 without naming it: passed over, not lost
    buffer.add(4.0, np.zeros(3), reached=2.5)
    buffer.add(5.0, np.zeros(3), reached=2.5)
    assert (buffer.pushed_out, buffer.passed_over, len(buffer)) == (1, 1, 2)
    buffer.add(6.0, np.zeros(3), reached=4.005)  # within the tolerance: it may still be named
    assert (buffer.pushed_out, buffer.passed_over, len(buffer)) == (2, 1, 2)


def test_refreshed_slots_equal_slots_matched_from_scratch():
    """refresh_slots against trajectory_slots on crowded stamps: twins microseconds apart,
    poses within the tolerance of two keyframes, folded scans, a trajectory that grows."""
    generator = np.random.default_rng(5)
    tolerance = 0.01
    for trial in range(200):
        # clusters of stamps closer than the tolerance, so claims and ties are everywhere
        centres = np.sort(generator.uniform(0.0, 0.3, generator.integers(5, 40)))
        stamps = np.unique(np.concatenate([centres, centres + generator.uniform(
            -0.012, 0.012, centres.size)]))
        keyframes = Keyframes(beams=3, tolerance=tolerance)
        known = generator.permutation(stamps)[:stamps.size // 2]
        shown = stamps[:generator.integers(1, stamps.size + 1)]
        take = generator.uniform(size=known.size) < 0.5
        for stamp in known[take]:
            keyframes.append(float(stamp) + generator.choice([0.0, 0.004]), np.zeros(3),
                             np.zeros(3), np.ones(3))
        keyframes.fold([float(stamp) for stamp in known[~take][::2]])
        version, before = keyframes.version, keyframes.trajectory_slots(shown)
        for stamp in known[~take][1::2]:  # later keyframes and folded scans
            if generator.uniform() < 0.5:
                keyframes.append(float(stamp), np.zeros(3), np.zeros(3), np.ones(3))
            else:
                keyframes.fold([float(stamp)])
        grown = stamps[:generator.integers(shown.size, stamps.size + 1)]
        slots = np.full(grown.size, NO_SCAN)
        slots[:shown.size] = before
        changed = np.concatenate([keyframes.added_since(version), grown[shown.size:]])
        refreshed = keyframes.refresh_slots(grown, slots, changed)
        np.testing.assert_array_equal(refreshed, keyframes.trajectory_slots(grown),
                                      err_msg=f'trial {trial}')


def test_a_new_keyframe_frees_an_old_one_for_a_pose_three_tolerances_away():
    # pose 1.9 holds keyframe 1.0 against pose 0.0, until keyframe 2.7 takes pose 1.9: then
    # pose 0.0, 2.7 s from the new stamp, holds keyframe 1.0
    keyframes = _store([1.0], tolerance=1.0)
    stamps = np.array([0.0, 1.9])
    before = keyframes.trajectory_slots(stamps)
    assert before.tolist() == [NO_SCAN, 0]
    version = keyframes.version
    keyframes.append(2.7, np.zeros(3), np.zeros(3), np.ones(3))
    refreshed = keyframes.refresh_slots(stamps, before, keyframes.added_since(version))
    assert refreshed.tolist() == keyframes.trajectory_slots(stamps).tolist() == [0, 1]
