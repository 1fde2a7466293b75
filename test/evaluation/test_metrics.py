"""Specificity / recall, threshold sweeps and Pareto frontiers against brute-force oracles."""
import itertools

import numpy as np
import pytest

from map_consistency_ros.evaluation.metrics import (dominates, frontier_area, pareto_frontier,
                                                    specificity_recall, threshold_sweep)


def test_specificity_recall_counts():
    truth = np.array([True, True, True, False, False])
    flagged = np.array([True, False, True, True, False])
    # 2 of 3 inconsistent maps flagged, 1 of 2 consistent maps passed
    assert specificity_recall(flagged, truth) == (0.5, pytest.approx(2 / 3))


def test_specificity_recall_rejects_bad_input():
    with pytest.raises(ValueError, match='labels'):
        specificity_recall(np.ones(3, bool), np.ones(2, bool))
    with pytest.raises(ValueError, match='both consistent and inconsistent'):
        specificity_recall(np.ones(3, bool), np.ones(3, bool))


def test_threshold_sweep_reaches_every_operating_point():
    rng = np.random.default_rng(11)
    statistic = np.round(rng.normal(size=25), 1)  # ties on purpose
    truth = rng.random(25) < 0.5
    sweep = threshold_sweep(statistic, truth)
    # oracle: every split of the sorted values, by brute force on a dense threshold grid
    dense = np.linspace(statistic.min() - 1, statistic.max() + 1, 5001)
    expected = {specificity_recall(statistic < t, truth) for t in dense}
    assert {tuple(row[1:]) for row in sweep} == expected
    for threshold, specificity, recall in sweep:
        assert (specificity, recall) == specificity_recall(statistic < threshold, truth)


def test_threshold_sweep_ignores_infinite_statistics():
    statistic = np.array([np.inf, -1.0, 0.0])
    sweep = threshold_sweep(statistic, np.array([False, True, False]))
    assert np.all(np.isfinite(sweep))
    assert len(sweep) == 3


def _brute_force_frontier(points: np.ndarray) -> set[tuple[float, float]]:
    kept = set()
    for a in points:
        beaten = any(np.all(b >= a) and np.any(b > a) for b in points)
        if not beaten:
            kept.add(tuple(a))
    return kept


def test_pareto_frontier_matches_brute_force():
    rng = np.random.default_rng(5)
    for _ in range(20):
        points = np.round(rng.random((30, 2)), 1)
        frontier = pareto_frontier(points)
        chosen = points[frontier]
        assert {tuple(p) for p in chosen} == _brute_force_frontier(points)
        assert len(frontier) == len({tuple(p) for p in chosen})
        assert np.all(np.diff(chosen[:, 0]) > 0) and np.all(np.diff(chosen[:, 1]) < 0)


def test_dominates():
    ours = np.array([[0.5, 1.0], [1.0, 0.8]])
    assert dominates(ours, np.array([[0.4, 0.9], [1.0, 0.5]]))
    assert dominates(ours, ours)
    assert not dominates(ours, np.array([[0.9, 0.9]]))
    assert not dominates(np.array([[0.9, 0.9]]), ours)


def test_frontier_area_of_staircases():
    assert frontier_area(np.array([[1.0, 1.0]])) == 1.0
    assert frontier_area(np.array([[0.5, 1.0], [1.0, 0.5]])) == pytest.approx(0.75)
    # dominated points add nothing
    assert frontier_area(np.array([[0.5, 1.0], [1.0, 0.5], [0.4, 0.4]])) == pytest.approx(0.75)
    corners = np.array(list(itertools.product([0.25, 0.75], [0.25, 0.75])))
    assert frontier_area(corners) == pytest.approx(0.75 * 0.75)
