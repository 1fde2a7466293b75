"""The node's outputs: ~/markers, ~/consistent, ~/report, /diagnostics and a retune's
~/tuned_phi and ~/optimized_trajectory (docs/node.md, Outputs).

What is published is the engine's newest snapshot with its newest verdict; the markers draw
the verdict's end points from the verdict's own placed scans (core/live/pipeline.py), placed
once for the explanation. The engine calls `publish` under its lock; the figures of the last
update (`timing`, `latency`, `updates`) and of the last retune (`phi`) are kept here.
"""
from __future__ import annotations

import time
from dataclasses import asdict

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Path
from rclpy.node import Node
from std_msgs.msg import Bool, Float64, String
from visualization_msgs.msg import MarkerArray

from map_consistency_ros.core.verdict import (NOTHING_TO_JUDGE, assessment_report, joined_json,
                                              to_json)
from map_consistency_ros.io import messages
from map_consistency_ros.ros.conversions import message_class
from map_consistency_ros.ros.diagnostics import MonitorHealth, map_status
from map_consistency_ros.ros.engine import Engine
from map_consistency_ros.ros.intake import Intake
from map_consistency_ros.ros.markers import MarkerUpdates
from map_consistency_ros.ros.qos import LATCHED, RELIABLE
from map_consistency_ros.core.configuration import NodeSettings


class Outputs:
    """The node's publishers and what they last sent (see the module docstring).

    Parameters
    ----------
    node: the node that publishes.
    settings: the node's settings.
    engine: whose snapshot and verdict are published.
    intake: whose figures /diagnostics shows.
    """

    def __init__(self, node: Node, settings: NodeSettings, engine: Engine,
                 intake: Intake) -> None:
        self._node = node
        self._settings = settings
        self._engine = engine
        self._intake = intake
        self.latency: float | None = None  # arrival of a change -> its verdict published
        self.updates = 0  # verdicts published for changes of the map (since the start)
        self.timing: dict[str, float] = {}  # seconds per stage of the last update
        self.phi: float | None = None  # of the last retune
        # (verdict, its part of the report as JSON text, the keys of that part)
        self._verdict_content: tuple[object, str, frozenset[str]] = (None, '{}', frozenset())
        self._marker_updates = MarkerUpdates()  # used under the engine's lock
        self._marker_subscribers = 0
        self._markers = node.create_publisher(MarkerArray, '~/markers', RELIABLE)
        self._diagnostics = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._consistent = node.create_publisher(Bool, '~/consistent', LATCHED)
        self._report = node.create_publisher(String, '~/report', LATCHED)
        self._tuned_phi = node.create_publisher(Float64, '~/tuned_phi', LATCHED)
        self._optimized = node.create_publisher(Path, '~/optimized_trajectory', LATCHED)

    def _stamp(self):
        return self._node.get_clock().now().to_msg()

    def publish(self, changed_at: float | None) -> None:
        """Publish the engine's snapshot with its newest verdict (under the engine's lock):
        the markers that changed, ~/consistent, ~/report and /diagnostics.

        Parameters
        ----------
        changed_at: the arrival (time.monotonic) of the input this answers: the update's
            latency counts from it. None for a new second stage.
        """
        engine = self._engine
        snapshot, verdict = engine.snapshot, engine.verdict
        start = time.perf_counter()
        limit = self._settings.max_marker_pairs
        markers = self._marker_updates.changed(
            snapshot, verdict.assessment, verdict.snapshot,
            lambda: verdict.misaligned_endpoints(limit), engine.frame_id, self._stamp())
        built = time.perf_counter()
        if markers.markers:
            self._markers.publish(markers)
        if verdict.assessment.outcome != NOTHING_TO_JUDGE:  # only an earned verdict
            self._consistent.publish(Bool(data=verdict.consistent))
        self.timing.update(markers_s=built - start, publish_s=time.perf_counter() - built)
        if changed_at is not None:
            self.latency = time.monotonic() - changed_at
            self.updates += 1
        self._report.publish(String(data=self._report_text()))
        self.publish_diagnostics()

    def greet_marker_subscribers(self) -> None:
        """The whole marker array once more when a subscriber joined (RViz started late):
        updates carry only what changed (worker thread only)."""
        count = self._markers.get_subscription_count()
        if count > self._marker_subscribers:
            with self._engine.lock:
                self._markers.publish(self._marker_updates.all())
        self._marker_subscribers = count

    def clear_markers(self) -> None:
        """DELETEALL: the markers of a session that was reset go (under the engine's lock)."""
        self._markers.publish(self._marker_updates.clear(self._engine.frame_id, self._stamp()))

    def publish_tuning(self, phi: float, stamps: np.ndarray, poses: np.ndarray) -> None:
        """A retune's Phi* and the graph's poses optimized with it.

        Parameters
        ----------
        phi: Phi*, published on ~/tuned_phi and kept for diagnostics.
        stamps: (N,) the stamps of the graph's vertices, seconds.
        poses: (N, 3) their optimized poses (x, y, theta), published on
            ~/optimized_trajectory in the engine's frame.
        """
        self.phi = phi
        self._tuned_phi.publish(Float64(data=phi))
        self._optimized.publish(messages.path_message(message_class, stamps, poses,
                                                      self._engine.frame_id))

    def publish_diagnostics(self) -> None:
        """The map's status on /diagnostics (any thread)."""
        status = map_status(self.health(), self._node.get_fully_qualified_name())
        array = DiagnosticArray(status=[status])
        array.header.stamp = self._stamp()
        self._diagnostics.publish(array)

    def health(self) -> MonitorHealth:
        """What the node knows about its map and inputs now.

        Returns
        -------
        The MonitorHealth of the engine's snapshot and verdict, the intake's figures and the
        last update and retune.
        """
        engine = self._engine
        snapshot = engine.snapshot
        result = snapshot.result
        assessment = None if engine.verdict is None or result is None else \
            engine.verdict.assessment
        feed, now = engine.pipeline.feed, self._intake.now()
        inputs = self._intake.figures()
        problem, when = inputs.last_problem
        stale_timeout = self._settings.stale_timeout
        # the snapshot, read before the intake's figures, holds only scans handed over by then
        # the pair counts are the verdict's (the map it judged, with the pairs of its flagged
        # scans that the partner budget left out), as its summary line and ~/report count
        # them; before a verdict, the newest update's
        counted = result if assessment is None else assessment.result
        scans = snapshot.scan_counts.with_intake(
            received=inputs.received_scans, queued=inputs.queued_scans,
            handed=inputs.handed_scans, lost_in_queue=inputs.lost_scans,
            unreadable=inputs.unreadable_scans)
        return MonitorHealth(
            scans=scans, buffered_scans=snapshot.buffered_scans,
            overlapping_pairs=0 if counted is None else counted.overlapping_pair_count,
            tested_pairs=0 if counted is None else counted.tested_pair_count,
            failed_pairs=0 if counted is None else counted.failed_pair_count,
            inconsistent_scans=0 if counted is None else int(counted.inconsistent.sum()),
            judged_keyframes=(None if assessment is None
                              else engine.verdict.snapshot.keyframe_count),
            unmatched_poses=snapshot.unmatched_poses,
            consistent=None if assessment is None else assessment.consistent,
            verdict='' if assessment is None else assessment.summary_line(),
            misaligned_scans=0 if assessment is None else int(assessment.flagged.sum()),
            misaligned_regions=0 if assessment is None else len(assessment.misalignments),
            changed_places=0 if assessment is None else len(assessment.changes),
            update_latency=self.latency, phi=self.phi, input_problems=inputs.problems,
            recent_problem=problem if time.monotonic() - when <= stale_timeout else '',
            seconds_since_input=(None if inputs.last_input is None
                                 else max(now - inputs.last_input, 0.0)),
            stale_timeout=stale_timeout, queued_scans=inputs.queued_scans,
            middleware_lost=inputs.middleware_lost, gap_scans=feed.gap_scans,
            poses_without_scan=snapshot.poses_without_scan, resets=feed.resets,
            last_reset=feed.last_reset, starting=not engine.ready,
            start_failure=engine.start_failure,
            explanation_failure=engine.explanation_failure,
            nothing_to_judge=assessment is not None and assessment.outcome == NOTHING_TO_JUDGE)

    def _report_text(self) -> str:
        """The machine-readable report of ~/report (the one place it is built), strict JSON:
        the verdict's report of the CLI, scans named by their stamps, then the node's own
        figures. The verdict's part is kept as text (_verdict_report): its lists of scans
        grow with the map, and every update publishes a report."""
        health = self.health()
        figures = dict(update_latency_s=self.latency, updates=self.updates, phi=self.phi,
                       timing=self.timing, scan_counts=asdict(health.scans),
                       scans_lost_by_middleware=health.middleware_lost,
                       poses_without_scan=health.poses_without_scan)
        bridge_counts = self._engine.pipeline.feed.bridge_counts
        if bridge_counts is not None:
            figures['slam_toolbox_bridge'] = asdict(bridge_counts)
        verdict_text, verdict_keys = self._verdict_report()
        if not verdict_keys.isdisjoint(figures):  # strict JSON: one member per key
            raise ValueError(f'~/report: the verdict and the node both name '
                             f'{sorted(verdict_keys & set(figures))}')
        return joined_json(verdict_text, to_json(figures))

    def _verdict_report(self) -> tuple[str, frozenset[str]]:
        """The part of the report that only a new verdict changes, as JSON text, and its keys:
        built once per verdict (every update publishes a report; a verdict comes at most every
        explanation_period)."""
        verdict = self._engine.verdict
        if self._verdict_content[0] is not verdict:
            assessment, judged = verdict.assessment, verdict.snapshot
            content = assessment_report(assessment, judged.stamps)
            content.pop('scans')  # per-scan arrays: the CLI's JSON has room for them, a topic not
            content.update(dict(assessment.result.summary(), consistent=assessment.consistent,
                                paper_consistent=assessment.result.consistent,
                                judged_keyframes=judged.keyframe_count,
                                judged_stamp=judged.estimate_stamp,
                                inconsistent_stamps=judged.stamps[
                                    assessment.result.inconsistent]))
            self._verdict_content = (verdict, to_json(content), frozenset(content))
        return self._verdict_content[1:]
