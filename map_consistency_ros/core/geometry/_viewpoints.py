"""Viewpoints: the scans of a trajectory that see the world from a new place.

The test's windows (the local scale fit, the registered submaps, the length of a region) count
scans, and its pairs multiply with the scans that overlap. A stack that keeps every raw scan
(4 cm apart, or standing still) therefore describes the same map with ten times the scans, ten
times shorter windows and a hundred times the pairs, and the verdict moved with the sampling.
A viewpoint is a scan at least `spacing` metres of travel or `turn` radians of heading away from
the previous viewpoint; the scans in between see what their viewpoint sees and are folded into
it. Every count of the verdict is then a count of viewpoints, i.e. of travel: the same map gives
the same verdict at any sampling denser than the spacing, and standing still is one viewpoint.
"""
from __future__ import annotations

import math

import numba
import numpy as np


def viewpoint_rows(poses: np.ndarray, spacing: float, turn: float) -> np.ndarray:
    """The viewpoints among poses in travel order, the first pose always one.

    A pose becomes a viewpoint when it lies at least `spacing` metres or `turn` radians from the
    last viewpoint (so with either 0 every pose is one).

    Parameters
    ----------
    poses: (N, 3) poses (x, y, theta) in travel order (any shape of 3N values is reshaped).
    spacing: the travel in metres that makes a new viewpoint.
    turn: the change of heading in radians that makes a new viewpoint.

    Returns
    -------
    (V,) int64 rows of `poses`, increasing; empty when N is 0.
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 3)
    if poses.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    return _greedy(poses, float(spacing), float(turn))


def is_new_viewpoint(step: np.ndarray, spacing: float, turn: float) -> bool:
    """Whether a pose is a new viewpoint: the rule of `viewpoint_rows`, one pose at a time, for
    a live trajectory.

    Parameters
    ----------
    step: (3,) the pose relative to the last viewpoint (x, y in metres, theta in radians).
    spacing: the travel in metres that makes a new viewpoint.
    turn: the change of heading in radians that makes a new viewpoint.

    Returns
    -------
    True when the step moves at least `spacing` or turns at least `turn`.
    """
    shift = math.hypot(float(step[0]), float(step[1]))
    heading = abs(math.remainder(float(step[2]), 2.0 * math.pi))
    return shift >= spacing or heading >= turn


@numba.njit(cache=True)
def _greedy(poses: np.ndarray, spacing: float, turn: float) -> np.ndarray:
    keep = np.zeros(poses.shape[0], dtype=np.bool_)
    keep[0] = True
    last = 0
    for row in range(1, poses.shape[0]):
        dx = poses[row, 0] - poses[last, 0]
        dy = poses[row, 1] - poses[last, 1]
        dtheta = poses[row, 2] - poses[last, 2]
        heading = abs(math.atan2(math.sin(dtheta), math.cos(dtheta)))
        if math.sqrt(dx * dx + dy * dy) >= spacing or heading >= turn:
            keep[row] = True
            last = row
    return np.flatnonzero(keep)
