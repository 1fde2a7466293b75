"""Localization mode, both stages: is the robot where its localizer says, or did the map age?

Stage (1), `_scan_test.py`: every live scan against the map (the paper's test per scan, the
cascaded test over windows of travel). Stage (2), here, for the flagged scans:

- **submaps**: the flagged scans (those of the frozen estimate set aside) grouped into
  stretches (scans within one test window of each other); each stretch covered by submaps of
  consecutive live scans spanning `submap_metres` of travel or `submap_seconds`, each
  starting half a submap after the previous (so that neighbours overlap).
- **registration** of each submap's end points onto the map's occupied cell centres
  (map_surface, register_onto_points: the ICP of mapping mode with gates wide enough for a
  kidnapping), seeded by a coarse search (_search.py) or a neighbour's correction where the
  estimate's own start does not bring the submap home.
- **a mislocalization** where the correction is determined, plausible (within
  `max_translation` at the robot and `max_rotation_deg`), significantly different from zero
  (chi-square with 3 degrees of freedom at `significance`), large enough to matter
  (`min_position_error` at the robot or `min_heading_error_deg`), MENDS the submap (after the
  correction its mean Psi drops, and `mend_fraction` of its failed scans pass, or the submap
  passes the cascaded test, or its mean Psi falls to `mend_ratio` of what it was) and at
  least `min_agreeing` overlapping or adjacent submaps agree on it (the robot placed within
  `agreement_metres`, headings within `agreement_deg`). The correction is the localizer's
  error. Scans covered by such submaps form episodes,
  trimmed of their end scans that the estimate fitted at least as well as the correction.
- **minor**: a correction that mends its submap (and is determined, plausible, significant)
  but moves the robot less than the tolerance: the localizer is a little off, the map is
  not out of date; neither an episode nor a change.
- **a change** everywhere else a scan was flagged: the map is out of date there. Its places:
  end points and map obstacles deeper than `change_depth` scales s_i, grouped within
  `change_cell` (place_labels of mapping mode), split into tiles of `max_change_extent`,
  their centroids.
- **a frozen estimate**: core/verdict/_frozen.py's rule on the live run (consecutive scans at
  one estimated pose whose scans changed `min_frozen_changes` times); no folding by pose.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyParameters, statistics
from map_consistency_ros.core.geometry import ScanSet, se2, true_runs
from map_consistency_ros.core.localization._grid_measure import (GridReference,
                                                                 grid_point_distances)
from map_consistency_ros.core.localization._map_surface import map_surface
from map_consistency_ros.core.localization._scan_test import (ScanTests, WindowTests,
                                                              cascaded_test, live_scales,
                                                              measure_and_judge, travel,
                                                              window_starts)
from map_consistency_ros.core.localization._search import DistanceField, coarse_correction
from map_consistency_ros.core.localization._settings import LocalizationSettings
from map_consistency_ros.core.verdict import (RegistrationSettings, place_labels,
                                              register_onto_points, surface_points)
from map_consistency_ros.core.verdict._frozen import FrozenEstimate, frozen_estimates

# end points of a submap scored by the coarse search at most (a regular subsample)
SEARCH_POINTS = 300

LOCALIZED = 'localized'
MISLOCALIZED = 'mislocalized'
NOTHING_TO_JUDGE = 'nothing to judge'


@dataclass(frozen=True)
class Episode:
    """Consecutive live scans (rows first..last) the localizer placed wrong, and by how much.

    `correction (3,)` the median world transform taking the estimate to where the scans fit
    the map (x, y, theta: p -> R p + t); `position_error` the median distance it moves the
    robot (metres), `heading_error` its median heading change (radians, signed).
    """

    first: int
    last: int
    correction: np.ndarray
    position_error: float
    heading_error: float


@dataclass(frozen=True)
class MapChange:
    """A place where the map is out of date: deep points of live scans first..last."""

    first: int
    last: int
    x: float
    y: float
    points: int


@dataclass(frozen=True)
class Submaps:
    """The registrations of stage (2), row t for submap t (live scans rows[t, 0]:rows[t, 1]).

    `transforms (T, 3)` world corrections; `position_error`, `heading_error` (T,) at the
    robot; boolean (T,) `determined`, `plausible`, `significant`, `large`, `mended`,
    `accepted` (all of them and agreed on).
    """

    rows: np.ndarray
    transforms: np.ndarray
    position_error: np.ndarray
    heading_error: np.ndarray
    determined: np.ndarray
    plausible: np.ndarray
    significant: np.ndarray
    large: np.ndarray
    mended: np.ndarray
    accepted: np.ndarray

    @property
    def minor(self) -> np.ndarray:
        """(T,) corrections that mend their submaps but move the robot less than the
        tolerance: a small error of the localizer, neither a mislocalization nor a change."""
        return (self.determined & self.plausible & self.significant & self.mended
                & ~self.large)

    @classmethod
    def empty(cls) -> Submaps:
        """No submaps.

        Returns
        -------
        Submaps of zero rows.
        """
        flags = np.zeros(0, dtype=bool)
        return cls(rows=np.zeros((0, 2), dtype=np.int64), transforms=np.zeros((0, 3)),
                   position_error=np.zeros(0), heading_error=np.zeros(0), determined=flags,
                   plausible=flags, significant=flags, large=flags, mended=flags,
                   accepted=flags)


@dataclass(frozen=True)
class LocalizationResult:
    """Both stages' findings on a live run, rows of the run's scans."""

    tests: ScanTests
    windows: WindowTests
    submaps: Submaps
    episodes: tuple[Episode, ...]
    changes: tuple[MapChange, ...]
    frozen: tuple[FrozenEstimate, ...]
    mislocalized: np.ndarray  # (N,) bool: scans inside an episode
    minor: np.ndarray  # (N,) bool: flagged scans a correction below the tolerance explains
    errors: np.ndarray = field(repr=False)  # (N, 2) position m / heading rad, NaN elsewhere

    @property
    def nothing_to_judge(self) -> bool:
        """No window of the run had enough judged scans to be flagged."""
        return not bool(self.windows.flaggable.any())

    @property
    def localized(self) -> bool:
        """No mislocalization episode and no frozen estimate."""
        return not self.episodes and not self.frozen

    @property
    def outcome(self) -> str:
        """'localized', 'mislocalized' or 'nothing to judge'."""
        if not self.localized:
            return MISLOCALIZED
        return NOTHING_TO_JUDGE if self.nothing_to_judge else LOCALIZED


@dataclass(frozen=True)
class MapSurface:
    """The map prepared for both stages: the measure's reference and the surface registered on."""

    reference: GridReference
    points: np.ndarray
    normals: np.ndarray
    field: DistanceField

    @classmethod
    def of(cls, reference: GridReference) -> MapSurface:
        """The map's surface for a prepared map.

        Parameters
        ----------
        reference: prepare_reference(grid).

        Returns
        -------
        The MapSurface.
        """
        points, normals = map_surface(reference.grid)
        return cls(reference=reference, points=points, normals=normals,
                   field=DistanceField.of(reference.grid))


def localize(scans: ScanSet, stamps: np.ndarray, surface: MapSurface,
             parameters: ConsistencyParameters | None = None,
             settings: LocalizationSettings | None = None) -> LocalizationResult:
    """Judge a live run against a fixed map: both stages.

    Parameters
    ----------
    scans: the N live scans at the localizer's poses (map frame), in travel order.
    stamps: (N,) their stamps, seconds (a stamp before its predecessor counts as no time
        passing).
    surface: the map (MapSurface.of(prepare_reference(grid))).
    parameters: the paper's test; None for the defaults.
    settings: localization mode's own; None for the defaults.

    Returns
    -------
    The LocalizationResult. Raises ValueError for stamps of another length or not finite.
    """
    parameters = parameters or ConsistencyParameters()
    settings = settings or LocalizationSettings()
    stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if stamps.size != scans.scan_count:
        raise ValueError(f'{stamps.size} stamps for {scans.scan_count} scans')
    if not np.all(np.isfinite(stamps)):
        raise ValueError('stamps must be finite')
    # a stamp going back (loggers' clocks jitter: the Intel log by up to 0.9 s) counts as no
    # time passing: the windows need a non-decreasing clock
    stamps = np.maximum.accumulate(stamps) if stamps.size else stamps
    reference = surface.reference
    scales = live_scales(scans, parameters, reference.grid.resolution, settings)
    tests = measure_and_judge(scans, reference, scales, parameters, settings)
    distance = travel(scans.sensor_poses)
    starts = window_starts(distance, stamps, settings.window_metres, settings.window_seconds)
    windows = cascaded_test(tests, starts, parameters)
    frozen = frozen_estimates(scans, parameters, settings.min_frozen_changes)
    frozen_rows = np.zeros(scans.scan_count, dtype=bool)
    for stretch in frozen:
        frozen_rows[stretch.scans] = True
    candidates = windows.flagged & ~frozen_rows
    stretches = _stretches(np.flatnonzero(candidates), starts)
    rows = _submap_rows(stretches, distance, stamps, settings)
    submaps, after_psi = _register(scans, surface, rows, tests, windows, parameters, settings)
    mislocalized, errors, episodes = _episodes(scans, submaps, tests, after_psi)
    episodes = _joined(scans, surface, tests, episodes, mislocalized, errors, parameters,
                       settings)
    minor = np.zeros(scans.scan_count, dtype=bool)
    for task in np.flatnonzero(submaps.minor):
        minor[slice(*submaps.rows[task])] = True
    unexplained = candidates & ~mislocalized & ~minor
    changes = _changes(scans, reference, tests, _stretches(np.flatnonzero(unexplained), starts),
                       unexplained, settings)
    return LocalizationResult(tests=tests, windows=windows, submaps=submaps,
                              episodes=tuple(episodes), changes=tuple(changes), frozen=frozen,
                              mislocalized=mislocalized, minor=minor & candidates,
                              errors=errors)


def _stretches(rows: np.ndarray, starts: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) of groups of rows, each within the test window of the next."""
    found: list[tuple[int, int]] = []
    for row in rows.tolist():
        if found and starts[row] <= found[-1][1]:
            found[-1] = (found[-1][0], row)
        else:
            found.append((row, row))
    return found


def _submap_rows(stretches: list[tuple[int, int]], distance: np.ndarray, stamps: np.ndarray,
                 settings: LocalizationSettings) -> np.ndarray:
    """(T, 2) scan ranges [q0, q1) of the submaps covering the stretches, half overlapping."""

    def reach(row: int, metres: float, seconds: float) -> int:
        by_travel = int(np.searchsorted(distance, distance[row] + metres, side='right'))
        by_time = int(np.searchsorted(stamps, stamps[row] + seconds, side='right'))
        return max(min(by_travel, by_time), row + 1)

    found = []
    for first, last in stretches:
        # one submap ends with the stretch, as the first starts with it: an episode's ends
        # are not blurred by scans the localizer placed well
        back_travel = int(np.searchsorted(distance, distance[last] - settings.submap_metres,
                                          side='left'))
        back_time = int(np.searchsorted(stamps, stamps[last] - settings.submap_seconds,
                                        side='left'))
        found.append((max(back_travel, back_time, first), last + 1))
        row = first
        while True:
            end = reach(row, settings.submap_metres, settings.submap_seconds)
            found.append((row, end))
            if end > last:
                break
            row = max(min(reach(row, 0.5 * settings.submap_metres,
                                0.5 * settings.submap_seconds), end - 1), row + 1)
    return np.unique(np.asarray(found, dtype=np.int64).reshape(-1, 2), axis=0)


def _register(scans: ScanSet, surface: MapSurface, rows: np.ndarray, tests: ScanTests,
              windows: WindowTests, parameters: ConsistencyParameters,
              settings: LocalizationSettings) -> tuple[Submaps, np.ndarray]:
    """Register every submap onto the map and decide which corrections are mislocalizations;
    also each scan's least Psi after an accepted correction (NaN elsewhere).

    Each submap is registered from the estimate; one with failed scans that does not give a
    mislocalization is registered again from the best correction of a coarse search
    (_search.py), then from the correction of the last submap before it that gives one
    (forwards, then backwards from the one after it): a localizer's error persists, and a
    turn about a far place moves the robot further than the gates reach from zero (10
    degrees are 1.7 m at 10 m)."""
    after_psi = np.full(scans.scan_count, np.nan)
    count = rows.shape[0]
    if count == 0:
        return Submaps.empty(), after_psi
    registration = RegistrationSettings(gates=settings.gates, trim=settings.trim)
    surfaces = surface_points(scans.endpoints, scans.valid)
    found = register_onto_points(surface.points, surface.normals, surfaces, rows, registration)
    fields = {name: np.zeros(count, dtype=bool) for name in
              ('determined', 'plausible', 'significant', 'large', 'mended')}
    transforms, position, psi_after = found.world_transforms(), np.zeros(count), {}
    for task in range(count):
        _judge_submap(task, rows, transforms[task], found.corrections[task],
                      found.covariances[task], bool(found.determined[task]), transforms[task],
                      scans, surface, tests, parameters, settings, fields, position,
                      psi_after)
    good = lambda task: all(fields[name][task] for name in fields)  # noqa: E731

    def again(task: int, seed: np.ndarray) -> bool:
        """Register submap `task` from `seed`; keep the result when it is a mislocalization."""
        nonlocal fields, position, psi_after
        member = np.arange(*rows[task])
        moved = scans.take(member).with_poses(se2.compose(seed, scans.sensor_poses[member]))
        found = register_onto_points(surface.points, surface.normals,
                                     surface_points(moved.endpoints, moved.valid),
                                     [[0, member.size]], registration)
        step = found.world_transforms()[0]
        total = se2.compose(step, seed)
        trial = {name: values.copy() for name, values in fields.items()}
        trial_position, trial_psi = position.copy(), dict(psi_after)
        _judge_submap(task, rows, total, _about(total, found.centroids[0]),
                      found.covariances[0], bool(found.determined[0]), step, scans, surface,
                      tests, parameters, settings, trial, trial_position, trial_psi)
        if not all(trial[name][task] for name in trial):
            return False
        fields, position, psi_after = trial, trial_position, trial_psi
        transforms[task] = total
        return True

    # from the coarse search where the estimate's own start did not bring the submap home
    for task in range(count):
        if good(task) or _minor(fields, task) or not tests.failed[
                rows[task, 0]:rows[task, 1]].any():
            continue
        member = np.arange(*rows[task])
        points = scans.endpoints[member][scans.valid[member]]
        points = points[::max(1, points.shape[0] // SEARCH_POINTS)]
        centre = np.median(scans.sensor_poses[member, :2], axis=0)
        seed, cost, zero_cost = coarse_correction(
            surface.field, points, centre, settings.max_translation,
            math.radians(settings.max_rotation_deg), settings.search_step,
            math.radians(settings.search_step_deg))
        if cost < zero_cost:
            again(task, seed)
    # from the correction of a neighbour: the localizer's error persists
    for order in (range(count), range(count - 1, -1, -1)):
        seed = None
        for task in order:
            if good(task):
                seed = transforms[task]
            elif seed is not None and again(task, seed):
                seed = transforms[task]
    candidates = np.logical_and.reduce([fields[name] for name in fields])
    accepted = _agreeing(candidates, rows, transforms, scans.sensor_poses, settings)
    for task in np.flatnonzero(accepted):
        member = np.arange(*rows[task])
        after_psi[member] = np.fmin(after_psi[member], psi_after[task])
    submaps = Submaps(rows=rows, transforms=transforms, position_error=position,
                      heading_error=se2.wrap_angle(transforms[:, 2]), accepted=accepted,
                      **fields)
    return submaps, after_psi


def _minor(fields: dict, task: int) -> bool:
    """A correction that mends its submap but is too small to matter: the localizer is off
    by less than the tolerance, and the map is not out of date there."""
    return bool(fields['determined'][task] and fields['plausible'][task]
                and fields['significant'][task] and fields['mended'][task]
                and not fields['large'][task])


def _about(transform: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """A world transform as a correction about `centre` (Registrations' parametrisation)."""
    cos, sin = math.cos(transform[2]), math.sin(transform[2])
    cx, cy = centre
    return np.array([transform[0] - cx + (cos * cx - sin * cy),
                     transform[1] - cy + (sin * cx + cos * cy), transform[2]])


def _judge_submap(task: int, rows: np.ndarray, transform: np.ndarray, correction: np.ndarray,
                  covariance: np.ndarray, determined: bool, step: np.ndarray, scans: ScanSet,
                  surface: MapSurface, tests: ScanTests, parameters: ConsistencyParameters,
                  settings: LocalizationSettings, fields: dict, position: np.ndarray,
                  psi_after: dict) -> None:
    """The criteria of one submap's correction `transform` (the registration's own `step`
    for plausibility), written into fields[name][task], position[task], psi_after[task]."""
    member = np.arange(*rows[task])
    poses = scans.sensor_poses[member]
    moved = se2.compose(transform, poses)
    position[task] = float(np.median(np.hypot(*(moved[:, :2] - poses[:, :2]).T)))
    stepped = se2.compose(step, poses)
    step_position = float(np.median(np.hypot(*(stepped[:, :2] - poses[:, :2]).T)))
    heading = abs(math.degrees(float(se2.wrap_angle(transform[2]))))
    fields['determined'][task] = determined
    fields['plausible'][task] = (step_position <= settings.max_translation
                                 and heading <= settings.max_rotation_deg)
    mahalanobis = statistics.mahalanobis_squared(correction[None], covariance[None])[0]
    fields['significant'][task] = determined and bool(
        np.nan_to_num(mahalanobis, nan=0.0)
        > statistics.chi_square_3_quantile(settings.significance))
    fields['large'][task] = (position[task] >= settings.min_position_error
                             or heading >= settings.min_heading_error_deg)
    fields['mended'][task] = False
    if not (determined and fields['plausible'][task] and fields['significant'][task]):
        return
    retested = measure_and_judge(scans.take(member).with_poses(moved), surface.reference,
                                 tests.scales[member], parameters, settings)
    fields['mended'][task] = _mends(tests, member, retested.failed, retested.judged,
                                    retested.psi, parameters, settings)
    psi_after[task] = retested.psi


def _mends(tests: ScanTests, member: np.ndarray, failed_after: np.ndarray,
           judged_after: np.ndarray, psi_after: np.ndarray, parameters: ConsistencyParameters,
           settings: LocalizationSettings) -> bool:
    """Whether a correction mends its submap: its scans fit the map better on average, and
    its failed scans pass (mend_fraction of them, or the submap passes the cascaded test) or
    its mean Psi falls to mend_ratio of what it was (what remains is the registration's
    accuracy against the map's cells, which the test at a scale of half a cell still sees)."""
    failed_before = tests.failed[member]
    if not failed_before.any():
        return False
    both = tests.judged[member] & judged_after
    if not both.any():
        return False
    before, after = np.mean(tests.psi[member][both]), np.mean(psi_after[both])
    if after >= before:
        return False
    if before > 0.0 and after <= settings.mend_ratio * before:
        return True
    critical = statistics.binomial_critical_count(int(judged_after.sum()),
                                                  parameters.failure_probability,
                                                  parameters.binomial_alpha)
    passes = int(failed_after.sum()) <= int(critical)
    repaired = np.count_nonzero(failed_before & ~failed_after)
    return passes or repaired >= settings.mend_fraction * np.count_nonzero(failed_before)


def _agreeing(candidates: np.ndarray, rows: np.ndarray, transforms: np.ndarray,
              poses: np.ndarray, settings: LocalizationSettings) -> np.ndarray:
    """Candidates with at least min_agreeing overlapping or adjacent candidates (themselves
    included) whose corrections place their robots alike."""
    accepted = np.zeros(candidates.size, dtype=bool)
    chosen = np.flatnonzero(candidates)
    for task in chosen:
        agree = 0
        for other in chosen:
            if rows[other, 0] > rows[task, 1] or rows[task, 0] > rows[other, 1]:
                continue
            positions = np.concatenate([poses[slice(*rows[task])], poses[slice(*rows[other])]])
            a, b = se2.compose(transforms[task], positions), se2.compose(transforms[other],
                                                                       positions)
            apart = float(np.max(np.hypot(*(a[:, :2] - b[:, :2]).T)))
            turn = abs(math.degrees(float(se2.wrap_angle(transforms[task, 2]
                                                         - transforms[other, 2]))))
            agree += apart <= settings.agreement_metres and turn <= settings.agreement_deg
        accepted[task] = agree >= settings.min_agreeing
    return accepted


def _episodes(scans: ScanSet, submaps: Submaps, tests: ScanTests,
              after_psi: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[Episode]]:
    """Scans covered by accepted submaps, joined into episodes and trimmed of end scans the
    estimate fitted at least as well; per-scan errors (the mean of the covering corrections)."""
    count = scans.scan_count
    errors = np.full((count, 2), np.nan)
    covered = np.zeros(count, dtype=np.int64)
    summed = np.zeros((count, 3))
    for task in np.flatnonzero(submaps.accepted):
        q0, q1 = submaps.rows[task]
        covered[q0:q1] += 1
        transform = submaps.transforms[task].copy()
        transform[2] = se2.wrap_angle(transform[2])
        summed[q0:q1] += transform
    inside = covered > 0
    mislocalized = np.zeros(count, dtype=bool)
    episodes = []
    for first, end in true_runs(inside).tolist():
        # better at the estimate: judged, not failed, and no better after the correction
        fine = (tests.judged[first:end] & ~tests.failed[first:end]
                & ~(after_psi[first:end] < tests.psi[first:end]))
        keep = np.flatnonzero(~fine)
        if keep.size == 0:
            continue
        last = first + int(keep[-1])
        first = first + int(keep[0])
        rows = np.arange(first, last + 1)
        transforms = summed[rows] / covered[rows, None]
        poses = scans.sensor_poses[rows]
        moved = np.stack([se2.compose(transform, pose) for transform, pose
                          in zip(transforms, poses)])
        errors[rows, 0] = np.hypot(*(moved[:, :2] - poses[:, :2]).T)
        errors[rows, 1] = transforms[:, 2]
        mislocalized[rows] = True
        episodes.append(Episode(first=first, last=last,
                                correction=np.median(transforms, axis=0),
                                position_error=float(np.median(errors[rows, 0])),
                                heading_error=float(np.median(errors[rows, 1]))))
    return mislocalized, errors, episodes


def _joined(scans: ScanSet, surface: MapSurface, tests: ScanTests, episodes: list[Episode],
            mislocalized: np.ndarray, errors: np.ndarray, parameters: ConsistencyParameters,
            settings: LocalizationSettings) -> list[Episode]:
    """Episodes joined across the gaps between them where their corrections agree and no
    scan of the gap refutes the correction (passes at the estimate, fails corrected); the
    gap's scans then count as mislocalized too (mislocalized, errors updated in place)."""
    joined: list[Episode] = []
    for episode in episodes:
        if joined:
            previous = joined[-1]
            gap = np.arange(previous.last + 1, episode.first)
            positions = scans.sensor_poses[previous.last:episode.first + 1]
            a = se2.compose(previous.correction, positions)
            b = se2.compose(episode.correction, positions)
            apart = float(np.max(np.hypot(*(a[:, :2] - b[:, :2]).T)))
            turn = abs(math.degrees(float(se2.wrap_angle(previous.correction[2]
                                                         - episode.correction[2]))))
            agree = apart <= settings.agreement_metres and turn <= settings.agreement_deg
            if agree and gap.size:
                moved = se2.compose(previous.correction, scans.sensor_poses[gap])
                after = measure_and_judge(scans.take(gap).with_poses(moved), surface.reference,
                                          tests.scales[gap], parameters, settings)
                refuted = tests.judged[gap] & ~tests.failed[gap] & after.failed
                agree = not refuted.any()
            if agree:
                if gap.size:
                    moved = se2.compose(previous.correction, scans.sensor_poses[gap])
                    errors[gap, 0] = np.hypot(*(moved[:, :2] - scans.sensor_poses[gap, :2]).T)
                    errors[gap, 1] = se2.wrap_angle(previous.correction[2])
                    mislocalized[gap] = True
                rows = np.arange(previous.first, episode.last + 1)
                joined[-1] = Episode(
                    first=previous.first, last=episode.last,
                    correction=np.median(np.stack([previous.correction, episode.correction]),
                                         axis=0),
                    position_error=float(np.median(errors[rows, 0])),
                    heading_error=float(np.median(errors[rows, 1])))
                continue
        joined.append(episode)
    return joined


def _changes(scans: ScanSet, reference: GridReference, tests: ScanTests,
             stretches: list[tuple[int, int]], flagged: np.ndarray,
             settings: LocalizationSettings) -> list[MapChange]:
    """The places of the flagged scans no correction explained: deep points grouped."""
    found = []
    for first, last in stretches:
        points, owners = [], []
        for row in range(first, last + 1):
            if not flagged[row]:
                continue
            depth = settings.change_depth * tests.scales[row]
            distances = grid_point_distances(scans, reference, row)
            deep = distances.endpoint_depth > depth
            obstacles = reference.obstacles[distances.obstacle_rows[
                distances.obstacle_depth > depth]]
            here = np.concatenate([scans.endpoints[row][deep], obstacles])
            points.append(here)
            owners.append(np.full(here.shape[0], row))
        points = np.concatenate(points) if points else np.zeros((0, 2))
        if points.shape[0] < settings.min_change_points:
            continue
        owners = np.concatenate(owners)
        labels = place_labels(points, settings.change_cell)
        # a place spans at most max_change_extent: a long chain of deep points (a corridor
        # seen out of date along its length) is split into tiles, each at its own centroid
        tiles = np.floor(points / settings.max_change_extent).astype(np.int64)
        _, labels = np.unique(np.column_stack([labels, tiles]), axis=0, return_inverse=True)
        labels = labels.reshape(-1)
        for label in np.unique(labels):
            mine = labels == label
            if np.count_nonzero(mine) < settings.min_change_points:
                continue
            centre = points[mine].mean(axis=0)
            found.append(MapChange(first=int(owners[mine].min()), last=int(owners[mine].max()),
                                   x=float(centre[0]), y=float(centre[1]),
                                   points=int(np.count_nonzero(mine))))
    return found
