"""RViz markers of the monitor's verdict: one arrow per keyframe and the inconsistent points.

`MarkerUpdates` keeps the markers the node has published and returns only those that changed
(new or moved keyframes, new colours, a new set of failed pairs), so the cost of an update does
not grow with the map; `all()` is the whole array for a subscriber that joins late.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from map_consistency_ros.core import se2
from map_consistency_ros.core.monitor import MonitorSnapshot

KEYFRAME_NAMESPACE = 'keyframes'
POINTS_NAMESPACE = 'inconsistent_points'

CONSISTENT = ColorRGBA(r=0.1, g=0.75, b=0.2, a=0.9)
INCONSISTENT = ColorRGBA(r=0.9, g=0.1, b=0.1, a=1.0)
UNTESTED = ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.7)  # no pair with enough overlap to test


def _keyframe_marker(key: int, pose: np.ndarray, colour: ColorRGBA, frame_id: str,
                     stamp: Time) -> Marker:
    marker = Marker(ns=KEYFRAME_NAMESPACE, id=key, type=Marker.ARROW, action=Marker.ADD)
    marker.header.frame_id, marker.header.stamp = frame_id, stamp
    marker.pose.position.x, marker.pose.position.y = float(pose[0]), float(pose[1])
    marker.pose.orientation.z, marker.pose.orientation.w = se2.quaternion_from_yaw(pose[2])
    marker.scale.x, marker.scale.y, marker.scale.z = 0.3, 0.06, 0.06
    marker.color = colour
    return marker


def _points_marker(points: np.ndarray, frame_id: str, stamp: Time) -> Marker:
    marker = Marker(ns=POINTS_NAMESPACE, id=0)
    marker.header.frame_id, marker.header.stamp = frame_id, stamp
    if len(points) == 0:
        marker.action = Marker.DELETE  # RViz warns about empty POINTS markers
        return marker
    marker.type, marker.action = Marker.POINTS, Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = 0.05
    marker.color = INCONSISTENT
    marker.points = [Point(x=x, y=y) for x, y in np.asarray(points, dtype=np.float64).tolist()]
    return marker


def _verdicts(snapshot: MonitorSnapshot) -> np.ndarray:
    """0 untested, 1 consistent, 2 inconsistent per keyframe (stamp order)."""
    result = snapshot.result
    if result is None:
        return np.zeros(snapshot.keyframe_count, dtype=np.int8)
    return np.where(result.inconsistent, 2, np.where(result.overlap_counts > 0, 1, 0)).astype(
        np.int8)


_COLOURS = (UNTESTED, CONSISTENT, INCONSISTENT)


def failed_pair_key(snapshot: MonitorSnapshot) -> bytes:
    """Identity of the failed pairs of inconsistent scans (by stable ids) and their poses:
    the inconsistent points change only when it does."""
    result = snapshot.result
    if result is None or result.consistent:
        return b''
    flagged = result.inconsistent[result.pairs[:, 0]] | result.inconsistent[result.pairs[:, 1]]
    pairs = snapshot.ids[result.pairs[result.failed & flagged]]
    involved = np.isin(snapshot.ids, pairs)
    return np.sort(pairs, axis=1).tobytes() + snapshot.poses[involved].tobytes()


class MarkerUpdates:
    """The markers already published, to send only what changed (see the module docstring)."""

    def __init__(self) -> None:
        self._keyframes: dict[int, tuple[bytes, Marker]] = {}
        self._points: Marker | None = None
        self._points_key: bytes | None = None

    def changed(self, snapshot: MonitorSnapshot, points: Callable[[], np.ndarray],
                frame_id: str, stamp: Time) -> MarkerArray:
        """Markers that differ from the last call; `points` computes the inconsistent end
        points, called only when the failed pairs changed."""
        markers = []
        verdicts = _verdicts(snapshot)
        for key, pose, verdict in zip(snapshot.ids.tolist(), snapshot.poses, verdicts.tolist()):
            identity = pose.tobytes() + bytes([verdict]) + frame_id.encode()
            known = self._keyframes.get(key)
            if known is None or known[0] != identity:
                marker = _keyframe_marker(key, pose, _COLOURS[verdict], frame_id, stamp)
                self._keyframes[key] = (identity, marker)
                markers.append(marker)
        points_key = failed_pair_key(snapshot) + frame_id.encode()
        if points_key != self._points_key:
            self._points_key = points_key
            drawn = points() if snapshot.result is not None and not snapshot.result.consistent \
                else np.zeros((0, 2))
            self._points = _points_marker(drawn, frame_id, stamp)
            markers.append(self._points)
        return MarkerArray(markers=markers)

    def all(self) -> MarkerArray:
        """Every marker published so far, for a subscriber that joined late."""
        markers = [marker for _, marker in self._keyframes.values()]
        if self._points is not None:
            markers.append(self._points)
        return MarkerArray(markers=markers)

    def clear(self, frame_id: str, stamp: Time) -> MarkerArray:
        """DELETEALL (after a reset: the old session's markers go)."""
        self._keyframes.clear()
        self._points = self._points_key = None
        marker = Marker(action=Marker.DELETEALL)
        marker.header.frame_id, marker.header.stamp = frame_id, stamp
        return MarkerArray(markers=[marker])
