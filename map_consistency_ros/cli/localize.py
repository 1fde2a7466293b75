"""Was the robot where its localizer said, on a fixed map? Live scans judged against the map.

RUN is a CARMEN log whose laser poses are the localizer's estimates (map frame); REFERENCE a
nav2 map_server map (YAML + image) or a mapping run (a CARMEN log, or a .g2o graph with
ROBOTLASER1 lines) ray-cast into a 0.05 m grid. Every scan is tested against the map (the
paper's test per scan, the cascaded test over windows of travel); flagged stretches are
registered onto the map: a correction that is significant, mends the scans and that
overlapping submaps agree on is a mislocalization (the correction is the localizer's error),
anything else a change (the map is out of date there). Scan indices are the 0-based positions
of RUN's laser records. docs/localization.md has the rule and the defaults.

Exit codes: 0 localized throughout, 1 mislocalized somewhere (an episode or a frozen
estimate), 2 bad input, 3 internal error, 4 nothing to judge (no window of scans the map
could judge).

examples:
  map-consistency localize run.log.gz --map map.yaml --report out/loc.json --plot out/loc.png
  map-consistency localize run.log.gz --map mapping_run.log.gz --max-range 8
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from map_consistency_ros.cli import check, exit_codes, options
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.localization import (LocalizationResult, LocalizationSettings,
                                                   MapSurface, OccupancyGrid, localize,
                                                   prepare_reference, ray_cast_grid)
from map_consistency_ros.core.parameters import settings_from_values
from map_consistency_ros.core.verdict import plain, to_json
from map_consistency_ros.io import carmen
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.staging import StagedOutputs

MAP_SUFFIXES = ('.yaml', '.yml')
RAY_CAST_RESOLUTION = 0.05  # metres: the cells of a map made from a mapping run
# the paper's test's parameters the test against a map reads (core/localization)
TEST_OPTIONS = ('alpha', 'local_alpha', 'failure_probability', 'binomial_alpha', 'local_window',
                'min_points', 'trim_largest', 'default_scale', 'min_scale', 'fold_depth',
                'fold_disagreement')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `localize`: the run, --map, the sensor options and the outputs.

    Parameters
    ----------
    parser: the parser of the `localize` subcommand.
    """
    parser.add_argument('log', type=Path, metavar='RUN',
                        help="CARMEN log whose laser poses are the localizer's estimates")
    parser.add_argument('--map', type=Path, required=True, metavar='REFERENCE',
                        help='nav2 map YAML, or a mapping run (CARMEN log, .g2o with laser)')
    options.add_sensor_arguments(parser)
    # the paper's test's options that apply against a map (no viewpoint folding in this mode)
    options.add_parameter_arguments(parser, ConsistencyParameters, 'statistical test',
                                    only=TEST_OPTIONS)
    options.add_parameter_arguments(parser, LocalizationSettings, 'localization')
    group = parser.add_argument_group('output')
    group.add_argument('--report', type=Path, metavar='JSON',
                       help='write the findings and the parameters as strict JSON')
    group.add_argument('--plot', type=Path, metavar='PNG',
                       help='write the map, the estimated path, episodes and changes')


def load_reference(args: argparse.Namespace) -> OccupancyGrid:
    """The reference map: read, or ray-cast from a mapping run's scans.

    Parameters
    ----------
    args: parsed options: map, and the sensor options for a mapping run.

    Returns
    -------
    The OccupancyGrid. Raises InputError for a map or run that cannot be read.
    """
    path = Path(args.map)
    if path.suffix.lower() in MAP_SUFFIXES:
        from map_consistency_ros.io.occupancy_map import read_occupancy_map
        return read_occupancy_map(path).grid
    log, ranges, poses, _ = check.read_laser_records(path)
    grid, _, _ = ray_cast_grid(check.place_scans(args, log, ranges, poses, str(path)),
                               RAY_CAST_RESOLUTION)
    return grid


def run(args: argparse.Namespace) -> int:
    """Judge the run against the map, print the findings, write the outputs.

    Parameters
    ----------
    args: parsed `localize` options.

    Returns
    -------
    The exit code: 0 localized, 1 mislocalized, 4 nothing to judge (bad input raises
    InputError, mapped to 2 by cli/main.py).
    """
    options.check_sensor_options(args)
    values = options.parameter_values(args)
    try:
        parameters = settings_from_values(ConsistencyParameters, values)
        settings = settings_from_values(LocalizationSettings, values)
    except ValueError as error:
        raise InputError('options', str(error)) from None
    log = carmen.read_carmen_log(args.log)
    scans = check.place_scans(args, log, log.ranges, log.laser_poses, str(args.log))
    grid = load_reference(args)
    result = localize(scans, log.timestamps, MapSurface.of(prepare_reference(grid)), parameters,
                      settings)
    stamps = log.timestamps
    print(summary(result, stamps, str(args.log)))
    if args.report or args.plot:
        with StagedOutputs() as outputs:
            if args.report:
                document = report(result, stamps, parameters, settings, str(args.log),
                                  str(args.map))
                outputs.path(args.report).write_text(to_json(document, indent=1) + '\n')
            if args.plot:
                plot(outputs.path(args.plot), grid, scans, result, str(args.log))
    if result.outcome == 'mislocalized':
        return exit_codes.EXIT_INCONSISTENT
    if result.outcome == 'nothing to judge':
        return exit_codes.EXIT_NOTHING_TO_JUDGE
    return exit_codes.EXIT_CONSISTENT


def summary(result: LocalizationResult, stamps: np.ndarray, source: str) -> str:
    """The findings in a few lines.

    Parameters
    ----------
    result: the localization result.
    stamps: (N,) the run's stamps, seconds.
    source: the run's name.

    Returns
    -------
    The text (no trailing newline).
    """
    judged = int(result.tests.judged.sum())
    lines = [f'{source}: {result.outcome} ({judged} of {result.tests.judged.size} scans judged '
             f'against the map)']
    for episode in result.episodes:
        lines.append(f'  mislocalized: records {episode.first}-{episode.last} '
                     f'({stamps[episode.first] - stamps[0]:.1f}-'
                     f'{stamps[episode.last] - stamps[0]:.1f} s): position off by '
                     f'{episode.position_error:.2f} m, heading by '
                     f'{math.degrees(episode.heading_error):.1f} deg')
    for stretch in result.frozen:
        lines.append(f'  frozen estimate: records {int(stretch.scans[0])}-'
                     f'{int(stretch.scans[-1])} at one pose while the scans changed '
                     f'{stretch.changes} times')
    for change in result.changes:
        lines.append(f'  map out of date at ({change.x:.2f}, {change.y:.2f}) m: records '
                     f'{change.first}-{change.last}, {change.points} points')
    if result.nothing_to_judge:
        lines.append(f'  nothing to judge: no window of travel held the '
                     f'{result.windows.flaggable_count} judged scans the test needs to flag '
                     'one (too few scans, or scans mostly in unknown space or off the map)')
    return '\n'.join(lines)


def report(result: LocalizationResult, stamps: np.ndarray, parameters: ConsistencyParameters,
           settings: LocalizationSettings, source: str, reference: str) -> dict:
    """The report as plain data (strict JSON through core.verdict.to_json).

    Parameters
    ----------
    result: the localization result.
    stamps: (N,) the run's stamps, seconds.
    parameters: the paper's test.
    settings: localization mode's own.
    source, reference: the run's and the map's names.

    Returns
    -------
    The report dict: localized, outcome, episodes, changes, frozen, counts, parameters.
    """
    return plain({
        'source': source, 'map': reference, 'outcome': result.outcome,
        'localized': result.localized, 'nothing_to_judge': result.nothing_to_judge,
        'scans': int(result.tests.judged.size), 'judged_scans': int(result.tests.judged.sum()),
        'failed_scans': int(result.tests.failed.sum()),
        'flagged_scans': int(result.windows.flagged.sum()),
        'minor_scans': int(result.minor.sum()),
        'episodes': [{'first': e.first, 'last': e.last,
                      'start_s': float(stamps[e.first]), 'end_s': float(stamps[e.last]),
                      'position_error_m': e.position_error,
                      'heading_error_deg': math.degrees(e.heading_error),
                      'correction': {'x': float(e.correction[0]), 'y': float(e.correction[1]),
                                     'theta_deg': math.degrees(e.correction[2])}}
                     for e in result.episodes],
        'changes': [{'first': c.first, 'last': c.last, 'x': c.x, 'y': c.y,
                     'points': c.points} for c in result.changes],
        'frozen': [{'first': int(f.scans[0]), 'last': int(f.scans[-1]), 'changes': f.changes}
                   for f in result.frozen],
        'parameters': {'consistency': parameters.as_dict(),
                       'localization': {name: getattr(settings, name)
                                        for name in settings.__dataclass_fields__}},
    })


def plot(path: Path, grid: OccupancyGrid, scans: ScanSet, result: LocalizationResult,
         source: str) -> None:
    """The map, the estimated path, episodes in red with their corrected paths, changes.

    Parameters
    ----------
    path: the PNG to write (a staged path).
    grid: the map.
    scans: the live scans at the estimated poses.
    result: the localization result.
    source: the run's name, the title.
    """
    # the map figures' conventions: the file's name as title, metres on the axes, the legend
    # below them, the text laid out within the figure
    from map_consistency_ros.cli import plots
    figure, axes = plots.plt.subplots(figsize=(9, 9))
    shade = np.where(grid.cells == 100, 0.0, np.where(grid.cells == 0, 1.0, 0.75))
    corners = grid.cell_centres(np.array([0, grid.height - 1]), np.array([0, grid.width - 1]))
    half = 0.5 * grid.resolution
    axes.imshow(shade, cmap='gray', origin='lower', vmin=0, vmax=1,
                extent=(corners[0, 0] - half, corners[1, 0] + half,
                        corners[0, 1] - half, corners[1, 1] + half))
    for shade_value, name in ((0.0, 'map: occupied'), (1.0, 'map: free'), (0.75, 'map: unknown')):
        axes.fill([], [], color=str(shade_value), edgecolor='0.5', label=name)
    poses = scans.sensor_poses
    axes.plot(poses[:, 0], poses[:, 1], color='tab:blue', linewidth=0.8, label='estimate')
    for index, episode in enumerate(result.episodes):
        rows = slice(episode.first, episode.last + 1)
        axes.plot(poses[rows, 0], poses[rows, 1], color='red', linewidth=1.6,
                  label='mislocalized' if index == 0 else None)
        moved = se2.compose(episode.correction, poses[rows])
        axes.plot(moved[:, 0], moved[:, 1], color='tab:green', linewidth=1.0, linestyle='--',
                  label='corrected' if index == 0 else None)
    for index, change in enumerate(result.changes):
        axes.plot(change.x, change.y, 'o', markerfacecolor='none', markeredgecolor='orange',
                  markersize=10, label='map out of date' if index == 0 else None)
    axes.set_title(plots.wrapped(f'{plots.title_name(source)}: {result.outcome}', axes, 10),
                   fontsize=10)
    axes.set_xlabel('x [m]')
    axes.set_ylabel('y [m]')
    axes.set_aspect('equal')
    plots.add_legend(axes)
    plots.lay_out(figure)
    plots.save_figure(figure, path)
