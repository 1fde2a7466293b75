"""SE(2) pose graph: vertices (poses), edges (relative measurements with information matrices).

Vertices are addressed by index 0..N-1. An edge from i to j measures the pose of j in the
frame of i. Edges between consecutive vertices (|from - to| == 1) are odometry; all others
are loop closures, the only edges a robust back-end may down-weight.
"""
from dataclasses import dataclass, replace

import numpy as np

from map_consistency_ros.core import se2


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
        """The same edges with another estimate of the poses (e.g. another initial guess)."""
        return replace(self, poses=poses)

    def odometry_chain(self) -> np.ndarray:
        """(N, 3) poses composed along the odometry edges from the first pose.

        This is the incremental solution: each pose is placed relative to its predecessor
        by the first odometry edge between them (inverted when it points backwards). A pose
        without an odometry edge to its predecessor keeps its current estimate relative
        to that predecessor.
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
    if not np.allclose(information, np.swapaxes(information, 1, 2)):
        raise ValueError('an information matrix is not symmetric')
    if information.size and np.any(np.linalg.eigvalsh(information)[:, 0] <= 0.0):
        raise ValueError('an information matrix is not positive definite')
