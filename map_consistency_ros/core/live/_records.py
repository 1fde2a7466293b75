"""The input contract of the monitor: one record type per kind of input message.

The node and bag replay convert their messages into these records (io/messages.py) and apply
them through one feed (core/live/_feed.py), so both see exactly the same input. Stamps are float
seconds, poses (x, y, yaw).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from map_consistency_ros.core.geometry import SensorModel


@dataclass(frozen=True)
class Scan:
    """One LaserScan; `model.max_range` is its range_max capped at the usable range."""

    stamp: float
    ranges: np.ndarray  # (K,) metres
    model: SensorModel
    frame_id: str = ''


@dataclass(frozen=True)
class KeyframeEstimate:
    """The SLAM back-end's full current keyframe estimate (a Path, or a bridge's output):
    each stamp (M,) is the stamp of the scan its keyframe was built from, poses (M, 3).
    `stamp` is the message's own (header) stamp: which estimate this is; NaN when unknown."""

    stamps: np.ndarray
    poses: np.ndarray
    frame_id: str = ''
    stamp: float = math.nan


@dataclass(frozen=True)
class PoseSample:
    """One pose of a single-pose message (Odometry, PoseStamped, PoseWithCovarianceStamped):
    the pose of `child_frame_id` in `frame_id` at `stamp`."""

    stamp: float
    pose: np.ndarray  # (3,)
    frame_id: str = ''
    child_frame_id: str = ''


@dataclass(frozen=True)
class Constraints:
    """The full edge set: rows (E, 11) laid out as posegraph.CONSTRAINT_FIELDS."""

    rows: np.ndarray


@dataclass(frozen=True)
class GraphSnapshot:
    """One full snapshot of a SLAM graph's vertices, positions only (slam_toolbox's
    graph_visualization): vertex ids (V,) and their current positions (V, 2) in `frame_id`.
    It replaces the previous snapshot: a vertex missing from it is gone."""

    ids: np.ndarray
    positions: np.ndarray
    frame_id: str = ''


@dataclass(frozen=True)
class NodeEvent:
    """A new node of a SLAM pose graph (slam_toolbox's NewNodeEvent): its id, the stamp of the
    scan it was built from, and its pose (x, y, yaw) when it was added."""

    node_id: int
    stamp: float
    pose: np.ndarray  # (3,)


@dataclass(frozen=True)
class PoseGraphNodes:
    """One full snapshot of a SLAM pose graph's nodes with headings (slam_toolbox's PoseGraph):
    node ids (V,) and poses (V, 3) in `frame_id`; `stamp` is the message's header stamp (the
    SLAM node's clock when it was built, not a scan's)."""

    ids: np.ndarray
    poses: np.ndarray
    stamp: float
    frame_id: str = ''


@dataclass(frozen=True)
class LoopClosure:
    """A SLAM back-end closed a loop at `stamp` (slam_toolbox's LoopClosureEvent: its node's
    clock); node poses move, and a PoseGraph built after it shows where to."""

    stamp: float


@dataclass(frozen=True)
class DroppedScans:
    """Scans received but never applied as Scan records, counted in the pipeline's account
    (core/live/_scan_counts.py): `lost` (L,) the stamps of scans dropped from a full queue, and
    `unreadable` (U,) the header stamps of scan messages that no record could be made of
    (rejected; NaN where the stamp was unreadable too)."""

    lost: np.ndarray
    unreadable: np.ndarray


Record = (Scan | KeyframeEstimate | PoseSample | Constraints | GraphSnapshot | NodeEvent
          | PoseGraphNodes | LoopClosure | DroppedScans)
