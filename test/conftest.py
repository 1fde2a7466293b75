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


def write_graph_bag(path, stream, messages_until=None):
    """The stream's messages as a bag recorded beside slam_toolbox (log time = publication)."""
    import numpy as np

    from map_consistency_ros.io.bags import BagTopics, BagWriter

    with BagWriter(path, topics=BagTopics(poses='/slam_toolbox/new_node_event')) as writer:
        for time, kind, payload in stream.messages[:messages_until]:
            if kind == 'scan':
                writer.write_scan(time, float(stream.stamps[payload]), stream.ranges[payload],
                                  stream.model)
            elif kind == 'node':
                writer.write_new_node_event(time, payload, float(stream.stamps[payload]),
                                            stream.poses[payload])
            elif kind == 'loop_closure':
                writer.write_loop_closure_event(time, payload)
            else:
                stamp, ids, poses = payload
                writer.write_pose_graph(time, stamp, ids, poses,
                                        edges=np.column_stack([ids[:-1], ids[1:]]))
    return path


def pose_graph_stream(stream, first_seen, final):
    """What slam_toolbox with its pose-graph interface (pull request 818) publishes while
    mapping the scans of `stream` (slam_toolbox_stream), in publication order.

    Every scan becomes node `index` with a NewNodeEvent (its scan's stamp, its pose then:
    `first_seen` before the loop closure at scan stream.loop, `final` from it on); the loop
    closure sends a LoopClosureEvent before that scan's node event (slam_toolbox fires it
    inside the mapper, before publishing the node); the PoseGraph it requests comes at the
    next tick of the visualisation loop, after scan GRAPH_AFTER, holding nodes 0..GRAPH_AFTER at
    their `final` poses, headings included. Returns a namespace: the stream's stamps, ranges,
    model, poses (every node event's pose), final, and messages [(log time, kind, payload)]
    with kind 'scan' (index), 'node' (index), 'loop_closure' (stamp) or 'graph' ((stamp, ids,
    poses)).
    """
    from types import SimpleNamespace

    import numpy as np

    count, loop = len(stream.stamps), stream.loop
    graph_after = loop + 4
    poses = np.where((np.arange(count) >= loop)[:, None], final, first_seen)
    messages = []
    for index in range(count):
        stamp = float(stream.stamps[index])
        messages.append((stamp, 'scan', index))
        if index == loop:
            messages.append((stamp + 1e-4, 'loop_closure', stamp + 1e-4))
        messages.append((stamp + 2e-4, 'node', index))
        if index == graph_after:
            ids = np.arange(graph_after + 1)
            messages.append((stamp + 3e-4, 'graph', (stamp + 3e-4, ids,
                                                     final[:graph_after + 1].copy())))
    return SimpleNamespace(stamps=stream.stamps, ranges=stream.ranges, model=stream.model,
                           poses=poses, final=final, loop=loop, graph_after=graph_after,
                           messages=messages)


@pytest.fixture(scope='session')
def slam_toolbox_graph_stream(slam_toolbox_stream):
    """pose_graph_stream of slam_toolbox_stream's wrong loop closure: nodes PIVOT.. move
    rigidly (0.1 rad and a shift), the map turns inconsistent."""
    stream = slam_toolbox_stream
    return pose_graph_stream(stream, stream.truth, stream.final)


@pytest.fixture(scope='session')
def rotated_graph_stream(slam_toolbox_stream):
    """pose_graph_stream of a loop closure that turns the whole graph by 0.3 rad about its
    first node and shifts it (every node moves, every heading changes): node events before it
    carry the poses before, the graph and later events the turned ones."""
    import numpy as np

    from map_consistency_ros.core.geometry import se2

    stream = slam_toolbox_stream
    motion = np.array([0.4, -0.7, 0.3])
    turned = se2.compose(se2.compose(stream.truth[0], motion),
                         se2.relative(stream.truth[0], stream.truth))
    return pose_graph_stream(stream, stream.truth, turned)
