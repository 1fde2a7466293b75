"""Latency of the incremental monitor on the whole Intel log, against full recomputes.

    .venv/bin/python bench/bench_monitor.py [--scans N] [--log PATH]

1. Streaming: each scan arrives, then the trajectory up to it (as the node sees them); the
   per-keyframe update time (add_scan + update_trajectory + the test in evaluate) is reported
   as median and p99.
2. Loop closure: the trajectory's last 10 %, 50 % and 100 % of poses move rigidly; the update
   time is set beside a full recompute of the same monitor (`recompute`) and the batch test
   (`check_consistency`) on the same scans, in the same run.
3. The test's statistics of the streaming updates (in `evaluate`, from the last result while
   the map only grows) beside testing every pair of the same measures again (every 10th
   keyframe, in the same run), per quarter of the stream, and whether both agree exactly.
4. Memory: resident set size along the stream, and a stream of scans that never get a pose
   (the buffer must stay at its bound).
"""
from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

from map_consistency_ros.core.consistency import (ConsistencyParameters, ConsistencyResult,
                                                  check_consistency, evaluate_pairs)
from map_consistency_ros.core.geometry import PairMeasures, ScanSet, se2
from map_consistency_ros.core.live import ConsistencyMonitor, MonitorSettings
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

DEFAULT_LOG = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'intel' / 'intel.gfs.log'


def rss_mib() -> float:
    """Current resident set size (MiB), from /proc."""
    with open('/proc/self/status') as status:
        for line in status:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def stream(stamps, ranges, poses, model) -> tuple[ConsistencyMonitor, np.ndarray, list]:
    """Feed the log scan by scan; (monitor, (N, 4) wall and CPU seconds per keyframe, the
    evaluation's and (every 10th keyframe, else NaN) a test of every pair, RSS)."""
    monitor = ConsistencyMonitor()
    times = np.full((len(stamps), 4), np.nan)
    memory = []
    checkpoints = {int(len(stamps) * f) - 1 for f in (0.25, 0.5, 0.75, 1.0)}
    for index in range(len(stamps)):
        start, cpu = time.perf_counter(), time.process_time()
        monitor.add_scan(stamps[index], ranges[index], model)
        monitor.update_trajectory(stamps[:index + 1], poses[:index + 1])
        tested = time.perf_counter()
        result = monitor.evaluate().result  # the test's statistics run here
        times[index, :3] = (time.perf_counter() - start, time.process_time() - cpu,
                            time.perf_counter() - tested)
        if index % 10 == 9 and result is not None:
            times[index, 3] = every_pair_again(result)
        if index in checkpoints:
            memory.append((index + 1, rss_mib()))
    return monitor, times, memory


def every_pair_again(result: ConsistencyResult) -> float:
    """Seconds to test every pair of `result`'s measures from scratch; NaN if the outcome
    differs from `result`'s."""
    measures = PairMeasures(pairs=result.pairs, distance_sum=result.distance_sum,
                            point_count=result.point_count,
                            largest=np.zeros((result.pairs.shape[0], 0)))
    start = time.perf_counter()
    again = evaluate_pairs(measures, result.scales, result.scan_count, result.parameters,
                           robust=(result.trimmed_sum, result.trimmed_count))
    seconds = time.perf_counter() - start
    same = all(np.array_equal(getattr(again, name), getattr(result, name), equal_nan=True)
               for name in ('tested', 'statistic', 'failed', 'overlap_counts', 'failed_counts',
                            'inconsistent'))
    return seconds if same else np.nan


def moved(poses: np.ndarray, fraction: float) -> np.ndarray:
    """The last `fraction` of the poses dragged rigidly by a loop-closure-like correction."""
    count = len(poses)
    first = count - max(int(round(count * fraction)), 1)
    pivot = poses[first]
    out = poses.copy()
    out[first:] = se2.compose(se2.compose(pivot, np.array([0.15, -0.1, 0.03])),
                              se2.relative(pivot, poses[first:]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--log', type=Path, default=DEFAULT_LOG)
    parser.add_argument('--scans', type=int, default=0, help='first N scans (0: all)')
    args = parser.parse_args()
    log = read_carmen_log(args.log)
    model = sensor_model(log)
    count = args.scans or log.scan_count
    stamps, ranges, poses = log.timestamps[:count], log.ranges[:count], log.laser_poses[:count]

    warm = ConsistencyMonitor()  # compile the numba kernels outside the timings
    for index in range(3):
        warm.add_scan(stamps[index], ranges[index], model)
    warm.update_trajectory(stamps[:3], poses[:3])
    base_rss = rss_mib()

    monitor, times, memory = stream(stamps, ranges, poses, model)
    result = monitor.evaluate().result
    print(f'# {args.log.name}: {count} scans of {ranges.shape[1]} beams, '
          f'{result.overlapping_pair_count} overlapping pairs, '
          f'{int(result.inconsistent.sum())} inconsistent scans at the logged poses')
    print('\n## streaming, per keyframe (add_scan + update_trajectory)')
    print('(wall time suffers from other processes on a shared machine; CPU time of this process '
          'much less)')
    for column, clock in enumerate(('wall', 'CPU')):
        values, last = times[:, column], times[-count // 10:, column]
        print(f'{clock:>4}: median {np.median(values) * 1e3:7.2f} ms   p99 '
              f'{np.percentile(values, 99) * 1e3:7.2f} ms   max {values.max() * 1e3:7.2f} ms   '
              f'total {values.sum():5.1f} s   last 10 %: median {np.median(last) * 1e3:.2f} ms, '
              f'p99 {np.percentile(last, 99) * 1e3:.2f} ms')
    print('target: median < 10 ms')

    print('\n## loop closure moving the last X % of poses (same run, same scans)')
    print(f'{"moved":>6} {"update":>10} {"recompute()":>12} {"batch check":>12} {"speed-up":>9}'
          f' {"pairs measured":>15}')
    order = np.argsort(stamps, kind='stable')
    # compared with the batch test on every scan and every pair: every keyframe a viewpoint,
    # no partner budget
    every_pair = (ConsistencyParameters(viewpoint_spacing=0.0, viewpoint_turn=0.0),
                  MonitorSettings(max_partners=0))
    for fraction in (0.1, 0.5, 1.0):
        trial = ConsistencyMonitor(*every_pair)
        for stamp, scan in zip(stamps, ranges):
            trial.add_scan(stamp, scan, model)
        trial.update_trajectory(stamps, poses)
        target = moved(poses, fraction)
        start = time.perf_counter()
        summary = trial.update_trajectory(stamps, target)
        incremental = trial.evaluate().result  # the test's statistics run here
        update = time.perf_counter() - start
        start = time.perf_counter()
        full = trial.recompute()
        trial.evaluate()
        recompute = time.perf_counter() - start
        start = time.perf_counter()
        batch = check_consistency(ScanSet.from_ranges(ranges[order], target[order], model),
                                  reference_scans=ScanSet.from_ranges(ranges[order],
                                                                      poses[order], model))
        batch_time = time.perf_counter() - start
        same = np.array_equal(incremental.inconsistent, batch.inconsistent)
        print(f'{fraction * 100:5.0f}% {update * 1e3:8.1f} ms {recompute * 1e3:9.1f} ms '
              f'{batch_time * 1e3:9.1f} ms {recompute / update:8.1f}x '
              f'{summary.measured_pairs:7d} / {full.measured_pairs:<7d}'
              f' verdict = batch: {same}')

    print("\n## evaluate per update (local scales, the test from the last result while the map "
          "only grows, copies) beside evaluate_pairs testing every pair again (what the "
          "incremental test saves)")
    rows = np.array_split(np.arange(count), 4)
    for quarter in rows:
        part = times[quarter]
        again = part[:, 3][~np.isnan(part[:, 3])]
        print(f'keyframes {quarter[0] + 1:>5}-{quarter[-1] + 1:<5} in evaluate median '
              f'{np.median(part[:, 2]) * 1e3:6.2f} ms, p99 '
              f'{np.percentile(part[:, 2], 99) * 1e3:6.2f} ms | every pair again median '
              f'{np.median(again) * 1e3:6.2f} ms')
    checked = ~np.isnan(times[9::10, 3])
    print(f'same outcome as testing every pair: {int(checked.sum())} of {checked.size} checks')

    print('\n## memory (resident set size)')
    print(f'after warm-up {base_rss:.0f} MiB; ' + ', '.join(
        f'{n} keyframes {rss:.0f} MiB' for n, rss in memory))
    bounded = ConsistencyMonitor(settings=MonitorSettings(max_buffered_scans=500))
    before = rss_mib()
    for repeat in range(10):  # 9100 scans that never get a pose
        for stamp, scan in zip(stamps, ranges):
            bounded.add_scan(stamp + repeat * 1e4, scan, model)
    print(f'9100 scans without poses: buffer holds {bounded.evaluate().buffered_scans} '
          f'(bound 500), RSS {before:.0f} -> {rss_mib():.0f} MiB')


if __name__ == '__main__':
    main()
