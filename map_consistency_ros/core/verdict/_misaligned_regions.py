"""Misaligned regions (explanation.py): stretches of scans that fail through their pairs and
temporal adjacency, their consensus correction, the regions hidden among changes, the
whole-region registration that sizes a region beyond local registration, and regions_alike."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult, statistics
from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.verdict._assessment import (ExplanationSettings, MISALIGNED,
                                                          Misalignment, _CLASS_CODE)
from map_consistency_ros.core.verdict._changed_places import _spans_beyond_changes
from map_consistency_ros.core.verdict._pair_classes import PointMoments, _failing_before_after
from map_consistency_ros.core.verdict._registration import (RegistrationSettings, register_submaps,
                                                            surface_points)
from map_consistency_ros.core.verdict._union_find import _components


def regions_alike(regions: tuple[Misalignment, ...], tolerance: float) -> list[list[int]]:
    """Groups of regions that move alike: their corrections place each region's centroid
    within `tolerance` of each other. Regions are counted apart where their scans are not
    joined by failing pairs or by consecutive viewpoints, so a stretch displaced once makes a
    region at every place where it meets the scans it revisits; regions that move alike are
    likely such one displacement.

    Parameters
    ----------
    regions: misaligned regions, in the order the outputs number them.
    tolerance: metres (the map's misalignment_tolerance).

    Returns
    -------
    The groups of two or more, each the sorted indices into `regions`, by their first
    index; regions without a correction or a centroid join none.
    """
    known = [index for index, region in enumerate(regions)
             if np.all(np.isfinite(region.correction)) and np.all(np.isfinite(region.centroid))]
    links = []
    for position, a in enumerate(known):
        for b in known[position + 1:]:
            first, second = regions[a], regions[b]
            if all(np.hypot(*(se2.compose(one.correction, [*at.centroid, 0.0])[:2]
                              - se2.compose(other.correction, [*at.centroid, 0.0])[:2]))
                   <= tolerance for one, other, at in ((first, second, first),
                                                       (first, second, second))):
                links.append((a, b))
    if not links:
        return []
    labels = _components(len(regions), np.array(links))
    groups = {}
    for index in sorted({member for link in links for member in link}):
        groups.setdefault(int(labels[index]), []).append(index)
    return sorted(groups.values())


def agreeing_registrations(moments: PointMoments, rows: np.ndarray, pairs: np.ndarray,
                           transforms: np.ndarray, task_of_pair: np.ndarray,
                           correction: np.ndarray, settings: ExplanationSettings) -> int:
    """Independent registrations (tasks) whose correction places the later scan's points within
    the tolerance (RMS) of where the region's correction places them: a loop-closure error
    moves a stretch rigidly, so its submaps agree.

    Parameters
    ----------
    moments: the point moments of every scan (PointMoments.of).
    rows: the region's rows of `pairs`, `transforms` and `task_of_pair`.
    pairs: (E, 2) explained pairs (i, j), j the later scan.
    transforms: (E, 3) the world transform of each pair's registration, moving j.
    task_of_pair: (E,) the registration task of each pair.
    correction: (3,) the region's world transform.
    settings: the explanation's settings (misalignment_tolerance).

    Returns
    -------
    The number of distinct tasks that agree.
    """
    later = pairs[rows, 1]
    # |T_k p - C p| = |C^-1 T_k p - p|: C^-1 T_k moves the points as far from C's placement
    relative = se2.relative(correction, transforms[rows])
    agree = moments.displacement(relative, later) <= settings.misalignment_tolerance
    return int(np.unique(task_of_pair[rows[agree]]).size)


def _consensus(points: PointMoments, transforms: np.ndarray) -> np.ndarray:
    """The world transform among `transforms` (E, 3) that places the `points` (one pooled
    set) nearest to where the others place them: the median displacement to the others, the
    smallest. Not the median of x, y and theta taken apart: a world transform's translation
    is R-dependent (t = c - R c about the centre c of the turn), so on a map tens of metres
    from its origin a median theta and a median (x, y) from different registrations are no
    rigid motion of the region, and place its points up to metres away."""
    unique = np.unique(transforms, axis=0)
    if len(unique) == 1:
        return unique[0]
    if len(unique) > _CONSENSUS_CANDIDATES:  # bounded cost: a spread subset of candidates
        unique = unique[np.linspace(0, len(unique) - 1, _CONSENSUS_CANDIDATES).astype(int)]
    count = len(unique)
    first, second = np.repeat(np.arange(count), count), np.tile(np.arange(count), count)
    relative = se2.relative(unique[first], unique[second])
    apart = points.displacement(relative, np.zeros(relative.shape[0], dtype=np.int64))
    return unique[int(np.argmin(np.median(apart.reshape(count, count), axis=1)))]


_CONSENSUS_CANDIDATES = 200


def longest_run(scans: np.ndarray, gap: int) -> int:
    """The longest run of scans joined by short steps.

    Parameters
    ----------
    scans: sorted scan indices.
    gap: the largest step between neighbours of one run.

    Returns
    -------
    The most scans in one run; 0 for no scans.
    """
    if scans.size == 0:
        return 0
    return int(np.bincount(_run_labels(scans, gap)).max())


def _run_labels(scans: np.ndarray, gap: int) -> np.ndarray:
    """(S,) the run of each of the sorted `scans` (S >= 1): 0, 1, ... in order; a step
    longer than `gap` starts the next run."""
    return np.concatenate([[0], np.cumsum(np.diff(scans) > gap)])


def longest_travel(scans: np.ndarray, gap: int, positions: np.ndarray, spacing: float) -> int:
    """The longest run of scans joined by short steps, counted in viewpoints of travel.

    A gross error displaces a stretch of the path: its extent is the travel along the run
    (its scans' positions in index order), one viewpoint per `spacing` plus the run's first,
    whatever the sampling. Turning on the spot adds none: one place, however many headings.

    Parameters
    ----------
    scans: sorted scan indices.
    gap: the largest step between index neighbours of one run.
    positions: (N, 2) the positions of all scans, metres.
    spacing: metres of travel per viewpoint (the test's viewpoint_spacing); 0 where every scan
        is a viewpoint: the run's scans are counted then (longest_run).

    Returns
    -------
    1 + floor(travel / spacing) of the run that travels furthest; 0 for no scans.
    """
    if scans.size == 0 or spacing <= 0.0:
        return longest_run(scans, gap)
    runs = _run_labels(scans, gap)
    steps = np.hypot(*np.diff(positions[scans], axis=0).T)
    steps[np.diff(runs) > 0] = 0.0  # a break between runs is no travel
    travel = np.bincount(runs[1:], weights=steps, minlength=runs[-1] + 1)
    # a hair of slack: a run of exactly k spacings counts k + 1 viewpoints
    return 1 + int(np.floor(travel.max() / spacing + 1e-9))


_RESOLVED_SAMPLE = 2000  # overlaps re-measured per region: enough for a share, bounded cost


def _resolved_fraction(scans: ScanSet, result: ConsistencyResult, moved: np.ndarray,
                       reference: np.ndarray, correction: np.ndarray) -> float:
    """The share of the failing tested pairs between `moved` and `reference` scans that pass
    with `moved` placed by the world transform `correction`, net of the passing pairs it breaks
    (0 when none fails): a region's correction must mend what its registrations mend one by
    one."""
    in_moved = np.zeros(result.scan_count, dtype=bool)
    in_moved[moved] = True
    in_reference = np.zeros(result.scan_count, dtype=bool)
    in_reference[reference] = True
    first, second = result.pairs[:, 0], result.pairs[:, 1]
    rows = np.flatnonzero(result.tested & ((in_moved[first] & in_reference[second])
                                           | (in_reference[first] & in_moved[second])))
    rows = rows[::max(1, -(-rows.size // _RESOLVED_SAMPLE))]
    (failing,), (after,) = _failing_before_after(
        scans, result, rows, in_moved[result.pairs[rows, 0]],
        np.repeat(correction[None], rows.size, axis=0), np.zeros(rows.size, dtype=np.int64), 1)
    return 0.0 if failing == 0 else 1.0 - after / failing


def _mostly_consecutive(pairs: np.ndarray, settings: ExplanationSettings) -> bool:
    """Whether most `pairs` (P, 2) join scans within a submap's reach of each other in time:
    the world does not change between consecutive keyframes (people aside, who make small
    places), so such failures are a break of the chain itself, a block displaced against its
    own neighbours, not a revisit of a changed room."""
    reach = 2 * settings.margin + settings.block
    return bool(np.count_nonzero(pairs[:, 1] - pairs[:, 0] <= reach) * 2 > len(pairs))


def _stretches(scan_count: int, pairs: np.ndarray, chosen: np.ndarray, chain: np.ndarray,
               settings: ExplanationSettings
               ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The candidate regions of the `chosen` pairs (P,) bool over `pairs` (P, 2): groups
    joined through their pairs and through the sorted scans `chain` at most a block apart,
    kept when they are a stretch of at least `min_region_scans` keyframes in a row on both
    sides (not scans out of place here and there, nor a revisit seen from one scan).

    Returns
    -------
    [(rows of `pairs` in the group, its moved (later) scans, its reference scans)].
    """
    if not chosen.any():
        return []
    adjacent = np.stack([chain[:-1], chain[1:]], axis=1)[np.diff(chain) <= settings.block]
    labels = _components(scan_count, np.concatenate([pairs[chosen], adjacent]))
    groups = []
    for label in np.unique(labels[pairs[chosen, 0]]):
        rows = np.flatnonzero(chosen & (labels[pairs[:, 0]] == label))
        moved = np.unique(pairs[rows, 1])
        reference = np.setdiff1d(np.unique(pairs[rows, 0]), moved)
        if min(longest_run(moved, settings.block),
               longest_run(reference, settings.block)) >= settings.min_region_scans:
            groups.append((rows, moved, reference))
    return groups


def _median_std(covariances: np.ndarray) -> np.ndarray:
    """(3,) a region's 1-sigma: the square roots of the median variances of its
    registrations' (E, 3, 3) covariances."""
    return np.sqrt(np.median(np.diagonal(covariances, axis1=1, axis2=2), axis=0))


def _regions(scans: ScanSet, result: ConsistencyResult, explained: np.ndarray,
             moments: PointMoments, bad: np.ndarray, codes: np.ndarray,
             transforms: np.ndarray, covariances: np.ndarray, task_of_pair: np.ndarray,
             flagged: np.ndarray, settings: ExplanationSettings,
             registration: RegistrationSettings | None) -> tuple[Misalignment, ...]:
    """Misaligned regions from the explained pairs (rows `explained` of `result`)."""
    pairs = result.pairs[explained]
    on_flagged = bad & (flagged[pairs[:, 0]] | flagged[pairs[:, 1]])
    regions = []
    for rows, moved, reference in _stretches(scans.scan_count, pairs, on_flagged,
                                             np.flatnonzero(flagged), settings):
        registered_rows = rows[codes[rows] == _CLASS_CODE[MISALIGNED]]
        registered = False
        whole = None  # the whole region registered onto its reference, once it is needed
        if registered_rows.size * 2 >= rows.size:
            correction = _consensus(moments.pooled(moved), transforms[registered_rows])
            # A correction that its registrations do not confirm, or that does not mend the
            # region, is no measurement of it; the region is then judged as beyond
            # registration (below), not dropped: a stretch displaced further than the
            # registrations reach (a turn of 5 degrees moves points 20 m away by 1.7 m) makes
            # them snap onto the wrong walls, and agree on it.
            registered = (
                agreeing_registrations(moments, registered_rows, pairs, transforms,
                                       task_of_pair, correction, settings)
                >= settings.min_registrations
                and _resolved_fraction(scans, result, moved, reference, correction)
                >= settings.min_resolved_fraction)
            if registered:
                # Submaps that share a sliver of surface with the reference (an object one
                # visit saw, a doorway) can agree on a correction that the region as a whole
                # does not bear: it must rest on enough shared surface, or it measures nothing.
                whole = _register_region(scans, moved, reference, registration)
                registered = whole.support >= settings.min_region_support
        if registered:
            spread = _median_std(covariances[registered_rows])
            displacement = float(moments.pooled(moved).displacement(correction[None])[0])
        else:
            # beyond registration, no correction corroborates it: a displaced stretch of the
            # path, at least a block of travel (a robot turning on the spot is one place),
            # spread wider than any change, that several registrations fail on
            if (np.unique(task_of_pair[rows]).size < settings.min_registrations
                    or longest_travel(moved, settings.block, scans.sensor_poses[:, :2],
                                      result.parameters.viewpoint_spacing) < settings.block
                    or not (_mostly_consecutive(pairs[rows], settings)
                            or _spans_beyond_changes(scans, result, explained[rows],
                                                     settings))):
                continue
            if whole is None:
                whole = _register_region(scans, moved, reference, registration)
            measured = _region_size(scans, result, moments, moved, reference, whole, settings)
            if measured is None:
                correction, spread, displacement = np.full(3, np.nan), np.full(3, np.nan), math.nan
            else:
                correction, spread, displacement = measured
                registered = True
        regions.append(Misalignment(scans=moved, reference_scans=reference,
                                    correction=correction, correction_std=spread,
                                    displacement=displacement, pairs=int(rows.size),
                                    registered=bool(registered),
                                    centroid=moments.pooled(moved).mean[0]))
    return tuple(regions)


def _regions_among_changes(scans: ScanSet, moments: PointMoments, pairs: np.ndarray,
                           among_changes: np.ndarray, transforms: np.ndarray,
                           covariances: np.ndarray, task_of_pair: np.ndarray,
                           taken: np.ndarray, settings: ExplanationSettings,
                           registration: RegistrationSettings | None
                           ) -> list[tuple[np.ndarray, Misalignment]]:
    """Misaligned regions hidden among changes: a revisit of a cluttered place whose failed
    pairs stay failing under any rigid correction (the furniture moved), while its submaps'
    registrations, made on the surfaces that did not move, agree on one correction beyond the
    tolerance.

    The pairwise test cannot confirm such a correction (its pairs fail either way), so the
    registrations are the only evidence, and they must stand on their own: a stretch on both
    sides (`min_region_scans`), at least `min_registrations` independent registrations placing
    the region's points within the tolerance of its correction, the region registered as one
    onto its reference scans (on at least `min_region_support` of shared surface) placing them
    there too, and a displacement beyond the tolerance by more than the registrations'
    disagreement allows at `significance` (one-sided normal test, the disagreement the RMS
    displacement between each registration's placement and the region's, over n - 1 for n
    placements). A revisit a few centimetres beyond the tolerance, on which registrations on
    changed surfaces disagree by as much, is not called misaligned on their word alone.

    Parameters
    ----------
    pairs: (E, 2) the explained pairs; `among_changes` (E,) those classed as change whose
        registration is a rigid correction beyond the tolerance (_classify's `rigid`),
        `transforms`, `covariances`, `task_of_pair` per pair as in _regions.
    taken: (N,) scans already in a region: a pair whose later scan is there is not reused.

    Returns
    -------
    [(rows of `pairs` behind the region, the region)] for each region found.
    """
    candidates = among_changes & ~taken[pairs[:, 1]]
    found = []
    for rows, moved, reference in _stretches(scans.scan_count, pairs, candidates,
                                             np.unique(pairs[candidates, 1]), settings):
        points = moments.pooled(moved)
        correction = _consensus(points, transforms[rows])
        if (agreeing_registrations(moments, rows, pairs, transforms, task_of_pair, correction,
                                   settings) < settings.min_registrations):
            continue
        whole = _register_region(scans, moved, reference, registration)
        placements = np.concatenate([np.unique(transforms[rows], axis=0),
                                     whole.correction[None]])
        apart = points.displacement(se2.relative(correction, placements),
                                    np.zeros(len(placements), dtype=np.int64))
        if whole.support < settings.min_region_support or apart[-1] > \
                settings.misalignment_tolerance:
            continue
        spread = math.sqrt(float(np.sum(apart ** 2)) / (len(placements) - 1))
        displacement = float(points.displacement(correction[None])[0])
        if (displacement - settings.misalignment_tolerance
                <= statistics.normal_quantile(settings.significance) * spread):
            continue
        found.append((rows, Misalignment(scans=moved, reference_scans=reference,
                                         correction=correction,
                                         correction_std=_median_std(covariances[rows]),
                                         displacement=displacement, pairs=int(rows.size),
                                         registered=True, centroid=points.mean[0])))
    return found


# Coarse association gates (metres) before the local registration's own: a region beyond
# local registration is displaced further than its submaps' gates reach (a turn of 5 degrees
# moves points 20 m from its centre by 1.7 m), but registered as one, hundreds of scans onto
# hundreds, its surfaces are many and spread enough to converge from gates this wide.
_REGION_GATES = (3.0, 2.0, 1.0)


@dataclass(frozen=True)
class _WholeRegion:
    """A region's moved scans registered as one submap onto all its reference scans."""

    correction: np.ndarray  # (3,) world transform of the moved scans
    covariance: np.ndarray  # (3, 3); inf where undetermined
    support: float  # metres of moved surface matched at the solution; 0 where undetermined


def _register_region(scans: ScanSet, moved: np.ndarray, reference: np.ndarray,
                     registration: RegistrationSettings | None) -> _WholeRegion:
    """Register all of a region's moved scans, as one submap, onto all its reference scans.

    The association gates start wider than local registration's (_REGION_GATES), so that a
    region displaced beyond its submaps' reach converges too. Its support is the surface the
    two sides share at the solution: the matched query end points, which are thinned to one
    per `query_spacing`, times that spacing, whatever the scans' density.
    """
    registration = registration or RegistrationSettings()
    gates = tuple(gate for gate in _REGION_GATES if gate > registration.gates[0])
    wide = replace(registration, gates=gates + tuple(registration.gates))
    order = np.concatenate([reference, moved])
    task = np.array([[0, reference.size, reference.size, order.size]], dtype=np.int64)
    found = register_submaps(surface_points(scans.endpoints[order], scans.valid[order]), task,
                             wide)
    determined = bool(found.determined[0])
    return _WholeRegion(correction=found.world_transforms()[0],
                        covariance=found.covariances[0],
                        support=(float(found.matched[0]) * registration.query_spacing
                                 if determined else 0.0))


def _region_size(scans: ScanSet, result: ConsistencyResult, moments: PointMoments,
                 moved: np.ndarray, reference: np.ndarray, whole: _WholeRegion,
                 settings: ExplanationSettings) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The size of a region beyond local registration, from its whole-region registration.

    Only a size: the region fails the map whatever this finds. A correction on less than
    `min_region_support` of shared surface, that does not mend `min_resolved_fraction` of the
    region's failing overlaps, or that is within the tolerance (local registrations would then
    have found it), measures nothing and gives None.

    Returns
    -------
    (world transform (3,), its 1-sigma (3,), RMS displacement of the moved end points, metres)
    or None.
    """
    if not whole.support or whole.support < settings.min_region_support:
        return None
    displacement = float(moments.pooled(moved).displacement(whole.correction[None])[0])
    if (not np.isfinite(displacement) or displacement <= settings.misalignment_tolerance
            or _resolved_fraction(scans, result, moved, reference, whole.correction)
            < settings.min_resolved_fraction):
        return None
    return whole.correction, np.sqrt(np.diagonal(whole.covariance)), displacement


def _region_scans(misalignments: tuple[Misalignment, ...], scan_count: int) -> np.ndarray:
    flagged = np.zeros(scan_count, dtype=bool)
    for region in misalignments:
        flagged[region.scans] = True
        flagged[region.reference_scans] = True
    return flagged
