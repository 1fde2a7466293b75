"""Cost of `check` by sampling density: the same map at every scan against every 5th scan.

    .venv/bin/python bench/bench_density.py [--logs fr079 intel-native] [--repeat 3]

Each run is `map-consistency check LOG --every N --quiet` in a fresh process (wall time of the
whole command, peak RSS of the process); the reference is the same log at every 5th scan, in
the same run, interleaved. Targets (issue 28): the every-scan check costs at most 6x the
every-5th one, and stays under 1.5 GB on Freiburg 079. Intel at its native rate is
`data/density/intel-native.log.gz` (built by `map-consistency evaluate --suite density`).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
LOGS = {'fr079': REPO.parent / 'shared' / 'data' / 'fr079' / 'freiburg-079-corrected.log.gz',
        'intel-native': REPO / 'data' / 'density' / 'intel-native.log.gz'}


# the check's own peak RSS, written last on stderr
_MEASURED = """
import resource, sys
from map_consistency_ros.cli.main import main
try:
    code = main(sys.argv[1:])
finally:
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)
sys.exit(code)
"""


def one_run(log: Path, every: int) -> tuple[float, float, str]:
    """Wall seconds, peak RSS (GB) and the summary line of one check in its own process."""
    command = [sys.executable, '-c', _MEASURED, 'check', str(log), '--every', str(every),
               '--quiet']
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, cwd=REPO)
    seconds = time.perf_counter() - start
    if done.returncode not in (0, 1):
        raise SystemExit(f'check failed ({done.returncode}): {done.stderr.strip()}')
    peak = int(done.stderr.strip().splitlines()[-1]) / 1e6  # kB -> GB
    return seconds, peak, done.stdout.splitlines()[0].split(': ', 1)[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--logs', nargs='+', default=['fr079', 'intel-native'],
                        choices=sorted(LOGS))
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args()
    for name in args.logs:
        log = LOGS[name]
        if not log.exists():
            print(f'{name}: {log} missing, skipped')
            continue
        one_run(log, 5)  # numba's cache and the page cache warm, not timed
        times = {1: [], 5: []}
        peaks = {1: 0.0, 5: 0.0}
        lines = {}
        for _ in range(args.repeat):
            for every in (1, 5):  # interleaved: drift of the machine hits both alike
                seconds, peak, line = one_run(log, every)
                times[every].append(seconds)
                peaks[every] = max(peaks[every], peak)
                lines[every] = line
        dense, sparse = np.median(times[1]), np.median(times[5])
        print(f'\n{name}: check, median of {args.repeat} interleaved runs')
        for every in (1, 5):
            print(f'  every {every} scan{"s" if every > 1 else ""}: '
                  f'{np.median(times[every]):6.2f} s  {lines[every]}')
        print(f'  every scan / every 5th: {dense / sparse:.2f}x time (target <= 6)')
        print(f'  peak RSS of the every-scan check: {peaks[1]:.2f} GB (target < 1.5 GB)')


if __name__ == '__main__':
    main()
