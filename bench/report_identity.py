"""The full verdict reports of a fixed set of maps in one JSON file, to prove that a change
leaves behaviour bit-identical.

    .venv/bin/python bench/report_identity.py OUT.json [--workers 2] [--seed 7]

Maps: (a) every map of the whole-log suite (evaluation/whole_logs.py: the five corrected logs,
their displaced copies at 2 seams per size and the false-loop maps, at --seed), judged as
`whole_logs.judge` judges them (the map's viewpoints, check_consistency, explain at default
settings); (b) the four maps of bench_explanation.py (check_consistency + explain on all
scans). Each map's report is the assessment report (the CLI's JSON and the node's ~/report)
through the strict `to_json`, keys sorted, fields that time something removed.

To compare two commits, run this file (of the newer tree) against each commit's package and
compare the outputs byte for byte:

    git worktree add /tmp/base BASE_COMMIT
    PYTHONPATH=/tmp/base .venv/bin/python bench/report_identity.py /tmp/identity_before.json
    PYTHONPATH=. .venv/bin/python bench/report_identity.py /tmp/identity_after.json
    cmp /tmp/identity_before.json /tmp/identity_after.json

It imports the core from the sub-package layout (issue 30) and, failing that, from the flat
layout before it, so both sides of that restructuring run it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

try:
    from map_consistency_ros.core.consistency import check_consistency
    from map_consistency_ros.core.geometry import ScanSet
    from map_consistency_ros.core.verdict import assessment_report, explain, to_json
except ImportError:  # the flat core/ before issue 30
    from map_consistency_ros.core.consistency import check_consistency
    from map_consistency_ros.core.explanation import explain
    from map_consistency_ros.core.reporting import assessment_report, to_json
    from map_consistency_ros.core.scan_geometry import ScanSet
from map_consistency_ros.evaluation import runner, whole_logs
from map_consistency_ros.evaluation.suite import displace
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data'
DATASETS = ['intel', 'fr079', 'fr101', 'belgioioso', 'orebro']
TIMING_WORDS = ('seconds', 'latency', 'elapsed', 'duration', 'time')


def explanation_maps(data: Path = DATA) -> list[tuple[str, ScanSet]]:
    """The maps of bench_explanation.py: corrected Intel, Intel turned by 1 degree after scan
    455, the first 290 scans of Intel (the demo map), and corrected Freiburg 101."""
    intel = read_carmen_log(data / 'intel' / 'intel.gfs.log')
    model = sensor_model(intel)
    turned = displace(intel.laser_poses, 455, intel.scan_count, np.radians(1.0), np.zeros(2))
    fr101 = read_carmen_log(data / 'carmen_corrected_extra' / 'freiburg-101-corrected.log.gz')
    return [
        ('Intel corrected (910 scans)', ScanSet.from_ranges(intel.ranges, intel.laser_poses,
                                                            model)),
        ('Intel, 1 deg after scan 455', ScanSet.from_ranges(intel.ranges, turned, model)),
        ('Intel demo map (290 scans)', ScanSet.from_ranges(intel.ranges[:290],
                                                           intel.laser_poses[:290], model)),
        ('Freiburg 101 (292 scans)', ScanSet.from_ranges(fr101.ranges, fr101.laser_poses,
                                                         sensor_model(fr101))),
    ]


def untimed(value):
    """`value` (plain JSON data) without the dict entries whose key names a timing."""
    if isinstance(value, dict):
        return {key: untimed(item) for key, item in value.items()
                if not any(word in key.lower() for word in TIMING_WORDS)}
    if isinstance(value, list):
        return [untimed(item) for item in value]
    return value


def report(scans: ScanSet) -> dict:
    """The full assessment report of both stages on `scans`, as strict JSON data, untimed."""
    return untimed(json.loads(to_json(assessment_report(explain(scans,
                                                                check_consistency(scans))))))


def whole_log_report(whole: whole_logs.WholeLogMap) -> dict:
    """The report of a whole-log map, judged as whole_logs.judge does (its viewpoints)."""
    scans, _ = whole_logs.map_scans(whole)
    return report(scans)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('out', type=Path)
    parser.add_argument('--data', type=Path, default=DATA)
    parser.add_argument('--seed', type=int, default=7)
    parser.add_argument('--workers', type=int, default=2)
    args = parser.parse_args()
    maps = whole_logs.build(args.data, DATASETS, 2, args.seed)
    print(f'{len(maps)} whole-log maps', file=sys.stderr)
    reports = runner.pooled(whole_log_report, maps, (), args.workers, None)
    content = {'whole_logs': {whole.name: item for whole, item in zip(maps, reports)},
               'explanation': {name: report(scans)
                               for name, scans in explanation_maps(args.data)}}
    args.out.write_text(json.dumps(content, sort_keys=True, indent=1, allow_nan=False) + '\n')
    print(f'{args.out}: {len(reports)} whole-log maps, {len(content["explanation"])} '
          'explanation maps', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
