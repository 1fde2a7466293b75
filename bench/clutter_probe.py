"""Does a changed world hide a misalignment, or pass for one? (the change / misalignment boundary)

    .venv/bin/python bench/clutter_probe.py LOG SEAM_FRACTION SHIFT_M TURN_DEG COUNT [--world]
    .venv/bin/python bench/clutter_probe.py --sweep [LOG ...]

The log's viewpoints (0.4 m / 0.4 rad) from SEAM_FRACTION of the run on are turned by TURN_DEG
about the seam and shifted by SHIFT_M (evaluation.suite.displace), and the later part of the run
sees a world that changed (seeded):

- flicker (default): every later scan gets COUNT objects of its own, runs of 3-15 beams cut to
  30-80 % of their range. Consecutive scans see different objects, unlike any real scene: the
  hardest case for the second stage, and one that also inflates the local scales.
- `--world`: COUNT discs of radius 0.15-0.4 m placed in free space seen from the later part (at
  30-80 % of a valid reading of a random later beam), cut into every later scan whose beams hit
  them, by ray casting at the true poses before the displacement: furniture brought in, seen
  consistently by every later scan that looks at it.

Prints the verdict and the pair classes; `--sweep` prints one table row per log, kind, COUNT and
displacement (seam at 0.6; clean, turned 1 deg, shifted 0.3 m).
"""
from __future__ import annotations

import sys

import numpy as np

from map_consistency_ros.core.geometry import ScanSet, SensorModel, viewpoint_rows
from map_consistency_ros.core.verdict import check_map
from map_consistency_ros.evaluation.suite import displace
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

DISC_RADII = (0.15, 0.4)  # metres: chairs to boxes
SWEEP_LOGS = ('/work/shared/data/intel/intel.gfs.log',
              '/work/shared/data/fr079/freiburg-079-corrected.log.gz')
SWEEP = (('flicker', 0), ('flicker', 10), ('flicker', 20), ('world', 30), ('world', 100),
         ('world', 300))
SWEEP_CASES = ((0.0, 0.0), (0.0, 1.0), (0.3, 0.0))  # (shift m, turn deg)


def flicker(ranges: np.ndarray, later: np.ndarray, count: int,
            rng: np.random.Generator) -> None:
    """Cut `count` runs of 3-15 beams of every `later` scan to 30-80 % of their range."""
    beams = ranges.shape[1]
    for row in later:
        for _ in range(count):
            start, width = rng.integers(0, beams - 15), rng.integers(3, 15)
            ranges[row, start:start + width] *= rng.uniform(0.3, 0.8)


def world_objects(ranges: np.ndarray, poses: np.ndarray, later: np.ndarray, count: int,
                  model: SensorModel, rng: np.random.Generator) -> None:
    """Cut `count` world-fixed discs into the `later` scans at their true `poses`."""
    bearings = model.bearings(ranges.shape[1])
    centres, radii = [], []
    while len(centres) < count:
        row, beam = rng.choice(later), rng.integers(0, ranges.shape[1])
        reading = ranges[row, beam]
        if not 0.5 < reading < model.max_range - 0.5:
            continue  # no return, or too close to place a disc before it
        distance = reading * rng.uniform(0.3, 0.8)
        heading = poses[row, 2] + bearings[beam]
        centres.append(poses[row, :2] + distance * np.array([np.cos(heading), np.sin(heading)]))
        radii.append(rng.uniform(*DISC_RADII))
    centres, radii = np.array(centres), np.array(radii)
    for row in later:
        headings = poses[row, 2] + bearings
        directions = np.stack([np.cos(headings), np.sin(headings)], axis=1)  # (K, 2)
        offsets = centres - poses[row, :2]  # (O, 2)
        along = directions @ offsets.T  # (K, O) distance to the disc centre's foot point
        miss2 = (offsets ** 2).sum(axis=1)[None] - along ** 2
        inside = miss2 < radii[None] ** 2
        entry = along - np.sqrt(np.maximum(radii[None] ** 2 - miss2, 0.0))
        hits = np.where(inside & (entry > 0.05), entry, np.inf)
        ranges[row] = np.minimum(ranges[row], hits.min(axis=1))


def probe(path: str, seam_fraction: float, shift: float, turn: float, count: int,
          world: bool) -> str:
    """The verdict line on one changed and displaced copy of the log (module docstring)."""
    log = read_carmen_log(path)
    model = sensor_model(log, max_range=8.0)
    rows = viewpoint_rows(log.laser_poses, 0.4, 0.4)
    poses, ranges = log.laser_poses[rows].copy(), log.ranges[rows].astype(float)
    scan_count = len(rows)
    seam = int(seam_fraction * scan_count)
    later = np.arange(seam, scan_count)
    rng = np.random.default_rng(0)
    if world:
        world_objects(ranges, poses, later, count, model, rng)
    else:
        flicker(ranges, later, count, rng)
    poses = displace(poses, seam, scan_count, np.radians(turn), np.array([shift, 0.0]))
    assessment = check_map(ScanSet.from_ranges(ranges, poses, model))
    classes = {str(name.value): count for name, count in assessment.class_counts().items()}
    return f'{assessment.summary_line()}; pair classes {classes}'


def sweep(logs: list[str]) -> None:
    """One markdown row per log, clutter kind and count, and displacement."""
    print('| log | clutter | count | shift m | turn deg | verdict |')
    print('|---|---|---|---|---|---|')
    for path in logs:
        for kind, count in SWEEP:
            for shift, turn in SWEEP_CASES:
                line = probe(path, 0.6, shift, turn, count, kind == 'world')
                print(f'| {path.split("/")[-1]} | {kind} | {count} | {shift} | {turn} | '
                      f'{line.split(";")[0]} |', flush=True)


def main(argv: list[str]) -> None:
    if argv and argv[0] == '--sweep':
        sweep(argv[1:] or list(SWEEP_LOGS))
        return
    world = '--world' in argv
    argv = [item for item in argv if item != '--world']
    path, seam_fraction, shift, turn, count = (argv[0], float(argv[1]), float(argv[2]),
                                               float(argv[3]), int(argv[4]))
    line = probe(path, seam_fraction, shift, turn, count, world)
    print(f'{path}: seam at {seam_fraction} of the run, shift {shift} m, turn {turn} deg, '
          f'{count} {"world-fixed discs" if world else "flickering objects per scan"}: {line}')


if __name__ == '__main__':
    main(sys.argv[1:])
