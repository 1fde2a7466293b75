"""One feed from input records to the ConsistencyMonitor, inside the live pipeline that the node,
bag replay and the warm-up share (core/live/pipeline.py).

`MonitorFeed.apply(record)` is the only way records reach a monitor; it returns what the
record did, including every warning, so the node and replay report the same problems.

- `Scan`: buffered by the monitor until a keyframe names it, or, with single poses, by the
  keyframer until poses bracket it. Scans also drive the loss count (stamp gaps, see
  `ScanGaps`) and the automatic reset: RESET_CONFIRMATIONS scans in a row stamped more than
  `reset_stamp_jump` seconds before the newest one mean the SLAM stack restarted or the bag
  looped (one stray old stamp must not wipe the map: such scans are held until confirmed,
  and skipped with a warning once RESET_CONFIRMATIONS scans of the current session in a row
  follow; a stray that comes just before the new session's scans is skipped too, and the
  session confirmed by its own scans: `_session_start`).
- `KeyframeEstimate`: the back-end's full keyframe estimate (a Path, or the output of a bridge
  from a SLAM stack's own graph messages: apply its keyframe stamps and poses here).
- `PoseSample`: one pose of a single-pose topic; `PoseKeyframer` interpolates each scan's pose
  and selects keyframes by travelled distance / turned angle, as a SLAM front end would.
- `Constraints`: the pose-graph edges for DCS retuning.
- `DroppedScans`: scans received but never applied (a full queue, unreadable messages), so
  that the account of every scan received (`scan_counts`, core/live/_scan_counts.py) holds
  them too.
- With `pose_source: slam_toolbox`, `PoseSample`s (slam_toolbox's `pose`, one per accepted
  scan) and `GraphSnapshot`s (its graph_visualization markers) go to the SlamToolboxBridge
  (core/live/_graph_bridge.py); after each snapshot the bridge's keyframes are applied as a
  keyframe estimate.
- With `pose_source: slam_toolbox_graph`, `NodeEvent`s, `LoopClosure`s and `PoseGraphNodes`
  (slam_toolbox's pose-graph interface) go to the PoseGraphBridge (core/live/_pose_graph_bridge.py);
  after each, unless the bridge waits for the graph of a loop closure, its keyframes are
  applied as a keyframe estimate.

`estimate_stamp` names the estimate the monitor's map holds, so that a verdict says which one
it judged (the node's ~/report and replay's report, `judged_stamp`): at the last change of the
map, the newest estimate taken, by its header stamp, or, for estimates without one (single
poses, graph snapshots), its newest keyframe's stamp. A scan that completes a keyframe of that
estimate later changes the map under the same name; an estimate that changes nothing renames
nothing. The live pipeline's snapshot (`LivePipeline.evaluate`, core/live/pipeline.py)
carries it.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.live._graph_bridge import BridgeCounts, SlamToolboxBridge
from map_consistency_ros.core.live._pose_graph_bridge import PoseGraphBridge, PoseGraphCounts
from map_consistency_ros.core.live._records import (Constraints, DroppedScans, GraphSnapshot,
                                                    KeyframeEstimate, LoopClosure, NodeEvent,
                                                    PoseGraphNodes, PoseSample, Record, Scan)
from map_consistency_ros.core.live._scan_counts import ScanCounts
from map_consistency_ros.core.live.monitor import (ConsistencyMonitor, MonitorSettings,
                                                   UpdateSummary)
from map_consistency_ros.core.parameters import Choice, Settings, parameter


class PoseSource(Choice):
    """Where keyframe poses come from (FeedSettings.pose_source; io/messages.py maps each to
    the message type of its topic)."""

    PATH = 'path'
    ODOMETRY = 'odometry'
    POSE = 'pose'
    POSE_WITH_COVARIANCE = 'pose_with_covariance'
    SLAM_TOOLBOX = 'slam_toolbox'
    SLAM_TOOLBOX_GRAPH = 'slam_toolbox_graph'


POSE_SOURCES = tuple(PoseSource)
# Sources whose single poses are keyframed by travel; slam_toolbox's poses go to its bridge.
KEYFRAMED_SOURCES = (PoseSource.ODOMETRY, PoseSource.POSE, PoseSource.POSE_WITH_COVARIANCE)
# A stamp gap longer than this many median scan periods counts the scans it must have held;
# drivers stamp regularly, but keyframe-only logs do not, so the count is an estimate.
_GAP_PERIODS = 2.5
_PERIOD_SAMPLES = 64
# No 2D laser scans faster than 1 kHz: stamps closer than this are one scan published twice or
# re-stamped, not a period (a median period of microseconds would count a normal 0.1 s
# interval as thousands of lost scans).
_SHORTEST_PERIOD = 1e-3
# Recent intervals whose 90th percentile is within this factor of their 10th are a steady rate
# (a driver's jitter stays well inside it).
_STEADY_SPREAD = 2.0
RESET_CONFIRMATIONS = 5


@dataclass(frozen=True)
class FeedSettings(Settings):
    """How input messages become keyframes."""

    pose_source: PoseSource = parameter(
        PoseSource.PATH, 'where keyframe poses come from: a keyframe Path on `trajectory`; single '
        'poses on `pose` (Odometry, PoseStamped, PoseWithCovarianceStamped), keyframed by '
        'travel; slam_toolbox: its `pose` (one per accepted scan) and its graph markers on '
        '`graph_visualization`, headings recovered from positions (releases without a pose '
        'graph topic); or slam_toolbox_graph: its node events, loop-closure events and pose '
        'graph (slam_toolbox with pull request 818), full headings; docs/slam_bridges.md',
        choices=PoseSource)
    max_range: float = parameter(
        8.0, 'usable laser range, capped by each scan\'s range_max; longer or invalid beams '
        'count as free space', 'm', (0.1, 1000.0))
    keyframe_distance: float = parameter(
        0.5, 'single poses: a scan becomes a keyframe after this much travel', 'm',
        (0.0, 1000.0))
    keyframe_angle: float = parameter(
        0.25, 'single poses: a scan becomes a keyframe after this much turning', 'rad',
        (0.0, 6.3))
    reset_stamp_jump: float = parameter(
        1.0, 'a scan stamped this much before the newest one resets the monitor (a restarted '
        'SLAM stack, a looped bag); 0: never', 's', (0.0, 1e9))

    @property
    def single_poses(self) -> bool:
        """Whether single poses are keyframed by travel (PoseKeyframer)."""
        return self.pose_source in KEYFRAMED_SOURCES

    @property
    def slam_toolbox(self) -> bool:
        """Whether poses and graph snapshots go to the slam_toolbox bridge."""
        return self.pose_source == PoseSource.SLAM_TOOLBOX

    @property
    def slam_toolbox_graph(self) -> bool:
        """Whether node events, loop closures and pose graphs go to the pose-graph bridge."""
        return self.pose_source == PoseSource.SLAM_TOOLBOX_GRAPH


class PoseKeyframer:
    """Keyframes from single-pose messages and the scans between them.

    Each scan takes the pose interpolated at its stamp between the two pose messages around
    it (scans outside the pose stream are dropped and counted in `unplaced`). A scan becomes a
    keyframe when the robot has moved `min_distance` metres or turned `min_angle` radians since
    the last keyframe (the others are counted in `passed_over`). `add_pose` returns the scans
    that became keyframes; every scan added is pending (`waiting`), returned or counted.
    """

    def __init__(self, min_distance: float, min_angle: float, history: int = 256) -> None:
        if not (min_distance >= 0.0 and min_angle >= 0.0):
            raise ValueError('keyframe distance and angle must not be negative')
        self.min_distance = min_distance
        self.min_angle = min_angle
        self._pending: deque[Scan] = deque()
        self._poses: deque[tuple[float, np.ndarray]] = deque(maxlen=history)
        self._last: np.ndarray | None = None
        self.stamps: list[float] = []
        self.poses: list[np.ndarray] = []
        self.unplaced = 0  # no pose before or around their stamps
        self.passed_over = 0  # the robot had not moved far enough since the last keyframe

    @property
    def waiting(self) -> int:
        """Scans held until a pose at or after their stamps arrives."""
        return len(self._pending)

    def add_scan(self, scan: Scan) -> None:
        """Hold a scan until a pose at or after its stamp arrives (`add_pose`).

        Parameters
        ----------
        scan: the scan, in stamp order with the others.
        """
        self._pending.append(scan)

    def add_pose(self, sample: PoseSample) -> list[Scan]:
        """Place the scans the new pose brackets.

        Parameters
        ----------
        sample: the next pose, stamped later than the previous one (else ValueError).

        Returns
        -------
        The held scans that became keyframes, in stamp order; their stamps and poses are
        appended to `stamps` and `poses`.
        """
        if self._poses and sample.stamp <= self._poses[-1][0]:
            raise ValueError(f'pose at {sample.stamp:.6f} is not later than the previous one')
        self._poses.append((sample.stamp, sample.pose))
        keyframes = []
        while self._pending and self._pending[0].stamp <= sample.stamp:
            scan = self._pending.popleft()
            pose = self._interpolate(scan.stamp)
            if pose is None:
                self.unplaced += 1
            elif self._is_keyframe(pose):
                self._last = pose
                self.stamps.append(scan.stamp)
                self.poses.append(pose)
                keyframes.append(scan)
            else:
                self.passed_over += 1
        return keyframes

    def _interpolate(self, stamp: float) -> np.ndarray | None:
        stamps = np.fromiter((entry[0] for entry in self._poses), dtype=np.float64)
        after = int(np.searchsorted(stamps, stamp))
        if after == len(stamps) or (after == 0 and stamps[0] != stamp):
            return None
        if stamps[after] == stamp:
            return self._poses[after][1]
        (start, first), (end, second) = self._poses[after - 1], self._poses[after]
        fraction = (stamp - start) / (end - start)
        step = se2.relative(first, second)
        return se2.compose(first, fraction * step)

    def _is_keyframe(self, pose: np.ndarray) -> bool:
        if self._last is None:
            return True
        distance = math.hypot(pose[0] - self._last[0], pose[1] - self._last[1])
        turn = abs(float(se2.wrap_angle(pose[2] - self._last[2])))
        return distance >= self.min_distance or turn >= self.min_angle


def _percentiles(ordered: list[float], fractions: tuple[float, ...]) -> list[float]:
    """np.percentile's linear interpolation on a short sorted list, without numpy's call
    overhead (tens of microseconds, paid on every scan).

    Parameters
    ----------
    ordered: the sample, sorted ascending, not empty.
    fractions: the quantiles wanted, each in [0, 1].

    Returns
    -------
    The quantiles, in the order of `fractions`.
    """
    last = len(ordered) - 1
    values = []
    for fraction in fractions:
        position = fraction * last
        below = min(int(position), last)
        above = min(below + 1, last)
        weight = position - below
        a, b = ordered[below], ordered[above]
        # numpy's _lerp: from the nearer end, so that a weight of 1 gives b exactly
        values.append(a + (b - a) * weight if weight < 0.5 else b - (b - a) * (1.0 - weight))
    return values


class ScanGaps:
    """Scans that never arrived, counted from gaps in the scan stamps.

    ROS 2 headers carry no sequence number; the scan period is the median of recent stamp
    differences, and a gap of more than 2.5 periods holds round(gap / period) - 1 lost scans.
    An estimate (a log of keyframes only has irregular stamps): reported, not warned about.
    """

    def __init__(self) -> None:
        self._last: float | None = None
        self._intervals: deque[float] = deque(maxlen=_PERIOD_SAMPLES)
        self.missing = 0

    def add(self, stamp: float) -> int:
        """Record one scan stamp.

        Parameters
        ----------
        stamp: the scan's stamp, seconds.

        Returns
        -------
        The number of scans missing just before it (0 unless the rate is steady and the gap
        long); added to `missing`.
        """
        missing = 0
        if self._last is not None and stamp > self._last:
            interval = stamp - self._last
            if len(self._intervals) >= 8:
                low, period, high = _percentiles(sorted(self._intervals), (0.1, 0.5, 0.9))
                # only a driver's steady rate has a period: stamps in bursts (a rebuilt log, a
                # bag of relayed scans) would count every pause as thousands of lost scans
                steady = high <= _STEADY_SPREAD * low
                if steady and period > 0.0 and interval > _GAP_PERIODS * period:
                    missing = int(round(interval / period)) - 1
            if missing == 0 and interval >= _SHORTEST_PERIOD:
                self._intervals.append(interval)  # gaps would inflate the period
        if self._last is None or stamp > self._last:
            self._last = stamp
        self.missing += missing
        return missing


def _session_start(held: list[Scan], jump: float) -> int:
    """Where a new session begins among scans held after a jump back in stamps.

    A stray old scan (a late one of the ending session) may come just before a restarted
    SLAM stack's first scans: those then jump back from it as they jumped back from the
    session. The new session is the longest tail of `held` in which no scan is stamped more
    than `jump` before an earlier one of the tail; the scans before it are strays.

    Parameters
    ----------
    held: the held scans, in arrival order.
    jump: reset_stamp_jump, seconds (positive).

    Returns
    -------
    The index in `held` of the new session's first scan (0: no stray).
    """
    first, oldest_after = len(held), math.inf
    for index in range(len(held) - 1, -1, -1):
        # held[index:] is jump-free when held[index + 1:] is and no scan of it jumps back
        # from held[index]
        stamp = held[index].stamp
        if oldest_after < stamp - jump:
            break
        first, oldest_after = index, min(oldest_after, stamp)
    return first


@dataclass(frozen=True)
class Applied:
    """What one record did: the update (None when the map did not change), its warnings,
    and the reason when it reset the monitor."""

    summary: UpdateSummary | None = None
    warnings: tuple[str, ...] = ()
    reset: str = ''


class MonitorFeed:
    """Records -> ConsistencyMonitor (see the module docstring). Not thread-safe."""

    def __init__(self, parameters: ConsistencyParameters | None = None,
                 monitor_settings: MonitorSettings | None = None,
                 settings: FeedSettings | None = None) -> None:
        self.parameters = parameters or ConsistencyParameters()
        self.monitor_settings = monitor_settings or MonitorSettings()
        self.settings = settings or FeedSettings()
        self.resets = 0
        self.last_reset = ''
        self._received = 0  # scans received since the start (scan records and DroppedScans)
        self._earlier = 0  # of those, the scans received before the last reset
        self._start()

    def _start(self) -> None:
        self.monitor = ConsistencyMonitor(self.parameters, self.monitor_settings)
        self.keyframer = (PoseKeyframer(self.settings.keyframe_distance,
                                        self.settings.keyframe_angle)
                          if self.settings.single_poses else None)
        self.bridge = SlamToolboxBridge() if self.settings.slam_toolbox else None
        self.graph_bridge = PoseGraphBridge() if self.settings.slam_toolbox_graph else None
        self._held: GraphSnapshot | None = None  # a snapshot waiting for its vertices' poses
        self.gaps = ScanGaps()
        self._newest_scan = -math.inf
        self._jumped: list[Scan] = []  # scans of a possible new session, awaiting confirmation
        self._current = 0  # scans of the current session in a row since the last one held
        self._rejected = 0  # scans of this session refused as bad input
        self._lost_in_queue = 0  # scans of this session dropped from a full queue
        self.estimate_stamp = math.nan  # (module docstring) NaN before any estimate
        self._taken_stamp = math.nan  # the newest estimate the monitor took

    def reset(self, reason: str) -> None:
        """Forget every scan, keyframe and constraint (a new SLAM session); the scans received
        so far count as `earlier_sessions` from now on.

        Parameters
        ----------
        reason: why, kept as `last_reset`.
        """
        self._reset(reason, carried=0)

    def _reset(self, reason: str, carried: int) -> None:
        """reset(reason), the last `carried` scans received belonging to the new session (they
        confirmed it and are applied after)."""
        self.resets += 1
        self.last_reset = reason
        self._earlier = self._received - carried
        self._start()

    def scan_counts(self, monitor_counts: dict[str, int] | None = None) -> ScanCounts:
        """What became of every scan received since the start (core/live/_scan_counts.py).

        Parameters
        ----------
        monitor_counts: the monitor's `counts()` now, when the caller has them (else read).

        Returns
        -------
        The ScanCounts, balanced.
        """
        counts = self.monitor.counts() if monitor_counts is None else monitor_counts
        keyframer = self.keyframer
        return ScanCounts(
            received=self._received, keyframes=self.monitor.keyframe_count,
            folded=counts['folded_scans'],
            waiting=(len(self._jumped) + counts['buffered_scans']
                     + (0 if keyframer is None else keyframer.waiting)),
            passed_over=(counts['passed_over_scans']
                         + (0 if keyframer is None else keyframer.passed_over)),
            lost_in_queue=self._lost_in_queue, pushed_out=counts['pushed_out_scans'],
            unplaced=0 if keyframer is None else keyframer.unplaced,
            rejected=self._rejected, earlier_sessions=self._earlier)

    @property
    def gap_scans(self) -> int:
        """Scans missing from the stamp sequence since the last reset (an estimate)."""
        return self.gaps.missing

    @property
    def newest_scan(self) -> float:
        """Stamp of the newest scan since the last reset, -inf before any."""
        return self._newest_scan

    @property
    def bridge_counts(self) -> BridgeCounts | PoseGraphCounts | None:
        """The slam_toolbox bridge's counts after its last snapshot, or the pose-graph
        bridge's (None for other sources)."""
        if self.graph_bridge is not None:
            return self.graph_bridge.counts
        return None if self.bridge is None else self.bridge.counts

    def apply(self, record: Record) -> Applied:
        """Apply one record; bad content becomes a warning, never an exception.

        Parameters
        ----------
        record: one input record (TypeError for anything else).

        Returns
        -------
        What it did: the update (None when the map did not change), its warnings, the reason
        when it reset the monitor.
        """
        if isinstance(record, Scan):
            self._received += 1
            return self._scan(record)
        if isinstance(record, DroppedScans):
            self._received += len(record.lost) + len(record.unreadable)
            self._lost_in_queue += len(record.lost)
            self._rejected += len(record.unreadable)
            self.monitor.note_not_kept(np.concatenate([record.lost, record.unreadable]))
            return Applied()
        if isinstance(record, KeyframeEstimate):
            if self.settings.pose_source != PoseSource.PATH:
                return Applied(warnings=('a keyframe estimate was given while pose_source is '
                                         f'{self.settings.pose_source.value!r}; ignored',))
            return self._estimate(record.stamps, record.poses, record.stamp)
        if isinstance(record, GraphSnapshot):
            return self._graph(record)
        if isinstance(record, (NodeEvent, PoseGraphNodes, LoopClosure)):
            return self._pose_graph(record)
        if isinstance(record, PoseSample):
            return self._bridge_pose(record) if self.bridge is not None else self._pose(record)
        if isinstance(record, Constraints):
            try:
                self.monitor.set_constraints(record.rows)
            except ValueError as error:
                return Applied(warnings=(f'constraints ignored: {error}',))
            return Applied()
        raise TypeError(f'not an input record: {type(record).__name__}')

    def _estimate(self, stamps: np.ndarray, poses: np.ndarray, stamp: float) -> Applied:
        """A keyframe estimate to the monitor, named by `stamp` (the newest keyframe's where
        that is not finite) once the monitor took it."""
        def take():
            summary = self.monitor.update_trajectory(stamps, poses)
            self._taken_stamp = (float(stamp) if math.isfinite(stamp) else
                                 float(np.max(stamps)) if len(stamps) else math.nan)
            return summary
        return self._update(take)

    def _update(self, step) -> Applied:
        try:
            summary = step()
        except ValueError as error:
            return Applied(warnings=(str(error),))
        if summary.changed:
            self.estimate_stamp = self._taken_stamp
        return Applied(summary=summary if summary.changed else None, warnings=summary.warnings)

    def _scan(self, scan: Scan) -> Applied:
        jump = self.settings.reset_stamp_jump
        if jump > 0.0 and scan.stamp < self._newest_scan - jump:
            self._jumped.append(scan)
            self._current = 0
            first = _session_start(self._jumped, jump)
            if len(self._jumped) - first < RESET_CONFIRMATIONS:
                return Applied()
            newest, strays = self._newest_scan, self._jumped[:first]
            session = self._jumped[first:]
            reason = (f'scan stamps jumped back {newest - session[0].stamp:.1f} s (more than '
                      f'reset_stamp_jump = {jump:g} s) for {len(session)} scans: a new session')
            self._reset(reason, carried=len(self._jumped))
            skipped = self._skipped(strays, newest)
            applied = [self._add_scan(held_scan) for held_scan in session]
            return Applied(summary=next((a.summary for a in reversed(applied) if a.summary),
                                        None),
                           warnings=skipped + tuple(w for a in applied for w in a.warnings),
                           reset=reason)
        skipped = ()
        self._current += 1
        if self._jumped and self._current >= RESET_CONFIRMATIONS:
            # the session goes on: the held scans were strays (one late scan of the session
            # among a restarted stack's first scans does not make them strays)
            skipped = self._skipped(self._jumped, self._newest_scan)
            self._jumped = []
        applied = self._add_scan(scan)
        return Applied(summary=applied.summary, warnings=skipped + applied.warnings)

    def _skipped(self, scans: list[Scan], newest: float) -> tuple[str, ...]:
        """Held scans skipped as strays, each older than `newest` by more than
        reset_stamp_jump: counted as rejected, and their warnings."""
        self._rejected += len(scans)
        self.monitor.note_not_kept([scan.stamp for scan in scans])
        return tuple(f'scan at {held.stamp:.6f} skipped: stamped more than reset_stamp_jump '
                     f'before the newest scan ({newest:.6f})' for held in scans)

    def _add_scan(self, scan: Scan) -> Applied:
        self._newest_scan = max(self._newest_scan, scan.stamp)
        self.gaps.add(scan.stamp)
        if self.keyframer is not None:
            self.keyframer.add_scan(scan)
            return Applied()
        try:
            self.monitor.add_scan(scan.stamp, scan.ranges, scan.model)
        except ValueError as error:
            self._rejected += 1
            return Applied(warnings=(f'scan at {scan.stamp:.6f} skipped: {error}',))
        return self._update(self.monitor.refresh) if self.monitor.pending else Applied()

    def _bridge_pose(self, sample: PoseSample) -> Applied:
        """A slam_toolbox `pose` message: the next vertex's stamp and first-seen pose; it
        releases a held snapshot once every vertex of it has its pose."""
        try:
            self.bridge.add_pose(sample.stamp, sample.pose)
        except ValueError as error:
            # The bridge associates by arrival order: a pose it cannot take shifts every
            # later vertex, and the user must hear that, not only that one pose was skipped.
            return Applied(warnings=(f'slam_toolbox pose at {sample.stamp:.6f} skipped: '
                                     f'{error}; later vertices may be associated with the '
                                     'wrong scans',))
        if self._held is not None and not self.bridge.waits_for_poses(self._held.ids):
            held, self._held = self._held, None
            return self._apply_graph(held)
        return Applied()

    def _graph(self, snapshot: GraphSnapshot) -> Applied:
        """A slam_toolbox graph snapshot, applied once its vertices' poses have come.

        slam_toolbox publishes a vertex's pose before any snapshot holding it, but the node
        takes one message per topic at a time, so a snapshot can overtake a backlog of poses.
        Applied early, its vertices would get other heading references and keyframe times than
        in log order (replay): it is held until the last of its poses arrives, or until the
        next snapshot (a pose was lost: then it is applied as it is, with a warning).
        """
        if self.bridge is None:
            return Applied(warnings=('a graph snapshot was given while pose_source is '
                                     f'{self.settings.pose_source.value!r}; ignored',))
        earlier = Applied()
        if self._held is not None:
            held, self._held = self._held, None
            earlier = self._apply_graph(held)
        if self.bridge.waits_for_poses(snapshot.ids):
            self._held = snapshot
            return earlier
        applied = self._apply_graph(snapshot)
        return Applied(summary=applied.summary or earlier.summary,
                       warnings=earlier.warnings + applied.warnings)

    def _apply_graph(self, snapshot: GraphSnapshot) -> Applied:
        """The snapshot to the bridge, the bridge's keyframes to the monitor."""
        try:
            self.bridge.update_vertices(snapshot.ids, snapshot.positions)
        except ValueError as error:
            return Applied(warnings=(f'graph snapshot ignored: {error}',))
        if not len(snapshot.ids):
            return Applied(warnings=('graph snapshot without vertices ignored (slam_toolbox '
                                     'sends its vertices elsewhere in interactive mode)',))
        stamps, poses = self.bridge.keyframes()
        counts = self.bridge.counts
        warnings = []
        if counts.vertices_without_pose:
            # Only a snapshot that waited in vain comes here with them: pose messages were
            # lost, or the session started before the bridge listened (first_vertex_id).
            warnings.append(f'graph snapshot: {counts.vertices_without_pose} vertices have no '
                            'pose message (lost, or sent before the node listened) and are '
                            'left out')
        if not len(stamps):
            return Applied(warnings=tuple(warnings))
        applied = self._estimate(stamps, poses, math.nan)
        return Applied(summary=applied.summary, warnings=tuple(warnings) + applied.warnings)

    def _pose_graph(self, record: NodeEvent | PoseGraphNodes | LoopClosure) -> Applied:
        """A message of slam_toolbox's pose-graph interface to its bridge, and the bridge's
        keyframes to the monitor unless it waits for the graph of a loop closure."""
        bridge = self.graph_bridge
        if bridge is None:
            return Applied(warnings=(f'a slam_toolbox {type(record).__name__} was given while '
                                     f'pose_source is {self.settings.pose_source.value!r}; '
                                     'ignored',))
        try:
            if isinstance(record, NodeEvent):
                if not bridge.add_node(record.node_id, record.stamp, record.pose):
                    return Applied()  # a repeated event changes nothing
            elif isinstance(record, LoopClosure):
                bridge.loop_closure(record.stamp)
            else:
                bridge.update_graph(record.ids, record.poses, record.stamp)
        except ValueError as error:
            return Applied(warnings=(f'slam_toolbox {type(record).__name__} ignored: {error}',))
        if bridge.waiting:
            return Applied()
        stamps, poses = bridge.keyframes()
        if not len(stamps):
            return Applied()
        return self._estimate(stamps, poses, math.nan)

    def _pose(self, sample: PoseSample) -> Applied:
        if self.keyframer is None:
            return Applied(warnings=('a single pose was given while pose_source is path; '
                                     'ignored',))
        problem = self.monitor.pose_problem(sample.pose)
        if problem:
            return Applied(warnings=(f'pose at {sample.stamp:.6f} skipped: {problem}',))
        try:
            placed = self.keyframer.add_pose(sample)
        except ValueError as error:
            return Applied(warnings=(f'{error}; skipped',))
        warnings = []
        for scan in placed:
            try:
                self.monitor.add_scan(scan.stamp, scan.ranges, scan.model)
            except ValueError as error:
                self._rejected += 1
                warnings.append(f'scan at {scan.stamp:.6f} skipped: {error}')
        if not placed:
            return Applied(warnings=tuple(warnings))
        applied = self._estimate(np.array(self.keyframer.stamps),
                                 np.array(self.keyframer.poses), math.nan)
        return Applied(summary=applied.summary, warnings=tuple(warnings) + applied.warnings)

