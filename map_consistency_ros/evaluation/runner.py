"""Both detectors over the map suite: geometry once per map (process pool), then parameter sweeps.

The expensive part, the pair measures M_ij / n_ij of the map and of its incremental solution's
local pairs, and the baseline's per-pair log-likelihoods, is computed once per map. Sweeping
the test's levels (alpha, alpha' = binomial_alpha, local_alpha) and the baseline's threshold
only re-runs the statistics.
"""
from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from map_consistency_ros import pool
from map_consistency_ros.core.consistency import (BaselineParameters, ConsistencyParameters,
                                                  PairLikelihoods, check_consistency,
                                                  evaluate_pairs, local_pairs, local_scales,
                                                  map_statistic, pair_log_likelihoods)
from map_consistency_ros.core.geometry import PairMeasures, ScanSet, candidate_pairs, pair_measures
from map_consistency_ros.core.verdict import ExplanationSettings, RegistrationCache, explain
from map_consistency_ros.evaluation import metrics
from map_consistency_ros.evaluation.suite import SuiteMap, SuiteParameters, keyframes
from map_consistency_ros.io.carmen import CarmenLog, read_carmen_log, sensor_model

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class MeasureSettings:
    """What the per-map geometry depends on (fixed during a sweep)."""

    max_range: float | None = None  # None: the reader's default (8 m, as the original)
    test: ConsistencyParameters = field(default_factory=ConsistencyParameters)
    baseline: BaselineParameters = field(default_factory=BaselineParameters)


@dataclass(frozen=True)
class MeasuredMap:
    """A suite map's label and everything the sweeps need, without the scans themselves."""

    name: str
    dataset: str
    kind: str
    inconsistent: bool
    environment: str
    scan_count: int
    measures: PairMeasures  # candidate pairs of the map
    local: PairMeasures  # temporally local pairs of the incremental solution
    likelihoods: PairLikelihoods  # the baseline's, same pairs as `measures`
    seconds_ours: float
    seconds_baseline: float


@dataclass(frozen=True)
class RuntimeRow:
    """One row of the runtime table (paper's Table I): N scans, R, K beams, seconds."""

    dataset: str
    scan_count: int
    mean_overlaps: float  # R: scans whose extents overlap a scan's, on average
    beam_count: int
    seconds_ours: float
    seconds_baseline: float


@lru_cache(maxsize=8)
def cached_log(path: Path) -> CarmenLog:
    """The log at `path`, read once per process (a pool worker judges many maps of it).

    Parameters
    ----------
    path: a CARMEN log; the cache keeps the last 8 logs read.

    Returns
    -------
    The CarmenLog, shared between callers: do not change its arrays. Raises InputError as
    read_carmen_log (errors are not cached).
    """
    return read_carmen_log(path)


def map_scans(suite_map: SuiteMap, max_range: float | None) -> ScanSet:
    """The map's scans placed at its poses.

    Parameters
    ----------
    suite_map: the map; its log is read through cached_log.
    max_range: usable range in metres; None for the reader's default (see sensor_model).

    Returns
    -------
    A ScanSet of the map's N scans at `suite_map.poses`, with the log's beam geometry.
    """
    log = cached_log(suite_map.log_path)
    return ScanSet.from_ranges(log.ranges[suite_map.scan_indices], suite_map.poses,
                               sensor_model(log, max_range=max_range))


def measure_map(suite_map: SuiteMap, settings: MeasureSettings) -> MeasuredMap:
    """The geometry of one map: our pair measures (map and local) and the baseline's scores.

    Parameters
    ----------
    suite_map: the map; its incremental solution (`reference_poses`) gives the local pairs.
    settings: usable range, test parameters (local window, trimming) and baseline parameters.

    Returns
    -------
    A MeasuredMap with the map's label, the measures of its candidate pairs, those of the
    local pairs of its incremental solution, the baseline's per-pair log-likelihoods, and the
    seconds each detector's geometry took.
    """
    scans = map_scans(suite_map, settings.max_range)
    reference = scans.with_poses(suite_map.reference_poses)
    keep = settings.test.trim_largest
    started = time.perf_counter()
    local = pair_measures(reference, local_pairs(reference, settings.test.local_window), keep)
    pairs = candidate_pairs(scans.extents)
    measures = pair_measures(scans, pairs, keep)
    middle = time.perf_counter()
    likelihoods = pair_log_likelihoods(scans, pairs, settings.baseline)
    ended = time.perf_counter()
    return MeasuredMap(name=suite_map.name, dataset=suite_map.dataset, kind=suite_map.kind,
                       inconsistent=suite_map.inconsistent, environment=suite_map.environment,
                       scan_count=scans.scan_count, measures=measures, local=local,
                       likelihoods=likelihoods, seconds_ours=middle - started,
                       seconds_baseline=ended - middle)


def measure_suite(maps: Sequence[SuiteMap], settings: MeasureSettings, workers: int | None = None,
                  progress: Progress | None = None,
                  scheduler: str | None = None) -> list[MeasuredMap]:
    """measure_map over all maps with a process pool (or on the Dask cluster of `scheduler`).

    Parameters
    ----------
    maps: the suite maps.
    settings: passed to measure_map.
    workers, progress, scheduler: how the maps are spread, as `pooled`.

    Returns
    -------
    One MeasuredMap per map, in the order of `maps`. Raises RuntimeError when a worker died.
    """
    return pooled(measure_map, maps, (settings,), workers, progress, scheduler)


def our_verdicts(measured: Sequence[MeasuredMap], parameters: ConsistencyParameters,
                 scales: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """Our test's verdict on every measured map.

    Parameters
    ----------
    measured: the M measured maps.
    parameters: the test's parameters.
    scales: per map, the (N,) local scales from `local_scales` at `parameters.local_alpha`,
        which skips refitting them; None to fit them here.

    Returns
    -------
    (M,) bool: the map fails the test (some scan fails its cascaded test) at `parameters`.
    """
    if scales is None:
        scales = [local_scales(item.local, item.scan_count, parameters) for item in measured]
    flagged = np.zeros(len(measured), dtype=bool)
    for index, (item, scale) in enumerate(zip(measured, scales)):
        result = evaluate_pairs(item.measures, scale, item.scan_count, parameters)
        flagged[index] = not result.consistent
    return flagged


def labels(measured: Sequence[MeasuredMap]) -> np.ndarray:
    """The labels of the measured maps.

    Parameters
    ----------
    measured: the M measured maps.

    Returns
    -------
    (M,) bool: the map is inconsistent by construction.
    """
    return np.array([item.inconsistent for item in measured], dtype=bool)


def sweep_ours(measured: Sequence[MeasuredMap], base: ConsistencyParameters,
               alphas: Sequence[float], binomial_alphas: Sequence[float],
               local_alphas: Sequence[float], flag_windows: Sequence[int] = (0,)) -> np.ndarray:
    """Our test over a grid of its levels, each setting's specificity and recall.

    Parameters
    ----------
    measured: the measured suite (both labels present).
    base: the parameters the swept ones replace.
    alphas: pairwise test levels.
    binomial_alphas: cascaded (binomial) test levels.
    local_alphas: levels of the local scale fit (the scales are fitted once per value).
    flag_windows: flag_window values.

    Returns
    -------
    (S, 6) rows (alpha, binomial_alpha, local_alpha, flag_window, specificity, recall), one per
    combination, local_alpha outermost. Raises ValueError as metrics.specificity_recall.
    """
    truth = labels(measured)
    rows = []
    for local_alpha in local_alphas:
        fitted = replace(base, local_alpha=local_alpha)
        scales = [local_scales(item.local, item.scan_count, fitted) for item in measured]
        for alpha, binomial_alpha, window in itertools.product(alphas, binomial_alphas,
                                                               flag_windows):
            parameters = replace(fitted, alpha=alpha, binomial_alpha=binomial_alpha,
                                 flag_window=window)
            flagged = our_verdicts(measured, parameters, scales)
            rows.append((alpha, binomial_alpha, local_alpha, window,
                         *metrics.specificity_recall(flagged, truth)))
    return np.array(rows)


def sweep_baseline(measured: Sequence[MeasuredMap], base: BaselineParameters,
                   quantiles: Sequence[float]) -> np.ndarray:
    """The baseline over its quantiles and every distinct threshold of its statistic.

    Parameters
    ----------
    measured: the measured suite (both labels present).
    base: the baseline parameters the swept quantile replaces.
    quantiles: quantiles of the per-pair log-likelihoods that make the map statistic.

    Returns
    -------
    (S, 4) rows (quantile, threshold, specificity, recall), quantile by quantile, thresholds
    as metrics.threshold_sweep. Raises ValueError as metrics.specificity_recall.
    """
    truth = labels(measured)
    rows = []
    for quantile in quantiles:
        parameters = replace(base, quantile=quantile)
        statistic = np.array([map_statistic(item.likelihoods, parameters) for item in measured])
        sweep = metrics.threshold_sweep(statistic, truth)
        rows.append(np.column_stack([np.full(len(sweep), quantile), sweep]))
    return np.concatenate(rows)


def two_stage_flags(item: tuple[SuiteMap, MeasuredMap], settings: MeasureSettings,
                    alphas: Sequence[float], tolerances: Sequence[float]) -> np.ndarray:
    """Whether both stages flag one map over a grid of two settings, from its measured pairs.

    The registrations do not depend on either setting: one cache serves the whole sweep.

    Parameters
    ----------
    item: (map, its MeasuredMap), one item of the pool.
    settings: usable range and the test parameters the swept alpha replaces.
    alphas: (A,) pairwise test levels.
    tolerances: (T,) misalignment tolerances of the second stage (every other explanation
        setting at its default).

    Returns
    -------
    (A, T) bool: both stages flag the map at alphas[a] and tolerances[t].
    """
    suite_map, measured = item
    scans = map_scans(suite_map, settings.max_range)
    registrations = RegistrationCache()
    flags = np.zeros((len(alphas), len(tolerances)), dtype=bool)
    for row, alpha in enumerate(alphas):
        parameters = replace(settings.test, alpha=alpha)
        result = evaluate_pairs(
            measured.measures, local_scales(measured.local, scans.scan_count, parameters),
            scans.scan_count, parameters)
        for column, tolerance in enumerate(tolerances):
            flags[row, column] = not explain(
                scans, result, ExplanationSettings(misalignment_tolerance=tolerance),
                cache=registrations).consistent
    return flags


def sweep_two_stage(maps: Sequence[SuiteMap], measured: Sequence[MeasuredMap],
                    settings: MeasureSettings, alphas: Sequence[float],
                    tolerances: Sequence[float], workers: int | None = None,
                    progress: Progress | None = None,
                    scheduler: str | None = None) -> np.ndarray:
    """The two-stage verdict over the suite for a grid of alphas and tolerances.

    Parameters
    ----------
    maps: the suite maps (both labels present).
    measured: measure_suite of `maps`, in the same order.
    settings: as two_stage_flags.
    alphas: pairwise test levels.
    tolerances: misalignment tolerances.
    workers, progress, scheduler: how the maps are spread, as `pooled`.

    Returns
    -------
    (A * T, 4) rows (alpha, tolerance, specificity, recall), alpha outermost. Raises
    RuntimeError when a worker died, ValueError as metrics.specificity_recall.
    """
    truth = np.array([item.inconsistent for item in maps], dtype=bool)
    flags = pooled(two_stage_flags, list(zip(maps, measured)),
                   (settings, tuple(alphas), tuple(tolerances)), workers, progress, scheduler)
    rows = []
    for row, alpha in enumerate(alphas):
        for column, tolerance in enumerate(tolerances):
            flagged = np.array([item[row, column] for item in flags])
            rows.append((alpha, tolerance, *metrics.specificity_recall(flagged, truth)))
    return np.array(rows)


def pooled(function: Callable, maps: Sequence, arguments: tuple, workers: int | None,
           progress: Progress | None, scheduler: str | None = None) -> list:
    """function(map, *arguments) for every map on the runner `batch` uses too (pool.py):
    local processes, or the Dask cluster of `scheduler`. A map whose worker process died stops
    the evaluation: its figures would be wrong without it.

    Parameters
    ----------
    function: a picklable module-level function of (map, *arguments).
    maps: the items, one call each.
    arguments: the further arguments of every call.
    workers: local processes; None for one per core, 1 to run in this process.
    progress: progress(done, total) after each finished map, or None.
    scheduler: a Dask scheduler address (tcp://host:8786); None for local processes.

    Returns
    -------
    The results in map order. Raises RuntimeError naming the map whose worker died; an
    exception of `function` propagates.
    """
    results = pool.run_all(function, maps, arguments, workers, scheduler, progress)
    for item, result in zip(maps, results):
        if isinstance(result, pool.WorkerDied):
            raise RuntimeError(f'{getattr(item, "name", item)}: {result.message}')
    return results


def _keyframe_scans(log_path: Path, suite: SuiteParameters, max_range: float | None) -> ScanSet:
    log = cached_log(log_path)
    frames = keyframes(log.laser_poses, suite.keyframe_distance, suite.keyframe_angle)
    return ScanSet.from_ranges(log.ranges[frames], log.laser_poses[frames],
                               sensor_model(log, max_range=max_range))


def runtime_row(dataset: str, log_path: Path, suite: SuiteParameters,
                settings: MeasureSettings) -> RuntimeRow:
    """Time the full test (and the baseline) on a whole log thinned to keyframes, as Table I.

    Parameters
    ----------
    dataset: the dataset's name, copied into the row.
    log_path: its corrected log.
    suite: the keyframe thresholds.
    settings: usable range, test and baseline parameters.

    Returns
    -------
    The RuntimeRow: keyframe count, mean overlapping scans per scan, beam count and the
    seconds of check_consistency and of the baseline's pair scoring.
    """
    scans = _keyframe_scans(log_path, suite, settings.max_range)
    started = time.perf_counter()
    check_consistency(scans, settings.test)
    middle = time.perf_counter()
    pairs = candidate_pairs(scans.extents)
    pair_log_likelihoods(scans, pairs, settings.baseline)
    ended = time.perf_counter()
    return RuntimeRow(dataset=dataset, scan_count=scans.scan_count,
                      mean_overlaps=2.0 * len(pairs) / max(scans.scan_count, 1),
                      beam_count=int(scans.ranges.shape[1]), seconds_ours=middle - started,
                      seconds_baseline=ended - middle)


def runtime_table(maps: Sequence[SuiteMap], suite: SuiteParameters, settings: MeasureSettings,
                  progress: Progress | None = None) -> list[RuntimeRow]:
    """runtime_row for every dataset of the suite, one after the other on all cores.

    A small untimed run first loads the compiled kernels, so that no row pays for that.

    Parameters
    ----------
    maps: the suite maps; each dataset among them gives one row (its log read once).
    suite: the keyframe thresholds.
    settings: usable range, test and baseline parameters.
    progress: progress(done, total) after each dataset, or None.

    Returns
    -------
    One RuntimeRow per dataset, in order of first appearance in `maps`; empty for no maps.
    """
    logs = {item.dataset: item.log_path for item in maps}
    if not logs:
        return []
    warm = _keyframe_scans(next(iter(logs.values())), suite, settings.max_range)
    warm = ScanSet.from_ranges(warm.ranges[:20], warm.sensor_poses[:20], warm.model)
    check_consistency(warm, settings.test)
    pair_log_likelihoods(warm, candidate_pairs(warm.extents), settings.baseline)
    rows = []
    for done, (dataset, path) in enumerate(logs.items(), start=1):
        rows.append(runtime_row(dataset, path, suite, settings))
        if progress:
            progress(done, len(logs))
    return rows
