"""Stage (1) of localization mode: the paper's test of every live scan against the map.

- M_i, n_i: the grid measure (grid_measures), both ways, trimmed of each scan's
  `trim_largest` largest depths as the pairwise test trims a pair's.
- s_i: the local scale of eq. 10 over pairs of temporally adjacent LIVE scans (the local
  window of the live run at the localizer's poses, its pairs at most `scale_metres` of travel
  apart: a run at the laser's rate or keyframed alike, and no revisit of a place counted),
  taken on each side apart (the largest bound over the pairs with earlier scans, and over
  those with later ones) and the smaller side kept: sensor noise shows on both sides, a jump
  of the estimate (the start or the end of an episode) on one side only, and must not
  inflate the scales that should find it: the sensor's noise and how well the
  estimate holds together over a few metres, which a rigid error of the localizer (a wrong
  map -> odom) leaves untouched; never from the map, the thing under test. Floored at
  `resolution_scale` map cells: the map quantizes every distance to its cells.
- The pairwise test of Psi_i = psi(M_i, n_i, s_i) at the paper's alpha, one-sided.
- Judged: a scan with at most `max_unjudged` of its valid beams in unknown space and at least
  `min_points` points after trimming; other scans are neither failed nor passed.
- The cascaded test over a window of travel: for scan i, the judged scans of the last
  `window_metres` of travel or `window_seconds` (whichever is reached first); the window is
  flagged when its failed scans r_f exceed the binomial critical count nu-hat(r) at the
  paper's failure probability and alpha'. A failed scan inside a flagged window is flagged.
- Nothing to judge (the evidence rule of core/verdict/_evidence.py): a window can be flagged
  only with at least `flaggable_pair_count` judged scans (r failed of r exceed nu-hat(r));
  a scan whose window has fewer could not have been flagged: its stretch is unjudged, and a
  run without one flaggable window is "nothing to judge".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.consistency import (NO_BOUND, ConsistencyParameters,
                                                  add_local_bounds, local_pairs, robust_sums,
                                                  scales_from_bounds, statistics)
from map_consistency_ros.core.geometry import ScanSet, measure_pairs
from map_consistency_ros.core.localization._grid_measure import (GridMeasures, GridReference,
                                                                 grid_measures)
from map_consistency_ros.core.localization._settings import LocalizationSettings
from map_consistency_ros.core.verdict import flaggable_pair_count


@dataclass(frozen=True)
class ScanTests:
    """The test of N live scans against the map, row i for scan i.

    `scales` s_i (metres); `distance_sum`, `point_count` the trimmed M_i, n_i; `psi` Psi_i
    (NaN where not judged); `judged`, `failed` bool; `unjudged_share` of each scan's beams.
    """

    scales: np.ndarray
    distance_sum: np.ndarray
    point_count: np.ndarray
    psi: np.ndarray
    judged: np.ndarray
    failed: np.ndarray
    unjudged_share: np.ndarray


def live_scales(scans: ScanSet, parameters: ConsistencyParameters, resolution: float,
                settings: LocalizationSettings) -> np.ndarray:
    """s_i of every live scan: eq. 10 over temporally adjacent live scans, floored.

    Parameters
    ----------
    scans: the live scans at the localizer's poses, in travel order.
    parameters: the paper's test (local_window, local_alpha, trimming, min_points, default
        and least scale).
    resolution: the map's cell size, metres.
    settings: scale_metres, the travel between a pair's scans at most; resolution_scale,
        the floor in cells.

    Returns
    -------
    (N,) s_i in metres.
    """
    pairs = local_pairs(scans, parameters.local_window)
    distance = travel(scans.sensor_poses)
    pairs = pairs[distance[pairs[:, 1]] - distance[pairs[:, 0]] <= settings.scale_metres]
    measures = measure_pairs(scans, pairs, keep_largest=max(parameters.trim_largest, 1))
    distance_sum, count = robust_sums(measures, parameters.trim_largest)
    # eq. 10 on each side apart: a pair (j, i) raises only i's bound from behind, only j's
    # from ahead (a pair of one scan twice raises that scan alone)
    sides = []
    for column in (0, 1):
        largest = np.full(scans.scan_count, NO_BOUND)
        own = np.repeat(measures.pairs[:, column:column + 1], 2, axis=1)
        add_local_bounds(largest, own, distance_sum, count, parameters)
        sides.append(largest)
    ahead, behind = sides
    both = (ahead >= 0.0) & (behind >= 0.0)
    largest = np.where(both, np.minimum(ahead, behind), np.maximum(ahead, behind))
    return np.maximum(scales_from_bounds(largest, parameters),
                      settings.resolution_scale * resolution)


def judge_scans(measures: GridMeasures, scales: np.ndarray, parameters: ConsistencyParameters,
               settings: LocalizationSettings) -> ScanTests:
    """The pairwise test of each scan against the map (Psi_i at alpha, one-sided).

    Parameters
    ----------
    measures: the scans' grid measures, keeping at least trim_largest depths.
    scales: (N,) s_i, metres.
    parameters: alpha, trim_largest, min_points.
    settings: max_unjudged.

    Returns
    -------
    The ScanTests.
    """
    distance_sum, count = robust_sums(measures, parameters.trim_largest)
    unjudged = measures.unjudged_share
    judged = (unjudged <= settings.max_unjudged) & (count >= parameters.min_points)
    psi = np.where(judged, statistics.standardized_inconsistency(distance_sum, count, scales),
                   np.nan)
    failed = judged & (np.nan_to_num(psi, nan=-np.inf) > statistics.normal_quantile(
        parameters.alpha))
    return ScanTests(scales=scales, distance_sum=distance_sum, point_count=count, psi=psi,
                     judged=judged, failed=failed, unjudged_share=unjudged)


def measure_and_judge(scans: ScanSet, reference: GridReference, scales: np.ndarray,
                     parameters: ConsistencyParameters,
                     settings: LocalizationSettings) -> ScanTests:
    """grid_measures then judge_scans: the scans at their poses against the map.

    Parameters
    ----------
    scans: the live scans (at the localizer's poses or corrected ones).
    reference: the prepared map.
    scales: (N,) s_i, metres.
    parameters: the paper's test.
    settings: max_unjudged.

    Returns
    -------
    The ScanTests.
    """
    measures = grid_measures(scans, reference, keep_largest=parameters.trim_largest)
    return judge_scans(measures, scales, parameters, settings)


def travel(poses: np.ndarray) -> np.ndarray:
    """Cumulative distance along the estimated positions.

    Parameters
    ----------
    poses: (N, 3) poses in travel order.

    Returns
    -------
    (N,) metres from the first pose, non-decreasing.
    """
    steps = np.hypot(*np.diff(np.asarray(poses)[:, :2], axis=0).T) if len(poses) > 1 else []
    return np.concatenate([[0.0], np.cumsum(steps)])


def window_starts(distance: np.ndarray, stamps: np.ndarray, metres: float,
                  seconds: float) -> np.ndarray:
    """The first scan of each scan's trailing window.

    Parameters
    ----------
    distance: (N,) cumulative travel, metres (`travel`).
    stamps: (N,) stamps, seconds, non-decreasing.
    metres, seconds: the window's length in travel and in time; whichever is reached first
        ends it.

    Returns
    -------
    (N,) int64: scan i's window is scans start[i]..i.
    """
    by_travel = np.searchsorted(distance, distance - metres, side='left')
    by_time = np.searchsorted(stamps, stamps - seconds, side='left')
    return np.maximum(np.maximum(by_travel, by_time), 0).astype(np.int64)


@dataclass(frozen=True)
class WindowTests:
    """The cascaded test over trailing windows, row i for the window ending at scan i.

    `starts` first scan of each window; `tested` judged scans r; `failed` failed scans;
    `critical` nu-hat(r); `flagged_windows` bool; `flagged` (N,) scans that failed inside a
    flagged window; `flaggable` (N,) windows with enough judged scans to be flagged;
    `flaggable_count` the judged scans that takes.
    """

    starts: np.ndarray
    tested: np.ndarray
    failed: np.ndarray
    critical: np.ndarray
    flagged_windows: np.ndarray
    flagged: np.ndarray
    flaggable: np.ndarray
    flaggable_count: int


def cascaded_test(tests: ScanTests, starts: np.ndarray,
                  parameters: ConsistencyParameters) -> WindowTests:
    """The binomial test of every trailing window (eqs. 7-8 over scans, not pairs).

    Parameters
    ----------
    tests: the scans' pairwise tests against the map.
    starts: (N,) the first scan of each scan's window (`window_starts`).
    parameters: failure_probability and binomial_alpha.

    Returns
    -------
    The WindowTests.
    """
    judged = np.concatenate([[0], np.cumsum(tests.judged)])
    failed = np.concatenate([[0], np.cumsum(tests.failed)])
    ends = np.arange(starts.size) + 1
    tested, failing = judged[ends] - judged[starts], failed[ends] - failed[starts]
    critical = statistics.binomial_critical_count(tested, parameters.failure_probability,
                                                  parameters.binomial_alpha)
    flagged_windows = failing > critical
    # every scan of a flagged window: +1 at its start, -1 after its end
    cover = np.zeros(starts.size + 1, dtype=np.int64)
    np.add.at(cover, starts[flagged_windows], 1)
    np.add.at(cover, ends[flagged_windows], -1)
    inside = np.cumsum(cover[:-1]) > 0
    needed = flaggable_pair_count(parameters.failure_probability, parameters.binomial_alpha)
    return WindowTests(starts=starts, tested=tested, failed=failing, critical=critical,
                       flagged_windows=flagged_windows, flagged=inside & tests.failed,
                       flaggable=tested >= needed, flaggable_count=needed)
