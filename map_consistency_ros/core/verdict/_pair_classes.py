"""Failed pairs classified (explanation.py, steps 1-2): the registration tasks of their
submaps, the corrected pairs' test, the classes (misaligned, minor, change, unregistered), the
confirmation of a correction on the submaps' other overlaps and the cascaded test of bad pairs;
PointMoments, the end points' moments that give a correction's displacement."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult, robust_statistic, statistics
from map_consistency_ros.core.geometry import SCAN_ARRAYS, ScanSet, pair_measures, spans
from map_consistency_ros.core.verdict._assessment import (CHANGE, ExplanationSettings, MINOR,
                                                          MISALIGNED, UNREGISTERED, _CLASS_CODE)
from map_consistency_ros.core.verdict._registration import Registrations


def _submap(block: int, settings: ExplanationSettings, scan_count: int) -> tuple[int, int]:
    low = block * settings.block - settings.margin
    high = (block + 1) * settings.block + settings.margin
    return max(low, 0), min(high, scan_count)


def _tasks(pairs: np.ndarray, settings: ExplanationSettings,
           scan_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Registration tasks (r0, r1, q0, q1) per block pair, and the task of every pair.

    Submaps of blocks close in time would share scans: there each pair gets submaps of its
    own that reach away from each other (the earlier scan and those before it, the later
    scan and those after it), so neither straddles the stretch between them.
    """
    blocks = pairs // settings.block
    near = blocks[:, 1] - blocks[:, 0] <= 1 + (2 * settings.margin) // max(settings.block, 1)
    keys = np.where(near, -1 - np.arange(len(pairs)), blocks[:, 0] * scan_count + blocks[:, 1])
    unique, task_of_pair = np.unique(keys, return_inverse=True)
    tasks = np.zeros((unique.size, 4), dtype=np.int64)
    first_pair = np.zeros(unique.size, dtype=np.int64)
    first_pair[task_of_pair[::-1]] = np.arange(len(pairs))[::-1]
    reach = settings.margin + settings.block // 2
    for task, pair in enumerate(first_pair):
        i, j = pairs[pair]
        if near[pair]:
            tasks[task] = (max(i - reach, 0), i + 1, j, min(j + reach + 1, scan_count))
        else:
            tasks[task] = (*_submap(int(blocks[pair, 0]), settings, scan_count),
                           *_submap(int(blocks[pair, 1]), settings, scan_count))
    return tasks, task_of_pair.reshape(-1)


@dataclass(frozen=True)
class PointMoments:
    """Per scan: the number of valid end points (N,), their mean (N, 2) and mean squared norm
    (N,): enough for the RMS displacement of any rigid transform, without the points."""

    count: np.ndarray
    mean: np.ndarray
    square: np.ndarray

    @classmethod
    def of(cls, scans: ScanSet) -> PointMoments:
        """The moments of each scan's valid end points.

        Parameters
        ----------
        scans: the N scans placed in the world.

        Returns
        -------
        The PointMoments of the N scans (mean and mean square 0 for a scan without valid
        points).
        """
        valid = scans.valid
        count = valid.sum(axis=1)
        safe = np.maximum(count, 1)
        x, y = scans.endpoints[..., 0], scans.endpoints[..., 1]
        mean = np.stack([np.where(valid, x, 0.0).sum(axis=1),
                         np.where(valid, y, 0.0).sum(axis=1)], axis=1) / safe[:, None]
        return cls(count, mean, np.where(valid, x * x + y * y, 0.0).sum(axis=1) / safe)

    def pooled(self, scans: np.ndarray) -> PointMoments:
        """The moments of the points of some scans taken together.

        Parameters
        ----------
        scans: indices of scans of these moments.

        Returns
        -------
        PointMoments of one set (arrays of length 1).
        """
        count = self.count[scans]
        weight = count / max(int(count.sum()), 1)
        return PointMoments(np.array([count.sum()]), (weight[:, None] * self.mean[scans]).sum(
            axis=0)[None], np.array([(weight * self.square[scans]).sum()]))

    def displacement(self, transforms: np.ndarray, rows: np.ndarray | None = None
                     ) -> np.ndarray:
        """The root mean square distance world transforms move the points of sets: the mean
        of |(R - I) p + t|^2 in closed form, as (R - I)^T (R - I) = 4 sin^2(theta / 2) I.

        Parameters
        ----------
        transforms: (E, 3) world transforms (x, y, theta).
        rows: (E,) the set each transform moves; None: every set, one transform each.

        Returns
        -------
        (E,) metres, 0 for a set without points.
        """
        count, mean, square = ((self.count, self.mean, self.square) if rows is None else
                               (self.count[rows], self.mean[rows], self.square[rows]))
        theta, tx, ty = transforms[:, 2], transforms[:, 0], transforms[:, 1]
        half_turn = np.sin(theta / 2.0) ** 2  # 1 - cos(theta) = 2 half_turn, exact near zero
        sin = np.sin(theta)
        rx = -2.0 * half_turn * mean[:, 0] - sin * mean[:, 1]
        ry = sin * mean[:, 0] - 2.0 * half_turn * mean[:, 1]
        mean_square = (4.0 * half_turn * square + 2.0 * (tx * rx + ty * ry)
                       + tx * tx + ty * ty)
        return np.where(count > 0, np.sqrt(np.maximum(mean_square, 0.0)), 0.0)


_CORRECTED_CHUNK = 4096  # pairs re-placed at once: 2 scans each, a few tens of MB


def _corrected_pairs_pass(scans: ScanSet, result: ConsistencyResult, pairs: np.ndarray,
                          transforms: np.ndarray) -> np.ndarray:
    """Whether each pair (i, j) passes the pairwise test with j moved by its transform."""
    passes = [np.zeros(0, dtype=bool)]
    for start in range(0, len(pairs), _CORRECTED_CHUNK):  # two placed scans per pair at a time
        part = slice(start, start + _CORRECTED_CHUNK)
        passes.append(_corrected_chunk_pass(scans, result, pairs[part], transforms[part]))
    return np.concatenate(passes)


def _corrected_chunk_pass(scans: ScanSet, result: ConsistencyResult, pairs: np.ndarray,
                          transforms: np.ndarray) -> np.ndarray:
    first, second = pairs[:, 0], pairs[:, 1]
    # one set of the fixed scans, each once, followed by the moved j of every pair
    fixed_rows, fixed_of_pair = np.unique(first, return_inverse=True)
    fixed, moved = scans.take(fixed_rows), scans.moved(second, transforms)
    placed = ScanSet.from_parts(scans.model, **{
        name: np.concatenate([getattr(fixed, name), getattr(moved, name)])
        for name in SCAN_ARRAYS})
    measures = pair_measures(placed, np.stack([fixed_of_pair.reshape(-1),
                                               fixed_rows.size + np.arange(len(pairs))], axis=1),
                             keep_largest=max(result.parameters.trim_largest, 1))
    scale = np.maximum(result.scales[first], result.scales[second])
    tested, statistic = robust_statistic(measures, scale, result.parameters)
    return ~(tested & (statistic > statistics.normal_quantile(result.parameters.alpha)))


def _classify(registrations: Registrations, task_of_pair: np.ndarray, passes: np.ndarray,
              displacement: np.ndarray,
              settings: ExplanationSettings) -> tuple[np.ndarray, np.ndarray]:
    """(E,) class codes of the pairs, and (E,) whether each pair's registration is a rigid
    correction beyond the tolerance (determined, plausible, significant), mended or not."""
    correction = registrations.corrections[task_of_pair]
    # A covariance that is singular or not finite (a fit that left no residual, as between the
    # identical scans of a robot standing still; a corridor) leaves the correction undetermined.
    mahalanobis = statistics.mahalanobis_squared(registrations.corrections,
                                                 registrations.covariances)[task_of_pair]
    determined = registrations.determined[task_of_pair] & np.isfinite(mahalanobis)
    plausible = ((np.hypot(correction[:, 0], correction[:, 1]) <= settings.max_translation)
                 & (np.abs(np.degrees(correction[:, 2])) <= settings.max_rotation_deg))
    registered = determined & plausible
    significant = registered & (mahalanobis
                                > statistics.chi_square_3_quantile(settings.significance))
    codes = np.full(len(task_of_pair), _CLASS_CODE[CHANGE], dtype=np.int64)
    codes[determined & ~plausible & ~passes] = _CLASS_CODE[UNREGISTERED]
    codes[registered & passes] = _CLASS_CODE[MINOR]
    rigid = significant & (displacement > settings.misalignment_tolerance)
    codes[rigid & passes] = _CLASS_CODE[MISALIGNED]
    return codes, rigid


def _cascaded(result: ConsistencyResult, pairs: np.ndarray, bad: np.ndarray,
              probability: float | None = None) -> np.ndarray:
    """Scans with more `bad` pairs than the cascaded binomial test allows at failure
    `probability` per pair (default: the paper's)."""
    count = result.scan_count
    bad_counts = (np.bincount(pairs[bad, 0], minlength=count)
                  + np.bincount(pairs[bad, 1], minlength=count))
    if probability is None:
        return bad_counts > result.critical_counts
    return bad_counts > statistics.binomial_critical_count(
        result.overlap_counts, probability, result.parameters.binomial_alpha)


_CONFIRM_SAMPLE = 36  # overlaps re-measured per registration: enough for a share, bounded


def _task_overlaps(result: ConsistencyResult, tasks: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The tested pairs between the reference and the query submap of each task (r0, r1, q0,
    q1), oriented (reference scan, query scan): rows into result.pairs (M,) and task ids (M,).
    At most _CONFIRM_SAMPLE per task, evenly spread."""
    count = result.scan_count
    tested = np.flatnonzero(result.tested)
    first, second = result.pairs[tested, 0], result.pairs[tested, 1]
    keys = np.concatenate([first * count + second, second * count + first])
    rows = np.concatenate([tested, tested])
    order = np.argsort(keys, kind='stable')
    keys, rows = keys[order], rows[order]
    scan, task_of_scan = spans(tasks[:, 0], tasks[:, 1])  # the reference scans of each task
    picked, of_scan = spans(np.searchsorted(keys, scan * count + tasks[task_of_scan, 2]),
                             np.searchsorted(keys, scan * count + tasks[task_of_scan, 3]))
    task_ids = task_of_scan[of_scan]
    if picked.size:  # evenly thin each task's overlaps (contiguous per task) to the sample
        task_total = np.bincount(task_ids, minlength=len(tasks))
        rank = np.arange(picked.size) - np.repeat(np.cumsum(task_total) - task_total,
                                                  task_total)
        step = np.maximum(1, -(-task_total // _CONFIRM_SAMPLE))
        keep = rank % step[task_ids] == 0
        picked, task_ids = picked[keep], task_ids[keep]
    return rows[picked], task_ids


def corrections_confirmed(scans: ScanSet, result: ConsistencyResult, tasks: np.ndarray,
                          transforms: np.ndarray, settings: ExplanationSettings) -> np.ndarray:
    """Whether each registration's correction resolves at least `min_resolved_fraction` of the
    failing tested pairs between its two submaps, net of the passing pairs it breaks.

    A rigid error of the query submap makes most pairs between the two submaps fail, changes
    aside, and its correction resolves them. A correction that snapped onto a moved object or a
    person resolves the pairs that see it and breaks those that see the static walls.

    Parameters
    ----------
    scans: the scans `result` was computed on.
    result: the paper's test on them.
    tasks: (T, 4) registration tasks (r0, r1, q0, q1): reference and query submaps.
    transforms: (T, 3) each task's correction as a world transform of its query submap.
    settings: the explanation's settings (min_resolved_fraction).

    Returns
    -------
    (T,) bool; False for a task without failing pairs between its submaps.
    """
    rows, task_ids = _task_overlaps(result, tasks)
    pairs = result.pairs[rows]
    in_query = (pairs >= tasks[task_ids, 2:3]) & (pairs < tasks[task_ids, 3:4])
    failing, after = _failing_before_after(scans, result, rows, in_query[:, 0] & ~in_query[:, 1],
                                           transforms[task_ids], task_ids, len(tasks))
    return (failing > 0) & (failing - after >= settings.min_resolved_fraction * failing)


def _failing_before_after(scans: ScanSet, result: ConsistencyResult, rows: np.ndarray,
                          first_moves: np.ndarray, transforms: np.ndarray, groups: np.ndarray,
                          group_count: int) -> tuple[np.ndarray, np.ndarray]:
    """(G,) twice, per group of the tested pairs `rows` of `result`: how many fail as they
    are, and how many fail with one scan of each pair moved by its world transform (the first
    where `first_moves`, else the second)."""
    pairs = result.pairs[rows]
    oriented = np.where(first_moves[:, None], pairs[:, ::-1], pairs)
    passes = _corrected_pairs_pass(scans, result, oriented, transforms)
    return (np.bincount(groups, weights=result.failed[rows], minlength=group_count),
            np.bincount(groups, weights=~passes, minlength=group_count))
