"""slam_toolbox's published graph -> the monitor's keyframe estimate (stamps (M,), poses (M, 3)).

slam_toolbox publishes two things a keyframe estimate can be made of (facts and source
references in docs/slam_bridges.md):

- `pose` (PoseWithCovarianceStamped): one message per scan the mapper accepted, stamped with
  that scan's stamp, holding the scan's full corrected pose at that moment. Accepted scans
  get consecutive vertex ids 0, 1, 2, ... in processing order, so the k-th `pose` message
  of a session is vertex `first_vertex_id + k`.
- `slam_toolbox/graph_visualization` (MarkerArray): every `map_update_interval` a DELETEALL,
  then one SPHERE per vertex (namespace `slam_toolbox`, marker id = vertex id) at the
  vertex's current corrected position. The orientation is always the identity: headings
  after a loop closure are not published.

The bridge keeps a reference pose per vertex: its `pose` message until the vertex has been in
a marker snapshot, then its estimate at the previous snapshot. The heading change of a vertex
is the rotation of the least squares rigid motion (2D Kabsch / Procrustes) that takes the
reference positions of its neighbourhood (up to `heading_window` vertices on each side, in id
order) onto their current positions; its heading is the reference heading plus that rotation.
A loop-closure correction is smooth along the trajectory, hence locally rigid, and the fit
recovers it. A vertex that has not moved keeps its reference heading. Where a neighbourhood
cannot show its rotation (too small: the robot turned on the spot; or not moved rigidly), the
rotation is interpolated along the ids from the nearest vertices whose fits are good, and
counted. Errors measured on the Intel lab data: docs/slam_bridges.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from map_consistency_ros.core.geometry import se2


@dataclass(frozen=True)
class BridgeSettings:
    """How vertices are associated with scans and how their headings are recovered."""

    first_vertex_id: int = field(default=0, metadata={
        'description': 'vertex id of the first pose message the bridge receives: 0 for a '
                       'slam_toolbox session started with the bridge listening; a session '
                       'continued from a serialized pose graph starts at its vertex count',
        'range': (0, 2**31 - 1), 'unit': 'vertex id'})
    heading_window: int = field(default=2, metadata={
        'description': 'vertices on each side of a vertex (in id order) whose rigid motion '
                       'since the previous snapshot gives the vertex its heading change',
        'range': (1, 100), 'unit': 'vertices'})
    max_fit_residual: float = field(default=0.05, metadata={
        'description': 'largest RMS residual of a neighbourhood rigid fit for its rotation '
                       'to be used; a vertex with a worse fit takes its rotation from its '
                       'neighbours along the ids',
        'range': (1e-6, 10.0), 'unit': 'm'})
    min_spread: float = field(default=0.5, metadata={
        'description': 'smallest RMS distance of a neighbourhood from its centroid for its '
                       'fit to determine a rotation (the robot turning on the spot makes '
                       'vertices without spread); a smaller one takes its rotation from its '
                       'neighbours along the ids',
        'range': (1e-6, 10.0), 'unit': 'm'})
    still_tolerance: float = field(default=1e-6, metadata={
        'description': 'a vertex that moved less than this since its reference pose keeps '
                       'its reference heading; the fit of a moved vertex uses only moved '
                       'neighbours',
        'range': (0.0, 1.0), 'unit': 'm'})

    def __post_init__(self) -> None:
        for item in fields(self):
            low, high = item.metadata['range']
            value = getattr(self, item.name)
            if not low <= value <= high:
                raise ValueError(f'{item.name} must be in [{low}, {high}], got {value}')


@dataclass(frozen=True)
class BridgeCounts:
    """What the last `keyframes()` could and could not use, for diagnostics."""

    keyframes: int  # vertices returned: associated with a pose message
    pending_poses: int  # pose messages with no vertex in the latest marker snapshot
    vertices_without_pose: int  # vertices in the snapshot with no pose message (yet)
    interpolated: int  # keyframes whose own fit was poor: rotation interpolated along the ids
    empty_snapshots: int  # snapshots without vertices, ignored (slam_toolbox interactive mode)


@dataclass(frozen=True)
class HeadingFit:
    """Per-vertex result of the neighbourhood rigid fits (V vertices)."""

    rotation: np.ndarray  # (V,) radians, reference -> current (zero for still points)
    residual: np.ndarray  # (V,) RMS metres of the fitted motion
    spread: np.ndarray  # (V,) RMS metres of the reference neighbourhood about its centroid
    still: np.ndarray  # (V,) bool: the point itself did not move


def neighbourhoods(count: int, window: int) -> np.ndarray:
    """The neighbours of each element of a sequence.

    Parameters
    ----------
    count: the length of the sequence.
    window: the neighbours on each side.

    Returns
    -------
    (count, 2 window + 1) int indices of k - window .. k + window for each element k, -1 off
    the sequence's ends.
    """
    offsets = np.arange(-window, window + 1)
    index = np.arange(count)[:, None] + offsets[None, :]
    return np.where((index >= 0) & (index < count), index, -1)


def fit_rotations(reference: np.ndarray, current: np.ndarray, window: int,
                  still_tolerance: float) -> HeadingFit:
    """Least-squares rigid motion of each point's neighbourhood from `reference` to `current`.

    A point that moved at most `still_tolerance` is still: no correction reached it since its
    reference was taken, so its rotation is zero. For a moved point k the neighbourhood is
    the moved points among k - window .. k + window (truncated at the ends): a still
    neighbour's reference was taken after the correction that moved k (slam_toolbox publishes
    a scan's pose after the loop closure that scan triggered), so it would pull the fit
    towards no rotation. The rotation maximises sum (R a_j) . b_j over the centred
    neighbourhood points a (reference) and b (current): angle = atan2(sum a x b, sum a . b).

    Parameters
    ----------
    reference: (V, 2) the points' reference positions, metres, ordered along the trajectory.
    current: (V, 2) the same V points' current positions.
    window: the neighbours on each side of a point.
    still_tolerance: the largest motion of a still point, metres.

    Returns
    -------
    The HeadingFit of the V points.
    """
    index = neighbourhoods(len(reference), window)
    safe = np.where(index >= 0, index, 0)
    moved = np.linalg.norm(current - reference, axis=1) > still_tolerance
    inside = (index >= 0) & (moved[safe] == moved[:, None])
    weight = inside.astype(np.float64)[..., None]
    members = inside.sum(axis=1)[:, None]
    a_centre = (reference[safe] * weight).sum(axis=1) / members
    b_centre = (current[safe] * weight).sum(axis=1) / members
    a = (reference[safe] - a_centre[:, None, :]) * weight
    b = (current[safe] - b_centre[:, None, :]) * weight
    cross = (a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]).sum(axis=1)
    dot = (a * b).sum(axis=(1, 2))
    rotation = np.where(moved, np.arctan2(cross, dot), 0.0)
    cos_r, sin_r = np.cos(rotation)[:, None], np.sin(rotation)[:, None]
    rotated = np.stack([cos_r * a[..., 0] - sin_r * a[..., 1],
                        sin_r * a[..., 0] + cos_r * a[..., 1]], axis=-1)
    misfit = ((rotated - b) ** 2).sum(axis=2) * inside
    residual = np.sqrt(misfit.sum(axis=1) / members[:, 0])
    spread = np.sqrt((a ** 2).sum(axis=(1, 2)) / members[:, 0])
    return HeadingFit(rotation=rotation, residual=residual, spread=spread, still=~moved)


def interpolate_rotations(rotation: np.ndarray, trusted: np.ndarray) -> np.ndarray:
    """Rotations with the untrusted entries interpolated along the sequence from trusted ones.

    A loop-closure correction rotates the trajectory smoothly along it, so a vertex whose own
    neighbourhood cannot show the rotation (too small, or not moved rigidly) takes it from the
    nearest trusted vertices on either side (the nearest one beyond the ends); with no trusted
    vertex at all the rotation is zero, i.e. the reference headings are kept.

    Parameters
    ----------
    rotation: (V,) radians, in sequence order.
    trusted: (V,) bool, the entries to interpolate from.

    Returns
    -------
    (V,) radians: linear interpolation over the index of the unwrapped trusted rotations (so
    trusted entries may differ from `rotation` by multiples of 2 pi); zeros when none is
    trusted.
    """
    if not trusted.any():
        return np.zeros_like(rotation)
    where = np.flatnonzero(trusted)
    # Unwrapped, so that interpolating between rotations either side of +-pi stays short.
    known = np.unwrap(rotation[where])
    return np.interp(np.arange(rotation.size), where, known)


def _finite(array: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    """`array` as float64 of `shape` (-1: any length), or ValueError naming `name`."""
    value = np.asarray(array, dtype=np.float64)
    if value.ndim != len(shape) or any(want not in (-1, got)
                                       for want, got in zip(shape, value.shape)):
        raise ValueError(f'{name} must have shape {shape}, got {value.shape}')
    if not np.isfinite(value).all():
        raise ValueError(f'{name} must be finite')
    return value


def _vertex_ids(ids: np.ndarray) -> np.ndarray:
    """`ids` as int64 (V,), or ValueError for non-integers, negatives or duplicates."""
    value = np.asarray(ids)
    if value.ndim != 1:
        raise ValueError(f'ids must have shape (V,), got {value.shape}')
    if value.size and not np.issubdtype(value.dtype, np.integer):
        as_float = value.astype(np.float64)
        if not (np.isfinite(as_float).all() and (as_float == np.round(as_float)).all()):
            raise ValueError('ids must be integers')
    value = value.astype(np.int64)
    if (value < 0).any():
        raise ValueError('ids must not be negative')
    unique, counts = np.unique(value, return_counts=True)
    if (counts > 1).any():
        # slam_toolbox's marker ids are per-laser state ids: two lasers repeat them.
        raise ValueError(f'duplicate vertex ids {unique[counts > 1][:5].tolist()} (one '
                         'graph_visualization message per laser is supported)')
    return value


class SlamToolboxBridge:
    """Keyframe estimate from slam_toolbox's `pose` messages and graph marker snapshots.

    Feed `add_pose` every `pose` message (stamp in seconds, pose (x, y, yaw) in the map frame)
    and `update_vertices` the SPHERE markers of namespace `slam_toolbox` of every
    graph_visualization message (the DELETEALL before them means the snapshot replaces the
    previous one: vertices missing from it are gone). `keyframes()` gives the current estimate
    of every vertex that has both, in id order. Messages on the two topics may arrive in
    either order: a vertex waits for its pose message and a pose message for its vertex.
    """

    def __init__(self, settings: BridgeSettings | None = None) -> None:
        self.settings = settings or BridgeSettings()
        self._stamps: list[float] = []
        self._stamp_set: set[float] = set()
        self._first_seen: list[np.ndarray] = []
        self._reference = np.empty((0, 3))
        self._ids = np.empty(0, dtype=np.int64)
        self._positions = np.empty((0, 2))
        self._empty_snapshots = 0
        self._counts = BridgeCounts(keyframes=0, pending_poses=0, vertices_without_pose=0,
                                    interpolated=0, empty_snapshots=0)

    def waits_for_poses(self, ids: np.ndarray) -> bool:
        """Whether a snapshot names vertices whose pose message has not come yet.

        slam_toolbox publishes every vertex's `pose` before any snapshot holding it, so such a
        snapshot overtook poses on their way (the topics are delivered independently).

        Parameters
        ----------
        ids: (V,) the snapshot's vertex ids.

        Returns
        -------
        True when its largest id lies beyond the pose messages received so far.
        """
        return bool(len(ids)) and int(np.max(ids)) >= (self.settings.first_vertex_id
                                                       + len(self._stamps))

    @property
    def counts(self) -> BridgeCounts:
        """Counts of the last `keyframes()` call."""
        return self._counts

    def add_pose(self, stamp: float, pose: np.ndarray) -> None:
        """One `pose` message: the next vertex's stamp and first-seen pose.

        Stamps need not increase: the association is by arrival order, and slam_toolbox
        processes scans in arrival order whatever their stamps (the Intel log has 4 scans
        stamped before their predecessor).

        Parameters
        ----------
        stamp: the message's stamp (its scan's), seconds.
        pose: (3,) the pose (x, y, yaw) in the map frame.

        Raises ValueError for a non-finite stamp or pose, or a stamp already received (a
        replayed message or a restarted session, which would shift every later association).
        """
        value = _finite(pose, (3,), 'pose')
        if not np.isfinite(stamp):
            raise ValueError(f'stamp must be finite, got {stamp}')
        if float(stamp) in self._stamp_set:
            raise ValueError(f'stamp {stamp} was already received')
        self._stamp_set.add(float(stamp))
        self._stamps.append(float(stamp))
        self._first_seen.append(value.copy())

    def update_vertices(self, ids: np.ndarray, positions: np.ndarray) -> None:
        """One graph_visualization snapshot; it replaces the previous one.

        A snapshot without vertices is ignored and counted: slam_toolbox publishes no graph
        while it is empty, so an empty one means interactive mode (the vertices go to the
        interactive marker server), not that every keyframe is gone.

        Parameters
        ----------
        ids: (V,) vertex ids (the markers' ids).
        positions: (V, 2) their current positions in the map frame, metres.

        Raises ValueError (and keeps the previous snapshot) for duplicate, negative or
        non-integer ids, or positions that are not finite (V, 2).
        """
        vertex_ids = _vertex_ids(ids)
        points = _finite(positions, (len(vertex_ids), 2), 'positions')
        if not vertex_ids.size:
            self._empty_snapshots += 1
            return
        # The previous snapshot's estimate becomes the reference: each later fit then compares
        # two snapshots of one graph, not poses first seen before and after different loop
        # closures (which bends the fitted neighbourhood at every such seam, every time).
        index, poses, _ = self._estimate()
        self._reference[index] = poses
        order = np.argsort(vertex_ids)
        self._ids = vertex_ids[order]
        self._positions = points[order]

    def keyframes(self) -> tuple[np.ndarray, np.ndarray]:
        """The current estimate; it also sets `counts`.

        Returns
        -------
        (stamps (M,), poses (M, 3)): every vertex of the snapshot with its pose message, at
        its current pose, in id order.
        """
        index, poses, trusted = self._estimate()
        self._counts = BridgeCounts(
            keyframes=len(index),
            pending_poses=len(self._stamps) - len(index),
            vertices_without_pose=len(self._ids) - len(index),
            interpolated=int((~trusted).sum()),
            empty_snapshots=self._empty_snapshots)
        return np.asarray(self._stamps, dtype=np.float64)[index], poses

    def _estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose-message indices (M,), current poses (M, 3) and trusted fits (M,) of the snapshot."""
        settings = self.settings
        self._grow_reference()
        index = self._ids - settings.first_vertex_id
        known = (index >= 0) & (index < len(self._stamps))
        index = index[known]
        current = self._positions[known]
        reference = self._reference[index]
        fit = fit_rotations(reference[:, :2], current, settings.heading_window,
                            settings.still_tolerance)
        fitted = ~fit.still & (fit.residual <= settings.max_fit_residual) & (
            fit.spread >= settings.min_spread)
        trusted = fit.still | fitted
        # Only moved vertices' fits fill in a poorly fitted moved vertex: a still neighbour's
        # zero rotation belongs to a reference taken after the correction.
        rotation = np.where(trusted, fit.rotation, interpolate_rotations(fit.rotation, fitted))
        heading = reference[:, 2] + rotation
        # Wrapping only headings that left [-pi, pi] keeps unmoved headings bit for bit.
        heading = np.where(np.abs(heading) > np.pi, se2.wrap_angle(heading), heading)
        poses = np.column_stack([current, heading])
        return index, poses, trusted

    def _grow_reference(self) -> None:
        """Append the first-seen poses received since the last call to the reference poses."""
        missing = len(self._first_seen) - len(self._reference)
        if missing:
            self._reference = np.concatenate(
                [self._reference, np.asarray(self._first_seen[-missing:]).reshape(-1, 3)])
