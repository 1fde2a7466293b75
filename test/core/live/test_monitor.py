"""The incremental monitor against the batch test (the oracle) on real Intel scans."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from map_consistency_ros.core.consistency import (ConsistencyParameters, ConsistencyResult,
                                                  check_consistency, inconsistent_endpoints)
from map_consistency_ros.core.geometry import ScanSet, SensorModel, point_distances, se2
from map_consistency_ros.core.live import ConsistencyMonitor, MonitorSettings
from map_consistency_ros.core.live import monitor as monitor_module
from map_consistency_ros.core.live._keyframes import NO_SCAN
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

# Scans 270..349 of the Intel log: one revisit, and two stamps out of file order (294/295).
FIRST, LAST = 270, 350
# The incremental machinery against the batch test: every keyframe is a viewpoint.
EVERY_KEYFRAME = ConsistencyParameters(viewpoint_spacing=0.0, viewpoint_turn=0.0)
# ... and every pair: the batch test has no partner budget.
ALL_PAIRS = MonitorSettings(max_partners=0)


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    stamps = log.timestamps[FIRST:LAST]
    assert np.any(np.diff(stamps) < 0), 'the excerpt should hold out-of-order stamps'
    return stamps, log.ranges[FIRST:LAST], log.laser_poses[FIRST:LAST], sensor_model(log)


def _stream(stamps, ranges, poses, model, settings=None) -> ConsistencyMonitor:
    """Scans and growing trajectories in file order, as a SLAM front-end emits them."""
    monitor = ConsistencyMonitor(EVERY_KEYFRAME, settings=settings or ALL_PAIRS)
    for index in range(len(stamps)):
        monitor.add_scan(stamps[index], ranges[index], model)
        monitor.update_trajectory(stamps[:index + 1], poses[:index + 1])
    return monitor


@pytest.fixture(scope='module')
def streamed(intel):
    return _stream(*intel)


def _oracle(ranges, poses, model, reference_poses=None) -> ConsistencyResult:
    reference = None if reference_poses is None else ScanSet.from_ranges(ranges, reference_poses,
                                                                         model)
    return check_consistency(ScanSet.from_ranges(ranges, poses, model), reference_scans=reference)


def _assert_same_verdict(result: ConsistencyResult, oracle: ConsistencyResult) -> None:
    np.testing.assert_allclose(result.scales, oracle.scales, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(result.inconsistent, oracle.inconsistent)
    np.testing.assert_array_equal(result.failed_counts, oracle.failed_counts)
    np.testing.assert_array_equal(result.overlap_counts, oracle.overlap_counts)
    overlapping = oracle.point_count > 0
    expected = {tuple(p): (m, n) for p, m, n in zip(oracle.pairs[overlapping].tolist(),
                                                    oracle.distance_sum[overlapping],
                                                    oracle.point_count[overlapping])}
    got = {tuple(p): (m, n) for p, m, n in zip(result.pairs.tolist(), result.distance_sum,
                                               result.point_count)}
    assert got.keys() == expected.keys()
    for pair, (distance_sum, count) in expected.items():
        assert got[pair][1] == count
        assert got[pair][0] == pytest.approx(distance_sum, rel=1e-9, abs=1e-12)


def _by_stamp(intel):
    stamps, ranges, poses, model = intel
    order = np.argsort(stamps, kind='stable')
    return stamps[order], ranges[order], poses[order], model


def _dragged(poses: np.ndarray, first: int) -> np.ndarray:
    """Poses from `first` on moved rigidly, as a wrong loop closure drags them."""
    moved = poses.copy()
    pivot = poses[first]
    moved[first:] = se2.compose(se2.compose(pivot, np.array([0.4, -0.2, 0.08])),
                                se2.relative(pivot, poses[first:]))
    return moved


def test_streaming_equals_the_batch_test_in_stamp_order(intel, streamed):
    stamps, ranges, poses, model = _by_stamp(intel)
    snapshot = streamed.evaluate()
    np.testing.assert_array_equal(snapshot.stamps, stamps)
    np.testing.assert_allclose(snapshot.poses, poses)
    _assert_same_verdict(snapshot.result, _oracle(ranges, poses, model))
    assert snapshot.buffered_scans == 0 and snapshot.unmatched_poses == 0
    # ids are registration order: the two swapped stamps keep their arrival ids
    assert sorted(snapshot.ids.tolist()) == list(range(len(stamps)))
    assert not np.array_equal(snapshot.ids, np.arange(len(stamps)))


def test_loop_closure_measures_only_moved_pairs(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    half = len(stamps) // 2
    monitor = ConsistencyMonitor(EVERY_KEYFRAME, ALL_PAIRS)
    for stamp, scan in zip(stamps, ranges):
        monitor.add_scan(stamp, scan, model)
    first = monitor.update_trajectory(stamps, poses)
    assert first.new_keyframes == len(stamps)
    earlier = monitor.evaluate()
    shared = ('pairs', 'distance_sum', 'point_count', 'trimmed_sum', 'trimmed_count')
    kept = [getattr(earlier.result, name).copy() for name in shared] + [earlier.poses.copy()]
    with pytest.raises(ValueError, match='read-only'):  # shared with the monitor, not copied
        earlier.result.distance_sum[0] = 1.0
    moved = _dragged(poses, half)
    summary = monitor.update_trajectory(stamps, moved)
    assert summary.moved_keyframes == len(stamps) - half and summary.new_keyframes == 0
    assert 0 < summary.measured_pairs < first.measured_pairs
    # later updates leave a snapshot alone
    for old, new in zip(kept, [getattr(earlier.result, name) for name in shared]
                        + [earlier.poses]):
        np.testing.assert_array_equal(old, new)
    result = monitor.evaluate().result
    oracle = _oracle(ranges, moved, model, reference_poses=poses)
    _assert_same_verdict(result, oracle)
    assert result.failed_pair_count > 0
    # The incremental solution is the first-seen one: the loop closure leaves it alone.
    np.testing.assert_allclose(se2.relative(monitor.evaluate().incremental_poses[:-1],
                                            monitor.evaluate().incremental_poses[1:]),
                               se2.relative(poses[:-1], poses[1:]), atol=1e-9)
    recomputed = monitor.recompute()
    assert recomputed.measured_pairs >= summary.measured_pairs
    _assert_same_verdict(monitor.evaluate().result, oracle)


def test_every_update_of_a_growing_map_equals_the_batch_test(intel):
    """The statistics start from the last result while the map only grows, and from scratch
    after a loop closure moved keyframes: each update against the batch test."""
    stamps, ranges, poses, model = _by_stamp(intel)
    moved = _dragged(poses, 30)
    monitor = ConsistencyMonitor(EVERY_KEYFRAME, ALL_PAIRS)
    for end in range(10, len(stamps) + 1, 10):
        for index in range(end - 10, end):
            monitor.add_scan(stamps[index], ranges[index], model)
        placed = poses if end <= 50 else moved  # the loop closure comes with scan 60
        monitor.update_trajectory(stamps[:end], placed[:end])
        reference = None if end <= 50 else poses[:end]
        _assert_same_verdict(monitor.evaluate().result,
                             _oracle(ranges[:end], placed[:end], model, reference))


def test_every_update_after_stamps_out_of_order_equals_the_batch_test(intel):
    """Scans arrive after later-stamped ones: the local bounds kept per slot and the test
    started from the last result give the batch test's verdict on every later update, not
    only after a fresh start."""
    stamps, ranges, poses, model = intel
    # and every 7th scan a step late, so that slots and ranks differ all along the run
    late = np.arange(len(stamps))
    for index in range(3, len(stamps) - 1, 7):
        late[[index, index + 1]] = late[[index + 1, index]]
    stamps, ranges, poses = stamps[late], ranges[late], poses[late]
    monitor = ConsistencyMonitor(EVERY_KEYFRAME, ALL_PAIRS)
    for end in range(1, len(stamps) + 1):
        monitor.add_scan(stamps[end - 1], ranges[end - 1], model)
        monitor.update_trajectory(stamps[:end], poses[:end])
        if end % 3 == 0 or end == len(stamps):
            order = np.argsort(stamps[:end], kind='stable')
            _assert_same_verdict(monitor.evaluate().result,
                                 _oracle(ranges[:end][order], poses[:end][order], model))


def test_a_partner_budget_thins_the_pairs_of_dense_keyframes_stably(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    budget = 8
    monitor = _stream(stamps, ranges, poses, model, MonitorSettings(max_partners=budget))
    full = _oracle(ranges, poses, model)
    overlapping = full.point_count > 0
    oracle = {tuple(p): m for p, m in zip(full.pairs[overlapping].tolist(),
                                          full.distance_sum[overlapping])}
    kept = monitor.evaluate().result
    later_partners = np.bincount(kept.pairs[:, 1], minlength=len(stamps))
    assert np.bincount(full.pairs[overlapping][:, 1]).max() > 3 * budget  # the budget binds
    assert later_partners.mean() <= budget and later_partners.max() <= 2 * budget
    assert later_partners[10:].min() > 0  # every keyframe keeps pairs with earlier ones
    assert len(kept.pairs) < 0.5 * overlapping.sum()
    # what is kept is measured as the batch test measures it
    for pair, distance_sum in zip(kept.pairs.tolist(), kept.distance_sum):
        assert distance_sum == pytest.approx(oracle[tuple(pair)], rel=1e-9, abs=1e-12)
    # a loop closure re-measures the pairs of the moved keyframes, leaves the others alone
    half = len(stamps) // 2
    monitor.update_trajectory(stamps, _dragged(poses, half))
    after = monitor.evaluate().result
    unmoved = {tuple(p) for p in kept.pairs.tolist() if p[1] < half}
    assert {tuple(p) for p in after.pairs.tolist() if p[1] < half} == unmoved
    assert np.bincount(after.pairs[:, 1], minlength=len(stamps)).mean() <= budget


def test_small_moves_do_not_trigger_measures(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor(settings=MonitorSettings(move_tolerance=0.05))
    for stamp, scan in zip(stamps[:10], ranges[:10]):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps[:10], poses[:10])
    nudged = poses[:10] + np.array([0.01, 0.0, 0.0])
    summary = monitor.update_trajectory(stamps[:10], nudged)
    assert not summary.changed and summary.measured_pairs == 0


def test_scans_stamped_microseconds_apart_do_not_move_their_keyframe(intel):
    # Raw logs hold scans published twice a few microseconds apart (Intel at its native rate
    # has 1,479): both poses fall within the stamp tolerance of the first one's keyframe.
    stamps, ranges, poses, model = _by_stamp(intel)
    twins = np.sort(np.concatenate([stamps[:12], stamps[:12] + 6e-6]))
    twin_poses = np.repeat(poses[:12], 2, axis=0)
    twin_poses[1::2] += np.array([0.03, 0.0, 0.0])  # the second copy's pose differs
    single = ConsistencyMonitor()  # the oracle: the same scans published once
    for stamp, scan in zip(stamps[:12], ranges[:12]):
        single.add_scan(stamp, scan, model)
    single.update_trajectory(stamps[:12], poses[:12])
    monitor = ConsistencyMonitor()
    for stamp, scan in zip(twins, np.repeat(ranges[:12], 2, axis=0)):
        monitor.add_scan(stamp, scan, model)
    first = monitor.update_trajectory(twins, twin_poses)
    expected = single.evaluate()
    assert first.new_keyframes == expected.keyframe_count  # every second copy is folded
    assert monitor.evaluate().folded_scans == expected.folded_scans + 12
    np.testing.assert_array_equal(monitor.evaluate().stamps, expected.stamps)
    np.testing.assert_array_equal(monitor.evaluate().poses, expected.poses)
    again = monitor.update_trajectory(twins, twin_poses)
    assert again.moved_keyframes == 0 and again.measured_pairs == 0
    assert again.unmatched_poses == 0


def test_new_keyframe_after_a_loop_closure_is_chained_on_its_predecessor(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    for stamp, scan in zip(stamps[:6], ranges[:6]):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps[:5], poses[:5])
    # The back-end corrects everything by a rigid transform and adds keyframe 5.
    correction = np.array([1.0, -2.0, 0.3])
    corrected = se2.compose(np.broadcast_to(correction, (6, 3)), poses[:6])
    monitor.update_trajectory(stamps[:6], corrected)
    incremental = monitor.evaluate().incremental_poses
    np.testing.assert_allclose(incremental[:5], poses[:5])
    np.testing.assert_allclose(incremental[5], se2.compose(poses[4],
                                                           se2.relative(poses[4], poses[5])))


def test_pose_before_scan_registers_on_refresh(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    monitor.add_scan(stamps[0], ranges[0], model)
    summary = monitor.update_trajectory(stamps[:3], poses[:3])
    assert summary.new_keyframes == 1 and summary.unmatched_poses == 2
    assert not monitor.pending
    monitor.add_scan(stamps[2] + 2e-4, ranges[2], model)  # within the stamp tolerance
    assert monitor.pending
    late = monitor.refresh()
    assert late.new_keyframes == 1 and late.unmatched_poses == 1
    snapshot = monitor.evaluate()
    np.testing.assert_allclose(snapshot.stamps, [stamps[0], stamps[2] + 2e-4])
    np.testing.assert_allclose(snapshot.incremental_poses, poses[[0, 2]])


def _pending_from_scratch(monitor: ConsistencyMonitor) -> bool:
    """Whether a buffered scan matches a pose of the last trajectory that has no scan,
    computed from every pose of that trajectory."""
    unmatched = monitor._path_stamps[monitor._path_slots() == NO_SCAN]
    return bool(unmatched.size and np.isfinite(monitor._buffer.matches(unmatched)).any())


def test_pending_follows_the_buffer_and_the_trajectory_from_scratch(intel):
    """`pending` is kept as scans come and go; it must equal its definition at every step:
    scans before and after their poses, out of order, lost, and pushed out of a full buffer."""
    stamps, ranges, poses, model = _by_stamp(intel)
    generator = np.random.default_rng(3)
    seen = set()
    for trial in range(4):
        monitor = ConsistencyMonitor(settings=MonitorSettings(max_buffered_scans=4))
        arrival = np.arange(len(stamps))
        swaps = generator.choice(len(stamps) - 1, size=10, replace=False)
        arrival[swaps], arrival[swaps + 1] = arrival[swaps + 1], arrival[swaps]
        path_end = 0
        for index in arrival:
            if generator.random() < 0.1:
                continue  # this scan is lost
            try:
                monitor.add_scan(stamps[index], ranges[index], model)
            except ValueError:  # the raw log stamps a few scans alike: the second is refused
                assert stamps[index] in monitor._buffer or monitor._keyframes.holds(
                    stamps[index])
            assert monitor.pending == _pending_from_scratch(monitor)
            seen.add(monitor.pending)
            if monitor.pending and generator.random() < 0.5:
                monitor.refresh()
                assert monitor.pending == _pending_from_scratch(monitor) is False
            if generator.random() < 0.3:  # the back-end runs ahead of the scans or behind
                path_end = min(len(stamps), path_end + int(generator.integers(1, 8)))
                monitor.update_trajectory(stamps[:path_end], poses[:path_end])
                assert monitor.pending == _pending_from_scratch(monitor)
    assert seen == {True, False}


def test_a_pending_scan_pushed_out_of_the_buffer_is_no_longer_pending(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor(settings=MonitorSettings(max_buffered_scans=2))
    monitor.add_scan(stamps[0], ranges[0], model)
    monitor.update_trajectory(stamps[:2], poses[:2])  # pose 1 waits for its scan
    monitor.add_scan(stamps[1], ranges[1], model)
    assert monitor.pending
    monitor.add_scan(stamps[5], ranges[5], model)  # the buffer holds 1 and 5: still pending
    assert monitor.pending
    monitor.add_scan(stamps[6], ranges[6], model)  # scan 1 is pushed out
    assert not monitor.pending and monitor.evaluate().pushed_out_scans == 1
    assert monitor.refresh().new_keyframes == 0
    # scan 1 came and was lost: counted there, its pose is not one whose scan never came
    assert monitor.evaluate().poses_without_scan == 0


def test_a_trajectory_before_any_scan_waits_for_its_scans(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    summary = monitor.update_trajectory(stamps[:3], poses[:3])
    assert summary.new_keyframes == 0 and summary.unmatched_poses == 3
    empty = monitor.evaluate()
    assert empty.keyframe_count == 0 and empty.result is None and empty.unmatched_poses == 3
    monitor.add_scan(stamps[0], ranges[0], model)
    assert monitor.pending and monitor.refresh().new_keyframes == 1


def test_late_first_scan_is_chained_on_its_successor(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    for stamp, scan in zip(stamps[1:4], ranges[1:4]):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps[:4], poses[:4])
    # a loop closure moves everything, then the scan of the first pose arrives
    correction = np.array([-3.0, 0.5, -0.4])
    corrected = se2.compose(np.broadcast_to(correction, (4, 3)), poses[:4])
    monitor.add_scan(stamps[0], ranges[0], model)
    summary = monitor.update_trajectory(stamps[:4], corrected)
    assert summary.new_keyframes == 1 and summary.moved_keyframes == 3
    # the incremental solution stays in the frame of the first trajectory
    np.testing.assert_allclose(monitor.evaluate().incremental_poses, poses[:4], atol=1e-9)


def test_scan_buffer_is_bounded_and_drops_the_oldest(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor(settings=MonitorSettings(max_buffered_scans=5))
    for stamp, scan in zip(stamps[:12], ranges[:12]):
        monitor.add_scan(stamp, scan, model)
    assert monitor.evaluate().buffered_scans == 5
    summary = monitor.update_trajectory(stamps[:12], poses[:12])
    assert summary.new_keyframes == 5 and summary.unmatched_poses == 7
    np.testing.assert_array_equal(monitor.evaluate().stamps, stamps[7:12])
    # the seven scans pushed out are counted once: as lost, not again by the poses naming them
    snapshot = monitor.evaluate()
    assert snapshot.pushed_out_scans == 7 and snapshot.poses_without_scan == 0


def test_poses_of_scans_that_came_or_came_before_the_first_are_not_without_scan(intel):
    """A full trajectory after a reset names the previous session's scans, and a refused
    scan's pose names a scan that came: neither is a pose whose scan never came."""
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    for index in range(10, 20):
        monitor.add_scan(stamps[index], ranges[index], model)
    with pytest.raises(ValueError):
        monitor.add_scan(stamps[20], ranges[20][:50], model)
    monitor.note_not_kept([stamps[21]])  # lost before it reached the monitor
    monitor.add_scan(stamps[22], ranges[22], model)
    monitor.update_trajectory(stamps[:23], poses[:23])
    snapshot = monitor.evaluate()
    assert snapshot.unmatched_poses == 10 + 2 and snapshot.poses_without_scan == 0
    monitor.add_scan(stamps[24], ranges[24], model)
    monitor.update_trajectory(stamps[:25], poses[:25])  # scan 23 never came
    assert monitor.evaluate().poses_without_scan == 1


def test_the_stamps_of_scans_not_kept_are_bounded(intel, monkeypatch):
    """Only the newest NOT_KEPT_LIMIT stamps of scans refused or lost are remembered: the pose
    of an older one counts as a pose whose scan never came."""
    monkeypatch.setattr(monitor_module, 'NOT_KEPT_LIMIT', 3)
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    monitor.add_scan(stamps[0], ranges[0], model)
    monitor.note_not_kept(stamps[1:6])
    monitor.add_scan(stamps[6], ranges[6], model)
    monitor.update_trajectory(stamps[:7], poses[:7])
    assert monitor.evaluate().poses_without_scan == 2  # scans 1 and 2 forgotten


def test_a_pose_whose_scan_never_came_is_reported_once_newer_scans_arrive(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    for index in (0, 1, 3):  # scan 2 is lost on the way
        monitor.add_scan(stamps[index], ranges[index], model)
    monitor.update_trajectory(stamps[:4], poses[:4])
    assert monitor.evaluate().poses_without_scan == 1
    monitor.update_trajectory(stamps[:5], poses[:5])  # pose 4 waits: its scan may still come
    assert monitor.evaluate().poses_without_scan == 1 and monitor.evaluate().unmatched_poses == 2


def test_bad_scans_raise_and_keep_the_state(intel):
    stamps, ranges, poses, model = intel
    monitor = ConsistencyMonitor()
    monitor.add_scan(stamps[0], ranges[0], model)
    monitor.update_trajectory(stamps[:1], poses[:1])
    before = monitor.evaluate()
    other = SensorModel(angle_min=model.angle_min + 0.1, angle_increment=model.angle_increment,
                        max_range=model.max_range)
    cases = [
        ((float('nan'), ranges[1], model), 'finite'),
        ((stamps[1], np.zeros(0), model), 'non-empty'),
        ((stamps[1], ranges[:2], model), 'non-empty 1-D'),
        ((stamps[1], ranges[1].reshape(2, -1), model), 'non-empty 1-D'),
        ((stamps[1], ranges[1], other), 'only scans like the first'),
        ((stamps[1], ranges[1][:90], model), 'only scans like the first'),
        ((stamps[1], ranges[1][:1], model), 'at least 2 beams'),
        ((stamps[1], np.ones(400), SensorModel(0.0, 0.02, 8.0)), 'overlap past 2 pi'),
        ((stamps[0], ranges[0], model), 'duplicates a registered keyframe'),
    ]
    for arguments, message in cases:
        with pytest.raises(ValueError, match=message):
            monitor.add_scan(*arguments)
    after = monitor.evaluate()
    assert after.buffered_scans == before.buffered_scans == 0
    np.testing.assert_array_equal(after.stamps, before.stamps)
    # NaN and inf beams are free space, not an error
    monitor.add_scan(stamps[1], np.where(np.arange(ranges.shape[1]) % 2, np.nan, np.inf), model)
    assert monitor.evaluate().buffered_scans == 1


def test_bad_trajectories_are_refused_or_cleaned(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    for stamp, scan in zip(stamps[:4], ranges[:4]):
        monitor.add_scan(stamp, scan, model)
    with pytest.raises(ValueError, match='stamps'):
        monitor.update_trajectory(stamps[:4], poses[:3])
    with pytest.raises(ValueError, match='stamps'):
        monitor.update_trajectory(stamps[:4], poses[:4, :2])
    assert monitor.keyframe_count == 0
    dirty_stamps = np.concatenate([stamps[[2, 0, 1]], stamps[[1]], [np.nan]])
    dirty_poses = np.concatenate([poses[[2, 0, 1]], poses[[3]], poses[[3]]])
    dirty_poses[0, 2] = np.inf
    summary = monitor.update_trajectory(dirty_stamps, dirty_poses)
    assert summary.new_keyframes == 2  # stamps 0 and 1; 2 had an infinite heading
    assert len(summary.warnings) == 2
    assert any('non-finite' in w for w in summary.warnings)
    assert any('duplicated stamp' in w for w in summary.warnings)
    snapshot = monitor.evaluate()
    np.testing.assert_array_equal(snapshot.stamps, stamps[:2])
    np.testing.assert_allclose(snapshot.poses, poses[:2])  # the first of the duplicates wins


def _edge_rows(stamps, poses, pairs):
    rows = []
    for i, j in pairs:
        step = se2.relative(poses[i], poses[j])
        rows.append([stamps[i], stamps[j], *step, 100.0, 0.0, 0.0, 100.0, 0.0, 400.0])
    return np.array(rows)


def test_constraints_validation_and_slam_graph(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    assert monitor.slam_graph() is None
    for stamp, scan in zip(stamps[:6], ranges[:6]):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps[:6], poses[:6])
    assert monitor.slam_graph() is None  # no constraints yet
    rows = _edge_rows(stamps, poses, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (0, 5)])
    unknown = rows[:1].copy()
    unknown[0, 0] = -50.0  # a stamp with no pose
    monitor.set_constraints(np.concatenate([rows, unknown]))
    slam = monitor.slam_graph()
    graph = slam.graph
    assert graph.vertex_count == 6 and graph.edge_count == 6
    np.testing.assert_array_equal(graph.edge_from, [0, 1, 2, 3, 4, 0])
    np.testing.assert_array_equal(graph.edge_to, [1, 2, 3, 4, 5, 5])
    np.testing.assert_allclose(graph.information[0], np.diag([100.0, 100.0, 400.0]))
    np.testing.assert_allclose(graph.poses, poses[:6])
    np.testing.assert_array_equal(slam.stamps, stamps[:6])
    assert graph.fixed.tolist() == [True] + [False] * 5
    assert graph.is_loop_closure.tolist() == [False] * 5 + [True]
    keyframes = monitor.evaluate()
    np.testing.assert_array_equal(slam.scan_vertices, np.arange(6))
    np.testing.assert_array_equal(slam.ranges, keyframes.ranges)
    assert slam.keyframes_outside == 0

    accepted = monitor.constraints.copy()
    self_loop = rows.copy()
    self_loop[2, 1] = self_loop[2, 0]
    not_definite = rows.copy()
    not_definite[1, 5] = -1.0
    non_finite = rows.copy()
    non_finite[3, 4] = np.nan
    for bad, message in [(rows[:, :10], 'shape'), (rows.ravel(), 'shape'),
                         (self_loop, 'row 2 connects'), (not_definite, 'row 1 .*positive'),
                         (non_finite, 'row 3 has non-finite')]:
        with pytest.raises(ValueError, match=message):
            monitor.set_constraints(bad)
    np.testing.assert_array_equal(monitor.constraints, accepted)


def test_laser_offset_places_the_scans(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    offset = np.array([0.2, -0.05, 0.1])
    keyframe_poses = se2.compose(poses[:30], np.broadcast_to(se2.inverse(offset), (30, 3)))
    monitor = ConsistencyMonitor(EVERY_KEYFRAME,
                                 settings=MonitorSettings(laser_offset=tuple(offset),
                                                          max_partners=0))
    for stamp, scan in zip(stamps[:30], ranges[:30]):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps[:30], keyframe_poses)
    snapshot = monitor.evaluate()
    np.testing.assert_allclose(snapshot.scans().sensor_poses, poses[:30], atol=1e-9)
    _assert_same_verdict(snapshot.result, _oracle(ranges[:30], poses[:30], model))


def test_inconsistent_endpoints_are_the_points_inside_the_other_scan(intel):
    stamps, ranges, poses, model = _by_stamp(intel)
    monitor = ConsistencyMonitor()
    for stamp, scan in zip(stamps, ranges):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps, poses)
    monitor.update_trajectory(stamps, _dragged(poses, len(stamps) // 2))
    snapshot = monitor.evaluate()
    scans, result = snapshot.scans(), snapshot.result
    assert not result.consistent
    points = inconsistent_endpoints(scans, result, max_pairs=3)
    flagged = result.inconsistent[result.pairs].any(axis=1) & result.failed
    worst = np.flatnonzero(flagged)[np.argsort(-result.statistic[flagged], kind='stable')[:3]]
    expected = 0
    for i, j in result.pairs[worst]:
        of_j, of_i = point_distances(scans, i, j)
        expected += np.count_nonzero(of_j) + np.count_nonzero(of_i)
    assert points.shape == (expected, 2)
    all_endpoints = scans.endpoints.reshape(-1, 2)
    assert all(np.any(np.all(all_endpoints == p, axis=1)) for p in points[:20])
    consistent = dataclasses.replace(result, inconsistent=np.zeros_like(result.inconsistent))
    assert inconsistent_endpoints(scans, consistent).shape == (0, 2)


def test_a_clean_trajectory_is_one_with_nothing_to_skip_sort_or_warn_about():
    from map_consistency_ros.core.live.monitor import _clean_trajectory
    stamps = np.array([1.0, 2.0, 3.0])
    poses = np.array([[0.0, 0.0, 0.0], [5.0, -5.0, 3.0], [-10.0, 10.0, -3.0]])
    assert _clean_trajectory(stamps, poses, 10.0)
    faults = [(np.array([1.0, 2.0, 2.0]), poses),  # a stamp twice
              (np.array([1.0, 3.0, 2.0]), poses),  # out of order
              (np.array([1.0, np.nan, 3.0]), poses)]
    for row, column, value in [(1, 0, np.nan), (2, 1, np.inf), (0, 2, np.nan), (1, 0, 10.5),
                               (2, 1, -10.5)]:
        bad = poses.copy()
        bad[row, column] = value
        faults.append((stamps, bad))
    for fault_stamps, fault_poses in faults:
        assert not _clean_trajectory(fault_stamps, fault_poses, 10.0)


def test_settings_are_validated():
    for bad in [dict(laser_offset=(0.0, 0.0)), dict(laser_offset=(0.0, np.nan, 0.0)),
                dict(max_buffered_scans=0), dict(stamp_tolerance=-1.0),
                dict(move_tolerance=np.inf), dict(max_partners=-1)]:
        with pytest.raises(ValueError):
            MonitorSettings(**bad)


def test_a_snapshot_before_any_keyframe_says_it_has_no_scans_to_place():
    snapshot = ConsistencyMonitor().evaluate()
    assert snapshot.result is None and snapshot.keyframe_count == 0
    with pytest.raises(ValueError, match='no keyframes'):
        snapshot.scans()


def test_trajectories_that_do_not_extend_the_last_one_are_matched_again(intel):
    """A trajectory is usually the last one plus a few poses (its slots are carried over); one
    that drops, reorders or shortens poses must be matched again: after every update each
    keyframe stands at its pose in the latest trajectory that holds its stamp."""
    stamps, ranges, poses, model = _by_stamp(intel)
    count = 40
    moved = poses[:count] + np.array([0.05, -0.03, 0.01])
    trajectories = [
        (stamps[:20], poses[:20]),
        (stamps[:30], poses[:30]),  # extends it
        (stamps[:30], moved[:30]),  # the same stamps, poses moved by a loop closure
        (np.delete(stamps[:35], 10), np.delete(poses[:35], 10, axis=0)),  # a pose dropped
        (stamps[:15], poses[:15]),  # shorter
        (stamps[:count][::-1], moved[:count][::-1]),  # reversed: sorted again
    ]
    monitor = ConsistencyMonitor()
    for index, (stamp, scan) in enumerate(zip(stamps[:count], ranges[:count])):
        monitor.add_scan(stamp, scan, model)
        if index == 25:  # scans keep arriving between trajectories
            monitor.update_trajectory(*trajectories[0])
    latest = {}  # stamp -> its pose in the latest trajectory holding it
    for stamp, pose in zip(*trajectories[0]):
        latest[float(stamp)] = pose
    for path_stamps, path_poses in trajectories[1:]:
        monitor.update_trajectory(path_stamps, path_poses)
        for stamp, pose in zip(path_stamps, path_poses):
            latest[float(stamp)] = pose
        snapshot = monitor.evaluate()
        assert snapshot.stamps.size > 10
        expected = np.array([latest[float(stamp)] for stamp in snapshot.stamps])
        np.testing.assert_allclose(snapshot.poses, expected)


def test_the_slam_graph_holds_every_pose_its_constraints_name_folded_or_not(intel):
    """Scans folded into a viewpoint are no keyframes, but their poses stay vertices of the
    back-end's graph; keyframes no constraint names are left out (and counted)."""
    stamps, ranges, poses, model = _by_stamp(intel)
    count = 40
    monitor = ConsistencyMonitor()  # the default viewpoint spacing folds some of these scans
    for stamp, scan in zip(stamps[:count], ranges[:count]):
        monitor.add_scan(stamp, scan, model)
    monitor.update_trajectory(stamps[:count], poses[:count])
    keyframes = monitor.evaluate()
    assert 0 < keyframes.folded_scans < count - 2
    named = count - 5  # the last five poses: in the trajectory, but no constraint names them
    monitor.set_constraints(_edge_rows(stamps, poses, [(k, k + 1) for k in range(named - 1)]
                                       + [(0, named - 1)]))
    slam = monitor.slam_graph()
    np.testing.assert_array_equal(slam.stamps, stamps[:named])
    np.testing.assert_allclose(slam.graph.poses, poses[:named])
    assert slam.graph.edge_count == named
    inside = np.isin(keyframes.stamps, stamps[:named])
    np.testing.assert_array_equal(slam.stamps[slam.scan_vertices], keyframes.stamps[inside])
    np.testing.assert_array_equal(slam.ranges, keyframes.ranges[inside])
    assert slam.keyframes_outside == int((~inside).sum()) > 0
    placed = slam.scans_at(slam.graph.poses)
    np.testing.assert_allclose(placed.sensor_poses, keyframes.poses[inside])
