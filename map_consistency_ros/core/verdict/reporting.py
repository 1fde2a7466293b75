"""The machine-readable report of a verdict: the one format that the CLI's JSON files and the
node's ~/report share, and the one place it becomes text (`to_json`): strict JSON, which jq,
JavaScript and Go parse, with null where a value does not exist (no NaN, no Infinity)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from map_consistency_ros.core.consistency import ConsistencyResult
from map_consistency_ros.core.verdict.explanation import Assessment, regions_alike


def scan_names(result: ConsistencyResult, scan_ids: np.ndarray | None) -> np.ndarray:
    """How the report names the scans.

    Parameters
    ----------
    result: the test's result on N scans.
    scan_ids: (N,) the scans' names in the input (record positions, stamps); None: indices.

    Returns
    -------
    (N,) `scan_ids` as an array, else 0..N-1.
    """
    return np.arange(result.scan_count) if scan_ids is None else np.asarray(scan_ids)


def result_report(result: ConsistencyResult, scan_ids: np.ndarray | None = None) -> dict:
    """The verdict, the figures and the per-scan decisions of a consistency result.

    Parameters
    ----------
    result: the paper's test.
    scan_ids: (N,) names of the scans in the input (record positions) where the test ran on a
        subset; None names them by index.

    Returns
    -------
    The report dict (numpy values; `to_json` makes it text).
    """
    ids = scan_names(result, scan_ids)
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
    paper's test (result_report). The node's ~/report and the CLI's JSON share it.

    Parameters
    ----------
    assessment: the verdict of both stages.
    scan_ids: as result_report.

    Returns
    -------
    The report dict (numpy values; `to_json` makes it text).
    """
    ids = scan_names(assessment.result, scan_ids)
    # the numbers of the other regions each region moves alike with (likely one displacement)
    alike = {index: [other + 1 for other in group if other != index]
             for group in regions_alike(assessment.misalignments,
                                        assessment.settings.misalignment_tolerance)
             for index in group}
    content = result_report(assessment.result, scan_ids)
    content.update({
        'verdict': assessment.outcome,
        'summary_line': assessment.summary_line(),
        # why nothing was judged (NOTHING_TO_JUDGE), else null
        'nothing_to_judge_reason': (None if assessment.evidence.sufficient or assessment.failed
                                    else assessment.evidence.reason()),
        'evidence': {'flaggable_scans': assessment.evidence.flaggable_scans,
                     'flaggable_pairs': assessment.evidence.flaggable_pairs,
                     'needed_scans': assessment.evidence.needed_scans},
        'paper_verdict': 'consistent' if assessment.result.consistent else 'inconsistent',
        'explanation': assessment.settings.as_dict(),
        'explained_pairs': assessment.class_counts(),
        # with the explained ones, the failed pairs: those of two scans passing the paper's test
        'failed_pairs_not_explained': assessment.failed_not_explained,
        'misaligned_scans': ids[np.flatnonzero(assessment.flagged)],
        'local_distortion_m': assessment.local_distortion,
        'distorted': assessment.distorted,
        'misalignments': [dict(_region(region, ids, number),
                               moves_alike_with=alike.get(number - 1, []))
                          for number, region in enumerate(assessment.misalignments, 1)],
        'minor_misalignments': [_region(region, ids, number) for number, region in enumerate(
            assessment.minor_misalignments, len(assessment.misalignments) + 1)],
        'changes': [{'scans': ids[place.scans], 'x': place.x, 'y': place.y,
                     'points': place.points} for place in assessment.changes],
        'frozen_estimates': [{'scans': ids[stretch.scans], 'changes': stretch.changes}
                             for stretch in assessment.frozen],
    })
    return content


def _region(region, ids: np.ndarray, number: int) -> dict:
    # number: #k of the printed summary and the figures (misalignments first, then the minor
    # regions); dx_m, dy_m and dtheta_deg are the correction as a world transform (rotation
    # about the world origin), the shift_at_centroid fields the same motion where the region is
    shift = region.shift_at_centroid
    return {
        'number': number,
        'scans': ids[region.scans], 'reference_scans': ids[region.reference_scans],
        'centroid_x_m': region.centroid[0], 'centroid_y_m': region.centroid[1],
        'shift_at_centroid_m': float(np.hypot(*shift)),
        'shift_at_centroid_dx_m': shift[0], 'shift_at_centroid_dy_m': shift[1],
        'dx_m': region.correction[0], 'dy_m': region.correction[1],
        'dtheta_deg': np.degrees(region.correction[2]),
        'std_dx_m': region.correction_std[0], 'std_dy_m': region.correction_std[1],
        'std_dtheta_deg': np.degrees(region.correction_std[2]),
        'displacement_m': region.displacement, 'pairs': region.pairs,
        'registered': region.registered,
    }


def plain(value):
    """A value as plain Python data for JSON.

    Parameters
    ----------
    value: a report, or any part of one: dicts, lists, tuples, numpy arrays and scalars,
        floats, paths, other values.

    Returns
    -------
    `value` with dict keys as strings, tuples and numpy arrays as lists, numpy scalars as
    numbers, paths as strings and non-finite floats as None; other values as they are.
    """
    if isinstance(value, dict):
        return {str(key): plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):  # np.float64 NaN is a float NaN after item()
        return plain(value.item())
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def to_json(report, indent: int | None = None) -> str:
    """A report as strict JSON text.

    Parameters
    ----------
    report: the report (`plain` makes its values plain).
    indent: json.dumps' indent; None for one line.

    Returns
    -------
    The text; a ValueError rather than a NaN or an Infinity that slipped past `plain` (no JSON
    parser but Python's would read the report).
    """
    return json.dumps(plain(report), indent=indent, allow_nan=False)


def joined_json(first: str, second: str) -> str:
    """Two JSON objects of `to_json` (one line) as one: the members of `first`, then those of
    `second`; the same text as `to_json` of the merged dict when no key is in both.

    A report whose large part changes rarely keeps that part's text and joins each update's
    small part to it, instead of turning the whole report into JSON again.

    Parameters
    ----------
    first, second: '{...}' texts of to_json (indent None), with no key in common.

    Returns
    -------
    The text of one object. ValueError when one of them is not an object's text.
    """
    first, second = first.strip(), second.strip()
    if not (first.startswith('{') and first.endswith('}') and second.startswith('{')
            and second.endswith('}')):
        raise ValueError('joined_json joins the texts of two JSON objects')
    if first == '{}':
        return second
    if second == '{}':
        return first
    return f'{first[:-1]}, {second[1:]}'
