"""Machine-readable reports: JSON with numpy values converted, CSV of pairs."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult
from map_consistency_ros.core.verdict import (Assessment, assessment_report, regions_alike,
                                              result_report, scan_names, to_json)
from map_consistency_ros.io.staging import staged

__all__ = ['assessment_report', 'result_report', 'write_json', 'write_pairs_csv',
           'format_summary', 'region_text', 'scan_span']


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
    if assessment.failed_not_explained:
        # the classes and these add up to the failed pairs
        lines.append(f'  not explained         {assessment.failed_not_explained} failed pairs '
                     "(their scans pass the paper's test)")
    for number, region in enumerate(assessment.misalignments[:_SHOWN_REGIONS], 1):
        lines.append(f'  misaligned region {f"#{number}":<4}{region_text(region, ids)}')
    if len(assessment.misalignments) > _SHOWN_REGIONS:
        lines.append(f'  ... {len(assessment.misalignments) - _SHOWN_REGIONS} more regions '
                     '(the report lists them all)')
    if len(assessment.misalignments) > 1:
        lines.append('  regions apart         one per place where displaced scans meet the '
                     'scans they revisit: a stretch displaced once shows at each such place')
    tolerance = assessment.settings.misalignment_tolerance
    for group in regions_alike(assessment.misalignments, tolerance):
        names = [f'#{index + 1}' for index in group]
        lines.append(f'  move alike            {", ".join(names[:-1])} and {names[-1]}: '
                     f'corrections within {tolerance:.2f} m of each other at their centroids '
                     '(likely one displacement)')
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
    One line, e.g. '29 scans between 12 and 40 against 12 scans between 0 and 11: shifted
    0.12 m and turned +1.90 deg at its centre (x 3.10 m, y -4.20 m), 0.31 m RMS over its end
    points, 57 pairs'; a region beyond local registration is called a gross error.
    """
    return f'{scan_span(ids[region.scans])} against {scan_span(ids[region.reference_scans])}: ' \
           f'{_size(region)}'


def scan_span(ids: np.ndarray) -> str:
    """Some scans in words: how many, and between which first and last name; a set of scans
    is rarely a run, so never 'a-b'.

    Parameters
    ----------
    ids: the scans' names.

    Returns
    -------
    e.g. '28 scans between 48 and 774', 'scan 12', 'no scan'.
    """
    if ids.size == 0:
        return 'no scan'
    return (f'{ids.size} scans between {ids.min()} and {ids.max()}' if ids.size > 1
            else f'scan {ids[0]}')


def _size(region) -> str:
    if not region.registered:
        return f'beyond local registration (a gross error), {region.pairs} pairs'
    # stated where the region is: a world transform's dx, dy move the world origin, metres
    # away from the region, and read as a contradiction of the RMS beside them
    shift, (x, y) = region.shift_at_centroid, region.centroid
    return (f'shifted {np.hypot(*shift):.2f} m and turned '
            f'{np.degrees(region.correction[2]):+.2f} deg at its centroid '
            f'(x {x:.2f} m, y {y:.2f} m), {region.displacement:.2f} m RMS over its end points, '
            f'{region.pairs} pairs')
