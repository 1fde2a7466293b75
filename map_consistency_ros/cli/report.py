"""Machine-readable reports: JSON with numpy values converted, CSV of pairs."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult
from map_consistency_ros.core.verdict import (Assessment, assessment_report, result_report,
                                              scan_names, to_json)
from map_consistency_ros.io.staging import staged

__all__ = ['assessment_report', 'result_report', 'write_json', 'write_pairs_csv',
           'format_summary', 'region_text']


def write_json(path: str | Path, report: dict) -> None:
    """Write `report` as indented strict JSON (numpy arrays and scalars become lists and
    numbers, values that do not exist null: reporting.to_json).

    Parameters
    ----------
    path: the JSON file; its folder is created. Written whole or not at all (io/staging.py).
    report: the report: dicts, lists, numbers, strings and numpy values.
    """
    text = to_json(report, indent=2) + '\n'
    with staged(path) as target:
        target.write_text(text)


def write_pairs_csv(path: str | Path, result: ConsistencyResult,
                    scan_ids: np.ndarray | None = None) -> None:
    """Write every overlapping pair (n_ij > 0) as CSV: i, j, M_ij, n_ij, psi_ij (empty if
    untested), failed.

    Parameters
    ----------
    path: the CSV file; its folder is created. Written whole or not at all (io/staging.py).
    result: the consistency result.
    scan_ids: (S,) names of the scans for i and j (record positions, stamps); None: their
        indices.
    """
    ids = scan_names(result, scan_ids)
    overlapping = np.flatnonzero(result.point_count > 0)
    with staged(path) as target, open(target, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(['i', 'j', 'M_ij', 'n_ij', 'psi_ij', 'failed'])
        for index in overlapping:
            psi = result.statistic[index]
            writer.writerow([int(ids[result.pairs[index, 0]]), int(ids[result.pairs[index, 1]]),
                             repr(float(result.distance_sum[index])),
                             int(result.point_count[index]),
                             '' if np.isnan(psi) else repr(float(psi)),
                             int(result.failed[index])])


def format_summary(assessment: Assessment, source: str,
                   scan_ids: np.ndarray | None = None) -> str:
    """A few human lines: the verdict, what was tested, the misaligned regions.

    Parameters
    ----------
    assessment: both stages' verdict.
    source: what was judged (the input's path), the first line's label.
    scan_ids: (S,) names of the scans in the regions; None: their indices.

    Returns
    -------
    The lines joined by newlines; at most five regions, then how many more there are.
    """
    result = assessment.result
    figures = result.summary()
    ids = scan_names(result, scan_ids)
    lines = [
        f'{source}: {assessment.summary_line()}',
        f'  scans                 {figures["scans"]}',
        f'  overlapping pairs     {figures["overlapping_pairs"]} '
        f'({figures["tested_pairs"]} with enough points to test)',
        f'  failed pairs          {figures["failed_pairs"]}',
        f'  paper\'s test flags    {figures["inconsistent_scans"]} scans',
    ]
    counts = assessment.class_counts()
    if sum(counts.values()):
        lines.append('  failed pairs explained ' + ', '.join(
            f'{count} {name}' for name, count in counts.items()))
    for region in assessment.misalignments[:_SHOWN_REGIONS]:
        lines.append(f'  misaligned region     {region_text(region, ids)}')
    if len(assessment.misalignments) > _SHOWN_REGIONS:
        lines.append(f'  ... {len(assessment.misalignments) - _SHOWN_REGIONS} more regions')
    return '\n'.join(lines)


_SHOWN_REGIONS = 5


def region_text(region, ids: np.ndarray) -> str:
    """One misaligned region: its scans (named by `ids`), its reference scans, its size.

    Parameters
    ----------
    region: a misaligned region of an Assessment.
    ids: (S,) names of the scans.

    Returns
    -------
    One line, e.g. 'scans 12-40 (29) against scans 0-11 (12): 0.31 m RMS (dx ...), 57 pairs';
    a region beyond local registration is called a gross error.
    """
    return f'{_span(ids[region.scans])} against {_span(ids[region.reference_scans])}: ' \
           f'{_size(region)}'


def _span(ids: np.ndarray) -> str:
    if ids.size == 0:
        return 'no scan'
    return f'scans {ids.min()}-{ids.max()} ({ids.size})' if ids.size > 1 else f'scan {ids[0]}'


def _size(region) -> str:
    if not region.registered:
        return f'beyond local registration (a gross error), {region.pairs} pairs'
    dx, dy, dtheta = region.correction
    return (f'{region.displacement:.2f} m RMS (dx {dx:+.2f} m, dy {dy:+.2f} m, '
            f'dtheta {np.degrees(dtheta):+.2f} deg), {region.pairs} pairs')
