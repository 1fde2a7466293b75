"""Replay the demo bag bundled with the package through the live monitor, then break it.

The demo bag holds the first 290 scans of the Intel Research Lab with their corrected poses
(/scan, /trajectory, /constraints, as a SLAM stack publishes them). The replay feeds them to
the same monitor the node runs and writes report.json, map.png, psi.png and pairs.csv into
--output: the corrected map passes.

Then the demo shows the other side: one wrong loop closure is added to the bag's pose graph
(the scan of laser record 268 seen from that of record 30, 0.6 m and 4 degrees off its true
place, as a false place recognition would report it), the graph is optimized by least squares
as a SLAM back-end would, and the optimized trajectory goes to the same monitor as the
back-end's next estimate. The verdict names the misaligned region and its size; its report,
map and the region zoomed in go to --output/wrong_loop_closure/.
"""
from __future__ import annotations

import argparse
import math
from importlib import resources
from pathlib import Path

import numpy as np

from map_consistency_ros.cli import main as cli_main
from map_consistency_ros.cli import check, exit_codes, replay, report
from map_consistency_ros.core.backend import PoseGraph, optimize
from map_consistency_ros.core.geometry import se2
from map_consistency_ros.core.verdict import explain

DEMO_BAG = 'intel_demo.mcap'
# the wrong loop closure: (from, to) vertices of the back-end's pose graph, the poses its
# constraints name in stamp order (in the demo bag every laser record: records 30 and 268),
# error (metres, metres, degrees)
WRONG_LOOP = ((30, 268), (0.6, 0.0, 4.0))


def demo_bag_path() -> Path:
    """The demo bag bundled with the package.

    Returns
    -------
    Its path inside the installed package (map_consistency_ros/data/intel_demo.mcap).
    """
    return Path(str(resources.files('map_consistency_ros') / 'data' / DEMO_BAG))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `demo`: --output and --quiet.

    Parameters
    ----------
    parser: the parser of the `demo` subcommand.
    """
    parser.add_argument('--output', type=Path, default=Path('out/demo'),
                        help='folder for the report and figures (default %(default)s)')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')


def with_wrong_loop_closure(graph: PoseGraph, keyframes: tuple[int, int],
                            error: tuple[float, float, float]) -> PoseGraph:
    """`graph` plus one wrong loop closure, weighted like the graph's first edge.

    Parameters
    ----------
    graph: the pose graph.
    keyframes: (from, to) vertices the loop closure joins.
    error: (dx, dy in metres, dtheta in degrees) composed with their current relative pose:
        the loop closure's measurement.

    Returns
    -------
    A new PoseGraph: the same poses and fixed vertices, the wrong edge after the others.
    """
    start, end = keyframes
    true = se2.relative(graph.poses[start], graph.poses[end])
    wrong = se2.compose(true, np.array([error[0], error[1], math.radians(error[2])]))
    return PoseGraph(poses=graph.poses, edge_from=np.r_[graph.edge_from, start],
                     edge_to=np.r_[graph.edge_to, end],
                     measurements=np.vstack([graph.measurements, wrong]),
                     information=np.concatenate([graph.information, graph.information[:1]]),
                     fixed=graph.fixed)


def break_map(judgement: replay.BagJudgement, out: Path, args: argparse.Namespace) -> int:
    """Close the wrong loop, give the monitor the optimized estimate, report its verdict.

    Parameters
    ----------
    judgement: the demo bag's replay; its monitor, holding the pose graph, takes the
        optimized trajectory as the back-end's next estimate, and its records name the scans.
    out: the --output folder; the report and map figure go to out/wrong_loop_closure/.
    args: the parsed options of the demo's replay, whose verdict settings explain the map.

    Returns
    -------
    The exit code of the verdict (cli/exit_codes.py); EXIT_INCONSISTENT (1) is the one
    expected. RuntimeError when the bag carries no constraints.
    """
    monitor = judgement.monitor
    slam = monitor.slam_graph()
    if slam is None:
        raise RuntimeError('the demo bag carries no constraints')
    (start, end), error = WRONG_LOOP
    solution = optimize(with_wrong_loop_closure(slam.graph, (start, end), error), None,
                        iterations=100)
    monitor.update_trajectory(slam.stamps, solution.poses)
    snapshot = monitor.evaluate()
    scans = snapshot.scans()
    _, explanation = check.verdict_settings(args)
    assessment = explain(scans, snapshot.result, explanation)
    # every output names scans by their laser records: the viewpoints judged, and the two
    # vertices of the graph the wrong loop closure joins
    scan_ids = judgement.replay.record_indices(snapshot.stamps)
    start, end = (int(record) for record in
                  judgement.replay.record_indices(slam.stamps[[start, end]]))
    print(f'\nThe same bag with one wrong loop closure (scan {end} seen from scan {start} '
          f'{error[0]:g} m and {error[2]:g} deg off), optimized by least squares:')
    print(report.format_summary(assessment, 'wrong loop closure', scan_ids))
    target = out / 'wrong_loop_closure'
    outputs = argparse.Namespace(report=target / 'report.json', plot=target / 'map.png',
                                 pairs_csv=None, explain=None)
    regions = check.write_outputs(outputs, scans, assessment,
                                  {'source': f'demo bag + one wrong loop closure {start}-{end}'},
                                  scan_ids)
    check.print_outputs([('report', outputs.report), ('figure', outputs.plot)], regions)
    return exit_codes.of_outcome(assessment.outcome)


def run(args: argparse.Namespace) -> int:
    """Both sides: replay the demo bag, then break its map (see the module docstring).

    Parameters
    ----------
    args: parsed `demo` options.

    Returns
    -------
    The exit code: 0 when the corrected map passes and the broken one fails, else 1.
    """
    out = args.output
    arguments = ['replay', str(demo_bag_path()), '--report', str(out / 'report.json'),
                 '--plot', str(out / 'map.png'), '--stats-plot', str(out / 'psi.png'),
                 '--pairs-csv', str(out / 'pairs.csv')]
    replay_args = cli_main.build_parser('replay').parse_args(arguments + (['--quiet'] if args.quiet
                                                                  else []))
    corrected, judgement = replay.replay_and_report(replay_args)
    broken = break_map(judgement, out, replay_args)
    as_expected = (corrected, broken) == (exit_codes.EXIT_CONSISTENT,
                                          exit_codes.EXIT_INCONSISTENT)
    print('\ndemo: ' + ('the corrected map passes and the wrong loop closure is caught'
                        if as_expected else 'UNEXPECTED verdicts (see above)'))
    return 0 if as_expected else 1
