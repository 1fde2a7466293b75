"""The live pipeline: input records in, both stages' verdict out, for the node, `map-consistency
replay` and the warm-up alike (so a bag replay gives what the node would have published).

`LivePipeline` owns the feed (records -> monitor: core/live/_feed.py), its ConsistencyMonitor,
the second stage's registration cache and both stages:

- `apply(record)`: one input record through the feed; a reset (a new session) also forgets the
  registrations;
- `evaluate()`: the first stage, the paper's test on the current map, as a MonitorSnapshot
  naming the estimate it holds (the one place the monitor is evaluated);
- `slam_graph()` and `retune(graph, settings)`: the back-end's pose graph (every pose its
  constraints name, folded scans' included) and the DCS Phi search on it, M(Phi) measured on
  its keyframes as the test measures the map, the tuned map judged by both stages;
- `explain(snapshot)`: the second stage on a snapshot, as a LiveVerdict that carries the
  snapshot, the Assessment and the snapshot's scans placed in the world. They are placed once,
  here, for the explanation, and whatever draws or reports the verdict (the node's markers,
  replay's figures and report) takes them from the verdict. The second stage weighs the first
  stage's result with every pair of its flagged scans measured (_flagged_pairs.py): the
  partner budget bounds what an update costs, not the evidence of the verdict.

Nothing is evaluated as a side effect of applying or reading. `apply`, `reset`, `recompute` and
`evaluate` and `slam_graph` belong to one thread (the monitor is not thread-safe); `explain` may
run on another, one explanation at a time (the registration cache is shared), and `retune` on
any (it reads only the graph it is given). A snapshot is immutable, so the
thread that explains it never sees the map change under it.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from map_consistency_ros.core.backend import (TuningResult, TuningSettings, tune_dcs,
                                              tuning_problem)
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.geometry import ScanSet, SensorModel
from map_consistency_ros.core.live._feed import Applied, FeedSettings, MonitorFeed
from map_consistency_ros.core.live._flagged_pairs import FlaggedPairs
from map_consistency_ros.core.live._records import KeyframeEstimate, Record, Scan
from map_consistency_ros.core.live.monitor import (ConsistencyMonitor, MonitorSettings,
                                                   MonitorSnapshot, SlamGraph, UpdateSummary)
from map_consistency_ros.core.verdict import (Assessment, ExplanationSettings, RegistrationCache,
                                              misaligned_endpoints)
from map_consistency_ros.core.verdict import explain as explain_map


@dataclass(frozen=True)
class LiveVerdict:
    """Both stages' verdict on one snapshot of the live map."""

    snapshot: MonitorSnapshot  # the keyframes judged and the paper's test on them
    assessment: Assessment  # the second stage on `snapshot`
    scans: ScanSet  # the snapshot's keyframes placed at their poses: the geometry judged
    seconds: float  # the second stage's time, placement included

    @property
    def consistent(self) -> bool:
        """The map's verdict (both stages)."""
        return self.assessment.consistent

    def misaligned_endpoints(self, max_pairs: int) -> np.ndarray:
        """End points (M, 2) of the pairs behind the verdict, drawn from the verdict's own scans.

        Parameters
        ----------
        max_pairs: at most this many pairs, largest statistic first.

        Returns
        -------
        The points, as core.verdict.misaligned_endpoints gives them.
        """
        return misaligned_endpoints(self.scans, self.assessment, max_pairs)


@dataclass(frozen=True)
class Retune:
    """A DCS retune of the back-end's graph: the Phi search and the tuned map's verdict."""

    graph: SlamGraph  # the graph tuned
    tuning: TuningResult  # Phi*, M(Phi*), every vertex's optimized pose, the paper's test
    assessment: Assessment  # both stages on the graph's keyframes at Phi*


class LivePipeline:
    """Feed, monitor, registration cache and both stages (see the module docstring).

    Parameters
    ----------
    parameters, monitor_settings, feed_settings: those of the feed (MonitorFeed).
    explanation: the second stage's settings.
    """

    def __init__(self, parameters: ConsistencyParameters | None = None,
                 monitor_settings: MonitorSettings | None = None,
                 feed_settings: FeedSettings | None = None,
                 explanation: ExplanationSettings | None = None) -> None:
        self.feed = MonitorFeed(parameters, monitor_settings, feed_settings)
        self.explanation = explanation or ExplanationSettings()
        # registrations of this session's maps: a live map changes a little per keyframe, so
        # most of them still hold at the next explanation (replaced on a reset)
        self._registrations = RegistrationCache()
        # the pairs of flagged scans that the partner budget left out (_flagged_pairs.py)
        self._flagged_pairs = FlaggedPairs()
        self._explaining = threading.Lock()

    @property
    def monitor(self) -> ConsistencyMonitor:
        """The feed's monitor (a new one after each reset)."""
        return self.feed.monitor

    def apply(self, record: Record) -> Applied:
        """Apply one input record (MonitorFeed.apply).

        Parameters
        ----------
        record: one input record.

        Returns
        -------
        What it did: the update (None when the map did not change), its warnings, the reason
        when it reset the monitor.
        """
        applied = self.feed.apply(record)
        if applied.reset:
            self._forget_explanations()
        return applied

    def reset(self, reason: str) -> None:
        """Forget every scan, keyframe, constraint and registration (a new SLAM session).

        Parameters
        ----------
        reason: why (the feed keeps it as `last_reset`).
        """
        self.feed.reset(reason)
        self._forget_explanations()

    def _forget_explanations(self) -> None:
        self._registrations = RegistrationCache()
        self._flagged_pairs = FlaggedPairs()

    def recompute(self) -> UpdateSummary:
        """Measure every pair again from scratch (ConsistencyMonitor.recompute).

        Returns
        -------
        The update's summary; `evaluate()` gives the verdict.
        """
        return self.monitor.recompute()

    def evaluate(self) -> MonitorSnapshot:
        """The first stage on the current map.

        Returns
        -------
        The monitor's snapshot (its `result` None before the first keyframe), its
        `estimate_stamp` naming the estimate the map holds.
        """
        snapshot = self.monitor.evaluate()
        return replace(snapshot, estimate_stamp=self.feed.estimate_stamp,
                       scan_counts=self.feed.scan_counts())

    def recount(self, snapshot: MonitorSnapshot) -> MonitorSnapshot:
        """`snapshot`, taken since the map last changed, with the monitor's counts of now
        (ConsistencyMonitor.counts): what `evaluate()` would return, without copying the
        keyframes again. Records that changed no keyframe (most scans) change only these.

        Parameters
        ----------
        snapshot: a snapshot of `evaluate()` on this pipeline's current map.

        Returns
        -------
        The snapshot with its counts of scans that are not keyframes, of poses without a scan
        and its `scan_counts` brought up to date.
        """
        if snapshot.keyframe_count == 0:  # nothing to copy; the first scan shapes the store
            return self.evaluate()
        counts = self.monitor.counts()
        return replace(snapshot, **counts, scan_counts=self.feed.scan_counts(counts))

    def slam_graph(self) -> SlamGraph | None:
        """The back-end's pose graph for a retune (ConsistencyMonitor.slam_graph).

        Returns
        -------
        The graph of the constraints between poses of the last trajectory, with its
        keyframes' scans; None when there is none to tune.
        """
        return self.monitor.slam_graph()

    def tuning_problem(self, graph: SlamGraph) -> str | None:
        """Why `graph` cannot be tuned honestly (core.backend.tuning_problem, poses and
        measurements within the monitor's max_pose_extent).

        Parameters
        ----------
        graph: a graph of `slam_graph()`.

        Returns
        -------
        The reason, a sentence for the user; None when it can be tuned.
        """
        return tuning_problem(graph.graph, self.feed.monitor_settings.max_pose_extent)

    def retune(self, graph: SlamGraph, settings: TuningSettings) -> Retune:
        """The Phi search on `graph` (any thread), judged with the monitor's test parameters.

        Parameters
        ----------
        graph: a graph of `slam_graph()`.
        settings: the search's settings.

        Returns
        -------
        The Retune: Phi*, the optimized poses of every vertex, and both stages' verdict on the
        graph's keyframes at Phi*. ValueError when the graph cannot be tuned (`tuning_problem`
        or a singular solve).
        """
        problem = self.tuning_problem(graph)
        if problem:
            raise ValueError(f'cannot tune this graph honestly: {problem}')
        tuning = tune_dcs(graph.graph, graph.ranges, graph.model, graph.laser_offset, settings,
                          self.feed.parameters, scan_vertices=graph.scan_vertices)
        assessment = explain_map(graph.scans_at(tuning.poses), tuning.consistency,
                                 self.explanation)
        return Retune(graph=graph, tuning=tuning, assessment=assessment)

    def explain(self, snapshot: MonitorSnapshot) -> LiveVerdict:
        """The second stage on `snapshot` (any thread; one explanation at a time).

        Parameters
        ----------
        snapshot: a snapshot of `evaluate()` with at least one keyframe.

        Returns
        -------
        The verdict, with the snapshot's scans placed once for it and shared from there.
        """
        if snapshot.result is None:
            raise ValueError('no keyframes to explain')
        with self._explaining:
            start = time.perf_counter()
            scans = snapshot.scans()
            result = self._flagged_pairs.complete(scans, snapshot.ids, snapshot.result)
            assessment = explain_map(scans, result, self.explanation,
                                     cache=self._registrations)
            return LiveVerdict(snapshot=snapshot, assessment=assessment, scans=scans,
                               seconds=time.perf_counter() - start)


def warm_up() -> None:
    """Run the compiled kernels of both stages once, through a throwaway pipeline, on a made-up
    corridor: a walk down it, then a revisit of its start placed 3 degrees off (its local
    window sees no part of the corridor it is wrong against, so that the test flags it and the
    second stage registers it). A partner budget of 2 makes the revisit crowded, so that the
    budget's kernels run too, and so do those that find the pairs it left out of the flagged
    scans for the second stage.

    Loading the kernels from numba's cache costs the first call a few hundred milliseconds: a
    node pays it at start instead of on its first update.
    """
    model = SensorModel(angle_min=-math.pi / 2, angle_increment=math.pi / 90, max_range=8.0)
    bearings = model.bearings(91)
    walk, revisit = 100, 8
    poses = np.zeros((walk + revisit, 3))
    poses[:walk, 0] = np.linspace(0.0, 20.0, walk)
    poses[walk:, 0] = np.linspace(0.0, 0.2, revisit)
    pipeline = LivePipeline(monitor_settings=MonitorSettings(max_partners=2))
    for stamp, pose in enumerate(poses):
        pipeline.apply(Scan(stamp=float(stamp), ranges=_corridor_ranges(pose, bearings),
                            model=model))
    placed = poses.copy()
    placed[walk:, 2] += math.radians(3.0)
    pipeline.apply(KeyframeEstimate(stamps=np.arange(float(len(poses))), poses=placed))
    pipeline.explain(pipeline.evaluate())


def _corridor_ranges(pose: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    """Ranges from `pose` to the walls of the rectangle [-2, 30] x [-2, 2] along `bearings`."""
    angles = bearings + pose[2]
    directions = np.stack([np.cos(angles), np.sin(angles)])
    low, high = np.array([[-2.0], [-2.0]]), np.array([[30.0], [2.0]])
    position = pose[:2, None]
    with np.errstate(divide='ignore'):
        steps = np.where(directions > 0, (high - position) / directions,
                         (low - position) / directions)
    return steps.min(axis=0)
