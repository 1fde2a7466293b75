"""The second stage's pairs: every pair of the flagged scans, whatever the partner budget,
against the batch check of the same keyframes."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from map_consistency_ros.core.consistency import ConsistencyParameters, check_consistency
from map_consistency_ros.core.geometry import ScanSet, candidate_pairs, measure_pairs, se2
from map_consistency_ros.core.live import KeyframeEstimate, LivePipeline, MonitorSettings, Scan
from map_consistency_ros.core.live import _flagged_pairs
from map_consistency_ros.core.live._flagged_pairs import FlaggedPairs
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

SCANS = 300
BUDGET = 3  # far below the overlaps of a revisit: most pairs of a flagged scan are left out


@pytest.fixture(scope='module')
def turned(shared_data):
    """Intel's first scans, everything after the middle turned 2 degrees about it."""
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    stamps, poses = log.timestamps[:SCANS], log.laser_poses[:SCANS].copy()
    pivot = poses[SCANS // 2]
    poses[SCANS // 2:] = se2.compose(se2.compose(pivot, np.array([0.0, 0.0, np.radians(2.0)])),
                                     se2.relative(pivot, poses[SCANS // 2:]))
    return stamps, log.ranges[:SCANS], poses, sensor_model(log)


def streamed(turned, budget: int) -> LivePipeline:
    stamps, ranges, poses, model = turned
    pipeline = LivePipeline(ConsistencyParameters(), MonitorSettings(max_partners=budget))
    for k in range(SCANS):
        pipeline.apply(Scan(stamp=float(stamps[k]), ranges=ranges[k], model=model))
        if (k + 1) % 10 == 0 or k + 1 == SCANS:
            pipeline.apply(KeyframeEstimate(stamps=stamps[:k + 1], poses=poses[:k + 1]))
    return pipeline


@pytest.fixture(scope='module')
def budgeted(turned):
    pipeline = streamed(turned, BUDGET)
    return pipeline, pipeline.evaluate()


def pair_rows(result) -> dict[tuple[int, int], int]:
    return {tuple(pair): row for row, pair in enumerate(result.pairs.tolist())}


def test_every_pair_of_a_flagged_scan_is_measured_as_check_measures_it(budgeted):
    _, snapshot = budgeted
    scans, first = snapshot.scans(), snapshot.result
    flagged = first.inconsistent
    assert flagged.sum() >= 10
    completed = FlaggedPairs().complete(scans, snapshot.ids, first)
    # the oracle: the batch measures of every overlapping pair of the same placed scans
    every = candidate_pairs(scans.extents)
    batch = measure_pairs(scans, every, ConsistencyParameters().trim_largest)
    around = (flagged[every[:, 0]] | flagged[every[:, 1]]) & (batch.point_count > 0)
    # the budget left out most of them
    assert around.sum() > 2 * np.count_nonzero(flagged[first.pairs].any(axis=1))
    rows = pair_rows(completed)
    for pair, distance, points in zip(every[around].tolist(), batch.distance_sum[around],
                                      batch.point_count[around]):
        row = rows[tuple(pair)]
        assert completed.point_count[row] == points
        assert completed.distance_sum[row] == pytest.approx(distance, rel=1e-12, abs=1e-12)
    # and so is every pair of a scan that only the added pairs flag
    also = completed.inconsistent & ~flagged
    assert also.any()
    rows_with_points = set(map(tuple, every[batch.point_count > 0].tolist()))
    for scan in np.flatnonzero(also):
        touching = {pair for pair in rows_with_points if scan in pair}
        assert touching <= rows.keys()
    # the first stage's pairs are all there, unchanged
    for pair, row in pair_rows(first).items():
        assert completed.distance_sum[rows[pair]] == first.distance_sum[row]
        assert completed.failed[rows[pair]] == first.failed[row]
    assert np.all(np.diff(completed.pairs[:, 0]) >= 0)
    # a flagged scan's counts are those of the batch test of the same keyframes (same scales)
    incremental = ScanSet.from_ranges(snapshot.ranges, snapshot.incremental_poses,
                                      snapshot.model)
    oracle = check_consistency(scans, ConsistencyParameters(), reference_scans=incremental)
    np.testing.assert_allclose(completed.scales, oracle.scales, rtol=1e-12)
    np.testing.assert_array_equal(completed.overlap_counts[flagged],
                                  oracle.overlap_counts[flagged])
    np.testing.assert_array_equal(completed.failed_counts[flagged],
                                  oracle.failed_counts[flagged])


def test_the_next_explanation_measures_only_what_moved(budgeted, monkeypatch):
    _, snapshot = budgeted
    scans, first = snapshot.scans(), snapshot.result
    measured = []
    real = _flagged_pairs.measure_pairs

    def counting(scans, pairs, keep_largest):
        measured.append(pairs.copy())
        return real(scans, pairs, keep_largest)

    monkeypatch.setattr(_flagged_pairs, 'measure_pairs', counting)
    pairs = FlaggedPairs()
    once = pairs.complete(scans, snapshot.ids, first)
    calls = len(measured)
    assert calls >= 1 and sum(len(batch) for batch in measured) > 0
    again = pairs.complete(scans, snapshot.ids, first)
    assert len(measured) == calls  # nothing moved: nothing measured
    np.testing.assert_array_equal(again.pairs, once.pairs)
    np.testing.assert_array_equal(again.distance_sum, once.distance_sum)
    # one flagged keyframe moves a millimetre (too little to change a flag): only the added
    # pairs with it are measured again
    moved = int(np.flatnonzero(first.inconsistent)[0])
    poses = scans.sensor_poses.copy()
    poses[moved, 0] += 0.001
    shifted = ScanSet.from_ranges(scans.ranges, poses, scans.model)
    pairs.complete(shifted, snapshot.ids, first)
    remeasured = np.concatenate(measured[calls:])
    with_moved = np.count_nonzero((once.pairs == moved).any(axis=1)
                                  & ~np.isin(once.pairs[:, 0] * SCANS + once.pairs[:, 1],
                                             first.pairs[:, 0] * SCANS + first.pairs[:, 1]))
    assert remeasured.shape[0] >= with_moved > 0
    assert np.all((remeasured == moved).any(axis=1))


def test_nothing_flagged_leaves_the_result_as_it_is(budgeted):
    _, snapshot = budgeted
    first = snapshot.result
    quiet = replace(first, inconsistent=np.zeros_like(first.inconsistent))
    assert FlaggedPairs().complete(snapshot.scans(), snapshot.ids, quiet) is quiet


def test_the_verdict_weighs_every_pair_of_the_flagged_scans(turned, budgeted):
    pipeline, snapshot = budgeted
    verdict = pipeline.explain(snapshot)
    assert verdict.snapshot.result is snapshot.result  # the first stage is published as it is
    explained = verdict.assessment.result
    assert explained.pairs.shape[0] > snapshot.result.pairs.shape[0]
    # the turn is caught as with every pair measured in the first stage
    everything = streamed(turned, 0)
    full = everything.explain(everything.evaluate())
    assert not verdict.consistent and not full.consistent
    assert verdict.assessment.misalignments and full.assessment.misalignments
