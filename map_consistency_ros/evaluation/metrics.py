"""Specificity, recall and Pareto frontiers of map-consistency detectors.

An inconsistent map is a positive: recall = TP / (TP + FN) is the share of inconsistent maps
flagged, specificity = TN / (TN + FP) the share of consistent maps passed (paper, Fig. 3).
"""
import numpy as np


def specificity_recall(flagged: np.ndarray, inconsistent: np.ndarray) -> tuple[float, float]:
    """Specificity and recall of one detector setting over a labelled suite.

    Parameters
    ----------
    flagged: (M,) bool, the detector's verdict per map (True: inconsistent).
    inconsistent: (M,) bool, the labels.

    Returns
    -------
    (specificity, recall), each in [0, 1]. Raises ValueError when the shapes differ or the
    labels lack either class.
    """
    flagged = np.asarray(flagged, dtype=bool)
    inconsistent = np.asarray(inconsistent, dtype=bool)
    if flagged.shape != inconsistent.shape:
        raise ValueError(f'{flagged.shape} verdicts for {inconsistent.shape} labels')
    positives = np.count_nonzero(inconsistent)
    negatives = inconsistent.size - positives
    if positives == 0 or negatives == 0:
        raise ValueError('the suite needs both consistent and inconsistent maps')
    true_negatives = np.count_nonzero(~flagged & ~inconsistent)
    true_positives = np.count_nonzero(flagged & inconsistent)
    return true_negatives / negatives, true_positives / positives


def threshold_sweep(statistic: np.ndarray, inconsistent: np.ndarray) -> np.ndarray:
    """Every distinct (threshold, specificity, recall) of "flag the map if statistic < threshold".

    Thresholds lie below, between (midpoints) and above the distinct statistics, so the sweep
    reaches every operating point a threshold can give.

    Parameters
    ----------
    statistic: (M,) per-map statistic, low meaning inconsistent; non-finite values take no
        part in choosing thresholds (NaN and +inf are never flagged, -inf always).
    inconsistent: (M,) bool labels.

    Returns
    -------
    (S, 3) rows (threshold, specificity, recall) by increasing threshold; a single row at
    threshold 0 when no statistic is finite. Raises ValueError as specificity_recall.
    """
    statistic = np.asarray(statistic, dtype=np.float64)
    values = np.unique(statistic[np.isfinite(statistic)])
    if values.size == 0:
        thresholds = np.array([0.0])
    else:
        thresholds = np.concatenate([[values[0] - 1.0], 0.5 * (values[1:] + values[:-1]),
                                     [values[-1] + 1.0]])
    rows = [(threshold, *specificity_recall(statistic < threshold, inconsistent))
            for threshold in thresholds]
    return np.array(rows)


def pareto_frontier(points: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats in both columns (both maximised).

    Parameters
    ----------
    points: (P, 2) points, e.g. (specificity, recall) rows.

    Returns
    -------
    (F,) int64 indices into `points`, sorted by the first column ascending; duplicates of a
    frontier point keep one index.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    # by first column descending, ties by second descending: a point is on the frontier when
    # its second column beats every point seen before it
    order = np.lexsort((-points[:, 1], -points[:, 0]))
    frontier = []
    best = -np.inf
    for index in order:
        if points[index, 1] > best:
            frontier.append(index)
            best = points[index, 1]
    return np.array(frontier[::-1], dtype=np.int64)


def dominates(frontier: np.ndarray, other: np.ndarray) -> bool:
    """Whether a frontier covers other points.

    Parameters
    ----------
    frontier: (F, 2) points, both columns maximised.
    other: (P, 2) points to compare.

    Returns
    -------
    True when every point of `other` is matched or beaten in both columns by one frontier
    point (also when `other` is empty).
    """
    frontier = np.asarray(frontier, dtype=np.float64).reshape(-1, 2)
    other = np.asarray(other, dtype=np.float64).reshape(-1, 2)
    covered = np.all(frontier[None, :, :] >= other[:, None, :], axis=2)
    return bool(np.all(covered.any(axis=1)))


def frontier_area(frontier: np.ndarray) -> float:
    """Area under the staircase of a frontier in the unit square.

    Parameters
    ----------
    frontier: (P, 2) (specificity, recall) points in [0, 1]; dominated ones are dropped first.

    Returns
    -------
    The area: each frontier point's recall times the specificity it adds over the previous
    point (from 0); 1 when the point (1, 1) is reached.
    """
    points = np.asarray(frontier, dtype=np.float64).reshape(-1, 2)
    points = points[pareto_frontier(points)]
    area = 0.0
    left = 0.0
    for specificity, recall in points:
        area += (specificity - left) * recall
        left = specificity
    return float(area)
