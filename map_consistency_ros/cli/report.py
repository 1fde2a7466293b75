"""Machine-readable reports: JSON with numpy values converted, CSV of pairs."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult


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


def format_summary(result: ConsistencyResult, source: str,
                   scan_ids: np.ndarray | None = None) -> str:
    """A few human lines: what was tested and the verdict."""
    figures = result.summary()
    ids = _ids(result, scan_ids)
    verdict = 'CONSISTENT' if result.consistent else 'INCONSISTENT'
    lines = [
        f'{source}: {verdict}',
        f'  scans                 {figures["scans"]}',
        f'  overlapping pairs     {figures["overlapping_pairs"]} '
        f'({figures["tested_pairs"]} with enough points to test)',
        f'  failed pairs          {figures["failed_pairs"]}',
        f'  inconsistent scans    {figures["inconsistent_scans"]}',
    ]
    if not result.consistent:
        shown = ', '.join(str(ids[index]) for index in result.inconsistent_scans[:20])
        more = ' ...' if figures['inconsistent_scans'] > 20 else ''
        lines.append(f'  flagged scan indices  {shown}{more}')
    return '\n'.join(lines)
