"""RViz markers of the verdict: one arrow per keyframe, the misaligned end points, the changed
places and a legend.

Keyframes are green (consistent), red (in a misaligned region) or grey (no pair to test); the
end points of misaligned pairs are red points, changed places (people, moved objects) cyan
spheres. `MarkerUpdates` keeps the markers the node has published and returns only those that
changed (new or moved keyframes, new colours, a new verdict), so the cost of an update does not
grow with the map; `all()` is the whole array for a subscriber that joins late.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from map_consistency_ros.core.geometry import se2, with_rows
from map_consistency_ros.core.live import MonitorSnapshot
from map_consistency_ros.core.verdict import Assessment

KEYFRAME_NAMESPACE = 'keyframes'
POINTS_NAMESPACE = 'misaligned_points'
CHANGES_NAMESPACE = 'changed_places'
LEGEND_NAMESPACE = 'legend'

CONSISTENT = ColorRGBA(r=0.1, g=0.75, b=0.2, a=0.9)
INCONSISTENT = ColorRGBA(r=0.9, g=0.1, b=0.1, a=1.0)
UNTESTED = ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.7)  # no pair with enough overlap to test
CHANGED = ColorRGBA(r=0.0, g=0.8, b=0.9, a=0.6)
LEGEND = ('green arrow: consistent keyframe\nred arrow: keyframe in a misaligned region\n'
          'grey arrow: nothing to test yet\nred points: misaligned end points\n'
          'cyan spheres: changed places (people, moved objects)')


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


def _changes_marker(assessment: Assessment, frame_id: str, stamp: Time) -> Marker:
    marker = Marker(ns=CHANGES_NAMESPACE, id=0)
    marker.header.frame_id, marker.header.stamp = frame_id, stamp
    if not assessment.changes:
        marker.action = Marker.DELETE
        return marker
    marker.type, marker.action = Marker.SPHERE_LIST, Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = 0.4
    marker.color = CHANGED
    marker.points = [Point(x=place.x, y=place.y) for place in assessment.changes]
    return marker


def _legend_marker(anchor: np.ndarray, frame_id: str, stamp: Time) -> Marker:
    marker = Marker(ns=LEGEND_NAMESPACE, id=0, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
    marker.header.frame_id, marker.header.stamp = frame_id, stamp
    marker.pose.position.x, marker.pose.position.y = float(anchor[0]), float(anchor[1]) + 1.5
    marker.pose.orientation.w = 1.0
    marker.scale.z = 0.3
    marker.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=0.9)
    marker.text = LEGEND
    return marker


def _verdicts(snapshot: MonitorSnapshot, assessment: Assessment,
              judged: MonitorSnapshot) -> np.ndarray:
    """0 untested, 1 consistent, 2 misaligned per keyframe of `snapshot` (stamp order), from
    the verdict on the (possibly older) snapshot `judged`."""
    result = snapshot.result
    if result is None:
        return np.zeros(snapshot.keyframe_count, dtype=np.int8)
    flagged = np.isin(snapshot.ids, judged.ids[assessment.flagged])
    return np.where(flagged, 2, np.where(result.overlap_counts > 0, 1, 0)).astype(np.int8)


_COLOURS = (UNTESTED, CONSISTENT, INCONSISTENT)


class MarkerUpdates:
    """The markers already published, to send only what changed (see the module docstring)."""

    def __init__(self) -> None:
        self._keyframes: dict[int, Marker] = {}
        # what each keyframe id's marker shows, compared with the snapshot in one vectorized
        # step: a Python loop over every keyframe on every update would grow with the map
        self._shown = np.zeros(0, dtype=bool)
        self._shown_poses = np.zeros((0, 3))
        self._shown_verdicts = np.zeros(0, dtype=np.int64)
        self._frame_id = ''
        self._verdict: tuple[Marker, Marker] | None = None  # points, changed places
        self._judged: Assessment | None = None
        self._legend: Marker | None = None

    def changed(self, snapshot: MonitorSnapshot, assessment: Assessment,
                judged: MonitorSnapshot, points: Callable[[], np.ndarray], frame_id: str,
                stamp: Time) -> MarkerArray:
        """Markers that differ from the last call.

        Parameters
        ----------
        snapshot: the keyframes to draw, at their current poses.
        assessment: the newest verdict, on `judged`.
        judged: the snapshot `assessment` judged (`snapshot` or an older one); the keyframes
            it flagged are red.
        points: computes the misaligned end points (P, 2) of `assessment`; called only when
            the verdict is new and inconsistent.
        frame_id: the markers' frame; a new one redraws every keyframe.
        stamp: the markers' header stamp.

        Returns
        -------
        The keyframes that are new, moved or recoloured, the verdict's end points and changed
        places when the verdict is new, and the legend once there is a keyframe; an empty
        array when nothing changed.
        """
        markers = []
        ids, poses = snapshot.ids, snapshot.poses
        verdicts = _verdicts(snapshot, assessment, judged)
        self._make_room(int(ids.max()) + 1 if ids.size else 0, frame_id)
        stale = np.flatnonzero(~self._shown[ids] | (self._shown_verdicts[ids] != verdicts)
                               | np.any(self._shown_poses[ids] != poses, axis=1))
        for index in stale.tolist():
            key = int(ids[index])
            marker = _keyframe_marker(key, poses[index], _COLOURS[int(verdicts[index])],
                                      frame_id, stamp)
            self._keyframes[key] = marker
            markers.append(marker)
        self._shown[ids[stale]] = True
        self._shown_poses[ids[stale]] = poses[stale]
        self._shown_verdicts[ids[stale]] = verdicts[stale]
        if assessment is not self._judged:
            self._judged = assessment
            drawn = np.zeros((0, 2)) if assessment.consistent else points()
            self._verdict = (_points_marker(drawn, frame_id, stamp),
                             _changes_marker(assessment, frame_id, stamp))
            markers.extend(self._verdict)
        if self._legend is None and snapshot.keyframe_count:
            self._legend = _legend_marker(snapshot.poses[0], frame_id, stamp)
            markers.append(self._legend)
        return MarkerArray(markers=markers)

    def _make_room(self, ids: int, frame_id: str) -> None:
        """Room for keyframe ids below `ids`; a new frame redraws every keyframe."""
        if frame_id != self._frame_id:
            self._shown[:] = False
            self._frame_id = frame_id
        if ids > self._shown.size:
            rows = max(ids, 2 * self._shown.size)
            self._shown, self._shown_poses, self._shown_verdicts = (
                with_rows(array, rows)
                for array in (self._shown, self._shown_poses, self._shown_verdicts))

    def all(self) -> MarkerArray:
        """Every marker published so far, for a subscriber that joined late.

        Returns
        -------
        The keyframes' markers as last published, the verdict's and the legend.
        """
        markers = list(self._keyframes.values())
        markers += [*(self._verdict or ()), *([self._legend] if self._legend else [])]
        return MarkerArray(markers=markers)

    def clear(self, frame_id: str, stamp: Time) -> MarkerArray:
        """DELETEALL (after a reset: the old session's markers go); forget what was shown.

        Parameters
        ----------
        frame_id: the marker's frame.
        stamp: the marker's header stamp.

        Returns
        -------
        An array of the one DELETEALL marker.
        """
        self._keyframes.clear()
        self._shown[:] = False
        self._verdict = self._judged = self._legend = None
        marker = Marker(action=Marker.DELETEALL)
        marker.header.frame_id, marker.header.stamp = frame_id, stamp
        return MarkerArray(markers=[marker])
