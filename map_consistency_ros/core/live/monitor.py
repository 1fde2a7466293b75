"""Incremental consistency state shared by the live node and offline bag replay.

Scans arrive with stamps and are buffered (bounded) until a trajectory names a pose with the
same stamp; the pair becomes a keyframe. Every trajectory is the SLAM back-end's full current
estimate. The monitor keeps, per keyframe:

- the current pose (for the map measures) and the incremental pose: the keyframe's first-seen
  pose relative to its predecessor in that same trajectory, chained onto the predecessor's
  incremental pose. Local scales (consistency.local_scales, eq. 10 of the paper) are fitted on
  pairs of temporally adjacent keyframes at their incremental poses, which a later loop closure
  never changes;
- cached pair measures (M_ij / n_ij, measure.py) at the current poses. When a trajectory moves
  poses (a loop closure), only pairs that involve moved or new keyframes are measured again,
  with candidates from a spatial index of the scans' extents.

Keyframes are identified by a stable slot (registration order); statistics run on keyframes in
stamp order. Not thread-safe: one thread owns a monitor.
"""
from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numba
import numpy as np

from map_consistency_ros.core.backend import (CONSTRAINT_WIDTH, PoseGraph, check_constraint_rows,
                                              split_constraint_rows)
# robust_sums: the pair cache trims each pair once, as evaluate_pairs would on every update
from map_consistency_ros.core.consistency import (ConsistencyParameters, ConsistencyResult,
                                                  evaluate_pairs, local_scales, robust_sums)
from map_consistency_ros.core.geometry import (SCAN_ARRAYS, PairMeasures, ScanExtentIndex, ScanSet,
                                               SensorModel, is_new_viewpoint, pair_measures, se2,
                                               with_rows)
from map_consistency_ros.core.parameters import Settings, parameter

# Below this many pairs the kernel runs on the calling thread alone: waking the OpenMP
# threads for a handful of pairs costs more than it saves; from about a hundred, two threads
# halve the time on an idle 2-core machine (bench/bench_monitor.py).
PARALLEL_MIN_PAIRS = 100
# Batches of at most this many pairs keep a live node's shutdown responsive during a large
# update (a loop closure, a burst of keyframes).
MEASURE_CHUNK = 1024
# Pair keys pack two slots into one int64 so that pair sets compare with np.isin / np.unique.
_SLOT_BITS = 31
# Partners of a new keyframe further apart than this many slots belong to different visits of
# its place (a pass through a place gives consecutive overlapping keyframes; a few may miss it).
_VISIT_GAP = 5
# A trajectory pose's slot: its keyframe's, or one of these.
_NO_SCAN = -1  # no scan registered for it (yet)
_FOLDED = -2  # its scan was folded into the previous viewpoint (core/viewpoints.py)


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
    cell_size: float = parameter(
        8.0, 'cell of the spatial index of scan extents, about a scan\'s extent', 'm',
        (0.1, 1000.0))
    max_pose_extent: float = parameter(
        1e5, 'poses with |x| or |y| beyond this are absurd: skipped and counted', 'm',
        (1.0, 1e9))
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
    dropped_scans: int = 0  # pushed out of the full buffer before a pose named them
    poses_without_scan: int = 0  # unmatched poses older than the newest scan: lost scans
    folded_scans: int = 0  # keyframes within a viewpoint's reach of the previous one, not tested
    estimate_stamp: float = math.nan  # the estimate these poses are (MonitorFeed.snapshot)

    @property
    def keyframe_count(self) -> int:
        return int(self.stamps.size)

    def scans(self) -> ScanSet:
        """The keyframes' scans placed at their current poses."""
        return ScanSet.from_ranges(self.ranges, sensor_poses(self.poses, self.laser_offset),
                                   self.model)


def sensor_poses(keyframe_poses: np.ndarray, laser_offset: np.ndarray) -> np.ndarray:
    """Poses of the laser for keyframe poses (N, 3) and the laser pose in the keyframe frame."""
    return se2.compose(keyframe_poses, np.broadcast_to(laser_offset, keyframe_poses.shape))


def _match(queries: np.ndarray, stamps: np.ndarray, tolerance: float,
           order: np.ndarray | None = None) -> np.ndarray:
    """Index of the stamp nearest to each query within `tolerance`, -1 where none; `order`:
    the stamps' stable argsort when the caller keeps it."""
    found = np.full(queries.size, -1, dtype=np.int64)
    if stamps.size == 0 or queries.size == 0:
        return found
    order = np.argsort(stamps, kind='stable') if order is None else order
    ordered = stamps[order]
    right = np.clip(np.searchsorted(ordered, queries), 0, ordered.size - 1)
    left = np.clip(right - 1, 0, ordered.size - 1)
    nearer = np.where(np.abs(ordered[left] - queries) < np.abs(ordered[right] - queries),
                      left, right)
    close = np.abs(ordered[nearer] - queries) <= tolerance
    found[close] = order[nearer[close]]
    return found


@contextmanager
def _threads_for(pair_count: int) -> Iterator[None]:
    """Run numba's parallel kernels on this thread alone for small batches."""
    if pair_count >= PARALLEL_MIN_PAIRS:
        yield
        return
    previous = numba.get_num_threads()
    numba.set_num_threads(1)  # thread-local: other threads keep their setting
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def _pair_keys(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    low, high = np.minimum(first, second), np.maximum(first, second)
    return (low.astype(np.int64) << _SLOT_BITS) | high.astype(np.int64)


def _key_slots(keys: np.ndarray) -> np.ndarray:
    return np.stack([keys >> _SLOT_BITS, keys & ((1 << _SLOT_BITS) - 1)], axis=1)


class _PairCache:
    """Pair measures of slot pairs (low, high) in growable arrays, insertion order, with each
    pair's trimmed (M_ij, n_ij) of the test, computed once when the pair is measured.

    An entry is never written once stored: inserts go past the end, and dropping entries or
    growing builds new arrays. So views of the first `size` entries stay valid for as long as
    anyone holds them, and a snapshot shares them instead of copying a million pairs.
    """

    def __init__(self, keep_largest: int, trim: int) -> None:
        self.size = 0
        self.generation = 0  # counts drops: between two drops entries are only appended
        # per slot, the first entry that can hold one of its pairs: the size when the slot's
        # pairs were first inserted (its later partners come later), 0 after a drop
        self._first_rows = np.zeros(0, dtype=np.int64)
        self._trim = trim
        self._pairs = np.zeros((64, 2), dtype=np.int64)
        self._distance_sum = np.zeros(64)
        self._point_count = np.zeros(64, dtype=np.int64)
        self._largest = np.zeros((64, keep_largest))
        self._trimmed_sum = np.zeros(64)
        self._trimmed_count = np.zeros(64, dtype=np.int64)

    @property
    def pairs(self) -> np.ndarray:
        return self._pairs[:self.size]

    @property
    def keys(self) -> np.ndarray:
        return _pair_keys(self.pairs[:, 0], self.pairs[:, 1])

    def _arrays(self) -> tuple[np.ndarray, ...]:
        return (self._pairs, self._distance_sum, self._point_count, self._largest,
                self._trimmed_sum, self._trimmed_count)

    def _keep(self, keep: np.ndarray) -> None:
        kept = int(np.count_nonzero(keep))
        self.generation += 1
        self._first_rows[:] = 0  # entries moved down
        (self._pairs, self._distance_sum, self._point_count, self._largest,
         self._trimmed_sum, self._trimmed_count) = (
            with_rows(array[:self.size][keep], array.shape[0]) for array in self._arrays())
        self.size = kept

    def retain(self, keys: np.ndarray) -> None:
        """Drop every entry whose key is not in `keys`."""
        self._keep(np.isin(self.keys, keys))

    def drop_slots(self, slots: np.ndarray, slot_count: int) -> None:
        """Drop every pair that involves one of `slots` (all below `slot_count`)."""
        if slots.size == 0:
            return
        hit = np.zeros(slot_count, dtype=bool)
        hit[slots] = True
        involved = hit[self.pairs[:, 0]] | hit[self.pairs[:, 1]]
        if involved.any():
            self._keep(~involved)

    def first_rows(self, slot_count: int) -> np.ndarray:
        """(slot_count,) no pair of slot s lies before entry first_rows[s]."""
        rows = np.zeros(slot_count, dtype=np.int64)
        known = min(slot_count, self._first_rows.size)
        rows[:known] = self._first_rows[:known]
        return rows

    def mark_new(self, slots: np.ndarray) -> None:
        """`slots` have no pair yet: theirs are all inserted from now on."""
        if slots.size and slots.max() >= self._first_rows.size:
            self._first_rows = with_rows(self._first_rows,
                                         max(int(slots.max()) + 1, 2 * self._first_rows.size))
        self._first_rows[slots] = self.size

    def insert(self, keys: np.ndarray, measures: PairMeasures) -> None:
        end = self.size + keys.size
        if end > self._pairs.shape[0]:
            capacity = max(2 * self._pairs.shape[0], end)
            (self._pairs, self._distance_sum, self._point_count, self._largest,
             self._trimmed_sum, self._trimmed_count) = (
                with_rows(array[:self.size], capacity) for array in self._arrays())
        self._pairs[self.size:end] = _key_slots(keys)
        self._distance_sum[self.size:end] = measures.distance_sum
        self._point_count[self.size:end] = measures.point_count
        self._largest[self.size:end] = measures.largest
        self._trimmed_sum[self.size:end], self._trimmed_count[self.size:end] = robust_sums(
            measures, self._trim)
        self.size = end

    def measures(self, rank_of_slot: np.ndarray | None) -> PairMeasures:
        """The cached pairs as PairMeasures over scan indices `rank_of_slot[slot]` (i < j);
        None means ranks are slots. Read-only views (see the class)."""
        if rank_of_slot is None:
            pairs = self.pairs
        else:  # each row (i, j) with i < j; sorting rows of two is many times slower
            first, second = rank_of_slot[self.pairs[:, 0]], rank_of_slot[self.pairs[:, 1]]
            pairs = np.stack([np.minimum(first, second), np.maximum(first, second)], axis=1)
        return PairMeasures(pairs=_read_only(pairs),
                            distance_sum=_read_only(self._distance_sum[:self.size]),
                            point_count=_read_only(self._point_count[:self.size]),
                            largest=_read_only(self._largest[:self.size]))

    def robust(self) -> tuple[np.ndarray, np.ndarray]:
        """The trimmed (M_ij, n_ij) of the cached pairs, in the order of `measures`."""
        return (_read_only(self._trimmed_sum[:self.size]),
                _read_only(self._trimmed_count[:self.size]))


class _Keyframes:
    """Growable per-keyframe arrays indexed by slot."""

    def __init__(self, beams: int) -> None:
        self.count = 0
        self.stamps = np.zeros(16)
        self.poses = np.zeros((16, 3))
        self.incremental = np.zeros((16, 3))
        self.ranges = np.zeros((16, beams))
        # whether a keyframe's pairs with earlier ones were thinned to the partner budget on
        # arrival (the kept pairs are the monitor's _kept_partners)
        self.budgeted = np.zeros(16, dtype=bool)
        # slots in stamp order, kept: every scan and every trajectory is matched against them
        self._order = np.zeros(0, dtype=np.int64)

    def append(self, stamp: float, pose: np.ndarray, incremental: np.ndarray,
               ranges: np.ndarray) -> int:
        if self.count == self.stamps.size:
            rows = 2 * self.count
            self.stamps, self.poses, self.incremental, self.ranges = (
                with_rows(array, rows)
                for array in (self.stamps, self.poses, self.incremental, self.ranges))
            self.budgeted = with_rows(self.budgeted, rows, fill=False)
        slot = self.count
        self.stamps[slot], self.poses[slot], self.incremental[slot] = stamp, pose, incremental
        self.ranges[slot] = ranges
        self.count += 1
        if self._order.size == slot and (slot == 0 or stamp >= self.stamps[self._order[-1]]):
            self._order = np.append(self._order, slot)  # the usual case: in stamp order
        else:
            self._order = np.argsort(self.stamps[:self.count], kind='stable')
        return slot

    def order(self) -> np.ndarray:
        """Slots in stamp order (read-only)."""
        return _read_only(self._order)

    def match(self, queries: np.ndarray, tolerance: float) -> np.ndarray:
        """The slot whose stamp is nearest to each query within `tolerance`, -1 where none."""
        return _match(queries, self.stamps[:self.count], tolerance, self._order)


class _Placement:
    """The world geometry (a ScanSet's arrays) of keyframe slots at one kind of pose, kept
    until a slot moves: an update then places only the scans it added or moved, where
    rebuilding every scan it touches was a quarter of its time."""

    def __init__(self) -> None:
        self._rows: dict[str, np.ndarray] = {}
        self._fresh = np.zeros(0, dtype=bool)
        self._model: SensorModel | None = None

    def invalidate(self, slots: np.ndarray) -> None:
        """Slots whose pose changed."""
        slots = np.asarray(slots, dtype=np.int64)
        self._fresh[slots[slots < self._fresh.size]] = False

    def scans(self, slots: np.ndarray, build: Callable[[np.ndarray], ScanSet]) -> ScanSet:
        """The scans of `slots`; `build(slots)` places the ones not yet (or no longer) kept."""
        slots = np.asarray(slots, dtype=np.int64)
        known = slots < self._fresh.size
        known[known] = self._fresh[slots[known]]
        missing = np.unique(slots[~known])
        if missing.size:
            self._store(missing, build(missing))
        return ScanSet.from_parts(self._model, **{name: rows[slots]
                                                  for name, rows in self._rows.items()})

    def _store(self, slots: np.ndarray, placed: ScanSet) -> None:
        self._model = placed.model
        needed = int(slots.max()) + 1
        if needed > self._fresh.size:
            capacity = max(needed, 2 * self._fresh.size, 16)
            for name in SCAN_ARRAYS:
                part = getattr(placed, name)
                self._rows[name] = with_rows(self._rows.get(name, part[:0]), capacity)
            self._fresh = with_rows(self._fresh, capacity)
        for name in SCAN_ARRAYS:
            self._rows[name][slots] = getattr(placed, name)
        self._fresh[slots] = True


def _same_model(a: SensorModel, b: SensorModel) -> bool:
    return (math.isclose(a.angle_min, b.angle_min, abs_tol=1e-9)
            and math.isclose(a.angle_increment, b.angle_increment, abs_tol=1e-12)
            and math.isclose(a.max_range, b.max_range, abs_tol=1e-9)
            and math.isclose(a.range_min, b.range_min, abs_tol=1e-9))


class ConsistencyMonitor:
    """Scans + the current trajectory -> an up-to-date consistency verdict, incrementally.

    Feed it with `add_scan` and `update_trajectory` (a late scan of an already published pose
    is registered by the next `update_trajectory` or by `refresh`); read it with `snapshot`.
    Bad input raises ValueError and leaves the state unchanged.
    """

    def __init__(self, parameters: ConsistencyParameters | None = None,
                 settings: MonitorSettings | None = None) -> None:
        self.parameters = parameters or ConsistencyParameters()
        self.settings = settings or MonitorSettings()
        self._offset = np.asarray(self.settings.laser_offset, dtype=np.float64)
        self._keep = max(self.parameters.trim_largest, 1)
        self._model: SensorModel | None = None
        self._buffer: OrderedDict[float, np.ndarray] = OrderedDict()
        self._keyframes: _Keyframes | None = None
        self._index = ScanExtentIndex(self.settings.cell_size)
        trim = self.parameters.trim_largest
        self._current = _PairCache(self._keep, trim)
        self._local = _PairCache(self._keep, trim)
        self._placed, self._placed_incremental = _Placement(), _Placement()
        self._path_stamps = np.zeros(0)
        self._path_poses = np.zeros((0, 3))
        # _path_slots at a keyframe count; a new trajectory clears it
        self._path_slots_of: tuple[tuple[int, int], np.ndarray] | None = None
        # stamps of the scans folded into their previous viewpoint, sorted
        self._folded = np.zeros(0)
        # pair keys kept by the partner budget of keyframes that exceeded it (sorted)
        self._kept_partners = np.zeros(0, dtype=np.int64)
        self._result: ConsistencyResult | None = None
        # the last result with rank == slot, its pair cache and the cache's generation then:
        # while the cache only grows, the next test starts from it
        self._tested_on: tuple[_PairCache, int, ConsistencyResult] | None = None
        self._last = UpdateSummary()
        self._unmatched = 0
        self._constraints = np.zeros((0, CONSTRAINT_WIDTH))
        self.dropped_scans = 0  # pushed out of the full buffer
        self._newest_scan = -math.inf

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

        NaN / inf beams are kept (they count as free space up to max range). Raises ValueError
        for a non-finite stamp, fewer than 2 beams, beams overlapping past 2 pi, a beam geometry
        that differs from the first scan's, or a stamp already registered as a keyframe.
        """
        stamp = float(stamp)
        ranges = np.asarray(ranges, dtype=np.float64)
        if not math.isfinite(stamp):
            raise ValueError(f'scan stamp must be finite, got {stamp}')
        if ranges.ndim != 1 or ranges.size == 0:
            raise ValueError(f'a scan needs a non-empty 1-D range array, got shape {ranges.shape}')
        model.check_beam_count(ranges.size)
        if self._model is None:
            self._model = model
            self._keyframes = _Keyframes(ranges.size)
        elif not _same_model(model, self._model) or ranges.size != self._keyframes.ranges.shape[1]:
            raise ValueError(
                f'scan at {stamp:.6f} has {ranges.size} beams from {model.angle_min:.6g} rad '
                f'by {model.angle_increment:.6g} rad (max range {model.max_range:g}); the monitor '
                f'takes only scans like the first ({self._keyframes.ranges.shape[1]} beams from '
                f'{self._model.angle_min:.6g} by {self._model.angle_increment:.6g}, max range '
                f'{self._model.max_range:g})')
        if self._registered_slot(stamp) is not None or self._is_folded(stamp):
            raise ValueError(f'scan at {stamp:.6f} duplicates a registered keyframe; ignored')
        self._buffer[stamp] = ranges
        self._newest_scan = max(self._newest_scan, stamp)
        while len(self._buffer) > self.settings.max_buffered_scans:
            self._buffer.pop(min(self._buffer))
            self.dropped_scans += 1

    def pose_problem(self, pose: np.ndarray) -> str:
        """Why a single pose (3,) is unusable ('' when it is usable)."""
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (3,) or not np.isfinite(pose).all():
            return f'non-finite values or an unusable quaternion ({pose.tolist()})'
        if np.abs(pose[:2]).max() > self.settings.max_pose_extent:
            return f'beyond max_pose_extent = {self.settings.max_pose_extent:g} m'
        return ''

    @property
    def pending(self) -> bool:
        """Whether buffered scans match poses of the last trajectory (call `refresh`)."""
        unmatched = self._path_stamps[self._path_slots() == _NO_SCAN]
        return bool(unmatched.size and np.isfinite(self._buffer_matches(unmatched)).any())

    def update_trajectory(self, stamps: np.ndarray, poses: np.ndarray) -> UpdateSummary:
        """Take the back-end's full current estimate: register, move, measure, test.

        `stamps` (M,) seconds and `poses` (M, 3). Poses with non-finite values or a duplicated
        stamp are skipped with a warning in the summary. Raises ValueError when the arrays do
        not have those shapes.
        """
        stamps = np.asarray(stamps, dtype=np.float64)
        poses = np.asarray(poses, dtype=np.float64)
        if stamps.ndim != 1 or poses.shape != (stamps.size, 3):
            raise ValueError(f'a trajectory needs stamps (M,) and poses (M, 3), got shapes '
                             f'{stamps.shape} and {poses.shape}')
        warnings = []
        finite = np.isfinite(stamps) & np.isfinite(poses).all(axis=1)
        if not finite.all():
            warnings.append(f'{int((~finite).sum())} trajectory poses with non-finite values '
                            '(or an unusable quaternion) skipped')
        with np.errstate(invalid='ignore'):
            absurd = finite & (np.abs(poses[:, :2]) > self.settings.max_pose_extent).any(axis=1)
        if absurd.any():
            warnings.append(f'{int(absurd.sum())} trajectory poses beyond max_pose_extent = '
                            f'{self.settings.max_pose_extent:g} m skipped')
        finite &= ~absurd
        stamps, poses = stamps[finite], poses[finite]
        order = np.argsort(stamps, kind='stable')
        stamps, poses = stamps[order], poses[order]
        duplicate = np.zeros(stamps.size, dtype=bool)
        duplicate[1:] = np.diff(stamps) <= 0.0
        if duplicate.any():
            warnings.append(f'{int(duplicate.sum())} trajectory poses with a duplicated stamp '
                            'skipped (the first is kept)')
        self._path_stamps, self._path_poses = stamps[~duplicate], poses[~duplicate]
        self._path_slots_of = None
        return self._apply_path(tuple(warnings))

    def refresh(self) -> UpdateSummary:
        """Register late scans against the last trajectory (a no-op when nothing is pending)."""
        return self._apply_path(())

    def recompute(self) -> UpdateSummary:
        """Measure every pair again from scratch (the incremental caches are rebuilt)."""
        start = time.perf_counter()
        self._index = ScanExtentIndex(self.settings.cell_size)
        trim = self.parameters.trim_largest
        self._current = _PairCache(self._keep, trim)
        self._local = _PairCache(self._keep, trim)
        self._placed, self._placed_incremental = _Placement(), _Placement()
        self._kept_partners = np.zeros(0, dtype=np.int64)  # chosen again on the current poses
        if self._keyframes is not None:
            self._keyframes.budgeted[:] = False
        slots = np.arange(self.keyframe_count)
        measured = self._measure(slots, slots) if slots.size else 0
        self._last = UpdateSummary(moved_keyframes=int(slots.size), measured_pairs=measured,
                                   unmatched_poses=self._unmatched,
                                   elapsed=time.perf_counter() - start)
        return self._last

    def set_constraints(self, rows: np.ndarray) -> None:
        """The pose-graph edges for DCS retuning, replacing the previous set.

        Rows `[stamp_from, stamp_to, dx, dy, dtheta, I11, I12, I13, I22, I23, I33]` (stamps in
        seconds, upper triangle of the information matrix). Raises ValueError on a wrong shape,
        non-finite values, an edge from a stamp to itself, or an information matrix that is not
        symmetric positive definite.
        """
        rows = check_constraint_rows(rows)
        self._constraints = rows.copy()

    @property
    def constraints(self) -> np.ndarray:
        """The last accepted constraint rows (E, 11)."""
        return self._constraints

    # -- output ------------------------------------------------------------------------------

    def pose_graph(self) -> PoseGraph | None:
        """Keyframes (stamp order, first one fixed) and the constraints between them.

        Constraint rows whose stamps match no keyframe are left out. None when there are fewer
        than two keyframes or no constraint connects two keyframes.
        """
        if self.keyframe_count < 2 or self._constraints.shape[0] == 0:
            return None
        keyframes = self._keyframes
        order = keyframes.order()
        stamps = keyframes.stamps[order]
        rows = self._constraints
        tolerance = self.settings.stamp_tolerance
        stamp_from, stamp_to, measurements, information = split_constraint_rows(rows)
        edge_from, edge_to = (_match(stamp_from, stamps, tolerance),
                              _match(stamp_to, stamps, tolerance))
        known = (edge_from >= 0) & (edge_to >= 0) & (edge_from != edge_to)
        if not known.any():
            return None
        fixed = np.zeros(stamps.size, dtype=bool)
        fixed[0] = True
        return PoseGraph(poses=keyframes.poses[order], edge_from=edge_from[known],
                         edge_to=edge_to[known], measurements=measurements[known],
                         information=information[known], fixed=fixed)

    def snapshot(self) -> MonitorSnapshot:
        """Copies of the keyframes in stamp order and the last verdict."""
        if self._keyframes is None:
            empty = np.zeros((0, 3))
            return MonitorSnapshot(ids=np.zeros(0, dtype=np.int64), stamps=np.zeros(0),
                                   poses=empty, incremental_poses=empty, ranges=np.zeros((0, 0)),
                                   model=self._model, laser_offset=self._offset.copy(),
                                   result=None, buffered_scans=len(self._buffer),
                                   unmatched_poses=self._unmatched, last_update=self._last,
                                   **self._loss())
        keyframes = self._keyframes
        order = keyframes.order()
        if np.array_equal(order, np.arange(keyframes.count)):
            # A slot's ranges never change once registered: a read-only view is a snapshot,
            # and copying every scan on every update would grow with the map.
            ranges = _read_only(keyframes.ranges[:keyframes.count])
        else:
            ranges = keyframes.ranges[order]
        return MonitorSnapshot(
            ids=order.astype(np.int64), stamps=keyframes.stamps[order],
            poses=keyframes.poses[order], incremental_poses=keyframes.incremental[order],
            ranges=ranges, model=self._model,
            laser_offset=self._offset.copy(), result=self._evaluate(),
            buffered_scans=len(self._buffer), unmatched_poses=self._unmatched,
            last_update=self._last, **self._loss())

    def _loss(self) -> dict[str, int]:
        # Scans arrive in stamp order: a pose older than the newest scan and still without
        # one names a scan that was lost (or refused).
        unmatched = self._path_stamps[self._path_slots() == _NO_SCAN]
        late = unmatched < self._newest_scan - self.settings.stamp_tolerance
        return dict(dropped_scans=self.dropped_scans,
                    poses_without_scan=int(np.count_nonzero(late)),
                    folded_scans=int(self._folded.size))

    # -- bookkeeping -------------------------------------------------------------------------

    def _is_folded(self, stamp: float) -> bool:
        return bool(_match(np.array([stamp]), self._folded, self.settings.stamp_tolerance,
                           np.arange(self._folded.size))[0] >= 0)

    def _registered_slot(self, stamp: float) -> int | None:
        if self.keyframe_count == 0:
            return None
        slot = int(self._keyframes.match(np.array([stamp]), self.settings.stamp_tolerance)[0])
        return slot if slot >= 0 else None

    def _buffer_matches(self, stamps: np.ndarray) -> np.ndarray:
        """For each stamp, the matching buffered scan's stamp, NaN where none."""
        buffered = np.fromiter(self._buffer, dtype=np.float64, count=len(self._buffer))
        found = _match(stamps, buffered, self.settings.stamp_tolerance)
        return np.where(found >= 0, buffered[np.maximum(found, 0)] if buffered.size else np.nan,
                        np.nan)

    def _path_slots(self) -> np.ndarray:
        """For each pose of the last trajectory, its keyframe slot, _FOLDED or _NO_SCAN (a
        copy: callers fill in slots they register)."""
        count = self.keyframe_count
        state = (count, self._folded.size)
        if self._path_slots_of is None or self._path_slots_of[0] != state:
            # kept: the node asks on every scan whether one is pending
            slots = (np.full(self._path_stamps.size, _NO_SCAN, dtype=np.int64) if count == 0
                     else self._keyframes.match(self._path_stamps,
                                                self.settings.stamp_tolerance))
            if count:
                slots[_claimed_twice(slots, self._path_stamps, self._keyframes.stamps)] = _NO_SCAN
            if self._folded.size:
                folded = _match(self._path_stamps, self._folded, self.settings.stamp_tolerance,
                                np.arange(self._folded.size)) >= 0
                slots[folded & (slots == _NO_SCAN)] = _FOLDED
            self._path_slots_of = (state, slots)
        return self._path_slots_of[1].copy()

    def _apply_path(self, warnings: tuple[str, ...]) -> UpdateSummary:
        start = time.perf_counter()
        path_slots = self._path_slots()
        moved = self._move_keyframes(path_slots)
        new = self._register(path_slots)
        self._unmatched = int(np.count_nonzero(self._path_slots() == _NO_SCAN))
        changed = np.union1d(moved, new).astype(np.int64)
        measured = self._measure(changed, new) if changed.size else 0
        self._last = UpdateSummary(new_keyframes=int(new.size), moved_keyframes=int(moved.size),
                                   measured_pairs=measured, unmatched_poses=self._unmatched,
                                   elapsed=time.perf_counter() - start, warnings=warnings)
        return self._last

    def _move_keyframes(self, path_slots: np.ndarray) -> np.ndarray:
        known = path_slots >= 0
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
        unregistered = np.flatnonzero(path_slots == _NO_SCAN)
        matches = self._buffer_matches(self._path_stamps[unregistered])
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
            if not self._new_viewpoint(index, earlier):
                self._buffer.pop(float(buffered))
                folded.append(float(buffered))
                path_slots[index] = _FOLDED
                continue
            pose = self._path_poses[index]
            anchor = earlier if earlier >= 0 else later
            incremental = self._incremental_pose(index, anchor, path_slots)
            scan = self._buffer.pop(float(buffered))
            slot = self._keyframes.append(float(buffered), pose, incremental, scan)
            path_slots[index] = slot
            registered = int(index)
            new.append(slot)
        if folded:
            self._folded = np.sort(np.concatenate([self._folded, folded]))
        return np.asarray(new, dtype=np.int64)

    def _new_viewpoint(self, index: int, earlier: int) -> bool:
        """Whether pose `index` of the trajectory is a viewpoint: far enough from the nearest
        earlier keyframe of the trajectory, pose `earlier` (core/viewpoints.py). A pose with
        no earlier keyframe (-1: the first, or a late first scan) always is."""
        if earlier < 0:
            return True
        # the laser's travel, as check measures it on a log's laser poses
        laser = sensor_poses(self._path_poses[[earlier, index]], self._offset)
        step = se2.relative(laser[0], laser[1])
        return is_new_viewpoint(step, self.parameters.viewpoint_spacing,
                                self.parameters.viewpoint_turn)

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
        pairs = _key_slots(keys)
        involved = np.unique(pairs)
        scans = self._scans(involved, incremental)
        local = np.searchsorted(involved, pairs)
        parts = []
        for start in range(0, len(local), MEASURE_CHUNK):
            chunk = local[start:start + MEASURE_CHUNK]
            with _threads_for(len(chunk)):
                parts.append(pair_measures(scans, chunk, keep_largest=self._keep))
        return PairMeasures(*(np.concatenate([getattr(part, name) for part in parts])
                              for name in ('pairs', 'distance_sum', 'point_count', 'largest')))

    def _measure(self, changed: np.ndarray, new: np.ndarray) -> int:
        """Measure pairs touching `changed` slots (`new` among them), update the local
        measures; the tests run when the next snapshot is taken."""
        keyframes = self._keyframes
        placed = self._scans(changed)
        self._index.update(changed, placed.extents)
        # new keyframes have no pairs yet: only moved ones lose theirs (a test over every pair)
        self._current.drop_slots(np.setdiff1d(changed, new), keyframes.count)
        self._current.mark_new(new)
        touching = self._within_budget(self._index.pairs_touching(changed), new)
        keys = np.unique(_pair_keys(touching[:, 0], touching[:, 1]))
        measured = 0
        if keys.size:
            measures = self._measure_keys(keys)
            keep = measures.point_count > 0  # pairs without points carry no evidence
            self._current.insert(keys[keep], _subset(measures, keep))
            measured += int(keys.size)
        order = keyframes.order()
        measured += self._update_local(order, _rank_of_slot(order)[new])
        self._result = None  # the statistics run once per snapshot, not per update
        return measured

    def _within_budget(self, pairs: np.ndarray, new: np.ndarray) -> np.ndarray:
        """The pairs (i, j), i < j slots, the budget of j keeps: with every earlier slot, or,
        when more than `max_partners` overlapped j on arrival, with the nearest keyframes of
        each earlier visit of its place (_nearest_of_each_visit), chosen then so that moves
        re-measure the same pairs. Every visit keeps pairs, so the failures of a revisit
        show whatever the budget; the local scales have pairs of their own (_update_local)."""
        budget, keyframes = self.settings.max_partners, self._keyframes
        if budget and new.size and pairs.size:
            later = pairs[:, 1]
            counts = np.bincount(later, minlength=keyframes.count)
            crowded = new[counts[new] > budget]
            if crowded.size:
                kept = [self._nearest_of_each_visit(pairs[later == slot, 0], slot, budget)
                        for slot in crowded]
                keyframes.budgeted[crowded] = True
                self._kept_partners = _sorted_insert(self._kept_partners, np.concatenate(kept))
        budgeted = keyframes.budgeted[pairs[:, 1]]
        if not budgeted.any():
            return pairs
        keep = ~budgeted
        keep[budgeted] = _sorted_contains(self._kept_partners,
                                          _pair_keys(pairs[budgeted, 0], pairs[budgeted, 1]))
        return pairs[keep]

    def _nearest_of_each_visit(self, partners: np.ndarray, slot: int, budget: int
                               ) -> np.ndarray:
        """Pair keys of `slot` with the nearest of its earlier `partners` in each visit: runs
        of partners at most _VISIT_GAP slots apart (one pass through the place) share the
        budget evenly, at least one pair each."""
        partners = np.unique(partners)
        starts = np.concatenate([[0], np.flatnonzero(np.diff(partners) > _VISIT_GAP) + 1])
        visit = np.zeros(partners.size, dtype=np.int64)
        visit[starts[1:]] = 1
        visit = np.cumsum(visit)
        quota = max(budget // starts.size, 1)
        laser = sensor_poses(self._keyframes.poses[np.append(partners, slot)], self._offset)
        distance = np.hypot(*(laser[:-1, :2] - laser[-1, :2]).T)
        order = np.lexsort((distance, visit))  # by visit, nearest first
        rank = np.empty(partners.size, dtype=np.int64)
        rank[order] = np.arange(partners.size) - starts[visit[order]]
        chosen = partners[rank < quota]
        return _pair_keys(chosen, np.full(chosen.size, slot))

    def _evaluate(self) -> ConsistencyResult | None:
        """The test on the current measures (computed at most once per change).

        The statistics cover every pair of the map; a burst of updates (a Path with late
        scans, a node catching up) costs one evaluation when its snapshot is taken. While
        keyframes only arrive in stamp order and none moved, only the new pairs and those of
        scans whose scale changed are tested again (evaluate_pairs' `previous`).
        """
        if self._result is None and self.keyframe_count:
            keyframes = self._keyframes
            order = keyframes.order()
            # Keyframes that arrived in stamp order have rank == slot: no re-indexing.
            in_order = np.array_equal(order, np.arange(keyframes.count))
            ranks = None if in_order else _rank_of_slot(order)
            scales = local_scales(self._local.measures(ranks), keyframes.count, self.parameters,
                                  robust=self._local.robust())
            cache, previous = self._current, None
            if in_order and self._tested_on is not None:
                tested_cache, generation, tested = self._tested_on
                if tested_cache is cache and generation == cache.generation:
                    previous = tested
            self._result = evaluate_pairs(cache.measures(ranks), scales, keyframes.count,
                                          self.parameters, robust=cache.robust(),
                                          previous=previous,
                                          first_rows=cache.first_rows(keyframes.count))
            self._tested_on = (cache, cache.generation, self._result) if in_order else None
        return self._result

    def _update_local(self, order: np.ndarray, new_ranks: np.ndarray) -> int:
        """Measures at the incremental poses of every pair within the local window."""
        half = self.parameters.local_reach
        count = order.size
        appended = new_ranks.size == 0 or new_ranks.min() >= count - new_ranks.size
        # Keyframes appended in stamp order only add pairs; an insertion reshapes windows.
        ranks = np.arange(count - new_ranks.size if appended else 0, count)
        second = np.repeat(ranks, half)
        first = second - np.tile(np.arange(1, half + 1), ranks.size)
        inside = first >= 0
        required = np.unique(_pair_keys(order[first[inside]], order[second[inside]]))
        if not appended:
            self._local.retain(required)
            required = required[~np.isin(required, self._local.keys)]
        if required.size:
            self._local.insert(required, self._measure_keys(required, incremental=True))
        return int(required.size)


def _read_only(array: np.ndarray) -> np.ndarray:
    view = array.view()
    view.setflags(write=False)
    return view


def _claimed_twice(slots: np.ndarray, stamps: np.ndarray, slot_stamps: np.ndarray
                   ) -> np.ndarray:
    """Poses that lose their keyframe slot to a pose nearer its stamp.

    Two poses within the stamp tolerance of one keyframe (scans stamped microseconds apart)
    would both move it, to two places, on every update; the nearest keeps it (the first of
    equals), the others are poses without a keyframe (their own scan is matched or folded).
    """
    matched = np.flatnonzero(slots >= 0)
    losing = np.zeros(slots.size, dtype=bool)
    if matched.size < 2:
        return losing
    offset = np.abs(stamps[matched] - slot_stamps[slots[matched]])
    order = np.lexsort((matched, offset, slots[matched]))  # by slot, nearest first
    repeated = np.zeros(order.size, dtype=bool)
    repeated[1:] = slots[matched[order[1:]]] == slots[matched[order[:-1]]]
    losing[matched[order[repeated]]] = True
    return losing


def _sorted_insert(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """`sorted_keys` with the `keys` it lacks, sorted: a merge, so that a keyframe's
    arrival costs its own keys and a copy, not a sort of every key of the map."""
    keys = np.unique(keys)
    keys = keys[~_sorted_contains(sorted_keys, keys)]
    return np.insert(sorted_keys, np.searchsorted(sorted_keys, keys), keys)


def _sorted_contains(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Whether each of `keys` is in `sorted_keys` (binary search: no pass over the map)."""
    where = np.searchsorted(sorted_keys, keys)
    inside = where < sorted_keys.size
    found = np.zeros(keys.shape, dtype=bool)
    found[inside] = sorted_keys[where[inside]] == keys[inside]
    return found


def _rank_of_slot(order: np.ndarray) -> np.ndarray:
    """The stamp-order rank of every slot, from the slots in stamp order."""
    ranks = np.empty(order.size, dtype=np.int64)
    ranks[order] = np.arange(order.size)
    return ranks


def _subset(measures: PairMeasures, keep: np.ndarray) -> PairMeasures:
    return PairMeasures(pairs=measures.pairs[keep], distance_sum=measures.distance_sum[keep],
                        point_count=measures.point_count[keep], largest=measures.largest[keep])

