"""The test's statistics against scipy.stats as an independent oracle."""
import numpy as np
import pytest
from scipy import stats

from map_consistency_ros.core.consistency import statistics


@pytest.mark.parametrize('scale', [0.005, 0.03, 1.7])
def test_halfnormal_moments_match_scipy(scale):
    mean = statistics.HALFNORMAL_MEAN_FACTOR * scale
    deviation = statistics.HALFNORMAL_STD_FACTOR * scale
    assert mean == pytest.approx(stats.halfnorm(scale=scale).mean(), rel=1e-12)
    assert deviation == pytest.approx(stats.halfnorm(scale=scale).std(), rel=1e-12)


def test_standardized_inconsistency_is_the_clt_statistic():
    rng = np.random.default_rng(4)
    scale = 0.02
    samples = np.abs(rng.normal(0.0, scale, size=(4000, 50)))
    psi = statistics.standardized_inconsistency(samples.sum(axis=1), np.full(4000, 50), scale)
    # Sums of half-normal samples standardized by eq. 5 are close to N(0, 1).
    assert abs(psi.mean()) < 0.06
    assert psi.std() == pytest.approx(1.0, abs=0.05)
    assert np.mean(psi > stats.norm.isf(0.01)) == pytest.approx(0.01, abs=0.006)


def test_standardized_inconsistency_without_points_is_nan():
    psi = statistics.standardized_inconsistency(np.array([0.0, 1.0]), np.array([0, 4]), 0.1)
    assert np.isnan(psi[0]) and np.isfinite(psi[1])


def test_scale_bound_puts_the_pair_exactly_on_the_threshold():
    distance_sum = np.array([0.8, 3.0, 12.0])
    count = np.array([20, 100, 400])
    alpha = 0.05
    bound = statistics.scale_bound(distance_sum, count, alpha)
    psi = statistics.standardized_inconsistency(distance_sum, count, bound)
    np.testing.assert_allclose(psi, stats.norm.isf(alpha), rtol=1e-12)


def test_normal_quantile_matches_scipy_and_rejects_bad_levels():
    assert statistics.normal_quantile(0.01) == pytest.approx(stats.norm.ppf(0.99), rel=1e-14)
    for bad in (0.0, 1.0, -0.1):
        with pytest.raises(ValueError):
            statistics.normal_quantile(bad)


@pytest.mark.parametrize('tail', [1e-12, 1e-9, 1e-6, 1e-3, 0.05, 0.5, 0.99])
def test_normal_quantile_matches_scipy_in_both_tails(tail):
    assert statistics.normal_quantile(tail) == pytest.approx(stats.norm.isf(tail), rel=1e-13,
                                                             abs=1e-15)


@pytest.mark.parametrize('tail', [1e-12, 1e-9, 1e-6, 1e-3, 0.05, 0.5, 0.99])
def test_chi_square_3_quantile_matches_scipy(tail):
    quantile = statistics.chi_square_3_quantile(tail)
    assert quantile == pytest.approx(stats.chi2.isf(tail, 3), rel=1e-10)
    assert stats.chi2.sf(quantile, 3) == pytest.approx(tail, rel=1e-8)


@pytest.mark.parametrize('bad', [0.0, 1.0, -0.1, float('nan')])
def test_chi_square_3_quantile_rejects_bad_levels(bad):
    with pytest.raises(ValueError, match='tail probability'):
        statistics.chi_square_3_quantile(bad)


def _scipy_critical_count(trials: int, probability: float, alpha: float) -> int:
    # eq. 7 literally: the smallest nu whose upper tail P(X > nu) is at most alpha.
    tails = stats.binom.sf(np.arange(trials + 1), trials, probability)
    return int(np.flatnonzero(tails <= alpha)[0])


@pytest.mark.parametrize('probability,alpha', [(0.015, 0.01), (0.01, 0.05), (0.2, 0.001)])
def test_binomial_critical_count_matches_scipy(probability, alpha):
    trials = np.array([0, 1, 2, 5, 17, 50, 99, 100, 133, 500, 1000, 2500, 5000])
    expected = [_scipy_critical_count(int(r), probability, alpha) for r in trials]
    np.testing.assert_array_equal(
        statistics.binomial_critical_count(trials, probability, alpha), expected)


def test_binomial_critical_count_is_stable_for_huge_trial_counts():
    # Factorials of 50,000 overflow any float; the log-space form (eq. 8) does not.
    trials = np.array([20000, 50000])
    counts = statistics.binomial_critical_count(trials, 0.015, 0.01)
    expected = [_scipy_critical_count(int(r), 0.015, 0.01) for r in trials]
    np.testing.assert_array_equal(counts, expected)


def test_binomial_critical_count_keeps_the_input_shape():
    trials = np.array([[3, 40], [40, 3]])
    counts = statistics.binomial_critical_count(trials, 0.015, 0.01)
    assert counts.shape == (2, 2) and counts[0, 1] == counts[1, 0]


@pytest.mark.parametrize('probability,alpha,trials', [
    (0.0, 0.01, [3]), (1.0, 0.01, [3]), (0.01, 0.0, [3]), (0.01, 0.01, [-1])])
def test_binomial_critical_count_rejects_bad_arguments(probability, alpha, trials):
    with pytest.raises(ValueError):
        statistics.binomial_critical_count(np.array(trials), probability, alpha)
