"""Viewpoints: the scans of a trajectory that see the world from a new place.

The test's windows (the local scale fit, the registered submaps, the length of a region) count
scans, and its pairs multiply with the scans that overlap. A stack that keeps every raw scan
(4 cm apart, or standing still) therefore describes the same map with ten times the scans, ten
times shorter windows and a hundred times the pairs, and the verdict moved with the sampling.
A viewpoint is a scan at least `spacing` metres of travel or `turn` radians of heading away from
the previous viewpoint; the scans in between see what their viewpoint sees and are folded into
it. Every count of the verdict is then a count of viewpoints, i.e. of travel: the same map gives
the same verdict at any sampling denser than the spacing, and standing still is one viewpoint.

A scan at its viewpoint's very pose folds only where it agrees with it, judged on the scans
themselves: a pose estimate that stopped while the robot went on (a back-end or a localizer
that froze) repeats one pose, and folding by pose alone would hide the whole stretch from the
test. The disagreement of two scans is the share of their end points lying deeper than `depth`
inside the other's free space (`disagreement`). A scan at the viewpoint's pose (within
SAME_POSITION and SAME_HEADING) whose disagreement exceeds `share` becomes a viewpoint of its
own, so the test sees it; a run of such viewpoints is the verdict's finding of a frozen estimate
(core/verdict/_frozen.py). A scan whose pose moved but stayed within reach still folds by pose:
where it disagrees, its pose is wrong by less than a viewpoint's reach, which the viewpoint
itself is tested for (on the Intel lab rebuilt at the laser's rate, checking those too unfolds
91 scans turned in place whose headings the rebuild got wrong, and the map reads as distorted
at every 2nd scan but not at every 5th: the verdict would follow the sampling again).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.geometry._measure import pairs_point_distances
from map_consistency_ros.core.geometry._scan_geometry import ScanSet

# A step this small is no step: the pose estimate repeated itself (the smallest step between
# viewpoints of a moving robot is the viewpoint spacing, tenths of a metre).
SAME_POSITION = 0.01  # m
SAME_HEADING = 0.01  # rad


def viewpoint_rows(poses: np.ndarray, spacing: float, turn: float,
                   scans: ScanSet | None = None, depth: float = 0.2,
                   share: float = 1.0) -> np.ndarray:
    """The viewpoints among poses in travel order, the first pose always one.

    A pose becomes a viewpoint when it lies at least `spacing` metres or `turn` radians from the
    last viewpoint (so with either 0 every pose is one), or, given `scans`, when it repeats the
    last viewpoint's pose (`same_pose`) and its scan disagrees with the viewpoint's by more
    than `share` (see `disagreement`).

    Parameters
    ----------
    poses: (N, 3) poses (x, y, theta) in travel order (any shape of 3N values is reshaped).
    spacing: the travel in metres that makes a new viewpoint.
    turn: the change of heading in radians that makes a new viewpoint.
    scans: the N scans at their poses; None folds by pose alone.
    depth: metres inside the other scan's free space that make an end point disagree.
    share: the largest share of disagreeing end points with which a scan still folds.

    Returns
    -------
    (V,) int64 rows of `poses`, increasing; empty when N is 0.
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 3)
    if poses.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    if scans is None or share >= 1.0:
        return _greedy(poses, float(spacing), float(turn))
    if scans.scan_count != poses.shape[0]:
        raise ValueError(f'{scans.scan_count} scans for {poses.shape[0]} poses')
    kept, start = [], 0
    while True:
        # the viewpoints by pose from `start` on; its folded scans are checked against their
        # viewpoint in batches until one disagrees, which then starts the selection anew
        rows = start + _greedy(poses[start:], float(spacing), float(turn))
        refused = _first_disagreeing(scans, rows, start, depth, share)
        if refused < 0:
            kept.append(rows)
            return np.concatenate(kept)
        kept.append(rows[rows < refused])
        start = refused


_BATCH = 256  # folded scans whose disagreement is measured in one call of the kernel


def _first_disagreeing(scans: ScanSet, rows: np.ndarray, start: int, depth: float,
                       share: float) -> int:
    """The first scan from `start` on that `rows` folds at its viewpoint's very pose but that
    disagrees with it by more than `share`; -1 when none does."""
    every = np.arange(start, scans.scan_count)
    folded = every[~np.isin(every, rows)]
    owners = rows[np.searchsorted(rows, folded, side='right') - 1]
    poses = scans.sensor_poses
    repeated = same_pose(poses[owners], poses[folded])
    folded, owners = folded[repeated], owners[repeated]
    for first in range(0, folded.size, _BATCH):
        batch = slice(first, first + _BATCH)
        shares = disagreements(scans, np.stack([owners[batch], folded[batch]], axis=1), depth)
        over = np.flatnonzero(shares > share)
        if over.size:
            return int(folded[batch][over[0]])
    return -1


def same_pose(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Whether poses repeat each other (within SAME_POSITION and SAME_HEADING).

    Parameters
    ----------
    first, second: (..., 3) poses (x, y, theta), broadcast against each other.

    Returns
    -------
    (...) bool.
    """
    step = np.asarray(second, dtype=np.float64) - np.asarray(first, dtype=np.float64)
    return ((np.hypot(step[..., 0], step[..., 1]) < SAME_POSITION)
            & (np.abs(se2.wrap_angle(step[..., 2])) < SAME_HEADING))


def disagreements(scans: ScanSet, pairs: np.ndarray, depth: float) -> np.ndarray:
    """`disagreement` of several pairs at once.

    Parameters
    ----------
    scans: the scans placed in the world.
    pairs: (P, 2) rows (i, j) of two scans each.
    depth: metres inside the other's free space that make an end point disagree.

    Returns
    -------
    (P,) shares in [0, 1].
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if pairs.size == 0:
        return np.zeros(0)
    distances = pairs_point_distances(scans, pairs)
    deep = np.count_nonzero(distances > depth, axis=(1, 2))
    points = scans.valid[pairs[:, 0]].sum(axis=1) + scans.valid[pairs[:, 1]].sum(axis=1)
    return np.where(points > 0, deep / np.maximum(points, 1), 0.0)


def disagreement(scans: ScanSet, i: int, j: int, depth: float) -> float:
    """How much two scans at their poses contradict each other: the share of their valid end
    points that lie deeper than `depth` inside the other's free space.

    Scans taken at one place of a static world agree up to noise (centimetres deep); people
    passing make a part of one scan disagree; a scan taken metres away but placed at the same
    pose contradicts its partner over whole walls.

    Parameters
    ----------
    scans: the scans placed in the world.
    i, j: rows of two scans.
    depth: metres inside the other's free space that make an end point disagree.

    Returns
    -------
    The share in [0, 1]; 0 when neither scan has a valid end point.
    """
    return float(disagreements(scans, np.array([[i, j]]), depth)[0])


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
