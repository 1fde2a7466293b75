"""Load on the live node: real logs streamed over DDS into the node process.

    .venv/bin/python bench/bench_node_load.py [--logs intel fr079] [--rates 100 400]
                                              [--path-every 10] [--repeat N] [--scans N]
                                              [--no-reference]
                                              [--executors events multi_threaded]
                                              [-p NAME:=VALUE ...]

For each log and rate a fresh node process (defaults of config/map_consistency.yaml) gets the
log's scans at the rate and, every `--path-every` scans, the growing keyframe Path of the
corrected poses (the node's contract: the full estimate each time), as a SLAM back-end would
publish them. Streaming starts when the node's diagnostics say `ready` (its compiled kernels
loaded). Printed per node run: its start-up (launch -> ready), keyframes registered / scans
sent, what became of the scans it received and of those it never received (the scan counts,
`scans lost by the middleware` and `poses without scan` of /diagnostics), its peak RSS and the time SIGINT takes to end it. Then the update latency
(arrival of the Path -> verdict published, from ~/report) as median / p99 overall and per
map-size bucket with the time per stage (monitor update, snapshot, markers, publishing),
beside the same Path updates through the feed in-process, its scans applied at the stream's
rate (the reference, run right after each node run), and back to back. With `--repeat N`, N
fresh nodes (each followed by its paced reference) get the stream and their updates are pooled; the last / first bucket ratio of each
run is printed beside the pooled one. Targets: at 400 scans/s every scan a keyframe or the loss
reported; median < 10 ms and p99 < 50 ms at 100 scans/s (issue 12); node / in-process median
and last / first bucket median each <= 1.5 (issue 28).

Paths are pre-serialized (a prefix of the full Path's CDR bytes, so the publisher keeps pace);
the publisher and the node share the machine, so latencies are upper bounds.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import signal
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / 'shared' / 'data'
LOGS = {'intel': DATA / 'intel' / 'intel.gfs.log',
        'fr079': DATA / 'fr079' / 'freiburg-079-corrected.log.gz',
        # Intel at the laser's native rate (the density suite's rebuild): scan by scan
        'intel-native': REPO / 'data' / 'density' / 'intel-native.log.gz'}
BUCKETS = 6


def map_size_buckets(sizes: np.ndarray) -> list[tuple[float, float, np.ndarray]]:
    """(low, high, which updates) of each non-empty map-size bucket: BUCKETS equal spans of
    (0, largest map size] over the updates' map sizes `sizes`."""
    edges = np.linspace(0, sizes.max(), BUCKETS + 1)
    buckets = [(low, high, (sizes > low) & (sizes <= high))
               for low, high in zip(edges[:-1], edges[1:])]
    return [bucket for bucket in buckets if bucket[2].any()]


def path_prefixes(stamps: np.ndarray, poses: np.ndarray):
    """A function k -> CDR bytes of the Path of the first k poses, cut from one serialization.

    Every PoseStamped after the first has the same size (its fields realign at the same
    offset), so a prefix of the full message with the sequence length patched is the
    serialization of the shorter Path.
    """
    from rclpy.serialization import serialize_message

    from map_consistency_ros.io import messages
    from map_consistency_ros.ros.conversions import message_class

    def serialized(count: int) -> bytes:
        return serialize_message(messages.path_message(message_class, stamps[:count],
                                                       poses[:count], 'map',
                                                       stamp=float(stamps[-1])))

    empty, one, two = (len(serialized(count)) for count in (0, 1, 2))
    full = serialized(len(stamps))
    first, entry = one - empty, two - one
    count_at = empty - 4

    def prefix(count: int) -> bytes:
        end = empty + (first + (count - 1) * entry if count else 0)
        return full[:count_at] + struct.pack('<I', count) + full[count_at + 4:end]

    return prefix


class Observer:
    """Subscribes to the node's report and diagnostics."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('load_observer', context=self.context)
        self.reports: list[dict] = []
        self.status: dict[str, str] = {}
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(String, '/map_consistency/report',
                                      lambda m: self.reports.append(json.loads(m.data)), qos)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_status, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_status(self, msg) -> None:
        for status in msg.status:
            if status.name == 'map_consistency: map':
                self.status = {kv.key: kv.value for kv in status.values}

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.thread.join(timeout=5)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def peak_rss_mib(pid: int) -> float:
    with open(f'/proc/{pid}/status') as status:
        for line in status:
            if line.startswith('VmHWM:'):
                return int(line.split()[1]) / 1024.0
    return float('nan')


def in_process(stamps, ranges, poses, model, path_every: int, threads: int,
               rate: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(seconds, keyframes after it) of each Path update of the same stream through the feed
    without ROS (the reference: what the node adds is decoding, queueing, markers, publishing,
    sharing), its kernels on as many threads as the node's updates (`update_threads`, 0: every
    core): the thread count is a setting of both, not a cost of the node.

    `rate` (scans per second): each scan is applied at its time in the stream, as the node gets
    it, and the processor idles in between; None: back to back. An update that follows idling
    finds colder caches than one that follows another at once, and the node's updates come at
    the stream's pace: the paced run is the reference of the same updates (docs/benchmarks.md
    has both)."""
    import numba
    available = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(available if threads == 0 else min(threads, available))
    from map_consistency_ros.core.live import KeyframeEstimate, MonitorFeed, Scan
    feed = MonitorFeed()
    seconds, sizes = [], []
    begin = time.perf_counter()
    for k in range(len(stamps)):
        if rate is not None:
            wait = begin + k / rate - time.perf_counter()
            if wait > 0.0:
                time.sleep(wait)
        feed.apply(Scan(stamp=float(stamps[k]), ranges=ranges[k], model=model))
        if (k + 1) % path_every == 0 or k + 1 == len(stamps):
            start = time.perf_counter()
            feed.apply(KeyframeEstimate(stamps=stamps[:k + 1], poses=poses[:k + 1]))
            feed.monitor.evaluate()  # the test's statistics run here
            seconds.append(time.perf_counter() - start)
            sizes.append(feed.monitor.keyframe_count)
    return np.array(seconds), np.array(sizes)


@dataclass
class NodeRun:
    """What one node process did with the stream."""

    startup: float  # launch -> ready, seconds
    ready: bool
    streamed: float  # seconds
    waited: float  # seconds after the stream, for the node to catch up
    rss: float  # peak, MiB
    status: dict  # the last /diagnostics values
    reports: list  # every ~/report, parsed
    stop_seconds: float  # SIGINT -> exit
    returncode: int
    answered: str  # what the retune call got
    retuning: bool  # SIGINT came during the retune


def stream_to_node(stamps, poses, scans, rate: float, path_every: int, executor: str,
                   parameters: list[str]) -> NodeRun:
    """Launch a node, stream `scans` (CDR) at `rate` with a Path every `path_every`, retune, stop
    it with SIGINT; what it did."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_srvs.srv import Trigger

    from map_consistency_ros.core.geometry import se2
    from map_consistency_ros.io import messages
    from map_consistency_ros.ros.conversions import message_class

    count = len(scans)
    prefix = path_prefixes(stamps, poses)
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(1, 200)),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    launched = time.monotonic()
    node = subprocess.Popen([sys.executable, '-m', 'map_consistency_ros.ros.node', '--ros-args',
                             '--params-file', str(REPO / 'config' / 'map_consistency.yaml'),
                             '-p', f'executor:={executor}',
                             *(word for value in parameters for word in ('-p', value))],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.environ.update(env)
    observer = Observer()
    try:
        publisher_node = observer.node
        scan_pub = publisher_node.create_publisher(message_class(messages.SCAN_TYPE), 'scan',
                                                   QoSProfile(depth=1000,
                                                              reliability=ReliabilityPolicy
                                                              .BEST_EFFORT))
        path_pub = publisher_node.create_publisher(message_class(messages.PATH_TYPE),
                                                   'trajectory', 10)
        # a SLAM stack starts beside the node: streaming begins once the node says it is ready
        # (kernels loaded); its start-up is a figure of its own
        deadline = time.monotonic() + 120
        while (scan_pub.get_subscription_count() == 0 or path_pub.get_subscription_count() == 0
               or observer.status.get('ready') != 'yes') and time.monotonic() < deadline:
            time.sleep(0.05)
        start = time.monotonic()
        startup = start - launched
        ready = observer.status.get('ready') == 'yes'
        for k in range(count):
            due = start + k / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            scan_pub.publish(scans[k])
            if (k + 1) % path_every == 0 or k + 1 == count:
                path_pub.publish(prefix(k + 1))
        streamed = time.monotonic() - start
        # the node may be behind: let it catch up, within reason, until every scan is
        # registered or its queue is empty and its counts stood still for 2 s (scans it refused
        # or that wait for a pose are never registered)
        settle, last, still = time.monotonic() + 60, None, 0
        while time.monotonic() < settle:
            time.sleep(0.5)
            status = dict(observer.status)
            registered = int(status.get('keyframes', 0)) + int(status.get('folded scans', 0))
            if registered == count:
                break
            counts = (registered, status.get('queued scans'), status.get('buffered scans'))
            still = still + 1 if counts == last and status.get('queued scans') == '0' else 0
            if still >= 4:
                break
            last = counts
        time.sleep(1.5)  # a diagnostics period or so for the last figures
        waited = time.monotonic() - start - streamed
        rss = peak_rss_mib(node.pid)
        reports, status = list(observer.reports), dict(observer.status)
        # SIGINT during a retune of the map: odometry edges and one loop closure
        constraints = publisher_node.create_publisher(
            message_class(messages.CONSTRAINTS_TYPE), 'constraints', 10)
        information = [100.0, 0.0, 0.0, 100.0, 0.0, 400.0]
        rows = [[stamps[k], stamps[k + 1], *se2.relative(poses[k], poses[k + 1]), *information]
                for k in range(count - 1)]
        rows.append([stamps[0], stamps[count // 2],
                     *se2.relative(poses[0], poses[count // 2]), *information])
        constraints.publish(messages.constraints_message(message_class, np.array(rows)))
        time.sleep(1.0)
        retune = publisher_node.create_client(Trigger, '/map_consistency/retune_dcs')
        answer = retune.call_async(Trigger.Request())
        time.sleep(2.0)
        retuning = not answer.done()
        stop_start = time.monotonic()
        node.send_signal(signal.SIGINT)
        node.wait(timeout=20)
        stop_seconds = time.monotonic() - stop_start
        deadline = time.monotonic() + 5
        while not answer.done() and time.monotonic() < deadline:
            time.sleep(0.05)
        answered = answer.result().message if answer.done() else "no answer"
    finally:
        observer.close()
        if node.poll() is None:
            node.kill()
    return NodeRun(startup=startup, ready=ready, streamed=streamed, waited=waited, rss=rss,
                   status=status, reports=reports, stop_seconds=stop_seconds,
                   returncode=node.returncode, answered=answered, retuning=retuning)


def run(name: str, rate: float, path_every: int, limit: int | None, reference: bool,
        executor: str, parameters: list[str], spacing: float, repeat: int) -> None:
    from rclpy.serialization import serialize_message

    from map_consistency_ros.core.geometry import viewpoint_rows
    from map_consistency_ros.io import messages
    from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
    from map_consistency_ros.ros.conversions import message_class

    log = read_carmen_log(LOGS[name])
    model = sensor_model(log)
    count = log.scan_count if limit is None else min(limit, log.scan_count)
    order = np.argsort(log.timestamps[:count], kind='stable')  # a driver stamps in order
    if spacing > 0.0:  # the stream of a stack that keyframes every `spacing` metres
        order = order[viewpoint_rows(log.laser_poses[order], spacing, spacing)]
        count = order.size
    stamps, poses, ranges = (log.timestamps[order], log.laser_poses[order],
                             log.ranges[order])
    scans = [serialize_message(messages.scan_message(message_class, stamps[k], ranges[k], model))
             for k in range(count)]
    if reference:
        from map_consistency_ros.core.configuration import NodeSettings
        threads = next((int(value.split(':=')[1]) for value in parameters
                        if value.startswith('update_threads:=')), NodeSettings().update_threads)
    # each node run, then its paced reference: this machine's speed drifts over minutes, and
    # a ratio of figures taken minutes apart would measure the drift
    runs, paced = [], []
    for _ in range(repeat):
        runs.append(stream_to_node(stamps, poses, scans, rate, path_every, executor,
                                   parameters))
        if reference:
            paced.append(in_process(stamps, ranges, poses, model, path_every, threads, rate))

    sampling = f'keyframes every {spacing:g} m' if spacing > 0.0 else 'every scan a keyframe'
    print(f'\n{name} ({sampling}): {count} scans at {rate:g} scans/s, a Path every '
          f'{path_every} scans, executor {executor}'
          + ''.join(f', {value}' for value in parameters)
          + (f'; {repeat} node runs, their updates pooled' if repeat > 1 else ''))
    updates = []  # (latency ms, keyframes, timing) of every update of every run
    explanations = []  # (keyframes judged, seconds) of every explanation of every run
    run_buckets = []  # per run: the median latency of each map-size bucket
    run_medians = []  # per run: its median latency
    for number, node_run in enumerate(runs, 1):
        print(f'  run {number}' if repeat > 1 else '', end='\n' if repeat > 1 else '')
        reports = print_run(node_run, count)
        latency = np.array([r['update_latency_s'] for r in reports]) * 1e3
        sizes = np.array([r['scan_counts']['keyframes'] for r in reports])  # map size: viewpoints
        updates += [(ms, r['scan_counts']['keyframes'], r['timing'])
                    for ms, r in zip(latency, reports)]
        explanations += [(r['judged_keyframes'], r['timing']['explanation_s'])
                         for r in node_run.reports if 'explanation_s' in r['timing']]
        run_medians.append(np.median(latency) if latency.size else np.nan)  # nan: no update
        if latency.size:
            run_buckets.append([np.median(latency[inside])
                                for _, _, inside in map_size_buckets(sizes)])
    latency = np.array([ms for ms, _, _ in updates])
    if latency.size:
        print(f'  update latency (ms)                  median {np.median(latency):.1f}, '
              f'p99 {np.percentile(latency, 99):.1f}, max {latency.max():.1f} over '
              f'{latency.size} updates (target: median < 10, p99 < 50)'
              + ('' if repeat == 1 else
                 '; each run\'s median: ' + ', '.join(f'{ms:.1f}' for ms in run_medians)))
        sizes = np.array([size for _, size, _ in updates])
        timings = [timing for _, _, timing in updates]
        buckets = []
        print('  keyframes        updates  median  p99   | queued monitor snapshot markers '
              'publish (median ms) | second stage (median ms per explanation)')
        for low, high, inside in map_size_buckets(sizes):
            stage = {key: np.median([timing.get(key, 0.0) for timing, keep in
                                     zip(timings, inside) if keep]) * 1e3
                     for key in ('queued_s', 'monitor_s', 'snapshot_s', 'markers_s', 'publish_s')}
            explained = np.median([seconds for judged, seconds in explanations
                                   if low < judged <= high] or [np.nan]) * 1e3
            buckets.append(np.median(latency[inside]))
            print(f'  {int(low) + 1:>5}-{int(high):<5}  {inside.sum():>8}  '
                  f'{np.median(latency[inside]):6.1f} {np.percentile(latency[inside], 99):6.1f}'
                  f' | {stage["queued_s"]:6.1f} {stage["monitor_s"]:7.1f} '
                  f'{stage["snapshot_s"]:8.1f} {stage["markers_s"]:7.1f} '
                  f'{stage["publish_s"]:7.1f} | {explained:7.1f}')
        each_run = ('' if repeat == 1 else ' (each run: ' + ', '.join(
            f'{medians[-1] / medians[0]:.2f}' for medians in run_buckets) + ')')
        print(f'  last / first map-size bucket, median latency: '
              f'{buckets[-1] / buckets[0]:.2f}{each_run} (target <= 1.5: flat in map size)')
        if len(buckets) > 2:
            # the first bucket is a young map: its keyframes overlap fewer earlier ones than
            # the partner budget keeps later
            print(f'  last / second bucket {buckets[-1] / buckets[1]:.2f}, largest / smallest '
                  f'of the buckets after the first {max(buckets[1:]) / min(buckets[1:]):.2f}')
    if reference:
        alone = np.concatenate([seconds for seconds, _ in paced]) * 1e3
        alone_sizes = np.concatenate([sizes for _, sizes in paced])
        hot = in_process(stamps, ranges, poses, model, path_every, threads)[0] * 1e3
        alone_buckets = [np.median(alone[inside])
                         for _, _, inside in map_size_buckets(alone_sizes)]
        print(f'  reference: the same Path updates in-process, no ROS, the scans applied at '
              f'{rate:g} scans/s as streamed'
              + (f' ({repeat} runs pooled)' if repeat > 1 else '') +
              f': median {np.median(alone):.1f} ms, p99 '
              f'{np.percentile(alone, 99):.1f} ms ({path_every} keyframes each, kernels on '
              f'{threads or "every"} thread(s) as the node\'s updates'
              + ('' if repeat == 1 else '; each run\'s median: ' + ', '.join(
                  f'{np.median(seconds) * 1e3:.1f}' for seconds, _ in paced))
              + '); back to back, warm: '
              f'median {np.median(hot):.1f} ms, p99 {np.percentile(hot, 99):.1f} ms')
        print(f'  in-process (paced) last / first map-size bucket, median: '
              f'{alone_buckets[-1] / alone_buckets[0]:.2f}')
        if latency.size:
            pairs = ('' if repeat == 1 else ' (each run / its reference: ' + ', '.join(
                f'{node_median / (np.median(seconds) * 1e3):.2f}'
                for node_median, (seconds, _) in zip(run_medians, paced)) + ')')
            print(f'  node / in-process median latency: '
                  f'{np.median(latency) / np.median(alone):.2f}{pairs} (target <= 1.5); node / '
                  f'back to back {np.median(latency) / np.median(hot):.2f}')


def print_run(node_run: NodeRun, count: int) -> list[dict]:
    """Print what one node run did with `count` scans (start-up, losses, memory, stopping);
    its reports, one per update (the first of each)."""
    reports, status = node_run.reports, node_run.status
    # the newest update's report: the second stage publishes too, and may land last with the
    # counts of the older snapshot it judged
    newest = max(reports, key=lambda report: report['updates']) if reports else {}
    # the counts from /diagnostics, published every period: a report goes out only when the
    # map changed, and scans folded into a viewpoint at the end change no map
    from map_consistency_ros.ros.diagnostics import SCAN_KEYS
    counts = {key: int(status.get(key, 0)) for key in SCAN_KEYS.values()}
    keyframes, folded = counts['keyframes'], counts['folded scans']
    print(f'  node start-up (launch -> ready)      {node_run.startup:.2f} s'
          + ('' if node_run.ready else ' (NOT READY: streamed after the 120 s deadline)'))
    print(f'  keyframes registered / scans sent   {keyframes + folded} / {count} '
          f'({keyframes} viewpoints, {folded} folded into them; streamed in '
          f'{node_run.streamed:.1f} s)')
    print('  scans received                       ' + ', '.join(
        f'{key} {value}' for key, value in counts.items() if value))
    print(f'  never received                       lost by the middleware '
          f'{status.get("scans lost by the middleware")}, poses without scan '
          f'{status.get("poses without scan")}, missing from stamps '
          f'{status.get("scans missing from stamps")}')
    print(f'  still waiting in the node (behind)   {counts["waiting scans"]} scans after '
          f'{node_run.waited:.0f} s')
    # every scan received is in one category; the scans sent and never received show as
    # the middleware's losses or as poses without their scan
    received = counts['scans received']
    honest = (received == sum(counts.values()) - received
              and (received == count or int(status.get('poses without scan', 0))
                   + int(status.get('scans lost by the middleware', 0)) >= count - received))
    print(f'  every scan accounted for: {"yes" if honest else "NO"}')
    published = newest.get('updates', 0)
    # one report per update (its first): the second stage publishes too, with the figures of
    # the last update
    first_reports: dict[int, dict] = {}
    for report in reports:
        if report['updates']:
            first_reports.setdefault(report['updates'], report)
    # ~/report is latched with depth 1: a report replaced before it reached the observer is
    # missing here, its update not
    print(f'  updates reported / published         {len(first_reports)} / {published}')
    print(f'  node peak RSS                        {node_run.rss:.0f} MiB')
    state = 'during a retune' if node_run.retuning else 'after the retune'
    print(f'  SIGINT -> exit, {state:<20} {node_run.stop_seconds:.2f} s (exit code '
          f'{node_run.returncode}; the retune call got {node_run.answered!r})   (target < 1 s)')
    return list(first_reports.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--logs', nargs='+', default=['intel', 'fr079'], choices=sorted(LOGS))
    parser.add_argument('--rates', nargs='+', type=float, default=[100.0, 400.0])
    parser.add_argument('--path-every', type=int, default=10)
    parser.add_argument('--keyframe-spacing', type=float, default=0.0, metavar='METRES',
                        help="stream only keyframes this far apart (and as many radians), as a "
                             "stack that keyframes would; 0: every scan of the log")
    parser.add_argument('--repeat', type=int, default=1, metavar='N',
                        help='stream to N fresh nodes (and run the in-process reference N '
                             'times) and pool their updates: a keyframed stream has about 13 '
                             'updates per map-size bucket, too few for a stable median')
    parser.add_argument('--scans', type=int, default=None, help='only the first N scans')
    parser.add_argument('--no-reference', action='store_true',
                        help='skip the in-process reference (minutes on Freiburg 079)')
    parser.add_argument('--executors', nargs='+', default=['events'],
                        choices=['events', 'multi_threaded'],
                        help="the node's executor parameter; several: side by side")
    parser.add_argument('-p', '--parameter', action='append', default=[], metavar='NAME:=VALUE',
                        help='a node parameter over the YAML defaults, e.g. '
                             'explanation_period:=3600 for the first stage alone (repeatable)')
    args = parser.parse_args()
    os.environ.setdefault('ROS_LOG_DIR', '/tmp/bench_node_load_logs')
    for name in args.logs:
        for rate in args.rates:
            for executor in args.executors:
                run(name, rate, args.path_every, args.scans, not args.no_reference, executor,
                    args.parameter, args.keyframe_spacing, args.repeat)


if __name__ == '__main__':
    main()
