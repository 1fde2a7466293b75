"""Does clutter hide a misalignment? (issue 29: a region whose failures are mostly "change")

    .venv/bin/python bench/clutter_probe.py LOG SEAM_FRACTION SHIFT_M TURN_DEG CLUTTER

The log's viewpoints (0.4 m / 0.4 rad) from SEAM_FRACTION of the run on are turned by TURN_DEG
about the seam and shifted by SHIFT_M (evaluation.suite.displace), and every later scan gets
CLUTTER objects: runs of 3-15 beams cut to 30-80 % of their range (people and furniture that
were not there on the first visit), seeded. Prints the verdict and the pair classes.
"""
from __future__ import annotations

import sys

import numpy as np

from map_consistency_ros.core.geometry import ScanSet, viewpoint_rows
from map_consistency_ros.core.verdict import check_map
from map_consistency_ros.evaluation.suite import displace
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model


def main(argv: list[str]) -> None:
    path, seam_fraction, shift, turn, clutter = (argv[0], float(argv[1]), float(argv[2]),
                                                 float(argv[3]), int(argv[4]))
    log = read_carmen_log(path)
    model = sensor_model(log, max_range=8.0)
    rows = viewpoint_rows(log.laser_poses, 0.4, 0.4)
    poses, ranges = log.laser_poses[rows].copy(), log.ranges[rows].astype(float)
    count = len(rows)
    seam = int(seam_fraction * count)
    poses = displace(poses, seam, count, np.radians(turn), np.array([shift, 0.0]))
    rng = np.random.default_rng(0)
    beams = ranges.shape[1]
    for row in range(seam, count):
        for _ in range(clutter):
            start, width = rng.integers(0, beams - 15), rng.integers(3, 15)
            ranges[row, start:start + width] *= rng.uniform(0.3, 0.8)
    assessment = check_map(ScanSet.from_ranges(ranges, poses, model))
    print(f'{path}: seam {seam} of {count}, shift {shift} m, turn {turn} deg, clutter {clutter}: '
          f'{assessment.summary_line()}; pair classes {assessment.class_counts()}')


if __name__ == '__main__':
    main(sys.argv[1:])
