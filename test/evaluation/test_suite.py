"""The labelled map suite: keyframes, rigid breaks, reproducibility on real logs."""
import numpy as np
import pytest

from map_consistency_ros.core.geometry import se2
from map_consistency_ros.evaluation.suite import (BREAKS, CORRECTED_LOGS, SuiteParameters,
                                                  build_suite, displace, keyframes)
from map_consistency_ros.io.carmen import read_carmen_log
from map_consistency_ros.io.errors import InputError

PARAMETERS = SuiteParameters(part_size=60)


@pytest.fixture(scope='module')
def orebro_suite(shared_data):
    return build_suite(shared_data, PARAMETERS, ['orebro'])


def test_keyframes_keep_poses_that_moved_or_turned():
    poses = np.array([[0, 0, 0], [0.2, 0, 0], [0.6, 0, 0], [0.7, 0, 0.6], [0.8, 0, 0.6],
                      [0.8, 0.6, 0.6]], dtype=float)
    assert keyframes(poses, 0.5, 0.5).tolist() == [0, 2, 3, 5]
    assert keyframes(poses[:0], 0.5, 0.5).tolist() == []


def test_displace_moves_one_part_rigidly():
    rng = np.random.default_rng(2)
    poses = np.column_stack([rng.uniform(-5, 5, (12, 2)), rng.uniform(-3, 3, 12)])
    rotation, shift = np.radians(4.0), np.array([0.3, -0.2])
    moved = displace(poses, 4, 9, rotation, shift)
    np.testing.assert_array_equal(moved[:4], poses[:4])
    np.testing.assert_array_equal(moved[9:], poses[9:])
    # oracle: rotate the positions about pose 4 with a rotation matrix, then shift
    turn = np.array([[np.cos(rotation), -np.sin(rotation)], [np.sin(rotation), np.cos(rotation)]])
    expected = (poses[4:9, :2] - poses[4, :2]) @ turn.T + poses[4, :2] + shift
    np.testing.assert_allclose(moved[4:9, :2], expected, atol=1e-12)
    np.testing.assert_allclose(se2.wrap_angle(moved[4:9, 2] - poses[4:9, 2]), rotation)
    # the moved part keeps its shape
    np.testing.assert_allclose(se2.relative(moved[4], moved[5:9]),
                               se2.relative(poses[4], poses[5:9]), atol=1e-12)


def test_suite_parts_and_labels(orebro_suite, shared_data):
    log = read_carmen_log(shared_data / CORRECTED_LOGS['orebro'])
    corrected = [item for item in orebro_suite if item.kind == 'corrected']
    assert len(orebro_suite) == len(corrected) * (1 + len(BREAKS))
    covered = np.concatenate([item.scan_indices for item in corrected])
    np.testing.assert_array_equal(covered, keyframes(log.laser_poses, 0.5, 0.5))
    for item in orebro_suite:
        np.testing.assert_array_equal(item.reference_poses, log.laser_poses[item.scan_indices])
        assert item.inconsistent == (item.kind != 'corrected')
        assert item.environment == 'static'
        moved = np.any(np.abs(item.poses - item.reference_poses) > 1e-9, axis=1)
        if item.kind == 'corrected':
            assert not moved.any()
        else:
            first = int(np.argmax(moved))
            assert len(item.scan_indices) // 4 <= first < 3 * len(item.scan_indices) // 4
            if item.kind == 'corrupted':
                assert 3 <= moved.sum() <= 10
            else:
                assert moved[first:].all()


def test_suite_is_reproducible_from_the_seed(orebro_suite, shared_data):
    again = build_suite(shared_data, PARAMETERS, ['orebro'])
    other = build_suite(shared_data, SuiteParameters(part_size=60, seed=8), ['orebro'])
    assert [item.name for item in again] == [item.name for item in orebro_suite]
    for first, second, third in zip(orebro_suite, again, other):
        np.testing.assert_array_equal(first.poses, second.poses)
        if first.inconsistent:
            assert not np.array_equal(first.poses, third.poses)


def test_unknown_dataset_and_bad_parameters_are_rejected(shared_data):
    with pytest.raises(ValueError, match='unknown datasets'):
        build_suite(shared_data, PARAMETERS, ['atlantis'])
    with pytest.raises(ValueError, match='part_size'):
        SuiteParameters(part_size=5)
    with pytest.raises(ValueError, match='bad range'):
        SuiteParameters(shift_metres=(0.5, 0.2))
    with pytest.raises(ValueError, match='keyframe'):
        SuiteParameters(keyframe_distance=-1.0)


def test_missing_data_folder_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match='no such file'):
        build_suite(tmp_path, PARAMETERS, ['orebro'])
