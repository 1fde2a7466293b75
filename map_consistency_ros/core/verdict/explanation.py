"""The second stage of the verdict: explain every failed pair as misalignment or change.

The paper's test (core/consistency) asks whether the inconsistency distances of a pair exceed
sensor noise. On real maps they also do where the world changed between two visits (people,
doors, chairs, no-return beams), which is no error of the map. This stage explains each failed
pair that contributes to a flagged scan:

- the submaps around its two scans (`block` consecutive scans each, widened by `margin`) are
  registered robustly (_registration.py): the correction of the later side onto the earlier one,
  with its covariance and the fraction of the surfaces that agree;
- misaligned: the correction is determined, plausible (within `max_translation` /
  `max_rotation_deg`), statistically different from zero, moves the later scan's end points by
  more than `misalignment_tolerance`, and with it the pair passes the pairwise test;
- minor: a correction within the tolerance, or not significant, makes the pair pass;
- change: the static surfaces agree but no rigid correction makes the pair pass;
- unregistered: the surfaces do not agree or the correction is beyond plausible (a gross error
  that local registration cannot converge on). Counted as misaligned: a map error of metres
  must never pass as a change.

Misaligned and unregistered pairs go through the paper's cascaded binomial test per scan; scans
that fail it form misaligned regions, joined through their pairs and temporal adjacency. The
map is inconsistent when a misaligned region exists. Changes never fail a map; their deep end
points are grouped into changed places and reported. `strict` keeps the paper's verdict.

The parts: _assessment.py (outcomes, pair classes, settings, Misalignment, ChangedPlace,
Assessment), _pair_classes.py (registration tasks, the corrected pairs' test, classes,
confirmation), _misaligned_regions.py (regions, regions among changes, whole-region
registration), _changed_places.py (changed places), _union_find.py; this module runs them in
order (explain, check_map) and keeps the registration cache. Their public names are importable
from here (and from the package).
"""
from __future__ import annotations

import numpy as np

from map_consistency_ros.core.consistency import (ConsistencyParameters, ConsistencyResult,
                                                  Progress, check_consistency,
                                                  inconsistent_endpoints, pair_endpoints)
from map_consistency_ros.core.geometry import ScanSet
from map_consistency_ros.core.verdict._assessment import (Assessment, CHANGE, CONSISTENT,
                                                          ChangedPlace, ExplanationSettings,
                                                          INCONSISTENT, MINOR, MISALIGNED,
                                                          Misalignment, NOTHING_TO_JUDGE,
                                                          PAIR_CLASSES, PairClass, UNREGISTERED,
                                                          _CLASS_CODE, _by_size, _local_distortion)
from map_consistency_ros.core.verdict._changed_places import _changes, place_labels
from map_consistency_ros.core.verdict._frozen import FrozenEstimate, frozen_estimates
from map_consistency_ros.core.verdict._misaligned_regions import (_region_scans, _regions,
                                                                  _regions_among_changes,
                                                                  agreeing_registrations,
                                                                  longest_run, longest_travel,
                                                                  regions_alike)
from map_consistency_ros.core.verdict._pair_classes import (PointMoments, _cascaded, _classify,
                                                            _corrected_pairs_pass, _tasks,
                                                            corrections_confirmed)
from map_consistency_ros.core.verdict._registration import (RegistrationSettings, Registrations,
                                                            register_submaps, surface_points)

__all__ = [
    'CONSISTENT', 'INCONSISTENT', 'NOTHING_TO_JUDGE', 'PairClass', 'MISALIGNED', 'MINOR', 'CHANGE',
    'UNREGISTERED', 'PAIR_CLASSES', 'ExplanationSettings', 'Misalignment', 'ChangedPlace',
    'Assessment', 'PointMoments', 'agreeing_registrations', 'corrections_confirmed', 'longest_run',
    'longest_travel', 'place_labels', 'regions_alike', 'RegistrationCache', 'explain', 'check_map',
    'misaligned_endpoints',
]


def _empty(result: ConsistencyResult, settings: ExplanationSettings,
           frozen: tuple[FrozenEstimate, ...]) -> Assessment:
    return Assessment(result=result, settings=settings, explained_pairs=np.zeros(0, np.int64),
                      pair_classes=np.zeros(0, np.int64), pair_corrections=np.zeros((0, 3)),
                      pair_displacements=np.zeros(0),
                      misaligned_scans=np.zeros(result.scan_count, dtype=bool),
                      misalignments=(), changes=(), local_distortion=_local_distortion(result),
                      frozen=frozen)


class RegistrationCache:
    """Registrations of submaps already registered, keyed by their scans and poses.

    A live map changes a little per keyframe: most registrations of the last explanation
    still hold. Bounded: the oldest entries go first beyond `capacity`.
    """

    def __init__(self, capacity: int = 50_000) -> None:
        self.capacity = capacity
        self._entries: dict[bytes, tuple] = {}

    def __len__(self) -> int:
        return len(self._entries)

    @staticmethod
    def _keys(scans: ScanSet, tasks: np.ndarray) -> list[bytes]:
        poses, ranges = scans.sensor_poses, scans.ranges
        return [b''.join((row.tobytes(), poses[row[0]:row[1]].tobytes(),
                          poses[row[2]:row[3]].tobytes(),
                          ranges[row[0]:row[1], ::16].tobytes(),
                          ranges[row[2]:row[3], ::16].tobytes())) for row in tasks]

    def register(self, scans: ScanSet, tasks: np.ndarray,
                 settings: RegistrationSettings | None) -> Registrations:
        """register_submaps of some tasks, computing only those not registered before.

        Parameters
        ----------
        scans: the scans placed in the world; a task is known by its scans' poses and ranges.
        tasks: (T, 4) registration tasks (r0, r1, q0, q1), as register_submaps.
        settings: the ICP's settings; None for the defaults. The cache's keys do not hold
            them: one cache serves one setting.

        Returns
        -------
        The Registrations of the T tasks, in order.
        """
        keys = self._keys(scans, tasks)
        missing = [index for index, key in enumerate(keys) if key not in self._entries]
        if missing:
            fresh = register_submaps(surface_points(scans.endpoints, scans.valid),
                                     tasks[missing], settings)
            for row, index in enumerate(missing):
                self._entries[keys[index]] = (
                    fresh.corrections[row], fresh.centroids[row], fresh.covariances[row],
                    fresh.matched[row], fresh.determined[row])
        entries = [self._entries[key] for key in keys]
        while len(self._entries) > self.capacity:
            del self._entries[next(iter(self._entries))]
        if not entries:
            return register_submaps(surface_points(scans.endpoints, scans.valid), tasks,
                                    settings)
        corrections, centroids, covariances, matched, determined = (
            np.array(column) for column in zip(*entries))
        return Registrations(corrections=corrections.reshape(-1, 3),
                             centroids=centroids.reshape(-1, 2),
                             covariances=covariances.reshape(-1, 3, 3),
                             matched=matched.astype(np.int64),
                             determined=determined.astype(bool))


def explain(scans: ScanSet, result: ConsistencyResult,
            settings: ExplanationSettings | None = None,
            registration: RegistrationSettings | None = None,
            cache: RegistrationCache | None = None) -> Assessment:
    """Explain the failed pairs of `result` on the map `scans` and make the verdict.

    Only failed pairs that involve a scan flagged by the paper's test are explained: the others
    cannot change the verdict. A map that passes the paper's test costs nothing here.

    Parameters
    ----------
    scans: the N scans `result` was computed on, at their map poses.
    result: the paper's test on them.
    settings: the explanation's settings; None for the defaults.
    registration: the ICP's settings; None for the defaults.
    cache: registrations kept across calls on a growing map: those that still hold are not
        computed again. None registers every task.

    Returns
    -------
    The Assessment. Raises ValueError when `scans` and `result` differ in scan count.
    """
    settings = settings or ExplanationSettings()
    if scans.scan_count != result.scan_count:
        raise ValueError(f'{scans.scan_count} scans for a result on {result.scan_count}')
    frozen = frozen_estimates(scans, result.parameters, settings.min_region_scans)
    pairs_all = result.pairs
    rows = np.flatnonzero(result.failed & (result.inconsistent[pairs_all[:, 0]]
                                           | result.inconsistent[pairs_all[:, 1]]))
    if rows.size == 0:
        return _empty(result, settings, frozen)
    pairs = pairs_all[rows]
    tasks, task_of_pair = _tasks(pairs, settings, scans.scan_count)
    registrations = (register_submaps(surface_points(scans.endpoints, scans.valid), tasks,
                                      registration) if cache is None
                     else cache.register(scans, tasks, registration))
    task_transforms = registrations.world_transforms()
    transforms = task_transforms[task_of_pair]
    passes = _corrected_pairs_pass(scans, result, pairs, transforms)
    moments = PointMoments.of(scans)
    displacement = moments.displacement(transforms, pairs[:, 1])
    codes, rigid = _classify(registrations, task_of_pair, passes, displacement, settings)
    candidates = np.unique(task_of_pair[codes == _CLASS_CODE[MISALIGNED]])
    unconfirmed = np.ones(len(tasks), dtype=bool)
    unconfirmed[candidates] = ~corrections_confirmed(scans, result, tasks[candidates],
                                                     task_transforms[candidates], settings)
    # a correction that breaks as much as it mends explains nothing: the failure is a change
    demoted = (codes == _CLASS_CODE[MISALIGNED]) & unconfirmed[task_of_pair]
    codes[demoted] = _CLASS_CODE[CHANGE]
    misaligned = codes == _CLASS_CODE[MISALIGNED]
    unexplained = (codes == _CLASS_CODE[CHANGE]) | (codes == _CLASS_CODE[UNREGISTERED])
    # Changes are local: a scan most of whose overlaps fail beyond any small correction sees
    # a gross error, which must never pass as a change.
    gross = _cascaded(result, pairs, unexplained, settings.gross_fraction)
    # A correction beyond any plausible local one that still leaves the pair failing is no
    # change either: a stretch displaced further than registration reaches.
    beyond = codes == _CLASS_CODE[UNREGISTERED]
    flagged = _cascaded(result, pairs, misaligned | beyond) | gross
    bad = misaligned | beyond | (unexplained & (gross[pairs[:, 0]] | gross[pairs[:, 1]]))
    regions = _regions(scans, result, rows, moments, bad, codes, transforms,
                       registrations.covariances[task_of_pair], task_of_pair, flagged, settings,
                       registration)
    among_changes = rigid & ~demoted & (codes == _CLASS_CODE[CHANGE])
    hidden = _regions_among_changes(scans, moments, pairs, among_changes, transforms,
                                    registrations.covariances[task_of_pair], task_of_pair,
                                    _region_scans(regions, scans.scan_count), settings,
                                    registration)
    for region_rows, _ in hidden:
        codes[region_rows] = _CLASS_CODE[MISALIGNED]
    regions = regions + tuple(region for _, region in hidden)
    # The tolerance is the map's: a region fails it by the displacement of its own correction,
    # however far the single registrations behind it strayed.
    within = [region.registered and region.displacement <= settings.misalignment_tolerance
              for region in regions]
    # numbered in this order by every output (#1 the region that fails the map)
    minor = _by_size(tuple(region for region, small in zip(regions, within) if small))
    misalignments = _by_size(tuple(region for region, small in zip(regions, within)
                                   if not small))
    flagged = _region_scans(misalignments, scans.scan_count)
    changes = _changes(scans, result, rows[codes == _CLASS_CODE[CHANGE]], settings)
    return Assessment(result=result, settings=settings, explained_pairs=rows, pair_classes=codes,
                      pair_corrections=transforms, pair_displacements=displacement,
                      misaligned_scans=flagged, misalignments=misalignments, changes=changes,
                      local_distortion=_local_distortion(result), minor_misalignments=minor,
                      frozen=frozen)


def check_map(scans: ScanSet, parameters: ConsistencyParameters | None = None,
              settings: ExplanationSettings | None = None,
              reference_scans: ScanSet | None = None,
              progress: Progress | None = None) -> Assessment:
    """Both stages on scans placed in the map: the paper's test, then the explanation.

    Parameters
    ----------
    scans, parameters, reference_scans, progress: as check_consistency.
    settings: the explanation's settings; None for the defaults.

    Returns
    -------
    The Assessment (its `result` the paper's test).
    """
    result = check_consistency(scans, parameters, reference_scans, progress)
    return explain(scans, result, settings)


def misaligned_endpoints(scans: ScanSet, assessment: Assessment, max_pairs: int = 200,
                         min_depth: float = 0.0,
                         region: Misalignment | None = None) -> np.ndarray:
    """End points inside the other scan's polygon in the pairs behind the verdict: the
    misaligned and unregistered pairs of flagged scans (strict: every failed pair of flagged
    scans), or the failed pairs behind one region.

    Parameters
    ----------
    scans: the scans the assessment was made on.
    assessment: the verdict.
    max_pairs: only the pairs with the largest statistic, this many.
    min_depth: a point counts when it lies deeper than this many times the pair's scale.
    region: one region of the assessment: its failed pairs with its reference scans
        (Assessment.region_pairs) instead; None: the pairs behind the verdict.

    Returns
    -------
    (M, 2) world end points, metres.
    """
    result = assessment.result
    if region is not None:
        return pair_endpoints(scans, result, assessment.region_pairs(region)[:max_pairs],
                              min_depth)[0]
    if assessment.settings.strict:
        return inconsistent_endpoints(scans, result, max_pairs, min_depth)
    flagged = assessment.misaligned_scans
    rows = assessment.explained_pairs
    pairs = result.pairs[rows]
    bad = np.isin(assessment.pair_classes, (_CLASS_CODE[MISALIGNED], _CLASS_CODE[UNREGISTERED]))
    keep = bad & (flagged[pairs[:, 0]] | flagged[pairs[:, 1]])
    chosen = rows[keep][np.argsort(-result.statistic[rows[keep]], kind='stable')[:max_pairs]]
    return pair_endpoints(scans, result, chosen, min_depth)[0]
