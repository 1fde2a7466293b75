"""SE(2) pose graph: vertices (poses), edges (relative measurements with information matrices).

Vertices are addressed by index 0..N-1. An edge from i to j measures the pose of j in the
frame of i. Edges between consecutive vertices (|from - to| == 1) are odometry; all others
are loop closures, the only edges a robust back-end may down-weight.

This module also owns the constraint row format in which the node and bags carry a graph's
edges between stamped keyframes: `CONSTRAINT_FIELDS`, one row per edge.
"""
from dataclasses import dataclass, replace

import numpy as np

from map_consistency_ros.core.geometry import se2

# [stamp_from, stamp_to, dx, dy, dtheta, I11, I12, I13, I22, I23, I33]: stamps in seconds,
# the pose of `to` in the frame of `from`, the upper triangle of the 3x3 information matrix.
CONSTRAINT_FIELDS = ('stamp_from', 'stamp_to', 'dx', 'dy', 'dtheta',
                     'I11', 'I12', 'I13', 'I22', 'I23', 'I33')
CONSTRAINT_WIDTH = len(CONSTRAINT_FIELDS)
_STAMPS, _MEASUREMENT, _UPPER_TRIANGLE = slice(0, 2), slice(2, 5), slice(5, 11)
_UPPER = np.triu_indices(3)
# Information entries beyond this (a standard deviation below a micrometre) make the
# normal equations overflow or lose every other edge to rounding: no honest tuning.
MAX_INFORMATION = 1e12
# Coordinates of poses and measured displacements (m, rad) beyond this are corrupt numbers, not
# a place (geometry.se2.MAX_EXTENT): the node's max_pose_extent defaults to it, and a graph is
# tuned within it.
MAX_POSE_EXTENT = se2.MAX_EXTENT


@dataclass(frozen=True)
class PoseGraph:
    """N poses (x, y, theta) and E edges; arrays are validated and made read-only.

    `poses (N, 3)` is the current estimate (an optimizer's initial guess), `edge_from`,
    `edge_to (E,)` vertex indices, `measurements (E, 3)` the pose of `to` seen from `from`,
    `information (E, 3, 3)` symmetric positive definite, `fixed (N,)` vertices an optimizer
    must not move.
    """

    poses: np.ndarray
    edge_from: np.ndarray
    edge_to: np.ndarray
    measurements: np.ndarray
    information: np.ndarray
    fixed: np.ndarray | None = None

    def __post_init__(self) -> None:
        poses = _float_array(self.poses, (-1, 3), 'poses')
        count = len(poses)
        edge_from = np.asarray(self.edge_from, dtype=np.int64).reshape(-1)
        edge_to = np.asarray(self.edge_to, dtype=np.int64).reshape(-1)
        edges = len(edge_from)
        measurements = _float_array(self.measurements, (edges, 3), 'measurements')
        information = _float_array(self.information, (edges, 3, 3), 'information')
        fixed = (np.zeros(count, dtype=bool) if self.fixed is None
                 else np.asarray(self.fixed, dtype=bool).reshape(-1))
        _check_edges(count, edge_from, edge_to, information)
        if fixed.shape != (count,):
            raise ValueError(f'fixed has {fixed.shape[0]} flags for {count} poses')
        for name, value in (('poses', poses), ('edge_from', edge_from), ('edge_to', edge_to),
                            ('measurements', measurements), ('information', information),
                            ('fixed', fixed)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def vertex_count(self) -> int:
        return len(self.poses)

    @property
    def edge_count(self) -> int:
        return len(self.edge_from)

    @property
    def is_loop_closure(self) -> np.ndarray:
        """(E,) bool: True for loop closures (|from - to| != 1), False for odometry edges."""
        return np.abs(self.edge_from - self.edge_to) != 1

    def with_poses(self, poses: np.ndarray) -> 'PoseGraph':
        """The same edges with another estimate of the poses (e.g. another initial guess).

        Parameters
        ----------
        poses: (N, 3) poses (x, y, theta), one per vertex.

        Returns
        -------
        A new PoseGraph; ValueError unless `poses` are N finite poses.
        """
        return replace(self, poses=poses)

    def odometry_chain(self) -> np.ndarray:
        """(N, 3) poses composed along the odometry edges from the first pose.

        This is the incremental solution: each pose is placed relative to its predecessor
        by the first odometry edge between them (inverted when it points backwards). A pose
        without an odometry edge to its predecessor keeps its current estimate relative
        to that predecessor.

        Returns
        -------
        (N, 3) poses, the first the graph's first pose.
        """
        steps = se2.relative(self.poses[:-1], self.poses[1:])
        odometry = ~self.is_loop_closure
        forward = odometry & (self.edge_to == self.edge_from + 1)
        backward = odometry & (self.edge_to == self.edge_from - 1)
        # The first edge between a pair wins (fancy assignment keeps the last, hence reversed):
        # graphs list odometry before any further sequential constraint.
        forward, backward = np.flatnonzero(forward)[::-1], np.flatnonzero(backward)[::-1]
        steps[self.edge_to[backward]] = se2.inverse(self.measurements[backward])
        steps[self.edge_from[forward]] = self.measurements[forward]
        return se2.chain(self.poses[0], steps)


def _float_array(value: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.array(value, dtype=np.float64)
    try:
        array = array.reshape(shape)
    except ValueError:
        raise ValueError(f'{name} has shape {np.shape(value)}, expected {shape}') from None
    if not np.all(np.isfinite(array)):
        raise ValueError(f'{name} holds NaN or infinite values')
    return array


def _check_edges(count: int, edge_from: np.ndarray, edge_to: np.ndarray,
                 information: np.ndarray) -> None:
    if edge_to.shape != edge_from.shape:
        raise ValueError(f'{len(edge_from)} edge sources but {len(edge_to)} edge targets')
    ends = np.concatenate([edge_from, edge_to])
    if ends.size and (ends.min() < 0 or ends.max() >= count):
        raise ValueError(f'an edge refers to a vertex outside 0..{count - 1}')
    if np.any(edge_from == edge_to):
        raise ValueError(f'edge {int(np.argmax(edge_from == edge_to))} connects a vertex to itself')
    problem = information_problem(information)
    if problem is not None:
        raise ValueError(f'an information matrix {problem[1]}')


def information_problem(information: np.ndarray) -> tuple[int, str] | None:
    """The first information matrix that is not symmetric positive definite, and why.

    Parameters
    ----------
    information: (E, 3, 3) finite information matrices.

    Returns
    -------
    (its index, 'is not symmetric' or 'is not positive definite'); None when all are.
    """
    if information.size == 0:
        return None
    asymmetric = ~np.isclose(information, np.swapaxes(information, 1, 2)).all(axis=(1, 2))
    if asymmetric.any():
        return int(np.flatnonzero(asymmetric)[0]), 'is not symmetric'
    with np.errstate(invalid='ignore', over='ignore'):
        smallest = np.linalg.eigvalsh(information)[:, 0]
    not_definite = np.flatnonzero(~(smallest > 0.0))
    if not_definite.size:
        return int(not_definite[0]), 'is not positive definite'
    return None


def information_upper(information: np.ndarray) -> np.ndarray:
    """The upper triangles of information matrices, as constraint rows carry them.

    Parameters
    ----------
    information: (E, 3, 3) symmetric information matrices.

    Returns
    -------
    (E, 6) float rows I11 I12 I13 I22 I23 I33.
    """
    return np.asarray(information, dtype=np.float64)[:, _UPPER[0], _UPPER[1]]


def information_from_upper(upper: np.ndarray) -> np.ndarray:
    """Symmetric matrices from their upper triangles (information_upper undone).

    Parameters
    ----------
    upper: (E, 6) rows I11 I12 I13 I22 I23 I33.

    Returns
    -------
    (E, 3, 3) symmetric float matrices (not checked to be positive definite).
    """
    upper = np.asarray(upper, dtype=np.float64)
    matrices = np.zeros((upper.shape[0], 3, 3))
    matrices[:, _UPPER[0], _UPPER[1]] = upper
    matrices[:, _UPPER[1], _UPPER[0]] = upper
    return matrices


def constraint_rows(stamp_from: np.ndarray, stamp_to: np.ndarray, measurements: np.ndarray,
                    information: np.ndarray) -> np.ndarray:
    """The constraint rows of edges between stamped keyframes.

    Parameters
    ----------
    stamp_from, stamp_to: (E,) stamps (s) of each edge's two keyframes.
    measurements: (E, 3) the pose (dx, dy, dtheta) of `to` in the frame of `from` (m, rad).
    information: (E, 3, 3) symmetric information matrices.

    Returns
    -------
    (E, 11) rows laid out as CONSTRAINT_FIELDS (unchecked: see check_constraint_rows).
    """
    return np.column_stack([stamp_from, stamp_to, measurements, information_upper(information)])


def split_constraint_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                      np.ndarray]:
    """The parts of constraint rows (constraint_rows undone).

    Parameters
    ----------
    rows: (E, 11) float rows laid out as CONSTRAINT_FIELDS.

    Returns
    -------
    (stamp_from (E,), stamp_to (E,), measurements (E, 3), information (E, 3, 3)); the
    first three are views of `rows`.
    """
    stamps = rows[:, _STAMPS]
    return (stamps[:, 0], stamps[:, 1], rows[:, _MEASUREMENT],
            information_from_upper(rows[:, _UPPER_TRIANGLE]))


def edge_problem(measurements: np.ndarray, information: np.ndarray,
                 extent: float = MAX_POSE_EXTENT) -> tuple[int, str] | None:
    """The first edge whose numbers no solve can take, and why: the one number policy of a
    graph's edges, wherever they come from (constraint rows, g2o files, a graph to tune).

    Parameters
    ----------
    measurements: (E, 3) the edges' measurements (dx, dy in m, dtheta in rad).
    information: (E, 3, 3) their information matrices.
    extent: the largest plausible magnitude of a measurement's coordinates.

    Returns
    -------
    (the edge's index, the reason: non-finite values, a measurement beyond `extent`,
    information entries beyond MAX_INFORMATION, an information matrix that is not symmetric
    positive definite); None when every edge is sound.
    """
    measurements = np.asarray(measurements, dtype=np.float64).reshape(-1, 3)
    information = np.asarray(information, dtype=np.float64).reshape(-1, 3, 3)
    finite = (np.isfinite(measurements).all(axis=1)
              & np.isfinite(information).all(axis=(1, 2)))
    with np.errstate(invalid='ignore'):
        beyond = finite & (np.abs(measurements).max(axis=1, initial=0.0) > extent)
        huge = finite & (np.abs(information).max(axis=(1, 2), initial=0.0) > MAX_INFORMATION)
    found = [(int(np.flatnonzero(mask)[0]), reason) for mask, reason in (
        (~finite, 'has non-finite values'),
        (beyond, f'has a measurement beyond {extent:g} (m, rad)'),
        (huge, f'has information entries beyond {MAX_INFORMATION:g}, which overflow the '
               'solver')) if mask.any()]
    sound = finite & ~huge
    matrices = np.where(sound[:, None, None], information, np.eye(3))
    problem = information_problem(matrices)
    if problem is not None:
        found.append((problem[0], f'has an information matrix that {problem[1]}'))
    # the first edge, and its first reason in the order above (min keeps the first of ties)
    return min(found, key=lambda item: item[0]) if found else None


def check_constraint_rows(rows: np.ndarray, extent: float = MAX_POSE_EXTENT) -> np.ndarray:
    """Constraint rows checked before they become edges.

    Parameters
    ----------
    rows: (E, 11) rows laid out as CONSTRAINT_FIELDS (anything np.asarray takes).
    extent: the largest plausible magnitude of a measurement's coordinates (edge_problem).

    Returns
    -------
    The rows as a float (E, 11) array. ValueError naming the first bad row on a wrong shape,
    non-finite values, an edge from a stamp to itself, or an edge that edge_problem refuses
    (a measurement beyond `extent`, information entries beyond MAX_INFORMATION, an
    information matrix that is not positive definite).
    """
    rows = np.asarray(rows, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != CONSTRAINT_WIDTH:
        raise ValueError(f'constraint rows must have shape (E, {CONSTRAINT_WIDTH}), '
                         f'got {rows.shape}')
    bad = ~np.isfinite(rows).all(axis=1)
    if bad.any():
        raise ValueError(f'constraint row {int(np.flatnonzero(bad)[0])} has non-finite values')
    stamp_from, stamp_to, measurements, information = split_constraint_rows(rows)
    loops = np.flatnonzero(stamp_from == stamp_to)
    if loops.size:
        raise ValueError(f'constraint row {int(loops[0])} connects stamp {stamp_from[loops[0]]} '
                         'to itself')
    problem = edge_problem(measurements, information, extent)
    if problem is not None:
        raise ValueError(f'constraint row {problem[0]} {problem[1]}')
    return rows


def tuning_problem(graph: PoseGraph, extent: float = MAX_POSE_EXTENT) -> str | None:
    """Why DCS tuning of `graph` could not be honest: the one check before a Phi search, for
    `map-consistency tune` and the node's retune alike.

    Refused: a pose or an edge with numbers no solve can take (coordinates beyond `extent`,
    edges that edge_problem refuses: information entries beyond MAX_INFORMATION overflow the
    solve or drown the other edges), a disconnected graph (the parts float freely against each
    other, any Phi gives some map), and one without loop closures (DCS scales only those:
    every Phi gives the same map).

    Parameters
    ----------
    graph: the graph the Phi search would run on.
    extent: the largest plausible magnitude of a pose's or a measurement's coordinates.

    Returns
    -------
    The first reason, a sentence for the user; None when it can be tuned.
    """
    # scipy.sparse only where it is used: `check` imports this package through the
    # configuration (TuningSettings) and tunes nothing
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    count = graph.vertex_count
    beyond = np.flatnonzero(np.abs(graph.poses).max(axis=1) > extent)
    if beyond.size:
        pose = graph.poses[beyond[0]]
        return (f'pose {int(beyond[0])} of {count} ({pose[0]:.3g}, {pose[1]:.3g}, '
                f'{pose[2]:.3g}) lies beyond {extent:g} (m, rad)')
    problem = edge_problem(graph.measurements, graph.information, extent)
    if problem is not None:
        edge = problem[0]
        return (f'edge {edge} (pose {int(graph.edge_from[edge])} to '
                f'{int(graph.edge_to[edge])}) {problem[1]}')
    if graph.edge_count < count - 1:
        return (f'{graph.edge_count} constraints for {count} poses: a connected graph needs '
                f'at least {count - 1}')
    adjacency = coo_matrix((np.ones(graph.edge_count), (graph.edge_from, graph.edge_to)),
                           shape=(count, count))
    parts = connected_components(adjacency, directed=False)[0]
    if parts > 1:
        return (f'the constraints split the {count} poses into {parts} disconnected parts; '
                'every pose must be linked to the others')
    if not graph.is_loop_closure.any():
        return 'no loop closure among the constraints: DCS has nothing to tune'
    return None
