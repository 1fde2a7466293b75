"""Judge many maps at once: CARMEN logs, g2o graphs with scans and bags, into one table.

Every input is judged exactly as `check` (logs, graphs) or `replay` (bags) would judge it, with
the same defaults; the options given here apply to every input that takes them. Inputs are
files, folders (searched recursively: *.log, *.log.gz, *.clf, *.gfs, *.g2o, *.bag, *.mcap, and
rosbag2 folders, which hold a metadata.yaml) or glob patterns (quote them: 'runs/**/*.bag').

The table (printed; --csv, --json) has one row per input: input, kind, verdict, summary line,
the misaligned regions with their sizes, the number of changed places, the runtime (reading
and judging, in the worker) and the error of an input that could not be judged. Inputs are
judged on a local process pool (--workers) or on a Dask distributed cluster (--scheduler);
see docs/batch.md. --html DIR writes an index page: the counts by verdict, the table sorted by
a click on a header and filtered by text and verdict, and a thumbnail of each map's first
misaligned region linking to the map's figure and JSON report.

Exit code: the worst over the inputs: 3 when a job failed unexpectedly (a bug, or a worker
that died), else 2 when an input is bad, else 1 when a map is inconsistent, else 0. Inputs
that fail are listed; the others are still judged.

examples:
  map-consistency batch data/*.log.gz runs/ --csv out/batch.csv --json out/batch.json
  map-consistency batch 'nightly/**/*.bag' --params-file config/map_consistency.yaml \\
      --html out/nightly
  map-consistency batch logs/ --scheduler tcp://10.0.0.5:8786
"""
from __future__ import annotations

import argparse
import csv
import datetime
import glob
import html
import io
import math
import re
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from map_consistency_ros import pool
from map_consistency_ros.cli import check, exit_codes, options, replay, report
from map_consistency_ros.cli.exit_codes import (EXIT_BAD_INPUT, EXIT_CONSISTENT,
                                                EXIT_INCONSISTENT, EXIT_INTERNAL_ERROR,
                                                EXIT_NOTHING_TO_JUDGE)
from map_consistency_ros.cli.progress import ProgressBar
from map_consistency_ros.core.consistency import ConsistencyParameters
from map_consistency_ros.core.live import FeedSettings, MonitorSettings
from map_consistency_ros.core.parameters import specs
from map_consistency_ros.core.verdict import ExplanationSettings
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.parameter_file import read_parameter_file
from map_consistency_ros.io.staging import StagedOutputs, staged

# EXIT_INTERNAL_ERROR: a job raised unexpectedly or its worker died: a bug, not the input
VERDICTS = exit_codes.NAMES
COLUMNS = ('input', 'kind', 'verdict', 'exit_code', 'scans', 'summary_line', 'regions',
           'changed_places', 'runtime_seconds', 'error')

# Kinds of input and the file names a folder search picks up; a file named explicitly with
# another suffix is read as a CARMEN log, as `check` would.
CARMEN, GRAPH, ROS1_BAG, ROS2_BAG = 'carmen log', 'g2o graph', 'ros1 bag', 'ros2 bag'
_SUFFIXES = {'.log': CARMEN, '.log.gz': CARMEN, '.clf': CARMEN, '.clf.gz': CARMEN,
             '.gfs': CARMEN, '.g2o': GRAPH, '.bag': ROS1_BAG, '.mcap': ROS2_BAG}
_ROS2_METADATA = 'metadata.yaml'
THUMBNAIL_HEIGHT = 120  # pixels: several rows of the HTML page fit on a screen
_THUMBNAIL_MARGIN = 2.0  # metres around a region's scans: its surroundings show what it is

# options of `batch` itself: never passed on to check / replay
_OWN = ('inputs', 'workers', 'scheduler', 'csv', 'json', 'html', 'quiet', 'params_file',
        'command', 'run')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `batch`: the inputs, how to run them, the outputs, and the options
    of `check` and `replay` that apply to every input taking them.

    Parameters
    ----------
    parser: the parser of the `batch` subcommand.
    """
    parser.add_argument('inputs', nargs='+', metavar='INPUT',
                        help='CARMEN logs, g2o graphs with ROBOTLASER1 lines, ROS 1 .bag files, '
                             'rosbag2 folders; or folders / glob patterns holding them')
    parser.add_argument('--params-file', type=Path, metavar='YAML',
                        help="the node's ROS 2 parameter file (config/map_consistency.yaml): all "
                             'of it for bags, its test, verdict and max_range values for logs '
                             'and graphs; options given here override it')
    run = parser.add_argument_group('running')
    run.add_argument('--workers', type=int, default=None, metavar='N',
                     help='local worker processes (default: one per core; 1: in this process; '
                          'not used with --scheduler)')
    run.add_argument('--scheduler', metavar='ADDRESS',
                     help='run on the Dask distributed cluster of this scheduler '
                          '(tcp://host:8786); needs the [distributed] extra, and workers that '
                          'can import this package and read the inputs at the paths given')
    output = parser.add_argument_group('output')
    output.add_argument('--csv', type=Path, metavar='CSV', help='write the table as CSV')
    output.add_argument('--json', type=Path, metavar='JSON', help='write the table as JSON')
    output.add_argument('--html', type=Path, metavar='DIR',
                        help='write DIR/index.html: counts by verdict, a row per input that '
                             'sorts and filters, a thumbnail per map linking to its figure and '
                             'JSON report (and the table as CSV and JSON)')
    output.add_argument('--quiet', action='store_true', help='no progress bar')
    parser.add_argument('--every', type=int, default=1, metavar='N',
                        help='logs and graphs: test every N-th laser record only (default '
                             '%(default)s)')
    options.add_sensor_arguments(parser)
    replay.add_topic_arguments(parser)
    options.add_parameter_arguments(parser, FeedSettings, 'bags: poses and sensor (as replay)',
                                    skip=('pose_source', 'max_range'))
    options.add_parameter_arguments(parser, MonitorSettings, 'bags: monitor (as replay)')
    options.add_test_arguments(parser)
    options.add_verdict_arguments(parser)


# -- inputs ---------------------------------------------------------------------------------

def _kind_of_file(path: Path) -> str | None:
    name = path.name.lower()
    for suffix, kind in _SUFFIXES.items():
        if name.endswith(suffix):
            return kind
    return None


def _in_folder(folder: Path) -> list[tuple[str, str]]:
    if (folder / _ROS2_METADATA).is_file():
        return [(str(folder), ROS2_BAG)]
    found = []
    for entry in sorted(folder.iterdir()):
        if entry.is_dir():
            found.extend(_in_folder(entry))
        elif _kind_of_file(entry) is not None:
            found.append((str(entry), _kind_of_file(entry)))
    return found


def find_inputs(arguments: list[str]) -> list[tuple[str, str]]:
    """Every input named by files, folders and glob patterns, each once.

    Parameters
    ----------
    arguments: the INPUT arguments as given: files (read as CARMEN logs unless their suffix
        names another kind), folders (searched recursively) and glob patterns.

    Returns
    -------
    (path, kind) per input, in the order given (folders and patterns sorted); kind is
    CARMEN, GRAPH, ROS1_BAG or ROS2_BAG. A name that matches nothing is kept with kind None:
    it is listed as a bad input.
    """
    found: list[tuple[str, str | None]] = []
    for argument in arguments:
        path = Path(argument)
        if path.is_dir():
            found.extend(_in_folder(path))
        elif path.exists():
            found.append((argument, _kind_of_file(path) or CARMEN))
        else:
            matches = sorted(glob.glob(argument, recursive=True))
            if not matches:
                found.append((argument, None))
            for match in matches:
                match_path = Path(match)
                if match_path.is_dir():
                    found.extend(_in_folder(match_path))
                else:
                    found.append((match, _kind_of_file(match_path) or CARMEN))
    unique, seen = [], set()
    for path, kind in found:
        key = str(Path(path).resolve())
        if key not in seen:
            seen.add(key)
            unique.append((path, kind))
    return unique


# -- one input ------------------------------------------------------------------------------

def judge_input(item: tuple[str, str | None], given: dict, file_values: dict,
                figures: bool) -> dict:
    """One row of the table: one input judged through `check` or `replay`. Runs in a worker:
    every exception becomes the row's error.

    Parameters
    ----------
    item: (path, kind) of `find_inputs`; kind None for a name that matched nothing.
    given: the options given on the command line that check / replay take (`_given`); they
        override `file_values`.
    file_values: the parameter file's values ({} without --params-file); logs and graphs
        take only those that mean the same for `check`.
    figures: the row also carries the map figure, its thumbnail and the JSON report as bytes
        under 'files' (the workers need not share a file system with the caller).

    Returns
    -------
    The row: a value per name of COLUMNS, exit_code and verdict being those `check` /
    `replay` would give (EXIT_INTERNAL_ERROR for an unexpected exception), and with
    `figures` the 'files' of a judged input.
    """
    path, kind = item
    row = {'input': path, 'kind': kind or 'missing', 'scans': None, 'summary_line': '',
           'regions': [], 'changed_places': None, 'error': None}
    started = time.perf_counter()
    try:
        if kind is None:
            raise InputError(path, 'no such file, folder or matching pattern')
        if kind in (ROS1_BAG, ROS2_BAG):
            args = _namespace('replay', path, given)
            values = replay.parameter_values(args, file_values)
            judgement = replay.judge(args, values)
            scan_ids = judgement.scan_ids
        else:
            args = _namespace('check', path, given, _check_file_values(file_values))
            judgement = check.judge(args)
            scan_ids = judgement.scan_ids
        row['runtime_seconds'] = _seconds(started)
        _describe(row, judgement.assessment, scan_ids)
        code = exit_codes.of_outcome(judgement.assessment.outcome)
        if figures:
            row['files'] = _files(args, judgement, scan_ids)
    except (InputError, OSError) as error:  # what `check` / `replay` exit 2 on
        code = EXIT_BAD_INPUT
        row['error'] = str(error) if isinstance(error, InputError) else \
            f'{error.filename or path}: {error.strerror or error}'
    except Exception as error:  # noqa: BLE001 (a bug must not stop the other inputs)
        code = EXIT_INTERNAL_ERROR
        frame = traceback.extract_tb(error.__traceback__)[-1]
        row['error'] = (f'internal error: {type(error).__name__}: {error} '
                        f'({Path(frame.filename).name}:{frame.lineno})')
    row.setdefault('runtime_seconds', _seconds(started))
    row.update(verdict=VERDICTS[code], exit_code=code)
    return row


def _seconds(started: float) -> float:
    """Seconds since `started`, to the millisecond: finer digits are timer noise, not a
    measure of the input."""
    return round(time.perf_counter() - started, 3)


def _namespace(command: str, path: str, given: dict, base: dict | None = None
               ) -> argparse.Namespace:
    """The options `command` would have parsed for `path`: its own defaults, then `base`, then
    the options given to batch that `command` takes."""
    parser = argparse.ArgumentParser(prog=f'map-consistency {command}')
    module = check if command == 'check' else replay
    module.add_arguments(parser)
    args = parser.parse_args([path, '--quiet'])
    takes = {action.dest for action in parser._actions}  # noqa: SLF001 (argparse has no API)
    for name, value in {**(base or {}), **given}.items():
        if name in takes and name not in _OWN:
            setattr(args, name, value)
    if command == 'replay':
        args.bags = [Path(path)]
    else:
        args.log = Path(path)
    return args


def _check_file_values(file_values: dict) -> dict:
    """The parameter file's values that mean the same for `check`: the test, the verdict and
    the usable range."""
    names = {spec.name for group in (ConsistencyParameters, ExplanationSettings)
             for spec in specs(group)} | {'max_range'}
    return {name: value for name, value in file_values.items() if name in names}


def _describe(row: dict, assessment, scan_ids: np.ndarray | None) -> None:
    result = assessment.result
    ids = report.scan_names(result, scan_ids)
    row['scans'] = int(result.scan_count)
    row['summary_line'] = assessment.summary_line()
    row['regions'] = [{
        'number': number,  # as `check` prints it and its report and figures name it
        'scans': _span(ids[region.scans]),
        'reference_scans': _span(ids[region.reference_scans]),
        'displacement_m': _number(region.displacement) if region.registered else None,
        'registered': bool(region.registered),
        'text': f'#{number} {report.region_text(region, ids)}',
    } for number, region in enumerate(assessment.misalignments, 1)]
    row['changed_places'] = len(assessment.changes)


def _span(ids: np.ndarray) -> list[int]:
    """[first, last, count] of a set of scan names."""
    return [int(ids.min()), int(ids.max()), int(ids.size)] if ids.size else [0, 0, 0]


def _number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _files(args: argparse.Namespace, judgement, scan_ids) -> dict[str, bytes]:
    """The map figure and the JSON report that `check` / `replay` would write with --plot and
    --report, and a thumbnail of the map's worst place (`_thumbnail`)."""
    with tempfile.TemporaryDirectory(prefix='map-consistency-batch-') as folder:
        folder = Path(folder)
        args.report, args.plot = folder / 'report.json', folder / 'map.png'
        args.pairs_csv = args.explain = None
        check.write_outputs(args, judgement.scans, judgement.assessment, judgement.details,
                            scan_ids)
        return {'figure': args.plot.read_bytes(),
                'thumbnail': _thumbnail(judgement.scans, judgement.assessment),
                'report': args.report.read_bytes()}


def _thumbnail(scans, assessment) -> bytes:
    """A PNG THUMBNAIL_HEIGHT pixels high of the map around its first misaligned region (the
    region's scans' end points and positions, with a margin), or of the whole map when it has
    none: a reader of the page sees the place to look at before opening the figure."""
    from PIL import Image  # matplotlib's own dependency

    from map_consistency_ros.cli import plots
    figure, ax = plots.plt.subplots(figsize=(3.0, 3.0))
    try:
        plots.plot_map(ax, scans, assessment)
        legend = ax.get_legend()
        if legend is not None:
            legend.remove()
        ax.set_title('')
        ax.set_axis_off()
        box = _region_box(scans, assessment)
        if box is not None:
            ax.set_xlim(box[0], box[2])
            ax.set_ylim(box[1], box[3])
        buffer = io.BytesIO()
        figure.savefig(buffer, format='png', dpi=100, bbox_inches='tight', pad_inches=0.02)
    finally:
        plots.plt.close(figure)
    thumbnail = io.BytesIO()
    with Image.open(buffer) as picture:
        width = max(1, round(picture.width * THUMBNAIL_HEIGHT / picture.height))
        picture.resize((width, THUMBNAIL_HEIGHT), Image.LANCZOS).save(thumbnail, format='PNG')
    return thumbnail.getvalue()


def _region_box(scans, assessment) -> tuple[float, float, float, float] | None:
    """(xmin, ymin, xmax, ymax) of the first misaligned region's scans with a margin of a
    tenth of its size, at least _THUMBNAIL_MARGIN; None without a region."""
    if not assessment.misalignments:
        return None
    rows = np.asarray(assessment.misalignments[0].scans)
    points = np.concatenate([scans.endpoints[rows][scans.valid[rows]],
                             scans.sensor_poses[rows, :2]])
    low, high = points.min(axis=0), points.max(axis=0)
    margin = max(_THUMBNAIL_MARGIN, 0.1 * float((high - low).max()))
    return low[0] - margin, low[1] - margin, high[0] + margin, high[1] + margin


# -- the batch ------------------------------------------------------------------------------

def _given(args: argparse.Namespace) -> dict:
    """The options given on the command line that check / replay take (the test and verdict
    options are only in the namespace when given; the others carry check's defaults)."""
    values = {name: value for name, value in vars(args).items() if name not in _OWN}
    if values.get('max_range') is None:
        values.pop('max_range', None)  # each command's own default
    return values


def run(args: argparse.Namespace) -> int:
    """Judge every input, print the table, and write --csv, --json and --html when asked.

    Parameters
    ----------
    args: the parsed `batch` options.

    Returns
    -------
    The exit code, the worst over the inputs (exit_codes.RANK): EXIT_INTERNAL_ERROR (3) when
    a job failed unexpectedly, else EXIT_BAD_INPUT (2) when an input is bad, else
    EXIT_INCONSISTENT (1) when a map is inconsistent, else EXIT_NOTHING_TO_JUDGE (4) when a map
    could not be judged, else EXIT_CONSISTENT (0). InputError (exit 2 through `main`)
    for a bad --workers or parameter file, or when the inputs hold no log, graph or bag.
    """
    if args.workers is not None and args.workers < 1:
        raise InputError('options', f'--workers must be at least 1, got {args.workers}')
    options.check_sensor_options(args)
    file_values = {}
    if args.params_file is not None:
        file_values = read_parameter_file(args.params_file)
        for warning in replay.parameter_file_warnings(file_values):
            print(f'map-consistency batch: {args.params_file}: {warning}', file=sys.stderr)
    items = find_inputs(args.inputs)
    if not items:  # empty folders: a pipeline must not pass on no maps at all
        raise InputError(' '.join(args.inputs), 'no logs, graphs or bags found')
    figures = args.html is not None
    started = time.perf_counter()
    with ProgressBar('judging maps', enabled=not args.quiet) as progress:
        results = pool.run_all(judge_input, items, (_given(args), file_values, figures),
                               workers=args.workers, scheduler=args.scheduler,
                               progress=progress)
    rows = [_died(item, result) if isinstance(result, pool.WorkerDied) else result
            for item, result in zip(items, results)]
    files = [row.pop('files', None) for row in rows]
    elapsed = time.perf_counter() - started
    print(format_table(rows))
    inputs, found = count_text(rows).split(': ', 1)
    print(f'{inputs} in {elapsed:.1f} s: {found}')
    for path, writer in ((args.csv, write_csv), (args.json, write_table_json)):
        if path is not None:
            writer(path, rows)
            print(f'  {path}')
    if figures:
        index = write_html(args.html, rows, files, _parameters_used(args, file_values))
        print(f'  {index}')
    return exit_codes.worst(row['exit_code'] for row in rows)


def _parameters_used(args: argparse.Namespace, file_values: dict) -> dict:
    """The values the inputs were judged with beside their commands' defaults: the parameter
    file's, then the options given on the command line (batch's own left out)."""
    values = {name: value for name, value in file_values.items()}
    defaults = vars(build_defaults())
    for name, value in _given(args).items():
        if name != 'debug' and (name not in defaults or defaults[name] != value):
            values[name] = value
    if args.params_file is not None:
        values['params_file'] = str(args.params_file)
    return values


def build_defaults() -> argparse.Namespace:
    """batch's options as parsed from no option at all.

    Returns
    -------
    The namespace of `batch INPUT` (its defaults; the parameter options are absent).
    """
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(['input'])


def _died(item: tuple[str, str | None], died: pool.WorkerDied) -> dict:
    path, kind = item
    return {'input': path, 'kind': kind or 'missing', 'verdict': VERDICTS[EXIT_INTERNAL_ERROR],
            'exit_code': EXIT_INTERNAL_ERROR, 'scans': None, 'summary_line': '', 'regions': [],
            'changed_places': None, 'runtime_seconds': None,
            'error': f'internal error: {died.message}'}


# -- outputs --------------------------------------------------------------------------------

def _regions_text(row: dict) -> str:
    return '; '.join(region['text'] for region in row['regions'])


def format_table(rows: list[dict]) -> str:
    """The table for the terminal: verdict, runtime and input, then the summary or error.

    Parameters
    ----------
    rows: the rows of `judge_input`.

    Returns
    -------
    The text: a line per row, and below it an indented line with its error or summary line
    when it has one.
    """
    lines = []
    for row in rows:
        runtime = row['runtime_seconds']
        seconds = '' if runtime is None else f'{runtime:7.1f} s'
        lines.append(f'{row["verdict"]:<15} {seconds:>9}  {row["input"]}')
        detail = row['error'] or row['summary_line']
        if detail:
            lines.append(f'{"":<27}{detail}')
    return '\n'.join(lines)


def write_csv(path: Path, rows: list[dict]) -> None:
    """Write the table as CSV, the regions as one text cell ('; ' between regions).

    Parameters
    ----------
    path: the CSV file; its folder is created. Written whole or not at all (io/staging.py).
    rows: the rows of `judge_input`, one CSV row each, columns COLUMNS (None as '').
    """
    with staged(path) as target, open(target, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow(['' if row[name] is None else
                             _regions_text(row) if name == 'regions' else row[name]
                             for name in COLUMNS])


def write_table_json(path: Path, rows: list[dict]) -> None:
    """Write the table as JSON: {'maps': [row, ...]} with the columns of COLUMNS.

    Parameters
    ----------
    path: the JSON file; its folder is created.
    rows: the rows of `judge_input`.
    """
    report.write_json(path, {'maps': [{name: row[name] for name in COLUMNS} for row in rows]})


def _slug(index: int, path: str) -> str:
    name = re.sub(r'[^A-Za-z0-9._-]+', '_', Path(path.rstrip('/')).name) or 'input'
    return f'{index:03d}_{name}'


# the verdicts in the order a reader takes them in: the maps judged, then the inputs that were not
SHOWN_ORDER = (EXIT_CONSISTENT, EXIT_INCONSISTENT, EXIT_NOTHING_TO_JUDGE, EXIT_BAD_INPUT,
               EXIT_INTERNAL_ERROR)
_JUDGED = (EXIT_CONSISTENT, EXIT_INCONSISTENT, EXIT_NOTHING_TO_JUDGE)


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """A count and its noun, in the plural unless the count is one.

    Parameters
    ----------
    count: how many.
    noun: the singular ('input', 'bad input').
    nouns: the plural; None: the singular and an 's'.

    Returns
    -------
    E.g. '1 input', '8 inputs', '2 maps judged'.
    """
    return f'{count} {noun if count == 1 else nouns or noun + "s"}'


def verdict_counts(rows: list[dict]) -> dict[int, int]:
    """How many rows have each exit code.

    Parameters
    ----------
    rows: the rows of `judge_input`.

    Returns
    -------
    exit code -> count, for every code of SHOWN_ORDER in that order (zeros included).
    """
    return {code: sum(row['exit_code'] == code for row in rows) for code in SHOWN_ORDER}


def count_text(rows: list[dict]) -> str:
    """What the batch found, maps apart from inputs that could not be judged: the line printed
    after the table and the title of the HTML page.

    Parameters
    ----------
    rows: the rows of `judge_input`.

    Returns
    -------
    E.g. '8 inputs: 6 maps judged (4 consistent, 1 inconsistent, 1 nothing to judge),
    2 bad inputs'; verdicts counting none are left out, the maps judged never.
    """
    counts = verdict_counts(rows)
    judged = sum(counts[code] for code in _JUDGED)
    verdicts = ', '.join(f'{counts[code]} {VERDICTS[code]}' for code in _JUDGED if counts[code])
    parts = [plural(judged, 'map judged', 'maps judged') + (f' ({verdicts})' if verdicts else '')]
    parts += [plural(counts[code], VERDICTS[code])
              for code in (EXIT_BAD_INPUT, EXIT_INTERNAL_ERROR) if counts[code]]
    return f'{plural(len(rows), "input")}: ' + ', '.join(parts)


def write_html(folder: Path, rows: list[dict], files: list[dict | None],
               parameters: dict | None = None) -> Path:
    """Write DIR/index.html, DIR/maps/* (figure, thumbnail, report per map) and
    DIR/batch.csv/.json.

    The page holds the counts by verdict, the parameters, the package version and the date,
    and the table: a row per input with a thumbnail of its map's worst place, sorted by a
    click on a column's header and filtered by a text box and a box per verdict. Its small
    inline script needs no network and no other file; the page's address fragment holds the
    view (#sort=runtime_seconds, #sort=-scans, &filter=TEXT, &hide=bad-input,consistent), so a
    link shows the same view.

    Parameters
    ----------
    folder: DIR; created if missing.
    rows: the rows of `judge_input`, without their 'files'.
    files: per row, the 'files' it carried (figure, thumbnail and report as bytes); None for
        an input that was not judged: its row has no picture and no links.
    parameters: the options and parameter file values the inputs were judged with, by name;
        None: none given (every input at its command's defaults).

    Returns
    -------
    The path of DIR/index.html. Every file appears, or none does (io/staging.py).
    """
    with StagedOutputs() as outputs:
        return _write_html(folder, rows, files, parameters or {}, outputs)


# (column id, header): the id names the column in the page's address (#sort=ID)
_HTML_COLUMNS = (('input', 'input'), ('kind', 'kind'), ('verdict', 'verdict'),
                 ('scans', 'scans'), ('summary_line', 'summary'),
                 ('regions', 'misaligned regions'), ('changed_places', 'changed places'),
                 ('runtime_seconds', 'runtime'), ('map', 'map'), ('files', 'files'))
_UNSORTED = ('map', 'files')


def _cell(column: str, content: str, value=None) -> str:
    attribute = '' if value is None else f' data-value="{html.escape(str(value))}"'
    return f'<td data-column="{column}"{attribute}>{content}</td>'


def _slug_of_verdict(verdict: str) -> str:
    return verdict.replace(' ', '-')


def _write_html(folder: Path, rows: list[dict], files: list[dict | None], parameters: dict,
                outputs: StagedOutputs) -> Path:
    from map_consistency_ros.cli.main import package_version
    maps = folder / 'maps'
    write_csv(outputs.path(folder / 'batch.csv'), rows)
    write_table_json(outputs.path(folder / 'batch.json'), rows)
    body = []
    for index, (row, content) in enumerate(zip(rows, files)):
        slug = _slug(index, row['input'])
        if content:
            for suffix, key in (('.png', 'figure'), ('.thumb.png', 'thumbnail'),
                                ('.json', 'report')):
                outputs.path(maps / f'{slug}{suffix}').write_bytes(content[key])
            picture = (f'<a href="maps/{slug}.png"><img src="maps/{slug}.thumb.png" '
                       f'height="{THUMBNAIL_HEIGHT}" '
                       f'alt="map of {html.escape(row["input"])}"></a>')
            links = f'<a href="maps/{slug}.png">figure</a> <a href="maps/{slug}.json">JSON</a>'
        else:
            picture, links = '', ''
        regions = '<br>'.join(html.escape(region['text']) for region in row['regions'])
        runtime, verdict = row['runtime_seconds'], row['verdict']
        worst = max((region['displacement_m'] or math.inf for region in row['regions']),
                    default=0.0)
        cells = [_cell('input', html.escape(row['input']), row['input']),
                 _cell('kind', html.escape(row['kind']), row['kind']),
                 _cell('verdict', f'<span class="{_slug_of_verdict(verdict)}">{verdict}</span>',
                       SHOWN_ORDER.index(row['exit_code'])),
                 _cell('scans', '' if row['scans'] is None else str(row['scans']),
                       '' if row['scans'] is None else row['scans']),
                 _cell('summary_line', html.escape(row['error'] or row['summary_line']),
                       row['error'] or row['summary_line']),
                 _cell('regions', regions or '-', worst if math.isfinite(worst) else 1e300),
                 _cell('changed_places', '' if row['changed_places'] is None else
                       str(row['changed_places']),
                       '' if row['changed_places'] is None else row['changed_places']),
                 _cell('runtime_seconds', '' if runtime is None else f'{runtime:.1f} s',
                       '' if runtime is None else runtime),
                 _cell('map', picture), _cell('files', links)]
        body.append(f'<tr data-index="{index}" data-verdict="{_slug_of_verdict(verdict)}">'
                    + ''.join(cells) + '</tr>')
    header = ''.join(
        f'<th data-column="{column}">{name}</th>' if column in _UNSORTED else
        f'<th data-column="{column}" class="sortable" title="sort by {name}">{name}</th>'
        for column, name in _HTML_COLUMNS)
    counts = verdict_counts(rows)
    count_items = ''.join(
        f'<li><b id="count-{_slug_of_verdict(VERDICTS[code])}">{counts[code]}</b> '
        f'<span class="{_slug_of_verdict(VERDICTS[code])}">{VERDICTS[code]}</span></li>'
        for code in SHOWN_ORDER)
    boxes = ''.join(
        f'<label><input type="checkbox" name="verdict" '
        f'value="{_slug_of_verdict(VERDICTS[code])}" checked> {VERDICTS[code]}</label> '
        for code in SHOWN_ORDER)
    given = ''.join(f'<tr><td>{html.escape(name)}</td><td>{html.escape(_value_text(value))}'
                    f'</td></tr>' for name, value in sorted(parameters.items()))
    settings = (f'<table class="parameters">{given}</table>' if given else
                '<p>none given: every input judged with its command\'s defaults</p>')
    made = datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    index = folder / 'index.html'
    outputs.path(index).write_text(_PAGE.format(
        title=html.escape(count_text(rows)), counts=count_items, boxes=boxes, header=header,
        body='\n'.join(body), parameters=settings, version=html.escape(package_version()),
        date=made, script=_SCRIPT))
    return index


def _value_text(value) -> str:
    if isinstance(value, (list, tuple)):
        return ' '.join(_value_text(item) for item in value)
    return str(value)


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>map consistency: {title}</title>
<style>
body {{ font-family: sans-serif; margin: 1em; }}
h1 {{ font-size: 140%; }}
table {{ border-collapse: collapse; }}
td, th {{ border: 1px solid #ccc; padding: 2px 6px; vertical-align: top; font-size: 85%; }}
td[data-column="summary_line"], td[data-column="regions"] {{ max-width: 26em; }}
td[data-column="map"] {{ padding: 0; }}
th.sortable {{ cursor: pointer; text-decoration: underline dotted; }}
th[aria-sort="ascending"]::after {{ content: " \\25B2"; }}
th[aria-sort="descending"]::after {{ content: " \\25BC"; }}
img {{ display: block; }}
ul.counts {{ list-style: none; padding: 0; display: flex; gap: 1.5em; font-size: 110%; }}
.consistent {{ color: #080; font-weight: bold; }}
.inconsistent {{ color: #c00; font-weight: bold; }}
.nothing-to-judge {{ color: #666; font-weight: bold; }}
.bad-input, .internal-error {{ color: #a60; font-weight: bold; }}
.controls {{ margin: 0.5em 0; }}
table.parameters td {{ font-family: monospace; }}
footer {{ margin-top: 1em; color: #555; font-size: 85%; }}
</style></head><body>
<h1>map consistency: {title}</h1>
<ul class="counts">{counts}</ul>
<p>Table as <a href="batch.csv">CSV</a> and <a href="batch.json">JSON</a>.
Click a column's header to sort by it (again: the other way).</p>
<div class="controls"><input type="search" id="filter" placeholder="filter rows by text"
 size="30"> {boxes}<span id="shown" style="margin-left: 1em"></span></div>
<table id="maps"><thead><tr>{header}</tr></thead><tbody>
{body}
</tbody></table>
<details><summary>parameters</summary>
<p>The options and parameter file values given; every other parameter at its default
(docs/node.md).</p>
{parameters}</details>
<footer>map_consistency_ros {version}, {date}</footer>
<script>
{script}
</script>
</body></html>
"""

# The view lives in the address fragment (sort, filter, hidden verdicts): a link or a
# reload shows the same rows, and a browser without a mouse (a test) can ask for a view.
_SCRIPT = """(function () {
  var table = document.getElementById('maps');
  var body = table.tBodies[0];
  var text = document.getElementById('filter');
  var boxes = Array.prototype.slice.call(document.querySelectorAll('input[name=verdict]'));
  var state = {sort: '', filter: '', hide: []};
  function read() {
    var params = new URLSearchParams(location.hash.slice(1));
    state.sort = params.get('sort') || '';
    state.filter = params.get('filter') || '';
    state.hide = (params.get('hide') || '').split(',').filter(Boolean);
    text.value = state.filter;
    boxes.forEach(function (box) { box.checked = state.hide.indexOf(box.value) < 0; });
  }
  function write() {
    var params = new URLSearchParams();
    if (state.sort) params.set('sort', state.sort);
    if (state.filter) params.set('filter', state.filter);
    if (state.hide.length) params.set('hide', state.hide.join(','));
    history.replaceState(null, '', '#' + params.toString());
    show();
  }
  function value(row, column) {
    var cell = row.querySelector('td[data-column="' + column + '"]');
    return cell ? cell.getAttribute('data-value') || '' : '';
  }
  function compare(first, second) {
    var a = parseFloat(first), b = parseFloat(second);
    if (!isNaN(a) && !isNaN(b)) return a - b;
    return first.localeCompare(second);
  }
  function show() {
    var rows = Array.prototype.slice.call(body.rows);
    var descending = state.sort.charAt(0) === '-';
    var column = descending ? state.sort.slice(1) : state.sort;
    rows.sort(function (first, second) {
      var order = 0;
      if (column) {
        var a = value(first, column), b = value(second, column);
        if (a === '' || b === '') order = (a === '') - (b === '');  // empty cells last
        else order = descending ? compare(b, a) : compare(a, b);
      }
      return order || first.getAttribute('data-index') - second.getAttribute('data-index');
    });
    var needle = state.filter.toLowerCase(), shown = 0;
    rows.forEach(function (row) {
      body.appendChild(row);
      row.hidden = state.hide.indexOf(row.getAttribute('data-verdict')) >= 0 ||
        (needle !== '' && row.textContent.toLowerCase().indexOf(needle) < 0);
      if (!row.hidden) shown += 1;
    });
    document.getElementById('shown').textContent = shown + ' of ' + rows.length + ' shown';
    Array.prototype.forEach.call(table.tHead.rows[0].cells, function (cell) {
      var own = cell.getAttribute('data-column') === column;
      if (own) cell.setAttribute('aria-sort', descending ? 'descending' : 'ascending');
      else cell.removeAttribute('aria-sort');
    });
  }
  Array.prototype.forEach.call(table.querySelectorAll('th.sortable'), function (cell) {
    cell.addEventListener('click', function () {
      var column = cell.getAttribute('data-column');
      state.sort = state.sort === column ? '-' + column : column;
      write();
    });
  });
  text.addEventListener('input', function () { state.filter = text.value; write(); });
  boxes.forEach(function (box) {
    box.addEventListener('change', function () {
      state.hide = boxes.filter(function (item) { return !item.checked; })
        .map(function (item) { return item.value; });
      write();
    });
  });
  window.addEventListener('hashchange', function () { read(); show(); });
  read();
  show();
})();"""
