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
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property

import numba
import numpy as np

from map_consistency_ros.core.consistency import (ConsistencyParameters, ConsistencyResult,
                                                  Progress, check_consistency,
                                                  inconsistent_endpoints, pair_endpoints,
                                                  robust_statistic, statistics)
from map_consistency_ros.core.geometry import SCAN_ARRAYS, ScanSet, pair_measures, se2, spans
from map_consistency_ros.core.parameters import Choice, Settings, parameter
from map_consistency_ros.core.verdict._evidence import Evidence, evidence
from map_consistency_ros.core.verdict._frozen import FrozenEstimate, frozen_estimates
from map_consistency_ros.core.verdict._registration import (RegistrationSettings, Registrations,
                                                            register_submaps, surface_points)

# The outcomes of a verdict: a map without enough tested pairs is never consistent.
CONSISTENT, INCONSISTENT, NOTHING_TO_JUDGE = 'consistent', 'inconsistent', 'nothing to judge'


class PairClass(Choice):
    """What the second stage makes of a failed pair (Assessment.pair_classes holds the
    index of its class in this order)."""

    MISALIGNED = 'misaligned'  # a significant correction beyond the tolerance mends it
    MINOR = 'minor'  # a correction mends it, insignificant or within the tolerance
    CHANGE = 'change'  # no correction mends it: the world changed between the visits
    UNREGISTERED = 'unregistered'  # its correction is larger than registration trusts


MISALIGNED, MINOR, CHANGE, UNREGISTERED = PairClass
PAIR_CLASSES = tuple(PairClass)
_CLASS_CODE = {name: code for code, name in enumerate(PAIR_CLASSES)}


@dataclass(frozen=True)
class ExplanationSettings(Settings):
    """How failed pairs are explained and what the map may bear (defaults: docs/verdict.md)."""

    misalignment_tolerance: float = parameter(
        0.1, 'misalignments moving end points further (root mean square) make the map '
        'inconsistent', 'm', (0.0, 10.0))
    strict: bool = parameter(
        False, "the paper's verdict instead: every scan failing its cascaded test fails the map")
    # the second stage runs on the viewpoints judged (scans from one place folded into one):
    # its counts are of viewpoints, not of laser records
    block: int = parameter(5, 'consecutive viewpoints registered as one rigid submap',
                           'viewpoints', (1, 1000))
    margin: int = parameter(3, 'viewpoints added on each side of a block to its submap',
                            'viewpoints', (0, 1000))
    max_translation: float = parameter(0.5, 'largest correction trusted as a local misalignment',
                                       'm', (0.01, 100.0))
    max_rotation_deg: float = parameter(10.0, 'largest rotation trusted as a local misalignment',
                                        'deg', (0.1, 180.0))
    significance: float = parameter(
        0.001, 'level of the chi-square test that a correction differs from zero, and of the '
        'test that a misalignment among changes exceeds the tolerance', '', (1e-12, 0.5))
    min_registrations: int = parameter(
        3, 'independent submap registrations that must agree on a misalignment', '', (1, 1000))
    min_region_scans: int = parameter(
        3, 'consecutive viewpoints a misaligned region must hold on each side (a stretch, not '
        'viewpoints here and there)', 'viewpoints', (1, 1000))
    min_region_support: float = parameter(
        5.0, 'surface a region must share with its reference scans, registered onto them as '
        'one, for its correction to count (matched end points, 0.1 m apart); less leaves the '
        'region unmeasured', 'm', (0.0, 1000.0))
    min_resolved_fraction: float = parameter(
        0.5, 'share of the failing overlaps between two submaps, and between a region and its '
        'reference scans, that a correction must mend, net of those it breaks', '', (0.0, 1.0))
    gross_fraction: float = parameter(
        0.5, 'a scan whose pairs fail unexplained more often than this (binomial test) sees a '
        'gross error, not changes', '', (0.01, 0.99))
    change_depth: float = parameter(
        3.0, 'end points this many pair scales inside free space mark a change', 'scales',
        (0.0, 100.0))
    change_cell: float = parameter(0.5, 'changed end points closer than this form one place',
                                   'm', (0.01, 100.0))
    max_change_extent: float = parameter(
        3.0, 'largest place a change can span (people, doors, furniture); a region beyond '
        'registration must show most of its inconsistent end points in larger places', 'm',
        (0.1, 1000.0))

    def as_dict(self) -> dict:
        """The settings as plain data.

        Returns
        -------
        A dict of every field by name.
        """
        return dict(self.__dict__)


@dataclass(frozen=True)
class Misalignment:
    """A region of scans displaced rigidly relative to reference scans."""

    scans: np.ndarray  # the later side, which the correction moves
    reference_scans: np.ndarray
    correction: np.ndarray  # (3,) world transform x, y, theta moving `scans` onto the reference
    correction_std: np.ndarray  # (3,) 1-sigma of the correction
    displacement: float  # metres, RMS end-point displacement the correction implies; NaN
    # when the region could not be registered (a gross error)
    pairs: int  # misaligned or unregistered pairs behind the region
    # its size is measured: by its submaps' agreeing registrations or, beyond their reach, by
    # registering the whole region onto its reference scans (_register_region)
    registered: bool
    # (2,) metres: the mean of the region's end points. A world transform's translation is
    # its motion of the world origin, metres away from the region on a large map; the motion
    # of this point is the region's own (shift_at_centroid)
    centroid: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))

    @property
    def shift_at_centroid(self) -> np.ndarray:
        """Where the correction moves the region's centroid: the region's shift where the
        robot saw it, beside its rotation `correction[2]`.

        Returns
        -------
        (2,) metres (dx, dy) in the world frame; NaN for a region without a correction or a
        centroid.
        """
        centre = np.array([self.centroid[0], self.centroid[1], 0.0])
        return se2.compose(self.correction, centre)[:2] - centre[:2]


@dataclass(frozen=True)
class ChangedPlace:
    """A cluster of end points inside free space another visit saw (people, moved objects)."""

    scans: np.ndarray
    x: float
    y: float
    points: int


@dataclass(frozen=True)
class Assessment:
    """The verdict on a map and its explanation."""

    result: ConsistencyResult
    settings: ExplanationSettings
    explained_pairs: np.ndarray  # (E,) rows of result.pairs that were explained
    pair_classes: np.ndarray  # (E,) int codes into PAIR_CLASSES
    pair_corrections: np.ndarray  # (E, 3) world transforms moving the later scan
    pair_displacements: np.ndarray  # (E,) metres
    misaligned_scans: np.ndarray  # (N,) bool: failed the cascaded test on misaligned pairs
    misalignments: tuple[Misalignment, ...]
    changes: tuple[ChangedPlace, ...]
    local_distortion: float  # metres (_local_distortion)
    # registered regions whose correction moves their points by at most the tolerance: real,
    # and reported, but no reason to fail the map
    minor_misalignments: tuple[Misalignment, ...] = ()
    # stretches whose pose stood still while the scans moved (_frozen.py): a map error in any
    # verdict, strict or not
    frozen: tuple[FrozenEstimate, ...] = ()

    @property
    def distorted(self) -> bool:
        """Consecutive scans disagree by more than the tolerance over most of the map: the
        chain itself is bent (a back-end pulled apart by wrong constraints), whatever the
        pairs say. Judged on maps of at least `min_region_scans` scans."""
        return (self.result.scan_count >= self.settings.min_region_scans
                and self.local_distortion > self.settings.misalignment_tolerance)

    @cached_property
    def evidence(self) -> Evidence:
        """What the tested pairs can support (core/verdict/_evidence.py)."""
        return evidence(self.result, self.settings.min_region_scans)

    @property
    def failed(self) -> bool:
        """Whether the active verdict found a failure (strict: a scan fails the paper's test;
        else a misalignment above the tolerance, or a distorted chain). A failure found is
        earned however little else was tested."""
        if self.frozen:
            return True
        if self.settings.strict:
            return not self.result.consistent
        return bool(self.misalignments) or self.distorted

    @property
    def outcome(self) -> str:
        """The verdict: CONSISTENT, INCONSISTENT or NOTHING_TO_JUDGE (no failure found, but too
        few tested pairs for the test to have found one: never consistent)."""
        if self.failed:
            return INCONSISTENT
        return CONSISTENT if self.evidence.sufficient else NOTHING_TO_JUDGE

    @property
    def consistent(self) -> bool:
        """Whether the map is judged and passes (False for nothing to judge)."""
        return self.outcome == CONSISTENT

    @property
    def flagged(self) -> np.ndarray:
        """(N,) the scans that make the map inconsistent under the active verdict."""
        return self.result.inconsistent if self.settings.strict else self.misaligned_scans

    def class_counts(self) -> dict[str, int]:
        """How many explained pairs fell into each class.

        Returns
        -------
        The count of each class of PAIR_CLASSES by its name, zeros included.
        """
        counts = np.bincount(self.pair_classes, minlength=len(PAIR_CLASSES))
        return {name: int(counts[code]) for code, name in enumerate(PAIR_CLASSES)}

    @property
    def failed_not_explained(self) -> int:
        """Failed pairs the second stage leaves unexplained: those of two scans that pass the
        paper's test, whose failures cannot change the verdict (the class counts and these add
        up to the failed pairs)."""
        return self.result.failed_pair_count - int(self.explained_pairs.size)

    def pair_class(self, rows: np.ndarray) -> list[str]:
        """The class of some pairs of the paper's test.

        Parameters
        ----------
        rows: rows of result.pairs.

        Returns
        -------
        The name of each pair's class in PAIR_CLASSES, 'not explained' for a pair the second
        stage did not explain, 'passed' for one that did not fail.
        """
        code = dict(zip(self.explained_pairs.tolist(), self.pair_classes.tolist()))
        return [PAIR_CLASSES[code[row]].value if row in code
                else 'not explained' if self.result.failed[row] else 'passed'
                for row in np.asarray(rows).tolist()]

    def region_pairs(self, region: Misalignment) -> np.ndarray:
        """The failed pairs between a region and its reference scans, the pairs behind it.

        Parameters
        ----------
        region: one of this assessment's regions (misalignments or minor_misalignments).

        Returns
        -------
        Rows of result.pairs, the largest statistic first.
        """
        result = self.result
        moved = np.zeros(result.scan_count, dtype=bool)
        moved[region.scans] = True
        reference = np.zeros(result.scan_count, dtype=bool)
        reference[region.reference_scans] = True
        first, second = result.pairs[:, 0], result.pairs[:, 1]
        rows = np.flatnonzero(result.failed & ((moved[first] & reference[second])
                                               | (reference[first] & moved[second])))
        return rows[np.argsort(-result.statistic[rows], kind='stable')]

    def summary_line(self) -> str:
        """The verdict in one line of text.

        Returns
        -------
        The line, e.g. INCONSISTENT: 2 misaligned regions (largest 0.31 m, 1.9 deg); 14
        changed places.
        """
        line = self._findings_line()
        if not self.frozen:
            return line
        stood = sum(stretch.scans.size for stretch in self.frozen)
        verdict, rest = line.split(': ', 1)
        return (f'{verdict}: the pose estimate stood still over {stood} scans while they show '
                f'the robot moving (a frozen estimate); {rest}')

    def _findings_line(self) -> str:
        verdict = self.outcome.upper()
        places = len(self.changes)
        changes = f'{places} changed place{"" if places == 1 else "s"} (people, moved objects)'
        if self.outcome == NOTHING_TO_JUDGE:
            return f'{verdict}: {self.evidence.reason()}'
        if self.settings.strict:
            flagged = int(self.result.inconsistent.sum())
            return f'{verdict}: {flagged} scans fail the paper\'s test (strict verdict); {changes}'
        distortion = (f'locally distorted (consecutive scans disagree by '
                      f'{self.local_distortion:.2f} m); ' if self.distorted else '')
        if not self.misalignments:
            tolerance = self.settings.misalignment_tolerance
            minor = ''
            if self.minor_misalignments:
                count = len(self.minor_misalignments)
                largest = max(region.displacement for region in self.minor_misalignments)
                minor = (f' ({count} minor region{"s" if count > 1 else ""} within it, '
                         f'largest {largest:.2f} m)')
            return (f'{verdict}: {distortion}no misalignment above {tolerance:.2f} m{minor}; '
                    f'{changes}')
        largest = _largest(self.misalignments)
        if largest.registered:
            size = (f'largest {largest.displacement:.2f} m, '
                    f'{abs(math.degrees(largest.correction[2])):.1f} deg')
        else:
            size = 'largest beyond local registration, a gross error'
        count = len(self.misalignments)
        regions = f'{count} misaligned region{"s" if count > 1 else ""}'
        return f'{verdict}: {distortion}{regions} ({size}); {changes}'


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


def _local_distortion(result: ConsistencyResult) -> float:
    """Metres: the mean inconsistency distance between the median scan of the map and its
    temporal neighbours, the half-normal mean sqrt(2 / pi) s of the median of the map's own
    local scales s_i (not those of an incremental solution the test may have used)."""
    if result.scan_count == 0:
        return 0.0
    return float(np.median(result.own_scales())) * statistics.HALFNORMAL_MEAN_FACTOR


def _largest(misalignments: tuple[Misalignment, ...]) -> Misalignment:
    return _by_size(misalignments)[0]


def _by_size(regions: tuple[Misalignment, ...]) -> tuple[Misalignment, ...]:
    """Regions in the order the outputs number them: the region that the summary line names
    first (a gross error, beyond local registration, by its pairs; else the largest
    displacement), then the others the same way.

    Parameters
    ----------
    regions: misaligned regions.

    Returns
    -------
    The same regions, reordered (stable among equals).
    """
    return tuple(sorted(regions, key=lambda item: (
        (0, -item.pairs) if not item.registered else (1, -item.displacement))))


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


def _components(scan_count: int, links: np.ndarray) -> np.ndarray:
    """Union-find labels (the smallest member) of nodes joined by the rows of `links` (L, 2)."""
    return _union_find(scan_count, np.ascontiguousarray(links, dtype=np.int64).reshape(-1, 2))


@numba.njit(cache=True)
def _union_find(count: int, links: np.ndarray) -> np.ndarray:
    parent = np.arange(count)
    for row in range(links.shape[0]):
        a, b = _root(parent, links[row, 0]), _root(parent, links[row, 1])
        if a != b:
            parent[max(a, b)] = min(a, b)
    for node in range(count):
        parent[node] = _root(parent, node)
    return parent


@numba.njit(cache=True)
def _root(parent: np.ndarray, node: int) -> int:
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node


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


def place_labels(points: np.ndarray, cell: float) -> np.ndarray:
    """Group points into places joined through neighbouring cells.

    Parameters
    ----------
    points: (M, 2) points, metres; M >= 1.
    cell: the side of a square cell, metres; points in one cell or in cells touching (the
        eight neighbours) share a place.

    Returns
    -------
    (M,) int64 labels, equal for the points of one place.
    """
    cells = np.floor(points / cell).astype(np.int64)
    cells -= cells.min(axis=0) - 1  # every neighbour of a cell has non-negative coordinates
    width = int(cells[:, 1].max()) + 2
    unique, cell_of_point = np.unique(cells[:, 0] * width + cells[:, 1], return_inverse=True)
    # half of the eight neighbours suffices: a link joins both ways
    neighbours = unique[:, None] + np.array([width - 1, width, width + 1, 1])[None]
    found = np.minimum(np.searchsorted(unique, neighbours), unique.size - 1)
    present = unique[found] == neighbours
    links = np.stack([np.nonzero(present)[0], found[present]], axis=1)
    return _components(unique.size, links)[cell_of_point.reshape(-1)]


def _changes(scans: ScanSet, result: ConsistencyResult, rows: np.ndarray,
             settings: ExplanationSettings) -> tuple[ChangedPlace, ...]:
    """The deep end points of the change pairs `rows` of `result`, grouped into places."""
    points, owners = pair_endpoints(scans, result, rows, settings.change_depth)
    if not len(points):
        return ()
    labels = place_labels(points, settings.change_cell)
    places = []
    for label in np.unique(labels):
        members = labels == label
        centre = points[members].mean(axis=0)
        places.append(ChangedPlace(scans=np.unique(owners[members]), x=float(centre[0]),
                                   y=float(centre[1]), points=int(members.sum())))
    return tuple(sorted(places, key=lambda place: -place.points))


_EXTENT_SAMPLE = 2000  # pairs whose end points show a region's extent: bounded cost


def _spans_beyond_changes(scans: ScanSet, result: ConsistencyResult, rows: np.ndarray,
                          settings: ExplanationSettings) -> bool:
    """Whether most deep inconsistent end points of the pairs `rows` lie in places wider than
    any change: a gross error crosses whole walls and rooms (places of 5-40 m on displaced
    copies), people, doors and furniture make places of a metre or two."""
    rows = rows[::max(1, -(-rows.size // _EXTENT_SAMPLE))]
    points, _ = pair_endpoints(scans, result, rows, settings.change_depth)
    if not len(points):
        return False
    labels = place_labels(points, settings.change_cell)
    low = np.full((labels.max() + 1, 2), np.inf)
    high = np.full((labels.max() + 1, 2), -np.inf)
    np.minimum.at(low, labels, points)
    np.maximum.at(high, labels, points)
    extent = np.hypot(*(high - low).T)
    return bool(np.count_nonzero(extent[labels] > settings.max_change_extent) * 2 > len(points))


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
