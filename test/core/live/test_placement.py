"""The monitor's placed geometry: built once per pose, again after invalidation."""
import math

import numpy as np

from map_consistency_ros.core.geometry import ScanSet, SensorModel
from map_consistency_ros.core.live._placement import Placement

MODEL = SensorModel(angle_min=-math.pi / 2, angle_increment=math.pi / 4, max_range=10.0)


def test_scans_are_placed_once_until_their_slot_is_invalidated():
    poses = np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)])
    ranges = np.full((5, 5), 2.0)
    built = []

    def build(slots):
        built.append(slots.tolist())
        return ScanSet.from_ranges(ranges[slots], poses[slots], MODEL)

    placement = Placement()
    first = placement.scans(np.array([3, 1, 3]), build)
    np.testing.assert_array_equal(first.sensor_poses, poses[[3, 1, 3]])
    placement.scans(np.array([1, 2]), build)
    assert built == [[1, 3], [2]]
    poses[1] = [7.0, 7.0, 0.0]
    placement.invalidate(np.array([1, 40]))  # a slot never placed is no error
    moved = placement.scans(np.array([2, 1]), build)
    assert built[-1] == [1]
    np.testing.assert_array_equal(moved.sensor_poses, poses[[2, 1]])
    np.testing.assert_array_equal(moved.endpoints,
                                  ScanSet.from_ranges(ranges[[2, 1]], poses[[2, 1]],
                                                      MODEL).endpoints)
