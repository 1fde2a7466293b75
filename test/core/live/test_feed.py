"""The feed from input records to the monitor: the node's and replay's one path."""
import math

import numpy as np
import pytest

from map_consistency_ros.core.consistency import ConsistencyParameters, check_consistency
from map_consistency_ros.core.geometry import ScanSet, SensorModel, viewpoint_rows
from map_consistency_ros.core.live import (RESET_CONFIRMATIONS, Applied, Constraints, FeedSettings,
                                           GraphSnapshot, KeyframeEstimate, MonitorFeed,
                                           MonitorSettings, PoseKeyframer, PoseSample, Scan,
                                           ScanGaps)
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

MODEL = SensorModel(angle_min=-math.pi / 2, angle_increment=math.pi / 179, max_range=81.83)
SCANS = 60
# Tests of how poses become keyframes: every keyframe is a viewpoint of the test.
EVERY_KEYFRAME = ConsistencyParameters(viewpoint_spacing=0.0, viewpoint_turn=0.0)


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return (log.timestamps[:SCANS], log.ranges[:SCANS], log.laser_poses[:SCANS],
            sensor_model(log))


def _scan_records(stamps, ranges, model):
    return [Scan(stamp=float(t), ranges=r, model=model) for t, r in zip(stamps, ranges)]


def test_keyframe_estimates_give_the_batch_verdict(intel):
    stamps, ranges, poses, model = intel
    feed = MonitorFeed()
    for index, scan in enumerate(_scan_records(stamps, ranges, model)):
        assert feed.apply(scan).warnings == ()
        applied = feed.apply(KeyframeEstimate(stamps=stamps[:index + 1], poses=poses[:index + 1]))
        # a keyframe folded into the previous viewpoint changes nothing to test
        assert applied.summary is None or applied.summary.new_keyframes == 1
    # the viewpoints check selects on the same poses (they never moved)
    parameters = ConsistencyParameters()
    rows = viewpoint_rows(poses, parameters.viewpoint_spacing, parameters.viewpoint_turn)
    assert 0 < SCANS - rows.size == feed.monitor.evaluate().folded_scans
    np.testing.assert_array_equal(feed.monitor.evaluate().stamps, stamps[rows])
    oracle = check_consistency(ScanSet.from_ranges(ranges[rows], poses[rows], model))
    result = feed.monitor.evaluate().result
    np.testing.assert_array_equal(result.inconsistent, oracle.inconsistent)
    assert result.failed_pair_count == oracle.failed_pair_count


def test_single_poses_are_keyframed_and_late_estimates_refused(intel):
    stamps, ranges, poses, model = intel
    feed = MonitorFeed(EVERY_KEYFRAME, settings=FeedSettings(
        pose_source='odometry', keyframe_distance=0.3, keyframe_angle=0.2))
    scans = _scan_records(stamps, ranges, model)
    for scan, stamp, pose in zip(scans, stamps, poses):
        feed.apply(scan)
        feed.apply(PoseSample(stamp=float(stamp), pose=pose))
    keyframes = feed.monitor.keyframe_count
    assert 1 < keyframes < SCANS  # the robot does not move 0.3 m between every scan
    np.testing.assert_allclose(feed.monitor.evaluate().poses, np.array(feed.keyframer.poses))
    refused = feed.apply(KeyframeEstimate(stamps=stamps, poses=poses))
    assert refused.summary is None and "pose_source is 'odometry'" in refused.warnings[0]


def test_the_estimate_stamp_names_the_last_estimate_that_changed_the_map(intel):
    stamps, ranges, poses, model = intel
    feed = MonitorFeed()
    assert math.isnan(feed.estimate_stamp)  # no estimate yet
    for scan in _scan_records(stamps, ranges, model):
        feed.apply(scan)
    feed.apply(KeyframeEstimate(stamps=stamps, poses=poses, stamp=1000.5))
    assert feed.estimate_stamp == 1000.5
    # the same estimate again changes nothing: the verdict on it still judged 1000.5
    assert feed.apply(KeyframeEstimate(stamps=stamps, poses=poses, stamp=1001.0)).summary is None
    assert feed.estimate_stamp == 1000.5
    moved = poses.copy()
    moved[SCANS // 2:, 0] += 0.5  # a loop closure moves half of the keyframes
    feed.apply(KeyframeEstimate(stamps=stamps, poses=moved, stamp=1002.0))
    assert feed.estimate_stamp == 1002.0
    # without a header stamp (a bridge's output): the newest keyframe's stamp
    feed.apply(KeyframeEstimate(stamps=stamps, poses=poses))
    assert feed.estimate_stamp == stamps.max()


def test_a_scan_completing_an_estimate_changes_the_map_under_its_name(intel):
    # The node takes topics as they come: a Path may name a scan that has not arrived yet.
    stamps, ranges, poses, model = intel
    feed = MonitorFeed(EVERY_KEYFRAME)
    scans = _scan_records(stamps, ranges, model)
    for scan in scans[:-1]:
        feed.apply(scan)
    feed.apply(KeyframeEstimate(stamps=stamps[:-1], poses=poses[:-1], stamp=500.0))
    waiting = feed.apply(KeyframeEstimate(stamps=stamps, poses=poses, stamp=501.0))
    assert waiting.summary is None and feed.estimate_stamp == 500.0
    assert feed.apply(scans[-1]).summary is not None  # the last keyframe, of estimate 501
    assert feed.monitor.keyframe_count == SCANS and feed.estimate_stamp == 501.0


def test_single_poses_name_their_estimate_by_the_newest_keyframe(intel):
    stamps, ranges, poses, model = intel
    feed = MonitorFeed(settings=FeedSettings(pose_source='odometry', keyframe_distance=0.3,
                                             keyframe_angle=0.2))
    for scan, stamp, pose in zip(_scan_records(stamps, ranges, model), stamps, poses):
        feed.apply(scan)
        feed.apply(PoseSample(stamp=float(stamp), pose=pose))
    assert feed.estimate_stamp == feed.monitor.evaluate().stamps.max()


@pytest.mark.parametrize('pose, problem', [
    ([math.nan, 0.0, 0.0], 'non-finite'), ([1e300, 0.0, 0.0], 'beyond max_pose_extent'),
    ([0.0, 0.0, math.nan], 'unusable quaternion')])
def test_absurd_single_poses_are_skipped_with_a_warning(pose, problem):
    feed = MonitorFeed(settings=FeedSettings(pose_source='pose'))
    applied = feed.apply(PoseSample(stamp=1.0, pose=np.array(pose)))
    assert applied.summary is None and problem in applied.warnings[0]


def test_absurd_keyframe_poses_are_skipped_with_a_warning(intel):
    stamps, ranges, poses, model = intel
    feed = MonitorFeed(monitor_settings=MonitorSettings(max_pose_extent=1000.0))
    for scan in _scan_records(stamps[:3], ranges[:3], model):
        feed.apply(scan)
    bad = poses[:3].copy()
    bad[1, 0] = 1e300
    bad[2, 2] = math.nan  # an infinite quaternion component gives no heading
    applied = feed.apply(KeyframeEstimate(stamps=stamps[:3], poses=bad))
    assert feed.monitor.keyframe_count == 1
    assert any('beyond max_pose_extent = 1000 m' in w for w in applied.warnings)
    assert any('non-finite' in w for w in applied.warnings)


def test_a_stamp_jump_resets_only_when_confirmed(intel):
    stamps, ranges, poses, model = intel
    feed = MonitorFeed()
    scans = _scan_records(stamps, ranges, model)
    for index, scan in enumerate(scans[:20]):
        feed.apply(scan)
    feed.apply(KeyframeEstimate(stamps=stamps[:20], poses=poses[:20]))
    assert feed.monitor.keyframe_count == 20
    # one stray old stamp is held, then skipped when the session goes on
    stray = Scan(stamp=float(stamps[0]) - 100.0, ranges=ranges[0], model=model)
    assert feed.apply(stray).warnings == ()
    for scan in scans[20:20 + RESET_CONFIRMATIONS - 1]:
        assert feed.apply(scan).warnings == ()
    applied = feed.apply(scans[20 + RESET_CONFIRMATIONS - 1])
    assert 'skipped: stamped more than reset_stamp_jump' in applied.warnings[0]
    assert feed.resets == 0 and feed.monitor.keyframe_count == 20
    # the same session again (a restarted SLAM stack, a looped bag): a reset, scans kept
    for scan in scans[:RESET_CONFIRMATIONS - 1]:
        assert feed.apply(scan).reset == ''
    applied = feed.apply(scans[RESET_CONFIRMATIONS - 1])
    assert 'jumped back' in applied.reset and feed.resets == 1
    feed.apply(KeyframeEstimate(stamps=stamps[:RESET_CONFIRMATIONS],
                                poses=poses[:RESET_CONFIRMATIONS]))
    assert feed.monitor.keyframe_count == RESET_CONFIRMATIONS


@pytest.mark.parametrize('stray_offset', [-0.5, -150.0])
def test_a_stray_old_scan_before_a_restart_costs_no_scan_of_the_new_session(intel,
                                                                           stray_offset):
    """A late scan of the ending session, stamped more than reset_stamp_jump before its newest
    (-0.5 s: newer than the new session's scans, -150 s: older), then a restarted session:
    one reset, every scan of the new session kept."""
    stamps, ranges, poses, model = intel
    feed = MonitorFeed(EVERY_KEYFRAME)
    for scan in _scan_records(stamps[:20], ranges[:20], model):
        feed.apply(scan)
    feed.apply(KeyframeEstimate(stamps=stamps[:20], poses=poses[:20]))
    stray = Scan(stamp=float(stamps[10]) + stray_offset, ranges=ranges[10], model=model)
    restarted = stamps[:30] - 100.0
    applied = [feed.apply(scan) for scan in
               [stray] + _scan_records(restarted, ranges[:30], model)]
    assert feed.resets == 1 and sum(bool(a.reset) for a in applied) == 1
    feed.apply(KeyframeEstimate(stamps=restarted, poses=poses[:30]))
    assert feed.monitor.keyframe_count == 30
    newer = stray_offset > -100.0  # the stray jumps back from nothing of the new session
    warned = [w for a in applied for w in a.warnings if 'skipped' in w]
    assert len(warned) == (1 if newer else 0)
    assert feed.monitor.evaluate().buffered_scans == (0 if newer else 1)


def test_a_late_scan_among_a_restarted_sessions_first_scans_costs_none_of_them(intel):
    """A scan of the ending session comes after the restarted stack's first two: the held
    scans still confirm one reset, and every scan of the new session is kept."""
    stamps, ranges, poses, model = intel
    feed = MonitorFeed(EVERY_KEYFRAME)
    for scan in _scan_records(stamps[:20], ranges[:20], model):
        feed.apply(scan)
    feed.apply(KeyframeEstimate(stamps=stamps[:20], poses=poses[:20]))
    restarted = _scan_records(stamps[:30] - 1000.0, ranges[:30], model)
    late = Scan(stamp=float(stamps[19]) + 0.01, ranges=ranges[19], model=model)
    applied = [feed.apply(scan) for scan in restarted[:2] + [late] + restarted[2:]]
    assert feed.resets == 1 and not any('skipped' in w for a in applied for w in a.warnings)
    feed.apply(KeyframeEstimate(stamps=stamps[:30] - 1000.0, poses=poses[:30]))
    assert feed.monitor.keyframe_count == 30


def test_constraints_and_bad_constraints():
    feed = MonitorFeed()
    assert feed.apply(Constraints(rows=np.zeros((0, 11)))).warnings == ()
    rows = np.array([[1.0, 2.0, 0.1, 0.0, 0.0, 1e300, 0.0, 0.0, 1.0, 0.0, 1.0]])
    assert 'beyond 1e+12' in feed.apply(Constraints(rows=rows)).warnings[0]


def test_stamp_gaps_count_missing_scans():
    gaps = ScanGaps()
    for stamp in np.arange(20) * 0.025:
        assert gaps.add(float(stamp)) == 0
    assert gaps.add(0.475 + 4 * 0.025) == 3  # three scans of a 40 Hz driver never came
    assert gaps.missing == 3


def test_the_period_quantiles_are_numpys_linear_percentiles():
    from map_consistency_ros.core.live._feed import _percentiles
    rng = np.random.default_rng(5)
    for size in (1, 2, 8, 9, 63, 64):
        sample = rng.exponential(0.05, size) * rng.choice([1e-3, 1.0, 10.0])
        expected = np.percentile(sample, [10, 50, 90])
        np.testing.assert_array_equal(_percentiles(sorted(sample.tolist()), (0.1, 0.5, 0.9)),
                                      expected)


def test_scans_published_twice_do_not_shrink_the_period():
    gaps = ScanGaps()
    for stamp in np.arange(40) * 0.1:  # a 10 Hz driver publishing every scan twice
        assert gaps.add(float(stamp)) == 0
        assert gaps.add(float(stamp) + 6e-6) == 0
    assert gaps.add(3.9 + 0.3) == 2  # the period stays 0.1 s: two scans never came
    assert gaps.missing == 2


def test_stamps_in_bursts_have_no_period_to_count_gaps_by():
    # Intel rebuilt at its native rate: runs of scans 8 ms apart between 0.1 s intervals; the
    # median interval (8 ms) is no period, and 0.1 s is not twelve lost scans
    gaps = ScanGaps()
    stamp = 0.0
    for _ in range(40):
        for interval in (0.008, 0.008, 0.008, 0.1):
            stamp += interval
            assert gaps.add(stamp) == 0
    assert gaps.missing == 0


def _sample(stamp, pose):
    return PoseSample(stamp=stamp, pose=np.asarray(pose, dtype=float), frame_id='odom',
                      child_frame_id='base_link')


def _scan(stamp):
    return Scan(stamp=stamp, ranges=np.ones(3, dtype=np.float32), model=MODEL, frame_id='laser')


def test_odometry_keyframes_interpolate_and_select():
    keyframes = PoseKeyframer(min_distance=1.0, min_angle=0.5)
    keyframes.add_scan(_scan(0.5))  # before any pose: cannot be placed
    assert keyframes.add_pose(_sample(1.0, [1.0, 2.0, math.pi / 2])) == []
    assert keyframes.unplaced == 1
    for stamp in (1.5, 2.0, 2.5, 3.5):
        keyframes.add_scan(_scan(stamp))
    # From (1, 2, pi/2) the robot moves 2 m forward and turns 0.4 rad by t = 3.
    placed = keyframes.add_pose(_sample(3.0, [1.0, 4.0, math.pi / 2 + 0.4]))
    # t = 1.5: a quarter of the step, (0.5 m, 0.1 rad) in the start frame -> first keyframe.
    # t = 2.0: 0.5 m and 0.1 rad further: below both thresholds. t = 2.5: 1 m further.
    # t = 3.5 waits for a later pose.
    assert [scan.stamp for scan in placed] == [1.5, 2.5]
    np.testing.assert_allclose(keyframes.poses, [[1.0, 2.5, math.pi / 2 + 0.1],
                                                 [1.0, 3.5, math.pi / 2 + 0.3]], atol=1e-12)
    assert keyframes.stamps == [1.5, 2.5]
    assert [scan.stamp for scan in keyframes.add_pose(_sample(4.0, [1.0, 6.0, 2.0]))] == [3.5]


def test_odometry_keyframes_turning_in_place_and_exact_stamps():
    keyframes = PoseKeyframer(min_distance=1.0, min_angle=0.5)
    keyframes.add_pose(_sample(0.0, [1.0, 1.0, 3.0]))
    keyframes.add_scan(_scan(0.0))
    keyframes.add_scan(_scan(1.0))
    placed = keyframes.add_pose(_sample(1.0, [1.0, 1.0, -2.7]))  # wraps through pi: +0.583 rad
    assert [scan.stamp for scan in placed] == [0.0, 1.0]
    np.testing.assert_allclose(keyframes.poses[1], [1.0, 1.0, -2.7])
    with pytest.raises(ValueError):
        PoseKeyframer(min_distance=-1.0, min_angle=0.1)




def _slam_toolbox_records(stream):
    """The stream's records in publishing order: scan, its pose, and a snapshot every 10."""
    snapshots = {index: (ids, positions) for index, ids, positions in stream.snapshots}
    for index, stamp in enumerate(stream.stamps):
        yield Scan(stamp=float(stamp), ranges=stream.ranges[index], model=stream.model)
        yield PoseSample(stamp=float(stamp), pose=stream.poses[index], frame_id='map')
        if index in snapshots:
            yield GraphSnapshot(*snapshots[index], frame_id='map')


def test_slam_toolbox_poses_and_markers_follow_a_loop_closure(slam_toolbox_stream):
    stream = slam_toolbox_stream
    feed = MonitorFeed(EVERY_KEYFRAME, settings=FeedSettings(pose_source='slam_toolbox'))
    updates = 0
    for record in _slam_toolbox_records(stream):
        applied = feed.apply(record)
        assert applied.warnings == ()
        updates += applied.summary is not None
    assert updates == len(stream.snapshots)  # each snapshot, and only a snapshot, updates
    snapshot = feed.monitor.evaluate()
    np.testing.assert_array_equal(snapshot.stamps, stream.stamps)
    # positions from the markers; the correction's 0.1 rad recovered from the rigid motion
    np.testing.assert_allclose(snapshot.poses[:, :2], stream.final[:, :2], atol=1e-9)
    heading_error = np.abs(np.angle(np.exp(1j * (snapshot.poses[:, 2] - stream.final[:, 2]))))
    assert heading_error.max() < 1e-3
    counts = feed.bridge_counts
    assert (counts.keyframes, counts.pending_poses, counts.vertices_without_pose) == (
        len(stream.stamps), 0, 0)
    # the verdict of a back-end publishing its full keyframe poses (a Path) at each snapshot
    path = MonitorFeed(EVERY_KEYFRAME)
    for index, ids, _ in stream.snapshots:
        for row in range(index - 9, index + 1):
            path.apply(Scan(stamp=float(stream.stamps[row]), ranges=stream.ranges[row],
                            model=stream.model))
        graph = stream.final if index >= stream.loop else stream.truth
        path.apply(KeyframeEstimate(stamps=stream.stamps[ids], poses=graph[ids]))
    expected = path.monitor.evaluate().result
    assert expected.inconsistent.any()  # the wrong loop closure shows
    np.testing.assert_array_equal(snapshot.result.inconsistent, expected.inconsistent)
    assert snapshot.result.failed_pair_count == expected.failed_pair_count


def test_slam_toolbox_bad_records_are_warned_about(slam_toolbox_stream):
    stream = slam_toolbox_stream
    feed = MonitorFeed(settings=FeedSettings(pose_source='slam_toolbox'))
    stamps = stream.stamps
    for index in range(3):
        feed.apply(Scan(stamp=float(stamps[index]), ranges=stream.ranges[index],
                        model=stream.model))
    feed.apply(PoseSample(stamp=float(stamps[0]), pose=stream.poses[0]))
    again = feed.apply(PoseSample(stamp=float(stamps[0]), pose=stream.poses[0]))
    assert 'already received; later vertices may be associated' in again.warnings[0]
    # a snapshot that overtook a pose waits for it
    early = feed.apply(GraphSnapshot(ids=np.arange(2), positions=stream.poses[:2, :2]))
    assert early == Applied()
    released = feed.apply(PoseSample(stamp=float(stamps[1]), pose=stream.poses[1]))
    assert released.summary is not None and released.summary.new_keyframes == 2
    assert released.warnings == ()
    # ... until the next snapshot: then its pose was lost
    assert feed.apply(GraphSnapshot(ids=np.arange(3), positions=stream.poses[:3, :2])) == (
        Applied())
    duplicate = feed.apply(GraphSnapshot(ids=np.array([0, 0]), positions=np.zeros((2, 2))))
    assert duplicate.summary is None and duplicate.warnings[0] == (
        'graph snapshot: 1 vertices have no pose message (lost, or sent before the node '
        'listened) and are left out')
    assert 'duplicate vertex ids [0]' in duplicate.warnings[1]
    empty = feed.apply(GraphSnapshot(ids=np.zeros(0, dtype=int), positions=np.zeros((0, 2))))
    assert empty.summary is None and 'without vertices ignored' in empty.warnings[0]
    path = feed.apply(KeyframeEstimate(stamps=stamps[:1], poses=stream.poses[:1]))
    assert "pose_source is 'slam_toolbox'; ignored" in path.warnings[0]
    assert feed.monitor.keyframe_count == 2
    other = MonitorFeed(settings=FeedSettings(pose_source='pose_with_covariance'))
    refused = other.apply(GraphSnapshot(ids=np.arange(1), positions=np.zeros((1, 2))))
    assert refused.summary is None and "pose_source is 'pose_with_covariance'" in (
        refused.warnings[0])


def test_slam_toolbox_snapshots_overtaking_poses_give_the_log_order_verdict(
        slam_toolbox_stream):
    """The node takes one message per topic at a time, so a snapshot can arrive before the last
    poses of its vertices: the feed holds it for them, and judges as in log order (replay)."""
    in_order = list(_slam_toolbox_records(slam_toolbox_stream))
    overtaking = []
    for record in in_order:
        if isinstance(record, GraphSnapshot):
            # before the last 3 pose messages (and the scans between them)
            where = [i for i, r in enumerate(overtaking) if isinstance(r, PoseSample)][-3]
            overtaking.insert(where, record)
        else:
            overtaking.append(record)
    results = []
    for records in (in_order, overtaking):
        feed = MonitorFeed(settings=FeedSettings(pose_source='slam_toolbox'))
        assert all(feed.apply(record).warnings == () for record in records)
        results.append(feed.monitor.evaluate())
    np.testing.assert_array_equal(results[0].poses, results[1].poses)
    np.testing.assert_array_equal(results[0].incremental_poses, results[1].incremental_poses)
    np.testing.assert_array_equal(results[0].result.inconsistent, results[1].result.inconsistent)
    assert results[0].result.failed_pair_count == results[1].result.failed_pair_count

