"""FLASER logs written from arrays read back exactly by io/carmen.py."""
import numpy as np
import pytest

from map_consistency_ros.io.carmen import read_carmen_log
from map_consistency_ros.io.carmen_writer import write_flaser_log


@pytest.mark.parametrize('name', ['run.log', 'run.log.gz'])
def test_round_trip(tmp_path, name):
    rng = np.random.default_rng(0)
    ranges = np.round(rng.uniform(0.1, 30, (4, 181)), 2)
    ranges[0, 0] = 1 / 3  # no short decimal: the shortest exact form
    poses = rng.uniform(-5, 5, (4, 3))
    stamps = np.arange(4) * 0.2 + 1e5
    write_flaser_log(tmp_path / name, ranges, poses, stamps, comment='made\nhere')
    log = read_carmen_log(tmp_path / name)
    assert np.array_equal(log.ranges, ranges)
    assert np.allclose(log.laser_poses, poses, atol=5e-7)
    assert np.array_equal(log.laser_poses, log.robot_poses)
    assert np.allclose(log.timestamps, stamps, atol=5e-7)
    assert log.line_numbers[0] == 2  # after the one comment line


@pytest.mark.parametrize('ranges, poses, stamps, host', [
    (np.ones((2, 3)), np.zeros((3, 3)), np.zeros(2), 'h'),
    (np.full((1, 3), np.nan), np.zeros((1, 3)), np.zeros(1), 'h'),
    (np.ones((1, 3)), np.zeros((1, 3)), np.zeros(1), 'two words'),
])
def test_bad_arrays_write_nothing(tmp_path, ranges, poses, stamps, host):
    with pytest.raises(ValueError):
        write_flaser_log(tmp_path / 'bad.log', ranges, poses, stamps, host=host)
    assert not list(tmp_path.iterdir())
