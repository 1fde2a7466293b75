"""The first run after an install against the second: `check` of the Intel log and the node's
start, each in fresh processes with a numba cache of their own.

    .venv/bin/python bench/bench_cold_start.py [--no-cold]

The install step is what `python3 bootstrap.py` does after pip: `map-consistency warm-up`
into an empty cache (NUMBA_CACHE_DIR). Then `check intel.gfs.log --quiet` twice (first and
second run) and the node started twice, each until it logs "kernels ready" (its start-up
warm-up: the wait before its first update). Targets: first / second <= 3 for both. For context
(--no-cold skips it): the same first runs into an empty cache without the warm-up, what a pip or
colcon install that never ran it pays once.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TREE = Path(__file__).resolve().parents[1]
INTEL = TREE.parent / 'shared' / 'data' / 'intel' / 'intel.gfs.log'
BIN = Path(sys.executable).parent
TARGET = 3.0


def _environment(cache: Path) -> dict:
    environment = dict(os.environ, NUMBA_CACHE_DIR=str(cache),
                       ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID='97')
    environment.pop('PYTHONDONTWRITEBYTECODE', None)
    return environment


def timed(command: list[str], cache: Path) -> float:
    """Wall seconds of a command run to its end (its exit code must be 0 or 1).

    Parameters
    ----------
    command: the command.
    cache: the numba cache folder it uses.

    Returns
    -------
    Seconds.
    """
    started = time.perf_counter()
    done = subprocess.run(command, env=_environment(cache), capture_output=True, text=True)
    if done.returncode not in (0, 1):
        raise RuntimeError(f'{command} exited {done.returncode}: {done.stderr[-500:]}')
    return time.perf_counter() - started


def node_ready(cache: Path, timeout: float = 600.0) -> float:
    """Wall seconds from starting the node to its "kernels ready" log line.

    Parameters
    ----------
    cache: the numba cache folder it uses.
    timeout: seconds to give up after.

    Returns
    -------
    Seconds; the node is stopped before returning.
    """
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as logs:
        environment = dict(_environment(cache), ROS_LOG_DIR=logs)
        process = subprocess.Popen([sys.executable, '-m', 'map_consistency_ros.ros.node'],
                                   env=environment, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + timeout
            for line in process.stdout:
                if 'kernels ready' in line:
                    return time.perf_counter() - started
                if time.monotonic() > deadline:
                    break
            raise RuntimeError('the node never said its kernels were ready')
        finally:
            process.terminate()
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--no-cold', action='store_true',
                        help='skip the runs into an empty cache without the warm-up')
    args = parser.parse_args()
    check = [str(BIN / 'map-consistency'), 'check', str(INTEL), '--quiet']
    with tempfile.TemporaryDirectory() as folder:
        cache = Path(folder) / 'warmed'
        warm = timed([str(BIN / 'map-consistency'), 'warm-up', '--quiet'], cache)
        first, second = timed(check, cache), timed(check, cache)
        node_first, node_second = node_ready(cache), node_ready(cache)
        print(f'install step (map-consistency warm-up into an empty cache): {warm:.1f} s')
        print(f'check intel.gfs.log: first {first:.2f} s, second {second:.2f} s: '
              f'first / second {first / second:.2f} (target <= {TARGET:g})')
        print(f'node start to kernels ready: first {node_first:.2f} s, second '
              f'{node_second:.2f} s: first / second {node_first / node_second:.2f} '
              f'(target <= {TARGET:g})')
        if not args.no_cold:
            cold = timed(check, Path(folder) / 'cold-check')
            cold_node = node_ready(Path(folder) / 'cold-node')
            print(f'without the warm-up (an empty cache): check first {cold:.1f} s '
                  f'({cold / second:.1f}x the second), node start {cold_node:.1f} s '
                  f'({cold_node / node_second:.1f}x)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
