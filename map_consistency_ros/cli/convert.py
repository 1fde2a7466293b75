"""Convert a CARMEN log, or a g2o graph with laser data, into a rosbag2 that replays like a
live SLAM run.

Inputs: a CARMEN log (FLASER / ROBOTLASER1, plain or gzip; scans in file order at their
logged laser poses), or a `.g2o` file whose every vertex carries one ROBOTLASER1 scan
(keyframes in vertex order at the vertex pose composed with the laser offset).
For every keyframe, in order, the bag gets:
  /scan         sensor_msgs/LaserScan: the ranges, beam angles from the input (ROBOTLASER1,
                PARAM or --fov), range_max = the sensor maximum the input states (else
                --range-max, else the largest reading), stamped with the logger timestamp;
  /trajectory   nav_msgs/Path: every laser pose so far, each stamped like its scan (the
                keyframe trajectory grows by one pose per keyframe);
  /constraints  std_msgs/Float64MultiArray: all edges between the keyframes so far, rows of
                stamp_from stamp_to dx dy dtheta I11 I12 I13 I22 I23 I33, every
                --constraints-every keyframes, after each loop closure and after the last.
                A log gives odometry edges between consecutive records (its odometry fields,
                --odometry-sigmas); a graph gives its own edges.
Replaying the bag (map-consistency replay) gives the same per-pair values and verdict as
`map-consistency check` on the log.

examples:
  map-consistency convert intel.gfs.log out/intel_bag
  map-consistency convert fr079-corrected.log.gz out/fr079 --storage sqlite3 --limit 500
  map-consistency convert orebro-corrected.log.gz out/orebro --rate 5   (log without timestamps)
  map-consistency convert graph_with_scans.g2o out/graph --compress
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from map_consistency_ros.cli import options
from map_consistency_ros.cli.progress import ProgressBar
from map_consistency_ros.core.backend import information_upper
from map_consistency_ros.core.geometry import SensorModel, se2
from map_consistency_ros.io import carmen, g2o
from map_consistency_ros.io.bags import STORAGES, BagTopics, BagWriter
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.limits import DISTANCE, STAMP, implausible

# Log-time offsets after a scan so that a subscriber has the scan before the pose naming it.
_CONSTRAINTS_DELAY = 1e-6
_TRAJECTORY_DELAY = 2e-6


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `convert`: the input, the bag to create, its storage, the scans'
    geometry, the stamps, the edges and the topics.

    Parameters
    ----------
    parser: the parser of the `convert` subcommand.
    """
    parser.add_argument('input', type=Path,
                        help='CARMEN log (plain text or gzip), or a .g2o graph with laser data')
    parser.add_argument('output', type=Path, help='rosbag2 folder to create')
    parser.add_argument('--storage', choices=STORAGES, default='mcap',
                        help='rosbag2 storage plugin (default %(default)s)')
    parser.add_argument('--compress', action='store_true',
                        help='zstd chunk compression (mcap only)')
    parser.add_argument('--limit', type=int, default=None, metavar='N',
                        help='convert only the first N laser records')
    options.add_fov_argument(parser)
    parser.add_argument('--range-max', type=float, default=None, metavar='METRES',
                        help='LaserScan range_max where the log does not state the sensor maximum '
                             '(default: the largest reading in the log)')
    parser.add_argument('--rate', type=float, default=None, metavar='HZ',
                        help='stamp the records at this rate from 0 s instead of using the '
                             'logger timestamps (needed when they are not increasing)')
    parser.add_argument('--constraints-every', type=int, default=100, metavar='N',
                        help='publish the edge set every N records and after the last '
                             '(default %(default)s)')
    parser.add_argument('--fix-stamps', action='store_true',
                        help='stamp a record whose logger timestamp goes backwards 10 ms after '
                             'the previous one (instead of refusing the log)')
    parser.add_argument('--odometry-sigmas', type=float, nargs=3, default=(0.05, 0.05, 0.02),
                        metavar=('X', 'Y', 'THETA'),
                        help='CARMEN logs: standard deviations of the odometry edges (metres, '
                             'metres, radians; default %(default)s)')
    parser.add_argument('--scan-topic', default='/scan')
    parser.add_argument('--trajectory-topic', default='/trajectory')
    parser.add_argument('--constraints-topic', default='/constraints')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')


def scan_model(log: carmen.CarmenLog, fov: float | None, range_max: float | None) -> SensorModel:
    """The LaserScan geometry: the log's beam angles, range_max as the sensor states it.

    Parameters
    ----------
    log: the laser records.
    fov: field of view in radians, overriding the log's beam angles; None: the log's own
        (carmen.sensor_model).
    range_max: range_max in metres where the log does not state the sensor maximum; None:
        the largest finite reading (0 without any).

    Returns
    -------
    The SensorModel of the scans written (range_min 0); ValueError for a bad `fov`.
    """
    stated = carmen.stated_max_range(log)
    maximum = stated if stated else range_max
    if maximum is None:
        finite = log.ranges[np.isfinite(log.ranges)]
        maximum = float(finite.max()) if finite.size else 0.0
    angles = carmen.sensor_model(log, fov=fov)
    return SensorModel(angle_min=angles.angle_min, angle_increment=angles.angle_increment,
                       max_range=maximum, range_min=0.0)


# Gap given to a record whose logger timestamp goes backwards, under --fix-stamps.
_FIX_STEP = 1e-2


def record_stamps(log: carmen.CarmenLog, count: int, rate: float | None = None,
                  fix: bool = False) -> tuple[np.ndarray, int]:
    """Strictly increasing stamps of the first `count` records and how many were fixed.

    Scans need distinct stamps in file order: without `fix`, a record whose timestamp does not
    increase is an InputError.

    Parameters
    ----------
    log: the laser records; their logger timestamps are the stamps by default.
    count: how many records, from the first, are stamped.
    rate: in Hz: record i is stamped i / rate seconds instead; None: the logger timestamps.
    fix: a record whose timestamp does not increase is stamped 10 ms after its predecessor.

    Returns
    -------
    (count,) stamps in seconds, and how many records were restamped (0 with a `rate`).
    InputError for a `rate` so low that the stamps go beyond what a ROS Time carries.
    """
    if rate is not None:
        stamps = np.arange(count) / rate
        problem = implausible(stamps, STAMP)
        if problem is not None:
            raise InputError('options', f'--rate {rate!r} stamps record {problem[0]} at '
                                        f'{problem[1]}')
        return stamps, 0
    stamps = log.timestamps[:count].astype(np.float64)
    backwards = np.flatnonzero(np.diff(stamps) <= 0) + 1
    if backwards.size and not fix:
        first = int(backwards[0])
        raise InputError(log.path, f'logger timestamp {float(stamps[first])!r} does not increase '
                                   f'(previous record {float(stamps[first - 1])!r}); scans need '
                                   'distinct stamps in file order: give --fix-stamps or --rate HZ',
                         int(log.line_numbers[first]))
    fixed = 0
    for index in range(1, stamps.size):
        if stamps[index] <= stamps[index - 1]:
            stamps[index] = stamps[index - 1] + _FIX_STEP
            fixed += 1
    return stamps, fixed


@dataclass(frozen=True)
class Keyframes:
    """What a converted bag replays: scans in keyframe order and the edges between them.

    `log` holds the scans with their map-frame laser poses; `edge_from`, `edge_to (E,)` are
    keyframe indices and `edges (E, 9)` the measurement (dx, dy, dtheta) and the upper
    triangle of the information (I11 I12 I13 I22 I23 I33).
    """

    log: carmen.CarmenLog
    edge_from: np.ndarray
    edge_to: np.ndarray
    edges: np.ndarray


def log_keyframes(path: Path, sigmas: tuple) -> Keyframes:
    """A CARMEN log's records, with odometry edges between consecutive records.

    Parameters
    ----------
    path: the CARMEN log (plain text or gzip).
    sigmas: standard deviations (x, y in metres, theta in radians) of every odometry edge;
        its information matrix is diagonal, their inverse squares.

    Returns
    -------
    The Keyframes: every record, and an edge (i, i + 1) per step between the robot poses of
    consecutive records.
    """
    log = carmen.read_carmen_log(path)
    steps = se2.relative(log.robot_poses[:-1], log.robot_poses[1:])
    upper = np.zeros((steps.shape[0], 6))
    upper[:, [0, 3, 5]] = 1.0 / np.asarray(sigmas, dtype=np.float64) ** 2
    indices = np.arange(steps.shape[0])
    return Keyframes(log=log, edge_from=indices, edge_to=indices + 1,
                     edges=np.column_stack([steps, upper]))


def graph_keyframes(path: Path) -> Keyframes:
    """A g2o graph's vertices (each with one scan) in index order, and its edges.

    Parameters
    ----------
    path: a .g2o file whose every vertex carries one ROBOTLASER1 scan.

    Returns
    -------
    The Keyframes: a scan per vertex at the vertex pose composed with the laser offset, with
    the timestamp and line number of its ROBOTLASER1 record, and the graph's edges.
    InputError without exactly one scan per vertex.
    """
    content = g2o.read_g2o(path)
    ranges = content.scan_ranges()
    laser, graph = content.laser, content.graph
    scan_of_vertex = np.empty(graph.vertex_count, dtype=np.int64)
    scan_of_vertex[content.laser_vertices] = np.arange(len(content.laser_vertices))
    laser_poses = se2.compose(graph.poses, np.broadcast_to(content.laser_offset,
                                                           graph.poses.shape))
    log = replace(laser, ranges=ranges, laser_poses=laser_poses, robot_poses=graph.poses,
                  timestamps=laser.timestamps[scan_of_vertex],
                  line_numbers=laser.line_numbers[scan_of_vertex])
    edges = np.column_stack([graph.measurements, information_upper(graph.information)])
    return Keyframes(log=log, edge_from=graph.edge_from, edge_to=graph.edge_to, edges=edges)


def edge_rows(keyframes: Keyframes, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                  np.ndarray]:
    """Rows of the edges among the first len(stamps) keyframes, in the order they become
    known (when their later keyframe arrives).

    Parameters
    ----------
    keyframes: the keyframes and all their edges.
    stamps: (K,) stamps of the first K keyframes, those written.

    Returns
    -------
    rows (E, 11): stamp_from stamp_to dx dy dtheta I11 I12 I13 I22 I23 I33, as /constraints
        carries them; known_at (E,): the keyframe whose arrival makes each edge known;
        loop (E,): whether it is a loop closure (between keyframes that are not consecutive).
    """
    count = stamps.size
    inside = (keyframes.edge_from < count) & (keyframes.edge_to < count)
    first, second = keyframes.edge_from[inside], keyframes.edge_to[inside]
    known_at = np.maximum(first, second)
    order = np.argsort(known_at, kind='stable')
    rows = np.column_stack([stamps[first], stamps[second], keyframes.edges[inside]])
    return rows[order], known_at[order], (np.abs(first - second) != 1)[order]


def check_options(args: argparse.Namespace) -> None:
    """Refuse bad option values before any file is read.

    Parameters
    ----------
    args: parsed `convert` options; InputError names the first bad value.
    """
    checks = (
        (args.limit is None or args.limit >= 1, f'--limit must be at least 1, got {args.limit}'),
        (args.constraints_every >= 1,
         f'--constraints-every must be at least 1, got {args.constraints_every}'),
        (args.rate is None or args.rate > 0, f'--rate must be positive, got {args.rate}'),
        (all(sigma > 0 for sigma in args.odometry_sigmas),
         f'--odometry-sigmas must be 3 positive numbers, got {args.odometry_sigmas}'),
        (args.range_max is None or 0 < args.range_max <= DISTANCE.bound,
         f'--range-max must be positive and at most {DISTANCE.bound:g} m, got '
         f'{args.range_max}'),
    )
    for valid, message in checks:
        if not valid:
            raise InputError('options', message)


def run(args: argparse.Namespace) -> int:
    """Write the bag: per keyframe its scan and the trajectory so far, and the edges known
    every --constraints-every keyframes, after each loop closure and after the last.

    Parameters
    ----------
    args: parsed `convert` options.

    Returns
    -------
    The exit code 0: the bag was written. Bad options or input raise InputError, which `main`
    turns into exit code 2.
    """
    check_options(args)
    topics = BagTopics(scan=args.scan_topic, poses=args.trajectory_topic,
                       constraints=args.constraints_topic)
    try:
        writer = BagWriter(args.output, storage=args.storage, compress=args.compress,
                           topics=topics)
    except ValueError as error:
        raise InputError('options', str(error)) from None
    if args.input.suffix == '.g2o':
        keyframes = graph_keyframes(args.input)
    else:
        keyframes = log_keyframes(args.input, tuple(args.odometry_sigmas))
    log = keyframes.log
    count = log.scan_count if args.limit is None else min(args.limit, log.scan_count)
    try:
        model = scan_model(log, options.fov_radians(args), args.range_max)
    except ValueError as error:
        raise InputError(str(args.input), str(error)) from None
    stamps, fixed = record_stamps(log, count, args.rate, args.fix_stamps)
    rows, known_at, loop = edge_rows(keyframes, stamps)
    closes_loop = set(known_at[loop].tolist())
    every = args.constraints_every
    with writer, ProgressBar('writing', enabled=not args.quiet) as progress:
        for index in range(count):
            stamp = float(stamps[index])
            writer.write_scan(stamp, stamp, log.ranges[index], model)
            if index and (index % every == 0 or index == count - 1 or index in closes_loop):
                known = int(np.searchsorted(known_at, index, side='right'))
                writer.write_constraints(stamp + _CONSTRAINTS_DELAY, rows[:known])
            writer.write_trajectory(stamp + _TRAJECTORY_DELAY, stamps[:index + 1],
                                    log.laser_poses[:index + 1])
            progress(index + 1, count)
    print(f'{args.output}: {count} scans ({log.beam_count} beams, range_max {model.max_range:g} m)'
          f', their growing trajectory and {rows.shape[0]} edges from {args.input}')
    if fixed:
        print(f'  {fixed} records whose logger timestamp went backwards were restamped')
    return 0
