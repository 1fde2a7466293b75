"""Machine-readable reports: JSON with numpy values converted, CSV of pairs."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult
from map_consistency_ros.core.explanation import Assessment


def _plain(value):
    if isinstance(value, dict):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | Path, report: dict) -> None:
    """Write `report` as indented JSON (numpy arrays and scalars become lists and numbers)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_plain(report), indent=2) + '\n')


def _ids(result: ConsistencyResult, scan_ids: np.ndarray | None) -> np.ndarray:
    return np.arange(result.scan_count) if scan_ids is None else np.asarray(scan_ids)


def result_report(result: ConsistencyResult, scan_ids: np.ndarray | None = None) -> dict:
    """The verdict, the figures and the per-scan decisions of a consistency result.

    `scan_ids` name the scans in the input (record positions) where the test ran on a subset.
    """
    ids = _ids(result, scan_ids)
    return {
        'verdict': 'consistent' if result.consistent else 'inconsistent',
        'summary': result.summary(),
        'parameters': result.parameters.as_dict(),
        'inconsistent_scans': ids[result.inconsistent_scans],
        'scans': {
            'id': ids,
            'scale': result.scales,
            'tested_pairs': result.overlap_counts,
            'failed_pairs': result.failed_counts,
            'critical_count': result.critical_counts,
        },
    }


def assessment_report(assessment: Assessment, scan_ids: np.ndarray | None = None) -> dict:
    """Both stages: the verdict, each misaligned region and each changed place, on top of the
    paper's test (result_report). The node's ~/report and the CLI's JSON share it."""
    ids = _ids(assessment.result, scan_ids)
    content = result_report(assessment.result, scan_ids)
    content.update({
        'verdict': 'consistent' if assessment.consistent else 'inconsistent',
        'summary_line': assessment.summary_line(),
        'paper_verdict': 'consistent' if assessment.result.consistent else 'inconsistent',
        'explanation': assessment.settings.as_dict(),
        'explained_pairs': assessment.class_counts(),
        'misaligned_scans': ids[np.flatnonzero(assessment.flagged)],
        'misalignments': [{
            'scans': ids[region.scans], 'reference_scans': ids[region.reference_scans],
            'dx_m': region.correction[0], 'dy_m': region.correction[1],
            'dtheta_deg': np.degrees(region.correction[2]),
            'std_dx_m': region.correction_std[0], 'std_dy_m': region.correction_std[1],
            'std_dtheta_deg': np.degrees(region.correction_std[2]),
            'displacement_m': region.displacement, 'pairs': region.pairs,
            'registered': region.registered,
        } for region in assessment.misalignments],
        'changes': [{'scans': ids[place.scans], 'x': place.x, 'y': place.y,
                     'points': place.points} for place in assessment.changes],
    })
    return content


def write_pairs_csv(path: str | Path, result: ConsistencyResult,
                    scan_ids: np.ndarray | None = None) -> None:
    """Every overlapping pair (n_ij > 0): i, j, M_ij, n_ij, psi_ij (empty if untested), failed."""
    ids = _ids(result, scan_ids)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    overlapping = np.flatnonzero(result.point_count > 0)
    with open(path, 'w', newline='') as stream:
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
    """A few human lines: the verdict, what was tested, the misaligned regions."""
    result = assessment.result
    figures = result.summary()
    ids = _ids(result, scan_ids)
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
        lines.append(f'  misaligned region     {_span(ids[region.scans])} against '
                     f'{_span(ids[region.reference_scans])}: {_size(region)}')
    if len(assessment.misalignments) > _SHOWN_REGIONS:
        lines.append(f'  ... {len(assessment.misalignments) - _SHOWN_REGIONS} more regions')
    return '\n'.join(lines)


_SHOWN_REGIONS = 5


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
