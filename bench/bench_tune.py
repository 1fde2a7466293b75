"""The Phi search on the built Intel graph (100 false loops, corrupted guess), beside references.

    .venv/bin/python bench/bench_tune.py [--false-loops 100] [--reference-tree DIR]

Builds the graph as `tune --build ... --false-loops 100 --corrupt-guess` does, saves it as g2o
with its laser data, then runs `map-consistency tune GRAPH.g2o` (default search: 20 grid steps,
tolerance 1e-4) as fresh processes and reads their summaries: this tree with its defaults, this
tree with the exhaustive search (`--flat-tolerance 0 --reuse-tolerance 0`: every pair measured on
every map, golden section down to the tolerance) and, with `--reference-tree`, another checkout
(e.g. the commit before a change) in the same run. The tuning time excludes start-up, graph
reading and the Phi = 1 comparison the command prints after the search; the process CPU
seconds include them.
"""
from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

from map_consistency_ros.io.datasets import BuildSettings, build_dataset
from map_consistency_ros.io.g2o import write_g2o

TREE = Path(__file__).resolve().parents[1]
INTEL = TREE.parent / 'shared' / 'data' / 'intel'
FIELDS = {'phi': r'Phi\* = (\S+),', 'verdict': r'map at Phi\* (\w+)',
          'm_star': r'M\(Phi\*\)\s+(\S+)', 'flagged': r'inconsistent scans\s+(\d+)',
          'evaluations': r'evaluations\s+(\d+)', 'seconds': r'tuning time\s+(\S+) s'}


def tune_summary(tree: Path, graph: Path, extra: list[str]) -> dict[str, str]:
    """Run `tune GRAPH` with `tree`'s package and return the figures of its summary, with the
    CPU seconds of the whole process (all threads: steadier than wall on a shared machine)."""
    environment = dict(os.environ, PYTHONPATH=str(tree))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    run = subprocess.run([sys.executable, '-m', 'map_consistency_ros.cli.main', 'tune',
                          str(graph), '--quiet', *extra], env=environment, cwd=tree,
                         capture_output=True, text=True, check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    found = {name: re.search(pattern, run.stdout) for name, pattern in FIELDS.items()}
    if not all(found.values()):
        raise RuntimeError(f'tune in {tree} failed:\n{run.stdout}\n{run.stderr}')
    summary = {name: match.group(1) for name, match in found.items()}
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    summary['cpu'] = f'{cpu:.1f}'
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--false-loops', type=int, default=100)
    parser.add_argument('--reference-tree', type=Path, action='append', default=[],
                        help='another checkout whose `tune` is timed in the same run')
    args = parser.parse_args()
    content = build_dataset(INTEL / 'intel.gfs.log', INTEL / 'intel.relations',
                            INTEL / 'intel.orig.bag',
                            BuildSettings(false_loop_closures=args.false_loops,
                                          corrupt_guess=True))
    graph = content.graph
    print(f'Intel graph: {graph.vertex_count} vertices, {graph.edge_count} edges '
          f'({int(graph.is_loop_closure.sum())} loop closures, {args.false_loops} false), '
          f'corrupted initial guess; target <= 10 s')
    runs = [('this tree', TREE, []),
            ('this tree, exhaustive search', TREE, ['--flat-tolerance', '0',
                                                    '--reuse-tolerance', '0'])]
    runs += [(str(tree), tree.resolve(), []) for tree in args.reference_tree]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / 'intel.g2o'
        write_g2o(path, content)
        print(f'{"run":<36}{"tuning s":>10}{"process cpu s":>15}{"evals":>7}{"Phi*":>10}'
              f'{"M(Phi*)":>10}{"flagged":>9}  verdict')
        for label, tree, extra in runs:
            summary = tune_summary(tree, path, extra)
            print(f'{label[-36:]:<36}{summary["seconds"]:>10}{summary["cpu"]:>15}'
                  f'{summary["evaluations"]:>7}'
                  f'{summary["phi"]:>10}{summary["m_star"]:>10}{summary["flagged"]:>9}  '
                  f'{summary["verdict"]}')


if __name__ == '__main__':
    main()
