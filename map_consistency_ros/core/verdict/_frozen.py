"""A pose estimate that stood still while the robot moved: a finding of its own.

A back-end or localizer that stops updating keeps publishing one pose while the laser goes on
seeing new places. Folding keeps only scans that agree with their viewpoint
(geometry.viewpoint_rows), so such a stretch reaches the test as consecutive viewpoints at one
pose whose scans disagree. The same holds with folding off: every scan is then a viewpoint. A
stretch is a frozen estimate when its scans, all at one pose, changed (disagreed with the last
scan they agreed with, as folding measures it) at least `min_region_scans` times: as much
evidence as a misaligned region needs, and far beyond what people walking past a robot that
stands still do to its scans.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.geometry import ScanSet, same_pose, true_runs, viewpoint_rows


@dataclass(frozen=True)
class FrozenEstimate:
    """Consecutive scans at one pose whose scans show the robot moving."""

    scans: np.ndarray  # rows of the map's scans, consecutive
    changes: int  # how often the scans disagreed with the last one they agreed with


def frozen_estimates(scans: ScanSet, parameters: ConsistencyParameters,
                     min_changes: int) -> tuple[FrozenEstimate, ...]:
    """The stretches of a map whose pose stood still while its scans changed.

    Parameters
    ----------
    scans: the map's scans (its viewpoints) in travel order, at their poses.
    parameters: the fold's depth and disagreement (what makes two scans disagree).
    min_changes: the changes of scene at one pose that make a stretch a frozen estimate.

    Returns
    -------
    The FrozenEstimate stretches, in travel order.
    """
    poses = scans.sensor_poses
    if poses.shape[0] <= min_changes:
        return ()
    found = []
    # a run of steps [start, end) that repeat the pose joins scans start..end
    for start, end in true_runs(same_pose(poses[:-1], poses[1:])).tolist():
        rows = np.arange(start, end + 1)
        if rows.size <= min_changes:
            continue
        # inside the stretch the pose never moves: only a change of scene makes a viewpoint
        changed = viewpoint_rows(poses[rows], math.inf, math.inf, scans.take(rows),
                                 parameters.fold_depth, parameters.fold_disagreement)
        if changed.size - 1 >= min_changes:
            found.append(FrozenEstimate(scans=rows, changes=int(changed.size - 1)))
    return tuple(found)
