"""A pose estimate that stood still while the robot moved is found, by `check` and by the live
pipeline alike, and folding no longer hides it; scans of a robot that stands still are no such
finding, and folding at moving poses is unchanged on the corrected logs."""
from pathlib import Path

import numpy as np
import pytest

from map_consistency_ros.core.consistency import ConsistencyParameters, select_viewpoints
from map_consistency_ros.core.geometry import (ScanSet, disagreement, same_pose,
                                               viewpoint_rows)
from map_consistency_ros.core.live import KeyframeEstimate, LivePipeline, Scan
from map_consistency_ros.core.verdict import INCONSISTENT, check_map
from map_consistency_ros.core.verdict.reporting import assessment_report, to_json
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

NATIVE = Path(__file__).resolve().parents[3] / 'data' / 'density' / 'intel-native.log.gz'
# 120 scans of the Intel lab at the laser's rate: 9.4 m down a corridor
CORRIDOR = slice(280, 400)


@pytest.fixture(scope='module')
def corridor():
    log = read_carmen_log(NATIVE)
    return (log.timestamps[CORRIDOR], log.ranges[CORRIDOR], log.laser_poses[CORRIDOR],
            sensor_model(log))


def _frozen(poses):
    return np.tile(poses[0], (len(poses), 1))


def test_scans_at_one_pose_that_disagree_are_viewpoints_of_their_own(corridor):
    _, ranges, poses, model = corridor
    frozen = _frozen(poses)
    scans = ScanSet.from_ranges(ranges, frozen, model)
    assert viewpoint_rows(frozen, 0.4, 0.4).tolist() == [0]  # by pose alone: one viewpoint
    rows = select_viewpoints(scans, ConsistencyParameters())
    assert rows.size >= 5 and rows[0] == 0
    # every new viewpoint disagrees with the one before it; the scans folded agree with theirs
    parameters = ConsistencyParameters()
    for before, after in zip(rows[:-1], rows[1:]):
        assert disagreement(scans, before, after, parameters.fold_depth) > 0.25
        for folded in range(before + 1, after):
            assert disagreement(scans, before, folded, parameters.fold_depth) <= 0.25


def test_a_frozen_estimate_fails_the_map_with_a_line_that_says_so(corridor, strict_json):
    _, ranges, poses, model = corridor
    every = ScanSet.from_ranges(ranges, _frozen(poses), model)
    for parameters in (ConsistencyParameters(),
                       ConsistencyParameters(viewpoint_spacing=0.0, viewpoint_turn=0.0)):
        assessment = check_map(every.take(select_viewpoints(every, parameters)), parameters)
        assert assessment.outcome == INCONSISTENT and assessment.frozen
        assert 'the pose estimate stood still over' in assessment.summary_line()
        report = strict_json(to_json(assessment_report(assessment)))
        assert report['frozen_estimates'][0]['changes'] >= 3


def test_the_corridor_at_its_true_poses_is_no_frozen_estimate(corridor):
    _, ranges, poses, model = corridor
    every = ScanSet.from_ranges(ranges, poses, model)
    assert not check_map(every.take(select_viewpoints(every, ConsistencyParameters()))).frozen


def test_a_robot_standing_still_is_no_frozen_estimate(shared_data):
    # the same scan 30 times at one pose (noise of 1 cm): it agrees with itself
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    model = sensor_model(log)
    rng = np.random.default_rng(3)
    ranges = log.ranges[[100] * 30] + rng.normal(0.0, 0.01, (30, log.ranges.shape[1]))
    poses = np.tile(log.laser_poses[100], (30, 1))
    every = ScanSet.from_ranges(ranges, poses, model)
    assert select_viewpoints(every, ConsistencyParameters()).tolist() == [0]
    assessment = check_map(every, ConsistencyParameters(viewpoint_spacing=0.0,
                                                        viewpoint_turn=0.0))
    assert not assessment.frozen


@pytest.mark.parametrize('name', ['intel/intel.gfs.log', 'fr079/freiburg-079-corrected.log.gz'])
def test_folding_by_agreement_keeps_the_viewpoints_of_the_corrected_logs(shared_data, name):
    log = read_carmen_log(shared_data / name)
    scans = ScanSet.from_ranges(log.ranges, log.laser_poses, sensor_model(log))
    np.testing.assert_array_equal(select_viewpoints(scans, ConsistencyParameters()),
                                  viewpoint_rows(log.laser_poses, 0.4, 0.4))


def test_same_pose_is_a_repeated_pose_across_the_angle_wrap():
    assert same_pose([0.0, 0.0, np.pi - 0.001], [0.005, 0.0, -np.pi + 0.001])
    assert not same_pose([0.0, 0.0, 0.0], [0.02, 0.0, 0.0])
    assert not same_pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.02])


def test_the_live_pipeline_finds_the_frozen_estimate_as_check_does(corridor):
    stamps, ranges, poses, model = corridor
    frozen = _frozen(poses)
    pipeline = LivePipeline()
    for index, (stamp, scan) in enumerate(zip(stamps, ranges)):
        pipeline.apply(Scan(stamp=float(stamp), ranges=scan, model=model))
        pipeline.apply(KeyframeEstimate(stamps=stamps[:index + 1], poses=frozen[:index + 1],
                                        stamp=float(stamp)))
    snapshot = pipeline.evaluate()
    every = ScanSet.from_ranges(ranges, frozen, model)
    rows = select_viewpoints(every, ConsistencyParameters())
    np.testing.assert_array_equal(snapshot.stamps, stamps[rows])
    assessment = pipeline.explain(snapshot).assessment
    assert assessment.outcome == INCONSISTENT and assessment.frozen
