"""Shared fixtures: the real datasets in ../shared/data beside the repository."""
import json
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


@pytest.fixture(scope='session')
def shared_data() -> Path:
    """Folder of the real datasets; CI clones the repo with ../shared beside it."""
    if not SHARED_DATA.is_dir():
        raise FileNotFoundError(f'real datasets not found at {SHARED_DATA}')
    return SHARED_DATA


def reject_constant(name: str):
    """parse_constant of a strict JSON parser: NaN, Infinity and -Infinity are not JSON (jq,
    JavaScript and Go reject a report holding one)."""
    raise ValueError(f'{name} is not JSON')


@pytest.fixture(scope='session')
def strict_json():
    """json.loads as strict as the parsers a report's readers use."""
    return lambda text: json.loads(text, parse_constant=reject_constant)


def rectangle_room_ranges(poses, beams=180, fov=3.141592653589793, width=8.0, height=5.0,
                          noise=0.01, seed=0):
    """Ranges a noisy 180-degree scanner reads in an empty width x height room (CARMEN angles)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    angles = -fov / 2 + np.arange(beams) * fov / beams
    ranges = np.empty((len(poses), beams))
    for row, (x, y, theta) in enumerate(poses):
        c, s = np.cos(theta + angles), np.sin(theta + angles)
        with np.errstate(divide='ignore'):
            tx = np.where(c > 0, (width - x) / c, np.where(c < 0, -x / c, np.inf))
            ty = np.where(s > 0, (height - y) / s, np.where(s < 0, -y / s, np.inf))
        ranges[row] = np.minimum(tx, ty) + rng.normal(0.0, noise, beams)
    return ranges


def write_flaser(path, ranges, poses, period=0.2, decimals=4):
    """A CARMEN log of FLASER lines: `ranges` (N, K) at `poses` (N, 3), scans `period` s
    apart, ranges with `decimals` decimals."""
    lines = []
    for index, (scan, pose) in enumerate(zip(ranges, poses)):
        values = ' '.join(f'{r:.{decimals}f}' for r in scan)
        pose_text = ' '.join(f'{v:.6f}' for v in pose)
        lines.append(f'FLASER {scan.size} {values} {pose_text} {pose_text} '
                     f'{index * period:.3f} host {index * period:.3f}\n')
    path.write_text(''.join(lines))


@pytest.fixture
def flaser_log():
    """`write(path, ranges, poses, period=0.2, decimals=4)`: a CARMEN log of FLASER lines."""
    return write_flaser


@pytest.fixture
def room_log(tmp_path):
    """Write a CARMEN log of 40 scans in a rectangular room; returns (path, poses, ranges)."""
    import numpy as np

    def write(poses=None, name='room.log'):
        if poses is None:
            t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
            poses = np.stack([4 + 2 * np.cos(t), 2.5 + 1.2 * np.sin(t), t + np.pi / 2], axis=1)
        ranges = rectangle_room_ranges(poses)
        path = tmp_path / name
        write_flaser(path, ranges, poses)
        return path, poses, ranges

    return write


@pytest.fixture
def displaced_room_log(room_log):
    """`write(name='displaced.log')`: one and a half laps of the room with the logged poses of
    the second half 0.4 m off, as if SLAM had put them there; one misaligned region (the
    second half revisits the first, so the second stage registers the displaced stretch
    against what it revisits). Returns the log's path."""
    import numpy as np

    def write(name='displaced.log'):
        t = np.linspace(0, 3 * np.pi, 60, endpoint=False)
        poses = np.stack([4 + 2 * np.cos(t), 2.5 + 1.2 * np.sin(t), t + np.pi / 2], axis=1)
        path, _, _ = room_log(poses, name=name)
        lines = []
        for index, line in enumerate(path.read_text().splitlines()):
            tokens = line.split()
            if index >= 30:
                for slot in (182, 185):
                    tokens[slot] = f'{float(tokens[slot]) + 0.4:.6f}'
            lines.append(' '.join(tokens))
        path.write_text('\n'.join(lines) + '\n')
        return path

    return write


def stop_process(process, timeout=10):
    """Terminate `process`, kill it when it has not ended within `timeout` seconds."""
    import subprocess
    process.terminate()
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=timeout)


@pytest.fixture
def process_stopper():
    """`stop(process, timeout=10)`: terminate a process, kill it when it does not end."""
    return stop_process


@pytest.fixture(scope='session')
def slam_toolbox_stream(shared_data):
    """What slam_toolbox publishes while mapping the first 120 real Intel scans.

    Every scan is accepted (vertex id = its index). Scan LOOP triggers a wrong loop closure:
    it moves vertices PIVOT.. rigidly (0.1 rad and a shift about vertex PIVOT), its own `pose`
    and every later one carry the moved poses, and the graph markers every 10 scans show the
    moved positions from then on. Returns a namespace: stamps (N,), ranges (N, K), model,
    poses (N, 3) (the `pose` message of each scan), snapshots [(index of the scan after which
    it is published, ids (V,), positions (V, 2))], final (N, 3) (the graph's final poses,
    headings included, which the markers do not carry), truth (N, 3) (the poses before the
    loop closure), loop.
    """
    from types import SimpleNamespace

    import numpy as np

    from map_consistency_ros.core.geometry import se2
    from map_consistency_ros.io.carmen import read_carmen_log, sensor_model

    scans, pivot, loop, every = 120, 40, 85, 10
    log = read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    order = np.argsort(log.timestamps[:scans], kind='stable')
    truth = log.laser_poses[:scans][order]
    moved = truth.copy()
    moved[pivot:] = se2.compose(se2.compose(truth[pivot], np.array([0.05, -0.03, 0.1])),
                                se2.relative(truth[pivot], truth[pivot:]))
    poses = np.where((np.arange(scans) >= loop)[:, None], moved, truth)
    snapshots = []
    for index in range(every - 1, scans, every):
        graph = moved if index >= loop else truth
        snapshots.append((index, np.arange(index + 1), graph[:index + 1, :2].copy()))
    return SimpleNamespace(stamps=log.timestamps[:scans][order], ranges=log.ranges[:scans][order],
                           model=sensor_model(log), poses=poses, snapshots=snapshots,
                           final=moved, truth=truth, loop=loop)
