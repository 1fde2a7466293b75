"""What the second stage gives: the verdict's outcomes, the classes of failed pairs, the
explanation's settings, misaligned regions (Misalignment), changed places (ChangedPlace) and the
Assessment that holds them (explanation.py makes it)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult, statistics
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.parameters import Choice, Settings, parameter
from map_consistency_ros.core.verdict._evidence import Evidence, evidence
from map_consistency_ros.core.verdict._frozen import FrozenEstimate


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
