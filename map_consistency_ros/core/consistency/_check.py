"""The statistical map-consistency test: from placed scans to per-scan and map verdicts.

Pipeline (Mazuran et al., ICRA 2014): candidate pairs from the scans' extents, the pairwise
measure M_ij / n_ij (geometry/_measure.py), per-scan half-normal scales s_i from the
incremental solution over temporally adjacent scans (eq. 10), the one-sided pairwise test on
Psi_ij with s = max(s_i, s_j) (eqs. 5-6), and the cascaded binomial test per scan (eqs. 7-8).
The map is consistent when no scan fails. Notation as in statistics.py.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from functools import cached_property

import numpy as np
from numba import njit

from map_consistency_ros.core.consistency import statistics
from map_consistency_ros.core.geometry import (PairMeasures, ScanSet, candidate_pairs,
                                               extents_overlap, measure_pairs, pair_measures,
                                               pairs_point_distances, viewpoint_rows)
from map_consistency_ros.core.parameters import Settings, parameter

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class ConsistencyParameters(Settings):
    """Confidence levels and robustifications of the test (defaults: see README, "Parameters")."""

    # Originals' option names: --normal-err, --incr-normal-err, --binomial-prob, --binomial-err.
    # the paper's evaluation sweeps alpha down to 1e-200 (cli/evaluate.py)
    alpha: float = parameter(0.01, "pairwise test level (the paper's alpha)", '', (1e-300, 0.5))
    local_alpha: float = parameter(
        0.05, 'level of the local scale fit on the incremental solution', '', (1e-9, 0.5))
    failure_probability: float = parameter(
        0.015, 'probability that one pairwise test fails by chance', '', (1e-9, 0.5))
    binomial_alpha: float = parameter(
        0.01, "level of the cascaded (binomial) test per scan (the paper's alpha')", '',
        (1e-9, 0.5))
    viewpoint_spacing: float = parameter(
        0.4, 'a scan becomes a viewpoint of the test this far from the previous one; the scans '
        'in between are folded into it (standing still is one viewpoint; 0: every scan)', 'm',
        (0.0, 100.0))
    viewpoint_turn: float = parameter(
        0.4, 'a scan turned this far from the previous viewpoint is a viewpoint too (0: every '
        'scan)', 'rad', (0.0, 3.15))
    fold_depth: float = parameter(
        0.2, 'an end point this deep inside the other scan\'s free space disagrees with it, when '
        'a scan is folded into its viewpoint (beyond noise: several times the scale s_i)', 'm',
        (0.0, 100.0))
    fold_disagreement: float = parameter(
        0.25, 'a scan within reach of its viewpoint still becomes one when more than this share '
        'of their end points disagree (1: fold by pose alone)', '', (0.0, 1.0))
    local_window: int = parameter(
        40, 'temporally adjacent viewpoints that fit a local scale, half on each side',
        'viewpoints', (0, 1000))
    min_points: int = parameter(
        10, 'pairs with fewer inconsistent points (after trimming) are not tested', '',
        (1, 100_000))
    trim_largest: int = parameter(
        10, 'largest distances of a pair dropped before its statistic', '', (0, 1000))
    default_scale: float = parameter(
        0.03, 'scale s_i of a scan whose neighbourhood gives no estimate', 'm', (1e-6, 10.0))
    min_scale: float = parameter(0.0, 'floor on every local scale s_i', 'm', (0.0, 10.0))
    flag_window: int = parameter(
        0, 'keep a flag only with another flagged viewpoint within this many (0: off)',
        'viewpoints', (0, 1000))

    @property
    def local_reach(self) -> int:
        """Temporal neighbours (the pairs of the local scale fit) are at most this many scan
        indices apart."""
        return _half_window(self.local_window)

    def as_dict(self) -> dict:
        """The parameters as plain data.

        Returns
        -------
        A dict of every field by name (dataclasses.asdict).
        """
        return asdict(self)


def select_viewpoints(scans: ScanSet, parameters: ConsistencyParameters) -> np.ndarray:
    """The viewpoints the test runs on among scans in travel order (geometry.viewpoint_rows:
    by travel and turn, and a scan that disagrees with its viewpoint is one of its own).

    Parameters
    ----------
    scans: the scans at their sensor poses, in travel order.
    parameters: the viewpoint spacing and turn and the fold's depth and disagreement.

    Returns
    -------
    (V,) int64 rows of `scans`, increasing.
    """
    return viewpoint_rows(scans.sensor_poses, parameters.viewpoint_spacing,
                          parameters.viewpoint_turn, scans, parameters.fold_depth,
                          parameters.fold_disagreement)


def _half_window(window: int) -> int:
    return max(window // 2, 1)


@dataclass(frozen=True)
class ConsistencyResult:
    """Everything the test decided, per pair (P) and per scan (N)."""

    pairs: np.ndarray  # (P, 2) scan indices i < j of pairs with overlapping extents
    distance_sum: np.ndarray  # (P,) M_ij
    point_count: np.ndarray  # (P,) n_ij
    trimmed_sum: np.ndarray  # (P,) M_ij without the pair's trim_largest largest distances
    trimmed_count: np.ndarray  # (P,) n_ij likewise
    tested: np.ndarray  # (P,) bool: enough points for the pairwise test
    statistic: np.ndarray  # (P,) Psi_ij of the tested pairs (robustified), NaN elsewhere
    failed: np.ndarray  # (P,) bool
    scales: np.ndarray  # (N,) s_i
    overlap_counts: np.ndarray  # (N,) r_i, tested pairs per scan
    failed_counts: np.ndarray  # (N,) failed pairs per scan
    critical_counts: np.ndarray  # (N,) nu-hat of each scan
    inconsistent: np.ndarray  # (N,) bool: the scan failed its cascaded test
    parameters: ConsistencyParameters = field(default_factory=ConsistencyParameters)

    def own_scales(self) -> np.ndarray:
        """s_i fitted on the map itself, from its measured pairs that join temporal neighbours:
        how its scans agree with their neighbours.

        Returns
        -------
        (N,) scales in metres; the same as `scales` unless the test fitted those on an
        incremental solution.
        """
        local = np.abs(self.pairs[:, 1] - self.pairs[:, 0]) <= self.parameters.local_reach
        return _scales_from_sums(self.pairs[local], self.trimmed_sum[local],
                                 self.trimmed_count[local], self.scan_count, self.parameters)

    @classmethod
    def untested(cls, parameters: ConsistencyParameters) -> ConsistencyResult:
        """The result on no scans (where an incremental evaluation starts).

        Parameters
        ----------
        parameters: the parameters the result is of.

        Returns
        -------
        A consistent result with zero pairs and zero scans.
        """
        empty, counts = np.zeros(0), np.zeros(0, dtype=np.int64)
        flags = np.zeros(0, dtype=bool)
        return cls(pairs=np.zeros((0, 2), dtype=np.int64), distance_sum=empty,
                   point_count=counts, trimmed_sum=empty, trimmed_count=counts, tested=flags,
                   statistic=empty, failed=flags, scales=empty, overlap_counts=counts,
                   failed_counts=counts, critical_counts=counts, inconsistent=flags,
                   parameters=parameters)

    @property
    def consistent(self) -> bool:
        return not bool(self.inconsistent.any())

    @property
    def scan_count(self) -> int:
        return int(self.scales.size)

    @property
    def inconsistent_scans(self) -> np.ndarray:
        return np.flatnonzero(self.inconsistent)

    # cached, the three counts: the node reports them on every update, each a pass over
    # every pair
    @cached_property
    def overlapping_pair_count(self) -> int:
        return int(np.count_nonzero(self.point_count))

    @cached_property
    def tested_pair_count(self) -> int:
        return int(np.count_nonzero(self.tested))

    @cached_property
    def failed_pair_count(self) -> int:
        return int(np.count_nonzero(self.failed))

    def summary(self) -> dict:
        """The figures a report or a diagnostic shows.

        Returns
        -------
        A dict of ints: scans, candidate_pairs, overlapping_pairs, tested_pairs, failed_pairs,
        inconsistent_scans, and the bool consistent.
        """
        return {
            'scans': self.scan_count,
            'candidate_pairs': int(self.pairs.shape[0]),
            'overlapping_pairs': self.overlapping_pair_count,
            'tested_pairs': self.tested_pair_count,
            'failed_pairs': self.failed_pair_count,
            'inconsistent_scans': int(self.inconsistent.sum()),
            'consistent': self.consistent,
        }


def robust_sums(measures: PairMeasures, trim: int) -> tuple[np.ndarray, np.ndarray]:
    """M_ij and n_ij without each pair's largest distances.

    Parameters
    ----------
    measures: the P pairs' measures, keeping at least `trim` largest distances (else
        ValueError).
    trim: how many of each pair's largest distances to drop (0: none).

    Returns
    -------
    (trimmed M_ij (P,) in metres, never negative; trimmed n_ij (P,)).
    """
    if trim == 0:
        return measures.distance_sum, measures.point_count
    if measures.largest.shape[1] < trim:
        raise ValueError(f'measures keep {measures.largest.shape[1]} largest distances per pair, '
                         f'trimming needs {trim}')
    trimmed_sum = measures.distance_sum - measures.largest[:, :trim].sum(axis=1)
    trimmed_count = measures.point_count - np.minimum(measures.point_count, trim)
    return np.maximum(trimmed_sum, 0.0), trimmed_count


def local_scales(measures: PairMeasures, scan_count: int,
                 parameters: ConsistencyParameters,
                 robust: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """s_i of every scan (eq. 10): the largest scale bound over its measured local pairs.

    Parameters
    ----------
    measures: the pairs of temporally adjacent scans measured on the incremental solution.
    scan_count: N, the scans of the map.
    parameters: the test's parameters (local_alpha, min_points, trim_largest, default_scale,
        min_scale).
    robust: the pairs' trimmed (M_ij, n_ij) when the caller keeps them (see
        `robust_statistic`); None computes them here.

    Returns
    -------
    (N,) s_i in metres. Scans without a usable local pair get `default_scale`; all are floored
    at `min_scale`.
    """
    distance_sum, count = (robust_sums(measures, parameters.trim_largest) if robust is None
                           else robust)
    return _scales_from_sums(measures.pairs, distance_sum, count, scan_count, parameters)


NO_BOUND = -1.0  # a scan's largest bound while it has no usable local pair (bounds are >= 0)


def _scales_from_sums(pairs: np.ndarray, distance_sum: np.ndarray, count: np.ndarray,
                      scan_count: int, parameters: ConsistencyParameters) -> np.ndarray:
    """local_scales from the local pairs' trimmed (M_ij, n_ij)."""
    largest = np.full(scan_count, NO_BOUND)
    add_local_bounds(largest, pairs, distance_sum, count, parameters)
    return scales_from_bounds(largest, parameters)


def add_local_bounds(largest: np.ndarray, pairs: np.ndarray, distance_sum: np.ndarray,
                     count: np.ndarray, parameters: ConsistencyParameters) -> None:
    """Raise each scan's largest scale bound (eq. 10) to those of more local pairs, in place.

    A scan's s_i is the largest bound over its usable local pairs, so pairs can be added in any
    order and in any number of calls: the live monitor adds only the pairs it measured since
    its last test (`scales_from_bounds` turns the result into s_i).

    Parameters
    ----------
    largest: (N,) the largest bound of each scan so far, NO_BOUND where it has none; updated.
    pairs: (P, 2) scan indices of the local pairs.
    distance_sum, count: (P,) their trimmed M_ij and n_ij.
    parameters: the test's parameters (local_alpha, min_points).
    """
    usable = count >= parameters.min_points
    bounds = np.zeros(len(pairs))
    bounds[usable] = statistics.scale_bound(distance_sum[usable], count[usable],
                                            parameters.local_alpha)
    _raise_largest(largest, np.asarray(pairs, dtype=np.int64).reshape(-1, 2), bounds, usable)


def scales_from_bounds(largest: np.ndarray, parameters: ConsistencyParameters) -> np.ndarray:
    """s_i from each scan's largest local bound (`add_local_bounds`).

    Parameters
    ----------
    largest: (N,) the largest bound of each scan, NO_BOUND where it has none.
    parameters: the test's parameters (default_scale, min_scale).

    Returns
    -------
    (N,) s_i in metres: `default_scale` for scans without a bound, all at least `min_scale`.
    """
    return np.maximum(np.where(largest >= 0.0, largest, parameters.default_scale),
                      parameters.min_scale)


@njit(cache=True)
def _raise_largest(largest: np.ndarray, pairs: np.ndarray, bounds: np.ndarray,
                   usable: np.ndarray) -> None:
    """Per scan, the largest of `largest` and the bounds of its usable pairs (in place)."""
    for index in range(pairs.shape[0]):
        if usable[index]:
            for scan in (pairs[index, 0], pairs[index, 1]):
                largest[scan] = max(largest[scan], bounds[index])


def _filter_isolated_flags(inconsistent: np.ndarray, window: int) -> np.ndarray:
    """Keep a flag only if another flagged scan lies within `window` indices."""
    flagged = np.flatnonzero(inconsistent)
    kept = np.zeros_like(inconsistent)
    for index in flagged:
        lo, hi = np.searchsorted(flagged, [index - window, index + window + 1])
        kept[index] = hi - lo > 1
    return kept


def robust_statistic(measures: PairMeasures, pair_scale: np.ndarray,
                     parameters: ConsistencyParameters,
                     robust: tuple[np.ndarray, np.ndarray] | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Which pairs have enough points to test, and their trimmed Psi_ij.

    Parameters
    ----------
    measures: the P pairs' measures.
    pair_scale: (P,) the scale s of each pair in metres (or one for all).
    parameters: the test's parameters (min_points, trim_largest).
    robust: the pairs' trimmed (M_ij, n_ij) (`robust_sums`) when the caller keeps them per pair
        as it measures them (the incremental monitor); None computes them here.

    Returns
    -------
    (tested (P,) bool, Psi_ij (P,) NaN where untested).
    """
    distance_sum, count = (robust_sums(measures, parameters.trim_largest) if robust is None
                           else robust)
    tested = count >= parameters.min_points
    return tested, statistics.standardized_inconsistency(
        distance_sum, np.where(tested, count, 0), pair_scale)


def evaluate_pairs(measures: PairMeasures, scales: np.ndarray, scan_count: int,
                   parameters: ConsistencyParameters,
                   robust: tuple[np.ndarray, np.ndarray] | None = None,
                   previous: ConsistencyResult | None = None,
                   first_rows: np.ndarray | None = None) -> ConsistencyResult:
    """The pairwise and cascaded tests on already measured pairs (no geometry).

    Parameters
    ----------
    measures: the P measured pairs (i < j).
    scales: (N,) s_i of every scan, metres (else ValueError).
    scan_count: N.
    parameters: the test's parameters.
    robust: see `robust_statistic`.
    previous: the result of these parameters on the first rows of these very pairs and sums (a
        map that only grew since): only the new pairs and the pairs of scans whose scale
        changed are tested again, with the same result as testing every pair (a live map has a
        million pairs, an update changes a few thousand). None tests every pair. ValueError
        when it cannot be such a prefix.
    first_rows: (N,), with `previous`: no pair of scan i lies before row first_rows[i] (0 when
        unknown), so the rows before those of the new and rescaled scans are not even read.

    Returns
    -------
    The ConsistencyResult of the P pairs and N scans.
    """
    scales = np.asarray(scales, dtype=np.float64)
    if scales.shape != (scan_count,):
        raise ValueError(f'expected {scan_count} scales, got shape {scales.shape}')
    pairs = measures.pairs
    robust = robust_sums(measures, parameters.trim_largest) if robust is None else robust
    arrays = (np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
              np.asarray(robust[0], dtype=np.float64), np.asarray(robust[1], dtype=np.int64),
              scales, parameters.min_points, statistics.normal_quantile(parameters.alpha))
    if previous is None:
        previous = ConsistencyResult.untested(parameters)
    elif (previous.parameters != parameters or previous.scan_count > scan_count
          or previous.pairs.shape[0] > arrays[0].shape[0]):
        raise ValueError('the previous result is not of a prefix of these pairs')
    grown = scan_count - previous.scan_count
    old_scales = np.pad(previous.scales, (0, grown), constant_values=np.nan)
    start = 0
    if first_rows is not None:
        retested = np.flatnonzero(scales != old_scales)  # NaN for the new scans: all of them
        start = min(int(first_rows[retested].min()) if retested.size else arrays[0].shape[0],
                    previous.pairs.shape[0])
    tested, statistic, failed, overlap_counts, failed_counts = _pairwise_tests(
        *arrays, start, old_scales, previous.tested, previous.statistic, previous.failed,
        np.pad(previous.overlap_counts, (0, grown)), np.pad(previous.failed_counts, (0, grown)))
    critical = statistics.binomial_critical_count(overlap_counts, parameters.failure_probability,
                                                  parameters.binomial_alpha)
    inconsistent = failed_counts > critical
    if parameters.flag_window > 0:
        inconsistent = _filter_isolated_flags(inconsistent, parameters.flag_window)
    return ConsistencyResult(
        pairs=pairs, distance_sum=measures.distance_sum, point_count=measures.point_count,
        trimmed_sum=robust[0], trimmed_count=robust[1], tested=tested, statistic=statistic,
        failed=failed, scales=scales,
        overlap_counts=overlap_counts, failed_counts=failed_counts, critical_counts=critical,
        inconsistent=inconsistent, parameters=parameters)


@njit(cache=True)
def _pairwise_tests(pairs: np.ndarray, trimmed_sum: np.ndarray, trimmed_count: np.ndarray,
                    scales: np.ndarray, min_points: int, threshold: float, start: int,
                    old_scales: np.ndarray, old_tested: np.ndarray, old_statistic: np.ndarray,
                    old_failed: np.ndarray, old_overlaps: np.ndarray, old_failures: np.ndarray):
    """Per pair: tested (enough points), Psi_ij with s = max(s_i, s_j) (NaN untested), failed
    (Psi_ij above the threshold); per scan: its tested and failed pairs (r_i and the count
    the cascaded test compares with nu-hat). Given these outputs on the first old_tested.size
    pairs with `old_scales` (NaN for scans added since), only the pairs of a scan whose scale
    changed and the new pairs are tested; the others keep their outcome and counts. Rows
    before `start` hold none of those (the caller knows where their pairs begin)."""
    count, known = pairs.shape[0], old_tested.size
    # each output row written once: a million pairs make these copies the cost of an update
    tested, statistic = np.empty(count, dtype=np.bool_), np.empty(count)
    failed = np.empty(count, dtype=np.bool_)
    tested[:known], statistic[:known], failed[:known] = old_tested, old_statistic, old_failed
    tested[known:], statistic[known:], failed[known:] = False, np.nan, False
    overlaps, failures = old_overlaps.copy(), old_failures.copy()
    rescaled = scales != old_scales  # NaN for new scans: always true
    for index in range(start, count):
        first, second = pairs[index, 0], pairs[index, 1]
        if index < known:
            if not (rescaled[first] or rescaled[second]):
                continue
            if tested[index]:
                overlaps[first] -= 1
                overlaps[second] -= 1
            if failed[index]:
                failures[first] -= 1
                failures[second] -= 1
            tested[index], statistic[index], failed[index] = False, np.nan, False
        if trimmed_count[index] < min_points:
            continue
        tested[index] = True
        overlaps[first] += 1
        overlaps[second] += 1
        scale = max(scales[first], scales[second])
        statistic[index] = statistics.psi(trimmed_sum[index], float(trimmed_count[index]), scale)
        if statistic[index] > threshold:
            failed[index] = True
            failures[first] += 1
            failures[second] += 1
    return tested, statistic, failed, overlaps, failures


def local_pairs(scans: ScanSet, window: int) -> np.ndarray:
    """Pairs of temporally adjacent scans whose extents overlap.

    Parameters
    ----------
    scans: the N scans in temporal order.
    window: the local window; scans at most max(window // 2, 1) indices apart are adjacent.

    Returns
    -------
    (P, 2) int64 rows (i, j), i < j, ordered by i then j.
    """
    half = _half_window(window)
    count = scans.extents.shape[0]
    first = np.repeat(np.arange(count), half)
    second = first + np.tile(np.arange(1, half + 1), count)
    keep = second < count
    first, second = first[keep], second[keep]
    overlap = extents_overlap(scans.extents[first], scans.extents[second])
    return np.stack([first[overlap], second[overlap]], axis=1).astype(np.int64)


def check_consistency(scans: ScanSet, parameters: ConsistencyParameters | None = None,
                      reference_scans: ScanSet | None = None,
                      progress: Progress | None = None) -> ConsistencyResult:
    """Run the whole test on scans placed in the map.

    Parameters
    ----------
    scans: the N scans at their map poses, in temporal order.
    parameters: the test's parameters; None for the defaults.
    reference_scans: the same scans at the incremental solution (poses before loop closures),
        from which the local scales are fitted; None fits them on the map itself. ValueError
        when their ranges differ in shape from `scans`.
    progress: called as progress(pairs measured, all pairs) while the pairs are measured.

    Returns
    -------
    The ConsistencyResult of every candidate pair and scan.
    """
    parameters = parameters or ConsistencyParameters()
    reference = scans if reference_scans is None else reference_scans
    if reference.ranges.shape != scans.ranges.shape:
        raise ValueError('reference scans must be the same scans as the map scans')
    keep = parameters.trim_largest
    measures = measure_pairs(scans, candidate_pairs(scans.extents), keep, progress=progress)
    if reference_scans is None:
        # The local pairs are the candidate pairs of temporal neighbours: measured already.
        gap = measures.pairs[:, 1] - measures.pairs[:, 0]
        local = measures.take(gap <= parameters.local_reach)
    else:
        local = pair_measures(reference, local_pairs(reference, parameters.local_window),
                              keep_largest=keep)
    scales = local_scales(local, scans.ranges.shape[0], parameters)
    return evaluate_pairs(measures, scales, scans.ranges.shape[0], parameters)


def average_inconsistency(measures: PairMeasures) -> float:
    """M(Phi) of eq. 11: the mean M_ij over the pairs whose polygons overlap (n_ij > 0).

    Parameters
    ----------
    measures: the measured pairs.

    Returns
    -------
    The mean in metres; 0.0 when no pair overlaps.
    """
    overlapping = measures.point_count > 0
    if not overlapping.any():
        return 0.0
    return float(measures.distance_sum[overlapping].mean())


def inconsistent_endpoints(scans: ScanSet, result: ConsistencyResult,
                           max_pairs: int | None = None, min_depth: float = 0.0) -> np.ndarray:
    """End points inside the other scan's polygon in failed pairs (the paper's Fig. 1).

    Only failed pairs that involve an inconsistent scan count.

    Parameters
    ----------
    scans: the scans `result` was computed on.
    result: the test's result.
    max_pairs: only the pairs with the largest statistic, this many (all when None), so that
        a badly broken map stays cheap to draw.
    min_depth: a point counts when it lies deeper than this many times the pair's scale
        max(s_i, s_j) inside.

    Returns
    -------
    (M, 2) world end points in metres.
    """
    flagged = result.inconsistent[result.pairs[:, 0]] | result.inconsistent[result.pairs[:, 1]]
    candidates = np.flatnonzero(result.failed & flagged)
    order = np.argsort(-result.statistic[candidates], kind='stable')
    return pair_endpoints(scans, result, candidates[order[:max_pairs]], min_depth)[0]


_ENDPOINT_CHUNK = 2048  # pairs whose point distances are held at once (a few MB)


def pair_endpoints(scans: ScanSet, result: ConsistencyResult, rows: np.ndarray,
                   min_depth: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """End points of some pairs lying inside the other scan's polygon.

    Parameters
    ----------
    scans: the scans `result` was computed on.
    result: the test's result.
    rows: rows of `result.pairs`.
    min_depth: a point counts when it lies deeper than this many times the pair's scale
        max(s_i, s_j) inside.

    Returns
    -------
    (world end points (M, 2), the scan each belongs to (M,) int64).
    """
    pairs = result.pairs[np.asarray(rows, dtype=np.int64)]
    points, owners = [np.zeros((0, 2))], [np.zeros(0, dtype=np.int64)]
    for start in range(0, len(pairs), _ENDPOINT_CHUNK):  # (P, 2, K) floats at a time
        chunk = pairs[start:start + _ENDPOINT_CHUNK]
        depth = pairs_point_distances(scans, chunk)  # points of j, then of i
        limit = min_depth * np.maximum(result.scales[chunk[:, 0]], result.scales[chunk[:, 1]])
        pair, side, beam = np.nonzero(depth > limit[:, None, None])
        owner = chunk[pair, 1 - side]
        points.append(scans.endpoints[owner, beam])
        owners.append(owner)
    return np.concatenate(points), np.concatenate(owners)
