"""Compile the kernels every subcommand and the node use, into numba's cache, once.

numba compiles each kernel on its first call and keeps the machine code in its cache (beside
the package's sources, or in NUMBA_CACHE_DIR): the first command after an install would wait
for all of them (tens of seconds), every later one loads them in a fraction of a second. This
runs each path once on the demo bag bundled with the package: the live pipeline (node, replay,
batch of bags), `check` of a log (both stages on placed scans), the least-squares and DCS
back-end and the Phi search (`tune`, `~/retune_dcs`). `python3 bootstrap.py` runs it after
installing; after a pip or colcon install run it once as the user that runs the node.

examples:
  map-consistency warm-up
  NUMBA_CACHE_DIR=/var/cache/map_consistency map-consistency warm-up
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import time

from map_consistency_ros.core.backend import TuningSettings, optimize
from map_consistency_ros.core.consistency import ConsistencyParameters, select_viewpoints
from map_consistency_ros.core.verdict import check_map


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """`warm-up` takes no option but --quiet.

    Parameters
    ----------
    parser: the parser of the `warm-up` subcommand.
    """
    parser.add_argument('--quiet', action='store_true', help='print nothing')


def warm_up() -> float:
    """Run every compiled path once on the demo bag.

    Returns
    -------
    The seconds it took (compiling, or loading from the cache).
    """
    from map_consistency_ros.cli import main as cli_main
    from map_consistency_ros.cli import demo, replay
    started = time.perf_counter()
    arguments = cli_main.build_parser('replay').parse_args(
        ['replay', str(demo.demo_bag_path()), '--quiet'])
    with contextlib.redirect_stdout(io.StringIO()):
        judgement = replay.judge(arguments)
    monitor = judgement.monitor
    # check: both stages on the scans placed at once, as a log is judged
    every = monitor.evaluate().scans()
    check_map(every.take(select_viewpoints(every, ConsistencyParameters())))
    # the back-end: least squares, then the retune's DCS, Phi search and verdict, coarsely,
    # on the demo's graph with its wrong loop closure (a graph without one is not tuned)
    slam = monitor.slam_graph()
    closed = dataclasses.replace(slam, graph=demo.with_wrong_loop_closure(slam.graph,
                                                                          *demo.WRONG_LOOP))
    optimize(closed.graph, None, iterations=5)
    judgement.replay.pipeline.retune(closed, TuningSettings(grid_steps=3, tolerance=1.0,
                                                            iterations=5, workers=1))
    return time.perf_counter() - started


def run(args: argparse.Namespace) -> int:
    """Warm numba's cache.

    Parameters
    ----------
    args: parsed `warm-up` options.

    Returns
    -------
    0.
    """
    seconds = warm_up()
    if not args.quiet:
        print(f'warm-up: compiled kernels cached ({seconds:.1f} s)')
    return 0
