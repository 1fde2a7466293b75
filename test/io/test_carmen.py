"""CARMEN log reading: real logs, sensor models, and every kind of bad input."""
import gzip
import math

import numpy as np
import pytest

from map_consistency_ros.io import carmen
from map_consistency_ros.io.errors import InputError

FLASER = 'FLASER 3 1.0 2.0 3.0 0.5 0.25 0.1 0.5 0.25 0.1 12.5 host 12.75\n'


def test_intel_corrected_log(shared_data):
    log = carmen.read_carmen_log(shared_data / 'intel' / 'intel.gfs.log')
    assert log.ranges.shape == (910, 180)
    assert log.laser_poses.shape == (910, 3)
    # Corrected logs carry the corrected pose in both pose slots.
    np.testing.assert_array_equal(log.laser_poses, log.robot_poses)
    np.testing.assert_allclose(log.ranges[0, :4], [1.09, 1.08, 1.08, 1.07])
    np.testing.assert_allclose(log.laser_poses[0], [0.600266, -0.0320327, -0.354665])
    assert log.timestamps[0] == pytest.approx(32.9068)
    model = carmen.sensor_model(log)
    assert model.angle_min == pytest.approx(-math.pi / 2)
    assert model.angle_increment == pytest.approx(math.pi / 180)
    assert model.max_range == 8.0


def test_gzipped_log_with_resolution_param(shared_data):
    log = carmen.read_carmen_log(shared_data / 'fr079' / 'freiburg-079-corrected.log.gz')
    assert log.ranges.shape == (4791, 360)
    model = carmen.sensor_model(log)
    assert model.angle_increment == pytest.approx(math.radians(0.5))
    assert model.angle_min == pytest.approx(-math.pi / 2)
    # The log states an 80.99 m sensor; the usable range stays the 8 m default.
    assert carmen.stated_max_range(log) == pytest.approx(80.99)
    assert model.max_range == 8.0


def test_explicit_fov_and_max_range(tmp_path):
    path = tmp_path / 'tiny.log'
    path.write_text(FLASER * 2)
    model = carmen.sensor_model(carmen.read_carmen_log(path), fov=math.radians(90),
                                max_range=4.0)
    assert model.angle_increment == pytest.approx(math.radians(45))
    assert model.angle_min == pytest.approx(-math.radians(45))
    assert model.max_range == 4.0
    full = carmen.sensor_model(carmen.read_carmen_log(path), fov=2 * math.pi)
    assert full.angle_increment == pytest.approx(2 * math.pi / 3)


def test_robotlaser_records(tmp_path):
    line = ('ROBOTLASER1 0 -1.5 3.0 1.5 20.0 0.01 0 3 1.0 2.0 3.0 2 7 8 '
            '1.0 2.0 0.3 0.9 2.0 0.3 0 0 0 0 0 99.5 host 99.75\n')
    path = tmp_path / 'robot.log.gz'
    with gzip.open(path, 'wt') as stream:
        stream.write('# comment\nPARAM robot_front_laser_max 30 nohost 0\n' + line)
    log = carmen.read_carmen_log(path)
    np.testing.assert_allclose(log.ranges, [[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(log.laser_poses, [[1.0, 2.0, 0.3]])
    np.testing.assert_allclose(log.robot_poses, [[0.9, 2.0, 0.3]])
    assert log.timestamps[0] == 99.75
    model = carmen.sensor_model(log, max_range=50.0)
    assert (model.angle_min, model.angle_increment) == (-1.5, 1.5)
    assert model.max_range == 20.0  # capped by the stated sensor maximum


@pytest.mark.parametrize('content,message,line', [
    ('', 'no FLASER or ROBOTLASER1', None),
    ('ODOM 0 0 0 0 0 0 1 host 1\n', 'no FLASER or ROBOTLASER1', None),
    ('FLASER 3 1.0 2.0\n', 'truncated FLASER', 1),
    ('# header\nFLASER 3 1.0 abc 3.0 0 0 0 0 0 0 1 h 1\n', "non-numeric range 'abc'", 2),
    ('FLASER x 1.0\n', 'integer', 1),
    (FLASER + 'FLASER 2 1.0 2.0 0 0 0 0 0 0 1 h 1\n', r'first laser record \(line 1\) has 3', 2),
    ('FLASER 3 1.0 2.0 3.0 nan 0 0 0 0 0 1 h 1\n', 'not finite', 1),
    ('ROBOTLASER1 0 -1.5 3.0 1.5 20.0 0.01 0 3 1.0 2.0\n', 'truncated ROBOTLASER1', 1),
])
def test_bad_input_names_file_and_line(tmp_path, content, message, line):
    path = tmp_path / 'bad.log'
    path.write_text(content)
    with pytest.raises(InputError, match=message) as caught:
        carmen.read_carmen_log(path)
    assert caught.value.line == line
    assert str(path) in str(caught.value)


# FLASER 3 ranges, laser pose, robot pose, ipc timestamp, host, logger timestamp
_FIELDS = ['1.0', '2.0', '3.0', '0', '0', '0', '0', '0', '0', '1', 'h', '1']


def _flaser(position: int, value: str) -> str:
    fields = list(_FIELDS)
    fields[position] = value
    return 'FLASER 3 ' + ' '.join(fields) + '\n'


@pytest.mark.parametrize('position,value,message', [
    (3, '1e300', r'laser pose x 1e\+300 is beyond 100000 m'),
    (4, '-2e6', r'laser pose y -2000000.0 is beyond'),
    (5, '1e200', r'laser pose theta 1e\+200 is beyond 1000 rad'),
    (5, 'inf', 'laser pose theta inf is not finite'),
    (8, 'nan', 'robot pose theta nan is not finite'),
    (11, 'nan', 'logger timestamp nan is not finite'),
    (11, '-1', 'logger timestamp -1.0 is negative'),
    (11, '1e12', 'logger timestamp 1000000000000.0 is beyond'),
    (1, 'nan', 'range 2 nan is not finite'),
    (2, '-inf', 'range 3 -inf is not finite'),
    (0, '1e300', r'range 1 1e\+300 is beyond'),
])
def test_implausible_numbers_are_bad_input(tmp_path, position, value, message):
    path = tmp_path / 'bad.log'
    path.write_text(FLASER + _flaser(position, value))
    with pytest.raises(InputError, match=message) as caught:
        carmen.read_carmen_log(path)
    assert caught.value.line == 2
    assert str(path) in str(caught.value)


@pytest.mark.parametrize('head,message', [
    ('nan 3.0 1.5 20.0', 'start angle nan is not finite'),
    ('-1.5 1e9 1.5 20.0', 'field of view 1000000000.0 is beyond'),
    ('-1.5 3.0 1.5 inf', 'maximum range inf is not finite'),
])
def test_implausible_laser_parameters_are_bad_input(tmp_path, head, message):
    path = tmp_path / 'bad.log'
    path.write_text(f'ROBOTLASER1 0 {head} 0.01 0 3 1.0 2.0 3.0 0 0 0 0 0 0 0 0 0 0 0 0 1 h 1\n')
    with pytest.raises(InputError, match=message) as caught:
        carmen.read_carmen_log(path)
    assert caught.value.line == 1


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match='no such file'):
        carmen.read_carmen_log(tmp_path / 'absent.log')


def test_garbled_gzip(tmp_path, shared_data):
    data = (shared_data / 'carmen_corrected_extra' / 'orebro-corrected.log.gz').read_bytes()
    path = tmp_path / 'garbled.log.gz'
    path.write_bytes(data[:1000] + b'\xff' * 16 + data[1016:])  # a broken deflate stream
    with pytest.raises(InputError, match='cannot read the file'):
        carmen.read_carmen_log(path)


def test_truncated_gzip(tmp_path, shared_data):
    data = (shared_data / 'carmen_corrected_extra' / 'orebro-corrected.log.gz').read_bytes()
    path = tmp_path / 'cut.log.gz'
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match='cannot read|truncated'):
        carmen.read_carmen_log(path)


@pytest.mark.parametrize('name, value, message', [
    ('robot_front_laser_max', '1e300', r'PARAM robot_front_laser_max \(in m\) 1e\+300 is beyond'),
    ('robot_front_laser_max', 'nan', r'PARAM robot_front_laser_max \(in m\) nan is not finite'),
    ('laser_front_laser_resolution', 'inf', 'laser_front_laser_resolution .* inf is not finite'),
])
def test_implausible_sensor_parameters_are_bad_input(tmp_path, name, value, message):
    path = tmp_path / 'bad.log'
    path.write_text(f'PARAM {name} {value} nohost 0\n' + FLASER)
    with pytest.raises(InputError, match=message) as caught:
        carmen.read_carmen_log(path)
    assert caught.value.line == 1
