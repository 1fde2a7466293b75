"""CARMEN log files (plain or gzip): FLASER and ROBOTLASER1 laser records, PARAM lines.

Record layouts (whitespace separated):

    FLASER K r_1 .. r_K x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp
    ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode
                K r_1 .. r_K R rem_1 .. rem_R laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety side_safety turn_axis ipc_timestamp host logger_timestamp

FLASER's `x y theta` is the laser pose and `odom_*` the robot pose (both corrected in the
"corrected" logs of the SLAM benchmarks). Scan index = 0-based position of the laser record in
the file, the convention every report uses.
"""
from __future__ import annotations

import gzip
import math
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import SensorModel
from map_consistency_ros.io.errors import InputError, not_a_file
from map_consistency_ros.io.limits import DISTANCE, HEADING, SCAN_ANGLE, STAMP, Limit, implausible

DEFAULT_FOV = math.pi
# The original implementation's usable range: readings beyond it count as free space.
DEFAULT_MAX_RANGE = 8.0

_FLASER_TAIL = 9  # pose (3), odometry pose (3), ipc timestamp, host, logger timestamp
_ROBOTLASER_HEAD = 8  # type, start angle, fov, resolution, max range, accuracy, remission mode, K


@dataclass(frozen=True)
class LaserAngles:
    """Beam geometry stated by a ROBOTLASER1 record."""

    start_angle: float
    fov: float
    resolution: float
    max_range: float


@dataclass(frozen=True)
class CarmenLog:
    """The laser records of a CARMEN log as arrays (N records of K beams)."""

    path: str
    ranges: np.ndarray  # (N, K) metres
    laser_poses: np.ndarray  # (N, 3) pose of the laser in the map frame
    robot_poses: np.ndarray  # (N, 3)
    timestamps: np.ndarray  # (N,) logger timestamps, seconds
    line_numbers: np.ndarray  # (N,) 1-based line of each record
    stated_angles: LaserAngles | None  # from ROBOTLASER1 records, None for FLASER-only logs
    parameters: dict[str, str]  # PARAM name -> value

    @property
    def scan_count(self) -> int:
        return int(self.ranges.shape[0])

    @property
    def beam_count(self) -> int:
        return int(self.ranges.shape[1])


# What reading a damaged file raises: a cut gzip stream EOFError, a bad CRC OSError, a garbled
# deflate stream zlib.error.
READ_ERRORS = (OSError, EOFError, UnicodeError, zlib.error)


def open_text(path: Path):
    """A text stream of a plain or gzip-compressed file (told apart by its magic bytes).

    Parameters
    ----------
    path: the file to open.

    Returns
    -------
    An open UTF-8 text stream (undecodable bytes replaced), for the caller to close; OSError
    when the file cannot be opened. Reading it raises one of READ_ERRORS for a damaged file.
    """
    with open(path, 'rb') as probe:
        gzipped = probe.read(2) == b'\x1f\x8b'
    if gzipped:
        return gzip.open(path, 'rt', encoding='utf-8', errors='replace')
    return open(path, encoding='utf-8', errors='replace')


def parse_floats(tokens: list[str], source: str, line: int, what: str) -> np.ndarray:
    """The tokens as float64.

    Parameters
    ----------
    tokens: the fields to convert.
    source: the file name, for the error message.
    line: the 1-based line of the record, for the error message.
    what: what a field is ('range', 'pose value', ...), for the error message.

    Returns
    -------
    (len(tokens),) float64 values. Raises InputError naming the first non-numeric token, the
    file and the line.
    """
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        bad = next(token for token in tokens if not _is_number(token))
        raise InputError(source, f'non-numeric {what} {bad!r}', line) from None
    return values


def check_plausible(values: np.ndarray, limit: Limit, source: str, lines,
                    names: tuple[str, ...] | str) -> None:
    """Refuse values outside their plausible range (io/limits.py).

    Parameters
    ----------
    values: the values of one record (W,), or of N records (N, W), checked at once.
    limit: their plausible range.
    source: the file name, for the error message.
    lines: the 1-based line of the record, or (N,) of each record, for the error message.
    names: the name of each of the W values, or one word for all of them (then numbered
        from 1).

    Returns
    -------
    None. Raises InputError naming the first implausible value, the file and its line.
    """
    values = np.asarray(values, dtype=np.float64)
    problem = implausible(values, limit)
    if problem is None:
        return
    index, reason = problem
    width = values.shape[-1] if values.ndim else 1
    row, column = divmod(index, width)
    name = names[column] if isinstance(names, tuple) else f'{names} {column + 1}'
    line = int(np.asarray(lines).reshape(-1)[row]) if np.ndim(lines) else int(lines)
    raise InputError(source, f'{name} {reason}', line)


_POSE_NAMES = ('x', 'y', 'theta')


def check_poses(poses: np.ndarray, source: str, lines, what: str) -> None:
    """Refuse poses whose position or heading is implausible (io/limits.py).

    Parameters
    ----------
    poses: (3,) or (N, 3) x, y in metres, heading in radians.
    source: the file name, for the error message.
    lines: the 1-based line of the pose, or (N,) of each, for the error message.
    what: whose poses they are ('laser pose', 'vertex pose', ...), for the error message.

    Returns
    -------
    None. Raises InputError naming the value, the file and the line.
    """
    poses = np.asarray(poses, dtype=np.float64)
    check_plausible(poses[..., :2], DISTANCE, source, lines,
                    tuple(f'{what} {name}' for name in _POSE_NAMES[:2]))
    check_plausible(poses[..., 2:], HEADING, source, lines, (f'{what} {_POSE_NAMES[2]}',))


def check_laser_records(log: CarmenLog) -> None:
    """Refuse laser records whose ranges, poses or logger timestamps are implausible.

    A text log writes a beam without return as the maximum reading: a non-finite range is
    damage, unlike in a LaserScan.

    Parameters
    ----------
    log: the records as read, with the line of each.

    Returns
    -------
    None. Raises InputError naming the first implausible value, the file and its line.
    """
    lines = log.line_numbers
    check_plausible(log.ranges, DISTANCE, log.path, lines, 'range')
    check_poses(log.laser_poses, log.path, lines, 'laser pose')
    check_poses(log.robot_poses, log.path, lines, 'robot pose')
    check_plausible(log.timestamps[:, None], STAMP, log.path, lines, ('logger timestamp',))


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _count(token: str, source: str, line: int, what: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise InputError(source, f'{what} must be an integer, got {token!r}', line) from None
    if value < 0:
        raise InputError(source, f'{what} must not be negative, got {value}', line)
    return value


def _need(tokens: list[str], length: int, source: str, line: int, record: str) -> None:
    if len(tokens) < length:
        raise InputError(source, f'truncated {record} record: {len(tokens)} fields, '
                                 f'expected at least {length}', line)


def parse_flaser(tokens: list[str], source: str, line: int):
    """The fields of a FLASER record.

    Parameters
    ----------
    tokens: the record's whitespace-separated fields, the tag 'FLASER' first.
    source: the file name, for error messages.
    line: the record's 1-based line, for error messages.

    Returns
    -------
    (ranges (K,), laser pose (3,), robot pose (3,), logger timestamp, None); the last is the
    LaserAngles slot, which FLASER records leave empty. Raises InputError for a truncated
    record, a bad beam count or a non-numeric field (`check_laser_records` checks the values).
    """
    _need(tokens, 2, source, line, 'FLASER')
    beams = _count(tokens[1], source, line, 'FLASER beam count')
    _need(tokens, 2 + beams + _FLASER_TAIL, source, line, 'FLASER')
    ranges = parse_floats(tokens[2:2 + beams], source, line, 'range')
    tail = tokens[2 + beams:]
    poses = parse_floats(tail[0:6], source, line, 'pose value')
    timestamp = parse_floats([tail[8]], source, line, 'timestamp')[0]
    return ranges, poses[0:3], poses[3:6], timestamp, None


def parse_robotlaser(tokens: list[str], source: str, line: int):
    """The fields of a ROBOTLASER1 record.

    Parameters
    ----------
    tokens: the record's whitespace-separated fields, the tag 'ROBOTLASER1' first.
    source: the file name, for error messages.
    line: the record's 1-based line, for error messages.

    Returns
    -------
    (ranges (K,), laser pose (3,), robot pose (3,), logger timestamp, LaserAngles); the
    remissions are skipped. Raises InputError for a truncated record, a bad beam or remission
    count, a non-numeric field or a laser parameter outside its plausible range (io/limits.py;
    `check_laser_records` checks the other values).
    """
    _need(tokens, _ROBOTLASER_HEAD + 1, source, line, 'ROBOTLASER1')
    head = parse_floats(tokens[2:7], source, line, 'laser parameter')
    beams = _count(tokens[8], source, line, 'ROBOTLASER1 beam count')
    _need(tokens, 9 + beams + 1, source, line, 'ROBOTLASER1')
    ranges = parse_floats(tokens[9:9 + beams], source, line, 'range')
    remissions = _count(tokens[9 + beams], source, line, 'ROBOTLASER1 remission count')
    rest = tokens[10 + beams + remissions:]
    _need(tokens, 10 + beams + remissions + 14, source, line, 'ROBOTLASER1')
    poses = parse_floats(rest[0:6], source, line, 'pose value')
    timestamp = parse_floats([rest[13]], source, line, 'timestamp')[0]
    check_plausible(head[0:3], SCAN_ANGLE, source, line, ('start angle', 'field of view',
                                                          'angular resolution'))
    check_plausible(head[3:4], DISTANCE, source, line, ('maximum range',))
    angles = LaserAngles(start_angle=head[0], fov=head[1], resolution=head[2], max_range=head[3])
    return ranges, poses[0:3], poses[3:6], timestamp, angles


_PARSERS = {'FLASER': parse_flaser, 'ROBOTLASER1': parse_robotlaser}

# The PARAM values the sensor model reads (stated_max_range, sensor_model): name -> (limit,
# factor to the limit's unit). A value that is no number is not used; an implausible one is
# damage.
_NUMERIC_PARAMETERS = {'robot_front_laser_max': (DISTANCE, 1.0),
                       'laser_front_laser_resolution': (SCAN_ANGLE, math.pi / 180.0)}


def _check_parameter(name: str, value: str, source: str, line: int) -> None:
    if name in _NUMERIC_PARAMETERS and _is_number(value):
        limit, factor = _NUMERIC_PARAMETERS[name]
        check_plausible(np.array([float(value) * factor]), limit, source, line,
                        (f'PARAM {name} (in {limit.unit})',))


def read_carmen_log(path: str | Path) -> CarmenLog:
    """Read every FLASER / ROBOTLASER1 record of a CARMEN log.

    Parameters
    ----------
    path: the log, plain or gzip-compressed. Other record types are skipped; PARAM lines are
        kept as `parameters`.

    Returns
    -------
    A CarmenLog of the N laser records in file order; `stated_angles` comes from the first
    ROBOTLASER1 record (None for a FLASER-only log). Raises InputError naming the file and line
    for a missing or unreadable file, a truncated or non-numeric record, records with differing
    beam counts, a number outside its plausible range (io/limits.py: ranges and positions
    within 1e5 m, headings within 1e3 rad, timestamps in [0, 2**31) s), or a log without laser
    records.
    """
    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise not_a_file(path)
    ranges, laser_poses, robot_poses, timestamps, lines = [], [], [], [], []
    stated: LaserAngles | None = None
    parameters: dict[str, str] = {}
    try:
        with open_text(path) as stream:
            for line_number, text in enumerate(stream, start=1):
                tokens = text.split()
                if not tokens or tokens[0].startswith('#'):
                    continue
                if tokens[0] == 'PARAM' and len(tokens) >= 3:
                    _check_parameter(tokens[1], tokens[2], source, line_number)
                    parameters[tokens[1]] = tokens[2]
                    continue
                parser = _PARSERS.get(tokens[0])
                if parser is None:
                    continue
                scan, laser_pose, robot_pose, stamp, angles = parser(tokens, source, line_number)
                if ranges and scan.shape != ranges[0].shape:
                    raise InputError(source, f'{scan.size} beams, but the first laser record '
                                             f'(line {lines[0]}) has {ranges[0].size}', line_number)
                stated = stated or angles
                ranges.append(scan)
                laser_poses.append(laser_pose)
                robot_poses.append(robot_pose)
                timestamps.append(stamp)
                lines.append(line_number)
    except READ_ERRORS as error:
        raise InputError(source, f'cannot read the file ({error})') from None
    if not ranges:
        raise InputError(source, 'no FLASER or ROBOTLASER1 laser records found')
    log = CarmenLog(path=source, ranges=np.array(ranges), laser_poses=np.array(laser_poses),
                    robot_poses=np.array(robot_poses), timestamps=np.array(timestamps),
                    line_numbers=np.array(lines), stated_angles=stated, parameters=parameters)
    check_laser_records(log)
    return log


def stated_max_range(log: CarmenLog) -> float | None:
    """The sensor's maximum range as the log states it (ROBOTLASER1 or PARAM), if it does.

    Parameters
    ----------
    log: the log read by `read_carmen_log`.

    Returns
    -------
    The range in metres from the first ROBOTLASER1 record, else from PARAM
    robot_front_laser_max; None when neither states a number.
    """
    if log.stated_angles is not None:
        return float(log.stated_angles.max_range)
    value = log.parameters.get('robot_front_laser_max')
    return float(value) if value is not None and _is_number(value) else None


def sensor_model(log: CarmenLog, fov: float | None = None, max_range: float | None = None,
                 range_min: float = 0.0) -> SensorModel:
    """The beam geometry of a log's scans.

    A ROBOTLASER1 record states its start angle and resolution. FLASER records do not: their
    beams start at -FOV/2 (FOV = `fov`, default 180 degrees) and are spaced by PARAM
    laser_front_laser_resolution if the log has it, else by FOV / K for an even beam count K and
    FOV / (K - 1) for an odd one (the SICK convention: 181 and 361 beams include both ends).
    That convention minimises the measure on the Intel, Freiburg 079 and Belgioioso logs.
    `max_range` is the usable range of the test (default 8 m, as the original implementation),
    capped by the sensor maximum the log states.

    Parameters
    ----------
    log: the log whose beam count K and stated geometry are used.
    fov: field of view in radians of FLASER-style scans; None for the ROBOTLASER1 statement
        or, without one, 180 degrees. Given, it overrides a ROBOTLASER1 statement and the
        resolution PARAM.
    max_range: usable range in metres; None for 8 m.
    range_min: readings at or below it (metres) are invalid.

    Returns
    -------
    The SensorModel. Raises ValueError for a field of view outside (0, 2 pi] or fewer than 2
    beams (when the increment is derived from FOV and K), and as SensorModel does for an
    invalid geometry.
    """
    beams = log.beam_count
    stated = log.stated_angles
    resolution_param = log.parameters.get('laser_front_laser_resolution')
    if stated is not None and fov is None:
        increment, angle_min = stated.resolution, stated.start_angle
    else:
        from_param = (fov is None and resolution_param is not None
                      and _is_number(resolution_param))
        fov = DEFAULT_FOV if fov is None else fov
        increment = (math.radians(float(resolution_param)) if from_param
                     else _increment_for(fov, beams))
        angle_min = -0.5 * fov
    usable = DEFAULT_MAX_RANGE if max_range is None else float(max_range)
    sensor_max = stated_max_range(log)
    if sensor_max is not None and sensor_max > 0:
        usable = min(usable, sensor_max)
    return SensorModel(angle_min=angle_min, angle_increment=increment, max_range=usable,
                       range_min=range_min)


def _increment_for(fov: float, beams: int) -> float:
    if fov <= 0 or fov > 2 * math.pi + 1e-9:
        raise ValueError(f'field of view must be in (0, 2 pi], got {fov}')
    if beams < 2:
        raise ValueError(f'a scan needs at least 2 beams, got {beams}')
    full_circle = fov >= 2 * math.pi - 1e-9
    return fov / beams if full_circle or beams % 2 == 0 else fov / (beams - 1)
