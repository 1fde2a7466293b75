"""RViz markers of the monitor's verdict: one arrow per keyframe and the inconsistent points."""
from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from map_consistency_ros.core.monitor import MonitorSnapshot

KEYFRAME_NAMESPACE = 'keyframes'
POINTS_NAMESPACE = 'inconsistent_points'

CONSISTENT = ColorRGBA(r=0.1, g=0.75, b=0.2, a=0.9)
INCONSISTENT = ColorRGBA(r=0.9, g=0.1, b=0.1, a=1.0)
UNTESTED = ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.7)  # no pair with enough overlap to test


def keyframe_colours(snapshot: MonitorSnapshot) -> list[ColorRGBA]:
    """Verdict colour of each keyframe in stamp order."""
    result = snapshot.result
    if result is None:
        return [UNTESTED] * snapshot.keyframe_count
    return [INCONSISTENT if bad else CONSISTENT if tested > 0 else UNTESTED
            for bad, tested in zip(result.inconsistent.tolist(), result.overlap_counts.tolist())]


def _keyframe_marker(key: int, pose: np.ndarray, colour: ColorRGBA, frame_id: str,
                     stamp: Time) -> Marker:
    marker = Marker(ns=KEYFRAME_NAMESPACE, id=key, type=Marker.ARROW, action=Marker.ADD)
    marker.header.frame_id, marker.header.stamp = frame_id, stamp
    marker.pose.position.x, marker.pose.position.y = float(pose[0]), float(pose[1])
    marker.pose.orientation.z = math.sin(pose[2] / 2.0)
    marker.pose.orientation.w = math.cos(pose[2] / 2.0)
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


def consistency_markers(snapshot: MonitorSnapshot, inconsistent_points: np.ndarray,
                        frame_id: str, stamp: Time) -> MarkerArray:
    """Arrow per keyframe (id = stable keyframe id, colour = verdict) and the inconsistent
    end points (M, 2) as one POINTS marker, deleted when there are none."""
    colours = keyframe_colours(snapshot)
    markers = [_keyframe_marker(int(key), pose, colour, frame_id, stamp)
               for key, pose, colour in zip(snapshot.ids.tolist(), snapshot.poses, colours)]
    markers.append(_points_marker(inconsistent_points, frame_id, stamp))
    return MarkerArray(markers=markers)
