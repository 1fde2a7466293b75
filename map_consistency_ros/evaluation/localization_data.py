"""Labelled localization runs from the corrected logs, for the localization mode (issue 49).

From a corrected log (the benchmark's best poses, taken as the truth):

- **the map**: a nav2 map_server map (YAML + PGM, 0.05 m) ray-cast from every scan at its
  corrected pose (core/localization/_ray_cast.py). Each valid beam (a real return within
  the usable range) is traced cell by
  cell (Amanatides & Woo): the cells it crosses count a miss, the cell of its end point a
  hit; beams without a return clear nothing (their length is unknown). A cell is occupied
  when hits / (hits + misses) > 0.25 (gmapping's occupancy threshold), free when visited and
  not occupied, unknown when no beam reached it.
- **runs**: the same scans as CARMEN logs whose poses are a localizer's estimate:
  `corrected` (the truth); `kidnap_*`, from scan `start` on for `length` scans every pose off
  by one rigid map-frame error, then back (0.1 m, 0.3 m, 2 deg, 5 deg, and a 1 m / 10 deg
  jump: as a localizer that latched onto a wrong map -> odom while odometry stays good; the
  turn is about the robot's position at the first off scan, the shift to the robot's left
  there); `frozen`, from scan `start` on for `length` scans the estimate stays where it was
  (a localizer that stopped updating); `outdated`, the corrected poses against a copy of the
  map made out of date.
- **the outdated map**: walls removed (a 1 m square around a well-observed occupied cell made
  free, as the map of a place before a wall was built: every non-free cell of the square) and
  furniture-size blocks added (0.6-1.0 m squares of occupied cells on open floor with 0.2 m
  of free space around them, as a map made before furniture was taken away).
- **labels**, by construction (never by the tool under test): per scan the estimate's error
  against the corrected pose; a scan is off when it is more than 0.15 m or 1.5 degrees away;
  an episode is at least 5 consecutive off scans. For `outdated`, the changes and, per scan,
  its valid end points inside a removed wall's square and its beams crossing an added block.

Outputs go under the folder given (never committed): `DATASET/map.yaml`, `map.pgm`,
`outdated.yaml`, `outdated.pgm`, `runs/NAME.log.gz`, `labels/NAME.json`, `manifest.json`.
Run `python -m map_consistency_ros.evaluation.localization_data OUT [--data FOLDER]
[--datasets intel fr079] [--scans N]`.
"""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.localization import (FREE, OCCUPIED, OCCUPIED_RATIO,
                                                   OccupancyGrid, beams_crossing, ray_cast_grid)
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.io.carmen_writer import write_flaser_log
from map_consistency_ros.io.occupancy_map import write_occupancy_map
from map_consistency_ros.io.staging import staged

CORRECTED_LOGS = {
    'intel': 'intel/intel.gfs.log',
    'fr079': 'fr079/freiburg-079-corrected.log.gz',
}
OFF_METRES = 0.15
OFF_DEGREES = 1.5
EPISODE_SCANS = 5
# (name, shift in metres to the robot's left, turn in degrees)
KIDNAPS = (('kidnap_0.1m', 0.1, 0.0), ('kidnap_0.3m', 0.3, 0.0), ('kidnap_2deg', 0.0, 2.0),
           ('kidnap_5deg', 0.0, 5.0), ('kidnap_1m_10deg', 1.0, 10.0))


@dataclass(frozen=True)
class GeneratorSettings:
    """What the generator makes; scan indices count from the first scan used."""

    resolution: float = 0.05
    margin: float = 1.0  # metres of unknown around the mapped area
    kidnap_start: int = 300
    kidnap_length: int = 300
    frozen_start: int = 450
    frozen_length: int = 60
    walls_removed: int = 4
    blocks_added: int = 6
    wall_square: float = 1.0  # metres
    block_sizes: tuple[float, float] = (0.6, 1.0)
    block_clearance: float = 0.2
    seed: int = 49
    scans: int | None = None  # the first N scans only (an excerpt), None for all
    kidnaps: tuple = field(default=KIDNAPS)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f'resolution must be positive, got {self.resolution}')
        for name in ('kidnap_start', 'kidnap_length', 'frozen_start', 'frozen_length'):
            if getattr(self, name) < 0:
                raise ValueError(f'{name} must not be negative')


# ---- runs and labels ---------------------------------------------------------------------

def kidnapped(truth: np.ndarray, start: int, length: int, shift: float,
              turn_degrees: float) -> np.ndarray:
    """Poses off by one rigid map-frame error from `start` for `length` scans.

    Parameters
    ----------
    truth: (N, 3) corrected poses.
    start, length: the first off scan and how many are off (clipped to the run).
    shift: metres, to the robot's left at `start`.
    turn_degrees: the turn, about the robot's position at `start`.

    Returns
    -------
    (N, 3) estimated poses.
    """
    poses = truth.copy()
    stop = min(start + length, len(truth))
    if start >= stop:
        return poses
    x, y, theta = truth[start]
    pivot = np.array([x, y, 0.0])
    # estimate = T(pivot + shift) . R(turn) . T(-pivot) . truth: the robot at `start` is
    # shifted by exactly `shift` and turned by `turn` in place
    moved_pivot = np.array([x - shift * math.sin(theta), y + shift * math.cos(theta),
                            math.radians(turn_degrees)])
    transform = se2.compose(moved_pivot, se2.inverse(pivot))
    poses[start:stop] = se2.compose(np.broadcast_to(transform, (stop - start, 3)),
                                    truth[start:stop])
    return poses


def frozen(truth: np.ndarray, start: int, length: int) -> np.ndarray:
    """Poses that stop updating at `start` for `length` scans.

    Parameters
    ----------
    truth: (N, 3) corrected poses.
    start, length: the first frozen scan (it keeps its own pose) and how many keep it.

    Returns
    -------
    (N, 3) estimated poses.
    """
    poses = truth.copy()
    stop = min(start + length, len(truth))
    if start < stop:
        poses[start:stop] = truth[start]
    return poses


def pose_labels(truth: np.ndarray, estimate: np.ndarray) -> dict:
    """Per scan errors of an estimate, the off scans and the episodes.

    Parameters
    ----------
    truth, estimate: (N, 3) poses.

    Returns
    -------
    {'translation_error_m': [...], 'rotation_error_deg': [...], 'off': [...],
    'episodes': [{'first', 'last', 'scans', 'max_translation_m', 'max_rotation_deg'}],
    'off_metres', 'off_degrees', 'episode_scans'}: a scan is off when its error exceeds
    OFF_METRES or OFF_DEGREES; an episode is a run of at least EPISODE_SCANS off scans.
    """
    translation = np.hypot(*(estimate[:, :2] - truth[:, :2]).T)
    rotation = np.degrees(np.abs(se2.wrap_angle(estimate[:, 2] - truth[:, 2])))
    off = (translation > OFF_METRES) | (rotation > OFF_DEGREES)
    episodes = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], off.astype(np.int8), [0]])))
    for first, stop in zip(edges[::2], edges[1::2]):
        if stop - first >= EPISODE_SCANS:
            episodes.append({'first': int(first), 'last': int(stop - 1),
                             'scans': int(stop - first),
                             'max_translation_m': float(translation[first:stop].max()),
                             'max_rotation_deg': float(rotation[first:stop].max())})
    return {'translation_error_m': [round(float(v), 6) for v in translation],
            'rotation_error_deg': [round(float(v), 6) for v in rotation],
            'off': off.tolist(), 'episodes': episodes, 'off_metres': OFF_METRES,
            'off_degrees': OFF_DEGREES, 'episode_scans': EPISODE_SCANS}


# ---- maps made out of date ---------------------------------------------------------------

def outdated_map(grid: OccupancyGrid, hits: np.ndarray, settings: GeneratorSettings,
                 rng: np.random.Generator) -> tuple[OccupancyGrid, list[dict], np.ndarray,
                                                    np.ndarray]:
    """A copy of the map with walls removed and blocks added.

    Parameters
    ----------
    grid: the up-to-date map.
    hits: (H, W) end point counts of the map's cells (well-observed walls are chosen).
    settings: how many changes of which sizes.
    rng: the seeded generator drawing them.

    Returns
    -------
    (the outdated grid, the changes [{'kind', 'rows': [first, stop), 'cols': [first, stop),
    'box_m': [xmin, ymin, xmax, ymax]}], removed (H, W) bool, added (H, W) bool).
    """
    cells = grid.cells.copy()
    resolution = grid.resolution
    removed = np.zeros(cells.shape, bool)
    added = np.zeros(cells.shape, bool)
    changes = []

    def record(kind, row, col, size):
        box = [grid.origin[0] + col * resolution, grid.origin[1] + row * resolution,
               grid.origin[0] + (col + size) * resolution,
               grid.origin[1] + (row + size) * resolution]
        changes.append({'kind': kind, 'rows': [int(row), int(row + size)],
                        'cols': [int(col), int(col + size)],
                        'box_m': [round(float(v), 6) for v in box]})

    side = max(1, int(round(settings.wall_square / resolution)))
    walls = np.argwhere((cells == OCCUPIED) & (hits >= np.percentile(hits[hits > 0], 75)))
    rng.shuffle(walls)
    for row, col in walls:
        if len([c for c in changes if c['kind'] == 'wall_removed']) >= settings.walls_removed:
            break
        row0, col0 = row - side // 2, col - side // 2
        if row0 < 0 or col0 < 0 or row0 + side > cells.shape[0] or col0 + side > cells.shape[1]:
            continue
        square = (slice(row0, row0 + side), slice(col0, col0 + side))
        # a wall bordering observed floor, away from the changes made so far
        if np.mean(cells[square] == FREE) < 0.3 or removed[square].any() or added[square].any():
            continue
        removed[square] = cells[square] != FREE
        cells[square] = FREE
        record('wall_removed', row0, col0, side)
    clearance = int(round(settings.block_clearance / resolution))
    low, high = (int(round(size / resolution)) for size in settings.block_sizes)
    floor = np.argwhere(cells == FREE)
    rng.shuffle(floor)
    for row, col in floor:
        if len([c for c in changes if c['kind'] == 'block_added']) >= settings.blocks_added:
            break
        size = int(rng.integers(low, high + 1))
        row0, col0 = row - clearance, col - clearance
        total = size + 2 * clearance
        if row0 < 0 or col0 < 0 or row0 + total > cells.shape[0] or col0 + total > cells.shape[1]:
            continue
        around = (slice(row0, row0 + total), slice(col0, col0 + total))
        if not (cells[around] == FREE).all() or removed[around].any():
            continue
        block = (slice(row, row + size), slice(col, col + size))
        cells[block] = OCCUPIED
        added[block] = True
        record('block_added', row, col, size)
    return (OccupancyGrid(cells=cells, resolution=resolution, origin=grid.origin), changes,
            removed, added)


# ---- the whole set -----------------------------------------------------------------------

def _write_json(path: Path, document: dict) -> None:
    with staged(path) as target:
        target.write_text(json.dumps(document, allow_nan=False, indent=1) + '\n')


def generate(data_folder: str | Path, out_folder: str | Path, dataset: str,
             settings: GeneratorSettings | None = None) -> dict:
    """Make the map, the outdated map, the runs and their labels of one dataset.

    Parameters
    ----------
    data_folder: the shared data folder (../shared/data).
    out_folder: where the dataset's folder is written.
    dataset: 'intel' or 'fr079'.
    settings: what to make; GeneratorSettings() when None.

    Returns
    -------
    The manifest (also written as DATASET/manifest.json): the files written, the settings,
    the map's cell counts and each run's episodes.
    """
    settings = settings or GeneratorSettings()
    if dataset not in CORRECTED_LOGS:
        raise ValueError(f'unknown dataset {dataset!r}; one of {sorted(CORRECTED_LOGS)}')
    log_path = Path(data_folder) / CORRECTED_LOGS[dataset]
    log = read_carmen_log(log_path)
    count = log.scan_count if settings.scans is None else min(settings.scans, log.scan_count)
    ranges, truth, stamps = log.ranges[:count], log.laser_poses[:count], log.timestamps[:count]
    model = sensor_model(log)
    scans = ScanSet.from_ranges(ranges, truth, model)
    grid, hits, _ = ray_cast_grid(scans, settings.resolution, settings.margin)
    rng = np.random.default_rng(settings.seed)
    old, changes, removed, added = outdated_map(grid, hits, settings, rng)

    folder = Path(out_folder) / dataset
    write_occupancy_map(folder / 'map.yaml', grid)
    write_occupancy_map(folder / 'outdated.yaml', old)
    runs = {'corrected': truth}
    for name, shift, turn in settings.kidnaps:
        runs[name] = kidnapped(truth, settings.kidnap_start, settings.kidnap_length, shift, turn)
    runs['frozen'] = frozen(truth, settings.frozen_start, settings.frozen_length)
    manifest = {'dataset': dataset, 'source': str(log_path), 'scans': int(count),
                'sensor': asdict(model), 'settings': _jsonable(asdict(settings)),
                'map': {'yaml': 'map.yaml', 'cells': grid.counts(),
                        'rule': f'occupied when hits / (hits + misses) > {OCCUPIED_RATIO}; '
                                'free when reached; beams without a return clear nothing'},
                'outdated_map': {'yaml': 'outdated.yaml', 'changes': changes},
                'runs': {}}
    for name, estimate in runs.items():
        log_name = f'runs/{name}.log.gz'
        write_flaser_log(folder / log_name, ranges, estimate, stamps,
                         comment=f'{dataset} localization run {name}: corrected scans at a '
                                 'localizer estimate (map_consistency_ros/evaluation/'
                                 'localization_data.py)', host='localization_data')
        labels = {'run': name, 'log': log_name, 'map': 'map.yaml', **pose_labels(truth, estimate)}
        _write_json(folder / f'labels/{name}.json', labels)
        manifest['runs'][name] = {'log': log_name, 'map': 'map.yaml',
                                  'labels': f'labels/{name}.json',
                                  'episodes': labels['episodes']}
    # the outdated run: the truth against the outdated map
    in_removed = _endpoints_in(scans, grid, removed)
    crossing = beams_crossing(scans, grid, added)
    labels = {'run': 'outdated', 'log': 'runs/corrected.log.gz', 'map': 'outdated.yaml',
              **pose_labels(truth, truth), 'changes': changes,
              'endpoints_in_removed_walls': in_removed.tolist(),
              'beams_crossing_added_blocks': crossing.tolist()}
    _write_json(folder / 'labels/outdated.json', labels)
    manifest['runs']['outdated'] = {'log': 'runs/corrected.log.gz', 'map': 'outdated.yaml',
                                    'labels': 'labels/outdated.json', 'episodes': [],
                                    'scans_seeing_changes': int(np.count_nonzero(
                                        (in_removed > 0) | (crossing > 0)))}
    _write_json(folder / 'manifest.json', manifest)
    return manifest


def _endpoints_in(scans: ScanSet, grid: OccupancyGrid, mask: np.ndarray) -> np.ndarray:
    rows, cols = grid.cell_of(scans.endpoints)
    on = grid.contains(rows, cols) & scans.valid
    inside = np.zeros(rows.shape, bool)
    inside[on] = mask[rows[on], cols[on]]
    return inside.sum(axis=1)


def _jsonable(value):
    if isinstance(value, dict):
        return {key: _jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(item) for item in value]
    return value


def main(argv: list[str] | None = None) -> int:
    """Command line: make the localization data of the datasets under a folder.

    Parameters
    ----------
    argv: the arguments (sys.argv[1:] when None).

    Returns
    -------
    0.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('out', type=Path, help='folder for the outputs')
    parser.add_argument('--data', type=Path,
                        default=Path(__file__).resolve().parents[3] / 'shared' / 'data',
                        help='the shared data folder')
    parser.add_argument('--datasets', nargs='+', default=sorted(CORRECTED_LOGS),
                        choices=sorted(CORRECTED_LOGS))
    parser.add_argument('--scans', type=int, default=None, help='the first N scans only')
    args = parser.parse_args(argv)
    for dataset in args.datasets:
        manifest = generate(args.data, args.out, dataset, GeneratorSettings(scans=args.scans))
        print(f'{dataset}: {manifest["scans"]} scans, map {manifest["map"]["cells"]}, '
              f'{len(manifest["outdated_map"]["changes"])} changes, '
              f'{len(manifest["runs"])} runs -> {args.out / dataset}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
