"""The node as a process: parameter errors, unknown names, shutdown in every state.

Each test starts its own node process (what is tested is the process: its exit code, its
output, how it ends).
"""
from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path as FilePath

import numba
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_srvs.srv import Trigger

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.io import messages
from map_consistency_ros.io.carmen import read_carmen_log, sensor_model
from map_consistency_ros.ros.conversions import message_class

REPO = FilePath(__file__).resolve().parents[2]
SCANS = 80
TIMEOUT = 30.0


@pytest.fixture()
def ros_env(tmp_path, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 200)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path / 'ros_log'))
    return dict(os.environ)


def _python(ros_env, *arguments: str) -> subprocess.Popen:
    """A Python process in the repository, its output merged and piped."""
    return subprocess.Popen([sys.executable, *arguments], cwd=REPO, env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _node(ros_env, *arguments: str) -> subprocess.Popen:
    """The node; every keyframe is a viewpoint, so that counts of scans sent are counts of
    keyframes tested."""
    return _python(ros_env, '-m', 'map_consistency_ros.ros.node', '--ros-args',
                   '-p', 'viewpoint_spacing:=0.0', *arguments)


def _params(tmp_path, text: str) -> str:
    path = tmp_path / 'params.yaml'
    path.write_text('/**:\n  ros__parameters:\n' + text)
    return str(path)


@pytest.mark.parametrize('text, expected', [
    ('    alpha: "0.01"\n', "alpha: expected a float, got a string '0.01'"),
    ('    min_points: 2.5\n', 'min_points: expected an integer, got a float 2.5'),
    ('    alpha: 0.7\n', 'alpha: 0.7 is outside [1e-300, 0.5]'),
    ('    pose_source: tf\n', "pose_source: 'tf' is not one of path"),
    ('    executor: fast\n', "executor: 'fast' is not one of events"),
    ('    update_threads: -1\n', 'update_threads: -1 is outside [0, 1024]'),
])
def test_a_bad_parameter_ends_the_node_with_one_line(ros_env, tmp_path, text, expected):
    process = _node(ros_env, '--params-file', _params(tmp_path, text))
    try:
        output, _ = process.communicate(timeout=60)
    finally:
        _cleanup(process)
    assert process.returncode == 2
    assert output.strip().count('\n') == 0 and 'Traceback' not in output
    assert expected in output and output.startswith('map_consistency: bad parameter:')


def _wait_for_line(process: subprocess.Popen, words: str) -> list[str]:
    lines = []
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        lines.append(line)
        if words in line:
            return lines
    raise AssertionError(f'no line with {words!r} in {lines}')


def _until(condition: Callable[[], object], seconds: float = TIMEOUT,
           step: Callable[[], None] | None = None) -> None:
    """Poll `condition` until it holds or `seconds` pass, calling `step` between polls; the
    caller asserts what it expects afterwards."""
    deadline = time.monotonic() + seconds
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.05)
        if step is not None:
            step()


def _matched(*publishers) -> None:
    """Wait until every publisher reaches a subscriber: a message published before discovery
    matched the two ends is lost, and a test that counts what the node took would count it."""
    _until(lambda: all(publisher.get_subscription_count() for publisher in publishers))
    assert all(publisher.get_subscription_count() for publisher in publishers), \
        'the node never subscribed'


def _stop(process: subprocess.Popen) -> tuple[float, str]:
    """SIGINT; seconds until the process ended and the rest of its output."""
    start = time.monotonic()
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=20)
    return time.monotonic() - start, output


def _cleanup(process: subprocess.Popen, client: Client | None = None) -> None:
    """The end of every test, whatever it asserted: the client closed, the node stopped
    (killed when still running: a failed assertion skipped its SIGINT) and reaped."""
    try:
        if client is not None:
            client.close()
    finally:
        if process.poll() is None:
            process.kill()
        process.wait(timeout=20)
        if process.stdout is not None:
            process.stdout.close()


def test_integers_for_floats_and_a_warning_for_unknown_names(ros_env, tmp_path):
    process = _node(ros_env, '--params-file',
                    _params(tmp_path, '    max_range: 8\n    alpah: 0.02\n'),
                    '-p', 'stale_timout:=3.0')
    try:
        lines = _wait_for_line(process, "unknown parameter 'stale_timout' ignored; "
                                        'did you mean stale_timeout?')
        assert any("unknown parameter 'alpah' ignored; did you mean alpha?" in line
                   for line in lines)
        _, output = _stop(process)
    finally:
        _cleanup(process)
    assert process.returncode == 0 and 'Traceback' not in output


class Client:
    """A test-side node spinning in a thread."""

    def __init__(self) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node('client', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def statuses(self) -> list:
        """Every DiagnosticStatus on /diagnostics from now on (a list that grows)."""
        from diagnostic_msgs.msg import DiagnosticArray
        received: list = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      lambda msg: received.extend(msg.status), 10)
        return received

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
        self.thread.join(timeout=5)


def _thread_niceness(pid: int) -> list[int]:
    """The nice value of every thread of a process (Linux: field 19 of /proc/PID/task/T/stat)."""
    values = []
    for stat in FilePath(f'/proc/{pid}/task').glob('*/stat'):
        fields = stat.read_text().rsplit(')', 1)[1].split()  # after the thread's name
        values.append(int(fields[16]))
    return values


def _on_a_thread(setup: Callable[[], None]) -> dict[str, int]:
    """Run `setup` on a new thread: the kernel threads and the niceness it leaves there."""
    seen = {}

    def run() -> None:
        setup()
        seen['threads'] = numba.get_num_threads()
        seen['nice'] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    return seen


def test_the_second_stage_thread_yields_its_priority_and_the_cores():
    """_yield_to_updates lowers only its own thread: the worker keeps its priority and every
    core for its kernels."""
    from map_consistency_ros.ros.engine import (EXPLAINER_NICENESS, EXPLAINER_THREADS,
                                                _yield_to_updates)
    before = (numba.get_num_threads(), os.getpriority(os.PRIO_PROCESS, 0))
    seen = _on_a_thread(_yield_to_updates)
    assert seen == {'threads': EXPLAINER_THREADS, 'nice': EXPLAINER_NICENESS}
    assert (numba.get_num_threads(), os.getpriority(os.PRIO_PROCESS, 0)) == before


@pytest.mark.parametrize('requested, expected', [(1, 1), (0, 'all'), (10_000, 'all')])
def test_the_update_thread_runs_its_kernels_on_the_threads_asked(requested, expected):
    """update_threads on the worker's thread alone (0 or too many: every core numba has)."""
    from map_consistency_ros.ros.engine import _run_kernels_on
    before = numba.get_num_threads()
    seen = _on_a_thread(lambda: _run_kernels_on(requested))
    everything = numba.config.NUMBA_NUM_THREADS
    assert seen['threads'] == (everything if expected == 'all' else expected)
    assert numba.get_num_threads() == before


def test_sigint_when_idle_ends_cleanly(ros_env):
    from map_consistency_ros.ros.engine import EXPLAINER_NICENESS
    process, client = _node(ros_env), None
    try:
        client = Client()
        check = client.node.create_client(Trigger, '/map_consistency/check')
        assert check.wait_for_service(timeout_sec=TIMEOUT)
        # the second stage yields the cores to the updates; everything else keeps the
        # priority the node inherited from this process (the suite may run under `nice`)
        inherited = os.getpriority(os.PRIO_PROCESS, 0)
        niceness = _thread_niceness(process.pid)
        assert sorted(niceness) == [inherited] * (len(niceness) - 1) + [
            max(inherited, EXPLAINER_NICENESS)], (inherited, niceness)
        seconds, output = _stop(process)
    finally:
        _cleanup(process, client)
    assert process.returncode == 0 and 'Traceback' not in output
    assert seconds < 10.0, output  # bench/bench_node_load.py measures it


def test_sigint_during_a_retune_answers_the_caller_and_ends_cleanly(ros_env, shared_data):
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    model = sensor_model(log)
    # a search that is long by construction: every grid point is solved and every pair is
    # measured again on each map (no reuse, no early stop), so a fast machine cannot finish it
    process = _node(ros_env, '-p', 'grid_steps:=10000', '-p', 'reuse_tolerance:=0.0',
                    '-p', 'flat_tolerance:=0.0', '-p', 'tolerance:=1e-12')
    client = None
    try:
        client = Client()
        node = client.node
        scan = node.create_publisher(message_class(messages.SCAN_TYPE), 'scan', 100)
        path = node.create_publisher(message_class(messages.PATH_TYPE), 'trajectory', 10)
        constraints = node.create_publisher(message_class(messages.CONSTRAINTS_TYPE),
                                            'constraints', 10)
        retune = node.create_client(Trigger, '/map_consistency/retune_dcs')
        assert retune.wait_for_service(timeout_sec=TIMEOUT)
        _matched(scan, path, constraints)
        stamps, poses = log.timestamps[:SCANS], log.laser_poses[:SCANS]
        for index in range(SCANS):
            scan.publish(messages.scan_message(message_class, stamps[index], log.ranges[index],
                                               model))
            time.sleep(0.004)
        path.publish(messages.path_message(message_class, stamps, poses, 'map'))
        information = [100.0, 0.0, 0.0, 100.0, 0.0, 400.0]
        rows = [[stamps[k], stamps[k + 1], *se2.relative(poses[k], poses[k + 1]), *information]
                for k in range(SCANS - 1)]
        rows.append([stamps[10], stamps[70], *se2.relative(poses[10], poses[70]), *information])
        constraints.publish(messages.constraints_message(message_class, np.array(rows)))
        time.sleep(1.0)  # the worker takes the graph
        future = retune.call_async(Trigger.Request())
        time.sleep(1.0)  # into the search
        assert not future.done(), f'the retune ended before the signal: {future.result()}'
        seconds, output = _stop(process)
        _until(future.done, 5.0)
        assert future.done(), 'the pending retune was never answered'
        response = future.result()
    finally:
        _cleanup(process, client)
    assert not response.success and response.message == 'the node is shutting down'
    assert process.returncode == 0 and 'Traceback' not in output
    assert seconds < 10.0, output  # bench/bench_node_load.py measures it


# the node's own entry point, with kernels that fail to load (a broken numba cache or
# compiler, say); nothing else differs
_FAILING_WARM_UP = """
import sys
from map_consistency_ros.ros import engine, node
def broken():
    raise OSError('kernel cache unreadable')
engine.warm_up = broken
sys.exit(node.main(['map_consistency', '--ros-args', '-p', 'diagnostics_period:=0.2']))
"""


def test_kernels_that_fail_to_load_are_reported_and_services_answer(ros_env, shared_data):
    """The node stays up and says why it monitors nothing; services fail at once."""
    from diagnostic_msgs.msg import DiagnosticStatus
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    process = _python(ros_env, '-c', _FAILING_WARM_UP)
    client = None
    try:
        client = Client()
        node, statuses = client.node, client.statuses()
        scan = node.create_publisher(message_class(messages.SCAN_TYPE), 'scan', 10)
        check = node.create_client(Trigger, '/map_consistency/check')
        assert check.wait_for_service(timeout_sec=TIMEOUT)
        _matched(scan)
        sent = []

        def queued() -> int:
            words = statuses[-1].message.split('; ')[-1].split() if statuses else []
            return int(words[0]) if words and words[0].isdigit() else 0

        def send() -> None:  # the node's scans are best effort: one may be lost while the
            if queued() < 3 and len(sent) < 100:  # two ends of discovery still match
                index = len(sent)
                scan.publish(messages.scan_message(message_class, float(log.timestamps[index]),
                                                   log.ranges[index], sensor_model(log)))
                sent.append(index)

        _until(lambda: queued() >= 3, step=send)
        status = statuses[-1]
        assert status.level == DiagnosticStatus.ERROR
        assert 3 <= queued() <= len(sent), (status.message, len(sent))
        assert status.message == ('not monitoring: loading the compiled kernels failed '
                                  f'(OSError: kernel cache unreadable); {queued()} scans '
                                  'queued unprocessed'), status.message
        assert {kv.key: kv.value for kv in status.values}['ready'] == 'failed'
        start = time.monotonic()
        answer = check.call_async(Trigger.Request())
        _until(answer.done)
        assert answer.done(), 'the check was never answered'
        assert answer.result().success is False
        assert answer.result().message == ('not monitoring: loading the compiled kernels '
                                           'failed (OSError: kernel cache unreadable)')
        assert time.monotonic() - start < 5.0  # not the 60 s service timeout
        _, output = _stop(process)
        assert process.returncode == 0
        assert 'not monitoring: loading the compiled kernels failed' in output
        assert 'Traceback' not in output
    finally:
        _cleanup(process, client)


def _send_intel_map(node: Node, statuses: list, shared_data) -> None:
    """Once the node publishes diagnostics: the first SCANS Intel scans, then their Path."""
    from nav_msgs.msg import Path
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    model = sensor_model(log)
    scan = node.create_publisher(message_class(messages.SCAN_TYPE), 'scan', 100)
    trajectory = node.create_publisher(Path, 'trajectory', 10)
    _until(lambda: statuses)
    _matched(scan, trajectory)
    for index in range(SCANS):
        scan.publish(messages.scan_message(message_class, float(log.timestamps[index]),
                                           log.ranges[index], model))
        time.sleep(0.004)
    trajectory.publish(messages.path_message(message_class, log.timestamps[:SCANS],
                                             log.laser_poses[:SCANS], 'map'))


# the end of the scripts below: the node's own entry point, diagnostics every 0.2 s and no
# staleness while a test feeds it
_NODE_MAIN = """
sys.exit(node.main(['map_consistency', '--ros-args', '-p', 'diagnostics_period:=0.2',
                    '-p', 'stale_timeout:=60.0', '-p', 'viewpoint_spacing:=0.0']))
"""

# the node's own entry point, with a second stage whose first and third explanations run out
# of memory (the node's pipeline only: the warm-up's explains as it should)
_FAILING_TWICE = """
import sys
from map_consistency_ros.core.live import LivePipeline
from map_consistency_ros.ros import node
calls = []
class FailingTwice(LivePipeline):
    def explain(self, snapshot):
        calls.append(1)
        if len(calls) in (1, 3):
            raise MemoryError('injected')
        return super().explain(snapshot)
node.LivePipeline = FailingTwice
""" + _NODE_MAIN


def test_a_failed_explanation_is_shown_until_the_next_one_succeeds(ros_env, shared_data):
    """The node says it has no verdict and why, logs it once, and tries again a period later
    (it used to say 'no keyframe yet' and publish nothing); ~/check says it failed."""
    from diagnostic_msgs.msg import DiagnosticStatus
    process = _python(ros_env, '-c', _FAILING_TWICE)
    client = None
    try:
        client = Client()
        node, statuses = client.node, client.statuses()
        _send_intel_map(node, statuses, shared_data)
        failed = re.compile(r'no verdict yet \((\d+) scans\); explanation failed: '
                            r'MemoryError: injected')
        # the failure shows until the retry a period later: on a busy machine the retry's
        # status may already be the newest when this looks, and the failed explanation may
        # have judged the map before its last scans came
        _until(lambda: any(failed.fullmatch(status.message) for status in statuses))
        shown = [status for status in statuses if failed.fullmatch(status.message)]
        assert shown and shown[0].level == DiagnosticStatus.WARN
        values = {kv.key: kv.value for kv in shown[0].values}
        assert values['second stage failure'] == 'explanation failed: MemoryError: injected'
        _until(lambda: statuses[-1].message.startswith('map '))
        assert statuses[-1].message.startswith('map CONSISTENT'), statuses[-1].message
        assert statuses[-1].level == DiagnosticStatus.OK
        assert {kv.key: kv.value for kv in statuses[-1].values}['second stage failure'] == 'none'
        check = node.create_client(Trigger, '/map_consistency/check')
        assert check.wait_for_service(timeout_sec=TIMEOUT)
        answer = check.call_async(Trigger.Request())
        _until(answer.done)
        assert answer.done(), 'the check was never answered'
        assert answer.result().success is False
        assert answer.result().message == 'no verdict: explanation failed: MemoryError: injected'
        _, output = _stop(process)
        assert process.returncode == 0 and 'Traceback' not in output
        assert output.count('explanation failed: MemoryError: injected') == 2, output
    finally:
        _cleanup(process, client)


# the node's own entry point, printing how many threads the monitor's pair measuring gets, at
# most, in first-stage updates and in ~/check (the kernel runs on no more)
_COUNTING_THREADS = """
import sys
import numba
from map_consistency_ros.core.live import monitor
from map_consistency_ros.ros import node
real_measures, real_recompute = monitor.measure_pairs, monitor.ConsistencyMonitor.recompute
most, job = {}, []
def measure_pairs(*args, **kwargs):
    caller = 'check' if job else 'update'
    if numba.get_num_threads() > most.get(caller, 0):
        most[caller] = numba.get_num_threads()
        print(f'kernel threads in {caller}: {most[caller]}', flush=True)
    return real_measures(*args, **kwargs)
def recompute(self):
    job.append(1)
    try:
        return real_recompute(self)
    finally:
        job.pop()
monitor.measure_pairs, monitor.ConsistencyMonitor.recompute = measure_pairs, recompute
""" + _NODE_MAIN


def test_updates_run_the_kernels_on_update_threads_and_a_check_on_every_core(ros_env,
                                                                             shared_data):
    """update_threads (1) from the warm-up on; a service job gets every core for its caller."""
    process = _python(ros_env, '-c', _COUNTING_THREADS)
    client = None
    try:
        client = Client()
        node, statuses = client.node, client.statuses()
        _send_intel_map(node, statuses, shared_data)
        _until(lambda: statuses[-1].message.startswith('map '))
        check = node.create_client(Trigger, '/map_consistency/check')
        assert check.wait_for_service(timeout_sec=TIMEOUT)
        answer = check.call_async(Trigger.Request())
        _until(answer.done)
        assert answer.done() and answer.result().success, 'the check failed'
        _, output = _stop(process)
    finally:
        _cleanup(process, client)
    assert 'kernel threads in update: 1' in output, output
    assert 'kernel threads in update: 2' not in output, output
    assert f'kernel threads in check: {numba.config.NUMBA_NUM_THREADS}' in output, output


def test_staleness_is_measured_on_the_node_clock(ros_env, shared_data):
    """With use_sim_time, a paused bag (a /clock that stops) is not stale input."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from rosgraph_msgs.msg import Clock
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    process = _node(ros_env, '-p', 'use_sim_time:=true', '-p', 'stale_timeout:=1.0',
                    '-p', 'diagnostics_period:=0.2')
    client = None
    try:
        client = Client()
        node, statuses = client.node, client.statuses()
        clock = node.create_publisher(Clock, '/clock', 10)
        scan = node.create_publisher(message_class(messages.SCAN_TYPE), 'scan', 10)
        _until(lambda: statuses)
        _matched(clock, scan)

        def tick(seconds: float) -> None:
            clock.publish(Clock(clock=messages.time_message(message_class, seconds)))

        for _ in range(10):  # the node's clock subscription matches at its own pace
            tick(100.0)
            time.sleep(0.1)
        scan.publish(messages.scan_message(message_class, 100.0, log.ranges[0],
                                           sensor_model(log)))
        time.sleep(2.5)  # wall time passes, the bag is paused
        assert statuses[-1].level != DiagnosticStatus.STALE, statuses[-1].message
        tick(103.0)  # the bag plays on without input
        _until(lambda: statuses[-1].level == DiagnosticStatus.STALE,
               step=lambda: tick(103.0))
        assert statuses[-1].message == 'no input for 3.0 s (stale after 1 s)'
        _stop(process)
    finally:
        _cleanup(process, client)
