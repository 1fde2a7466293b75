"""The account of every scan received: each in exactly one category, after every record."""
from __future__ import annotations

import numpy as np
import pytest

from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.geometry import SensorModel
from map_consistency_ros.core.live import (RESET_CONFIRMATIONS, DroppedScans, FeedSettings,
                                           KeyframeEstimate, LivePipeline, MonitorSettings,
                                           PoseSample, PoseSource, Scan, ScanCounts)
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

SCANS = 100


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return (log.timestamps[:SCANS], log.ranges[:SCANS], log.laser_poses[:SCANS],
            sensor_model(log))


class Account:
    """A pipeline whose account is checked after every record: balanced, and every scan
    given to it received."""

    def __init__(self, pipeline: LivePipeline) -> None:
        self.pipeline = pipeline
        self.given = 0

    def apply(self, record):
        if isinstance(record, Scan):
            self.given += 1
        elif isinstance(record, DroppedScans):
            self.given += len(record.lost) + len(record.unreadable)
        applied = self.pipeline.apply(record)
        counts = self.counts()
        assert counts.balanced(), counts
        assert counts.received == self.given, counts
        return applied

    def counts(self) -> ScanCounts:
        return self.pipeline.evaluate().scan_counts


def test_every_scan_of_a_faulty_stream_is_counted_once(intel):
    stamps, ranges, poses, model = intel
    account = Account(LivePipeline(monitor_settings=MonitorSettings(max_buffered_scans=20)))
    other = SensorModel(model.angle_min, model.angle_increment * 0.5, model.max_range)
    lost = [float(stamps[30]), float(stamps[31])]  # dropped from a full queue ahead
    for k in range(SCANS):
        if k in (30, 31, 33):
            continue
        scan = Scan(stamp=float(stamps[k]), ranges=ranges[k], model=model)
        account.apply(scan)
        if k == 12:
            account.apply(scan)  # published twice: the second is refused
        if k == 20:
            account.apply(Scan(stamp=float(stamps[k]) + 0.01, ranges=ranges[k], model=other))
        if k % 10 == 9 and k < 80:  # the estimate lags five scans, names every one but 40..49
            named = np.array([j for j in range(k - 4) if not 40 <= j < 50])
            account.apply(KeyframeEstimate(stamps=stamps[named], poses=poses[named]))
    # unreadable scans: one whose header stamp could be read, two that could not
    account.apply(DroppedScans(lost=np.array(lost),
                               unreadable=np.array([float(stamps[33]), np.nan, np.nan])))
    counts = account.counts()
    monitor = account.pipeline.monitor
    snapshot = account.pipeline.evaluate()
    assert counts.keyframes == monitor.keyframe_count and counts.folded == snapshot.folded_scans
    assert counts.rejected == 2 + 3 and counts.lost_in_queue == 2
    # scans 80..99 came without an estimate: the full buffer let 75..79 go before any pose
    # reached them (lost); it let 40..49 go after the estimate went past them (passed over)
    assert counts.waiting == snapshot.buffered_scans == 20
    assert counts.passed_over == 10 and counts.pushed_out == 5
    assert counts.earlier_sessions == 0 and counts.unplaced == 0
    # the poses of the scans lost or rejected before the pipeline name scans that came
    assert snapshot.poses_without_scan == 0
    # a reset: everything so far was the previous session's
    account.pipeline.reset('test')
    counts = account.counts()
    assert counts == ScanCounts(received=account.given, earlier_sessions=account.given)


def test_an_automatic_reset_keeps_the_scans_that_confirmed_it(intel):
    stamps, ranges, poses, model = intel
    account = Account(LivePipeline())
    for k in range(20):
        account.apply(Scan(stamp=float(stamps[k]), ranges=ranges[k], model=model))
    account.apply(KeyframeEstimate(stamps=stamps[:20], poses=poses[:20]))
    before = account.given
    # a stray held and skipped: rejected
    account.apply(Scan(stamp=float(stamps[0]) - 50.0, ranges=ranges[0], model=model))
    for k in range(20, 20 + RESET_CONFIRMATIONS):
        account.apply(Scan(stamp=float(stamps[k]), ranges=ranges[k], model=model))
    assert account.counts().rejected == 1
    before = account.given
    # a stray just before a restarted session: one reset, the stray rejected in the new one
    account.apply(Scan(stamp=float(stamps[19]) - 2.0, ranges=ranges[0], model=model))
    restarted = stamps[:RESET_CONFIRMATIONS + 3] - 1000.0
    for k, stamp in enumerate(restarted):
        applied = account.apply(Scan(stamp=float(stamp), ranges=ranges[k], model=model))
        assert not applied.reset or k == RESET_CONFIRMATIONS - 1
    counts = account.counts()
    assert account.pipeline.feed.resets == 1
    assert counts.earlier_sessions == before and counts.rejected == 1
    assert counts.waiting == len(restarted)


def test_single_poses_place_pass_over_or_lose_every_scan(intel):
    stamps, ranges, poses, model = intel
    feed = FeedSettings(pose_source=PoseSource.ODOMETRY, keyframe_distance=0.3)
    account = Account(LivePipeline(ConsistencyParameters(viewpoint_spacing=0.0,
                                                         viewpoint_turn=0.0),
                                   feed_settings=feed))
    for k in range(40):
        account.apply(Scan(stamp=float(stamps[k]), ranges=ranges[k], model=model))
        if k >= 6 and k % 3 == 0:  # poses from scan 6 on: scans 0..5 have none before them
            account.apply(PoseSample(stamp=float(stamps[k]), pose=poses[k]))
    counts = account.counts()
    assert counts.unplaced == 6 and counts.passed_over > 0 and counts.keyframes > 0
    assert counts.waiting == 39 - 39  # scan 39 is bracketed by its own pose
    assert counts.lost == 6


def test_a_queue_in_front_adds_what_it_holds_and_what_is_on_its_way():
    pipeline = ScanCounts(received=10, keyframes=4, folded=3, waiting=1, rejected=2)
    node = pipeline.with_intake(received=20, queued=4, handed=13, lost_in_queue=2, unreadable=1)
    assert node.balanced() and node.received == 20
    assert node.waiting == 1 + 4 + 3 and node.lost_in_queue == 2 and node.rejected == 3
    assert not ScanCounts(received=1).balanced() and not ScanCounts(received=-1,
                                                                    rejected=-1).balanced()
