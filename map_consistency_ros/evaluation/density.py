"""The density suite: one map sampled at several densities, and displaced copies of each.

Two parts:

- `native_log`: Intel rebuilt at the laser's native rate. The corrected log (`intel.gfs.log`)
  keeps 910 of the 13,631 raw scans of `intel.orig.bag` (~0.67 m apart). Every raw scan is
  placed from its nearest corrected keyframe (in time) by the raw odometry between the two
  stamps, then registered (core.verdict, point-to-line ICP) onto the surfaces of the
  corrected keyframes around it; keyframes keep their corrected poses. Written as a gzip CARMEN
  log of FLASER records with the raw scans' stamps.
- The suite: each log at every n-th scan (and Intel at its keyframes), the map itself and
  copies with everything after a fixed point of the run turned about that point or shifted.
  The point is chosen by stamp (the scan at `PIVOT_TRAVEL` of the travelled distance of the
  full-density log), so every density displaces the same stretch of the building about the same
  centre. Each case runs in its own process (`run_case`, `python -m ...density case`) so that
  its peak resident memory is its own.

Truth of a copy: the RMS distance between the end points of the displaced scans at the copy's
and at the true poses (over all displaced scans, and over the scans of the largest reported
region), and the rotation.
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyParameters, select_viewpoints
from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.verdict import RegistrationSettings, register_submaps, surface_points
from map_consistency_ros.io.carmen import CarmenLog, read_carmen_log, sensor_model
from map_consistency_ros.io.carmen_writer import write_flaser_log
from map_consistency_ros.io.datasets import RawBag, match_scans
from map_consistency_ros.io.staging import staged

# log name -> path under the data folder (intel-native: under the checkout, built by native_log)
LOGS = {
    'fr079': 'fr079/freiburg-079-corrected.log.gz',
    'intel-native': 'data/density/intel-native.log.gz',
}
# the source tree this module belongs to (holds data/density/)
CHECKOUT = Path(__file__).resolve().parents[2]
INTEL_KEYFRAMES = 'intel/intel.gfs.log'
INTEL_BAG = 'intel/intel.orig.bag'
INTEL_RELATIONS = 'intel/intel.relations'
DENSITIES = {'fr079': ('1', '2', '5', '10'),
             'intel-native': ('1', '2', '5', '10', 'keyframes')}
# case name -> (rotation degrees, shift metres)
CASES = {'map': (0.0, 0.0), 'rot1': (1.0, 0.0), 'rot2': (2.0, 0.0), 'rot5': (5.0, 0.0),
         'shift0.1': (0.0, 0.1), 'shift0.3': (0.0, 0.3)}
PIVOT_TRAVEL = 0.5  # fraction of the travelled distance where the displaced stretch begins
SHIFT_HEADING = 0.6  # radians, world direction of the shifts (fixed: the same at every density)

# Refinement of the in-between scans: the keyframes within this many of the nearest one form
# the reference, and corrections beyond these bounds are not trusted (the odometry between
# neighbouring keyframes, ~0.67 m apart, does not drift that far).
REFERENCE_KEYFRAMES = 2
MAX_CORRECTION_M = 0.3
MAX_CORRECTION_RAD = np.radians(8.0)


# ---------------------------------------------------------------- Intel at its native rate


@dataclass(frozen=True)
class NativeLog:
    """Raw scans placed in the corrected map: (S,) stamps, (S, K) ranges, (S, 3) laser poses."""

    stamps: np.ndarray
    ranges: np.ndarray
    poses: np.ndarray
    odometry_poses: np.ndarray  # before registration
    keyframe_rows: np.ndarray  # (N,) rows of the corrected keyframes, increasing
    registered: np.ndarray  # (S,) bool: the registration's correction was applied


def native_log(keyframes: CarmenLog, bag: RawBag,
               settings: RegistrationSettings | None = None) -> NativeLog:
    """Every raw scan of `bag` placed by odometry from its nearest keyframe, then registered.

    The bag's laser offset is taken into account (odometry moves the base, poses are the
    laser's); keyframes keep their corrected laser poses exactly.

    Parameters
    ----------
    keyframes: the corrected keyframe log (intel.gfs.log), N scans found in the bag by their
        ranges.
    bag: the raw bag's scans, odometry and laser offset (io.datasets.read_raw_bag), S scans.
    settings: the registration onto the keyframes; None for the defaults.

    Returns
    -------
    A NativeLog of the S raw scans in bag order. Raises InputError when a keyframe matches no
    raw scan, ValueError when two keyframes match the same one.
    """
    rows = match_scans(keyframes, bag)
    if len(np.unique(rows)) != len(rows):
        raise ValueError('two keyframes match the same raw scan')
    # intel.gfs.log has four keyframes out of time order: place and register in time order
    order = np.argsort(rows)
    rows, keyframe_poses = rows[order], keyframes.laser_poses[order]
    stamps = bag.scan_stamps
    nearest = _nearest_keyframe(stamps[rows], stamps)
    offset = np.asarray(bag.laser_offset, dtype=np.float64)
    odometry = bag.odometry_at(stamps)
    # laser pose = keyframe laser pose * offset^-1 * odom(k)^-1 * odom(t) * offset
    step = se2.relative(odometry[rows[nearest]], odometry)
    placed = se2.compose(se2.compose(se2.compose(keyframe_poses[nearest],
                                                 se2.inverse(offset)), step), offset)
    placed[rows] = keyframe_poses
    poses, registered = _register_onto_keyframes(bag.scan_ranges, placed, rows, nearest,
                                                 sensor_model(keyframes), settings)
    return NativeLog(stamps=stamps, ranges=bag.scan_ranges, poses=poses, odometry_poses=placed,
                     keyframe_rows=rows, registered=registered)


def _nearest_keyframe(keyframe_stamps: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    after = np.clip(np.searchsorted(keyframe_stamps, stamps), 1, len(keyframe_stamps) - 1)
    before = after - 1
    closer_before = (stamps - keyframe_stamps[before]) <= (keyframe_stamps[after] - stamps)
    return np.where(closer_before, before, after)


def _register_onto_keyframes(ranges: np.ndarray, placed: np.ndarray, rows: np.ndarray,
                             nearest: np.ndarray, model, settings) -> tuple[np.ndarray, np.ndarray]:
    """Register every non-keyframe scan onto keyframes nearest-2 .. nearest+2 (one pass)."""
    count = len(rows)
    others = np.setdiff1d(np.arange(len(placed)), rows)
    # keyframes first, then the scans to place: the references are contiguous keyframe ranges
    order = np.concatenate([rows, others])
    scans = ScanSet.from_ranges(ranges[order], placed[order], model)
    surfaces = surface_points(scans.endpoints, scans.valid)
    centre = nearest[others]
    first = np.clip(centre - REFERENCE_KEYFRAMES, 0, count - 1)
    last = np.clip(centre + REFERENCE_KEYFRAMES + 1, 1, count)
    query = count + np.arange(len(others))
    tasks = np.stack([first, last, query, query + 1], axis=1)
    result = register_submaps(surfaces, tasks, settings)
    transforms = result.world_transforms()
    # the correction's size on the scan: its translation at the scan's own position
    moved = se2.compose(transforms, placed[others])
    step = se2.relative(placed[others], moved)
    trusted = (result.determined & (np.hypot(step[:, 0], step[:, 1]) < MAX_CORRECTION_M)
               & (np.abs(step[:, 2]) < MAX_CORRECTION_RAD))
    poses = placed.copy()
    poses[others[trusted]] = moved[trusted]
    registered = np.zeros(len(placed), dtype=bool)
    registered[others[trusted]] = True
    return poses, registered


def write_carmen_log(path: Path, native: NativeLog) -> None:
    """FLASER records (laser pose in both pose slots, as the corrected logs have it), gzip.

    Ranges are written in their shortest float32 form, so that reading them back gives the
    bag's float32 values exactly (the keyframes are found again by identical ranges).

    Parameters
    ----------
    path: the gzip log to write (its folder is created, an existing file replaced).
    native: the placed scans; poses with 6 decimals, stamps in seconds with 6 decimals.
    """
    write_flaser_log(path, np.asarray(native.ranges, dtype=np.float32), native.poses,
                     native.stamps, host='density',
                     comment='Intel Research Lab at the native laser rate: raw scans of '
                             'intel.orig.bag placed from the corrected keyframes of intel.gfs.log '
                             'by odometry and point-to-line ICP '
                             '(map_consistency_ros/evaluation/density.py)')


def relation_errors(stamps: np.ndarray, poses: np.ndarray,
                    relations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Errors of a trajectory against the relations whose two stamps are scans of the log.

    Parameters
    ----------
    stamps: (S,) increasing scan stamps, seconds.
    poses: (S, 3) the scans' poses.
    relations: (R, 5) rows `t1 t2 x y yaw` as io.datasets.read_relations gives them; a
        relation is used when both stamps lie within 1 ms of a scan's.

    Returns
    -------
    (translation errors (F,) metres, rotation errors (F,) radians, absolute) of the F
    relations used, in file order.
    """
    first = np.searchsorted(stamps, relations[:, 0]).clip(0, len(stamps) - 1)
    second = np.searchsorted(stamps, relations[:, 1]).clip(0, len(stamps) - 1)
    found = ((np.abs(stamps[first] - relations[:, 0]) < 1e-3)
             & (np.abs(stamps[second] - relations[:, 1]) < 1e-3))
    step = se2.relative(poses[first[found]], poses[second[found]])
    truth = relations[found][:, 2:5]
    return (np.hypot(*(step[:, :2] - truth[:, :2]).T),
            np.abs(se2.wrap_angle(step[:, 2] - truth[:, 2])))


# ---------------------------------------------------------------- the suite


@dataclass(frozen=True)
class Case:
    """One map of the suite: a log at a density, displaced or not."""

    log: str
    density: str  # '1', '2', ... (every n-th scan) or 'keyframes'
    case: str  # key of CASES

    @property
    def name(self) -> str:
        every = 'keyframes' if self.density == 'keyframes' else f'every {self.density}'
        return f'{self.log} {every} {self.case}'


def selection(log: CarmenLog, density: str, keyframes: CarmenLog | None = None) -> np.ndarray:
    """Rows of `log` at `density`: every n-th record, or those with the keyframes' ranges.

    Parameters
    ----------
    log: the full-density log.
    density: 'n' (a positive integer: every n-th record from the first) or 'keyframes'.
    keyframes: the keyframe log, needed for 'keyframes' only.

    Returns
    -------
    (M,) int64 rows of `log`; for 'keyframes', one per keyframe in the keyframe log's order.
    Raises ValueError for a density that is neither, or 'keyframes' without the keyframe
    log, and InputError when a keyframe's ranges are not in `log`.
    """
    if density == 'keyframes':
        if keyframes is None:
            raise ValueError('the keyframes density needs the keyframe log')
        stand_in = SimpleNamespace(scan_ranges=log.ranges.astype(np.float32),
                                   scan_stamps=log.timestamps)
        return match_scans(keyframes, stand_in)
    every = int(density)
    if every < 1:
        raise ValueError(f'density must be a positive integer or "keyframes", got {density}')
    return np.arange(0, log.scan_count, every)


def pivot(poses: np.ndarray, stamps: np.ndarray, travel: float = PIVOT_TRAVEL):
    """Where the displaced stretch begins: the first full-density scan at `travel` of the
    distance travelled.

    Parameters
    ----------
    poses: (N, 3) laser poses of the full-density log, in time order.
    stamps: (N,) their stamps, seconds.
    travel: fraction of the total travelled distance, in [0, 1].

    Returns
    -------
    (stamp of that scan, its position (2,), the centre of the rotations).
    """
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    distance = np.concatenate([[0.0], np.cumsum(steps)])
    row = int(np.searchsorted(distance, travel * distance[-1]))
    return float(stamps[row]), poses[row, :2].copy()


def displaced(poses: np.ndarray, stamps: np.ndarray, start: float, centre: np.ndarray,
              degrees: float, metres: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses with those at or after `start` turned by `degrees` about `centre` and then
    shifted by `metres` along SHIFT_HEADING.

    Parameters
    ----------
    poses: (N, 3) poses; not changed.
    stamps: (N,) their stamps, seconds.
    start: stamp of the first displaced pose (see `pivot`).
    centre: (2,) centre of the rotation.
    degrees: rotation, counter-clockwise.
    metres: length of the shift.

    Returns
    -------
    (displaced copy of the poses (N, 3), the rows moved (D,) int64).
    """
    rotation = np.radians(degrees)
    cos_r, sin_r = np.cos(rotation), np.sin(rotation)
    shift = metres * np.array([np.cos(SHIFT_HEADING), np.sin(SHIFT_HEADING)])
    turned = np.array([cos_r * centre[0] - sin_r * centre[1], sin_r * centre[0] + cos_r * centre[1]])
    transform = np.array([*(centre - turned + shift), rotation])
    rows = np.flatnonzero(stamps >= start)
    moved = np.array(poses, dtype=np.float64)
    moved[rows] = se2.compose(transform, moved[rows])
    return moved, rows


def endpoint_rms(scans: ScanSet, rows: np.ndarray, true_poses: np.ndarray) -> float:
    """RMS distance between the valid end points of `rows` at the scans' poses and at the
    true poses (all end points of those scans pooled).

    Parameters
    ----------
    scans: the scans at their (displaced) poses.
    rows: indices of the scans to compare.
    true_poses: (N, 3) true poses of all the scans.

    Returns
    -------
    The RMS in metres; 0 when `rows` is empty or its scans have no valid end point.
    """
    if len(rows) == 0:
        return 0.0
    truth = scans.with_poses(true_poses)
    square = np.sum((scans.endpoints[rows] - truth.endpoints[rows]) ** 2, axis=-1)
    valid = scans.valid[rows]
    return float(np.sqrt(square[valid].mean())) if valid.any() else 0.0


def load(case: Case, data: Path, checkout: Path):
    """The viewpoints `check` tests for `case`, placed as the case displaces them.

    Parameters
    ----------
    case: the log, density and displacement.
    data: the shared data folder (FR079, the Intel keyframe log).
    checkout: the source tree holding data/density/intel-native.log.gz.

    Returns
    -------
    (ScanSet of the V viewpoints, their true poses (V, 3), the displaced viewpoints (D,)
    int64; empty for the case 'map'). Raises InputError for a missing or malformed log.
    """
    path = (checkout if case.log == 'intel-native' else data) / LOGS[case.log]
    log = read_carmen_log(path)
    keyframes = (read_carmen_log(data / INTEL_KEYFRAMES)
                 if case.density == 'keyframes' else None)
    rows = selection(log, case.density, keyframes)
    start, centre = pivot(log.laser_poses, log.timestamps)
    degrees, metres = CASES[case.case]
    true_poses = log.laser_poses[rows]
    poses, moved = displaced(true_poses, log.timestamps[rows], start, centre, degrees, metres)
    if case.case == 'map':
        moved = np.zeros(0, dtype=np.int64)
    # the viewpoints `check` tests, selected on the map's poses as it selects them
    parameters = ConsistencyParameters()
    every = ScanSet.from_ranges(log.ranges[rows], poses, sensor_model(log))
    keep = select_viewpoints(every, parameters)
    displaced_row = np.zeros(len(rows), dtype=bool)
    displaced_row[moved] = True
    return every.take(keep), true_poses[keep], np.flatnonzero(displaced_row[keep])


def run_case(case: Case, data: Path, checkout: Path) -> dict:
    """The verdict of `check` (its viewpoints, core.verdict.check_map at default settings)
    on the case, with its runtime, this process's peak memory and the truth.

    Parameters
    ----------
    case: the case to judge.
    data: the shared data folder.
    checkout: the source tree holding data/density/.

    Returns
    -------
    A JSON-ready row: the case's fields and name, viewpoint count, verdict, flag and region
    counts, the largest region (displacement m, rotation deg, scans, registered; None /
    0 without one), the truth (rotation, shift, end point RMS over all displaced scans and
    over those of the largest region), check seconds and peak resident MB.
    """
    from map_consistency_ros.core.verdict import check_map
    scans, true_poses, moved = load(case, data, checkout)
    started = time.perf_counter()
    assessment = check_map(scans)
    seconds = time.perf_counter() - started
    regions = assessment.misalignments
    largest = max(regions, key=lambda item: (np.nan_to_num(item.displacement, nan=np.inf)),
                  default=None)
    degrees, metres = CASES[case.case]
    row = {
        **asdict(case), 'name': case.name, 'scans': scans.scan_count,
        'consistent': bool(assessment.consistent), 'summary': assessment.summary_line(),
        'paper_flagged': int(assessment.result.inconsistent.sum()),
        'flagged': int(assessment.flagged.sum()), 'regions': len(regions),
        'largest_displacement_m': None, 'largest_dtheta_deg': None, 'largest_scans': 0,
        'largest_registered': None,
        'truth_rotation_deg': degrees, 'truth_shift_m': metres,
        'truth_rms_m': endpoint_rms(scans, moved, true_poses), 'displaced_scans': len(moved),
        'truth_rms_region_m': None,
        'seconds': seconds, 'peak_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    if largest is not None:
        row.update(largest_displacement_m=_finite(largest.displacement),
                   largest_dtheta_deg=_finite(np.degrees(largest.correction[2])),
                   largest_scans=int(len(largest.scans)),
                   largest_registered=bool(largest.registered))
        if len(moved):
            region = np.intersect1d(largest.scans, moved)
            row['truth_rms_region_m'] = endpoint_rms(scans, region, true_poses)
    return row


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def all_cases(logs=None, densities=None, cases=None) -> list[Case]:
    """Every (log, density, case) asked for, FR079 first; None means all.

    Parameters
    ----------
    logs: keys of LOGS, in this order (KeyError for others); None or empty for all.
    densities: densities to keep among each log's DENSITIES; None for all.
    cases: keys of CASES, in this order; None or empty for all.

    Returns
    -------
    The cases, log outermost, then density, then case.
    """
    chosen = []
    for log in logs or list(LOGS):
        for density in DENSITIES[log]:
            if densities is not None and density not in densities:
                continue
            for case in cases or list(CASES):
                chosen.append(Case(log, density, case))
    return chosen


def run_in_subprocess(case: Case, data: Path, checkout: Path, nice: int = 5,
                      timeout: float | None = None) -> dict:
    """`run_case` in a fresh `nice`d interpreter with the caller's PYTHONPATH and checkout.

    Parameters
    ----------
    case: the case to run.
    data: the shared data folder.
    checkout: the source tree holding data/density/.
    nice: niceness increment of the process.
    timeout: seconds before the process is killed; None for no limit.

    Returns
    -------
    run_case's row plus 'wall_seconds'; for a failed process, the case's fields, name and
    'error' (the timeout, or the last stderr line or the exit code).
    """
    command = ['nice', '-n', str(nice), sys.executable, '-m',
               'map_consistency_ros.evaluation.density', 'case', json.dumps(asdict(case)),
               str(data), str(checkout)]
    environment = dict(os.environ)
    started = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, env=environment,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return {**asdict(case), 'name': case.name, 'error': f'timeout after {timeout} s'}
    if done.returncode != 0:
        return {**asdict(case), 'name': case.name,
                'error': done.stderr.strip().splitlines()[-1] if done.stderr.strip() else
                f'exit {done.returncode}', 'wall_seconds': time.perf_counter() - started}
    row = json.loads(done.stdout.strip().splitlines()[-1])
    row['wall_seconds'] = time.perf_counter() - started
    return row


def markdown_table(rows: list[dict]) -> list[str]:
    """One line per case: verdict, regions, largest region against the truth, cost.

    Parameters
    ----------
    rows: rows of run_in_subprocess (error rows included).

    Returns
    -------
    The markdown lines: header, separator, then one per row.
    """
    lines = ['| log | density | case | scans | verdict | paper flags | flagged | regions | '
             'largest (m, deg, scans) | truth (deg, m; RMS all / region m) | check s | '
             'peak MB |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|']
    for row in rows:
        if 'error' in row:
            lines.append(f"| {row['log']} | {row['density']} | {row['case']} | | "
                         f"ERROR: {row['error']} | | | | | | | |")
            continue
        size = ('-' if row['regions'] == 0 else
                f"{_fmt(row['largest_displacement_m'])}, {_fmt(row['largest_dtheta_deg'], 2)}, "
                f"{row['largest_scans']}")
        truth = ('-' if row['case'] == 'map' else
                 f"{row['truth_rotation_deg']:g}, {row['truth_shift_m']:g}; "
                 f"{row['truth_rms_m']:.3f} / {_fmt(row['truth_rms_region_m'])}")
        verdict = 'CONSISTENT' if row['consistent'] else 'INCONSISTENT'
        lines.append(f"| {row['log']} | {row['density']} | {row['case']} | {row['scans']} | "
                     f"{verdict} | {row['paper_flagged']} | {row['flagged']} | {row['regions']} | "
                     f"{size} | {truth} | {row['seconds']:.1f} | {row['peak_rss_mb']:.0f} |")
    return lines


def build_native(data: Path, output: Path) -> dict:
    """Rebuild Intel at its native rate from the data folder into `output`.

    Parameters
    ----------
    data: the shared data folder with intel.gfs.log, intel.orig.bag and intel.relations.
    output: the gzip CARMEN log to write (see write_carmen_log).

    Returns
    -------
    {'scans', 'keyframes', 'registered' (counts), 'relation_errors'}: for 'odometry' and
    'registered' placement, the relations used and their mean and median errors in metres
    and degrees. Raises InputError for missing or malformed inputs.
    """
    from map_consistency_ros.io.datasets import read_raw_bag, read_relations
    native = native_log(read_carmen_log(data / INTEL_KEYFRAMES), read_raw_bag(data / INTEL_BAG))
    write_carmen_log(output, native)
    relations = read_relations(data / INTEL_RELATIONS)
    errors = {}
    for name, poses in (('odometry', native.odometry_poses), ('registered', native.poses)):
        metres, radians = relation_errors(native.stamps, poses, relations)
        errors[name] = {'relations': len(metres), 'mean_m': float(metres.mean()),
                        'median_m': float(np.median(metres)),
                        'mean_deg': float(np.degrees(radians.mean())),
                        'median_deg': float(np.degrees(np.median(radians)))}
    return {'scans': len(native.stamps), 'keyframes': len(native.keyframe_rows),
            'registered': int(native.registered.sum()), 'relation_errors': errors}


def run_suite(cases: list[Case], data: Path, checkout: Path, json_path: Path, doc_path: Path,
              timeout: float | None = None, report=print) -> list[dict]:
    """Every case in its own process, one at a time; the JSON and the markdown table are
    rewritten after each case so that an interrupted run keeps what it measured.

    Parameters
    ----------
    cases: the cases, in order.
    data: the shared data folder.
    checkout: the source tree holding data/density/ (recorded in the JSON).
    json_path: the JSON file of the rows (its folder is created).
    doc_path: the markdown page of the table (its folder is created).
    timeout: seconds per case; None for no limit.
    report: called with each case's table line as it finishes.

    Returns
    -------
    The rows of run_in_subprocess, in case order.
    """
    rows = []
    for case in cases:
        rows.append(run_in_subprocess(case, data, checkout, timeout=timeout))
        report(markdown_table(rows[-1:])[-1])
        with staged(json_path) as target:
            target.write_text(json.dumps({'checkout': str(checkout), 'cases': rows},
                                         indent=1, allow_nan=False))
        with staged(doc_path) as target:
            target.write_text('\n'.join([
                '# One map at several densities', '',
                '_Generated by `map-consistency evaluate --suite density` (evaluation/density.py): '
                'each log at every n-th scan (Intel rebuilt at its native rate also at its 910 '
                'keyframes), the map and copies with everything after the same point of the run '
                'turned or shifted, `check` at default settings in a process of its own. "scans": '
                'the viewpoints tested; "largest": the largest region (RMS displacement, rotation, '
                'scans; "-" beyond local registration); "truth": the rotation and shift made and '
                'the '
                'RMS displacement of the displaced scans\' end points (all of them / those of the '
                'largest region); "peak MB": the process\'s peak resident memory._', '',
                *markdown_table(rows)]) + '\n')
    return rows


def _fmt(value, digits: int = 3) -> str:
    return '-' if value is None else f'{value:.{digits}f}'


def _main(argv: list[str]) -> int:
    if len(argv) == 4 and argv[0] == 'case':
        case = Case(**json.loads(argv[1]))
        print(json.dumps(run_case(case, Path(argv[2]), Path(argv[3])), allow_nan=False))
        return 0
    print('usage: python -m map_consistency_ros.evaluation.density case CASE_JSON DATA CHECKOUT',
          file=sys.stderr)
    return 2


if __name__ == '__main__':
    sys.exit(_main(sys.argv[1:]))
