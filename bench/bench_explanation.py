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

from bench_measure import median_time  # this folder's helpers: bench scripts run from here
from map_consistency_ros.core.consistency import check_consistency
from map_consistency_ros.core.verdict import explain
from report_identity import explanation_maps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args()
    print(f'{"map":<30} {"paper test [s]":>16} {"explanation [s]":>17} {"ratio":>7}  '
          'explained pairs')
    for name, scans in explanation_maps():
        test, result = median_time(lambda: check_consistency(scans), args.repeat)
        second, assessment = median_time(lambda: explain(scans, result), args.repeat)
        print(f'{name:<30} {test.wall:7.3f} ({test.cpu:5.2f}) {second.wall:8.3f} '
              f'({second.cpu:5.2f}) {second.wall / test.wall:6.0%}  '
              f'{assessment.explained_pairs.size} of '
              f'{result.failed_pair_count} failed')
    print('(wall seconds, CPU seconds in brackets; ratio = explanation / paper test, wall)')


if __name__ == '__main__':
    main()
