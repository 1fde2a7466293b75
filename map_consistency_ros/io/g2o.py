"""g2o SE(2) graph files, with laser scans attached to vertices (the gm2dl flavour).

Records (whitespace separated, one per line):

    VERTEX_SE2 id x y theta
    EDGE_SE2 from to dx dy dtheta I11 I12 I13 I22 I23 I33   (upper triangle of the information)
    FIX id [id ...]
    ROBOTLASER1 ...   a CARMEN laser record (see io.carmen) attached to the vertex line above it

Vertices may carry any integer ids; they become indices 0..N-1 in increasing id order, so
consecutive ids are consecutive indices (the odometry / loop-closure split of PoseGraph).
Lines starting with '#' and empty lines are skipped; any other record is an error.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.core.backend import (PoseGraph, edge_problem, information_from_upper,
                                              information_upper)
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io.carmen import (READ_ERRORS, CarmenLog, LaserAngles,
                                           check_laser_records, check_poses, open_text,
                                           parse_floats, parse_robotlaser)
from map_consistency_ros.io.errors import InputError, not_a_file
from map_consistency_ros.io.staging import staged

_LASER_OFFSET_TOLERANCE = 1e-6


@dataclass(frozen=True)
class G2oGraph:
    """A graph file's content: the pose graph, the file's vertex ids, and the attached scans.

    `laser` holds the scans (ranges, laser and robot poses as written, timestamps, line
    numbers, beam geometry) and `laser_vertices (L,)` the vertex index of each; both are None
    when the file carries no laser records. `source` names the graph in errors (the file read;
    'graph' for one built in memory).
    """

    graph: PoseGraph
    vertex_ids: np.ndarray
    laser: CarmenLog | None = None
    laser_vertices: np.ndarray | None = None
    source: str = 'graph'

    @property
    def laser_offset(self) -> np.ndarray:
        """(3,) pose of the laser in the robot frame, the same for every scan."""
        if self.laser is None:
            raise ValueError('the graph carries no laser data')
        offsets = se2.relative(self.laser.robot_poses, self.laser.laser_poses)
        spread = np.abs(se2.wrap_angle(offsets - offsets[0])).max()
        if spread > _LASER_OFFSET_TOLERANCE:
            raise InputError(self.laser.path, f'the laser offset from the robot varies by '
                                              f'{spread:.3g} between scans')
        return offsets[0]

    def scan_ranges(self) -> np.ndarray:
        """The scans' ranges re-ordered to follow the vertices.

        Returns
        -------
        (N, K) ranges in metres, row i the scan of vertex index i. Raises InputError when the
        graph carries no laser records or some vertex has no scan or more than one.
        """
        if self.laser is None:
            raise InputError(self.source, 'the graph carries no laser data (ROBOTLASER1 lines)')
        count = self.graph.vertex_count
        seen = np.bincount(self.laser_vertices, minlength=count)
        if np.any(seen != 1):
            vertex = int(np.flatnonzero(seen != 1)[0])
            raise InputError(self.laser.path, f'vertex {int(self.vertex_ids[vertex])} has '
                                              f'{int(seen[vertex])} laser scans, expected 1')
        ranges = np.empty_like(self.laser.ranges)
        ranges[self.laser_vertices] = self.laser.ranges
        return ranges


def read_g2o(path: str | Path) -> G2oGraph:
    """Read a g2o SE(2) file (the record layout is in the module docstring).

    Parameters
    ----------
    path: the file, plain or gzip-compressed.

    Returns
    -------
    A G2oGraph: vertices re-indexed 0..N-1 in increasing id order, `vertex_ids (N,)` the file's
    ids, and the ROBOTLASER1 scans (None when there are none). Raises InputError naming the file
    and line for a missing or unreadable file, a malformed, non-numeric or non-finite record, a
    vertex pose or laser value outside its plausible range (io/limits.py), an unsupported
    record type, a duplicate or unknown vertex id, an edge from a vertex to itself, an edge
    that core.backend.edge_problem refuses (a measurement beyond MAX_POSE_EXTENT, information
    entries beyond MAX_INFORMATION, an information matrix that is not positive definite), a
    ROBOTLASER1 line before any vertex,
    scans with differing beam counts, or a file without vertices.
    """
    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise not_a_file(path)
    reader = _Reader(source)
    try:
        with open_text(path) as stream:
            for line_number, text in enumerate(stream, start=1):
                tokens = text.split()
                if tokens and not tokens[0].startswith('#'):
                    reader.record(tokens, line_number)
    except READ_ERRORS as error:
        raise InputError(source, f'cannot read the file ({error})') from None
    return reader.result()


def write_g2o(path: str | Path, content: G2oGraph) -> None:
    """Write `content` so that `read_g2o` gives it back (poses to 1e-9, ranges as given).

    Each scan's ROBOTLASER1 line follows its vertex, with the robot pose at the vertex's
    current pose and the laser pose composed with the laser offset.

    Parameters
    ----------
    path: the file to write (plain text; replaced if it exists), whole or not at all
        (io/staging.py).
    content: the graph, its vertex ids (written in place of the indices) and optional scans;
        the scans must share one laser offset (`G2oGraph.laser_offset`, else InputError).
    """
    graph, ids = content.graph, content.vertex_ids
    scan_of = np.full(graph.vertex_count, -1)
    offset = None
    if content.laser is not None:
        scan_of[content.laser_vertices] = np.arange(len(content.laser_vertices))
        offset = content.laser_offset
    lines = []
    for index, (pose, vertex_id) in enumerate(zip(graph.poses, ids)):
        lines.append(f'VERTEX_SE2 {vertex_id} {_numbers(pose)}')
        if scan_of[index] >= 0:
            lines.append(_robotlaser_line(content.laser, scan_of[index], pose,
                                          se2.compose(pose, offset)))
    if graph.fixed.any():
        lines.append('FIX ' + ' '.join(str(vertex_id) for vertex_id in ids[graph.fixed]))
    upper = information_upper(graph.information)
    for a, b, measurement, info in zip(ids[graph.edge_from], ids[graph.edge_to],
                                       graph.measurements, upper):
        lines.append(f'EDGE_SE2 {a} {b} {_numbers(measurement)} {_numbers(info)}')
    with staged(path) as target:
        target.write_text('\n'.join(lines) + '\n')


def _numbers(values: np.ndarray) -> str:
    return ' '.join(f'{value:.17g}' for value in values)


def _robotlaser_line(laser: CarmenLog, scan: int, robot_pose: np.ndarray,
                     laser_pose: np.ndarray) -> str:
    angles = laser.stated_angles
    ranges = laser.ranges[scan]
    stamp = f'{laser.timestamps[scan]:.6f}'
    return (f'ROBOTLASER1 0 {_numbers([angles.start_angle, angles.fov, angles.resolution])} '
            f'{angles.max_range:.17g} 0.01 0 {len(ranges)} {_numbers(ranges)} 0 '
            f'{_numbers(laser_pose)} {_numbers(robot_pose)} 0 0 0 0 0 {stamp} g2o {stamp}')


class _Reader:
    """Accumulates records line by line; `result()` checks references and builds the graph."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.vertices: dict[int, tuple[np.ndarray, int]] = {}
        self.edges: list[tuple[int, int, np.ndarray, int]] = []
        self.fixed: list[tuple[int, int]] = []
        self.scans: list[tuple[int, tuple, int]] = []
        self.last_vertex: int | None = None

    def record(self, tokens: list[str], line: int) -> None:
        tag = tokens[0]
        if tag == 'VERTEX_SE2':
            self._expect(tokens, 5, line)
            vertex = self._id(tokens[1], line)
            if vertex in self.vertices:
                raise InputError(self.source, f'vertex {vertex} defined twice', line)
            self.vertices[vertex] = (parse_floats(tokens[2:5], self.source, line, 'pose value'),
                                     line)
            self.last_vertex = vertex
        elif tag == 'EDGE_SE2':
            self._expect(tokens, 12, line)
            values = self._finite(tokens[3:12], line, 'edge value')
            self.edges.append((self._id(tokens[1], line), self._id(tokens[2], line), values, line))
        elif tag == 'FIX':
            if len(tokens) < 2:
                raise InputError(self.source, 'FIX names no vertex', line)
            self.fixed.extend((self._id(token, line), line) for token in tokens[1:])
        elif tag == 'ROBOTLASER1':
            if self.last_vertex is None:
                raise InputError(self.source, 'ROBOTLASER1 before any VERTEX_SE2', line)
            self.scans.append((self.last_vertex, parse_robotlaser(tokens, self.source, line),
                               line))
        else:
            raise InputError(self.source, f'unsupported record {tag!r}', line)

    def result(self) -> G2oGraph:
        if not self.vertices:
            raise InputError(self.source, 'no VERTEX_SE2 records')
        ids = np.array(sorted(self.vertices), dtype=np.int64)
        index = {vertex: position for position, vertex in enumerate(ids)}
        poses = np.array([self.vertices[vertex][0] for vertex in ids])
        check_poses(poses, self.source, [self.vertices[vertex][1] for vertex in ids],
                    'vertex pose')
        fixed = np.zeros(len(ids), dtype=bool)
        for vertex, line in self.fixed:
            fixed[self._index(index, vertex, line)] = True
        edge_from = np.array([self._index(index, a, line) for a, _, _, line in self.edges],
                             dtype=np.int64)
        edge_to = np.array([self._index(index, b, line) for _, b, _, line in self.edges],
                           dtype=np.int64)
        values = np.array([edge[2] for edge in self.edges]).reshape(-1, 9)
        for (a, b, _, line) in self.edges:
            if a == b:
                raise InputError(self.source, f'edge connects vertex {a} to itself', line)
        information = information_from_upper(values[:, 3:])
        self._check_edges(values[:, :3], information)
        graph = PoseGraph(poses=poses, edge_from=edge_from, edge_to=edge_to,
                          measurements=values[:, :3], information=information, fixed=fixed)
        laser, laser_vertices = self._laser(index)
        return G2oGraph(graph=graph, vertex_ids=ids, laser=laser, laser_vertices=laser_vertices,
                        source=self.source)

    def _laser(self, index: dict[int, int]) -> tuple[CarmenLog | None, np.ndarray | None]:
        if not self.scans:
            return None, None
        first_beams = len(self.scans[0][1][0])
        for _, parsed, line in self.scans:
            if len(parsed[0]) != first_beams:
                raise InputError(self.source, f'{len(parsed[0])} beams, but the first laser '
                                              f'record has {first_beams}', line)
        angles: LaserAngles = self.scans[0][1][4]
        log = CarmenLog(path=self.source, ranges=np.array([s[1][0] for s in self.scans]),
                        laser_poses=np.array([s[1][1] for s in self.scans]),
                        robot_poses=np.array([s[1][2] for s in self.scans]),
                        timestamps=np.array([s[1][3] for s in self.scans]),
                        line_numbers=np.array([s[2] for s in self.scans]),
                        stated_angles=angles, parameters={})
        check_laser_records(log)
        return log, np.array([index[vertex] for vertex, _, _ in self.scans], dtype=np.int64)

    def _check_edges(self, measurements: np.ndarray, information: np.ndarray) -> None:
        problem = edge_problem(measurements, information)
        if problem is not None:
            raise InputError(self.source, f'EDGE_SE2 {problem[1]}', self.edges[problem[0]][3])

    def _finite(self, tokens: list[str], line: int, what: str) -> np.ndarray:
        values = parse_floats(tokens, self.source, line, what)
        if not np.all(np.isfinite(values)):
            raise InputError(self.source, f'{what} is not finite', line)
        return values

    def _expect(self, tokens: list[str], count: int, line: int) -> None:
        if len(tokens) != count:
            raise InputError(self.source, f'{tokens[0]} needs {count - 1} fields, '
                                          f'got {len(tokens) - 1}', line)

    def _id(self, token: str, line: int) -> int:
        try:
            return int(token)
        except ValueError:
            raise InputError(self.source, f'vertex id must be an integer, got {token!r}',
                             line) from None

    def _index(self, index: dict[int, int], vertex: int, line: int) -> int:
        if vertex not in index:
            raise InputError(self.source, f'unknown vertex {vertex}', line)
        return index[vertex]
