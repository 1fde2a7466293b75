"""The labelled map suite: consistent maps from real corrected logs and broken copies of them.

Every corrected log of ../shared/data is thinned to keyframes (a scan is kept when the laser
moved `keyframe_distance` or turned `keyframe_angle` since the last kept one, as SLAM front
ends do; FR079 gives 814 keyframes, the paper's Table I lists 833) and cut into consecutive
parts of `part_size` keyframes. Each part at its corrected poses is a consistent map. Its
inconsistent copies break it the way mapping fails, with the magnitudes drawn from a seeded
generator:

- `rotation`: everything after a pivot scan turned by 2-5 degrees about the pivot (a wrong
  heading at one step, e.g. an accepted false loop closure pulling the tail around);
- `shift`: everything after the pivot moved by 0.2-0.5 m;
- `rotation+shift`: both;
- `corrupted`: a block of 3-10 consecutive scans moved and turned as one (a scan-matcher
  failure on a short stretch).

The pivot lies in the middle half of the part, so the break always cuts through pairs of
strongly overlapping consecutive scans: the labels are true by construction. The incremental
solution of every copy is its part's corrected poses (only loop closing goes wrong).
"""
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import se2, viewpoint_rows
from map_consistency_ros.io.carmen import CarmenLog, read_carmen_log

# dataset name -> corrected log, relative to the shared data folder
CORRECTED_LOGS = {
    'intel': 'intel/intel.gfs.log',
    'fr079': 'fr079/freiburg-079-corrected.log.gz',
    'fr101': 'carmen_corrected_extra/freiburg-101-corrected.log.gz',
    'belgioioso': 'carmen_corrected_extra/belgioioso-corrected.log.gz',
    'orebro': 'carmen_corrected_extra/orebro-corrected.log.gz',
}

BREAKS = ('rotation', 'shift', 'rotation+shift', 'corrupted')


@dataclass(frozen=True)
class SuiteParameters:
    """How the suite is cut from the logs and how hard its maps are broken."""

    seed: int = 7
    keyframe_distance: float = 0.5  # metres
    keyframe_angle: float = 0.5  # radians
    part_size: int = 150  # keyframes per map; the last part of a log takes the remainder
    rotation_degrees: tuple[float, float] = (2.0, 5.0)
    shift_metres: tuple[float, float] = (0.2, 0.5)
    block_scans: tuple[int, int] = (3, 10)

    def __post_init__(self) -> None:
        if self.keyframe_distance < 0 or self.keyframe_angle < 0:
            raise ValueError('keyframe thresholds must not be negative')
        if self.part_size < 2 * self.block_scans[1]:
            raise ValueError(f'part_size must be at least {2 * self.block_scans[1]} scans')
        for low, high in (self.rotation_degrees, self.shift_metres, self.block_scans):
            if not 0 < low <= high:
                raise ValueError(f'bad range ({low}, {high}): need 0 < low <= high')


@dataclass(frozen=True)
class SuiteMap:
    """One map of the suite: which scans of which log, where they are placed, and its label."""

    name: str
    dataset: str
    log_path: Path
    scan_indices: np.ndarray  # (N,) records of the log, in time order
    poses: np.ndarray  # (N, 3) laser poses of the map
    reference_poses: np.ndarray  # (N, 3) incremental solution, for the local scales
    inconsistent: bool
    kind: str  # 'corrected' or one of BREAKS
    description: str
    environment: str = 'static'


def keyframes(poses: np.ndarray, distance: float, angle: float) -> np.ndarray:
    """Indices of the poses kept when each must move `distance` or turn `angle` from the last.

    Parameters
    ----------
    poses: (N, 3) poses in travel order.
    distance: metres from the last kept pose.
    angle: radians from the last kept pose's heading.

    Returns
    -------
    (V,) int64 increasing row indices into `poses`, the first pose always kept.
    """
    return viewpoint_rows(poses, distance, angle)


def displace(poses: np.ndarray, first: int, last: int, rotation: float,
             shift: np.ndarray) -> np.ndarray:
    """Poses with those in [first, last) turned by `rotation` about the position of pose
    `first` and then moved by `shift`: a rigid displacement of that part of the trajectory.

    Parameters
    ----------
    poses: (N, 3) poses; not changed.
    first: index of the first displaced pose, the centre of the rotation.
    last: one past the last displaced pose.
    rotation: radians, counter-clockwise.
    shift: (2,) translation in metres, applied after the rotation.

    Returns
    -------
    (N, 3) float64 copy with the displaced rows.
    """
    poses = np.array(poses, dtype=np.float64)
    centre = poses[first, :2]
    cos_r, sin_r = np.cos(rotation), np.sin(rotation)
    turned_centre = np.array([cos_r * centre[0] - sin_r * centre[1],
                              sin_r * centre[0] + cos_r * centre[1]])
    transform = np.array([*(centre + np.asarray(shift) - turned_centre), rotation])
    poses[first:last] = se2.compose(transform, poses[first:last])
    return poses


def _parts(count: int, size: int) -> list[np.ndarray]:
    starts = list(range(0, count, size))
    if len(starts) > 1 and count - starts[-1] < size // 2:
        starts.pop()
    bounds = starts + [count]
    return [np.arange(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])]


def _draw_break(kind: str, count: int, rng: np.random.Generator,
                parameters: SuiteParameters) -> tuple[int, int, float, np.ndarray, str]:
    """(first, last, rotation, shift, description) of one break of a part of `count` scans."""
    rotation = 0.0
    shift = np.zeros(2)
    if kind in ('rotation', 'rotation+shift', 'corrupted'):
        rotation = np.radians(rng.uniform(*parameters.rotation_degrees)) * rng.choice([-1, 1])
    if kind in ('shift', 'rotation+shift', 'corrupted'):
        heading = rng.uniform(-np.pi, np.pi)
        shift = rng.uniform(*parameters.shift_metres) * np.array([np.cos(heading),
                                                                  np.sin(heading)])
    first = int(rng.integers(count // 4, 3 * count // 4))
    last = count
    if kind == 'corrupted':
        last = first + int(rng.integers(parameters.block_scans[0], parameters.block_scans[1] + 1))
    description = (f'scans {first}..{last - 1} turned {np.degrees(rotation):+.1f} deg, '
                   f'moved {np.hypot(*shift):.2f} m')
    return first, last, rotation, shift, description


def dataset_maps(name: str, log: CarmenLog, log_path: Path,
                 parameters: SuiteParameters) -> list[SuiteMap]:
    """The consistent parts of one corrected log and their broken copies.

    Parameters
    ----------
    name: the dataset's name (a key of CORRECTED_LOGS); it seeds the dataset's generator
        together with `parameters.seed`, and prefixes the map names.
    log: the corrected log.
    log_path: the log's file, recorded in each map.
    parameters: keyframe thresholds, part size and break magnitudes.

    Returns
    -------
    Per part, in log order, the consistent map '<name>/part<i>/corrected' followed by one
    broken copy per kind of BREAKS ('<name>/part<i>/<kind>').
    """
    # one generator per dataset: a map does not change when other datasets are left out
    rng = np.random.default_rng([parameters.seed, sum(name.encode())])
    frames = keyframes(log.laser_poses, parameters.keyframe_distance, parameters.keyframe_angle)
    maps = []
    for part_number, part in enumerate(_parts(len(frames), parameters.part_size)):
        indices = frames[part]
        poses = log.laser_poses[indices]
        prefix = f'{name}/part{part_number}'
        maps.append(SuiteMap(f'{prefix}/corrected', name, log_path, indices, poses, poses, False,
                             'corrected', f'{len(indices)} corrected keyframes'))
        for kind in BREAKS:
            first, last, rotation, shift, description = _draw_break(kind, len(indices), rng,
                                                                    parameters)
            maps.append(SuiteMap(f'{prefix}/{kind}', name, log_path, indices,
                                 displace(poses, first, last, rotation, shift), poses, True,
                                 kind, description))
    return maps


def build_suite(data_folder: str | Path, parameters: SuiteParameters | None = None,
                datasets: list[str] | None = None) -> list[SuiteMap]:
    """Every map of the suite, the same for the same seed and data.

    Parameters
    ----------
    data_folder: the shared data folder holding the CORRECTED_LOGS paths.
    parameters: how the suite is cut and broken; None for the defaults.
    datasets: names of CORRECTED_LOGS to use, in this order; None for all.

    Returns
    -------
    The maps of every dataset as dataset_maps gives them. Raises ValueError for an unknown
    dataset name and InputError for a missing or malformed log.
    """
    parameters = parameters or SuiteParameters()
    data_folder = Path(data_folder)
    names = list(CORRECTED_LOGS) if datasets is None else datasets
    unknown = sorted(set(names) - set(CORRECTED_LOGS))
    if unknown:
        raise ValueError(f'unknown datasets {unknown}; known: {sorted(CORRECTED_LOGS)}')
    maps = []
    for name in names:
        path = data_folder / CORRECTED_LOGS[name]
        maps.extend(dataset_maps(name, read_carmen_log(path), path, parameters))
    return maps
