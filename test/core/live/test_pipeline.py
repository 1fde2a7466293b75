"""The live pipeline (feed, monitor, both stages) against the batch check on real Intel scans."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from map_consistency_ros.core.backend import TuningSettings, constraint_rows
from map_consistency_ros.core.consistency import ConsistencyParameters, check_consistency
from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.live import (Constraints, KeyframeEstimate, LivePipeline,
                                           MonitorSettings, MonitorSnapshot, Scan)
from map_consistency_ros.core.verdict import explain, misaligned_endpoints
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

SCANS = 80
# Against the batch check: every keyframe a viewpoint, every pair measured.
EVERY_KEYFRAME = ConsistencyParameters(viewpoint_spacing=0.0, viewpoint_turn=0.0)
ALL_PAIRS = MonitorSettings(max_partners=0)


@pytest.fixture(scope='module')
def intel(shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    stamps, poses = log.timestamps[:SCANS], log.laser_poses[:SCANS]
    assert np.all(np.diff(stamps) > 0)
    # a wrong loop closure drags the second half of the excerpt aside
    dragged = poses.copy()
    pivot = poses[SCANS // 2]
    dragged[SCANS // 2:] = se2.compose(se2.compose(pivot, np.array([0.3, 0.0, 0.05])),
                                       se2.relative(pivot, poses[SCANS // 2:]))
    return stamps, log.ranges[:SCANS], poses, dragged, sensor_model(log)


@pytest.fixture(scope='module')
def streamed(intel):
    """The pipeline after the scans, the estimate as mapped, then the dragged one."""
    stamps, ranges, poses, dragged, model = intel
    pipeline = LivePipeline(EVERY_KEYFRAME, ALL_PAIRS)
    for stamp, scan in zip(stamps, ranges):
        assert pipeline.apply(Scan(stamp=float(stamp), ranges=scan, model=model)).warnings == ()
    assert pipeline.apply(KeyframeEstimate(stamps=stamps, poses=poses, stamp=10.0)).summary
    assert pipeline.apply(KeyframeEstimate(stamps=stamps, poses=dragged, stamp=11.0)).summary
    return pipeline


def test_both_stages_give_the_batch_verdict(intel, streamed):
    stamps, ranges, _, dragged, model = intel
    snapshot = streamed.evaluate()
    verdict = streamed.explain(snapshot)
    # the batch check of the same poses, its local scales fitted on the same first-seen poses
    scans = ScanSet.from_ranges(ranges, dragged, model)
    oracle = check_consistency(scans, EVERY_KEYFRAME, reference_scans=ScanSet.from_ranges(
        ranges, snapshot.incremental_poses, model))
    expected = explain(scans, oracle)
    result = verdict.snapshot.result
    np.testing.assert_array_equal(snapshot.stamps, stamps)
    np.testing.assert_array_equal(result.inconsistent, oracle.inconsistent)
    np.testing.assert_array_equal(result.failed_counts, oracle.failed_counts)
    assert result.failed_pair_count == oracle.failed_pair_count > 0
    assessment = verdict.assessment
    assert not assessment.consistent and not expected.consistent
    np.testing.assert_array_equal(assessment.flagged, expected.flagged)
    assert assessment.summary_line() == expected.summary_line()
    assert len(assessment.misalignments) == len(expected.misalignments) > 0
    for live, batch in zip(assessment.misalignments, expected.misalignments):
        np.testing.assert_array_equal(live.scans, batch.scans)
        assert live.displacement == pytest.approx(batch.displacement, rel=1e-6, abs=1e-9)
    # every explained pair in the same class
    classes = {tuple(pair): code for pair, code in zip(
        result.pairs[assessment.explained_pairs].tolist(), assessment.pair_classes)}
    assert classes == {tuple(pair): code for pair, code in zip(
        oracle.pairs[expected.explained_pairs].tolist(), expected.pair_classes)}
    np.testing.assert_allclose(verdict.misaligned_endpoints(50),
                               misaligned_endpoints(scans, expected, 50), atol=1e-9)


def test_the_placed_geometry_is_placed_once_and_shared(streamed, monkeypatch):
    placed = []
    real = MonitorSnapshot.scans

    def scans(snapshot):
        placed.append(real(snapshot))
        return placed[-1]

    monkeypatch.setattr(MonitorSnapshot, 'scans', scans)
    snapshot = streamed.evaluate()
    assert placed == []  # the first stage places nothing for the second
    verdict = streamed.explain(snapshot)
    assert len(placed) == 1 and verdict.scans is placed[0] and verdict.snapshot is snapshot
    points = verdict.misaligned_endpoints(50)  # what the markers draw
    assert len(placed) == 1 and len(points) > 0
    np.testing.assert_array_equal(verdict.scans.sensor_poses, snapshot.scans().sensor_poses)


def test_evaluate_is_the_monitors_snapshot_named_by_its_estimate(intel, streamed):
    snapshot = streamed.evaluate()
    assert snapshot.estimate_stamp == 11.0
    np.testing.assert_array_equal(snapshot.poses, streamed.monitor.evaluate().poses)
    np.testing.assert_array_equal(snapshot.poses, intel[3])


def test_a_recount_is_the_snapshot_of_a_map_no_scan_changed(intel):
    """Scans waiting for their pose (one pushed out of the full buffer, poses without a scan
    among them) change only the counts: the last snapshot recounted equals a new one."""
    from dataclasses import fields
    stamps, ranges, poses, _, model = intel
    pipeline = LivePipeline(EVERY_KEYFRAME, MonitorSettings(max_partners=0, max_buffered_scans=6))
    snapshot, unchanged = pipeline.evaluate(), 0
    lost = {23, 24, 37}
    for k, (stamp, scan) in enumerate(zip(stamps, ranges)):
        if k not in lost:
            applied = pipeline.apply(Scan(stamp=float(stamp), ranges=scan, model=model))
            if applied.summary is None:
                unchanged += 1
                recounted, fresh = pipeline.recount(snapshot), pipeline.evaluate()
                for field in fields(fresh):
                    value, expected = getattr(recounted, field.name), getattr(fresh, field.name)
                    if isinstance(expected, np.ndarray):
                        np.testing.assert_array_equal(value, expected)
                    elif field.name == 'result':
                        assert value is expected
                    else:
                        assert value == expected or (value != value and expected != expected)
                snapshot = recounted
        if k % 10 == 9:  # the estimate lags ten scans: the scans after it wait in the buffer
            pipeline.apply(KeyframeEstimate(stamps=stamps[:k - 4], poses=poses[:k - 4]))
            snapshot = pipeline.evaluate()
    assert unchanged > 30
    assert snapshot.pushed_out_scans > 0 and snapshot.poses_without_scan > 0
    assert snapshot.buffered_scans > 0


def test_a_reset_starts_a_new_session(intel):
    stamps, ranges, poses, _, model = intel
    pipeline = LivePipeline(EVERY_KEYFRAME, ALL_PAIRS)
    with pytest.raises(ValueError, match='no keyframes'):
        pipeline.explain(pipeline.evaluate())
    for stamp, scan in zip(stamps[:20], ranges[:20]):
        pipeline.apply(Scan(stamp=float(stamp), ranges=scan, model=model))
    pipeline.apply(KeyframeEstimate(stamps=stamps[:20], poses=poses[:20]))
    monitor = pipeline.monitor
    assert pipeline.explain(pipeline.evaluate()).snapshot.keyframe_count == 20
    pipeline.reset('a new session')
    assert pipeline.monitor is not monitor and pipeline.feed.resets == 1
    snapshot = pipeline.evaluate()
    assert snapshot.result is None and math.isnan(snapshot.estimate_stamp)


def test_warm_up_loads_every_kernel_of_both_stages():
    """In a fresh interpreter (this one has run the kernels already)."""
    # the modules that hold the kernels, through the public functions they define
    probe = ('import sys\n'
             'from map_consistency_ros.core.consistency import statistics\n'
             'from map_consistency_ros.core.geometry import ScanExtentIndex, pair_measures\n'
             'from map_consistency_ros.core.live import _keyframes, _pair_selection, monitor\n'
             'from map_consistency_ros.core.live import warm_up\n'
             'from map_consistency_ros.core.verdict import register_submaps\n'
             'warm_up()\n'
             'measure = sys.modules[pair_measures.__module__]\n'
             'registration = sys.modules[register_submaps.__module__]\n'
             'index = sys.modules[ScanExtentIndex.__module__]\n'
             'kernels = [measure._pair_kernel, measure._pairs_distances, '
             'registration._thin_ranges, registration._register_tasks, '
             'statistics._critical_counts, index._overlapping, index._sweep_pairs, '
             '_pair_selection._partners_by_slot, _pair_selection._nearest_in_visits, '
             '_pair_selection._kept_by_slot, monitor._clean_trajectory, '
             '_keyframes._match_sorted]\n'
             'print(",".join(str(len(kernel.signatures)) for kernel in kernels))\n')
    done = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                          check=True)
    assert done.stdout.strip() == '1,1,1,1,1,1,1,1,1,1,1,1'


def _retuned(intel, parameters):
    """A retune of the excerpt streamed as a SLAM stack would: the dragged estimate (it took a
    wrong loop closure), and its graph: an edge between consecutive scans, measured on the
    poses as mapped, and the wrong loop closure."""
    stamps, ranges, poses, dragged, model = intel
    pipeline = LivePipeline(parameters)
    for k, (stamp, scan) in enumerate(zip(stamps, ranges), 1):
        pipeline.apply(Scan(stamp=float(stamp), ranges=scan, model=model))
        if k % 10 == 0:
            pipeline.apply(KeyframeEstimate(stamps=stamps[:k], poses=dragged[:k]))
    information = np.repeat(np.diag([100.0, 100.0, 400.0])[None], SCANS, axis=0)
    loop = [10, SCANS - 10]
    rows = np.concatenate([
        constraint_rows(stamps[:-1], stamps[1:], se2.relative(poses[:-1], poses[1:]),
                        information[1:]),
        constraint_rows(stamps[loop[:1]], stamps[loop[1:]],
                        se2.relative(dragged[loop[:1]], dragged[loop[1:]]), information[:1])])
    assert pipeline.apply(Constraints(rows)).warnings == ()
    graph = pipeline.slam_graph()
    return pipeline, graph, pipeline.retune(graph, TuningSettings(grid_steps=5, tolerance=0.05))


def test_a_retune_tunes_the_back_ends_graph_whatever_the_test_folds(intel):
    """Folded scans stay vertices of the retune's graph: the same graph, Phi* and optimized
    poses as with every scan a keyframe; M(Phi) measured on the keyframes."""
    stamps, _, poses, _, _ = intel
    folding, folded, folded_retune = _retuned(intel, ConsistencyParameters())
    _, every, every_retune = _retuned(intel, EVERY_KEYFRAME)
    keyframes = folding.evaluate()
    assert keyframes.folded_scans > 0 and keyframes.keyframe_count < SCANS
    for graph in (folded, every):
        np.testing.assert_array_equal(graph.stamps, stamps)
    np.testing.assert_array_equal(folded.graph.edge_to, every.graph.edge_to)
    np.testing.assert_array_equal(folded.graph.poses, every.graph.poses)
    np.testing.assert_array_equal(folded.stamps[folded.scan_vertices], keyframes.stamps)
    assert folded_retune.tuning.phi == every_retune.tuning.phi
    np.testing.assert_array_equal(folded_retune.tuning.poses, every_retune.tuning.poses)
    assert folded_retune.tuning.consistency.scan_count == keyframes.keyframe_count
    # the wrong loop closure is weighed out: the map as mapped, judged consistent
    assert np.abs(folded_retune.tuning.poses[:, :2] - poses[:, :2]).max() < 0.01
    assert folded_retune.assessment.consistent


def test_a_retune_refuses_what_tune_refuses(intel):
    """One number policy (core.backend.tuning_problem, check_constraint_rows): odometry alone is
    no graph to tune, and a measurement beyond max_pose_extent no edge."""
    stamps, ranges, poses, _, model = intel
    pipeline = LivePipeline(EVERY_KEYFRAME)
    for stamp, scan in zip(stamps, ranges):
        pipeline.apply(Scan(stamp=float(stamp), ranges=scan, model=model))
    pipeline.apply(KeyframeEstimate(stamps=stamps, poses=poses))
    information = np.repeat(np.diag([100.0, 100.0, 400.0])[None], SCANS - 1, axis=0)
    odometry = constraint_rows(stamps[:-1], stamps[1:], se2.relative(poses[:-1], poses[1:]),
                               information)
    assert pipeline.apply(Constraints(odometry)).warnings == ()
    graph = pipeline.slam_graph()
    assert 'no loop closure' in pipeline.tuning_problem(graph)
    with pytest.raises(ValueError, match='cannot tune this graph honestly: no loop closure'):
        pipeline.retune(graph, TuningSettings(grid_steps=3))
    absurd = odometry.copy()
    absurd[0, 2] = 1e300  # refused on arrival, the edges before kept
    applied = pipeline.apply(Constraints(absurd))
    assert applied.warnings == ('constraints ignored: constraint row 0 has a measurement '
                                'beyond 100000 (m, rad)',)
    np.testing.assert_array_equal(pipeline.monitor.constraints, odometry)
