"""Tune the DCS parameter Phi of a pose graph for the most consistent map, and test that map.

Searches Phi* = argmin M(Phi), the average pairwise inconsistency of the DCS solution
(Mazuran et al., ICRA 2014, Section V): a grid over sqrt(Phi), then golden-section refinement.
Prints Phi*, M(Phi*) and the statistical test's verdict on the map at Phi*, beside the map
at Phi = 1. Exit code 0 when the map at Phi* is consistent, 1 when not, 2 on bad input, 3 on an
internal error. A graph that cannot be tuned honestly (absurd numbers, disconnected, no loop
closure: the checks of the node's retune) is bad input.

input forms:
  GRAPH.g2o                 g2o SE(2) graph whose vertices carry ROBOTLASER1 lines (gm2dl)
  GRAPH.g2o --scans LOG     scans from a CARMEN log instead: laser record k is the scan of
                            the k-th vertex in id order
  --build LOG RELATIONS BAG build the graph from a corrected CARMEN log, a relations file and
                            the raw bag (odometry edges from the bag's /odom, loop closures
                            from the relations); --save-graph keeps it as g2o

examples:
  map-consistency tune intel_graph.g2o --report out/tune.json --profile-plot out/profile.png
  map-consistency tune --build intel.gfs.log intel.relations intel.orig.bag \\
      --false-loops 100 --save-graph out/intel_f100.g2o --maps-plot out/maps.png
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from map_consistency_ros.cli import exit_codes, options, report
from map_consistency_ros.cli.progress import ProgressBar
from map_consistency_ros.core.backend import (InconsistencyProfile, TuningResult, TuningSettings,
                                              search_findings, tune_dcs, tuning_problem)
from map_consistency_ros.core.consistency import check_consistency
from map_consistency_ros.core.geometry import SensorModel
from map_consistency_ros.core.verdict import INCONSISTENT, Assessment, explain
from map_consistency_ros.io import carmen, datasets
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.g2o import G2oGraph, read_g2o, write_g2o



def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add tune's arguments: the input forms, graph building, the search's parameters, the
    sensor, the test's and the verdict's parameters, the outputs.

    Parameters
    ----------
    parser: the parser of the `tune` subcommand.
    """
    parser.add_argument('graph', type=Path, nargs='?', help='g2o graph file (see input forms)')
    parser.add_argument('--scans', type=Path, metavar='LOG',
                        help='CARMEN log with one laser record per vertex, in vertex id order')
    parser.add_argument('--build', type=Path, nargs=3, metavar=('LOG', 'RELATIONS', 'BAG'),
                        help='build the graph from a corrected log, relations and raw bag')
    build = parser.add_argument_group('graph building (with --build)')
    build.add_argument('--false-loops', type=int, default=0, metavar='N',
                       help='add N false loop closures between random scan pairs')
    build.add_argument('--corrupt-guess', action='store_true',
                       help='start from a noisy propagation of the trajectory')
    build.add_argument('--stride', type=int, default=1, help='keep every STRIDE-th scan')
    build.add_argument('--seed', type=int, default=0, help='random seed (default %(default)s)')
    build.add_argument('--save-graph', type=Path, metavar='G2O', help='write the built graph')
    options.add_parameter_arguments(parser, TuningSettings, 'search')
    options.add_sensor_arguments(parser)
    options.add_test_arguments(parser)
    options.add_verdict_arguments(parser)
    output = parser.add_argument_group('output')
    output.add_argument('--report', type=Path, metavar='JSON', help='write the result as JSON')
    output.add_argument('--profile-plot', type=Path, metavar='PNG',
                        help='write M(Phi) over the search range (the paper\'s Fig. 4, bottom)')
    output.add_argument('--maps-plot', type=Path, metavar='PNG',
                        help='write the map at Phi = 1 beside the map at Phi*')
    output.add_argument('--quiet', action='store_true', help='no progress bar')


def load_graph(args: argparse.Namespace) -> tuple[G2oGraph, carmen.CarmenLog]:
    """The graph and the CARMEN-style record of its scans, from whichever input form was used.

    Parameters
    ----------
    args: the parsed arguments (graph, --scans, --build and the graph-building options).

    Returns
    -------
    (the graph file's content, the log whose laser records are the vertices' scans in vertex
    id order). InputError when neither or both of GRAPH and --build are given, when the log
    has not one laser record per vertex, when the graph carries no scans and no --scans is
    given, or when a file cannot be read.
    """
    if (args.graph is None) == (args.build is None):
        raise InputError('arguments', 'give either GRAPH or --build LOG RELATIONS BAG')
    if args.build is not None:
        try:
            settings = datasets.BuildSettings(stride=args.stride, seed=args.seed,
                                              false_loop_closures=args.false_loops,
                                              corrupt_guess=args.corrupt_guess)
        except ValueError as error:
            raise InputError('options', str(error)) from None
        content = datasets.build_dataset(*args.build, settings=settings)
        if args.save_graph:
            write_g2o(args.save_graph, content)
    else:
        content = read_g2o(args.graph)
    if args.scans is not None:
        log = carmen.read_carmen_log(args.scans)
        if log.scan_count != content.graph.vertex_count:
            raise InputError(str(args.scans), f'{log.scan_count} laser records for '
                                              f'{content.graph.vertex_count} vertices')
        return content, log
    if content.laser is None:
        raise InputError(str(args.graph), 'no ROBOTLASER1 lines: give the scans with --scans LOG')
    return content, content.laser


def run(args: argparse.Namespace) -> int:
    """Tune Phi on the input of `args`, print the summary and write the outputs asked for.

    Parameters
    ----------
    args: the parsed arguments of `tune`.

    Returns
    -------
    The exit code of the verdict on the map at Phi* (cli/exit_codes.py). InputError
    (exit code 2) on bad options, files or graphs, and on a graph that cannot be tuned
    honestly (core.backend.tuning_problem: the node's retune refuses the same).
    """
    try:
        config = options.configuration(args, ('consistency', 'explanation', 'tuning'))
    except ValueError as error:
        raise InputError('options', str(error)) from None
    settings, parameters, explanation = config.tuning, config.consistency, config.explanation
    options.check_sensor_options(args)
    content, log = load_graph(args)
    source = str(args.graph or args.build[0])
    problem = tuning_problem(content.graph)
    if problem:
        raise InputError(source, f'cannot tune this graph honestly: {problem}')
    if args.scans is not None:
        ranges, offset = log.ranges, (0.0, 0.0, 0.0)
    else:
        ranges, offset = content.scan_ranges(), content.laser_offset
    try:
        model = carmen.sensor_model(log, fov=options.fov_radians(args), max_range=args.max_range,
                                    range_min=args.range_min)
        profile = InconsistencyProfile(content.graph, ranges, model, offset, settings)
    except ValueError as error:
        raise InputError(log.path, str(error)) from None
    started = time.perf_counter()
    with ProgressBar('tuning Phi', enabled=not args.quiet) as progress:
        try:
            result = tune_dcs(content.graph, ranges, model, offset, settings, parameters,
                              progress, profile)
        except ValueError as error:
            raise InputError(source, str(error)) from None
    elapsed = time.perf_counter() - started
    baseline = profile.evaluate(1.0)
    baseline_scans = profile.scans_at(baseline.optimization.poses)
    baseline_test = explain(baseline_scans, check_consistency(
        baseline_scans, parameters,
        reference_scans=profile.scans_at(content.graph.odometry_chain())), explanation)
    tuned = explain(profile.scans_at(result.poses), result.consistency, explanation)
    _print_summary(source, result, tuned, baseline.value, baseline_test, elapsed)
    warnings = search_findings(result, settings, options.option_name)
    for warning in warnings:
        print(f'map-consistency tune: {source}: warning: {warning}', file=sys.stderr)
    written = []
    if args.report:
        report.write_json(args.report, _report(source, result, tuned, model, baseline,
                                               baseline_test, settings, elapsed, warnings))
        written.append(('report', args.report))
    if args.profile_plot:
        _save_profile(args.profile_plot, result, settings, source)
        written.append(('profile plot', args.profile_plot))
    if args.maps_plot:
        _save_maps(args.maps_plot, profile, baseline.optimization.poses, baseline_test, result,
                   tuned)
        written.append(('maps plot', args.maps_plot))
    if args.build is not None and args.save_graph:
        written.append(('graph', args.save_graph))
    for name, path in written:
        print(f'  {name:<22}{path}')
    return exit_codes.of_outcome(tuned.outcome)


def _print_summary(source: str, result: TuningResult, tuned: Assessment, baseline_value: float,
                   baseline_test: Assessment, elapsed: float) -> None:
    # M is a mean over overlapping scan pairs of the summed distances (m) by which end points
    # lie inside the other scan's free space (eq. 11)
    print(f'{source}: Phi* = {result.phi:.6g}, map at Phi* {tuned.summary_line()}')
    print(f'  M(Phi*)               {result.average_inconsistency:.6g} m '
          '(average inconsistency of the overlapping scan pairs)')
    print(f'  M(1)                  {baseline_value:.6g} m '
          f'({baseline_test.outcome} at Phi = 1)')
    print(f'  inconsistent scans    {int(result.consistency.inconsistent.sum())} of '
          f'{result.consistency.scan_count}')
    print(f'  evaluations           {len(result.profile_phi)}')
    print(f'  tuning time           {elapsed:.1f} s')
    if tuned.outcome == INCONSISTENT:
        print('  still inconsistent at Phi*, the most consistent map DCS finds: no Phi '
              'downweights the error away; look for a wrong loop closure the graph trusts '
              '(high information) or a front-end fault (scan matching, odometry)')


def _report(source: str, result: TuningResult, tuned: Assessment, model: SensorModel, baseline,
            baseline_test: Assessment, settings: TuningSettings, elapsed: float,
            warnings: list[str]) -> dict:
    content = report.assessment_report(tuned)
    content.update({
        'source': source,
        'phi': result.phi,
        'average_inconsistency': result.average_inconsistency,
        'profile': {'phi': result.profile_phi, 'average_inconsistency': result.profile_value},
        'baseline_phi_1': {'average_inconsistency': baseline.value,
                           'summary': baseline_test.result.summary(),
                           'summary_line': baseline_test.summary_line()},
        'search': dict(vars(settings)),
        'sensor_model': vars(model),
        'poses': result.poses,
        'runtime_seconds': elapsed,
        'at_bound': result.at_bound,
        'flat_profile': result.flat,
        'warnings': warnings,
    })
    return content


def _save_profile(path: Path, result: TuningResult, settings: TuningSettings,
                  source: str) -> None:
    # matplotlib costs half a second of start-up: only the runs that draw pay it.
    from map_consistency_ros.cli import plots
    figure, ax = plots.plt.subplots(figsize=(5, 3.5))
    ax.plot(result.profile_phi, result.profile_value, '.-', lw=0.8, ms=3, c='tab:blue')
    ax.axvline(result.phi, c='red', lw=1, label=f'Phi* = {result.phi:.4g}')
    ax.set_xscale('function', functions=(lambda x: x ** 0.5, lambda x: x ** 2))
    ax.set_xlim(0.0, settings.phi_max * 1.03)  # keep a Phi* at the end visible
    ax.set_xticks([value for value in (0, 1, 4, 9, 16, 25, 36) if value <= settings.phi_max])
    ax.set_xlabel('DCS parameter Phi (square-root scale)')
    ax.set_ylabel('average inconsistency M(Phi) [m]')
    ax.set_title(Path(source).name, fontsize=9)
    ax.legend(fontsize=7)
    plots.save_figure(figure, path)


def _save_maps(path: Path, profile: InconsistencyProfile, baseline_poses,
               baseline_test: Assessment, result: TuningResult, tuned: Assessment) -> None:
    from map_consistency_ros.cli import plots
    figure, axes = plots.plt.subplots(1, 2, figsize=(14, 7))
    plots.plot_map(axes[0], profile.scans_at(baseline_poses), baseline_test, 'Phi = 1')
    plots.plot_map(axes[1], profile.scans_at(result.poses), tuned, f'Phi* = {result.phi:.4g}')
    plots.lay_out(figure)  # two long titles side by side: wrapped, laid out on their extents
    plots.save_figure(figure, path)

