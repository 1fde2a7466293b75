"""The real-SLAM suite: maps made by MRPT's icp-slam and rbpf-slam, labelled without this tool.

The maps, their labels (relation errors of Kuemmerle et al. 2009 and a look at each map) and
the script that regenerates them are in `data/real_slam/` and `bench/real_slam/`. Here each
map is judged by `map-consistency check` at default settings in its own process, so that a
crash shows as its exit code, and the verdicts are scored against the labels. Maps the
labels call borderline (their largest keyframe loop error within 0.05 m of the rule's 0.3 m)
are listed but not scored: the relations resolve no better than the corrected reference logs
do (0.25 m), coarser than the verdict's tolerance.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

SUITE = Path('data') / 'real_slam'
MAX_RANGE = 8.0  # the evaluation's usable range for Intel and Freiburg 079 (the default)


def _finite(value):
    return value if isinstance(value, (int, float)) and math.isfinite(value) else None


def labels(checkout: Path) -> dict:
    """The labels of every map (data/real_slam/labels.json), by map name.

    Parameters
    ----------
    checkout: the repository checkout holding data/real_slam/.

    Returns
    -------
    Map name -> its label entry ('label', 'borderline', 'relation_errors', 'slam', ...).
    """
    return json.loads((checkout / SUITE / 'labels.json').read_text())['maps']


def check(checkout: Path, name: str, reports: Path, timeout: float) -> dict:
    """`check` of one map in its own process: exit code, wall time and the report's figures.

    Parameters
    ----------
    checkout: the repository checkout holding data/real_slam/<name>.log.gz.
    name: the map's name.
    reports: folder for the JSON report <name>.json (an old one is removed first).
    timeout: seconds before the process is killed.

    Returns
    -------
    A row: 'map', 'exit_code' (None on timeout), 'wall_seconds', 'error' (the last stderr
    line when the exit code is neither 0 nor 1, else None) and, when a report was written,
    'verdict', 'summary_line', 'viewpoints', 'records', 'local_distortion_m' and
    'misalignments' (non-finite figures as None).
    """
    report = reports / f'{name}.json'
    report.unlink(missing_ok=True)
    command = [sys.executable, '-m', 'map_consistency_ros.cli.main', 'check',
               str(checkout / SUITE / f'{name}.log.gz'), '--max-range', f'{MAX_RANGE:g}',
               '--report', str(report), '--quiet']
    started = time.monotonic()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        code, stderr = done.returncode, done.stderr
    except subprocess.TimeoutExpired:
        code, stderr = None, f'timed out after {timeout:g} s'
    row = {'map': name, 'exit_code': code, 'wall_seconds': round(time.monotonic() - started, 1),
           'error': stderr.strip().splitlines()[-1] if code not in (0, 1) and stderr else None}
    if report.exists():
        data = json.loads(report.read_text())
        row.update({
            'verdict': data['verdict'], 'summary_line': data['summary_line'],
            'viewpoints': data['summary']['scans'], 'records': data.get('laser_records'),
            'local_distortion_m': _finite(data.get('local_distortion_m')),
            'misalignments': [{'scans': len(item['scans']),
                               'displacement_m': _finite(item['displacement_m']),
                               'dtheta_deg': _finite(item['dtheta_deg']),
                               'registered': item['registered']}
                              for item in data['misalignments']]})
    return row


def score(rows: list[dict], truth: dict) -> dict:
    """The counts behind recall and specificity over the maps whose label is not borderline.

    Parameters
    ----------
    rows: rows of `check`; a row without a verdict counts as not flagged.
    truth: the labels, as `labels` gives them.

    Returns
    -------
    {'caught', 'inconsistent', 'passed', 'consistent'}: recall is caught / inconsistent,
    specificity passed / consistent.
    """
    counts = {'caught': 0, 'inconsistent': 0, 'passed': 0, 'consistent': 0}
    for row in rows:
        label = truth[row['map']]
        if label.get('borderline'):
            continue
        judged_inconsistent = row.get('verdict') == 'inconsistent'
        if label['label'] == 'inconsistent':
            counts['inconsistent'] += 1
            counts['caught'] += judged_inconsistent
        else:
            counts['consistent'] += 1
            counts['passed'] += not judged_inconsistent
    return counts


def _sizes(row: dict) -> str:
    parts = []
    for item in row.get('misalignments', []):
        size = item['displacement_m']
        parts.append(f'{size:.2f} m, {abs(item["dtheta_deg"]):.1f} deg ({item["scans"]} scans)'
                     if size is not None else f'beyond registration ({item["scans"]} scans)')
    return '; '.join(parts) or 'none'


def table(rows: list[dict], truth: dict) -> list[str]:
    """Markdown lines: one row per map, then the score.

    Parameters
    ----------
    rows: rows of `check`.
    truth: the labels, as `labels` gives them.

    Returns
    -------
    The table's lines, a blank line, and the score of the non-borderline maps.
    """
    lines = ['| map | SLAM (settings) | viewpoints / scans | keyframe loop relations: max m, '
             'p95 deg | label | verdict (exit) | check s | misaligned regions | local '
             'distortion m |', '|---|---|---|---|---|---|---|---|---|']
    for row in rows:
        label = truth[row['map']]
        errors = label['relation_errors']['keyframe_loop']
        slam = label['slam']
        settings = ', '.join(f'{key} {value}' for key, value in slam.get('overrides', {}).items())
        distortion = row.get('local_distortion_m')
        lines.append(
            f'| {row["map"]} | {slam["app"]}{f" ({settings})" if settings else ""} | '
            f'{row.get("viewpoints", "-")} / {row.get("records", label.get("scans"))} | '
            f'{errors["translation_m"]["max"]:.2f}, {errors["rotation_deg"]["p95"]:.1f} | '
            f'{label["label"]}{" (borderline)" if label.get("borderline") else ""} | '
            f'{row.get("verdict", row.get("error"))} ({row["exit_code"]}) | '
            f'{row["wall_seconds"]} | {_sizes(row)} | '
            f'{"-" if distortion is None else f"{distortion:.2f}"} |')
    counts = score(rows, truth)
    lines += ['', f'Scored maps (labels not borderline): recall {counts["caught"]}/'
                  f'{counts["inconsistent"]}, specificity {counts["passed"]}/'
                  f'{counts["consistent"]}.']
    return lines


def run_suite(checkout: Path, reports: Path, timeout: float, names=None) -> list[dict]:
    """`check` of every map (or of `names`), one after another.

    Parameters
    ----------
    checkout: the repository checkout holding data/real_slam/.
    reports: folder for the reports, created if missing.
    timeout: seconds per map.
    names: map names to check; None for all labelled maps.

    Returns
    -------
    The rows of `check`, by map name.
    """
    reports.mkdir(parents=True, exist_ok=True)
    return [check(checkout, name, reports, timeout) for name in sorted(labels(checkout))
            if names is None or name in names]
