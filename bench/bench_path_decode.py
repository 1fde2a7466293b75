"""Reading a stream of growing Paths: the node's PathReader against decoding every Path whole.

    .venv/bin/python bench/bench_path_decode.py [--every 10] [--repeat 5]

A back-end that publishes its whole estimate as a nav_msgs/Path sends every pose again each
time. Intel at its native rate (13,631 poses, the density suite's rebuild) is cut into the
Paths a node streamed scan by scan receives, one every `--every` scans, serialized as rclpy
does. Printed per map-size bucket (poses in the Path), from the same run: the median time per
Path of messages.PathReader (one reader over the stream, as the node's subscription and bag
replay use it) and of messages.path_from_cdr (every entry decoded), and their ratio. Both give
the same record (checked on every Path).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_node_load import LOGS, path_prefixes  # noqa: E402

from map_consistency_ros.io import messages  # noqa: E402
from map_consistency_ros.io.carmen import read_carmen_log  # noqa: E402

BUCKETS = 6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--every', type=int, default=10, help='scans between Paths')
    parser.add_argument('--repeat', type=int, default=5, help='passes over the stream')
    args = parser.parse_args()
    log = read_carmen_log(LOGS['intel-native'])
    order = np.argsort(log.timestamps, kind='stable')
    prefix = path_prefixes(log.timestamps[order], log.laser_poses[order])
    counts = np.arange(args.every, order.size + 1, args.every)
    stream = [prefix(int(count)) for count in counts]
    timings = {'reader': np.full((args.repeat, counts.size), np.inf),
               'whole': np.full((args.repeat, counts.size), np.inf)}
    for attempt in range(args.repeat):
        reader = messages.PathReader()
        for index, data in enumerate(stream):
            started = time.perf_counter()
            fast = reader(data)
            middle = time.perf_counter()
            whole = messages.path_from_cdr(data)
            timings['reader'][attempt, index] = middle - started
            timings['whole'][attempt, index] = time.perf_counter() - middle
            if attempt == 0 and not (np.array_equal(fast.stamps, whole.stamps)
                                     and np.array_equal(fast.poses, whole.poses,
                                                        equal_nan=True)):
                raise SystemExit(f'the reader differs at the Path of {counts[index]} poses')
    # the best of the passes per Path: the cost of the code, not of what else ran then
    reader, whole = (timings[name].min(axis=0) * 1e3 for name in ('reader', 'whole'))
    print(f'{counts.size} Paths of {args.every}-{counts[-1]} poses (Intel native, one every '
          f'{args.every} scans), best of {args.repeat} passes, median ms per Path')
    print('  poses in the Path    reader   whole    whole / reader')
    edges = np.linspace(0, counts[-1], BUCKETS + 1)
    for low, high in zip(edges[:-1], edges[1:]):
        inside = (counts > low) & (counts <= high)
        ratio = np.median(whole[inside] / reader[inside])
        print(f'  {int(low) + 1:6d}-{int(high):6d}    {np.median(reader[inside]):6.3f}  '
              f'{np.median(whole[inside]):6.3f}    {ratio:5.1f}')
    last, first = counts > edges[-2], counts <= edges[1]
    growth = {name: np.median(times[last]) / np.median(times[first])
              for name, times in (('reader', reader), ('whole', whole))}
    print(f'  last / first bucket: reader {growth["reader"]:.2f}, whole {growth["whole"]:.2f}')


if __name__ == '__main__':
    main()
