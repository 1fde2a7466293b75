"""What the second stage of the verdict (explanation.py) adds to the paper's test, in one run.

    .venv/bin/python bench/bench_explanation.py [--repeat 5]

For each map the reference is the paper's full test (check_consistency: local scales,
candidate pairs, measures, both tests) on the same scans in the same run; the figure is the
explanation (registration of the failed pairs' submaps, the corrected pairs' test, regions,
changed places) and its ratio to that reference. Maps: the corrected Intel map (910 scans),
the same with everything after scan 455 turned by 1 degree, the first 290 scans of Intel (the
demo map), and Freiburg 101, which passes the paper's test's cascade almost everywhere.
Medians of --repeat runs after a warm-up, wall and process CPU seconds.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bench_measure import median_time  # this folder's helper: bench scripts run from here
from map_consistency_ros.core.consistency import check_consistency
from map_consistency_ros.core.explanation import explain
from map_consistency_ros.core.scan_geometry import ScanSet
from map_consistency_ros.evaluation.suite import displace
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data'


def maps() -> list[tuple[str, ScanSet]]:
    intel = read_carmen_log(DATA / 'intel' / 'intel.gfs.log')
    model = sensor_model(intel)
    turned = displace(intel.laser_poses, 455, intel.scan_count, np.radians(1.0), np.zeros(2))
    fr101 = read_carmen_log(DATA / 'carmen_corrected_extra' / 'freiburg-101-corrected.log.gz')
    return [
        ('Intel corrected (910 scans)', ScanSet.from_ranges(intel.ranges, intel.laser_poses,
                                                            model)),
        ('Intel, 1 deg after scan 455', ScanSet.from_ranges(intel.ranges, turned, model)),
        ('Intel demo map (290 scans)', ScanSet.from_ranges(intel.ranges[:290],
                                                           intel.laser_poses[:290], model)),
        ('Freiburg 101 (292 scans)', ScanSet.from_ranges(fr101.ranges, fr101.laser_poses,
                                                         sensor_model(fr101))),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args()
    print(f'{"map":<30} {"paper test [s]":>16} {"explanation [s]":>17} {"ratio":>7}  '
          'explained pairs')
    for name, scans in maps():
        test, result = median_time(lambda: check_consistency(scans), args.repeat)
        second, assessment = median_time(lambda: explain(scans, result), args.repeat)
        print(f'{name:<30} {test.wall:7.3f} ({test.cpu:5.2f}) {second.wall:8.3f} '
              f'({second.cpu:5.2f}) {second.wall / test.wall:6.0%}  '
              f'{assessment.explained_pairs.size} of '
              f'{result.failed_pair_count} failed')
    print('(wall seconds, CPU seconds in brackets; ratio = explanation / paper test, wall)')


if __name__ == '__main__':
    main()
