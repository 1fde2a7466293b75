"""A verdict is earned: too few tested pairs for the test to have found a failure is "nothing
to judge", never CONSISTENT, while a failure found is reported however little was tested."""
import numpy as np
import pytest
from scipy import stats

from map_consistency_ros.core.geometry import ScanSet
from map_consistency_ros.core.verdict import (CONSISTENT, INCONSISTENT, NOTHING_TO_JUDGE,
                                              check_map,
                                              flaggable_pair_count)
from map_consistency_ros.core.verdict.reporting import assessment_report, to_json
from map_consistency_ros.io import carmen


@pytest.fixture(scope='module')
def intel(shared_data):
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    return log, carmen.sensor_model(log, max_range=8.0)


@pytest.mark.parametrize('probability, alpha', [(0.015, 0.01), (0.05, 0.05), (0.2, 0.01),
                                                (0.001, 1e-6)])
def test_flaggable_pair_count_is_the_fewest_pairs_whose_all_failing_beats_chance(probability,
                                                                                   alpha):
    # oracle: scipy's binomial survival; r failures of r flag the scan when P(X >= r) <= alpha
    count = flaggable_pair_count(probability, alpha)
    assert stats.binom.sf(count - 1, count, probability) <= alpha
    if count > 1:
        assert stats.binom.sf(count - 2, count - 1, probability) > alpha


def _scans(intel, rows, poses=None):
    log, model = intel
    rows = np.asarray(rows)
    return ScanSet.from_ranges(log.ranges[rows], log.laser_poses[rows] if poses is None
                               else poses, model)


def test_one_scan_is_nothing_to_judge(intel):
    assessment = check_map(_scans(intel, [0]))
    assert assessment.outcome == NOTHING_TO_JUDGE and not assessment.consistent
    assert assessment.summary_line().startswith('NOTHING TO JUDGE: no scan has')


def test_one_scan_twice_is_nothing_to_judge(intel):
    scans = _scans(intel, [0, 0])  # one pair, which even failing is within chance
    assessment = check_map(scans)
    assert assessment.outcome == NOTHING_TO_JUDGE


def test_scans_that_hit_nothing_are_nothing_to_judge(intel):
    log, model = intel
    for value in (model.max_range, 0.0, -1.0, np.inf, np.nan):
        ranges = np.full((30, log.ranges.shape[1]), value)
        scans = ScanSet.from_ranges(ranges, log.laser_poses[:30], model)
        assessment = check_map(scans)
        assert assessment.outcome == NOTHING_TO_JUDGE, value
        report = assessment_report(assessment)
        assert report['verdict'] == 'nothing to judge'
        assert 'tested pairs' in report['nothing_to_judge_reason']
        to_json(report)


def test_a_stretch_of_the_real_map_is_judged(intel):
    assessment = check_map(_scans(intel, np.arange(60)))
    assert assessment.evidence.sufficient
    assert assessment.outcome == CONSISTENT
    assert assessment_report(assessment)['nothing_to_judge_reason'] is None


def test_a_failure_found_is_earned_however_little_was_tested(intel):
    # four scans, too few to judge a pass, the later two a metre off: the failure stands
    log, _ = intel
    poses = log.laser_poses[:4].copy()
    poses[2:, 1] += 1.0
    assessment = check_map(_scans(intel, np.arange(4), poses))
    assert not assessment.evidence.sufficient
    assert assessment.outcome == INCONSISTENT and assessment.failed
    assert assessment_report(assessment)['nothing_to_judge_reason'] is None
