"""A labelled suite of whole maps, judged at default settings by both stages of the verdict.

Unlike the 150-keyframe parts of suite.py, every map here is a whole log as a user would check
it: the five corrected logs (Freiburg 079 every 5th scan), copies of each with everything after
a random seam turned (1, 2, 5 degrees) or shifted (0.1, 0.3 m) rigidly, and least-squares maps
of graphs built from Intel and Freiburg 079 (odometry from the raw bags, loop closures from the
relations) with some false loop closures added.

The label is what the map shows, not how it was made: the observable displacement of a map is
the largest, over the pairs of scans that overlap in the corrected map (n_ij >= min_points),
of the root mean square distance between the end points of the later scan placed by the map's
relative pose and by the corrected one. A map is inconsistent when it exceeds the verdict's
misalignment tolerance. The corrected logs are the reference (displacement 0) and are labelled
consistent, although they contain small genuine errors of their own.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.core.consistency import (BaselineParameters, ConsistencyParameters,
                                                  check_consistency, map_statistic,
                                                  pair_log_likelihoods, select_viewpoints)
from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.verdict import Assessment, ExplanationSettings, explain
from map_consistency_ros.evaluation import runner
from map_consistency_ros.evaluation.suite import CORRECTED_LOGS, displace
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

Progress = Callable[[int, int], None]

# every n-th scan of a log in the suite (Freiburg 079 has 4,791 scans)
EVERY = {'fr079': 5}
ROTATIONS_DEG = (1.0, 2.0, 5.0)
SHIFTS_M = (0.1, 0.3)
# graphs built from corrected log + relations + raw bag: dataset -> (relations, bag, stride)
BUILT_GRAPHS = {
    'intel': ('intel/intel.relations', 'intel/intel.orig.bag', 1),
    'fr079': ('fr079/fr079.relations', 'fr079/fr079.orig.bag', 5),
}
FALSE_LOOPS = (1, 3, 10)


@dataclass(frozen=True)
class WholeLogMap:
    """One map: the scans (ranges of a log) at `poses`, and its true (corrected) poses."""

    name: str
    dataset: str
    kind: str  # 'corrected', 'rotation', 'shift' or 'false loops'
    description: str
    log_path: Path
    scan_indices: np.ndarray  # records of the log
    poses: np.ndarray  # (N, 3) laser poses of the map
    true_poses: np.ndarray  # (N, 3) the corrected laser poses


@dataclass(frozen=True)
class WholeLogResult:
    """Both stages' verdicts on one map, the baseline's statistic, and its label."""

    name: str
    dataset: str
    kind: str
    description: str
    displacement: float  # observable displacement, metres
    paper_consistent: bool
    consistent: bool
    summary_line: str
    paper_flagged: int
    flagged: int
    baseline_statistic: float
    seconds_test: float
    seconds_explanation: float


def _corrected(dataset: str, data: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    path = data / CORRECTED_LOGS[dataset]
    log = read_carmen_log(path)
    indices = np.arange(0, log.scan_count, EVERY.get(dataset, 1))
    return path, indices, log.laser_poses[indices]


def displaced_maps(dataset: str, data: Path, seams: int, seed: int) -> list[WholeLogMap]:
    """The corrected map and its rigidly displaced copies at `seams` random seams per size.

    Parameters
    ----------
    dataset: a key of suite.CORRECTED_LOGS (thinned to every EVERY[dataset]-th scan).
    data: the shared data folder.
    seams: copies per size of ROTATIONS_DEG and SHIFTS_M; each seam is drawn in the middle
        half of the log, with a random sign of rotation or direction of shift.
    seed: seeds the draws together with the dataset's name.

    Returns
    -------
    The corrected map, then for each rotation and shift size its `seams` copies. Raises
    InputError for a missing or malformed log.
    """
    path, indices, poses = _corrected(dataset, data)
    maps = [WholeLogMap(f'{dataset}/corrected', dataset, 'corrected', 'corrected log', path,
                        indices, poses, poses)]
    rng = np.random.default_rng([seed, sum(map(ord, dataset))])
    count = len(indices)
    sizes = [('rotation', value, 0.0) for value in ROTATIONS_DEG] + \
            [('shift', 0.0, value) for value in SHIFTS_M]
    for kind, degrees, metres in sizes:
        for seam in range(seams):
            pivot = int(rng.integers(count // 4, 3 * count // 4))
            sign = rng.choice([-1.0, 1.0])
            heading = rng.uniform(-np.pi, np.pi)
            shift = metres * np.array([np.cos(heading), np.sin(heading)])
            moved = displace(poses, pivot, count, sign * np.radians(degrees), shift)
            size = f'{degrees:g} deg' if kind == 'rotation' else f'{metres:g} m'
            maps.append(WholeLogMap(f'{dataset}/{kind} {size} #{seam}', dataset, kind,
                                    f'scans {pivot}-{count - 1} displaced by {size}', path,
                                    indices, moved, poses))
    return maps


def false_loop_maps(dataset: str, data: Path, seed: int) -> list[WholeLogMap]:
    """Least-squares maps of the built graph of `dataset` with FALSE_LOOPS false loop closures.

    Parameters
    ----------
    dataset: a key of BUILT_GRAPHS.
    data: the shared data folder with the corrected log, relations and raw bag.
    seed: the graph with c false loop closures is built with seed + c.

    Returns
    -------
    One map per count of FALSE_LOOPS: the optimized laser poses, the corrected ones as the
    truth. Raises InputError for missing or malformed inputs.
    """
    from map_consistency_ros.core.backend import optimize
    from map_consistency_ros.io.datasets import (BuildSettings, build_graph, read_raw_bag,
                                                 read_relations)
    relations, bag_path, stride = BUILT_GRAPHS[dataset]
    path = data / CORRECTED_LOGS[dataset]
    log, bag = read_carmen_log(path), read_raw_bag(data / bag_path)
    relation_rows = read_relations(data / relations)
    maps = []
    for count in FALSE_LOOPS:
        built = build_graph(log, relation_rows, bag, BuildSettings(
            stride=stride, false_loop_closures=count, seed=seed + count))
        solution = optimize(built.graph, None, iterations=100)
        laser = built.laser
        poses = se2.compose(solution.poses, bag.laser_offset)
        indices = np.arange(0, log.scan_count, stride)
        maps.append(WholeLogMap(f'{dataset}/false loops {count}', dataset, 'false loops',
                                f'least squares with {count} false loop closures', path,
                                indices, poses, laser.laser_poses))
    return maps


def observable_displacement(scans: ScanSet, true_poses: np.ndarray,
                            parameters: ConsistencyParameters) -> float:
    """The label (module docstring): largest RMS end-point displacement over overlapping pairs.

    Parameters
    ----------
    scans: the map's scans at its poses.
    true_poses: (N, 3) the corrected poses of the same scans.
    parameters: the test's parameters; the pairs it tests on the corrected map are the
        overlapping pairs.

    Returns
    -------
    The displacement in metres; 0 when no pair overlaps.
    """
    truth = scans.with_poses(true_poses)
    result = check_consistency(truth, parameters)
    pairs = result.pairs[result.tested]
    if pairs.size == 0:
        return 0.0
    first, second = pairs[:, 0], pairs[:, 1]
    # the world transform that puts scan i of the map onto its true pose, applied to scan j
    correction = se2.compose(true_poses[first], se2.inverse(scans.sensor_poses[first]))
    worst = 0.0
    for start in range(0, len(pairs), 4096):
        rows = slice(start, start + 4096)
        placed = se2.compose(correction[rows], scans.sensor_poses[second[rows]])
        error = _endpoint_rms(scans, second[rows], placed, true_poses[second[rows]])
        worst = max(worst, float(error.max()))
    return worst


def _endpoint_rms(scans: ScanSet, scan_rows: np.ndarray, placed: np.ndarray,
                  truth: np.ndarray) -> np.ndarray:
    """RMS distance between the end points of scans at `placed` and at `truth` poses."""
    bearings = scans.model.bearings(scans.ranges.shape[1])[None, :]
    ranges = scans.ranges[scan_rows]
    valid = scans.valid[scan_rows]

    def ends(poses: np.ndarray) -> np.ndarray:
        angle = poses[:, 2:3] + bearings
        return np.stack([poses[:, 0:1] + ranges * np.cos(angle),
                         poses[:, 1:2] + ranges * np.sin(angle)], axis=-1)

    square = np.sum((ends(placed) - ends(truth)) ** 2, axis=-1)
    return np.sqrt(np.where(valid, square, 0.0).sum(axis=1) / np.maximum(valid.sum(axis=1), 1))


def build(data: Path, datasets: list[str], seams: int, seed: int) -> list[WholeLogMap]:
    """The whole suite: displaced copies of each dataset, false-loop maps where it has a graph.

    Parameters
    ----------
    data: the shared data folder.
    datasets: keys of suite.CORRECTED_LOGS, in order.
    seams: as displaced_maps.
    seed: as displaced_maps and false_loop_maps.

    Returns
    -------
    The displaced maps of every dataset, then the false-loop maps of those in BUILT_GRAPHS.
    """
    maps = [item for dataset in datasets for item in displaced_maps(dataset, data, seams, seed)]
    return maps + [item for dataset in datasets if dataset in BUILT_GRAPHS
                   for item in false_loop_maps(dataset, data, seed)]


def map_scans(whole: WholeLogMap, parameters: ConsistencyParameters | None = None
              ) -> tuple[ScanSet, np.ndarray]:
    """The map's viewpoints placed at its poses (as `check` tests a log), and their rows.

    Parameters
    ----------
    whole: the map.
    parameters: the viewpoint spacing and turn; None for the defaults.

    Returns
    -------
    (ScanSet of the V viewpoints, their rows (V,) into the map's scans).
    """
    parameters = parameters or ConsistencyParameters()
    log = runner.cached_log(whole.log_path)
    every = ScanSet.from_ranges(log.ranges[whole.scan_indices], whole.poses, sensor_model(log))
    rows = select_viewpoints(every, parameters)
    return every.take(rows), rows


def assess(whole: WholeLogMap, parameters: ConsistencyParameters | None = None,
           settings: ExplanationSettings | None = None) -> tuple[ScanSet, Assessment]:
    """The map's viewpoints and both stages' verdict on them.

    Parameters
    ----------
    whole: the map.
    parameters: the test's parameters; None for the defaults.
    settings: the explanation's settings; None for the defaults.

    Returns
    -------
    (ScanSet of the viewpoints, the Assessment).
    """
    scans, _ = map_scans(whole, parameters)
    return scans, explain(scans, check_consistency(scans, parameters), settings)


def judge(whole: WholeLogMap, parameters: ConsistencyParameters,
          settings: ExplanationSettings, baseline: BaselineParameters) -> WholeLogResult:
    """Both stages at the given settings, the baseline's statistic, and the map's label.

    Parameters
    ----------
    whole: the map.
    parameters: the test's parameters.
    settings: the explanation's settings.
    baseline: the baseline's parameters (scored on the pairs the test measured).

    Returns
    -------
    The WholeLogResult, with the observable displacement of the viewpoints and the seconds of
    each stage.
    """
    scans, rows = map_scans(whole, parameters)
    started = time.perf_counter()
    result = check_consistency(scans, parameters)
    middle = time.perf_counter()
    assessment = explain(scans, result, settings)
    ended = time.perf_counter()
    statistic = map_statistic(pair_log_likelihoods(scans, result.pairs, baseline), baseline)
    return WholeLogResult(
        name=whole.name, dataset=whole.dataset, kind=whole.kind, description=whole.description,
        displacement=observable_displacement(scans, whole.true_poses[rows], parameters),
        paper_consistent=result.consistent, consistent=assessment.consistent,
        summary_line=assessment.summary_line(), paper_flagged=int(result.inconsistent.sum()),
        flagged=int(assessment.flagged.sum()), baseline_statistic=statistic,
        seconds_test=middle - started, seconds_explanation=ended - middle)


def judge_all(maps: list[WholeLogMap], parameters: ConsistencyParameters | None = None,
              settings: ExplanationSettings | None = None,
              baseline: BaselineParameters | None = None, workers: int | None = None,
              progress: Progress | None = None,
              scheduler: str | None = None) -> list[WholeLogResult]:
    """`judge` over all maps in a process pool (or on the Dask cluster of `scheduler`).

    Parameters
    ----------
    maps: the maps.
    parameters, settings, baseline: as judge; None for the defaults.
    workers, progress, scheduler: how the maps are spread, as runner.pooled.

    Returns
    -------
    One WholeLogResult per map, in the order of `maps`. Raises RuntimeError when a worker
    died.
    """
    arguments = (parameters or ConsistencyParameters(), settings or ExplanationSettings(),
                 baseline or BaselineParameters())
    return runner.pooled(judge, maps, arguments, workers, progress, scheduler)
