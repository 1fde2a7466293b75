"""Compare the consistency test with the Hähnel et al. baseline on a labelled suite of real maps.

Builds the suite (corrected logs as consistent maps, rigidly broken copies as inconsistent ones,
reproducible from --seed), measures every map once in a process pool, sweeps the test's levels
(alpha, alpha', local alpha) and the baseline's threshold, and reports specificity / recall, the
Pareto frontiers (a figure like the paper's Fig. 3) and a runtime table like its Table I.

examples:
  map-consistency evaluate --data ../shared/data
  map-consistency evaluate --datasets intel orebro --part-size 100 --doc out/eval.md
  map-consistency evaluate --suite density --density-logs fr079 --densities 1 5 --cases map rot2

`--suite density` runs the density suite instead (docs/density.md): each map at several
densities and displaced copies of it, every case in its own process at default settings;
`--build-native` first rebuilds data/density/intel-native.log.gz from the raw Intel bag.
`--suite real-slam` judges the maps made by MRPT's SLAM in data/real_slam/ and scores the
verdicts against their labels (docs/real_slam.md).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from map_consistency_ros.cli import plots, report
from map_consistency_ros.cli.plots import save_figure
from map_consistency_ros.cli.progress import ProgressBar
from map_consistency_ros.core.consistency import (BaselineParameters, ConsistencyParameters,
                                                  check_consistency, map_statistic)
from map_consistency_ros.core.verdict import ExplanationSettings, explain
from map_consistency_ros.evaluation import density, metrics, real_slam, runner, whole_logs
from map_consistency_ros.evaluation.suite import (CORRECTED_LOGS, SuiteMap, SuiteParameters,
                                                  build_suite)
from map_consistency_ros.io.errors import InputError
from map_consistency_ros.io.staging import staged

# Table I of the paper (i7-3770K, 8 threads): N, R, K, seconds
PAPER_RUNTIMES = {
    'intel': (1311, 133.7, 180, 13.4),
    'fr079': (833, 118.4, 360, 29.5),
    'fr101': (504, 73.6, 360, 6.8),
    'belgioioso': (349, 29.7, 361, 5.3),
    'orebro': (237, 19.5, 181, 0.7),
}
ALPHAS = [0.1, 1e-2, 1e-3, 1e-4, 1e-6, 1e-9, 1e-12, 1e-16, 1e-24, 1e-32, 1e-50, 1e-80, 1e-120,
          1e-200]
BINOMIAL_ALPHAS = [0.1, 1e-2, 1e-4, 1e-6, 1e-9]
LOCAL_ALPHAS = [0.05, 0.2]
FLAG_WINDOWS = [0, 4]
QUANTILES = [0.0, 0.001, 0.01, 0.05, 0.1]
TWO_STAGE_ALPHAS = [0.1, 1e-2, 1e-4, 1e-6]
TOLERANCES = [0.03, 0.05, 0.1, 0.2, 0.4]
TARGET = 0.95  # the bar: recall and specificity both at least this


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `evaluate`: the suite, the sweep, the whole logs, the density suite
    and the outputs.

    Parameters
    ----------
    parser: the parser of the `evaluate` subcommand.
    """
    defaults = SuiteParameters()
    suite = parser.add_argument_group('suite')
    suite.add_argument('--suite', choices=('paper', 'density', 'real-slam'), default='paper',
                       help='the labelled suite of the paper (default), the density suite, or '
                            'the maps made by a real SLAM system (data/real_slam)')
    suite.add_argument('--data', type=Path, default=Path('../shared/data'),
                       help='folder of the real datasets (default %(default)s)')
    suite.add_argument('--datasets', nargs='+', choices=sorted(CORRECTED_LOGS),
                       default=list(CORRECTED_LOGS), help='corrected logs to use (default: all)')
    suite.add_argument('--seed', type=int, default=defaults.seed,
                       help='seed of the breaks (default %(default)s)')
    suite.add_argument('--part-size', type=int, default=defaults.part_size,
                       help='keyframes per map (default %(default)s)')
    sweep = parser.add_argument_group('sweep')
    sweep.add_argument('--alphas', type=float, nargs='+', default=ALPHAS,
                       help='pairwise test levels swept')
    sweep.add_argument('--binomial-alphas', type=float, nargs='+', default=BINOMIAL_ALPHAS,
                       help="cascaded test levels (alpha') swept")
    sweep.add_argument('--local-alphas', type=float, nargs='+', default=LOCAL_ALPHAS,
                       help='levels fitting the local scales swept')
    sweep.add_argument('--flag-windows', type=int, nargs='+', default=FLAG_WINDOWS,
                       help='flag filters swept: keep a flagged scan only if another lies within '
                            'this many indices (0: off; the original implementation offers 4)')
    sweep.add_argument('--quantiles', type=float, nargs='+', default=QUANTILES,
                       help="quantiles of the pairs' log-likelihoods taken as the baseline's map "
                            'statistic (0 = the worst pair)')
    sweep.add_argument('--cell-size', type=float, default=BaselineParameters().cell_size,
                       help="baseline's grid resolution in metres (default %(default)s)")
    sweep.add_argument('--two-stage-alphas', type=float, nargs='+', default=TWO_STAGE_ALPHAS,
                       help='pairwise test levels swept for the two-stage verdict')
    sweep.add_argument('--tolerances', type=float, nargs='+', default=TOLERANCES,
                       help='misalignment tolerances (m) swept for the two-stage verdict')
    whole = parser.add_argument_group('whole logs')
    whole.add_argument('--seams', type=int, default=2,
                       help='random seams per displacement size and log (default %(default)s)')
    whole.add_argument('--no-whole-logs', action='store_true',
                       help='skip the whole-log suite (the slowest part)')
    dense = parser.add_argument_group('density suite (--suite density)')
    dense.add_argument('--density-logs', nargs='+', choices=list(density.LOGS),
                       default=list(density.LOGS), help='logs (default: all)')
    dense.add_argument('--densities', nargs='+', default=None, metavar='N',
                       help="every N-th scan, or 'keyframes' (Intel only); default: all")
    dense.add_argument('--cases', nargs='+', choices=list(density.CASES), default=None,
                       help='the map and its displaced copies (default: all)')
    dense.add_argument('--checkout', type=Path, default=density.CHECKOUT,
                       help='folder holding data/density/ (default: this source tree); the '
                            'verdict code is whatever PYTHONPATH imports')
    dense.add_argument('--case-timeout', type=float, default=None, metavar='SECONDS',
                       help='give up a case after this long (default: never)')
    dense.add_argument('--build-native', action='store_true',
                       help='rebuild data/density/intel-native.log.gz first')
    dense.add_argument('--json', type=Path, default=Path('docs/figures/density.json'),
                       help='density suite results (default %(default)s)')
    parser.add_argument('--max-range', type=float, default=None, metavar='METRES',
                        help='usable laser range (default 8, as the original implementation)')
    out = parser.add_argument_group('output')
    out.add_argument('--doc', type=Path, default=Path('docs/evaluation.md'),
                     help='write-up to generate; figures and JSON go to figures/ beside it '
                          '(default %(default)s)')
    out.add_argument('--workers', type=int, default=None,
                     help='processes measuring maps (default: all cores)')
    out.add_argument('--scheduler', metavar='ADDRESS',
                     help='measure the maps on the Dask distributed cluster of this scheduler '
                          'instead (tcp://host:8786; docs/batch.md); the runtime table stays '
                          'on this machine')
    out.add_argument('--no-runtime', action='store_true',
                     help='skip the runtime table (timing whole logs)')
    out.add_argument('--quiet', action='store_true', help='no progress bars')


def _settings(args: argparse.Namespace) -> tuple[SuiteParameters, runner.MeasureSettings]:
    try:
        suite = SuiteParameters(seed=args.seed, part_size=args.part_size)
        settings = runner.MeasureSettings(
            max_range=args.max_range, test=ConsistencyParameters(),
            baseline=BaselineParameters(cell_size=args.cell_size))
        # every swept value within its parameter's declared range, before the sweep starts
        for name, swept in (('alpha', args.alphas), ('binomial_alpha', args.binomial_alphas),
                            ('local_alpha', args.local_alphas),
                            ('flag_window', args.flag_windows)):
            for value in swept:
                replace(settings.test, **{name: value})
        for value in args.quantiles:
            replace(settings.baseline, quantile=value)
    except ValueError as error:
        raise InputError('options', str(error)) from None
    if args.workers is not None and args.workers < 1:
        raise InputError('options', f'--workers must be at least 1, got {args.workers}')
    return suite, settings


def _frontier(rows: np.ndarray, columns: slice) -> np.ndarray:
    return rows[metrics.pareto_frontier(rows[:, columns])]


def _best_recall(rows: np.ndarray, specificity: int, recall: int, floor: float) -> float:
    """The highest recall among settings whose specificity reaches `floor` (0 if none)."""
    good = rows[:, specificity] >= floor
    return float(rows[good, recall].max()) if good.any() else 0.0


def _balanced(rows: np.ndarray, specificity: int, recall: int) -> np.ndarray:
    """The setting with the largest specificity + recall."""
    return rows[int(np.argmax(rows[:, specificity] + rows[:, recall]))]


def plot_frontiers(path: Path, ours: np.ndarray, baseline: np.ndarray, two_stage: np.ndarray,
                   title: str) -> None:
    """Specificity / recall of every setting and the Pareto frontiers, as the paper's Fig. 3.

    Parameters
    ----------
    path: the PNG to write.
    ours: rows (alpha, binomial_alpha, local_alpha, flag_window, specificity, recall) of
        runner.sweep_ours.
    baseline: rows (quantile, threshold, specificity, recall) of runner.sweep_baseline.
    two_stage: rows (alpha, tolerance, specificity, recall) of runner.sweep_two_stage.
    title: the figure's title.
    """
    import matplotlib.pyplot as plt  # here, after plots chose the non-interactive backend
    figure, ax = plt.subplots(figsize=(5.0, 4.6))
    for rows, columns, colour, label in ((baseline, slice(2, 4), 'tab:blue', 'Hähnel et al.'),
                                         (ours, slice(4, 6), 'tab:red', "the paper's test"),
                                         (two_stage, slice(2, 4), 'tab:green',
                                          'two-stage verdict')):
        points = rows[:, columns]
        ax.scatter(points[:, 0], points[:, 1], s=8, color=colour, alpha=0.25)
        front = points[metrics.pareto_frontier(points)]
        # each frontier point attains its recall at every specificity up to its own
        ax.step(np.r_[0.0, front[:, 0]], np.r_[front[0, 1], front[:, 1]], where='pre',
                color=colour, linewidth=2, label=label)
        ax.plot(front[:, 0], front[:, 1], 'o', color=colour, markersize=4)
    ax.set_xlim(0.0, 1.02)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel('specificity')
    ax.set_ylabel('recall')
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc='lower left')
    save_figure(figure, path)


def _commit() -> str:
    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=root, capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain'], cwd=root, capture_output=True,
                               text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown (not a git checkout)'
    return f'{head} plus uncommitted changes' if dirty else head


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    return lines + ['| ' + ' | '.join(row) + ' |' for row in rows]


def _frontier_rows(frontier: np.ndarray, setting: list[str]) -> list[list[str]]:
    return [[*(f'{value:g}' for value in row[:len(setting)]),
             f'{row[-2]:.3f}', f'{row[-1]:.3f}'] for row in frontier]


def _kind_rates(measured: list[runner.MeasuredMap], flagged: np.ndarray) -> dict[str, tuple]:
    kinds = sorted({item.kind for item in measured})
    rates = {}
    for kind in kinds:
        chosen = np.array([item.kind == kind for item in measured])
        rates[kind] = (int(chosen.sum()), float(flagged[chosen].mean()))
    return rates


def _suite_lines(measured: list[runner.MeasuredMap]) -> list[str]:
    rows = []
    for dataset in dict.fromkeys(item.dataset for item in measured):
        mine = [item for item in measured if item.dataset == dataset]
        rows.append([dataset, str(sum(not item.inconsistent for item in mine)),
                     str(sum(item.inconsistent for item in mine)),
                     str(sum(item.scan_count for item in mine if not item.inconsistent)),
                     f'{np.mean([len(item.measures.pairs) for item in mine]):.0f}'])
    return _table(['dataset', 'consistent maps', 'inconsistent maps', 'scans (consistent maps)',
                   'candidate pairs per map'], rows)


def _runtime_lines(rows: list[runner.RuntimeRow]) -> list[str]:
    table = []
    for row in rows:
        paper = PAPER_RUNTIMES.get(row.dataset)
        theirs = [f'{paper[0]}', f'{paper[1]:.1f}', f'{paper[2]}', f'{paper[3]:.1f}'] \
            if paper else ['-'] * 4
        table.append([row.dataset, str(row.scan_count), f'{row.mean_overlaps:.1f}',
                      str(row.beam_count), f'{row.seconds_ours:.2f}',
                      f'{row.seconds_baseline:.2f}', *theirs])
    return _table(['dataset', 'N', 'R', 'K', 'ours [s]', 'baseline [s]', 'paper N', 'paper R',
                   'paper K', 'paper [s]'], table)


def false_alarm_lines(maps: list[SuiteMap], flagged: np.ndarray, parameters: ConsistencyParameters,
                      max_range: float | None, figure: Path) -> list[str]:
    """The consistent maps the test flags at `parameters`: their worst pairs, and a map figure
    of the one with the strongest conflict.

    Parameters
    ----------
    maps: the suite's maps.
    flagged: (M,) bool per map: the test at `parameters` flags it.
    parameters: the test's setting judged.
    max_range: the usable range in metres; None: the default of carmen.sensor_model.
    figure: the PNG of the map with the strongest conflict; removed when no map is flagged.

    Returns
    -------
    Markdown lines: a table of the flagged consistent maps and the figure, or one line saying
    that no consistent map is flagged.
    """
    rows, worst = [], None
    for suite_map, verdict in zip(maps, flagged):
        if suite_map.inconsistent or not verdict:
            continue
        scans = runner.map_scans(suite_map, max_range)
        result = check_consistency(scans, parameters, scans.with_poses(suite_map.reference_poses))
        statistic = np.where(result.failed, result.statistic, -np.inf)
        index = int(np.argmax(statistic))
        i, j = result.pairs[index]
        rows.append([suite_map.name, str(int(result.inconsistent.sum())),
                     str(result.failed_pair_count), f'{i}-{j}', f'{statistic[index]:.0f}',
                     f'{result.point_count[index]}'])
        if worst is None or statistic[index] > worst[0]:
            worst = (statistic[index], suite_map.name, scans, result)
    if worst is None:
        figure.unlink(missing_ok=True)
        return ['No consistent map is flagged at this setting.']
    strict = explain(worst[2], worst[3], ExplanationSettings(strict=True))
    plots.save_map_figure(figure, worst[2], strict, title=worst[1])
    return [*_table(['map', 'flagged scans', 'failed pairs', 'worst pair', 'Psi', 'n_ij'], rows),
            '', f'![{worst[1]}]({figure.parent.name}/{figure.name})']


def missed_lines(maps: list[SuiteMap], ours: np.ndarray, theirs: np.ndarray) -> list[str]:
    """The broken maps our test passes, with how they were broken and the baseline's verdict.

    Parameters
    ----------
    maps: the suite's maps.
    ours: (M,) bool per map: our test flags it.
    theirs: (M,) bool per map: the baseline flags it.

    Returns
    -------
    Markdown lines: a table of those maps, or one line when every broken map is flagged.
    """
    rows = [[item.name, item.description, 'flagged' if their_verdict else 'passed']
            for item, our_verdict, their_verdict in zip(maps, ours, theirs)
            if item.inconsistent and not our_verdict]
    if not rows:
        return ['None: every broken map is flagged.']
    return _table(['map', 'break', 'baseline'], rows)


def summary_lines(measured: list[runner.MeasuredMap], ours: np.ndarray,
                  baseline: np.ndarray) -> list[str]:
    """The comparison in a few lines: frontiers, dominance, the 0.95 / 0.95 bar.

    Parameters
    ----------
    measured: the measured maps (runner.measure_suite).
    ours: rows of runner.sweep_ours over them.
    baseline: rows of runner.sweep_baseline over them.

    Returns
    -------
    Plain lines: the write-up lists them, the command prints them.
    """
    our_front = _frontier(ours, slice(4, 6))
    their_front = _frontier(baseline, slice(2, 4))
    consistent = sum(not item.inconsistent for item in measured)
    return [
        f'maps: {len(measured)} ({consistent} consistent, {len(measured) - consistent} '
        'inconsistent), all static environments',
        'Pareto frontier area (1 = the point (1, 1)): '
        f'ours {metrics.frontier_area(our_front[:, 4:6]):.3f}, '
        f'baseline {metrics.frontier_area(their_front[:, 2:4]):.3f}',
        f'our frontier dominates the baseline\'s: '
        f'{"yes" if metrics.dominates(our_front[:, 4:6], their_front[:, 2:4]) else "no"}',
        'baseline frontier points ours does not match or beat: '
        + (', '.join(f'({a:.3f}, {b:.3f})' for a, b in their_front[:, 2:4]
                     if not metrics.dominates(our_front[:, 4:6], np.array([a, b])))
           or 'none'),
        f'best recall at specificity >= {TARGET}: ours {_best_recall(ours, 4, 5, TARGET):.3f}, '
        f'baseline {_best_recall(baseline, 2, 3, TARGET):.3f} (the bar: {TARGET})',
        f'highest specificity reached: ours {ours[:, 4].max():.3f}, '
        f'baseline {baseline[:, 2].max():.3f}',
    ]


def two_stage_lines(two_stage: np.ndarray) -> list[str]:
    """The two-stage verdict on the parts suite: its frontier and its default setting.

    Parameters
    ----------
    two_stage: rows (alpha, tolerance, specificity, recall) of runner.sweep_two_stage.

    Returns
    -------
    Plain lines: the frontier's area and best recall, then the result at the defaults when
    the sweep holds that setting.
    """
    front = two_stage[metrics.pareto_frontier(two_stage[:, 2:4])]
    defaults = (ConsistencyParameters().alpha, ExplanationSettings().misalignment_tolerance)
    at_default = two_stage[(two_stage[:, 0] == defaults[0]) & (two_stage[:, 1] == defaults[1])]
    lines = [f'two-stage verdict: frontier area {metrics.frontier_area(front[:, 2:4]):.3f}, '
             f'best recall at specificity >= {TARGET}: '
             f'{_best_recall(two_stage, 2, 3, TARGET):.3f}']
    if len(at_default):
        lines.append(f'two-stage verdict at its defaults (alpha {defaults[0]:g}, tolerance '
                     f'{defaults[1]:g} m): specificity {at_default[0, 2]:.3f}, recall '
                     f'{at_default[0, 3]:.3f}')
    return lines


def _verdict(consistent: bool) -> str:
    return 'passes' if consistent else 'FLAGGED'


def whole_log_lines(results: list[whole_logs.WholeLogResult], tolerance: float,
                    figures: Path, data_maps: list[whole_logs.WholeLogMap]) -> list[str]:
    """The whole-log suite at default settings: every map, the three detectors, the errors.

    Parameters
    ----------
    results: whole_logs.judge_all's result per map.
    tolerance: the misalignment tolerance in metres: a map whose observable displacement
        exceeds it is labelled inconsistent.
    figures: the folder of the figures of the maps the two-stage verdict gets wrong.
    data_maps: the maps of `results`, in the same order (whole_logs.build).

    Returns
    -------
    Markdown lines: the detectors' specificity and recall, a table of every map, and a
    figure of each map the two-stage verdict gets wrong.
    """
    truth = np.array([item.displacement > tolerance for item in results])
    ours = np.array([not item.consistent for item in results])
    paper = np.array([not item.paper_consistent for item in results])
    statistic = np.array([item.baseline_statistic for item in results])
    sweep = metrics.threshold_sweep(statistic, truth)
    best = sweep[np.argmax(sweep[:, 1] + sweep[:, 2])] if len(sweep) else (np.nan,) * 3
    rows = [[item.name, f'{item.displacement:.3f}', 'inconsistent' if label else 'consistent',
             _verdict(item.paper_consistent), _verdict(item.consistent),
             f'{item.seconds_test:.2f} + {item.seconds_explanation:.2f}', item.summary_line]
            for item, label in zip(results, truth)]
    lines = [
        f'{len(results)} maps, {int(truth.sum())} with an observable displacement above the '
        f'tolerance ({tolerance:g} m), {int((~truth).sum())} within it. Every detector at its '
        'default setting, except Hähnel et al., which has none: it gets its best threshold in '
        'hindsight (largest specificity + recall on these very maps).',
        '',
        *_table(['detector', 'specificity', 'recall'], [
            ['two-stage verdict (defaults)',
             *(f'{value:.3f}' for value in metrics.specificity_recall(ours, truth))],
            ["the paper's test (defaults)",
             *(f'{value:.3f}' for value in metrics.specificity_recall(paper, truth))],
            [f'Hähnel et al. (best threshold {best[0]:.4f})', f'{best[1]:.3f}', f'{best[2]:.3f}'],
        ]),
        '',
        *_table(['map', 'displacement [m]', 'label', "paper's test", 'two-stage',
                 'time [s] (test + explanation)', 'verdict'], rows),
        '',
    ]
    wrong = [index for index, (flag, label) in enumerate(zip(ours, truth)) if flag != label]
    if not wrong:
        return lines + ['The two-stage verdict labels every map right.', '']
    lines += ['### The maps the two-stage verdict gets wrong', '']
    for index in wrong:
        item = results[index]
        kind = 'false alarm' if ours[index] else 'missed'
        name = item.name.replace('/', '_').replace(' ', '_').replace('#', '')
        figure = figures / f'whole_{name}.png'
        whole = data_maps[index]
        scans, assessment = whole_logs.assess(whole)
        plots.save_map_figure(figure, scans, assessment, title=item.name)
        lines += [f'- **{item.name}** ({kind}, observable displacement '
                  f'{item.displacement:.3f} m): {item.summary_line}',
                  f'  ![{item.name}]({figures.name}/{figure.name})']
    return lines + ['']


def write_doc(args: argparse.Namespace, maps: list[SuiteMap], measured: list[runner.MeasuredMap],
              ours: np.ndarray, baseline: np.ndarray, two_stage: np.ndarray,
              whole: tuple | None, runtimes: list[runner.RuntimeRow],
              figure: Path, elapsed: float, commit: str) -> None:
    """Write the write-up --doc (docs/evaluation.md): everything in it is computed by this run.

    Parameters
    ----------
    args: parsed `evaluate` options (doc, seed, part_size, datasets, cell_size, max_range).
    maps: the suite's maps.
    measured: their measurements (runner.measure_suite), in the same order.
    ours, baseline, two_stage: rows of runner.sweep_ours, sweep_baseline and
        sweep_two_stage, as `plot_frontiers` takes them.
    whole: (results, maps) of the whole-log suite; None when it was skipped.
    runtimes: the rows of the runtime table; empty when it was skipped.
    figure: the Pareto figure, in the folder of figures beside --doc.
    elapsed: seconds the whole run took.
    commit: the commit evaluated (`_commit`).
    """
    our_front = _frontier(ours, slice(4, 6))
    their_front = _frontier(baseline, slice(2, 4))
    truth = runner.labels(measured)
    best_ours = _balanced(ours, 4, 5)
    best_theirs = _balanced(baseline, 2, 3)
    balanced = replace(ConsistencyParameters(), alpha=best_ours[0],
                       binomial_alpha=best_ours[1], local_alpha=best_ours[2],
                       flag_window=int(best_ours[3]))
    our_flags = runner.our_verdicts(measured, balanced)
    statistic = np.array([map_statistic(item.likelihoods, replace(
        BaselineParameters(cell_size=args.cell_size), quantile=best_theirs[0]))
        for item in measured])
    their_flags = statistic < best_theirs[1]
    our_rates, their_rates = _kind_rates(measured, our_flags), _kind_rates(measured, their_flags)
    lines = [
        '# Evaluation: the consistency test against the Hähnel et al. baseline',
        '',
        '_Generated by `map-consistency evaluate`; every figure below is output of that run._',
        '',
        _OTHER_SUITES,
        '',
        f'- commit: `{commit}`',
        f'- date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}',
        f'- machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; '
        f'whole run {elapsed:.0f} s',
        f'- suite seed {args.seed}, {args.part_size} keyframes per map, datasets: '
        f'{", ".join(args.datasets)}',
        '',
        '## Result',
        '',
        *[f'- {line}' for line in summary_lines(measured, ours, baseline)],
        *[f'- {line}' for line in two_stage_lines(two_stage)],
        '',
        f'![Pareto frontiers]({figure.parent.name}/{figure.name})',
        '',
        'Static environments only: the shared datasets are indoor runs without marked '
        'dynamics, so there is no "dynamic" panel (the paper\'s Fig. 3b); the figure is the '
        'paper\'s Fig. 3a / 3c.',
        '',
        '## Suite',
        '',
        'Consistent maps: consecutive parts of each corrected log, thinned to keyframes (0.5 m or '
        '0.5 rad). Inconsistent maps: each part broken once in each way (`rotation` 2-5 deg '
        'about a pivot scan, `shift` 0.2-0.5 m, `rotation+shift`, `corrupted` = a block of 3-10 '
        'scans displaced); see `map_consistency_ros/evaluation/suite.py`. The incremental '
        'solution (for the local scales) of every map is its part\'s corrected poses.',
        '',
        *_suite_lines(measured),
        '',
        '## Detection by kind of map at each method\'s most balanced setting',
        '',
        f'Ours: alpha {best_ours[0]:g}, alpha\' {best_ours[1]:g}, local alpha {best_ours[2]:g}, '
        f'flag window {best_ours[3]:g}. '
        f'Baseline: quantile {best_theirs[0]:g}, threshold {best_theirs[1]:.4f}. '
        'The share of maps flagged inconsistent (for `corrected` lower is better).',
        '',
        *_table(['kind', 'maps', 'ours flagged', 'baseline flagged'],
                [[kind, str(count), f'{rate:.2f}', f'{their_rates[kind][1]:.2f}']
                 for kind, (count, rate) in our_rates.items()]),
        '',
        'Specificity / recall there: ours {:.3f} / {:.3f}, baseline {:.3f} / {:.3f}.'.format(
            *metrics.specificity_recall(our_flags, truth),
            *metrics.specificity_recall(their_flags, truth)),
        '',
        '## Consistent maps the test flags at that setting',
        '',
        'The pair with the largest Psi of each; the figure shows the map with the strongest '
        'conflict (flagged scans orange, their end points deep inside a failed partner red). '
        'The corrected logs are the consistent class of the suite, but they are real data: '
        'doors and people move, glass and dark surfaces return nothing (such beams count as '
        'free space up to the maximum range, as in the original implementation), and the '
        'corrected poses are a SLAM result, not ground truth.',
        '',
        *false_alarm_lines(maps, our_flags, balanced, args.max_range,
                           figure.parent / 'evaluation_false_alarm.png'),
        '',
        '## Inconsistent maps the test misses at that setting',
        '',
        'A break shows only in pairs of scans that overlap across it. Where the robot passed a '
        'stretch once (a corridor), the displaced scans overlap the others only near the pivot, '
        'where a rotation moves them least, and a shift along the corridor moves walls along '
        'themselves: such breaks leave little or no trace in the sensor data.',
        '',
        *missed_lines(maps, our_flags, their_flags),
        '',
        '## Pareto frontiers',
        '',
        'Ours (every setting of the sweep is a point; the frontier keeps the undominated ones):',
        '',
        *_table(['alpha', "alpha'", 'local alpha', 'flag window', 'specificity', 'recall'],
                _frontier_rows(our_front, ['a', 'b', 'c', 'w'])),
        '',
        'Baseline (map statistic = the given quantile of the per-pair mean log-likelihood; '
        'inconsistent below the threshold):',
        '',
        *_table(['quantile', 'threshold', 'specificity', 'recall'],
                _frontier_rows(their_front, ['q', 't'])),
        '',
    ]
    two_front = two_stage[metrics.pareto_frontier(two_stage[:, 2:4])]
    lines += [
        'Two-stage verdict (the paper\'s test at level alpha, then the explanation of its '
        'failures; every other setting at its default):',
        '',
        *_table(['alpha', 'tolerance [m]', 'specificity', 'recall'],
                _frontier_rows(two_front, ['a', 't'])),
        '',
    ]
    if whole is not None:
        results, whole_maps = whole
        lines += ['## Whole logs at default settings', '',
                  'The five corrected logs whole (Freiburg 079 every 5th scan), copies with '
                  'everything after a random seam turned by 1, 2 or 5 degrees or shifted by 0.1 or '
                  '0.3 m, and least-squares maps of graphs built from Intel and Freiburg 079 with '
                  '1, 3 or 10 false loop closures (`map_consistency_ros/evaluation/whole_logs.py`).'
                  ' The label is the observable displacement: the largest RMS distance by which '
                  'the map misplaces a scan relative to a scan it overlaps in the corrected map.',
                  '',
                  *whole_log_lines(results, ExplanationSettings().misalignment_tolerance,
                                   figure.parent, whole_maps)]
    if runtimes:
        lines += [
            '## Runtime (the paper\'s Table I)',
            '',
            f'Whole logs thinned to keyframes, full test (local scales, candidate pairs, measures, '
            f'both tests) on this machine ({os.cpu_count()} cores, shared with other work, so '
            'timings are noisy); the paper used an i7-3770K with 8 threads and its own scan '
            'selection. R = scans whose bounding boxes overlap a scan\'s, on average.',
            '',
            *_runtime_lines(runtimes),
            '',
        ]
    with staged(args.doc) as target:
        target.write_text('\n'.join(lines))


_OTHER_SUITES = ('Two more suites have pages of their own: the same maps at several sampling '
                 'densities, [`density.md`](density.md) (`--suite density`), and maps made by a '
                 'real SLAM system (MRPT), [`real_slam.md`](real_slam.md) '
                 '(`--suite real-slam`).')


def run_density(args: argparse.Namespace) -> int:
    """The density suite: the table goes to --doc (when left at its default, to
    docs/density.md) and the rows to --json.

    Parameters
    ----------
    args: parsed `evaluate` options with --suite density.

    Returns
    -------
    The exit code 0; InputError when no case matches the options.
    """
    if args.build_native:
        built = density.build_native(args.data, args.checkout / density.LOGS['intel-native'])
        print(json.dumps(built))
    cases = density.all_cases(args.density_logs, args.densities, args.cases)
    if not cases:
        raise InputError('options', 'no density-suite case matches --density-logs / --densities')
    doc = Path('docs/density.md') if args.doc == Path('docs/evaluation.md') else args.doc
    density.run_suite(cases, args.data, args.checkout, args.json, doc, args.case_timeout)
    print(f'table {doc}, rows {args.json}')
    return 0


def run_real_slam(args: argparse.Namespace) -> int:
    """The real-SLAM suite: the table and score go to docs/real_slam.md (or --doc), the rows to
    figures/real_slam.json beside it.

    Parameters
    ----------
    args: parsed `evaluate` options with --suite real-slam.

    Returns
    -------
    The exit code 0.
    """
    truth = real_slam.labels(density.CHECKOUT)
    rows = real_slam.run_suite(density.CHECKOUT, Path(tempfile.mkdtemp()), timeout=3600.0)
    doc = Path('docs/real_slam.md') if args.doc == Path('docs/evaluation.md') else args.doc
    lines = ['# Maps made by a real SLAM system', '',
             '_Generated by `map-consistency evaluate --suite real-slam` '
             f'({_commit()[:12]}); the maps, their labels and how they were made: '
             '[`data/real_slam/README.md`](../data/real_slam/README.md)._', '',
             *real_slam.table(rows, truth), '']
    with staged(doc) as target:
        target.write_text('\n'.join(lines))
    report.write_json(doc.parent / 'figures' / 'real_slam.json', {'maps': rows})
    print('\n'.join(lines))
    return 0


def run(args: argparse.Namespace) -> int:
    """Build the suite, measure and sweep it, write the write-up, its figures and
    figures/evaluation.json, and print the summary (--suite density / real-slam: that suite).

    Parameters
    ----------
    args: parsed `evaluate` options.

    Returns
    -------
    The exit code 0: the evaluation measures, it gives no verdict. InputError for bad options.
    """
    if args.suite == 'density':
        return run_density(args)
    if args.suite == 'real-slam':
        return run_real_slam(args)
    commit = _commit()  # before this run writes its own figures into the tree
    suite_parameters, settings = _settings(args)
    started = time.perf_counter()
    maps = build_suite(args.data, suite_parameters, args.datasets)
    with ProgressBar('measuring maps', enabled=not args.quiet) as progress:
        measured = runner.measure_suite(maps, settings, args.workers, progress, args.scheduler)
    ours = runner.sweep_ours(measured, settings.test, args.alphas, args.binomial_alphas,
                             args.local_alphas, args.flag_windows)
    baseline = runner.sweep_baseline(measured, settings.baseline, args.quantiles)
    with ProgressBar('two-stage verdicts', enabled=not args.quiet) as progress:
        two_stage = runner.sweep_two_stage(maps, measured, settings, args.two_stage_alphas,
                                           args.tolerances, args.workers, progress,
                                           args.scheduler)
    whole = None
    if not args.no_whole_logs:
        whole_maps = whole_logs.build(args.data, args.datasets, args.seams, args.seed)
        with ProgressBar('whole logs', enabled=not args.quiet) as progress:
            whole = (whole_logs.judge_all(whole_maps, workers=args.workers, progress=progress,
                                          scheduler=args.scheduler),
                     whole_maps)
    runtimes = []
    if not args.no_runtime:
        with ProgressBar('timing datasets', enabled=not args.quiet) as progress:
            runtimes = runner.runtime_table(maps, suite_parameters, settings, progress)
    elapsed = time.perf_counter() - started
    figures = args.doc.parent / 'figures'
    figure = figures / 'evaluation_pareto.png'
    plot_frontiers(figure, ours, baseline, two_stage, 'static environments (all maps)')
    report.write_json(figures / 'evaluation.json', {
        'ours': {'columns': ['alpha', 'binomial_alpha', 'local_alpha', 'flag_window',
                             'specificity', 'recall'],
                 'rows': ours},
        'baseline': {'columns': ['quantile', 'threshold', 'specificity', 'recall'],
                     'rows': baseline},
        'two_stage': {'columns': ['alpha', 'misalignment_tolerance', 'specificity', 'recall'],
                      'rows': two_stage},
        'whole_logs': [vars(item) for item in whole[0]] if whole else [],
        'maps': [{'name': item.name, 'inconsistent': item.inconsistent,
                  'scans': item.scan_count} for item in measured],
        'runtimes': [vars(row) for row in runtimes],
    })
    write_doc(args, maps, measured, ours, baseline, two_stage, whole, runtimes, figure, elapsed,
              commit)
    for line in summary_lines(measured, ours, baseline) + two_stage_lines(two_stage):
        print(line)
    if runtimes:
        print('\n'.join(_runtime_lines(runtimes)))
    print(f'write-up {args.doc}, figure {figure}')
    return 0
