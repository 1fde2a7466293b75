"""Damaged real inputs through the real command line: whatever the damage, the contract holds.

Real files (the Intel log cut to its first scans, the Freiburg 079 gzip log, a g2o graph of
Intel scans, a bag converted from the Intel log, the bundled demo bag) are damaged in many
ways by a seeded generator (truncation, garbage bytes, implausible numbers, missing fields,
wrong beam counts, shuffled or repeated lines, empty or binary files, cut gzip streams,
malformed metadata.yaml) and given to `check`, `convert`, `replay` and `tune`. The contract on
every variant: exit code 0, 1, 2 or 4 (never 3, never a traceback or a numpy warning); on
exit 2 exactly one line on stderr naming the input; no output (report, table, figure, bag) and
no staging folder left behind by a failure; any report written is strict JSON.
"""
from __future__ import annotations

import gzip
import math
import random
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from map_consistency_ros.cli.main import main

SCANS = 150  # Intel scans in the damaged logs
GRAPH_SCANS = 40  # vertices of the damaged graph
BAG_SCANS = 80  # scans in the damaged bag
DEMO_BAG = Path(__file__).resolve().parents[2] / 'map_consistency_ros' / 'data' / 'intel_demo.mcap'
TUNE_FAST = ['--grid-steps', '3', '--tolerance', '2', '--iterations', '20']
ALLOWED_CODES = {0, 1, 2, 4}  # 4: nothing to judge

# Field values that are no plausible number, and values that are no number at all
IMPLAUSIBLE = ('nan', 'NaN', 'inf', '-inf', '1e300', '-1e300', '1e200', '3e6', '-7e8')
MALFORMED = ('abc', '', '1.2.3', '0x10', '--1', '1e', 'None')


# -- the real sources -----------------------------------------------------------------------

@pytest.fixture(scope='module')
def sources(shared_data, tmp_path_factory):
    """The undamaged inputs: Intel's first SCANS scans, a graph of its first GRAPH_SCANS
    scans with laser lines, a bag of its first BAG_SCANS scans, and Freiburg 079's gzip log."""
    folder = tmp_path_factory.mktemp('sources')
    lines = (shared_data / 'intel' / 'intel.gfs.log').read_text().splitlines(keepends=True)
    flaser = [index for index, line in enumerate(lines) if line.startswith('FLASER')]
    log = folder / 'intel.log'
    log.write_text(''.join(lines[:flaser[SCANS - 1] + 1]))
    graph = folder / 'intel.g2o'
    _write_graph(graph, log)
    bag = folder / 'intel_bag'
    assert main(['convert', str(log), str(bag), '--quiet', '--limit', str(BAG_SCANS)]) == 0
    return {'log': log, 'graph': graph, 'bag': bag,
            'gzip': shared_data / 'fr079' / 'freiburg-079-corrected.log.gz'}


def _write_graph(path: Path, log_path: Path) -> None:
    """A g2o graph of the log's first scans: odometry edges, two loop closures, laser lines."""
    from map_consistency_ros.core.backend import PoseGraph
    from map_consistency_ros.core.geometry import se2
    from map_consistency_ros.io import carmen, g2o
    log = carmen.read_carmen_log(log_path)
    count = GRAPH_SCANS
    poses = log.laser_poses[:count]
    first = [*range(count - 1), 3, 0]
    second = [*range(1, count), 30, 35]
    graph = PoseGraph(poses=poses, edge_from=first, edge_to=second,
                      measurements=se2.relative(poses[first], poses[second]),
                      information=np.tile(np.diag([100.0, 100.0, 400.0]), (len(first), 1, 1)))
    laser = carmen.CarmenLog(
        path='', ranges=log.ranges[:count], laser_poses=poses, robot_poses=poses,
        timestamps=log.timestamps[:count], line_numbers=log.line_numbers[:count],
        stated_angles=carmen.LaserAngles(start_angle=-math.pi / 2, fov=math.pi,
                                         resolution=math.pi / 179, max_range=50.0),
        parameters={})
    g2o.write_g2o(path, g2o.G2oGraph(graph=graph, vertex_ids=np.arange(count), laser=laser,
                                     laser_vertices=np.arange(count)))


# -- damage ---------------------------------------------------------------------------------

def _lines(data: bytes) -> list[bytes]:
    return data.splitlines(keepends=True)


def _record_lines(lines: list[bytes], tags: tuple[bytes, ...]) -> list[int]:
    return [index for index, line in enumerate(lines) if line.split()[:1] and
            line.split()[0] in tags]


def _set_field(rng: random.Random, data: bytes, tags: tuple[bytes, ...], values) -> bytes:
    """One field of a random record of `tags` replaced by a random one of `values`."""
    lines = _lines(data)
    index = rng.choice(_record_lines(lines, tags))
    tokens = lines[index].split()
    tokens[rng.randrange(1, len(tokens))] = rng.choice(values).encode()
    lines[index] = b' '.join(tokens) + b'\n'
    return b''.join(lines)


def _laser_field(rng: random.Random, data: bytes, tag: bytes) -> bytes:
    """A pose value, heading, timestamp or range of a random laser record made implausible."""
    lines = _lines(data)
    index = rng.choice(_record_lines(lines, (tag,)))
    tokens = lines[index].split()
    beams_at = 1 if tag == b'FLASER' else 8
    beams = int(tokens[beams_at])
    if tag == b'FLASER':
        fields = [2 + rng.randrange(beams), *range(2 + beams, 8 + beams), len(tokens) - 1]
    else:
        fields = [9 + rng.randrange(beams), *range(10 + beams, 16 + beams), len(tokens) - 1]
    tokens[rng.choice(fields)] = rng.choice(IMPLAUSIBLE).encode()
    lines[index] = b' '.join(tokens) + b'\n'
    return b''.join(lines)


def _drop_fields(rng: random.Random, data: bytes, tags: tuple[bytes, ...]) -> bytes:
    lines = _lines(data)
    index = rng.choice(_record_lines(lines, tags))
    tokens = lines[index].split()
    for _ in range(rng.randint(1, 5)):
        if len(tokens) > 1:
            del tokens[rng.randrange(1, len(tokens))]
    lines[index] = b' '.join(tokens) + b'\n'
    return b''.join(lines)


def _beam_count(rng: random.Random, data: bytes, tag: bytes) -> bytes:
    lines = _lines(data)
    index = rng.choice(_record_lines(lines, (tag,)))
    tokens = lines[index].split()
    at = 1 if tag == b'FLASER' else 8
    tokens[at] = str(max(0, int(tokens[at]) + rng.choice((-3, -1, 1, 2, 1000)))).encode()
    lines[index] = b' '.join(tokens) + b'\n'
    return b''.join(lines)


def _shuffle(rng: random.Random, data: bytes) -> bytes:
    lines = _lines(data)
    rng.shuffle(lines)
    return b''.join(lines)


def _duplicate(rng: random.Random, data: bytes) -> bytes:
    lines = _lines(data)
    start = rng.randrange(len(lines))
    stop = min(len(lines), start + rng.randint(1, 40))
    return b''.join(lines[:stop] + lines[start:stop] + lines[stop:])


def _truncate(rng: random.Random, data: bytes) -> bytes:
    return data[:rng.randrange(len(data))]


def _garbage(rng: random.Random, data: bytes) -> bytes:
    at = rng.randrange(len(data))
    return data[:at] + rng.randbytes(rng.randint(1, 64)) + data[at:]


def _overwrite(rng: random.Random, data: bytes) -> bytes:
    at = rng.randrange(len(data))
    noise = rng.randbytes(rng.randint(8, 256))
    return data[:at] + noise + data[at + len(noise):]


_TEXT_DAMAGE = {
    'truncated': _truncate,
    'garbage bytes': _garbage,
    'implausible number': lambda rng, data: _laser_field(rng, data, b'FLASER'),
    'malformed number': lambda rng, data: _set_field(rng, data, (b'FLASER',), MALFORMED),
    'missing fields': lambda rng, data: _drop_fields(rng, data, (b'FLASER',)),
    'wrong beam count': lambda rng, data: _beam_count(rng, data, b'FLASER'),
    'shuffled lines': _shuffle,
    'duplicated lines': _duplicate,
    'empty': lambda rng, data: b'',
    'binary garbage': lambda rng, data: rng.randbytes(4096),
}
# variants per kind of damage
_TEXT_VARIANTS = {'truncated': 4, 'garbage bytes': 3, 'implausible number': 12,
                  'malformed number': 4, 'missing fields': 3, 'wrong beam count': 3,
                  'shuffled lines': 2, 'duplicated lines': 3, 'empty': 1, 'binary garbage': 2}

_GRAPH_DAMAGE = {
    'truncated': _truncate,
    'garbage bytes': _garbage,
    'implausible vertex': lambda rng, data: _set_field(rng, data, (b'VERTEX_SE2',),
                                                       IMPLAUSIBLE),
    'implausible laser value': lambda rng, data: _laser_field(rng, data, b'ROBOTLASER1'),
    'malformed laser line': lambda rng, data: _set_field(rng, data, (b'ROBOTLASER1',),
                                                         MALFORMED + IMPLAUSIBLE),
    'missing fields': lambda rng, data: _drop_fields(rng, data, (b'VERTEX_SE2',
                                                                 b'ROBOTLASER1')),
    'wrong beam count': lambda rng, data: _beam_count(rng, data, b'ROBOTLASER1'),
    'duplicated lines': _duplicate,
    'shuffled lines': _shuffle,
}
_GRAPH_VARIANTS = {'truncated': 2, 'garbage bytes': 1, 'implausible vertex': 3,
                   'implausible laser value': 3, 'malformed laser line': 2,
                   'missing fields': 2, 'wrong beam count': 1, 'duplicated lines': 1,
                   'shuffled lines': 1}


def _variants(counts: dict[str, int]) -> list:
    return [pytest.param(kind, seed, id=f'{kind.replace(" ", "-")}-{seed}')
            for kind, count in counts.items() for seed in range(count)]


def _rng(kind: str, seed: int) -> random.Random:
    return random.Random(f'issue-48 {kind} {seed}')  # str seeds hash the same in every run


# -- the contract ---------------------------------------------------------------------------

def _run(capsys, arguments: list[str]) -> tuple[int, str, str]:
    """The command in this process: exit code, stdout, stderr; no numpy warning allowed."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        code = main(arguments)
    out, err = capsys.readouterr()
    numeric = [str(warning.message) for warning in caught
               if issubclass(warning.category, RuntimeWarning)]
    assert not numeric, f'{arguments}: warnings {numeric}'
    return code, out, err


def _assert_contract(code: int, err: str, source: Path, outputs: list[Path], strict_json,
                     workspace: Path) -> None:
    assert code in ALLOWED_CODES, err
    assert 'Traceback' not in err, err
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert str(source) in lines[0], err
        for output in outputs:
            assert not output.exists(), f'{output} left behind by a failed run'
    else:
        for output in outputs:
            if output.suffix == '.json' and output.exists():
                strict_json(output.read_text())
    assert not list(workspace.rglob('*.partial')), 'a staging folder was left behind'


def _check(capsys, strict_json, source: Path, out: Path, *extra: str) -> int:
    outputs = [out / 'report.json', out / 'pairs.csv']
    arguments = ['check', str(source), '--quiet', '--report', str(outputs[0]), '--pairs-csv',
                 str(outputs[1]), *extra]
    if '--plot' in extra:
        outputs.append(Path(extra[extra.index('--plot') + 1]))
    code, _, err = _run(capsys, arguments)
    _assert_contract(code, err, source, outputs, strict_json, out.parent)
    if code == 2:
        assert not out.exists()  # not even the folder made for the outputs
    return code


# -- CARMEN logs ----------------------------------------------------------------------------

@pytest.mark.parametrize('kind, seed', _variants(_TEXT_VARIANTS))
def test_damaged_logs(sources, tmp_path, capsys, strict_json, kind, seed):
    rng = _rng(kind, seed)
    damaged = tmp_path / 'damaged.log'
    damaged.write_bytes(_TEXT_DAMAGE[kind](rng, sources['log'].read_bytes()))
    draw = ['--plot', str(tmp_path / 'out' / 'map.png')] if seed == 0 and kind in (
        'truncated', 'implausible number') else []
    _check(capsys, strict_json, damaged, tmp_path / 'out', *draw)
    if kind in ('implausible number', 'duplicated lines', 'truncated', 'malformed number'):
        bag = tmp_path / 'bags' / 'converted'
        code, _, err = _run(capsys, ['convert', str(damaged), str(bag), '--quiet',
                                     '--limit', '60'])
        _assert_contract(code, err, damaged, [bag], strict_json, tmp_path)
        if code == 2:
            assert not (tmp_path / 'bags').exists()
        elif seed == 0:
            report = tmp_path / 'replayed' / 'report.json'
            code, _, err = _run(capsys, ['replay', str(bag), '--quiet', '--report',
                                         str(report)])
            _assert_contract(code, err, bag, [report], strict_json, tmp_path)


@pytest.mark.parametrize('kind, seed', [
    pytest.param('cut', 0, id='cut-early'), pytest.param('cut', 1, id='cut-late'),
    *(pytest.param('garbled', seed, id=f'garbled-{seed}') for seed in range(4)),
    pytest.param('header', 0, id='header-only')])
def test_damaged_gzip_logs(sources, tmp_path, capsys, strict_json, kind, seed):
    data = sources['gzip'].read_bytes()
    rng = _rng(kind, seed)
    if kind == 'cut':
        # early: the first scans, late: most of the log, before the stream's end
        at = rng.randrange(len(data) // 20, len(data) // 10) if seed == 0 else len(data) - 100
        damaged_bytes = data[:at]
    elif kind == 'garbled':  # a run of set bits in the first scans: a broken deflate stream
        at, length = rng.randrange(100, len(data) // 20), rng.randint(8, 32)
        damaged_bytes = data[:at] + b'\xff' * length + data[at + length:]
    else:
        damaged_bytes = data[:10]
    damaged = tmp_path / 'damaged.log.gz'
    damaged.write_bytes(damaged_bytes)
    assert _check(capsys, strict_json, damaged, tmp_path / 'out', '--every', '4') == 2


def _sensor_parameter(rng: random.Random, data: bytes) -> bytes:
    """The stated maximum range or resolution (PARAM lines) made implausible."""
    name = rng.choice((b'robot_front_laser_max', b'laser_front_laser_resolution'))
    lines = _lines(data)
    index = next(index for index, line in enumerate(lines) if line.startswith(b'PARAM ' + name))
    tokens = lines[index].split()
    tokens[2] = rng.choice(IMPLAUSIBLE).encode()
    lines[index] = b' '.join(tokens) + b'\n'
    return b''.join(lines)


@pytest.mark.parametrize('field', ['laser record', 'sensor parameter'])
def test_a_gzip_log_of_implausible_numbers(sources, tmp_path, capsys, strict_json, field):
    rng = _rng(f'gzip {field}', 0)
    with gzip.open(sources['gzip'], 'rb') as stream:
        text = stream.read()[:400_000]  # the PARAM lines and the first scans
    text = text[:text.rindex(b'\n') + 1]
    damaged = tmp_path / 'damaged.log.gz'
    damaged.write_bytes(gzip.compress(_laser_field(rng, text, b'FLASER') if field == 'laser record'
                                      else _sensor_parameter(rng, text)))
    assert _check(capsys, strict_json, damaged, tmp_path / 'out') == 2


# -- g2o graphs -----------------------------------------------------------------------------

@pytest.mark.parametrize('kind, seed', _variants(_GRAPH_VARIANTS))
def test_damaged_graphs(sources, tmp_path, capsys, strict_json, kind, seed):
    rng = _rng(kind, seed)
    damaged = tmp_path / 'damaged.g2o'
    damaged.write_bytes(_GRAPH_DAMAGE[kind](rng, sources['graph'].read_bytes()))
    _check(capsys, strict_json, damaged, tmp_path / 'out')
    if seed == 0 and kind in ('implausible vertex', 'implausible laser value', 'truncated'):
        report = tmp_path / 'tuned' / 'tune.json'
        code, _, err = _run(capsys, ['tune', str(damaged), '--quiet', '--report', str(report),
                                     *TUNE_FAST])
        _assert_contract(code, err, damaged, [report], strict_json, tmp_path)


# -- bags -----------------------------------------------------------------------------------

def _bag_metadata(rng: random.Random, folder: Path) -> None:
    metadata = folder / 'metadata.yaml'
    lines = metadata.read_text().splitlines(keepends=True)
    at = rng.randrange(len(lines))
    lines[at] = lines[at].rstrip('\n') + rng.choice((' [', ': :', ' {a', ' "')) + '\n'
    metadata.write_text(''.join(lines))


_BAG_DAMAGE = {
    'truncated storage': lambda rng, folder: _damage_file(rng, folder, _truncate),
    'overwritten storage': lambda rng, folder: _damage_file(rng, folder, _overwrite),
    'metadata syntax': _bag_metadata,
    'metadata structure': lambda rng, folder: (folder / 'metadata.yaml').write_text(
        rng.choice(('rosbag2_bagfile_information: 5\n', '- [1, 2]\n', 'x: {}\n'))),
    'metadata empty': lambda rng, folder: (folder / 'metadata.yaml').write_text(''),
    'metadata missing': lambda rng, folder: (folder / 'metadata.yaml').unlink(),
    'storage missing': lambda rng, folder: next(folder.glob('*.mcap')).unlink(),
}
_BAG_VARIANTS = {'truncated storage': 4, 'overwritten storage': 5, 'metadata syntax': 3,
                 'metadata structure': 2, 'metadata empty': 1, 'metadata missing': 1,
                 'storage missing': 1}


def _damage_file(rng: random.Random, folder: Path, damage) -> None:
    storage = next(folder.glob('*.mcap'))
    storage.write_bytes(damage(rng, storage.read_bytes()))


@pytest.mark.parametrize('kind, seed', _variants(_BAG_VARIANTS))
def test_damaged_bags(sources, tmp_path, capsys, strict_json, kind, seed):
    bag = tmp_path / 'damaged_bag'
    shutil.copytree(sources['bag'], bag)
    _BAG_DAMAGE[kind](_rng(kind, seed), bag)
    report = tmp_path / 'out' / 'report.json'
    code, _, err = _run(capsys, ['replay', str(bag), '--quiet', '--report', str(report)])
    _assert_contract(code, err, bag, [report], strict_json, tmp_path)


@pytest.mark.parametrize('damage', [_truncate, _overwrite], ids=['truncated', 'overwritten'])
def test_damaged_demo_bag(tmp_path, capsys, strict_json, damage):
    bag = tmp_path / 'intel_demo.mcap'
    bag.write_bytes(damage(_rng(damage.__name__, 0), DEMO_BAG.read_bytes()))
    report = tmp_path / 'out' / 'report.json'
    code, _, err = _run(capsys, ['replay', str(bag), '--quiet', '--report', str(report),
                                 '--duration', '20'])
    _assert_contract(code, err, bag, [report], strict_json, tmp_path)


# -- a real process -------------------------------------------------------------------------

def test_a_real_process_prints_one_line_and_leaves_nothing(sources, tmp_path):
    # the cases, end to end: a pose of 1e300, a heading of 1e200, a NaN timestamp
    # given to convert; each refused in one line naming file and line, no bag behind
    lines = sources['log'].read_bytes().splitlines(keepends=True)
    index = _record_lines(lines, (b'FLASER',))[10]
    tokens = lines[index].split()
    beams = int(tokens[1])
    cases = []
    for name, field, value in (('pose', 2 + beams, b'1e300'), ('heading', 4 + beams, b'1e200'),
                               ('stamp', len(tokens) - 1, b'nan')):
        changed = list(tokens)
        changed[field] = value
        damaged = tmp_path / f'{name}.log'
        damaged.write_bytes(b''.join(lines[:index] + [b' '.join(changed) + b'\n']
                                     + lines[index + 1:]))
        cases.append(damaged)
    commands = [['check', str(cases[0])], ['check', str(cases[1])],
                ['convert', str(cases[2]), str(tmp_path / 'out' / 'bag')]]
    for command in commands:
        done = subprocess.run([sys.executable, '-m', 'map_consistency_ros.cli.main', *command,
                               '--quiet'], capture_output=True, text=True, timeout=300)
        assert done.returncode == 2, done.stderr
        (line,) = done.stderr.strip().splitlines()
        assert f'{command[1]}:{index + 1}: ' in line
    assert not (tmp_path / 'out').exists()


def _damage_scan_angle(rng, msgtype, message):
    message.angle_increment = rng.choice((math.nan, math.inf, -0.01, 0.0, 40.0))


def _damage_scan_limits(rng, msgtype, message):
    message.range_max = rng.choice((math.nan, -math.inf, 1e9, -1.0))


def _damage_scan_ranges(rng, msgtype, message):
    # beams without a return are legitimate: NaN, inf, negative, beyond range_max
    ranges = message.ranges.copy()
    ranges[rng.sample(range(ranges.size), 20)] = rng.choice((np.nan, np.inf, -np.inf, -1.0,
                                                            1e30))
    message.ranges = ranges


def _damage_stamp(rng, msgtype, message):
    message.header.stamp.sec = rng.choice((-5, -2 ** 31))


def _damage_path(rng, msgtype, message):
    entry = rng.choice(message.poses)
    setattr(entry.pose.position, rng.choice('xy'), rng.choice((math.nan, 1e300, -3e6)))
    entry.pose.orientation.w = rng.choice((math.nan, 1e300, 0.0))
    entry.pose.orientation.z = rng.choice((math.inf, 0.0))


def _damage_constraints(rng, msgtype, message):
    data = message.data.copy()
    data[rng.randrange(data.size)] = rng.choice((np.nan, np.inf, 1e300, -1e300))
    message.data = data


_MESSAGE_DAMAGE = {
    'scan angles': ('sensor_msgs/msg/LaserScan', _damage_scan_angle),
    'scan range limits': ('sensor_msgs/msg/LaserScan', _damage_scan_limits),
    'scan ranges': ('sensor_msgs/msg/LaserScan', _damage_scan_ranges),
    'scan stamps': ('sensor_msgs/msg/LaserScan', _damage_stamp),
    'trajectory poses': ('nav_msgs/msg/Path', _damage_path),
    'constraints': ('std_msgs/msg/Float64MultiArray', _damage_constraints),
}


@pytest.mark.parametrize('kind', list(_MESSAGE_DAMAGE))
def test_a_bag_of_damaged_messages(sources, tmp_path, capsys, strict_json, kind):
    # a sound container whose messages carry damaged numbers: each is ignored with a warning
    # or refused, never an internal error, and the report stays strict JSON
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    rng = _rng(kind, 0)
    target_type, damage = _MESSAGE_DAMAGE[kind]
    store = get_typestore(Stores.ROS2_JAZZY)
    bag = tmp_path / 'damaged_bag'
    with AnyReader([sources['bag']], default_typestore=store) as reader, \
            Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {connection.id: writer.add_connection(connection.topic,
                                                            connection.msgtype,
                                                            typestore=store)
                       for connection in reader.connections}
        damaged = set(rng.sample(range(reader.message_count), reader.message_count // 10))
        for index, (connection, time, data) in enumerate(reader.messages()):
            if connection.msgtype == target_type and (index in damaged or index < 3):
                message = reader.deserialize(data, connection.msgtype)
                damage(rng, connection.msgtype, message)
                data = store.serialize_cdr(message, connection.msgtype)
            writer.write(connections[connection.id], time, data)
    report = tmp_path / 'out' / 'report.json'
    code, _, err = _run(capsys, ['replay', str(bag), '--quiet', '--report', str(report)])
    _assert_contract(code, err, bag, [report], strict_json, tmp_path)
