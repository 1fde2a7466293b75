"""Per-map geometry and the sweeps, checked against the one-shot check and the baseline API."""
import itertools

import numpy as np
import pytest

from map_consistency_ros.core.consistency import (BaselineParameters, ConsistencyParameters,
                                                  check_consistency, evaluate_pairs, local_scales,
                                                  map_statistic, pair_log_likelihoods)
from map_consistency_ros.core.geometry import candidate_pairs
from map_consistency_ros.evaluation import metrics, runner
from map_consistency_ros.evaluation.suite import SuiteParameters, build_suite

SUITE = SuiteParameters(part_size=60)
SETTINGS = runner.MeasureSettings()


@pytest.fixture(scope='module')
def maps(shared_data):
    return build_suite(shared_data, SUITE, ['orebro'])


@pytest.fixture(scope='module')
def measured(maps):
    return runner.measure_suite(maps, SETTINGS, workers=1)


def test_pool_gives_the_same_measures_in_order(maps, measured):
    done = []
    pooled = runner.measure_suite(maps[:6], SETTINGS, workers=2,
                                  progress=lambda count, total: done.append((count, total)))
    assert done[-1] == (6, 6)
    for mine, theirs in zip(measured[:6], pooled):
        assert mine.name == theirs.name
        np.testing.assert_array_equal(mine.measures.pairs, theirs.measures.pairs)
        np.testing.assert_allclose(mine.measures.distance_sum, theirs.measures.distance_sum)
        np.testing.assert_allclose(mine.likelihoods.log_likelihood,
                                   theirs.likelihoods.log_likelihood)



def test_a_dask_cluster_gives_the_same_measures_in_order(maps, measured):
    from distributed import LocalCluster
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    try:
        remote = runner.measure_suite(maps[:3], SETTINGS, scheduler=cluster.scheduler_address)
    finally:
        cluster.close()
    for mine, theirs in zip(measured[:3], remote, strict=True):
        assert mine.name == theirs.name
        np.testing.assert_array_equal(mine.measures.pairs, theirs.measures.pairs)
        np.testing.assert_allclose(mine.measures.distance_sum, theirs.measures.distance_sum)
        np.testing.assert_array_equal(mine.local.point_count, theirs.local.point_count)

@pytest.mark.parametrize('alpha, binomial_alpha', [(0.01, 0.01), (1e-9, 1e-6)])
def test_cached_verdicts_equal_the_full_check(maps, measured, alpha, binomial_alpha):
    parameters = ConsistencyParameters(alpha=alpha, binomial_alpha=binomial_alpha)
    flagged = runner.our_verdicts(measured, parameters)
    for suite_map, verdict in zip(maps, flagged):
        scans = runner.map_scans(suite_map, SETTINGS.max_range)
        result = check_consistency(scans, parameters,
                                   reference_scans=scans.with_poses(suite_map.reference_poses))
        assert verdict == (not result.consistent), suite_map.name


def test_baseline_sweep_matches_direct_scores(maps, measured):
    rows = runner.sweep_baseline(measured, SETTINGS.baseline, [0.0, 0.05])
    truth = runner.labels(measured)
    scores = [pair_log_likelihoods(scans, candidate_pairs(scans.extents), SETTINGS.baseline)
              for scans in (runner.map_scans(item, None) for item in maps)]
    direct = {quantile: np.array([map_statistic(score, BaselineParameters(quantile=quantile))
                                  for score in scores])
              for quantile in (0.0, 0.05)}
    for quantile, threshold, specificity, recall in rows:
        flagged = direct[quantile] < threshold
        assert (specificity, recall) == metrics.specificity_recall(flagged, truth)


def test_our_sweep_covers_every_setting(measured):
    alphas, binomial_alphas, local_alphas, windows = [0.01, 1e-6], [0.01, 1e-4], [0.05, 0.2], [0, 4]
    rows = runner.sweep_ours(measured, ConsistencyParameters(), alphas, binomial_alphas,
                             local_alphas, windows)
    settings = [(a, b, c, w) for c in local_alphas
                for a, b, w in itertools.product(alphas, binomial_alphas, windows)]
    assert [tuple(row[:4]) for row in rows] == settings
    truth = runner.labels(measured)
    for row in rows[::3]:
        parameters = ConsistencyParameters(alpha=row[0], binomial_alpha=row[1],
                                           local_alpha=row[2], flag_window=int(row[3]))
        expected = metrics.specificity_recall(runner.our_verdicts(measured, parameters), truth)
        assert tuple(row[4:]) == expected


def test_broken_maps_fail_more_pairs_than_their_corrected_part(measured):
    parameters = ConsistencyParameters(alpha=1e-6)
    failed = {}
    for item in measured:
        scales = local_scales(item.local, item.scan_count, parameters)
        result = evaluate_pairs(item.measures, scales, item.scan_count, parameters)
        failed[item.name] = result.failed_pair_count
    broken = [count for name, count in failed.items() if not name.endswith('corrected')]
    corrected = [count for name, count in failed.items() if name.endswith('corrected')]
    assert np.mean(broken) > 2 * np.mean(corrected)


def test_runtime_table_rows(maps):
    rows = runner.runtime_table(maps, SUITE, SETTINGS)
    assert [row.dataset for row in rows] == ['orebro']
    row = rows[0]
    scans = runner.map_scans(maps[0], None)
    assert row.beam_count == scans.ranges.shape[1]
    assert row.scan_count == sum(len(item.scan_indices) for item in maps
                                 if item.kind == 'corrected')
    assert row.mean_overlaps > 0 and row.seconds_ours > 0 and row.seconds_baseline > 0
