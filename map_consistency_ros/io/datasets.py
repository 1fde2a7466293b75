"""Pose graphs with laser data from the SLAM benchmark data: corrected log + relations + raw bag.

Inputs (see the shared data README): a corrected CARMEN log (the scans and their corrected
poses), Kümmerle et al.'s `.relations` file (`t1 t2 x y z roll pitch yaw`: the robot pose at
raw scan stamp t2 seen from the one at t1) and the raw ROS 1 bag the relations' stamps refer
to (`/scan`, `/odom`, `/tf_static`). Each log scan is paired with its raw scan by identical
ranges, which gives it a raw stamp and a raw odometry pose.

The graph: one vertex per kept log scan (every `stride`-th) at its corrected robot pose;
odometry edges between consecutive vertices from the raw odometry; an edge per relation whose
stamps lie within `max_relation_gap` seconds of two different kept scans (moved onto those
scans along the raw odometry): a loop closure, or a second sequential edge beside the
odometry when the scans are neighbours; optionally false loop
closures between random scan pairs and an initial guess corrupted by propagating the
corrected trajectory's steps with noise (the raw odometry alone drifts too far for any
robust back-end to recover the Intel map from it).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from map_consistency_ros.core.backend import PoseGraph
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io.carmen import (CarmenLog, LaserAngles, check_plausible,
                                           read_carmen_log, sensor_model)
from map_consistency_ros.io.errors import InputError, not_a_file
from map_consistency_ros.io.g2o import G2oGraph
from map_consistency_ros.io.limits import DISTANCE, HEADING, STAMP
from map_consistency_ros.io.messages import stamp_to_seconds


@dataclass(frozen=True)
class BuildSettings:
    """How the graph is built; standard deviations in metres and radians.

    Odometry edges get sigma = base + per-metre * distance (+ per-radian * |turn| for the
    heading), loop closures fixed sigmas. False loop closures join `false_loop_closures`
    random non-neighbouring scan pairs with a measurement drawn as a false place recognition
    would report it (offset N(0, false_offset_sigma) per axis, any heading), with the loop
    closures' information. `corrupt_guess` starts the optimizer from the corrected trajectory's
    steps propagated with N(0, guess_sigma_*) noise per step instead of the corrected poses.
    The odometry sigmas are loose because Intel's raw odometry errors against the corrected
    poses are heavy-tailed (median 5 cm and 0.05 rad per step, a tail ten times that); the
    loop-closure sigmas match the relations' median error (4 cm, 0.03 rad).
    """

    stride: int = 1
    max_relation_gap: float = 1.0
    odometry_sigma_xy: tuple[float, float] = (0.05, 0.2)
    odometry_sigma_theta: tuple[float, float, float] = (0.05, 0.2, 0.1)
    loop_sigma_xy: float = 0.05
    loop_sigma_theta: float = 0.04
    false_loop_closures: int = 0
    false_offset_sigma: float = 0.5
    corrupt_guess: bool = False
    guess_sigma_xy: float = 0.02
    guess_sigma_theta: float = 0.005
    seed: int = 0

    def __post_init__(self) -> None:
        if self.stride < 1:
            raise ValueError(f'stride must be >= 1, got {self.stride}')
        if self.false_loop_closures < 0:
            raise ValueError(f'false_loop_closures must be >= 0, got {self.false_loop_closures}')


@dataclass(frozen=True)
class RawBag:
    """What the builder needs from a raw bag: scans, odometry and the laser mounting."""

    scan_stamps: np.ndarray   # (S,) header stamps, seconds
    scan_ranges: np.ndarray   # (S, K) float32, as recorded
    angles: LaserAngles
    odom_stamps: np.ndarray   # (O,) increasing
    odom_poses: np.ndarray    # (O, 3) with the heading unwrapped
    laser_offset: np.ndarray  # (3,) laser pose in the base frame

    def odometry_at(self, stamps: np.ndarray) -> np.ndarray:
        """Odometry poses interpolated linearly at some stamps.

        Parameters
        ----------
        stamps: (M,) times in seconds on the bag's clock; those outside the odometry's span get
            its first or last pose.

        Returns
        -------
        (M, 3) x, y, yaw with the heading wrapped to (-pi, pi].
        """
        stamps = np.asarray(stamps, dtype=np.float64)
        poses = np.stack([np.interp(stamps, self.odom_stamps, self.odom_poses[:, axis])
                          for axis in range(3)], axis=1)
        poses[:, 2] = se2.wrap_angle(poses[:, 2])
        return poses


def build_dataset(log_path: str | Path, relations_path: str | Path, bag_path: str | Path,
                  settings: BuildSettings = BuildSettings()) -> G2oGraph:
    """Build the pose graph with laser data (see the module docstring).

    Parameters
    ----------
    log_path: the corrected CARMEN log (plain or gzip).
    relations_path: the `.relations` file of the same data set.
    bag_path: the raw ROS 1 or ROS 2 bag the relations' stamps refer to.
    settings: how the graph is built.

    Returns
    -------
    The graph as `build_graph` gives it. Raises InputError for a missing or malformed file
    and for a log scan no raw scan matches.
    """
    return build_graph(read_carmen_log(log_path), read_relations(relations_path),
                       read_raw_bag(bag_path), settings)


def build_graph(log: CarmenLog, relations: np.ndarray, bag: RawBag,
                settings: BuildSettings = BuildSettings()) -> G2oGraph:
    """`build_dataset` on inputs already read.

    Parameters
    ----------
    log: the corrected log (`read_carmen_log`).
    relations: (R, 5) rows `t1 t2 x y yaw` as `read_relations` gives them.
    bag: the raw bag's content (`read_raw_bag`).
    settings: how the graph is built; its seed fixes the false loop closures and the noisy
        initial guess.

    Returns
    -------
    A G2oGraph of N = ceil(scan_count / stride) vertices with ids 0..N-1, the first fixed:
    odometry edges first, then relation edges, then false loop closures. Its laser holds the
    kept scans with their corrected robot poses, the laser poses through the bag's laser
    offset, the raw scan stamps as timestamps and the log's beam geometry. Raises InputError
    when the log's scans do not match the bag's (see match_scans), ValueError for false loop
    closures with fewer than 4 vertices.
    """
    matched = match_scans(log, bag)
    keep = np.arange(0, log.scan_count, settings.stride)
    stamps = bag.scan_stamps[matched[keep]]
    odometry = bag.odometry_at(stamps)
    rng = np.random.default_rng(settings.seed)
    edge_from, edge_to, measurements, information = _odometry_edges(odometry, settings)
    loops = _relation_edges(relations, stamps, bag, settings)
    false = _false_edges(len(keep), settings, rng)
    edge_from = np.concatenate([edge_from, loops[0], false[0]])
    edge_to = np.concatenate([edge_to, loops[1], false[1]])
    measurements = np.concatenate([measurements, loops[2], false[2]])
    loop_information = _information(np.full(len(loops[0]) + len(false[0]), settings.loop_sigma_xy),
                                    np.full(len(loops[0]) + len(false[0]),
                                            settings.loop_sigma_theta))
    information = np.concatenate([information, loop_information])
    poses = log.robot_poses[keep]
    if settings.corrupt_guess:
        poses = _noisy_chain(poses[0], se2.relative(poses[:-1], poses[1:]), settings, rng)
    fixed = np.zeros(len(keep), dtype=bool)
    fixed[0] = True
    graph = PoseGraph(poses=poses, edge_from=edge_from, edge_to=edge_to,
                      measurements=measurements, information=information, fixed=fixed)
    robot_poses = log.robot_poses[keep]
    # The log's beam geometry, not the bag converter's (angle_increment = pi / (K - 1)): the
    # log's convention is the one under which its scans are most consistent (io/carmen.py).
    geometry = sensor_model(log)
    angles = LaserAngles(start_angle=geometry.angle_min,
                         fov=geometry.angle_increment * log.beam_count,
                         resolution=geometry.angle_increment, max_range=bag.angles.max_range)
    laser = CarmenLog(path=log.path, ranges=log.ranges[keep],
                      laser_poses=se2.compose(robot_poses, bag.laser_offset),
                      robot_poses=robot_poses, timestamps=stamps,
                      line_numbers=log.line_numbers[keep], stated_angles=angles,
                      parameters=log.parameters)
    return G2oGraph(graph=graph, vertex_ids=np.arange(len(keep)), laser=laser,
                    laser_vertices=np.arange(len(keep)))


def read_relations(path: str | Path) -> np.ndarray:
    """Read a relations file (lines `t1 t2 x y z roll pitch yaw`, '#' comments skipped).

    Parameters
    ----------
    path: the `.relations` file.

    Returns
    -------
    (R, 5) rows `t1 t2 x y yaw` (stamps in seconds, the planar part of each relation). Raises
    InputError for a missing file, a line without 8 fields or with a non-numeric one, a
    number outside its plausible range (io/limits.py; naming the line), or a file without
    relations.
    """
    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise not_a_file(path)
    rows, lines = [], []
    with open(path, encoding='utf-8', errors='replace') as stream:
        for line_number, text in enumerate(stream, start=1):
            tokens = text.split()
            if not tokens or tokens[0].startswith('#'):
                continue
            if len(tokens) != 8:
                raise InputError(source, f'a relation has 8 fields (t1 t2 x y z roll pitch yaw), '
                                         f'got {len(tokens)}', line_number)
            try:
                rows.append([float(token) for token in tokens])
            except ValueError:
                raise InputError(source, 'non-numeric relation field', line_number) from None
            lines.append(line_number)
    if not rows:
        raise InputError(source, 'no relations found')
    values = np.array(rows)
    check_plausible(values[:, 0:2], STAMP, source, lines, ('relation t1', 'relation t2'))
    check_plausible(values[:, 2:5], DISTANCE, source, lines,
                    ('relation x', 'relation y', 'relation z'))
    check_plausible(values[:, 5:8], HEADING, source, lines,
                    ('relation roll', 'relation pitch', 'relation yaw'))
    return values[:, [0, 1, 2, 3, 7]]


def read_raw_bag(path: str | Path) -> RawBag:
    """Scans, odometry and the base-to-laser transform of a raw (ROS 1 or 2) bag.

    Parameters
    ----------
    path: the bag, with LaserScans on /scan, Odometry on /odom and optionally the transform
        to frame 'laser' on /tf_static.

    Returns
    -------
    A RawBag: the scans in bag order, the beam geometry of the first scan, the odometry sorted
    by stamp with its heading unwrapped, the laser offset (zeros without the transform).
    Raises InputError for a missing or unreadable bag, one without /scan messages or with
    fewer than 2 /odom messages, or scans that differ in beam count.
    """
    path = Path(path)
    source = str(path)
    if not path.exists():
        raise not_a_file(path)
    scans, odometry, offset, angles = [], [], np.zeros(3), None
    try:
        with AnyReader([path]) as reader:
            for connection, _, raw in reader.messages(connections=reader.connections):
                if connection.topic not in ('/scan', '/odom', '/tf_static'):
                    continue
                message = reader.deserialize(raw, connection.msgtype)
                if connection.topic == '/scan':
                    scans.append((stamp_to_seconds(message.header.stamp), message.ranges))
                    angles = angles or LaserAngles(
                        start_angle=message.angle_min, fov=message.angle_max - message.angle_min,
                        resolution=message.angle_increment, max_range=message.range_max)
                elif connection.topic == '/odom':
                    pose = message.pose.pose
                    odometry.append((stamp_to_seconds(message.header.stamp), pose.position.x,
                                     pose.position.y, _yaw(pose.orientation)))
                else:
                    offset = _laser_offset(message, offset)
    except InputError:
        raise
    except Exception as error:  # rosbags raises many types for corrupt bags
        raise InputError(source, f'cannot read the bag ({type(error).__name__}: {error})') from None
    if not scans or len(odometry) < 2:
        raise InputError(source, 'the bag needs /scan and /odom messages')
    odometry_array = np.array(sorted(odometry))
    odometry_array[:, 3] = np.unwrap(odometry_array[:, 3])
    ranges = [np.asarray(ranges, dtype=np.float32) for _, ranges in scans]
    if len({len(r) for r in ranges}) != 1:
        raise InputError(source, '/scan messages differ in beam count')
    return RawBag(scan_stamps=np.array([stamp for stamp, _ in scans]),
                  scan_ranges=np.array(ranges), angles=angles,
                  odom_stamps=odometry_array[:, 0], odom_poses=odometry_array[:, 1:],
                  laser_offset=offset)


def match_scans(log: CarmenLog, bag: RawBag) -> np.ndarray:
    """The raw scan with the same ranges as each log scan (compared as float32).

    Identical range arrays recur (the robot standing still, a sparse corridor), so among
    identical raw scans the one nearest in time wins, the log's clock being moved onto the
    bag's by the median offset of the scans that match exactly one raw scan.

    Parameters
    ----------
    log: the corrected log, N scans.
    bag: the raw bag's content.

    Returns
    -------
    (N,) int64 index into the bag's scans. Raises InputError when the beam counts differ or
    a log scan matches no raw scan (naming its line).
    """
    if log.beam_count != bag.scan_ranges.shape[1]:
        raise InputError(log.path, f'{log.beam_count} beams per scan, but the bag\'s scans have '
                                   f'{bag.scan_ranges.shape[1]}')
    candidates: dict[bytes, list[int]] = {}
    for index, ranges in enumerate(bag.scan_ranges):
        candidates.setdefault(ranges.tobytes(), []).append(index)
    options = [candidates.get(ranges.tobytes(), []) for ranges in log.ranges.astype(np.float32)]
    for scan, found in enumerate(options):
        if not found:
            raise InputError(log.path, 'no raw scan in the bag has these ranges',
                             int(log.line_numbers[scan]))
    unique = [scan for scan, found in enumerate(options) if len(found) == 1]
    offset = (np.median(bag.scan_stamps[[options[scan][0] for scan in unique]]
                        - log.timestamps[unique]) if unique else 0.0)
    return np.array([found[int(np.argmin(np.abs(bag.scan_stamps[found] - stamp - offset)))]
                     for found, stamp in zip(options, log.timestamps)], dtype=np.int64)


def _yaw(quaternion) -> float:
    return float(se2.yaw_from_quaternion(quaternion.x, quaternion.y, quaternion.z, quaternion.w))


def _laser_offset(message, current: np.ndarray) -> np.ndarray:
    for transform in message.transforms:
        if transform.child_frame_id.strip('/') == 'laser':
            translation = transform.transform.translation
            return np.array([translation.x, translation.y, _yaw(transform.transform.rotation)])
    return current


def _information(sigma_xy: np.ndarray, sigma_theta: np.ndarray) -> np.ndarray:
    information = np.zeros((len(sigma_xy), 3, 3))
    information[:, 0, 0] = information[:, 1, 1] = 1.0 / sigma_xy ** 2
    information[:, 2, 2] = 1.0 / sigma_theta ** 2
    return information


def _odometry_edges(odometry: np.ndarray, settings: BuildSettings):
    steps = se2.relative(odometry[:-1], odometry[1:])
    distance = np.hypot(steps[:, 0], steps[:, 1])
    base_xy, per_metre_xy = settings.odometry_sigma_xy
    base_theta, per_radian, per_metre_theta = settings.odometry_sigma_theta
    information = _information(base_xy + per_metre_xy * distance,
                               base_theta + per_radian * np.abs(steps[:, 2])
                               + per_metre_theta * distance)
    index = np.arange(len(steps))
    return index, index + 1, steps, information


def _relation_edges(relations: np.ndarray, stamps: np.ndarray, bag: RawBag,
                    settings: BuildSettings):
    first, first_gap = _nearest(stamps, relations[:, 0])
    second, second_gap = _nearest(stamps, relations[:, 1])
    usable = ((first_gap <= settings.max_relation_gap) & (second_gap <= settings.max_relation_gap)
              & (first != second))
    # One edge per scan pair: several relations often land on the same two scans.
    pair = np.stack([np.minimum(first, second), np.maximum(first, second)], axis=1)
    _, unique = np.unique(pair[usable], axis=0, return_index=True)
    chosen = np.flatnonzero(usable)[np.sort(unique)]
    relation = np.column_stack([relations[chosen, 2:4], relations[chosen, 4]])
    # Move the relation from the raw stamps onto the scans' stamps along the raw odometry.
    at_first = se2.relative(bag.odometry_at(stamps[first[chosen]]),
                            bag.odometry_at(relations[chosen, 0]))
    at_second = se2.relative(bag.odometry_at(relations[chosen, 1]),
                             bag.odometry_at(stamps[second[chosen]]))
    measurement = se2.compose(se2.compose(at_first, relation), at_second)
    return first[chosen], second[chosen], measurement


def _nearest(stamps: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    right = np.clip(np.searchsorted(stamps, queries), 1, len(stamps) - 1)
    left = right - 1
    nearest = np.where(np.abs(stamps[right] - queries) < np.abs(stamps[left] - queries),
                       right, left)
    return nearest, np.abs(stamps[nearest] - queries)


def _false_edges(count: int, settings: BuildSettings, rng: np.random.Generator):
    wanted = settings.false_loop_closures
    if wanted and count < 4:
        raise ValueError('false loop closures need at least 4 scans')
    first = np.empty(0, dtype=np.int64)
    second = np.empty(0, dtype=np.int64)
    while len(first) < wanted:
        a = rng.integers(0, count, size=wanted)
        b = rng.integers(0, count, size=wanted)
        ok = np.abs(a - b) > 1
        first = np.concatenate([first, a[ok]])[:wanted]
        second = np.concatenate([second, b[ok]])[:wanted]
    measurement = np.column_stack([rng.normal(0.0, settings.false_offset_sigma, (wanted, 2)),
                                   rng.uniform(-np.pi, np.pi, wanted)])
    return first, second, measurement


def _noisy_chain(start: np.ndarray, steps: np.ndarray, settings: BuildSettings,
                 rng: np.random.Generator) -> np.ndarray:
    noise = np.column_stack([rng.normal(0.0, settings.guess_sigma_xy, (len(steps), 2)),
                             rng.normal(0.0, settings.guess_sigma_theta, len(steps))])
    return se2.chain(start, se2.compose(steps, noise))
