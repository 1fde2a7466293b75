"""Run `map-consistency check` at default settings on every map of data/real_slam/labels.json.

Prints a Markdown table (label, verdict, exit code, wall time, misalignments) and writes it, with
the reports' key numbers, to data/real_slam/check_results.json. Each check is a separate process,
so a crash shows as its exit code.

  PYTHONPATH=. python bench/real_slam/check_suite.py [--maps NAME ...] [--reports DIR]
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / 'data' / 'real_slam'
# the evaluation's usable range for Intel and Freiburg 079 (the package default, 8 m)
MAX_RANGE = 8.0


def finite(value):
    return value if isinstance(value, (int, float)) and math.isfinite(value) else None


def check(name: str, reports: Path, timeout: float) -> dict:
    report = reports / f'{name}.json'
    report.unlink(missing_ok=True)
    command = [sys.executable, '-m', 'map_consistency_ros.cli.main', 'check',
               str(OUT / f'{name}.log.gz'), '--max-range', f'{MAX_RANGE:g}', '--report',
               str(report), '--quiet']
    started = time.monotonic()
    try:
        process = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        code, stderr = process.returncode, process.stderr
    except subprocess.TimeoutExpired:
        code, stderr = 'timeout', ''
    seconds = time.monotonic() - started
    result = {'exit_code': code, 'wall_seconds': round(seconds, 1)}
    if report.exists():
        # the reports may hold NaN for unregistered regions; Python's json reads it
        data = json.loads(report.read_text())
        result.update({
            'verdict': data.get('verdict'), 'paper_verdict': data.get('paper_verdict'),
            'summary_line': data.get('summary_line'),
            'runtime_seconds': finite(data.get('runtime_seconds')),
            'inconsistent_scans': len(data.get('inconsistent_scans', [])),
            'failed_pairs': data.get('summary', {}).get('failed_pairs'),
            'local_distortion_m': finite(data.get('local_distortion_m')),
            'misalignments': [
                {'scans': len(m.get('scans', [])), 'displacement_m': finite(m.get('displacement_m')),
                 'dx_m': finite(m.get('dx_m')), 'dy_m': finite(m.get('dy_m')),
                 'dtheta_deg': finite(m.get('dtheta_deg')), 'registered': m.get('registered')}
                for m in data.get('misalignments', [])],
            'changes': len(data.get('changes', [])),
            'report_has_nan': 'NaN' in report.read_text()})
    else:
        result['stderr_tail'] = stderr.strip().splitlines()[-3:]
    return result


def sizes(result: dict) -> str:
    parts = []
    for m in result.get('misalignments', []):
        size = m['displacement_m']
        parts.append(f'{size:.2f} m ({m["scans"]} scans)' if size is not None
                     else f'gross ({m["scans"]} scans)')
    return ', '.join(parts) or 'none'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--maps', nargs='*', default=None)
    parser.add_argument('--reports', type=Path, default=Path('/tmp/real_slam_reports'))
    parser.add_argument('--timeout', type=float, default=1800.0)
    args = parser.parse_args(argv)
    args.reports.mkdir(parents=True, exist_ok=True)
    labels = json.loads((OUT / 'labels.json').read_text())['maps']
    results_path = OUT / 'check_results.json'
    results = json.loads(results_path.read_text()) if results_path.exists() else {}
    for name in sorted(labels):
        if args.maps is not None and name not in args.maps:
            continue
        outcome = check(name, args.reports, args.timeout)
        # re-read before writing: another run of this script may have added maps meanwhile
        results = json.loads(results_path.read_text()) if results_path.exists() else {}
        results[name] = outcome
        results_path.write_text(json.dumps(results, indent=1, sort_keys=True) + '\n')
        print(name, results[name].get('summary_line'), results[name]['exit_code'], flush=True)
    print('| map | scans | label | check verdict | exit | wall s | misalignments | distortion m |')
    print('|---|---|---|---|---|---|---|---|')
    for name in sorted(results):
        result, label = results[name], labels.get(name, {})
        distortion = result.get('local_distortion_m')
        print(f'| {name} | {label.get("scans")} | {label.get("label")} | '
              f'{result.get("verdict", "-")} | {result["exit_code"]} | {result["wall_seconds"]} | '
              f'{sizes(result)} | {"-" if distortion is None else f"{distortion:.2f}"} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
