"""Replay throughput on the raw Intel bag, against the rate the bag was recorded at.

    .venv/bin/python bench/bench_replay.py [--bag PATH] [--duration SECONDS]

The Intel bag (ROS 1, bz2, 13631 LaserScans + 26915 Odometry over 2691 s) is replayed with
`map-consistency replay`'s own code path: odometry keyframes (0.5 m / 0.25 rad), the live
node's ConsistencyMonitor. Printed side by side, from the same run:
  - bag reading alone (decompress + deserialize every scan and odometry message);
  - the full replay, in scans per wall-clock second;
  - the bag's real-time rate (scans per second of bag time), which a live node must sustain.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from map_consistency_ros.cli import replay
from map_consistency_ros.cli.main import build_parser
from map_consistency_ros.core.live import Scan
from map_consistency_ros.io.bags import BagReader, BagTopics

DEFAULT_BAG = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'intel' / 'intel.orig.bag'


def read_only(bag_path: Path, duration: float | None) -> tuple[int, float]:
    """Scans read and wall seconds to read (and deserialize) the bag's records."""
    started = time.perf_counter()
    scans = 0
    with BagReader([bag_path], BagTopics()) as bag:
        stop = bag.start_time + (duration if duration is not None else float('inf'))
        for log_time, record in bag.records():
            if log_time > stop:
                break
            scans += isinstance(record, Scan)
    return scans, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--bag', type=Path, default=DEFAULT_BAG)
    parser.add_argument('--duration', type=float, default=None,
                        help='replay only the first SECONDS of the bag (default: all)')
    options = parser.parse_args()
    arguments = ['replay', str(options.bag), '--quiet']
    if options.duration is not None:
        arguments += ['--duration', str(options.duration)]
    args = build_parser().parse_args(arguments)

    read_scans, read_seconds = read_only(options.bag, options.duration)
    with replay.open_bag(args) as bag:
        snapshot, run, _ = replay.replay_bag(args, bag)
    stats = run.stats
    result = snapshot.result
    print(f'bag: {options.bag} ({stats.log_seconds:.0f} s of bag time replayed)')
    print(f'keyframes: {snapshot.keyframe_count} of {stats.scans} scans; verdict: '
          f'{"consistent" if result.consistent else "inconsistent"} '
          f'({int(result.inconsistent.sum())} scans flagged)')
    print(f'{"":30}{"scans":>8}{"wall s":>10}{"scans/s":>10}')
    print(f'{"bag reading only":30}{read_scans:>8}{read_seconds:>10.2f}'
          f'{read_scans / read_seconds:>10.1f}')
    print(f'{"replay through the monitor":30}{stats.scans:>8}{stats.seconds:>10.2f}'
          f'{stats.scan_rate:>10.1f}')
    print(f'{"bag real time (reference)":30}{stats.scans:>8}{stats.log_seconds:>10.2f}'
          f'{stats.realtime_rate:>10.1f}')
    print(f'replay runs at {stats.scan_rate / stats.realtime_rate:.1f}x the real-time rate')


if __name__ == '__main__':
    main()
