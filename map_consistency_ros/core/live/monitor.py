"""Incremental consistency state shared by the live node and offline bag replay.

Scans arrive with stamps and are buffered (bounded) until a trajectory names a pose with the
same stamp; the pair becomes a keyframe. Every trajectory is the SLAM back-end's full current
estimate. The monitor keeps, per keyframe:

- the current pose (for the map measures) and the incremental pose: the keyframe's first-seen
  pose relative to its predecessor in that same trajectory, chained onto the predecessor's
  incremental pose. Local scales (consistency.local_scales, eq. 10 of the paper) are fitted on
  pairs of temporally adjacent keyframes at their incremental poses, which a later loop closure
  never changes;
- cached pair measures (M_ij / n_ij, core/geometry/_measure.py) at the current poses. When a
  trajectory moves poses (a loop closure), only pairs that involve moved or new keyframes are
  measured again, with candidates from a spatial index of the scans' extents.

Keyframes are identified by a stable slot (registration order); statistics run on keyframes in
stamp order. The test runs only when asked for (`evaluate`), once per change of the map. Not
thread-safe: one thread owns a monitor.

The pieces, each in a module of its own with its invariants: the scan buffer (_scan_buffer.py),
the keyframe store and stamp matching (_keyframes.py), the pair caches (_pair_cache.py), which
pairs are measured (_pair_selection.py: the partner budget, the local window) and the placed
geometry (_placement.py). The monitor coordinates them.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from map_consistency_ros.core.backend import (CONSTRAINT_WIDTH, MAX_POSE_EXTENT, PoseGraph,
                                              check_constraint_rows, split_constraint_rows)
from map_consistency_ros.core.consistency import (NO_BOUND, ConsistencyParameters,
                                                  ConsistencyResult, add_local_bounds,
                                                  evaluate_pairs, scales_from_bounds)
from map_consistency_ros.core.geometry import (PairMeasures, ScanExtentIndex, ScanSet,
                                               SensorModel, disagreement, is_new_viewpoint,
                                               measure_pairs, read_only, same_pose, se2)
from map_consistency_ros.core.live._keyframes import (FOLDED, NO_SCAN, Keyframes, match_sorted,
                                                      rank_of_slot)
from map_consistency_ros.core.live._pair_cache import PairCache, key_slots, pair_keys
from map_consistency_ros.core.live._pair_selection import PartnerBudget, local_pair_keys
from map_consistency_ros.core.live._placement import Placement
from map_consistency_ros.core.live._scan_buffer import ScanBuffer
from map_consistency_ros.core.live._scan_counts import ScanCounts
from map_consistency_ros.core.parameters import Settings, parameter

# Batches of at most this many pairs keep a live node's shutdown responsive during a large
# update (a loop closure, a burst of keyframes).
MEASURE_CHUNK = 1024
# The stamps of scans refused or lost that the monitor remembers (the newest; 0.8 MB), so that
# the poses naming them are not taken for poses whose scans never came: bounded, as scans may
# be refused all along (a second laser on the topic).
NOT_KEPT_LIMIT = 100_000


@dataclass(frozen=True)
class MonitorSettings(Settings):
    """Bookkeeping of the monitor (the statistics are in ConsistencyParameters)."""

    laser_offset: tuple[float, float, float] = parameter(
        (0.0, 0.0, 0.0), 'pose [x, y, yaw] of the laser in the keyframe frame', 'm, m, rad')
    stamp_tolerance: float = parameter(
        1e-3, 'largest |pose stamp - scan stamp| of a keyframe', 's', (0.0, 1.0))
    max_buffered_scans: int = parameter(
        2000, 'scans waiting for a pose; the oldest are dropped (and counted) beyond', '',
        (1, 1_000_000))
    move_tolerance: float = parameter(
        0.01, 'a keyframe moving further is measured again', 'm', (0.0, 10.0))
    move_angle_tolerance: float = parameter(
        0.005, 'a keyframe turning further is measured again', 'rad', (0.0, 3.14))
    max_pose_extent: float = parameter(
        MAX_POSE_EXTENT, 'poses with |x| or |y| beyond this are absurd: skipped and counted',
        'm', (1.0, 1e9))
    max_partners: int = parameter(
        50, 'a new viewpoint is measured against at most about this many earlier overlapping '
        'ones, shared among the earlier visits of its place (the nearest of each visit), chosen '
        'when it arrives: bounds the cost per keyframe in places visited very often; 0: all',
        '', (0, 1_000_000))


@dataclass(frozen=True)
class UpdateSummary:
    """What one update did."""

    new_keyframes: int = 0
    moved_keyframes: int = 0
    measured_pairs: int = 0  # pairs whose M_ij / n_ij were computed in this update
    unmatched_poses: int = 0  # trajectory poses with no scan (yet)
    elapsed: float = 0.0  # seconds
    warnings: tuple[str, ...] = ()  # input problems that were skipped, not fatal

    @property
    def changed(self) -> bool:
        return self.new_keyframes > 0 or self.moved_keyframes > 0


@dataclass(frozen=True)
class MonitorSnapshot:
    """The keyframes in stamp order and the verdict on them."""

    ids: np.ndarray  # (N,) stable keyframe ids (registration order)
    stamps: np.ndarray  # (N,) seconds
    poses: np.ndarray  # (N, 3) current keyframe poses
    incremental_poses: np.ndarray  # (N, 3) poses of the incremental solution
    ranges: np.ndarray  # (N, K)
    model: SensorModel | None
    laser_offset: np.ndarray  # (3,)
    result: ConsistencyResult | None  # None until there is at least one keyframe
    buffered_scans: int = 0
    unmatched_poses: int = 0
    last_update: UpdateSummary = field(default_factory=UpdateSummary)
    pushed_out_scans: int = 0  # lost: pushed out of the full buffer before a pose reached them
    passed_over_scans: int = 0  # pushed out of the buffer after the estimate went past them
    # unmatched poses older than the newest scan and not older than the first, whose scans
    # never came (ConsistencyMonitor.counts)
    poses_without_scan: int = 0
    folded_scans: int = 0  # keyframes within a viewpoint's reach of the previous one, not tested
    estimate_stamp: float = math.nan  # the estimate these poses are (LivePipeline.evaluate)
    # what became of every scan received (LivePipeline.evaluate; None from the monitor alone)
    scan_counts: ScanCounts | None = None

    @property
    def keyframe_count(self) -> int:
        return int(self.stamps.size)

    def scans(self) -> ScanSet:
        """The keyframes' scans placed at their current poses.

        Returns
        -------
        A ScanSet of the N keyframes in stamp order, the laser at `laser_offset` from each
        pose. ValueError before the first keyframe (`result` None): no scan, no beam geometry.
        """
        if self.model is None:
            raise ValueError('no keyframes yet: the snapshot holds no scan to place')
        return ScanSet.from_ranges(self.ranges, sensor_poses(self.poses, self.laser_offset),
                                   self.model)


@dataclass(frozen=True)
class SlamGraph:
    """The SLAM back-end's pose graph as the monitor holds it, for a DCS retune.

    Its vertices are the poses of the last trajectory that the constraints name, whether their
    scans became keyframes or were folded into a viewpoint (or never came): the back-end's own
    graph. The keyframes among them carry their scans; M(Phi) is measured on those, as the test
    measures the map.
    """

    graph: PoseGraph  # vertices in stamp order, at the trajectory's poses, the first fixed
    stamps: np.ndarray  # (N,) the vertices' stamps, seconds
    scan_vertices: np.ndarray  # (S,) the vertex of each keyframe in the graph, increasing
    ranges: np.ndarray  # (S, K) their scans
    model: SensorModel
    laser_offset: np.ndarray  # (3,)
    keyframes_outside: int = 0  # keyframes that no constraint names (not in the graph)

    def scans_at(self, poses: np.ndarray) -> ScanSet:
        """The keyframes of the graph placed with the vertices at `poses`.

        Parameters
        ----------
        poses: (N, 3) vertex poses (e.g. a DCS solution's).

        Returns
        -------
        The ScanSet of the S keyframes, in stamp order.
        """
        return ScanSet.from_ranges(self.ranges, sensor_poses(poses[self.scan_vertices],
                                                             self.laser_offset), self.model)


def sensor_poses(keyframe_poses: np.ndarray, laser_offset: np.ndarray) -> np.ndarray:
    """Poses of the laser for keyframe poses.

    Parameters
    ----------
    keyframe_poses: (N, 3) keyframe poses (x, y, yaw).
    laser_offset: (3,) the laser's pose in the keyframe frame.

    Returns
    -------
    (N, 3) the laser's poses, keyframe_pose (+) laser_offset.
    """
    return se2.compose(keyframe_poses, np.broadcast_to(laser_offset, keyframe_poses.shape))


def _same_model(a: SensorModel, b: SensorModel) -> bool:
    return (math.isclose(a.angle_min, b.angle_min, abs_tol=1e-9)
            and math.isclose(a.angle_increment, b.angle_increment, abs_tol=1e-12)
            and math.isclose(a.max_range, b.max_range, abs_tol=1e-9)
            and math.isclose(a.range_min, b.range_min, abs_tol=1e-9))


class ConsistencyMonitor:
    """Scans + the current trajectory -> an up-to-date consistency verdict, incrementally.

    Feed it with `add_scan` and `update_trajectory` (a late scan of an already published pose
    is registered by the next `update_trajectory` or by `refresh`); run the test and read the
    state with `evaluate`. Bad input raises ValueError and leaves the state unchanged.
    """

    def __init__(self, parameters: ConsistencyParameters | None = None,
                 settings: MonitorSettings | None = None) -> None:
        self.parameters = parameters or ConsistencyParameters()
        self.settings = settings or MonitorSettings()
        self._offset = np.asarray(self.settings.laser_offset, dtype=np.float64)
        self._keep = max(self.parameters.trim_largest, 1)
        self._model: SensorModel | None = None
        self._buffer = ScanBuffer(self.settings.max_buffered_scans, self.settings.stamp_tolerance)
        self._keyframes: Keyframes | None = None  # from the first scan (its beam count) on
        self._path_stamps = np.zeros(0)
        self._path_poses = np.zeros((0, 3))
        # the last _path_slots: (trajectory stamps, keyframe store, its version, slots)
        self._path_slots_of: tuple[np.ndarray, Keyframes, int, np.ndarray] | None = None
        self._reset_pairs()
        self._result: ConsistencyResult | None = None
        # the last result, its pair cache, the cache's generation and the keyframe order then:
        # while the cache only grows and that order stays the start of the current one, the
        # next test starts from it
        self._tested_on: tuple[PairCache, int, ConsistencyResult, np.ndarray] | None = None
        self._last = UpdateSummary()
        # the stamps (sorted) of the last trajectory's poses without a scan, and whether a
        # buffered scan matches one of them: kept by _apply_path and add_scan, because the node
        # asks on every scan (`pending`) and a pass over the trajectory would grow with the run
        self._unmatched_stamps = np.zeros(0)
        self._pending = False
        # the oldest scan stamp given to add_scan; the stamps of the scans that came and were
        # not kept (sorted, the newest NOT_KEPT_LIMIT of them, and those noted since)
        self._first_scan = math.inf
        self._not_kept = np.zeros(0)
        self._not_kept_new: list[float] = []
        self._constraints = np.zeros((0, CONSTRAINT_WIDTH))

    def _reset_pairs(self) -> None:
        """Empty pair caches, index, placements and partner budget (nothing measured yet)."""
        self._index = ScanExtentIndex()
        trim = self.parameters.trim_largest
        self._current = PairCache(self._keep, trim)  # map pairs at the current poses
        self._local = PairCache(self._keep, trim)  # local-window pairs at incremental poses
        # the local cache, its generation and size when each slot's largest local bound
        # (add_local_bounds) was last brought up to date, and those bounds
        self._local_bounds: tuple[PairCache, int, int, np.ndarray] | None = None
        self._placed, self._placed_incremental = Placement(), Placement()
        self._budget = PartnerBudget(self.settings.max_partners)

    # -- input -------------------------------------------------------------------------------

    @property
    def model(self) -> SensorModel | None:
        """The beam geometry of every scan, fixed by the first scan."""
        return self._model

    @property
    def keyframe_count(self) -> int:
        return 0 if self._keyframes is None else self._keyframes.count

    def add_scan(self, stamp: float, ranges: np.ndarray, model: SensorModel) -> None:
        """Buffer one scan until a trajectory names its pose.

        Parameters
        ----------
        stamp: the scan's stamp, seconds.
        ranges: (K,) metres; NaN / inf beams are kept (they count as free space up to max
            range).
        model: its beam geometry; the first scan's fixes every later scan's.

        Raises ValueError for a non-finite stamp, fewer than 2 beams, beams overlapping past
        2 pi, a beam geometry that differs from the first scan's, or a stamp already registered
        as a keyframe or buffered; the map is unchanged, the stamp remembered as a scan that
        came (`note_not_kept`).
        """
        try:
            self._add_scan(float(stamp), ranges, model)
        except ValueError:
            self.note_not_kept([stamp])
            raise
        # the window in which a pose without its scan names a scan that never came
        self._first_scan = min(self._first_scan, float(stamp))

    def note_not_kept(self, stamps) -> None:
        """Remember scans that came but were not kept (refused, or lost before they reached
        the monitor), so that a pose naming one is not counted among the poses whose scan
        never came: each is counted once, where it went (core/live/_scan_counts.py).

        Parameters
        ----------
        stamps: the scans' stamps, seconds (non-finite ones are ignored).
        """
        finite = [float(stamp) for stamp in stamps if math.isfinite(stamp)]
        self._not_kept_new.extend(finite)
        if len(self._not_kept_new) > NOT_KEPT_LIMIT:
            self._merge_not_kept()

    def _merge_not_kept(self) -> None:
        """The stamps noted as not kept into the sorted ones, of which the newest
        NOT_KEPT_LIMIT are kept (a pose naming an older one is then taken for one whose scan
        never came)."""
        merged = np.sort(np.concatenate([self._not_kept, self._not_kept_new]))
        self._not_kept = merged[-NOT_KEPT_LIMIT:]
        self._not_kept_new = []

    def _add_scan(self, stamp: float, ranges: np.ndarray, model: SensorModel) -> None:
        """add_scan, without the bookkeeping of scans not kept."""
        ranges = np.asarray(ranges, dtype=np.float64)
        if not math.isfinite(stamp):
            raise ValueError(f'scan stamp must be finite, got {stamp}')
        if ranges.ndim != 1 or ranges.size == 0:
            raise ValueError(f'a scan needs a non-empty 1-D range array, got shape {ranges.shape}')
        model.check_beam_count(ranges.size)
        if self._model is None:
            self._model = model
            self._keyframes = Keyframes(ranges.size, self.settings.stamp_tolerance)
        elif not _same_model(model, self._model) or ranges.size != self._keyframes.beams:
            raise ValueError(
                f'scan at {stamp:.6f} has {ranges.size} beams from {model.angle_min:.6g} rad '
                f'by {model.angle_increment:.6g} rad (max range {model.max_range:g}); the monitor '
                f'takes only scans like the first ({self._keyframes.beams} beams from '
                f'{self._model.angle_min:.6g} by {self._model.angle_increment:.6g}, max range '
                f'{self._model.max_range:g})')
        if self._keyframes.holds(stamp):
            raise ValueError(f'scan at {stamp:.6f} duplicates a registered keyframe; ignored')
        buffer = self._buffer
        left = buffer.pushed_out + buffer.passed_over
        reached = self._path_stamps[-1] if self._path_stamps.size else -math.inf  # sorted
        self.note_not_kept(buffer.add(stamp, ranges, reached))
        if buffer.pushed_out + buffer.passed_over != left:  # a scan went: check what is held
            self._pending = self._buffer_matches_unmatched()
        elif not self._pending:
            self._pending = bool(match_sorted(np.array([stamp]), self._unmatched_stamps,
                                              self.settings.stamp_tolerance)[0] >= 0)

    def pose_problem(self, pose: np.ndarray) -> str:
        """Why a single pose is unusable.

        Parameters
        ----------
        pose: (3,) a pose (x, y, yaw).

        Returns
        -------
        The reason (non-finite values, beyond max_pose_extent), '' when it is usable.
        """
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (3,) or not np.isfinite(pose).all():
            return f'non-finite values or an unusable quaternion ({pose.tolist()})'
        if np.abs(pose[:2]).max() > self.settings.max_pose_extent:
            return f'beyond max_pose_extent = {self.settings.max_pose_extent:g} m'
        return ''

    @property
    def pending(self) -> bool:
        """Whether buffered scans match poses of the last trajectory (call `refresh`)."""
        return self._pending

    @property
    def _unmatched(self) -> int:
        """Poses of the last trajectory without a scan (yet)."""
        return int(self._unmatched_stamps.size)

    def _buffer_matches_unmatched(self) -> bool:
        unmatched = self._unmatched_stamps
        return bool(unmatched.size and np.isfinite(self._buffer.matches(unmatched)).any())

    def update_trajectory(self, stamps: np.ndarray, poses: np.ndarray) -> UpdateSummary:
        """Take the back-end's full current estimate: register, move, measure, test.

        Parameters
        ----------
        stamps: (M,) the keyframes' scan stamps, seconds, in any order.
        poses: (M, 3) their poses (x, y, yaw). Poses with non-finite values, beyond
            max_pose_extent or with a duplicated stamp are skipped with a warning in the
            summary.

        Returns
        -------
        What the update did (the test runs at the next `evaluate`). Raises ValueError when the
        arrays do not have those shapes.
        """
        # copies: the monitor keeps them, whatever the caller does with its arrays
        stamps = np.array(stamps, dtype=np.float64)
        poses = np.array(poses, dtype=np.float64)
        if stamps.ndim != 1 or poses.shape != (stamps.size, 3):
            raise ValueError(f'a trajectory needs stamps (M,) and poses (M, 3), got shapes '
                             f'{stamps.shape} and {poses.shape}')
        if _clean_trajectory(stamps, poses, self.settings.max_pose_extent):
            # one compiled pass: a trajectory holds every pose of the run, and a pass per check
            # was most of what an update's cost grew by with it
            self._path_stamps, self._path_poses = stamps, poses
            return self._apply_path(())
        warnings = []
        x, y = poses[:, 0], poses[:, 1]
        finite = (np.isfinite(stamps) & np.isfinite(x) & np.isfinite(y)
                  & np.isfinite(poses[:, 2]))
        if not finite.all():
            warnings.append(f'{int((~finite).sum())} trajectory poses with non-finite values '
                            '(or an unusable quaternion) skipped')
        extent = self.settings.max_pose_extent
        with np.errstate(invalid='ignore'):
            absurd = finite & ((np.abs(x) > extent) | (np.abs(y) > extent))
        if absurd.any():
            warnings.append(f'{int(absurd.sum())} trajectory poses beyond max_pose_extent = '
                            f'{extent:g} m skipped')
        finite &= ~absurd
        if not finite.all():
            stamps, poses = stamps[finite], poses[finite]
        if not np.all(np.diff(stamps) > 0.0):  # else already in order, no stamp twice
            order = np.argsort(stamps, kind='stable')
            stamps, poses = stamps[order], poses[order]
            duplicate = np.zeros(stamps.size, dtype=bool)
            duplicate[1:] = np.diff(stamps) <= 0.0
            if duplicate.any():
                warnings.append(f'{int(duplicate.sum())} trajectory poses with a duplicated '
                                'stamp skipped (the first is kept)')
                stamps, poses = stamps[~duplicate], poses[~duplicate]
        self._path_stamps, self._path_poses = stamps, poses
        return self._apply_path(tuple(warnings))

    def refresh(self) -> UpdateSummary:
        """Register late scans against the last trajectory (a no-op when nothing is pending).

        Returns
        -------
        What the update did.
        """
        return self._apply_path(())

    def recompute(self) -> UpdateSummary:
        """Measure every pair again from scratch (the incremental caches are rebuilt; the
        partner budget chooses again on the current poses).

        Returns
        -------
        What it did: every keyframe counted as moved, the pairs measured.
        """
        start = time.perf_counter()
        self._reset_pairs()
        slots = np.arange(self.keyframe_count)
        measured = self._measure(slots, slots) if slots.size else 0
        self._last = UpdateSummary(moved_keyframes=int(slots.size), measured_pairs=measured,
                                   unmatched_poses=self._unmatched,
                                   elapsed=time.perf_counter() - start)
        return self._last

    def set_constraints(self, rows: np.ndarray) -> None:
        """The pose-graph edges for DCS retuning, replacing the previous set.

        Parameters
        ----------
        rows: (E, 11) `[stamp_from, stamp_to, dx, dy, dtheta, I11, I12, I13, I22, I23, I33]`
            (stamps in seconds, upper triangle of the information matrix).

        Raises ValueError (and keeps the previous set) on a wrong shape, non-finite values, an
        edge from a stamp to itself, a measurement beyond max_pose_extent, information entries
        beyond MAX_INFORMATION, or an information matrix that is not symmetric positive
        definite.
        """
        rows = check_constraint_rows(rows, self.settings.max_pose_extent)
        self._constraints = rows.copy()

    @property
    def constraints(self) -> np.ndarray:
        """The last accepted constraint rows (E, 11)."""
        return self._constraints

    # -- output ------------------------------------------------------------------------------

    def slam_graph(self) -> SlamGraph | None:
        """The back-end's pose graph: the constraints between poses of the last trajectory.

        Returns
        -------
        The SlamGraph whose vertices are the trajectory's poses that constraint rows name
        (stamp order, the first fixed), folded scans' poses included, and whose edges are the
        rows between two of them (rows naming a stamp the trajectory lacks are left out), with
        the scans of the keyframes among the vertices. None when no row connects two poses of
        the trajectory or fewer than two of the graph's vertices are keyframes.
        """
        if self._keyframes is None or self._constraints.shape[0] == 0:
            return None
        # the trajectory's stamps are sorted (update_trajectory keeps them so)
        stamps, tolerance = self._path_stamps, self.settings.stamp_tolerance
        stamp_from, stamp_to, measurements, information = split_constraint_rows(
            self._constraints)
        ends_from = match_sorted(stamp_from, stamps, tolerance)
        ends_to = match_sorted(stamp_to, stamps, tolerance)
        known = (ends_from >= 0) & (ends_to >= 0) & (ends_from != ends_to)
        named = np.unique(np.concatenate([ends_from[known], ends_to[known]]))
        slots = self._path_slots()[named]
        scan_vertices = np.flatnonzero(slots >= 0)
        if scan_vertices.size < 2:
            return None
        vertex_of = np.full(stamps.size, -1, dtype=np.int64)
        vertex_of[named] = np.arange(named.size)
        fixed = np.zeros(named.size, dtype=bool)
        fixed[0] = True
        graph = PoseGraph(poses=self._path_poses[named], edge_from=vertex_of[ends_from[known]],
                          edge_to=vertex_of[ends_to[known]], measurements=measurements[known],
                          information=information[known], fixed=fixed)
        return SlamGraph(graph=graph, stamps=stamps[named], scan_vertices=scan_vertices,
                         ranges=self._keyframes.ranges[slots[scan_vertices]], model=self._model,
                         laser_offset=self._offset.copy(),
                         keyframes_outside=self.keyframe_count - int(scan_vertices.size))

    def evaluate(self) -> MonitorSnapshot:
        """Run the test on the current map (when it changed since the last evaluation) and
        return it with the keyframes in stamp order.

        Returns
        -------
        A MonitorSnapshot: copies (or read-only views) of the keyframes and the verdict on them
        (`result`, None while there is no keyframe).
        """
        if self._keyframes is None:
            empty = np.zeros((0, 3))
            return MonitorSnapshot(ids=np.zeros(0, dtype=np.int64), stamps=np.zeros(0),
                                   poses=empty, incremental_poses=empty, ranges=np.zeros((0, 0)),
                                   model=self._model, laser_offset=self._offset.copy(),
                                   result=None, last_update=self._last, **self.counts())
        keyframes = self._keyframes
        order = keyframes.order()
        if keyframes.in_stamp_order():
            # A slot's ranges never change once registered: a read-only view is a snapshot,
            # and copying every scan on every update would grow with the map.
            ranges = read_only(keyframes.ranges[:keyframes.count])
        else:
            ranges = keyframes.ranges[order]
        return MonitorSnapshot(
            ids=order.astype(np.int64), stamps=keyframes.stamps[order],
            poses=keyframes.poses[order], incremental_poses=keyframes.incremental[order],
            ranges=ranges, model=self._model,
            laser_offset=self._offset.copy(), result=self._test(),
            last_update=self._last, **self.counts())

    def counts(self) -> dict[str, int]:
        """The snapshot's counts of scans and poses that are not keyframes: buffered, pushed
        out (lost), passed over, folded, and poses still without a scan. A scan that changes
        no keyframe changes only these; none of them passes over the map.

        Returns
        -------
        MonitorSnapshot field name -> value.
        """
        return dict(buffered_scans=len(self._buffer), unmatched_poses=self._unmatched,
                    pushed_out_scans=self._buffer.pushed_out,
                    passed_over_scans=self._buffer.passed_over,
                    poses_without_scan=self._poses_without_scan(),
                    folded_scans=self._folded_count())

    def _poses_without_scan(self) -> int:
        """Poses of the last trajectory whose scans never came.

        Scans arrive in stamp order: a pose older than the newest scan and still without one
        names a scan that did not come, unless it is older than the first scan (a scan before
        a reset, or before the node listened) or its scan came and was not kept (refused or
        lost: counted as such)."""
        tolerance = self.settings.stamp_tolerance
        unmatched = self._unmatched_stamps
        low, high = np.searchsorted(unmatched, [self._first_scan - tolerance,
                                                self._buffer.newest - tolerance])
        late = unmatched[low:max(low, high)]
        if late.size and (self._not_kept.size or self._not_kept_new):
            if self._not_kept_new:
                self._merge_not_kept()
            late = late[match_sorted(late, self._not_kept, tolerance) < 0]
        return int(late.size)

    # -- bookkeeping -------------------------------------------------------------------------

    def _folded_count(self) -> int:
        return 0 if self._keyframes is None else int(self._keyframes.folded.size)

    def _path_slots(self, writable: bool = False) -> np.ndarray:
        """For each pose of the last trajectory, its keyframe slot, FOLDED or NO_SCAN:
        read-only, or with `writable` a copy (callers fill in the slots they register).

        Kept, because the node asks on every scan whether one is pending, and carried over:
        a trajectory usually repeats the last one's poses and adds a few, so only the poses
        near new stamps (new poses, new keyframes, newly folded scans) are matched again, and
        the cost of an update does not grow with the length of the run."""
        stamps, keyframes = self._path_stamps, self._keyframes
        if keyframes is None:
            return np.full(stamps.size, NO_SCAN, dtype=np.int64)
        cached, slots = self._path_slots_of, None
        if cached is not None and cached[1] is keyframes:
            old_stamps, _, version, old_slots = cached
            if old_stamps is stamps and version == keyframes.version:
                slots = old_slots
            elif old_stamps.size <= stamps.size and (
                    old_stamps is stamps
                    or np.array_equal(stamps[:old_stamps.size], old_stamps)):
                slots = np.empty(stamps.size, dtype=np.int64)
                slots[:old_slots.size] = old_slots
                slots[old_slots.size:] = NO_SCAN
                changed = np.concatenate([keyframes.added_since(version),
                                          stamps[old_stamps.size:]])
                slots = keyframes.refresh_slots(stamps, slots, changed)
        if slots is None:
            slots = keyframes.trajectory_slots(stamps)
        self._path_slots_of = (stamps, keyframes, keyframes.version, slots)
        return slots.copy() if writable else read_only(slots)

    def _apply_path(self, warnings: tuple[str, ...]) -> UpdateSummary:
        start = time.perf_counter()
        path_slots = self._path_slots(writable=True)
        moved = self._move_keyframes(path_slots)
        new = self._register(path_slots)
        self._unmatched_stamps = self._path_stamps[self._path_slots() == NO_SCAN]
        self._pending = self._buffer_matches_unmatched()
        changed = np.union1d(moved, new).astype(np.int64)
        measured = self._measure(changed, new) if changed.size else 0
        self._last = UpdateSummary(new_keyframes=int(new.size), moved_keyframes=int(moved.size),
                                   measured_pairs=measured, unmatched_poses=self._unmatched,
                                   elapsed=time.perf_counter() - start, warnings=warnings)
        return self._last

    def _move_keyframes(self, path_slots: np.ndarray) -> np.ndarray:
        known = np.flatnonzero(path_slots >= 0)  # indices: a mask over (M, 3) costs more
        slots, targets = path_slots[known], self._path_poses[known]
        if slots.size == 0:
            return np.zeros(0, dtype=np.int64)
        current = self._keyframes.poses[slots]
        shift = np.hypot(*(targets[:, :2] - current[:, :2]).T)
        turn = np.abs(se2.wrap_angle(targets[:, 2] - current[:, 2]))
        settings = self.settings
        moved = (shift > settings.move_tolerance) | (turn > settings.move_angle_tolerance)
        self._keyframes.poses[slots[moved]] = targets[moved]
        self._placed.invalidate(slots[moved])
        return slots[moved]

    def _register(self, path_slots: np.ndarray) -> np.ndarray:
        """New keyframes for poses whose scan is buffered and that are new viewpoints; their
        incremental poses. The scans of the other poses are folded (counted, not kept)."""
        new, folded = [], []
        unregistered = np.flatnonzero(path_slots == NO_SCAN)
        matches = self._buffer.matches(self._path_stamps[unregistered])
        # trajectory indices of keyframes before this pass; the pass goes in index order, so
        # a keyframe it registers is the nearest earlier one of every later pose
        known = np.flatnonzero(path_slots >= 0)
        registered = -1
        for index, buffered in zip(unregistered[np.isfinite(matches)],
                                   matches[np.isfinite(matches)]):
            if buffered not in self._buffer:
                continue  # two poses within the tolerance of one scan: the first takes it
            place = int(np.searchsorted(known, index))
            earlier = max(int(known[place - 1]) if place else -1, registered)
            later = int(known[place]) if place < known.size else -1
            if not self._new_viewpoint(index, earlier, path_slots, float(buffered)):
                self._buffer.pop(float(buffered))
                folded.append(float(buffered))
                path_slots[index] = FOLDED
                continue
            pose = self._path_poses[index]
            anchor = earlier if earlier >= 0 else later
            incremental = self._incremental_pose(index, anchor, path_slots)
            scan = self._buffer.pop(float(buffered))
            slot = self._keyframes.append(float(buffered), pose, incremental, scan)
            path_slots[index] = slot
            registered = int(index)
            new.append(slot)
        if folded:  # a fold needs an earlier keyframe: the store exists
            self._keyframes.fold(folded)
        return np.asarray(new, dtype=np.int64)

    def _new_viewpoint(self, index: int, earlier: int, path_slots: np.ndarray,
                       stamp: float) -> bool:
        """Whether pose `index` of the trajectory, whose scan is the buffered one at `stamp`, is
        a viewpoint: far enough from the nearest earlier keyframe of the trajectory, pose
        `earlier`, or repeating that keyframe's pose while its scan disagrees with the
        keyframe's (core/geometry/_viewpoints.py, as `check` selects them). A pose with no earlier keyframe (-1: the first, or a late first
        scan) always is."""
        if earlier < 0:
            return True
        # the laser's travel, as check measures it on a log's laser poses
        laser = sensor_poses(self._path_poses[[earlier, index]], self._offset)
        step = se2.relative(laser[0], laser[1])
        parameters = self.parameters
        if is_new_viewpoint(step, parameters.viewpoint_spacing, parameters.viewpoint_turn):
            return True
        if parameters.fold_disagreement >= 1.0 or not same_pose(laser[0], laser[1]):
            return False
        ranges = np.stack([self._keyframes.ranges[path_slots[earlier]],
                           self._buffer.peek(stamp)])
        pair = ScanSet.from_ranges(ranges, laser, self._model)
        return disagreement(pair, 0, 1, parameters.fold_depth) > parameters.fold_disagreement

    def _incremental_pose(self, index: int, anchor: int, path_slots: np.ndarray
                          ) -> np.ndarray:
        """First-seen pose relative to the nearest keyframe of the same trajectory, pose
        `anchor`: the nearest earlier pose that is (or has just become) a keyframe, else the
        nearest later one (a late first scan); -1 when there is none, and the pose itself
        starts the incremental solution. (Path poses are in stamp order.)
        """
        if anchor < 0:
            return self._path_poses[index]
        step = se2.relative(self._path_poses[anchor], self._path_poses[index])
        return se2.compose(self._keyframes.incremental[path_slots[anchor]], step)

    def _scans(self, slots: np.ndarray, incremental: bool = False) -> ScanSet:
        """The keyframes `slots` placed at their current (or incremental) poses."""
        keyframes = self._keyframes
        poses = keyframes.incremental if incremental else keyframes.poses
        placement = self._placed_incremental if incremental else self._placed
        return placement.scans(slots, lambda missing: ScanSet.from_ranges(
            keyframes.ranges[missing], sensor_poses(poses[missing], self._offset), self._model))

    def _measure_keys(self, keys: np.ndarray, incremental: bool = False) -> PairMeasures:
        """Measures of the pairs `keys` at the current (or incremental) poses."""
        pairs = key_slots(keys)
        involved = np.unique(pairs)
        scans = self._scans(involved, incremental)
        return measure_pairs(scans, np.searchsorted(involved, pairs), self._keep,
                             chunk=MEASURE_CHUNK)

    def _measure(self, changed: np.ndarray, new: np.ndarray) -> int:
        """Measure pairs touching `changed` slots (`new` among them), update the local
        measures; the tests run at the next evaluation."""
        keyframes = self._keyframes
        placed = self._scans(changed)
        self._index.update(changed, placed.extents)
        # new keyframes have no pairs yet: only moved ones lose theirs (a test over every pair)
        self._current.drop_slots(np.setdiff1d(changed, new), keyframes.count)
        self._current.mark_new(new)
        touching = self._budget.select(
            self._index.pairs_touching(changed), new, keyframes.count,
            lambda slots: sensor_poses(keyframes.poses[slots], self._offset))
        keys = np.unique(pair_keys(touching[:, 0], touching[:, 1]))
        measured = 0
        if keys.size:
            measures = self._measure_keys(keys)
            keep = measures.point_count > 0  # pairs without points carry no evidence
            self._current.insert(keys[keep], measures.take(keep))
            measured += int(keys.size)
        order = keyframes.order()
        measured += self._update_local(order, rank_of_slot(order)[new])
        self._result = None  # the statistics run once per evaluation, not per update
        return measured

    def _test(self) -> ConsistencyResult | None:
        """The test on the current measures (computed at most once per change).

        The statistics cover every pair of the map; a burst of updates (a Path with late
        scans, a node catching up) costs one test, at the next evaluation. While no keyframe
        moved and the new ones came after every earlier one in stamp order (the earlier ones
        keep their ranks, whether or not they once arrived out of order), only the new pairs
        and those of scans whose scale changed are tested again (evaluate_pairs' `previous`).
        """
        if self._result is None and self.keyframe_count:
            keyframes = self._keyframes
            order = keyframes.order()
            # Keyframes that arrived in stamp order have rank == slot: no re-indexing.
            in_order = keyframes.in_stamp_order()
            ranks = None if in_order else rank_of_slot(order)
            scales = self._local_scales(keyframes.count)
            first_rows = self._current.first_rows(keyframes.count)
            if not in_order:  # by slot -> by rank
                scales, first_rows = scales[order], first_rows[order]
            cache, previous = self._current, None
            if self._tested_on is not None:
                tested_cache, generation, tested, tested_order = self._tested_on
                if (tested_cache is cache and generation == cache.generation
                        and np.array_equal(order[:tested_order.size], tested_order)):
                    previous = tested
            self._result = evaluate_pairs(cache.measures(ranks), scales, keyframes.count,
                                          self.parameters, robust=cache.robust(),
                                          previous=previous, first_rows=first_rows)
            self._tested_on = (cache, cache.generation, self._result, order.copy())
        return self._result

    def _local_scales(self, slot_count: int) -> np.ndarray:
        """s_i of every keyframe slot (consistency.local_scales on the local-window pairs),
        indexed by slot.

        A scan's s_i is the largest bound over its local pairs, whatever their order: while
        the local cache only grows (no drop), only the pairs appended since the last test are
        added to the bounds kept per slot, the same s_i at a cost that does not grow with the
        map. Per slot, so that a keyframe arriving out of stamp order (which shifts the ranks)
        does not start them over; the pairs it reshapes are dropped, which does.
        """
        local = self._local
        kept = self._local_bounds
        if (kept is None or kept[0] is not local or kept[1] != local.generation
                or kept[3].size > slot_count):
            start, largest = 0, np.full(slot_count, NO_BOUND)
        else:
            start, largest = kept[2], kept[3]
            if largest.size < slot_count:
                largest = np.concatenate([largest, np.full(slot_count - largest.size, NO_BOUND)])
        trimmed_sum, trimmed_count = local.robust()
        add_local_bounds(largest, local.pairs[start:], trimmed_sum[start:],
                         trimmed_count[start:], self.parameters)
        self._local_bounds = (local, local.generation, local.size, largest)
        return scales_from_bounds(largest, self.parameters)

    def _update_local(self, order: np.ndarray, new_ranks: np.ndarray) -> int:
        """Measures at the incremental poses of every pair within the local window."""
        required, appended = local_pair_keys(order, new_ranks, self.parameters.local_reach)
        if not appended:  # windows reshaped: the pairs that left them go
            self._local.retain(required)
            required = required[~np.isin(required, self._local.keys)]
        if required.size:
            self._local.insert(required, self._measure_keys(required, incremental=True))
        return int(required.size)


@numba.njit(cache=True)
def _clean_trajectory(stamps: np.ndarray, poses: np.ndarray, extent: float) -> bool:
    """Whether every pose is finite and within `extent` of the origin in x and y, and the
    stamps are finite and strictly increase: nothing to skip, sort or warn about."""
    previous = -np.inf
    for k in range(stamps.size):
        stamp, x, y = stamps[k], poses[k, 0], poses[k, 1]
        if not (np.isfinite(stamp) and np.isfinite(x) and np.isfinite(y)
                and np.isfinite(poses[k, 2])):
            return False
        if abs(x) > extent or abs(y) > extent or not stamp > previous:
            return False
        previous = stamp
    return True
