"""Whole-process `map-consistency check` of the Intel log beside shapely on the same pairs.

    .venv/bin/python bench/bench_check.py [--repeat 5] [--reference-tree DIR]

Times fresh processes (interpreter start, imports, numba cache load, log reading, the test,
the verdict) as a user sees them: `check LOG --max-range 8 --quiet` and `--help`, with the bare
interpreter and `import numpy` as floors. `--reference-tree` times the same commands on another
checkout of the package (e.g. the commit before a change) in the same run. Then the measure of
every candidate pair by shapely in this process (prepared polygons, as bench_measure), the
straightforward alternative a user would write, whose time excludes its own imports.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench_measure import shapely_measures
from map_consistency_ros.core.geometry import ScanSet, candidate_pairs
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

TREE = Path(__file__).resolve().parents[1]
INTEL = TREE.parent / 'shared' / 'data' / 'intel' / 'intel.gfs.log'


def process_seconds(arguments: list[str], trees: list[Path], repeat: int) -> list[float]:
    """Median wall seconds of `python ARGUMENTS` with each tree first on the import path.

    The trees take turns run by run, so that a machine whose speed drifts during the bench
    (this one does, 2-3x between days) favours none of them. Bytecode is written and read as
    on a user's machine: an installed package has it (pip and colcon compile it), while
    PYTHONDONTWRITEBYTECODE, set here, would recompile every source of the tree at each start.
    """
    environment = {key: value for key, value in os.environ.items()
                   if key != 'PYTHONDONTWRITEBYTECODE'}
    walls: list[list[float]] = [[] for _ in trees]
    for _ in range(repeat + 1):
        for tree, runs in zip(trees, walls):
            start = time.perf_counter()
            subprocess.run([sys.executable, *arguments], cwd=tree, check=False,
                           env=dict(environment, PYTHONPATH=str(tree)),
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            runs.append(time.perf_counter() - start)
    # The first run may compile into an empty numba cache and write bytecode: not what a user
    # sees after install.
    return [float(np.median(runs[1:])) for runs in walls]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--log', type=Path, default=INTEL)
    parser.add_argument('--repeat', type=int, default=5)
    parser.add_argument('--reference-tree', type=Path, action='append', default=[],
                        help='another checkout whose package is timed in the same run')
    args = parser.parse_args()

    cli = ['-m', 'map_consistency_ros.cli.main']
    commands = [('python -c pass', ['-c', 'pass'], 'floor'),
                ('python -c "import numpy"', ['-c', 'import numpy'], 'floor'),
                ('map-consistency --help', [*cli, '--help'], 'target <= 0.3 s'),
                (f'map-consistency check {args.log.name} --max-range 8', [
                    *cli, 'check', str(args.log.resolve()), '--max-range', '8', '--quiet'],
                 'target <= 0.8 s')]
    trees = [('this tree', TREE)] + [(str(tree), tree.resolve()) for tree in args.reference_tree]
    print(f'{"whole process, median wall s of " + str(args.repeat):<52}'
          + ''.join(f'{name[-18:]:>20}' for name, _ in trees))
    check_seconds = 0.0
    for label, arguments, note in commands:
        seconds = process_seconds(arguments, [tree for _, tree in trees], args.repeat)
        check_seconds = seconds[0]
        print(f'{label:<52}' + ''.join(f'{value:>20.3f}' for value in seconds) + f'   {note}')

    log = read_carmen_log(args.log)
    scans = ScanSet.from_ranges(log.ranges, log.laser_poses, sensor_model(log))
    start = time.perf_counter()
    pairs = candidate_pairs(scans.extents)
    sums, counts = shapely_measures(scans, pairs)
    shapely_seconds = time.perf_counter() - start
    print(f'\nshapely, all {len(pairs)} candidate pairs in-process ({int((counts > 0).sum())} '
          f'overlap, sum M_ij = {sums.sum():.3f} m): {shapely_seconds:.3f} s wall, '
          f'{shapely_seconds / check_seconds:.1f}x the whole `check` process')


if __name__ == '__main__':
    main()
