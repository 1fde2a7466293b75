"""Test the map of a CARMEN log (or of a g2o graph with scans) for consistency.

Reads FLASER / ROBOTLASER1 records (plain or .gz), places every scan at its logged laser pose,
runs the statistical test (Mazuran et al., ICRA 2014) and prints the verdict. The test runs on
the viewpoints of the trajectory (--viewpoint-spacing, --viewpoint-turn): scans taken closer
than that to the previous viewpoint, standing still among them, are folded into it, so a log
recorded at the laser's rate gets the verdict of the same map keyframed. Scan indices in
every output are the 0-based positions of the laser records in the file. A .g2o graph whose
vertices carry ROBOTLASER1 lines is judged with its scans at the vertex poses as stored; its
scans are then named by vertex id.

examples:
  map-consistency check intel.gfs.log --max-range 8 --report out/intel.json --plot out/intel.png
  map-consistency check fr079-corrected.log.gz --pairs-csv out/pairs.csv
  map-consistency check intel_graph.g2o --plot out/graph.png
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from map_consistency_ros.cli import exit_codes, options, report
from map_consistency_ros.cli.progress import ProgressBar
from map_consistency_ros.core.consistency import ConsistencyParameters, select_viewpoints
from map_consistency_ros.core.geometry import ScanSet, se2
from map_consistency_ros.core.verdict import Assessment, check_map
from map_consistency_ros.io import carmen
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.staging import StagedOutputs


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `check`: the input, --every, the sensor, test and verdict options
    and the outputs.

    Parameters
    ----------
    parser: the parser of the `check` subcommand.
    """
    parser.add_argument('log', type=Path,
                        help='CARMEN log file (plain text or gzip), or a .g2o graph with '
                             'ROBOTLASER1 lines')
    parser.add_argument('--every', type=int, default=1, metavar='N',
                        help='test every N-th laser record only, for dense logs (indices in the '
                             'outputs stay record positions; default %(default)s)')
    options.add_sensor_arguments(parser)
    options.add_test_arguments(parser)
    options.add_verdict_arguments(parser)
    add_output_arguments(parser)


def add_output_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the output options (--report, --plot, --pairs-csv, --explain, --quiet) that
    `write_outputs` serves; replay takes them too.

    Parameters
    ----------
    parser: the parser to add them to, as the group 'output'.
    """
    group = parser.add_argument_group('output')
    group.add_argument('--report', type=Path, metavar='JSON',
                       help='write the verdict, figures, sensor model and parameters as JSON')
    group.add_argument('--plot', type=Path, metavar='PNG',
                       help='write the map with inconsistent scans and end points highlighted '
                            'and its misaligned regions numbered as printed; each region '
                            'zoomed in, as mapped and corrected, beside it as '
                            'STEM_region1.png, STEM_region2.png, ...')
    group.add_argument('--pairs-csv', type=Path, metavar='CSV',
                       help='write every overlapping pair: i, j, M_ij, n_ij, psi_ij, failed')
    group.add_argument('--explain', type=Path, metavar='PNG',
                       help='write the failed pairs behind the verdict, zoomed in: the three '
                            'strongest of region #1 (the region that fails the map), then the '
                            'three strongest others')
    group.add_argument('--quiet', action='store_true', help='no progress bar')


def load_scans(args: argparse.Namespace, parameters: ConsistencyParameters
               ) -> tuple[carmen.CarmenLog, np.ndarray, ScanSet]:
    """Read the log (or graph) and place the viewpoints among every `--every`-th scan.

    Parameters
    ----------
    args: parsed `check` options: log, every, max_range, range_min and fov.
    parameters: the test's parameters; their viewpoint_spacing and viewpoint_turn pick the
        viewpoints.

    Returns
    -------
    The laser records, the names (S,) of the S scans tested (record positions, or vertex ids
    of a graph), and those scans. Bad option values become InputError.
    """
    if args.every < 1:
        raise InputError('options', f'--every must be at least 1, got {args.every}')
    options.check_sensor_options(args)
    if args.log.is_dir():
        raise InputError(str(args.log), 'is a folder; check takes one log or .g2o graph '
                                        '(batch takes folders)')
    log, ranges, poses, names = read_laser_records(args.log)
    selected = np.arange(0, len(ranges), args.every)
    every = place_scans(args, log, ranges[selected], poses[selected], str(args.log))
    rows = select_viewpoints(every, parameters)
    return log, names[selected[rows]], every.take(rows)


def read_laser_records(path: Path) -> tuple[carmen.CarmenLog, np.ndarray, np.ndarray,
                                            np.ndarray]:
    """The laser records of a CARMEN log, or of a g2o graph with ROBOTLASER1 lines.

    Parameters
    ----------
    path: the log or graph (`is_graph`).

    Returns
    -------
    (the laser records, their ranges (N, K), laser poses (N, 3), names (N,): record positions,
    or vertex ids of a graph). InputError for an input that cannot be read, or a graph without
    exactly one scan per vertex.
    """
    if is_graph(path):
        # the graph reader brings scipy.sparse (the pose graph): only graphs pay for it
        from map_consistency_ros.io.g2o import read_g2o
        content = read_g2o(path)
        return (content.laser, content.scan_ranges(),
                se2.compose(content.graph.poses, content.laser_offset), content.vertex_ids)
    log = carmen.read_carmen_log(path)
    return log, log.ranges, log.laser_poses, np.arange(log.scan_count)


def place_scans(args: argparse.Namespace, log: carmen.CarmenLog, ranges: np.ndarray,
                poses: np.ndarray, source: str) -> ScanSet:
    """Scans placed at laser poses, with the sensor model of the log and the options.

    Parameters
    ----------
    args: parsed sensor options (options.add_sensor_arguments).
    log: the laser records (their beam count and stated range).
    ranges: (N, K) ranges.
    poses: (N, 3) laser poses.
    source: the input, named by a bad value's error.

    Returns
    -------
    The ScanSet; InputError naming `source` for a model or scans that cannot be made.
    """
    try:
        model = carmen.sensor_model(log, fov=options.fov_radians(args),
                                    max_range=args.max_range, range_min=args.range_min)
        return ScanSet.from_ranges(ranges, poses, model)
    except ValueError as error:
        raise InputError(source, str(error)) from None


def is_graph(path: Path) -> bool:
    """Whether `check` reads `path` as a g2o graph rather than a CARMEN log.

    Parameters
    ----------
    path: the input file.

    Returns
    -------
    True for the suffix .g2o (in any case).
    """
    return Path(path).suffix.lower() == '.g2o'


def write_outputs(args: argparse.Namespace, scans: ScanSet, assessment: Assessment,
                  details: dict, scan_ids: np.ndarray | None = None,
                  outputs: StagedOutputs | None = None) -> list[Path]:
    """Write the report, figures and pairs CSV the user asked for, all of them or none.

    Parameters
    ----------
    args: parsed options with report, plot, pairs_csv and explain: paths, None for an
        output not asked for.
    scans: the S scans judged, at the poses judged.
    assessment: both stages' verdict on `scans`.
    details: the report's fields beside the verdict; its 'source' (its file name) titles the
        map figure.
    scan_ids: (S,) names of the scans in every output; None: their indices.
    outputs: the caller's staged outputs, for outputs of its own to appear with these; None:
        these appear together when all are written, and none of them when one fails
        (io/staging.py).

    Returns
    -------
    The zoomed figures of the misaligned regions written beside --plot (none without it).
    """
    if outputs is None:
        with StagedOutputs() as outputs:
            return write_outputs(args, scans, assessment, details, scan_ids, outputs)
    if args.plot or args.explain:
        # matplotlib costs half a second of start-up: only the runs that draw pay it.
        from map_consistency_ros.cli import plots
    if args.report:
        write = report.assessment_report(assessment, scan_ids)
        write.update(details)
        report.write_json(outputs.path(args.report), write)
    regions = []
    if args.plot:
        plots.save_map_figure(outputs.path(args.plot), scans, assessment,
                              title=plots.title_name(details.get('source', '')))
        regions = plots.save_region_figures(args.plot, scans, assessment, scan_ids,
                                            place=outputs.path)
    if args.pairs_csv:
        report.write_pairs_csv(outputs.path(args.pairs_csv), assessment.result, scan_ids)
    if args.explain:
        plots.save_pairs_figure(outputs.path(args.explain), scans, assessment, scan_ids)
    return regions


def verdict_settings(args: argparse.Namespace):
    """The paper's parameters and the explanation settings of the parsed options.

    Parameters
    ----------
    args: parsed options with the test and verdict options (`options.add_test_arguments`,
        `options.add_verdict_arguments`); those not given keep their defaults.

    Returns
    -------
    (ConsistencyParameters, ExplanationSettings); bad values become InputError.
    """
    try:
        config = options.configuration(args, ('consistency', 'explanation'))
    except ValueError as error:
        raise InputError('options', str(error)) from None
    return config.consistency, config.explanation


@dataclass(frozen=True)
class Judgement:
    """Both stages' verdict on one map, with what the outputs are written from."""

    assessment: Assessment
    scans: ScanSet
    scan_ids: np.ndarray  # names of the scans in every output
    details: dict  # the report's fields beside the verdict
    seconds: float  # the test and its explanation, without reading the input

    @property
    def consistent(self) -> bool:
        """Whether both stages find the map consistent."""
        return self.assessment.consistent


def judge(args: argparse.Namespace) -> Judgement:
    """Read the input named by parsed `check` options and judge its map (the one code path
    of `check` and of `batch` for logs and graphs).

    Parameters
    ----------
    args: parsed `check` options (--quiet: no progress bar).

    Returns
    -------
    The Judgement: both stages' verdict, the scans and their names, the report's details and
    the seconds the test took. InputError for a bad input or option value.
    """
    parameters, explanation = verdict_settings(args)
    log, selected, scans = load_scans(args, parameters)
    started = time.perf_counter()
    with ProgressBar('checking pairs', enabled=not args.quiet) as progress:
        # Without a bar the pairs go to the kernel in one piece, not in chunks.
        assessment = check_map(scans, parameters, explanation,
                               progress=None if args.quiet else progress)
    elapsed = time.perf_counter() - started
    model = scans.model
    details = {
        'source': str(args.log),
        'sensor_model': {
            'angle_min': model.angle_min, 'angle_increment': model.angle_increment,
            'max_range': model.max_range, 'range_min': model.range_min,
            'beams': log.beam_count, 'stated_sensor_max_range': carmen.stated_max_range(log),
        },
        'runtime_seconds': elapsed,
        'every': args.every,
        'laser_records': log.scan_count,
    }
    return Judgement(assessment, scans, selected, details, elapsed)


def run(args: argparse.Namespace) -> int:
    """Judge the input, print the summary and write the outputs asked for.

    Parameters
    ----------
    args: parsed `check` options.

    Returns
    -------
    The exit code of the verdict (cli/exit_codes.py): 0 consistent, 1 inconsistent, 4 nothing
    to judge. Bad input raises InputError, which `main` turns into exit code 2.
    """
    judgement = judge(args)
    print(report.format_summary(judgement.assessment, str(args.log), judgement.scan_ids))
    print(f'  viewpoints            {judgement.scan_ids.size} of '
          f'{judgement.details["laser_records"]} laser records')
    print(f'  test time             {judgement.seconds:.2f} s')
    regions = write_outputs(args, judgement.scans, judgement.assessment, judgement.details,
                            judgement.scan_ids)
    print_outputs([('report', args.report), ('figure', args.plot),
                   ('pairs', args.pairs_csv), ('failed pairs figure', args.explain)], regions)
    return exit_codes.of_outcome(judgement.assessment.outcome)


def print_outputs(outputs: list[tuple[str, Path | None]], regions: list[Path]) -> None:
    """Print the files written, one per line: the outputs asked for, then the zoomed figure
    of each region.

    Parameters
    ----------
    outputs: (label, path) of each output; a path None was not asked for.
    regions: the region figures written, region #1 first.
    """
    for label, path in outputs:
        if path:
            print(f'  {label:<21} {path}')
    for number, path in enumerate(regions, 1):
        print(f'  {f"region #{number} figure":<21} {path}')
